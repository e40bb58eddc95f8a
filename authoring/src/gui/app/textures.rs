//! The pictures on the GPU: one texture per view, uploaded as the worker sends pictures, and
//! the hint strokes' overlay, updated over the pixels each stroke changes.

use std::collections::HashMap;

use eframe::egui::Color32;
use image::RgbaImage;

use crate::gui::doc::{HintLayer, NO_HINT};
use crate::gui::gpu::{GpuImage, Pictures, TileMask};
use crate::gui::views::ViewKind;

/// Tiles of the hint overlay this large are drawn or skipped whole.
const OVERLAY_TILE: u32 = 128;

/// The hint strokes' overlay: a picture mostly transparent, drawn where it holds strokes.
pub(super) struct Overlay {
    pub(super) image: GpuImage,
    pub(super) tiles: TileMask,
}

pub(super) struct Texture {
    pub(super) image: GpuImage,
    /// The photo's size (the picture covers it; its texture may be smaller, see `set_view`).
    pub(super) size: [u32; 2],
}

pub(super) struct Textures {
    /// Uploads and draws them.
    pub(super) gpu: Pictures,
    pub(super) views: HashMap<ViewKind, Texture>,
    /// `None` when the photo is larger than the adapter's textures.
    pub(super) overlay: Option<Overlay>,
    /// The classes' display colours (palette or picks), cached: reading them touches files.
    pub(super) colours: Vec<[u8; 3]>,
}

impl Textures {
    pub(super) fn new(gpu: Pictures) -> Self {
        Self { gpu, views: HashMap::new(), overlay: None, colours: Vec::new() }
    }

    /// Uploads the picture of `view`, for a photo of `photo_size`.
    pub(super) fn set_view(&mut self, view: ViewKind, img: &RgbaImage, photo_size: [u32; 2]) {
        let max = self.gpu.max_side;
        let scaled;
        let img = if img.width() > max || img.height() > max {
            // Larger than the adapter can hold in one texture: shown downscaled.
            let f = max as f32 / img.width().max(img.height()) as f32;
            scaled = image::imageops::resize(
                img,
                ((img.width() as f32 * f) as u32).max(1),
                ((img.height() as f32 * f) as u32).max(1),
                image::imageops::FilterType::Triangle,
            );
            &scaled
        } else {
            img
        };
        let dims = [img.width(), img.height()];
        match self.views.get(&view) {
            Some(t) if t.image.size == dims => {
                self.gpu.update(&t.image, [0, 0, dims[0], dims[1]], img.as_raw())
            }
            _ => {
                let image = self.gpu.image(dims, img.as_raw());
                self.views.insert(view, Texture { image, size: photo_size });
            }
        }
    }

    /// Re-uploads the hint overlay (all of it, or the pixels `rect`).
    pub(super) fn refresh_overlay(&mut self, h: &HintLayer, rect: Option<[u32; 4]>) {
        let colours = &self.colours;
        let [x, y, w, hh] = rect.unwrap_or([0, 0, h.width, h.height]);
        if w == 0 || hh == 0 {
            return;
        }
        // Premultiplied, so that mip levels average colour and coverage together.
        let mut rgba = Vec::with_capacity((w * hh * 4) as usize);
        for row in y..y + hh {
            for col in x..x + w {
                let l = h.labels[(row * h.width + col) as usize];
                rgba.extend(match colours.get(l as usize) {
                    Some(c) if l != NO_HINT => {
                        Color32::from_rgba_unmultiplied(c[0], c[1], c[2], 170).to_array()
                    }
                    _ => [0; 4],
                });
            }
        }
        let filled = |px: u32, py: u32| h.labels[(py * h.width + px) as usize] != NO_HINT;
        match (&mut self.overlay, rect) {
            (Some(o), Some(r)) => {
                self.gpu.update(&o.image, r, &rgba);
                o.tiles.update(r, filled);
            }
            _ if w > self.gpu.max_side || hh > self.gpu.max_side => {
                self.overlay = None;
                tracing::warn!(
                    "the hint overlay is not shown: the photo is larger than the adapter's textures"
                );
            }
            _ => {
                let mut tiles = TileMask::new([w, hh], OVERLAY_TILE);
                tiles.update([0, 0, w, hh], filled);
                self.overlay = Some(Overlay { image: self.gpu.image([w, hh], &rgba), tiles });
            }
        }
    }
}
