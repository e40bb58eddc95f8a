//! The demo's `index.html` from what the chain wrote ([`Inputs`], gathered by the parent
//! module): pure, so its captions, colour bars and escaping are tested without files. Every
//! figure shown comes from `Inputs`; a file that is missing is said to be missing. The
//! calibration and compensation sections are in their own files.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use restage_authoring::calibrate::geometry::GeometryReport;
use restage_authoring::calibrate::photometric::PhotometricSummary;
use restage_authoring::compensate::io::Summary;
use restage_authoring::contact_sheet::{GAP, tile_origin};
use restage_authoring::restore::BEFORE_AFTER_GAP;
use restage_shared::policy::ExposurePolicy;

use super::svg::{self, Panel, Scale, esc, href};

/// Everything the page shows, read from the demo's folder. Paths are relative to it, with `/`.
#[derive(Clone, Debug, Default)]
pub struct Inputs {
    /// The object's name (`bundle.toml`).
    pub object: Option<String>,
    /// Where the capture came from (`capture/capture.json`).
    pub capture_source: Option<String>,
    /// Camera image size, pixels.
    pub camera: Option<(u32, u32)>,
    /// Size in pixels of each picture that exists.
    pub pictures: BTreeMap<String, (u32, u32)>,
    /// The capture contact sheet's tiles per projector row (pattern names, left to right).
    pub sheet_columns: Vec<Vec<String>>,
    pub geometry: Option<GeometryReport>,
    pub photometric: Option<PhotometricSummary>,
    /// Per projector, from the calibrated stage model (`stage/stage.bin`).
    pub projectors: Vec<Projector>,
    /// Nearest and farthest surface point, mm (the depth map's range).
    pub depth_mm: Option<(f32, f32)>,
    pub scenes: Vec<Scene>,
    pub bundle: Option<Bundle>,
    /// `summary.txt`, as written.
    pub summary_txt: Option<String>,
    /// The folder's top-level entries and their sizes.
    pub files: Vec<Entry>,
}

/// One projector of the calibrated stage model.
#[derive(Clone, Debug, Default)]
pub struct Projector {
    pub width: u32,
    pub height: u32,
    pub black: [f32; 3],
    /// Relative output per 8-bit input, red, green, blue.
    pub response: [Vec<f32>; 3],
    /// The footprint map's full scale ([`footprint_scale`] of the stage model's transport).
    ///
    /// [`footprint_scale`]: restage_authoring::calibrate::photometric::footprint_scale
    pub footprint_scale: Option<f32>,
}

/// One compensated scene (`comp/<id>/`).
#[derive(Clone, Debug)]
pub struct Scene {
    pub id: String,
    /// The name visitors see (`bundle.toml`), else the id.
    pub name: String,
    /// `comp/<id>`.
    pub dir: String,
    pub summary: Summary,
    /// The frames (`comp/<id>/proj<k>.png`) that exist.
    pub frames: Vec<String>,
    /// `comp/<id>/report` when compensation wrote its report there.
    pub report: Option<String>,
    /// The line of `summary.txt` on this scene (the demo's check with the true physics).
    pub check_line: Option<String>,
}

/// The signed bundle and what it was made from.
#[derive(Clone, Debug, Default)]
pub struct Bundle {
    pub file: String,
    pub bytes: u64,
    pub description: String,
    pub trust: String,
    pub keys: String,
    /// The exposure policy's CIE 157 class as written in `bundle.toml` (None: the default).
    pub policy_class: Option<String>,
    /// The policy the bundle carries (`export::policy_from` the description).
    pub policy: Option<ExposurePolicy>,
    /// The line of `summary.txt` on the verification.
    pub verify_line: Option<String>,
}

/// A top-level file or folder and its size in bytes (folders: everything inside).
#[derive(Clone, Debug)]
pub struct Entry {
    pub name: String,
    pub bytes: u64,
    pub dir: bool,
}

