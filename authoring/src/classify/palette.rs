//! The classification's output files: the label map (`labels.png`) and the palette
//! (`palette.json`). Both are a contract with the restoration step; `Palette` is versioned.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::ClassifyError;
use crate::imgio::check_dimensions;

/// Label value of a pixel that is not part of the object (masked out, or outside it).
pub const MASKED: u8 = 255;

/// Current version of the `palette.json` format.
pub const PALETTE_VERSION: u32 = 1;

/// One class per pixel, row-major (`y * width + x`); values `0..K` index
/// [`Palette::classes`], [`MASKED`] marks pixels that are not object. Stored as an 8-bit
/// greyscale PNG whose grey value is the class index.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LabelMap {
    pub width: u32,
    pub height: u32,
    pub data: Vec<u8>,
}

impl LabelMap {
    /// A map of the given size with every pixel set to `fill`.
    pub fn new(width: u32, height: u32, fill: u8) -> Result<Self, ClassifyError> {
        check_dimensions(width, height)?;
        Ok(Self { width, height, data: vec![fill; width as usize * height as usize] })
    }

    /// Wraps existing labels, checking that there is one per pixel.
    pub fn from_vec(width: u32, height: u32, data: Vec<u8>) -> Result<Self, ClassifyError> {
        check_dimensions(width, height)?;
        let expected = width as usize * height as usize;
        if data.len() != expected {
            return Err(ClassifyError::LabelSize { got: data.len(), expected, width, height });
        }
        Ok(Self { width, height, data })
    }

    pub fn get(&self, x: u32, y: u32) -> u8 {
        self.data[y as usize * self.width as usize + x as usize]
    }

    pub fn set(&mut self, x: u32, y: u32, v: u8) {
        let w = self.width as usize;
        self.data[y as usize * w + x as usize] = v;
    }

    /// Reads an 8-bit greyscale PNG; any other pixel format is refused (a colour or 16-bit
    /// image is not a label map, and silently converting it would invent labels).
    pub fn load(path: &Path) -> Result<Self, ClassifyError> {
        let img = image::open(path)
            .map_err(|source| crate::imgio::ImageError::Read { path: path.into(), source })?;
        let image::DynamicImage::ImageLuma8(buf) = img else {
            return Err(ClassifyError::LabelFormat {
                path: path.into(),
                found: format!("{:?}", img.color()),
            });
        };
        let (width, height) = buf.dimensions();
        Self::from_vec(width, height, buf.into_raw())
    }

    /// Writes the map as an 8-bit greyscale PNG.
    pub fn save(&self, path: &Path) -> Result<(), ClassifyError> {
        image::save_buffer(path, &self.data, self.width, self.height, image::ExtendedColorType::L8)
            .map_err(|source| crate::imgio::ImageError::Write { path: path.into(), source }.into())
    }

    /// Number of pixels per class `0..k` (masked pixels and labels >= k are not counted).
    pub fn histogram(&self, k: usize) -> Vec<u64> {
        let mut h = vec![0u64; k];
        for &l in &self.data {
            if let Some(c) = h.get_mut(l as usize) {
                *c += 1;
            }
        }
        h
    }
}

/// One paint colour of the object.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PaletteClass {
    /// The conservator's name for the colour, e.g. "black paint".
    pub name: String,
    /// Representative colour: the mean of the picked pixels, CIE xyY (Y = 1 is the camera's
    /// full scale).
    pub representative_xyy: [f64; 3],
    /// Mean linear camera RGB of all pixels classified to this colour (the final k-means
    /// centroid, in RGB).
    pub mean_linear_rgb: [f64; 3],
    /// Number of pixels classified to this colour.
    pub pixels: u64,
    /// The colour the restoration should show, as 8-bit sRGB, if the conservator gave one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub display_srgb8: Option<[u8; 3]>,
}

/// `palette.json`: the colours, the fitted distance weights and how the clustering ran.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Palette {
    /// Format version, [`PALETTE_VERSION`].
    pub version: u32,
    /// Class `i` of the label map is `classes[i]`.
    pub classes: Vec<PaletteClass>,
    /// Weights `[a1, a2, a3]` of `D = a1 dx^2 + a2 dy^2 + a3 dY^2` (Eq. 1 with the brief's fix);
    /// positive, summing to one.
    pub weights: [f64; 3],
    /// x, y and Y are divided by these before the weighted distance: the picks' pooled
    /// within-colour standard deviation per channel, so that a channel counts in units of its
    /// own spread over the object (shading, grain, noise) and the weights do not depend on
    /// exposure. See `classify::calibrated`.
    pub channel_scale: [f64; 3],
    /// k-means iterations run.
    pub iterations: u32,
    /// Whether k-means stopped because no label changed (rather than at the iteration cap).
    pub converged: bool,
}

