//! Images inside the authoring tool: linear-light float RGB and 8-bit label maps, with PNG
//! input/output that names the file in every error.
//!
//! Convention (ARCHITECTURE.md): camera images are linear light, stored as 16-bit PNG;
//! anything meant for people to look at is 8-bit sRGB PNG.

use std::path::{Path, PathBuf};

use image::{ImageBuffer, Rgb};
use thiserror::Error;

/// The text note in every 16-bit linear PNG we write.
pub const LINEAR16_NOTE: &str =
    "linear light, not sRGB: 0..65535 is 0..1 of the camera's full scale (gAMA 1.0)";

#[derive(Debug, Error)]
pub enum ImageError {
    #[error("cannot read image {path}: {source}")]
    Read { path: PathBuf, source: image::ImageError },
    #[error(
        "cannot read image {path}: {source}; restage reads PNG, JPEG and TIFF (convert other \
         formats first, e.g. `magick photo.heic photo.png`)"
    )]
    Unsupported { path: PathBuf, source: image::ImageError },
    #[error("cannot write image {path}: {source}")]
    Write { path: PathBuf, source: image::ImageError },
    #[error("image {path} is {got_w}x{got_h}, expected {want_w}x{want_h}")]
    Size { path: PathBuf, got_w: u32, got_h: u32, want_w: u32, want_h: u32 },
    #[error("image size {width}x{height} is invalid (expected 1..=32768 on each side)")]
    BadDimensions { width: u32, height: u32 },
}

/// A linear-light RGB image, row-major, one `[r, g, b]` per pixel, values nominally in 0..=1.
#[derive(Clone, Debug, PartialEq)]
pub struct LinearImage {
    pub width: u32,
    pub height: u32,
    pub data: Vec<[f32; 3]>,
}

impl LinearImage {
    pub fn new(width: u32, height: u32) -> Result<Self, ImageError> {
        check_dimensions(width, height)?;
        Ok(Self { width, height, data: vec![[0.0; 3]; width as usize * height as usize] })
    }

    pub fn get(&self, x: u32, y: u32) -> [f32; 3] {
        self.data[y as usize * self.width as usize + x as usize]
    }

    pub fn set(&mut self, x: u32, y: u32, v: [f32; 3]) {
        let w = self.width as usize;
        self.data[y as usize * w + x as usize] = v;
    }

    /// Reads a PNG (8 or 16 bit, grey or colour). 16-bit files are taken as linear light
    /// (our camera images); 8-bit files are decoded from sRGB.
    pub fn load(path: &Path) -> Result<Self, ImageError> {
        let img = image::open(path).map_err(|source| match source {
            image::ImageError::Unsupported(_) => ImageError::Unsupported { path: path.into(), source },
            source => ImageError::Read { path: path.into(), source },
        })?;
        let is16 = matches!(
            img.color(),
            image::ColorType::L16
                | image::ColorType::La16
                | image::ColorType::Rgb16
                | image::ColorType::Rgba16
        );
        let (width, height) = (img.width(), img.height());
        check_dimensions(width, height)?;
        let data = if is16 {
            img.to_rgb16().pixels().map(|p| p.0.map(|c| c as f32 / 65535.0)).collect()
        } else {
            img.to_rgb8().pixels().map(|p| p.0.map(|c| srgb_to_linear(c as f32 / 255.0))).collect()
        };
        Ok(Self { width, height, data })
    }

    /// Like [`load`](Self::load) but refuses an image of the wrong size.
    pub fn load_sized(path: &Path, width: u32, height: u32) -> Result<Self, ImageError> {
        let img = Self::load(path)?;
        if img.width != width || img.height != height {
            return Err(ImageError::Size {
                path: path.into(),
                got_w: img.width,
                got_h: img.height,
                want_w: width,
                want_h: height,
            });
        }
        Ok(img)
    }

    /// Writes linear values as a 16-bit linear PNG (clamped to 0..=1), with a gAMA chunk of
    /// 1.0 and a text note saying so: without them a viewer takes the values as sRGB and shows
    /// a camera image nearly black.
    pub fn save_linear16(&self, path: &Path) -> Result<(), ImageError> {
        let write_err = |e: std::io::Error| ImageError::Write { path: path.into(), source: e.into() };
        let png_err = |e: png::EncodingError| write_err(e.into());
        let file = std::fs::File::create(path).map_err(write_err)?;
        let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), self.width, self.height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Sixteen);
        // The `image` crate's defaults, which wrote these files before (its `Fast` is fdeflate,
        // over ten times quicker than `Balanced` on noisy camera images, files 10 % larger).
        encoder.set_compression(png::Compression::Fast);
        encoder.set_filter(png::Filter::Adaptive);
        encoder.set_source_gamma(png::ScaledFloat::new(1.0));
        encoder.add_text_chunk("Comment".into(), LINEAR16_NOTE.into()).map_err(png_err)?;
        let mut writer = encoder.write_header().map_err(png_err)?;
        // PNG samples are big-endian.
        let bytes: Vec<u8> = self
            .data
            .iter()
            .flat_map(|p| p.map(|c| (c.clamp(0.0, 1.0) * 65535.0).round() as u16))
            .flat_map(u16::to_be_bytes)
            .collect();
        writer.write_image_data(&bytes).map_err(png_err)?;
        writer.finish().map_err(png_err)
    }

    /// Writes an 8-bit sRGB PNG for people to look at (values scaled by `gain` first).
    pub fn save_srgb8(&self, path: &Path, gain: f32) -> Result<(), ImageError> {
        self.to_srgb8(gain).save(path).map_err(|source| ImageError::Write { path: path.into(), source })
    }

    /// 8-bit sRGB rendition (values scaled by `gain`, then clamped).
    pub fn to_srgb8(&self, gain: f32) -> image::RgbImage {
        ImageBuffer::from_fn(self.width, self.height, |x, y| {
            Rgb(self.get(x, y).map(|c| (linear_to_srgb((c * gain).clamp(0.0, 1.0)) * 255.0).round() as u8))
        })
    }
}

