//! SVG and HTML pieces of the demo's report, as pure string builders: a picture cut into
//! panels with axes in the picture's own units, colour bars with ticks and units, line plots,
//! and the escaping that every text and path read from a file goes through.

use std::fmt::Write as _;

/// Escapes text for HTML and SVG content and attribute values.
pub fn esc(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// A relative link to a file in the report's folder: each byte outside the URL's unreserved
/// set (and `/`) percent-encoded, so names with spaces, `#`, `?` or markup stay one path.
pub fn href(rel: &str) -> String {
    let mut out = String::with_capacity(rel.len());
    for b in rel.bytes() {
        if b.is_ascii_alphanumeric() || b"-._~/".contains(&b) {
            out.push(b as char);
        } else {
            let _ = write!(out, "%{b:02X}");
        }
    }
    out
}

/// `rgb(r,g,b)` for a fill.
pub fn rgb(c: [u8; 3]) -> String {
    format!("rgb({},{},{})", c[0], c[1], c[2])
}

/// Round tick values over `lo..=hi`: multiples of 1, 2 or 5 times a power of ten, about
/// `target` of them. Returns the ticks and the step (which sets the decimals shown).
pub fn ticks(lo: f64, hi: f64, target: usize) -> (Vec<f64>, f64) {
    if !lo.is_finite() || !hi.is_finite() || hi <= lo {
        return (vec![lo], 1.0);
    }
    let raw = (hi - lo) / target.max(1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0].into_iter().map(|m| m * mag).find(|s| *s >= raw).unwrap_or(10.0 * mag);
    let first = (lo / step - 1e-9).ceil() as i64;
    let last = (hi / step + 1e-9).floor() as i64;
    ((first..=last).map(|i| i as f64 * step).collect(), step)
}

/// A tick label with as many decimals as the step needs (no "-0").
pub fn tick_label(v: f64, step: f64) -> String {
    let decimals = if step >= 1.0 { 0 } else { (-step.log10().floor()) as usize };
    let s = format!("{v:.decimals$}");
    if s.trim_start_matches('-').chars().all(|c| c == '0' || c == '.') {
        s.trim_start_matches('-').to_string()
    } else {
        s
    }
}

/// A linear map from values to positions along one side of a panel, in the picture's pixels
/// measured from the panel's corner (`px.0` is where `value.0` lies).
#[derive(Clone, Debug, PartialEq)]
pub struct Scale {
    /// What the axis measures, with its unit ("camera x (px)").
    pub label: String,
    pub value: (f64, f64),
    pub px: (f64, f64),
}

impl Scale {
    /// Pixel coordinates of an image `extent` pixels long shown over `len` picture pixels.
    /// Integer coordinates are pixel centres (ARCHITECTURE.md), so the edges are -0.5 and
    /// `extent - 0.5`.
    pub fn pixels(label: impl Into<String>, extent: u32, len: u32) -> Scale {
        Scale { label: label.into(), value: (-0.5, extent as f64 - 0.5), px: (0.0, len as f64) }
    }

    fn at(&self, v: f64) -> f64 {
        self.px.0 + (v - self.value.0) / (self.value.1 - self.value.0) * (self.px.1 - self.px.0)
    }

    fn ticks(&self) -> (Vec<f64>, f64) {
        let (lo, hi) = (self.value.0.min(self.value.1), self.value.0.max(self.value.1));
        ticks(lo, hi, 5)
    }
}

/// One panel of a picture: the part `src = [x, y, w, h]` (picture pixels), shown `width`
/// units wide, with a title, alt text and optional axes.
#[derive(Clone, Debug)]
pub struct Panel {
    pub src: [u32; 4],
    pub width: f64,
    pub title: String,
    pub alt: String,
    pub x: Option<Scale>,
    pub y: Option<Scale>,
}

const FONT: &str = r##"font-family="system-ui,sans-serif" font-size="12" fill="#1a1a1a""##;

/// One panel as a standalone SVG (so panels wrap on a narrow screen): the picture at `href`
/// (`img` its size in pixels) cropped to the panel, the title above, ticks and labels on the
/// left and bottom. `role="img"` with the alt text as its title, for screen readers.
pub fn panel(href_attr: &str, img: (u32, u32), p: &Panel, id: &str) -> String {
    let [sx, sy, sw, sh] = p.src;
    let k = p.width / sw.max(1) as f64;
    let (w, h) = (p.width, sh as f64 * k);
    let left = if p.y.is_some() { 46.0 } else { 4.0 };
    let bottom = if p.x.is_some() { 38.0 } else { 4.0 };
    let top = if p.title.is_empty() { 4.0 } else { 20.0 };
    let right = 12.0;
    let (tw, th) = (left + w + right, top + h + bottom);
    let mut s = String::new();
    let _ = write!(
        s,
        r#"<svg class="panel" role="img" aria-labelledby="{id}" viewBox="0 0 {tw:.0} {th:.0}" width="{tw:.0}" height="{th:.0}" {FONT}><title id="{id}">{alt}</title>"#,
        alt = esc(&p.alt)
    );
    if !p.title.is_empty() {
        let _ = write!(s, r#"<text x="{left}" y="14" font-weight="600">{}</text>"#, esc(&p.title));
    }
    let _ = write!(
        s,
        r#"<svg x="{left}" y="{top}" width="{w:.1}" height="{h:.1}" viewBox="{sx} {sy} {sw} {sh}" preserveAspectRatio="none"><image href="{href_attr}" width="{}" height="{}"/></svg>"#,
        img.0, img.1
    );
    s.push_str(&panel_axes(p, left, top, k));
    s.push_str("</svg>");
    s
}

/// A colour bar: the colours a false-colour map gives to values `lo..=hi`, as a gradient
/// through `stops` (position 0..=1 along the bar, colour), with ticks in `unit`, labelled
/// marks (a limit) and swatches for colours outside the scale ("not measured").
#[derive(Clone, Debug)]
pub struct ColourBar {
    pub title: String,
    pub stops: Vec<(f64, [u8; 3])>,
    pub lo: f64,
    pub hi: f64,
    pub unit: String,
    pub marks: Vec<(f64, String)>,
    pub swatches: Vec<([u8; 3], String)>,
}

impl ColourBar {
    /// Samples `colour(t)` at `n + 1` even steps of 0..=1; exact for a ramp that is linear
    /// between stops at multiples of `1 / n`.
    pub fn sampled(n: usize, colour: impl Fn(f64) -> [u8; 3]) -> Vec<(f64, [u8; 3])> {
        (0..=n).map(|i| i as f64 / n as f64).map(|t| (t, colour(t))).collect()
    }
}

/// The bar as a standalone SVG, 360 units wide (`id` must be unique in the page: it names the
/// gradient).
pub fn colour_bar(b: &ColourBar, id: &str) -> String {
    // Room on both sides for the end labels, centred on the bar's ends.
    let (left, bar_w, bar_top, bar_h) = (24.0, 312.0, 36.0, 16.0);
    let height = bar_top + bar_h + 22.0 + if b.swatches.is_empty() { 0.0 } else { 20.0 };
    let mut s = String::new();
    let _ = write!(
        s,
        r#"<svg class="bar" role="img" aria-labelledby="{id}-t" viewBox="0 0 360 {height}" width="360" height="{height}" {FONT}><title id="{id}-t">Colour scale: {title}, {lo} to {hi} {unit}</title><defs><linearGradient id="{id}">"#,
        title = esc(&b.title),
        lo = b.lo,
        hi = b.hi,
        unit = esc(&b.unit)
    );
    for (t, c) in &b.stops {
        let _ = write!(s, r#"<stop offset="{:.4}" stop-color="{}"/>"#, t, rgb(*c));
    }
    let _ = write!(
        s,
        r##"</linearGradient></defs><text x="{left}" y="13" font-weight="600">{} ({})</text><rect x="{left}" y="{bar_top}" width="{bar_w}" height="{bar_h}" fill="url(#{id})" stroke="#555"/>"##,
        esc(&b.title),
        esc(&b.unit)
    );
    let at = |v: f64| left + (v - b.lo) / (b.hi - b.lo) * bar_w;
    let (mut vals, step) = ticks(b.lo, b.hi, 5);
    // The scale's ends are always labelled (a reader needs to know where the colours stop);
    // a round tick too close to an end to keep its label apart gives way.
    vals.retain(|v| [b.lo, b.hi].iter().all(|e| *v == *e || (v - e).abs() >= step * 0.5));
    for end in [b.lo, b.hi] {
        if !vals.contains(&end) {
            vals.push(end);
        }
    }
    for v in vals {
        let x = at(v);
        // An end that is not a round tick shows one decimal (7.3 camera px, 807.6 mm).
        let end = (v == b.lo || v == b.hi) && v.fract() != 0.0;
        let label = tick_label(v, if end { step.min(0.1) } else { step });
        let _ = write!(
            s,
            r##"<line x1="{x:.1}" y1="{:.1}" x2="{x:.1}" y2="{:.1}" stroke="#333"/><text x="{x:.1}" y="{:.1}" text-anchor="middle">{label}</text>"##,
            bar_top + bar_h,
            bar_top + bar_h + 4.0,
            bar_top + bar_h + 16.0
        );
    }
    for (v, label) in &b.marks {
        let x = at(*v);
        let _ = write!(
            s,
            r##"<path d="M{x:.1} {:.1} l-5 -8 h10 z" fill="#1a1a1a"/><text x="{:.1}" y="{:.1}" text-anchor="{}">{}</text>"##,
            bar_top - 1.0,
            x,
            bar_top - 12.0,
            if x > left + bar_w * 0.6 { "end" } else { "middle" },
            esc(label)
        );
    }
    let mut x = left;
    for (c, label) in &b.swatches {
        let y = bar_top + bar_h + 26.0;
        let _ = write!(
            s,
            r##"<rect x="{x}" y="{y}" width="12" height="12" fill="{}" stroke="#555"/><text x="{:.1}" y="{:.1}">{}</text>"##,
            rgb(*c),
            x + 16.0,
            y + 10.0,
            esc(label)
        );
        x += 24.0 + 6.5 * label.len() as f64;
    }
    s.push_str("</svg>");
    s
}

/// One line of a plot.
#[derive(Clone, Debug)]
pub struct Series {
    pub label: String,
    pub colour: [u8; 3],
    pub dashed: bool,
    pub points: Vec<(f64, f64)>,
}

/// A line plot with axes on `x` and `y` (their `px` fields are ignored: the plot lays out its
/// own area) and a legend.
#[derive(Clone, Debug)]
pub struct Plot {
    pub title: String,
    pub alt: String,
    pub x: Scale,
    pub y: Scale,
    pub series: Vec<Series>,
}

/// The plot as a standalone SVG 380 units wide.
pub fn plot(p: &Plot, id: &str) -> String {
    let (left, top, w, h) = (50.0, 24.0, 310.0, 200.0);
    let legend_h = 16.0 * p.series.len() as f64;
    let total_h = top + h + 40.0 + legend_h;
    let mut s = String::new();
    let _ = write!(
        s,
        r#"<svg class="plot" role="img" aria-labelledby="{id}" viewBox="0 0 380 {total_h}" width="380" height="{total_h}" {FONT}><title id="{id}">{}</title><text x="{left}" y="15" font-weight="600">{}</text>"#,
        esc(&p.alt),
        esc(&p.title)
    );
    let xs = |v: f64| left + (v - p.x.value.0) / (p.x.value.1 - p.x.value.0) * w;
    let ys = |v: f64| top + h - (v - p.y.value.0) / (p.y.value.1 - p.y.value.0) * h;
    let (xt, xstep) = ticks(p.x.value.0, p.x.value.1, 5);
    for v in xt {
        let x = xs(v);
        let _ = write!(
            s,
            r##"<line x1="{x:.1}" y1="{top}" x2="{x:.1}" y2="{:.1}" stroke="#ddd"/><text x="{x:.1}" y="{:.1}" text-anchor="middle">{}</text>"##,
            top + h + 4.0,
            top + h + 16.0,
            tick_label(v, xstep)
        );
    }
    let (yt, ystep) = ticks(p.y.value.0, p.y.value.1, 5);
    for v in yt {
        let y = ys(v);
        let _ = write!(
            s,
            r##"<line x1="{:.1}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="#ddd"/><text x="{:.1}" y="{:.1}" text-anchor="end">{}</text>"##,
            left - 4.0,
            left + w,
            left - 6.0,
            y + 4.0,
            tick_label(v, ystep)
        );
    }
    let _ = write!(
        s,
        r##"<rect x="{left}" y="{top}" width="{w}" height="{h}" fill="none" stroke="#555"/><text x="{:.1}" y="{:.1}" text-anchor="middle">{}</text><text x="12" y="{:.1}" text-anchor="middle" transform="rotate(-90 12 {:.1})">{}</text>"##,
        left + w / 2.0,
        top + h + 32.0,
        esc(&p.x.label),
        top + h / 2.0,
        top + h / 2.0,
        esc(&p.y.label)
    );
    for (i, line) in p.series.iter().enumerate() {
        let pts: String = line.points.iter().map(|&(x, y)| format!("{:.1},{:.1} ", xs(x), ys(y))).collect();
        let dash = if line.dashed { r#" stroke-dasharray="5 3""# } else { "" };
        let ly = top + h + 48.0 + 16.0 * i as f64;
        let _ = write!(
            s,
            r#"<polyline fill="none" stroke="{c}" stroke-width="1.6"{dash} points="{pts}"/><line x1="{left}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="{c}" stroke-width="2"{dash}/><text x="{:.1}" y="{:.1}">{}</text>"#,
            ly - 4.0,
            left + 24.0,
            ly - 4.0,
            left + 30.0,
            ly,
            esc(&line.label),
            c = rgb(line.colour)
        );
    }
    s.push_str("</svg>");
    s
}

/// A small two-dimensional colour key: `colour(u, v)` over a grid, u rightwards along `x`,
/// v downwards along `y` (both 0..=1 mapped onto the scales' values), with axes.
pub fn colour_key(
    title: &str,
    alt: &str,
    x: &Scale,
    y: &Scale,
    id: &str,
    colour: impl Fn(f64, f64) -> Option<[u8; 3]>,
) -> String {
    let (left, top, side, n) = (46.0, 20.0, 120.0, 24usize);
    let cell = side / n as f64;
    let mut s = String::new();
    let _ = write!(
        s,
        r#"<svg class="key" role="img" aria-labelledby="{id}" viewBox="0 0 190 {th}" width="190" height="{th}" {FONT}><title id="{id}">{}</title><text x="4" y="14" font-weight="600">{}</text>"#,
        esc(alt),
        esc(title),
        th = top + side + 40.0
    );
    for j in 0..n {
        for i in 0..n {
            let (u, v) = ((i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64);
            if let Some(c) = colour(u, v) {
                let _ = write!(
                    s,
                    r#"<rect x="{:.2}" y="{:.2}" width="{:.2}" height="{:.2}" fill="{}"/>"#,
                    left + i as f64 * cell,
                    top + j as f64 * cell,
                    cell + 0.3,
                    cell + 0.3,
                    rgb(c)
                );
            }
        }
    }
    let panel = Panel {
        src: [0, 0, side as u32, side as u32],
        width: side,
        title: String::new(),
        alt: String::new(),
        x: Some(Scale { px: (0.0, side), ..x.clone() }),
        y: Some(Scale { px: (0.0, side), ..y.clone() }),
    };
    s.push_str(&panel_axes(&panel, left, top, 1.0));
    s.push_str("</svg>");
    s
}

/// The frame, ticks and labels of a panel's axes drawn at (`left`, `top`), `k` units per source
/// pixel.
fn panel_axes(p: &Panel, left: f64, top: f64, k: f64) -> String {
    let [_, _, sw, sh] = p.src;
    let (w, h) = (sw as f64 * k, sh as f64 * k);
    let mut s =
        format!(r##"<rect x="{left}" y="{top}" width="{w:.1}" height="{h:.1}" fill="none" stroke="#555"/>"##);
    if let Some(x) = &p.x {
        let (vals, step) = x.ticks();
        for v in vals {
            let px = left + x.at(v) * k;
            let _ = write!(
                s,
                r##"<line x1="{px:.1}" y1="{:.1}" x2="{px:.1}" y2="{:.1}" stroke="#333"/><text x="{px:.1}" y="{:.1}" text-anchor="middle">{}</text>"##,
                top + h,
                top + h + 4.0,
                top + h + 16.0,
                tick_label(v, step)
            );
        }
        let _ = write!(
            s,
            r#"<text x="{:.1}" y="{:.1}" text-anchor="middle">{}</text>"#,
            left + w / 2.0,
            top + h + 32.0,
            esc(&x.label)
        );
    }
    if let Some(y) = &p.y {
        let (vals, step) = y.ticks();
        for v in vals {
            let py = top + y.at(v) * k;
            let _ = write!(
                s,
                r##"<line x1="{:.1}" y1="{py:.1}" x2="{left}" y2="{py:.1}" stroke="#333"/><text x="{:.1}" y="{:.1}" text-anchor="end">{}</text>"##,
                left - 4.0,
                left - 6.0,
                py + 4.0,
                tick_label(v, step)
            );
        }
        let (cx, cy) = (12.0, top + h / 2.0);
        let _ = write!(
            s,
            r#"<text x="{cx}" y="{cy:.1}" text-anchor="middle" transform="rotate(-90 {cx} {cy:.1})">{}</text>"#,
            esc(&y.label)
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_and_links_are_escaped() {
        assert_eq!(esc(r#"<script>a&b"c'</script>"#), "&lt;script&gt;a&amp;b&quot;c&#39;&lt;/script&gt;");
        assert_eq!(href("comp/a b/<x>#1?.png"), "comp/a%20b/%3Cx%3E%231%3F.png");
        assert_eq!(href("stage/report.png"), "stage/report.png");
    }

    #[test]
    fn ticks_are_round_and_inside_the_range() {
        assert_eq!(ticks(0.0, 150.0, 5), (vec![0.0, 50.0, 100.0, 150.0], 50.0));
        // Camera pixels: edges at -0.5 and 799.5, ticks at pixel centres.
        assert_eq!(ticks(-0.5, 799.5, 5).0, vec![0.0, 200.0, 400.0, 600.0]);
        let (t, step) = ticks(0.0, 1.0, 5);
        assert_eq!(t.len(), 6);
        assert_eq!(tick_label(t[3], step), "0.6");
        assert_eq!(tick_label(-0.0, 1.0), "0");
        assert_eq!(ticks(3.0, 3.0, 5).0, vec![3.0]);
    }

    #[test]
    fn a_panel_has_its_alt_text_picture_and_axis_labels() {
        let p = Panel {
            src: [0, 0, 400, 300],
            width: 200.0,
            title: "Photo <1>".into(),
            alt: "The \"photo\"".into(),
            x: Some(Scale::pixels("camera x (px)", 800, 400)),
            y: Some(Scale::pixels("camera y (px)", 600, 300)),
        };
        let s = panel("a%20b.png", (800, 300), &p, "f1");
        assert!(s.contains(r#"role="img" aria-labelledby="f1""#), "{s}");
        assert!(s.contains(r#"<title id="f1">The &quot;photo&quot;</title>"#), "{s}");
        assert!(s.contains(r#"<image href="a%20b.png" width="800" height="300"/>"#), "{s}");
        assert!(s.contains("Photo &lt;1&gt;") && s.contains("camera x (px)") && s.contains("camera y (px)"));
        // Ticks 0..600 along x (camera px), the last at (600.5 / 800) of 200 units from the left.
        assert!(s.contains(">600</text>") && !s.contains(">800</text>"), "{s}");
        let x600 = 46.0 + 600.5 / 800.0 * 200.0;
        assert!(s.contains(&format!(r#"x1="{x600:.1}""#)), "{s}");
    }

    #[test]
    fn a_colour_bar_labels_both_ends_its_marks_and_swatches() {
        let b = ColourBar {
            title: "Footprint".into(),
            stops: ColourBar::sampled(2, |t| [(t * 255.0) as u8, 0, 0]),
            lo: 0.0,
            hi: 7.3,
            unit: "camera px".into(),
            marks: vec![(3.65, "median".into())],
            swatches: vec![([0, 0, 0], "not measured".into())],
        };
        let s = colour_bar(&b, "bar-1");
        assert!(s.contains(r#"<linearGradient id="bar-1">"#) && s.contains(r##"fill="url(#bar-1)""##));
        assert_eq!(s.matches("<stop ").count(), 3);
        assert!(s.contains(r#"<stop offset="0.5000" stop-color="rgb(127,0,0)"/>"#), "{s}");
        assert!(s.contains(">0</text>") && s.contains(">7.3</text>") && s.contains(">median</text>"), "{s}");
        assert!(s.contains("not measured") && s.contains("Footprint (camera px)"));
    }
}