impl Palette {
    pub fn load(path: &Path) -> Result<Self, ClassifyError> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| ClassifyError::Read { path: path.into(), source })?;
        // Check the version before the shape, so a future format gets the clear message.
        #[derive(Deserialize)]
        struct Versioned {
            version: u32,
        }
        let v: Versioned = serde_json::from_str(&text)
            .map_err(|source| ClassifyError::Json { path: path.into(), source })?;
        if v.version != PALETTE_VERSION {
            return Err(ClassifyError::PaletteVersion {
                path: path.into(),
                got: v.version,
                expected: PALETTE_VERSION,
            });
        }
        serde_json::from_str(&text).map_err(|source| ClassifyError::Json { path: path.into(), source })
    }

    pub fn save(&self, path: &Path) -> Result<(), ClassifyError> {
        let text = serde_json::to_string_pretty(self).expect("a palette always serialises");
        std::fs::write(path, text + "\n").map_err(|source| ClassifyError::Write { path: path.into(), source })
    }

    /// The 8-bit sRGB colour to show class `i` as: the conservator's display colour if given,
    /// else the class's mean colour.
    pub fn display_colour(&self, i: usize) -> [u8; 3] {
        let c = &self.classes[i];
        c.display_srgb8.unwrap_or_else(|| crate::color::linear_to_srgb8(c.mean_linear_rgb))
    }
}

/// False-colour rendition of a label map: each class in its display colour
/// ([`Palette::display_colour`]), masked pixels black, labels without a class magenta.
pub fn preview(labels: &LabelMap, palette: &Palette) -> image::RgbImage {
    let colours: Vec<[u8; 3]> = (0..palette.classes.len()).map(|i| palette.display_colour(i)).collect();
    let mut out = image::RgbImage::new(labels.width, labels.height);
    for (p, &l) in out.pixels_mut().zip(&labels.data) {
        p.0 = match l {
            MASKED => [0, 0, 0],
            l => colours.get(l as usize).copied().unwrap_or([255, 0, 255]),
        };
    }
    out
}

/// Paths of the classification's output files inside its output directory.
pub fn output_paths(dir: &Path) -> (PathBuf, PathBuf, PathBuf) {
    (dir.join("labels.png"), dir.join("palette.json"), dir.join("preview.png"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn palette() -> Palette {
        Palette {
            version: PALETTE_VERSION,
            classes: vec![
                PaletteClass {
                    name: "clay".into(),
                    representative_xyy: [0.4, 0.38, 0.3],
                    mean_linear_rgb: [0.4, 0.25, 0.15],
                    pixels: 5,
                    display_srgb8: None,
                },
                PaletteClass {
                    name: "black".into(),
                    representative_xyy: [0.33, 0.34, 0.02],
                    mean_linear_rgb: [0.02, 0.02, 0.02],
                    pixels: 1,
                    display_srgb8: Some([20, 18, 16]),
                },
            ],
            weights: [0.4, 0.4, 0.2],
            channel_scale: [0.003, 0.003, 0.05],
            iterations: 3,
            converged: true,
        }
    }

    #[test]
    fn palette_round_trips_and_refuses_other_versions() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("palette.json");
        let pal = palette();
        pal.save(&p).unwrap();
        assert_eq!(Palette::load(&p).unwrap(), pal);
        assert_eq!(pal.display_colour(1), [20, 18, 16]);
        let mut future = pal.clone();
        future.version = 7;
        future.save(&p).unwrap();
        let err = Palette::load(&p).unwrap_err().to_string();
        assert!(err.contains("palette.json") && err.contains("version 7"), "{err}");
    }

    #[test]
    fn label_map_round_trips_and_refuses_colour_pngs() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("labels.png");
        let mut m = LabelMap::new(4, 3, MASKED).unwrap();
        m.set(1, 2, 3);
        m.set(0, 0, 0);
        m.save(&p).unwrap();
        let back = LabelMap::load(&p).unwrap();
        assert_eq!(back, m);
        assert_eq!(back.histogram(4), vec![1, 0, 0, 1]);
        let rgb = dir.path().join("rgb.png");
        image::RgbImage::new(2, 2).save(&rgb).unwrap();
        let err = LabelMap::load(&rgb).unwrap_err().to_string();
        assert!(err.contains("rgb.png") && err.contains("8-bit greyscale"), "{err}");
        assert!(LabelMap::from_vec(2, 2, vec![0; 3]).is_err());
    }
}