/// The page's style: system fonts, dark text on white (contrast above 7:1), figures that wrap
/// on a phone, no colour behind text in print.
const STYLE: &str = r#"
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;color:#1a1a1a;background:#fff;line-height:1.45;margin:0 auto;padding:0 1rem 3rem;max-width:78rem}
h1{font-size:1.7rem;margin:1.2rem 0 .4rem}h2{font-size:1.35rem;margin-top:2.2rem;border-bottom:2px solid #1a1a1a}h3{font-size:1.1rem;margin-top:1.6rem}
a{color:#0b4ea2}a:visited{color:#5a2d91}
code,pre{font-family:ui-monospace,Menlo,Consolas,monospace;font-size:.92em}
pre{white-space:pre-wrap;overflow-wrap:anywhere;background:#f4f4f4;border:1px solid #ccc;padding:.6rem}
figure{margin:1rem 0;break-inside:avoid}
.panels{display:flex;flex-wrap:wrap;gap:.5rem 1rem;align-items:flex-start}
.panels svg{max-width:100%;height:auto}
figcaption{max-width:60rem;margin-top:.3rem}
.tbl{overflow-x:auto}table{border-collapse:collapse;margin:.5rem 0}
th,td{border:1px solid #bbb;padding:.2rem .5rem;text-align:left;vertical-align:top}td.n{text-align:right;font-variant-numeric:tabular-nums}
th{background:#eee}
.cert{border:2px solid #1e6b35;padding:.2rem 1rem;margin:1rem 0;max-width:60rem}
.cert.over{border-color:#a0001c}
.ok{color:#1e6b35;font-weight:600}.bad{color:#a0001c;font-weight:600}
.missing{color:#6b4a00}
nav ol{columns:2 16rem}
@media print{body{max-width:none;padding:0}a{color:#1a1a1a}nav{display:none}h2{break-after:avoid}pre{background:none}}
"#;

/// The page.
pub fn render(inp: &Inputs) -> String {
    let mut p = Page { html: String::new(), next_id: 0, inp };
    p.head();
    p.glance();
    p.capture();
    p.calibrate();
    p.classify_restore_relight();
    p.compensate();
    p.bundle();
    p.next_steps();
    p.files();
    p.log();
    p.html.push_str("</main>\n</body>\n</html>\n");
    p.html
}

/// The one phrase that says a picture was not written (tests look for it).
pub const MISSING: &str = "was not written";

/// The page being written: its HTML so far, a counter for unique element ids, the inputs.
/// Sections are methods, in this file and in `calibration` and `compensation`.
pub(super) struct Page<'a> {
    pub(super) html: String,
    pub(super) next_id: usize,
    pub(super) inp: &'a Inputs,
}

/// One piece of a figure: a panel of a picture, or a ready SVG (a colour bar, a key).
pub(super) enum Part {
    Picture(String, Panel),
    Svg(String),
}

/// A link showing the path itself, as code.
pub(super) fn file(rel: &str) -> String {
    format!(r#"<a href="{}"><code>{}</code></a>"#, href(rel), esc(rel))
}

pub(super) fn num(v: f64, decimals: usize) -> String {
    if v.is_finite() { format!("{v:.decimals$}") } else { "not determined".into() }
}

pub(super) fn pct(v: f64) -> String {
    num(100.0 * v, 2) + " %"
}

/// A duration for people: minutes under two hours, else hours.
fn hours(h: f64) -> String {
    if h < 2.0 { format!("{} minutes", num(60.0 * h, 0)) } else { format!("{} hours", num(h, 0)) }
}

fn size(bytes: u64) -> String {
    let b = bytes as f64;
    if b >= 1e9 {
        format!("{:.2} GB", b / 1e9)
    } else if b >= 1e6 {
        format!("{:.1} MB", b / 1e6)
    } else if b >= 1e3 {
        format!("{:.1} kB", b / 1e3)
    } else {
        format!("{bytes} B")
    }
}

/// Camera pixel axes for a panel `len` picture pixels wide showing the whole camera image.
pub(super) fn camera_axes(cam: (u32, u32), w: u32, h: u32) -> (Option<Scale>, Option<Scale>) {
    (Some(Scale::pixels("camera x (px)", cam.0, w)), Some(Scale::pixels("camera y (px)", cam.1, h)))
}

impl Page<'_> {
    pub(super) fn id(&mut self, what: &str) -> String {
        self.next_id += 1;
        format!("{what}-{}", self.next_id)
    }

    pub(super) fn push(&mut self, s: &str) {
        self.html.push_str(s);
    }

    /// A figure of panels cut from the picture `rel` (or a note that it is missing), extra
    /// SVGs (colour bars, keys) after them, and a caption (HTML, already escaped).
    pub(super) fn figure(&mut self, rel: &str, panels: &[Panel], extra: &[String], caption: &str) {
        if !self.inp.pictures.contains_key(rel) {
            let _ = write!(self.html, r#"<p class="missing"><code>{}</code> {MISSING}.</p>"#, esc(rel));
            return;
        }
        let mut parts: Vec<Part> = panels.iter().map(|p| Part::Picture(rel.to_string(), p.clone())).collect();
        parts.extend(extra.iter().cloned().map(Part::Svg));
        self.figure_of(&parts, caption);
    }

    /// A figure of several pictures' panels and SVGs in order, then the caption and a link to
    /// each picture. Pictures that do not exist are left out.
    pub(super) fn figure_of(&mut self, parts: &[Part], caption: &str) {
        self.push("<figure><div class=\"panels\">");
        let mut files: Vec<&str> = Vec::new();
        for part in parts {
            match part {
                Part::Picture(rel, panel) => {
                    let Some(&size) = self.inp.pictures.get(rel) else { continue };
                    let id = self.id("fig");
                    let s = svg::panel(&href(rel), size, panel, &id);
                    self.push(&s);
                    if !files.contains(&rel.as_str()) {
                        files.push(rel);
                    }
                }
                Part::Svg(s) => self.push(s),
            }
        }
        let links: Vec<String> = files.iter().map(|r| file(r)).collect();
        let _ = writeln!(
            self.html,
            "</div><figcaption>{caption} {}: {}.</figcaption></figure>",
            if links.len() == 1 { "File" } else { "Files" },
            links.join(", ")
        );
    }

    /// The whole picture as one panel, `width` wide, with camera pixel axes.
    pub(super) fn camera_picture(
        &mut self,
        rel: &str,
        title: &str,
        alt: &str,
        width: f64,
        extra: &[String],
        caption: &str,
    ) {
        let Some(&(w, h)) = self.inp.pictures.get(rel) else {
            self.figure(rel, &[], &[], "");
            return;
        };
        let cam = self.inp.camera.unwrap_or((w, h));
        let (x, y) = camera_axes(cam, w, h);
        let panel = Panel { src: [0, 0, w, h], width, title: title.into(), alt: alt.into(), x, y };
        self.figure(rel, &[panel], extra, caption);
    }

    fn head(&mut self) {
        let title = match &self.inp.object {
            Some(o) => format!("restage demo: {}", esc(o)),
            None => "restage demo".to_string(),
        };
        let _ = write!(
            self.html,
            r#"<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<style>{STYLE}</style>
</head>
<body>
<header>
<h1>{title}</h1>
<p>This folder holds what <code>restage-author demo</code> made: the whole authoring chain run
on the <em>virtual stage</em>, a simulated museum stage (a painted object, a camera and
projectors) that stands in for real hardware. Each section below shows one step's pictures and
figures, read from the files the step wrote; every file named is linked. Pictures of the
object are in camera pixel coordinates (x to the right, y down, 0 at the centre of the top-left
pixel); projector frames in projector pixel coordinates.</p>
"#
        );
        if let Some(src) = &self.inp.capture_source {
            let _ = writeln!(self.html, "<p>Capture: {}.</p>", esc(src));
        }
        self.push(
            r##"<nav aria-label="Contents"><ol>
<li><a href="#glance">At a glance</a></li>
<li><a href="#capture">Capture</a></li>
<li><a href="#calibrate">Calibration</a></li>
<li><a href="#restore">Classification, restoration, relighting</a></li>
<li><a href="#compensate">Compensation and the light certificate</a></li>
<li><a href="#bundle">Bundle and verification</a></li>
<li><a href="#next">What to do next</a></li>
<li><a href="#files">Files and disk use</a></li>
<li><a href="#log">The demo's log</a></li>
</ol></nav>
</header>
<main>
"##,
        );
    }

    fn glance(&mut self) {
        self.push("<section id=\"glance\"><h2>At a glance</h2>\n");
        let rel = "before_restored_target.png";
        if let Some(&(w, h)) = self.inp.pictures.get(rel) {
            let titles = [
                ("Photo (before)", "The object as photographed under even room light, deteriorated"),
                ("Restored target", "The restored image that compensation aims for"),
                ("Visitor view, restored", "What a visitor sees with the restored scene projected"),
                ("Visitor view, relit", "What a visitor sees with the relit variant projected"),
            ];
            // One row of equal tiles with a gap around each (contact_sheet::grid).
            let tw = (w.saturating_sub(GAP) / titles.len() as u32).saturating_sub(GAP);
            let th = h.saturating_sub(2 * GAP);
            let cam = self.inp.camera.unwrap_or((tw, th));
            let panels: Vec<Panel> = titles
                .iter()
                .enumerate()
                .map(|(i, (title, alt))| {
                    let (x0, y0) = tile_origin((tw, th), 0, i as u32);
                    let (x, y) = camera_axes(cam, tw, th);
                    // 230 units: the four fit one row of a desktop window.
                    Panel {
                        src: [x0, y0, tw, th],
                        width: 230.0,
                        title: title.to_string(),
                        alt: alt.to_string(),
                        x,
                        y,
                    }
                })
                .collect();
            self.figure(
                rel,
                &panels,
                &[],
                "Left to right: the photo of the object as found; the restored image the \
                 projectors aim to make the object look like; what a visitor sees when the \
                 restored scene is projected; the same for the relit variant. The visitor views \
                 are rendered with the virtual stage's <em>true</em> physics (not the model \
                 compensation used), with brightness divided by each compensation's global \
                 scale so they compare with the target: the real object looks dimmer, by that \
                 scale, under light kept below the bound.",
            );
        } else {
            self.figure(rel, &[], &[], "");
        }
        if !self.inp.scenes.is_empty() {
            self.push(
                "<p>Each scene's light certificate (details under <a href=\"#compensate\">Compensation</a>):</p>\
                 <div class=\"tbl\"><table><thead><tr><th scope=\"col\">scene</th><th scope=\"col\">peak found (lx)</th>\
                 <th scope=\"col\">allowed (lx)</th><th scope=\"col\">E_bound (lx)</th><th scope=\"col\">result</th></tr></thead><tbody>",
            );
            for s in &self.inp.scenes {
                let st = &s.summary.stats;
                let limit = limit_lux(&s.summary);
                let _ = write!(
                    self.html,
                    r##"<tr><td><a href="#scene-{}">{}</a></td><td class="n">{}</td><td class="n">{}</td><td class="n">{}</td><td>{}</td></tr>"##,
                    href(&s.id),
                    esc(&s.name),
                    num(st.peak_lux, 1),
                    num(limit, 1),
                    num(s.summary.e_bound_lux, 1),
                    verdict(st.peak_lux, limit)
                );
            }
            self.push("</tbody></table></div>\n");
        }
        self.push("</section>\n");
    }

    fn capture(&mut self) {
        self.push(
            "<section id=\"capture\"><h2>1. Capture</h2>\n<p>The virtual stage photographs the object \
             under even room light, then records what the camera sees while each projector in turn \
             shows structured-light patterns (Gray codes, phase shifts, dot grids, colour ramps). \
             On a real stage <code>restage-author capture</code> does this with the camera and \
             projectors. The images are 16-bit PNGs in linear light (value 0 to 65535 = 0 to 1 of \
             the camera's full scale), marked as such (gAMA 1.0) so viewers show them correctly; \
             they are most of this folder's size.</p>\n",
        );
        let rel = "capture_contact_sheet.png";
        let columns = self.inp.sheet_columns.clone();
        match (self.inp.pictures.get(rel).copied(), columns.iter().map(Vec::len).max()) {
            (Some((w, h)), Some(cols)) if cols > 0 => {
                let rows = columns.len() as u32 + 1;
                let tw = (w.saturating_sub(GAP) / cols as u32).saturating_sub(GAP);
                let th = (h.saturating_sub(GAP) / rows).saturating_sub(GAP);
                let cam = self.inp.camera.unwrap_or((tw, th));
                let (x, y) = camera_axes(cam, tw, th);
                let mut panels = vec![Panel {
                    src: [GAP, GAP, tw, th],
                    width: 320.0,
                    title: "Photo".into(),
                    alt: "The photo of the object under even room light".into(),
                    x,
                    y,
                }];
                for (k, row) in columns.iter().enumerate() {
                    for (c, name) in row.iter().enumerate() {
                        let (x0, y0) = tile_origin((tw, th), k as u32 + 1, c as u32);
                        panels.push(Panel {
                            src: [x0, y0, tw, th],
                            width: 132.0,
                            title: format!("P{k} {name}"),
                            alt: format!("Camera image while projector {k} shows {name}"),
                            x: None,
                            y: None,
                        });
                    }
                }
                self.figure(
                    rel,
                    &panels,
                    &[],
                    "The capture set at a glance, brightened for viewing. First the photo (axes: \
                     camera pixels); then, for each projector P0, P1, …, the whole camera image while \
                     that projector shows the named pattern: full white and black, a coarse and a fine \
                     Gray-code bit in x and y, the first phase image in x and y, the first dot grid, \
                     and mid-level red, green and blue. A projector's light falls only where it \
                     reaches the object.",
                );
            }
            _ => self.figure(rel, &[], &[], ""),
        }
        let _ = writeln!(
            self.html,
            "<p>Files: {} (the photo), {} (what was captured, and how), {} (the virtual stage's truth, \
             which only the demo's stand-ins and the evaluation read; a real capture has none).</p>\n</section>",
            file("capture/photo.png"),
            file("capture/capture.json"),
            file("capture/ground-truth/")
        );
    }

    fn classify_restore_relight(&mut self) {
        self.push(
            "<section id=\"restore\"><h2>3–5. Classification, restoration, relighting</h2>\n<p>The \
             photo's pixels are sorted into the paint colours a conservator picks (here the picks \
             are stand-ins drawn from the virtual stage's truth, in ",
        );
        let _ = writeln!(
            self.html,
            "{}); the boundaries between colours are then restored (chips and cracks that expose \
             bare clay filled, contours smoothed), and a relit variant adds virtual lighting and \
             some of the photo's material texture. Palette and labels: {}, {}.</p>",
            file("classify/picks.json"),
            file("classify/palette.json"),
            file("classify/labels.png")
        );
        self.camera_picture(
            "classify/preview.png",
            "Classification",
            "Each object pixel painted in the colour of its class",
            420.0,
            &[],
            "Each pixel of the object in the display colour of the paint class it was sorted \
             into: deterioration (chips, cracks, stains) shows as the wrong class or bare clay.",
        );
        if let Some(&(w, h)) = self.inp.pictures.get("restore/before_after.png") {
            // Two camera images side by side, a gap apart (restore::before_after).
            let half = w.saturating_sub(BEFORE_AFTER_GAP) / 2;
            let cam = self.inp.camera.unwrap_or((half, h));
            let panels: Vec<Panel> = [
                ("Before", "The classified labels, their contours in magenta"),
                ("After", "The restored labels, contours before in magenta and after in cyan"),
            ]
            .iter()
            .enumerate()
            .map(|(i, (t, a))| {
                let (x, y) = camera_axes(cam, half, h);
                let x0 = i as u32 * (half + BEFORE_AFTER_GAP);
                Panel { src: [x0, 0, half, h], width: 400.0, title: t.to_string(), alt: a.to_string(), x, y }
            })
            .collect();
            self.figure(
                "restore/before_after.png",
                &panels,
                &[],
                "The label map before and after restoration, each class in its display colour. \
                 Magenta: the contours between colours before restoration (on both sides); cyan: \
                 the contours after, so what restoration moved stands out.",
            );
        } else {
            self.figure("restore/before_after.png", &[], &[], "");
        }
        self.camera_picture(
            "restore/restored.png",
            "Restored",
            "The restored image: each class in its restored display colour",
            420.0,
            &[],
            "The restored image: each restored class in its display colour. This is the target \
             of the \"Restored\" scene.",
        );
        self.camera_picture(
            "relit.png",
            "Relit",
            "The restored image under a virtual key light with some of the photo's texture",
            420.0,
            &[],
            "The relit variant: the restored image under a soft virtual key light, with 30 % of \
             the photo's material noise, the target of the \"Restored, relit\" scene.",
        );
        self.push("</section>\n");
    }

    fn bundle(&mut self) {
        self.push("<section id=\"bundle\"><h2>7–8. Bundle and verification</h2>\n");
        let Some(b) = self.inp.bundle.clone() else {
            let _ = write!(self.html, r#"<p class="missing">The bundle {MISSING}.</p></section>"#);
            return;
        };
        let _ = writeln!(
            self.html,
            "<p>The scenes' frames, their light certificate, the light model and the exposure policy \
             are signed into one file, {} ({}), described by {}. The appliance plays only a bundle \
             whose signature it trusts and whose every scene passes the light check.</p>",
            file(&b.file),
            size(b.bytes),
            file(&b.description)
        );
        match &b.policy {
            Some(p) => {
                let class = b.policy_class.as_deref().map_or("high (the default)".to_string(), esc);
                let _ = write!(
                    self.html,
                    "<p>Exposure policy (CIE 157 class {class}): showings of at most {} s with {} s \
                     dark between them, {} lx·h a day and {} lx·h a year.",
                    p.max_showing_s,
                    p.cooldown_s,
                    num(p.daily_budget_lxh, 1),
                    num(p.annual_budget_lxh, 0)
                );
                // The appliance charges each lit second at the scene's certified peak.
                let peak = self.inp.scenes.iter().map(|s| s.summary.stats.peak_lux).fold(0.0, f64::max);
                if peak > 0.0 {
                    let _ = write!(
                        self.html,
                        " The appliance charges every lit second at the scene's peak: at {} lx that \
                         is about {} of showing a day and {} a year.",
                        num(peak, 1),
                        hours(p.daily_budget_lxh / peak),
                        hours(p.annual_budget_lxh / peak)
                    );
                }
                self.push("</p>\n");
            }
            None => self.push("<p>Exposure policy: see <code>bundle.toml</code>.</p>\n"),
        }
        let _ = writeln!(
            self.html,
            "<p>It is signed with a <strong>demo key</strong> made from the seed ({}): anyone can \
             make the same key, so never trust it for a real object; make your own with \
             <code>restage-author keygen</code>. The public key is in {}, the folder the appliance \
             (and <code>verify</code>) trusts.</p>",
            file(&b.keys),
            file(&b.trust)
        );
        if let Some(line) = &b.verify_line {
            let _ = writeln!(
                self.html,
                "<p>Verification, as the appliance does it (from <code>summary.txt</code>):</p><pre>{}</pre>",
                esc(line)
            );
        }
        self.push("</section>\n");
    }

    fn next_steps(&mut self) {
        let bundle = self.inp.bundle.as_ref().map_or("demo.restage".to_string(), |b| b.file.clone());
        let trust = self
            .inp
            .bundle
            .as_ref()
            .map_or("trust".to_string(), |b| b.trust.trim_end_matches('/').to_string());
        let _ = writeln!(
            self.html,
            "<section id=\"next\"><h2>What to do next</h2><ol>\
             <li>Edit the colour picks, regions and parameters in the interactive tool; it opens this \
             folder as a project and re-runs only what an edit changes:<pre>restage-author gui &lt;this folder&gt;</pre></li>\
             <li>Check the bundle exactly as the appliance will (signature, hashes, every scene's \
             light check):<pre>restage-author verify &lt;this folder&gt;/{} --trust &lt;this folder&gt;/{}</pre></li>\
             <li>Copy the bundle to the stage appliance (its configured <code>bundle</code> path, or \
             <code>restage-appliance install</code>) with the public key in its trust directory. For \
             a real object: capture, calibrate with a lux meter, and sign with your own key.</li>\
             </ol><p>Here <code>&lt;this folder&gt;</code> is the folder holding this page (for the \
             demo's default, <code>out/demo</code>).</p></section>",
            esc(&bundle),
            esc(&trust)
        );
    }

    fn files(&mut self) {
        self.push(
            "<section id=\"files\"><h2>Files and disk use</h2><div class=\"tbl\"><table><thead><tr>\
             <th scope=\"col\">file or folder</th><th scope=\"col\">size</th><th scope=\"col\">what</th></tr></thead><tbody>",
        );
        let total: u64 = self.inp.files.iter().map(|e| e.bytes).sum();
        for e in &self.inp.files {
            let rel = if e.dir { format!("{}/", e.name) } else { e.name.clone() };
            let _ = write!(
                self.html,
                r#"<tr><td>{}</td><td class="n">{}</td><td>{}</td></tr>"#,
                file(&rel),
                size(e.bytes),
                what_is(&e.name)
            );
        }
        let _ = write!(
            self.html,
            r#"<tr><th scope="row">total</th><td class="n">{}</td><td></td></tr></tbody></table></div></section>"#,
            size(total)
        );
        self.push("\n");
    }

    fn log(&mut self) {
        self.push("<section id=\"log\"><h2>The demo's log</h2>");
        match &self.inp.summary_txt {
            Some(t) => {
                let _ = write!(
                    self.html,
                    "<p>Each step's one-line summary with its time since the start, as written to {}:</p><pre>{}</pre>",
                    file("summary.txt"),
                    esc(t)
                );
            }
            None => {
                let _ = write!(self.html, r#"<p class="missing"><code>summary.txt</code> {MISSING}.</p>"#);
            }
        }
        self.push("</section>\n");
    }
}

/// E_bound less the margin: what the certificate must stay under, as compensation computed it
/// (so the verdict here is the one compensation reached).
pub fn limit_lux(s: &Summary) -> f64 {
    s.stats.limit_lux
}

pub(super) fn verdict(peak: f64, limit: f64) -> &'static str {
    if peak <= limit {
        r#"<span class="ok">within the allowed level</span>"#
    } else {
        r#"<span class="bad">ABOVE the allowed level: these frames must not be shown</span>"#
    }
}

/// What a top-level entry of the demo's folder is.
fn what_is(name: &str) -> &'static str {
    match name {
        "capture" => "the capture set: 16-bit camera images of every pattern, and the virtual stage's truth",
        "capture_contact_sheet.png" => "the capture at a glance",
        "stage" => "the calibrated stage model and its reports",
        "classify" => "colour picks, palette and label map",
        "restore" => "the restored labels and image",
        "relit.png" => "the relit variant",
        "comp" => "each scene's frames, figures and light certificate",
        "keys" => "the demo's signing key (never for real use)",
        "trust" => "the public key the appliance trusts",
        "bundle.toml" => "the bundle's description",
        "demo.restage" => "the signed bundle for the appliance",
        "before_restored_target.png" => "photo, target and visitor views side by side",
        "summary.txt" => "the demo's log",
        "index.html" => "this page",
        _ => "",
    }
}

#[cfg(test)]
#[path = "page_tests.rs"]
mod tests;
