//! Colour picks: the conservator names each paint colour and clicks example pixels of it.
//!
//! Two equivalent inputs, both written by the interactive tool too:
//! - `picks.json` ([`Picks`], version 1): per colour a name, optional restored display
//!   colour, example pixels and/or rectangles, optionally a stroke colour that selects that
//!   colour's pixels from a strokes PNG named in the same file.
//! - a strokes PNG (the photo's size): pixels painted in one stroke colour per class; black
//!   or transparent pixels are not picks. Read alone, each stroke colour becomes one class
//!   named `#rrggbb`, in order of first appearance (raster order).
//!
//! Pixel coordinates are integer column `x` and row `y` (ARCHITECTURE.md's pixel centres).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::ClassifyError;

/// Current version of the picks format.
pub const PICKS_VERSION: u32 = 1;

/// An axis-aligned rectangle of picked pixels: columns `x..x+width`, rows `y..y+height`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PickRect {
    pub x: i64,
    pub y: i64,
    pub width: u32,
    pub height: u32,
}

/// One named paint colour and the pixels that show it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PickColour {
    pub name: String,
    /// The colour the restoration should show (8-bit sRGB), if the conservator chose one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub display_srgb8: Option<[u8; 3]>,
    /// Example pixels `[x, y]`.
    #[serde(default)]
    pub pixels: Vec<[i64; 2]>,
    /// Example rectangles.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub rects: Vec<PickRect>,
    /// The stroke colour standing for this class in the strokes PNG, if one is used.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stroke_srgb8: Option<[u8; 3]>,
}

/// `picks.json`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Picks {
    pub version: u32,
    pub colours: Vec<PickColour>,
    /// A strokes PNG, relative to the JSON file, whose strokes add pixels to the colours
    /// with a matching `stroke_srgb8`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub strokes: Option<PathBuf>,
}

impl Picks {
    /// Reads picks from a `.json` file (and the strokes PNG it names) or from a strokes PNG.
    pub fn load(path: &Path) -> Result<Self, ClassifyError> {
        let is_png = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("png"));
        if is_png { Self::load_strokes(path) } else { Self::load_json(path) }
    }

    fn load_json(path: &Path) -> Result<Self, ClassifyError> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| ClassifyError::Read { path: path.into(), source })?;
        let mut picks: Picks = serde_json::from_str(&text)
            .map_err(|source| ClassifyError::Json { path: path.into(), source })?;
        if picks.version != PICKS_VERSION {
            return Err(ClassifyError::PicksVersion {
                path: path.into(),
                got: picks.version,
                expected: PICKS_VERSION,
            });
        }
        if let Some(rel) = picks.strokes.take() {
            let png = path.parent().unwrap_or(Path::new(".")).join(rel);
            let strokes = read_strokes(&png)?;
            for (rgb, pixels) in strokes {
                let Some(colour) = picks.colours.iter_mut().find(|c| c.stroke_srgb8 == Some(rgb)) else {
                    return Err(ClassifyError::UnknownStroke { path: png, rgb: hex(rgb) });
                };
                colour.pixels.extend(pixels);
            }
        }
        Ok(picks)
    }

    /// Reads a strokes PNG alone: one class per stroke colour, named by its hex value.
    pub fn load_strokes(path: &Path) -> Result<Self, ClassifyError> {
        let colours = read_strokes(path)?
            .into_iter()
            .map(|(rgb, pixels)| PickColour {
                name: hex(rgb),
                display_srgb8: None,
                pixels,
                rects: Vec::new(),
                stroke_srgb8: Some(rgb),
            })
            .collect();
        Ok(Self { version: PICKS_VERSION, colours, strokes: None })
    }

    pub fn save(&self, path: &Path) -> Result<(), ClassifyError> {
        let text = serde_json::to_string_pretty(self).expect("picks always serialise");
        std::fs::write(path, text + "\n").map_err(|source| ClassifyError::Write { path: path.into(), source })
    }

    /// Every colour's picked pixels (points and rectangles) as pixel indices `y * width + x`,
    /// checking that each colour has at least one, that all lie inside the image and that
    /// names are unique.
    pub fn pixel_indices(&self, width: u32, height: u32) -> Result<Vec<Vec<usize>>, ClassifyError> {
        let mut out = Vec::with_capacity(self.colours.len());
        for (i, c) in self.colours.iter().enumerate() {
            if self.colours[..i].iter().any(|o| o.name == c.name) {
                return Err(ClassifyError::DuplicateName { name: c.name.clone() });
            }
            let outside =
                |x: i64, y: i64| ClassifyError::PickOutside { name: c.name.clone(), x, y, width, height };
            let inside = |x: i64, y: i64| x >= 0 && y >= 0 && x < width as i64 && y < height as i64;
            let mut idx = Vec::new();
            for &[x, y] in &c.pixels {
                if !inside(x, y) {
                    return Err(outside(x, y));
                }
                idx.push(y as usize * width as usize + x as usize);
            }
            for r in &c.rects {
                if r.width == 0 || r.height == 0 {
                    continue;
                }
                let (x1, y1) = (r.x + r.width as i64 - 1, r.y + r.height as i64 - 1);
                for (px, py) in [(r.x, r.y), (x1, y1)] {
                    if !inside(px, py) {
                        return Err(outside(px, py));
                    }
                }
                for y in r.y..=y1 {
                    idx.extend((r.x..=x1).map(|x| y as usize * width as usize + x as usize));
                }
            }
            if idx.is_empty() {
                return Err(ClassifyError::NoPicks { name: c.name.clone() });
            }
            out.push(idx);
        }
        Ok(out)
    }
}

