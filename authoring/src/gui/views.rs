//! The tool's views (what picture the central area shows) and the pan/zoom transform between
//! screen points and image pixel coordinates (ARCHITECTURE.md: integer values at pixel
//! centres, so pixel (i, j) covers [i-0.5, i+0.5) x [j-0.5, j+0.5)).

use super::doc::Scene;

/// A picture the tool can show.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ViewKind {
    Photo,
    /// The photo with what is not the object tinted (the object mask).
    Object,
    /// The classification in the palette's display colours.
    Classes,
    /// The classification in distinct false colours.
    ClassesFalse,
    Restored,
    Relit,
    /// What a visitor sees of a scene (virtual stage, exposure normalised by the scale).
    Visitor(Scene),
    /// The irradiance heat map of a scene's frames, lux.
    Irradiance(Scene),
}

impl ViewKind {
    pub fn label(self) -> String {
        match self {
            ViewKind::Photo => "photo".into(),
            ViewKind::Object => "object".into(),
            ViewKind::Classes => "classes".into(),
            ViewKind::ClassesFalse => "classes (false colour)".into(),
            ViewKind::Restored => "restored".into(),
            ViewKind::Relit => "relit".into(),
            ViewKind::Visitor(s) => format!("visitor: {}", s.id()),
            ViewKind::Irradiance(s) => format!("lux: {}", s.id()),
        }
    }

    /// A file-name-safe name (screenshots, golden images).
    pub fn slug(self) -> String {
        self.label().replace([':', ' ', '(', ')'], "_").replace("__", "_").trim_end_matches('_').to_string()
    }
}

/// Pan and zoom: a screen point `s` (points, relative to the view's top-left) shows image
/// coordinate `offset + s / zoom - 0.5` (so screen 0 is the left edge of pixel 0 when offset = 0).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewTransform {
    /// Screen points per image pixel.
    pub zoom: f32,
    /// Image coordinate (pixel edges: 0 = left edge of pixel 0) at the view's top-left.
    pub offset: [f32; 2],
}

impl Default for ViewTransform {
    fn default() -> Self {
        Self { zoom: 1.0, offset: [0.0, 0.0] }
    }
}

impl ViewTransform {
    pub const MIN_ZOOM: f32 = 1.0 / 64.0;
    pub const MAX_ZOOM: f32 = 64.0;

    /// The whole image, centred, in a view of `view` points.
    pub fn fit(image: [u32; 2], view: [f32; 2]) -> Self {
        let zoom =
            (view[0] / image[0] as f32).min(view[1] / image[1] as f32).clamp(Self::MIN_ZOOM, Self::MAX_ZOOM);
        let offset = [(image[0] as f32 - view[0] / zoom) * 0.5, (image[1] as f32 - view[1] / zoom) * 0.5];
        Self { zoom, offset }
    }

    /// Image pixel coordinate (centres at integers) under screen point `s`.
    pub fn to_image(self, s: [f32; 2]) -> [f32; 2] {
        [self.offset[0] + s[0] / self.zoom - 0.5, self.offset[1] + s[1] / self.zoom - 0.5]
    }

    /// Screen point of image pixel coordinate `p`.
    pub fn to_screen(self, p: [f32; 2]) -> [f32; 2] {
        [(p[0] + 0.5 - self.offset[0]) * self.zoom, (p[1] + 0.5 - self.offset[1]) * self.zoom]
    }

    /// Moves the picture by `d` screen points.
    pub fn pan(&mut self, d: [f32; 2]) {
        self.offset[0] -= d[0] / self.zoom;
        self.offset[1] -= d[1] / self.zoom;
    }

    /// Zooms by `factor` keeping the image point under screen point `at` where it is.
    pub fn zoom_at(&mut self, factor: f32, at: [f32; 2]) {
        let before = self.to_image(at);
        self.zoom = (self.zoom * factor).clamp(Self::MIN_ZOOM, Self::MAX_ZOOM);
        let after = self.to_image(at);
        self.offset[0] += before[0] - after[0];
        self.offset[1] += before[1] - after[1];
    }

    /// The image's pixels visible in a view of `view` points, clamped to the image:
    /// `[x, y, w, h]`, or `None` when none is.
    pub fn visible(&self, image: [u32; 2], view: [f32; 2]) -> Option<[u32; 4]> {
        let x0 = self.offset[0].floor().max(0.0);
        let y0 = self.offset[1].floor().max(0.0);
        let x1 = (self.offset[0] + view[0] / self.zoom).ceil().min(image[0] as f32);
        let y1 = (self.offset[1] + view[1] / self.zoom).ceil().min(image[1] as f32);
        (x1 > x0 && y1 > y0).then_some([x0 as u32, y0 as u32, (x1 - x0) as u32, (y1 - y0) as u32])
    }

    /// The screen rectangle `[x0, y0, x1, y1]` (points) the whole image covers; the painter
    /// clips it to the view, and the GPU samples only what is visible.
    pub fn image_rect(&self, image: [u32; 2]) -> [f32; 4] {
        let a = self.to_screen([-0.5, -0.5]);
        let b = self.to_screen([image[0] as f32 - 0.5, image[1] as f32 - 0.5]);
        [a[0], a[1], b[0], b[1]]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn screen_and_image_coordinates_invert() {
        let mut t = ViewTransform::fit([4000, 2500], [800.0, 600.0]);
        assert!((t.zoom - 0.2).abs() < 1e-6);
        let p = [123.25, 456.5];
        let q = t.to_image(t.to_screen(p));
        assert!((q[0] - p[0]).abs() < 1e-3 && (q[1] - p[1]).abs() < 1e-3);
        // Zooming keeps the point under the cursor.
        let at = [300.0, 200.0];
        let before = t.to_image(at);
        t.zoom_at(3.0, at);
        let after = t.to_image(at);
        assert!((before[0] - after[0]).abs() < 1e-2 && (before[1] - after[1]).abs() < 1e-2);
        // Panning right by 10 points shows what was 10/zoom px to the left.
        let z = t.zoom;
        let before = t.to_image([0.0, 0.0]);
        t.pan([10.0, 0.0]);
        assert!((t.to_image([0.0, 0.0])[0] - (before[0] - 10.0 / z)).abs() < 1e-3);
    }

    #[test]
    fn pixel_centres_and_visible_rect() {
        let t = ViewTransform { zoom: 4.0, offset: [10.0, 20.0] };
        // Screen 0 is the left edge of pixel 10; pixel 10's centre is 2 points in.
        assert_eq!(t.to_screen([10.0, 20.0]), [2.0, 2.0]);
        assert_eq!(t.visible([100, 100], [40.0, 20.0]), Some([10, 20, 10, 5]));
        let far = ViewTransform { zoom: 1.0, offset: [500.0, 0.0] };
        assert_eq!(far.visible([100, 100], [40.0, 40.0]), None);
        let r = t.image_rect([100, 100]);
        assert_eq!([r[0], r[1]], [-40.0, -80.0]);
    }

    #[test]
    fn slugs_are_file_names() {
        assert_eq!(ViewKind::Visitor(Scene::Restored).slug(), "visitor_restored");
        assert_eq!(ViewKind::ClassesFalse.slug(), "classes_false_colour");
    }
}