/// Opens any image file and refuses one that is not `width x height`, naming the file.
pub fn open_sized(path: &Path, width: u32, height: u32) -> Result<image::DynamicImage, ImageError> {
    let img = image::open(path).map_err(|source| ImageError::Read { path: path.into(), source })?;
    if img.width() != width || img.height() != height {
        return Err(ImageError::Size {
            path: path.into(),
            got_w: img.width(),
            got_h: img.height(),
            want_w: width,
            want_h: height,
        });
    }
    Ok(img)
}

pub fn check_dimensions(width: u32, height: u32) -> Result<(), ImageError> {
    if !(1..=32768).contains(&width) || !(1..=32768).contains(&height) {
        return Err(ImageError::BadDimensions { width, height });
    }
    Ok(())
}

/// sRGB electro-optical transfer (IEC 61966-2-1): encoded 0..=1 to linear 0..=1.
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
}

/// Inverse of [`srgb_to_linear`].
pub fn linear_to_srgb(c: f32) -> f32 {
    if c <= 0.003_130_8 { c * 12.92 } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_round_trip() {
        for i in 0..=255 {
            let c = i as f32 / 255.0;
            assert!((linear_to_srgb(srgb_to_linear(c)) - c).abs() < 1e-5);
        }
    }

    #[test]
    fn linear16_round_trip_and_size_check() {
        let dir = tempfile::tempdir().unwrap();
        let mut img = LinearImage::new(3, 2).unwrap();
        img.set(2, 1, [0.25, 0.5, 1.0]);
        let p = dir.path().join("a.png");
        img.save_linear16(&p).unwrap();
        let back = LinearImage::load(&p).unwrap();
        assert!((back.get(2, 1)[0] - 0.25).abs() < 1e-4);
        let err = LinearImage::load_sized(&p, 4, 2).unwrap_err();
        assert!(err.to_string().contains("a.png"), "{err}");
        assert!(LinearImage::new(0, 5).is_err());
    }

    /// Camera images looked black in viewers: they are linear but carried no gAMA chunk.
    #[test]
    fn linear16_carries_gamma_one_and_its_pixels_read_back_exactly() {
        let dir = tempfile::tempdir().unwrap();
        let mut img = LinearImage::new(5, 3).unwrap();
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = [i as f32 / 15.0, 1.0 - i as f32 / 15.0, (i % 4) as f32 / 3.0];
        }
        img.data[7] = [-0.5, 2.0, f32::NAN];
        let p = dir.path().join("linear.png");
        img.save_linear16(&p).unwrap();

        let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&p).unwrap()));
        let mut reader = decoder.read_info().unwrap();
        let info = reader.info();
        assert_eq!(info.gamma(), Some(png::ScaledFloat::new(1.0)), "no gAMA 1.0 chunk");
        assert!(info.srgb.is_none() && info.icc_profile.is_none());
        let note = info.uncompressed_latin1_text.iter().find(|t| t.keyword == "Comment").unwrap();
        assert!(note.text.contains("linear"), "{}", note.text);
        assert_eq!((info.width, info.height, info.bit_depth), (5, 3, png::BitDepth::Sixteen));
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        reader.next_frame(&mut buf).unwrap();
        let samples: Vec<u16> = buf.chunks_exact(2).map(|b| u16::from_be_bytes([b[0], b[1]])).collect();
        let want: Vec<u16> =
            img.data.iter().flat_map(|p| p.map(|c| (c.clamp(0.0, 1.0) * 65535.0).round() as u16)).collect();
        assert_eq!(samples, want);
        // And through our own reader (the `image` crate), unchanged by the chunk.
        let back = LinearImage::load(&p).unwrap();
        let back16: Vec<u16> =
            back.data.iter().flat_map(|p| p.map(|c| (c * 65535.0).round() as u16)).collect();
        assert_eq!(back16, want);
    }
}