fn hex(rgb: [u8; 3]) -> String {
    format!("#{:02x}{:02x}{:02x}", rgb[0], rgb[1], rgb[2])
}

/// Stroke colours and their pixels, in order of first appearance.
/// Pixels `[x, y]` painted in one stroke colour.
type Stroke = ([u8; 3], Vec<[i64; 2]>);

fn read_strokes(path: &Path) -> Result<Vec<Stroke>, ClassifyError> {
    let img = image::open(path)
        .map_err(|source| crate::imgio::ImageError::Read { path: path.into(), source })?
        .to_rgba8();
    let mut out: Vec<Stroke> = Vec::new();
    for (x, y, p) in img.enumerate_pixels() {
        let [r, g, b, a] = p.0;
        if a < 128 || (r, g, b) == (0, 0, 0) {
            continue;
        }
        let rgb = [r, g, b];
        match out.iter_mut().find(|(c, _)| *c == rgb) {
            Some((_, v)) => v.push([x as i64, y as i64]),
            None => out.push((rgb, vec![[x as i64, y as i64]])),
        }
    }
    Ok(out)
}

/// Picks as a conservator would click them, derived from a label map: `per_class` pixels of
/// each class `0..names.len()`, drawn (seeded) from pixels whose `(2r+1)^2` neighbourhood
/// (r = 2) is all that class, i.e. well inside a painted patch, from all over the object.
/// A class with no such pixel falls back to any of its pixels; a class absent from the map
/// is an error.
pub fn picks_from_labels(
    labels: &super::LabelMap,
    names: &[String],
    display: &[Option<[u8; 3]>],
    per_class: usize,
    seed: u64,
) -> Result<Picks, ClassifyError> {
    use rand::SeedableRng;
    use rand::seq::SliceRandom;
    const R: i64 = 2;
    let (w, h) = (labels.width as i64, labels.height as i64);
    let k = names.len();
    let mut interior: Vec<Vec<[i64; 2]>> = vec![Vec::new(); k];
    let mut any: Vec<Vec<[i64; 2]>> = vec![Vec::new(); k];
    for y in 0..h {
        for x in 0..w {
            let l = labels.data[(y * w + x) as usize] as usize;
            if l >= k {
                continue;
            }
            any[l].push([x, y]);
            let inside = (y - R..=y + R).all(|yy| {
                (x - R..=x + R).all(|xx| {
                    xx >= 0
                        && yy >= 0
                        && xx < w
                        && yy < h
                        && labels.data[(yy * w + xx) as usize] as usize == l
                })
            });
            if inside {
                interior[l].push([x, y]);
            }
        }
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut colours = Vec::with_capacity(k);
    for c in 0..k {
        let pool = if interior[c].is_empty() { &mut any[c] } else { &mut interior[c] };
        if pool.is_empty() {
            return Err(ClassifyError::NoPicks { name: names[c].clone() });
        }
        let (chosen, _) = pool.partial_shuffle(&mut rng, per_class.max(1));
        colours.push(PickColour {
            name: names[c].clone(),
            display_srgb8: display.get(c).copied().flatten(),
            pixels: chosen.to_vec(),
            rects: Vec::new(),
            stroke_srgb8: None,
        });
    }
    Ok(Picks { version: PICKS_VERSION, colours, strokes: None })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn colour(name: &str, pixels: Vec<[i64; 2]>) -> PickColour {
        PickColour { name: name.into(), display_srgb8: None, pixels, rects: vec![], stroke_srgb8: None }
    }

    #[test]
    fn json_with_rects_and_strokes_resolves_to_pixels() {
        let dir = tempfile::tempdir().unwrap();
        let mut strokes = image::RgbaImage::new(6, 4);
        strokes.put_pixel(5, 3, image::Rgba([255, 0, 0, 255]));
        strokes.put_pixel(0, 1, image::Rgba([0, 255, 0, 255]));
        strokes.put_pixel(1, 1, image::Rgba([0, 255, 0, 10])); // transparent: not a pick
        strokes.save(dir.path().join("strokes.png")).unwrap();
        let mut a = colour("clay", vec![[1, 0]]);
        a.rects.push(PickRect { x: 2, y: 2, width: 2, height: 2 });
        a.stroke_srgb8 = Some([255, 0, 0]);
        let mut b = colour("black", vec![]);
        b.stroke_srgb8 = Some([0, 255, 0]);
        let picks = Picks {
            version: PICKS_VERSION,
            colours: vec![a, b],
            strokes: Some(PathBuf::from("strokes.png")),
        };
        let p = dir.path().join("picks.json");
        picks.save(&p).unwrap();
        let back = Picks::load(&p).unwrap();
        let idx = back.pixel_indices(6, 4).unwrap();
        assert_eq!(idx[0], vec![1, 23, 14, 15, 20, 21]);
        assert_eq!(idx[1], vec![6]);

        let alone = Picks::load(&dir.path().join("strokes.png")).unwrap();
        assert_eq!(alone.colours.len(), 2);
        assert_eq!(alone.colours[0].name, "#00ff00"); // first in raster order
    }

    #[test]
    fn bad_picks_get_clear_errors() {
        let p = |colours| Picks { version: PICKS_VERSION, colours, strokes: None };
        let err = p(vec![colour("a", vec![[0, 0]]), colour("b", vec![])]).pixel_indices(4, 4).unwrap_err();
        assert!(err.to_string().contains("'b' has no picked pixels"), "{err}");
        let err = p(vec![colour("a", vec![[4, 0]])]).pixel_indices(4, 4).unwrap_err();
        assert!(err.to_string().contains("(4, 0)") && err.to_string().contains("4x4"), "{err}");
        let err =
            p(vec![colour("a", vec![[0, 0]]), colour("a", vec![[1, 1]])]).pixel_indices(4, 4).unwrap_err();
        assert!(err.to_string().contains("twice"), "{err}");
        let mut c = colour("r", vec![]);
        c.rects.push(PickRect { x: 3, y: 3, width: 2, height: 1 });
        assert!(p(vec![c]).pixel_indices(4, 4).is_err());

        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("picks.json");
        std::fs::write(&f, r#"{"version": 2, "colours": []}"#).unwrap();
        let err = Picks::load(&f).unwrap_err().to_string();
        assert!(err.contains("picks.json") && err.contains("version 2"), "{err}");
    }
}
