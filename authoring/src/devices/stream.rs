//! A camera built on a stream of raw driver frames (V4L2 or a simulated one): drops the
//! frames the driver queued before the pattern changed, averages a few fresh ones, and turns
//! the bytes (YUYV, RGB3, GREY or MJPG) into linear light.

use std::fmt;

use crate::capture_set::CameraIntrinsics;
use crate::hw::{Camera, HwError};
use crate::imgio::{LinearImage, srgb_to_linear};

/// The byte layouts a camera may deliver.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PixelFormat {
    /// YUV 4:2:2, `Y0 U Y1 V` per two pixels, BT.601 limited range (most webcams).
    Yuyv,
    /// 8-bit RGB, three bytes per pixel.
    Rgb3,
    /// 8-bit grey.
    Grey,
    /// Motion JPEG, one JPEG per frame.
    Mjpg,
}

impl PixelFormat {
    /// The V4L2 four-character code.
    pub fn fourcc(self) -> [u8; 4] {
        match self {
            PixelFormat::Yuyv => *b"YUYV",
            PixelFormat::Rgb3 => *b"RGB3",
            PixelFormat::Grey => *b"GREY",
            PixelFormat::Mjpg => *b"MJPG",
        }
    }

    pub fn from_fourcc(code: [u8; 4]) -> Option<Self> {
        [PixelFormat::Yuyv, PixelFormat::Rgb3, PixelFormat::Grey, PixelFormat::Mjpg]
            .into_iter()
            .find(|f| f.fourcc() == code)
    }

    /// Bytes a frame of `width x height` has (`None` for compressed formats).
    pub fn frame_len(self, width: u32, height: u32) -> Option<usize> {
        let n = width as usize * height as usize;
        match self {
            PixelFormat::Yuyv => Some(n * 2),
            PixelFormat::Rgb3 => Some(n * 3),
            PixelFormat::Grey => Some(n),
            PixelFormat::Mjpg => None,
        }
    }
}

impl fmt::Display for PixelFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(std::str::from_utf8(&self.fourcc()).unwrap_or("????"))
    }
}

/// How the camera's 8-bit values relate to light. Webcams encode with (roughly) the sRGB
/// curve; machine-vision cameras in raw mode are linear. Radiometric calibration absorbs
/// what remains (per-pixel gain and offset, projector responses).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraResponse {
    Srgb,
    Linear,
}

impl std::str::FromStr for CameraResponse {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "srgb" => Ok(CameraResponse::Srgb),
            "linear" => Ok(CameraResponse::Linear),
            _ => Err(format!("{s:?} is not a camera response (srgb or linear)")),
        }
    }
}

/// One frame as the driver delivered it.
#[derive(Clone, Debug, PartialEq)]
pub struct RawFrame {
    pub width: u32,
    pub height: u32,
    pub format: PixelFormat,
    pub bytes: Vec<u8>,
}

/// Decodes a raw frame to linear RGB (0..1 of full scale). `device` names the camera in errors.
pub fn to_linear(frame: &RawFrame, response: CameraResponse, device: &str) -> Result<LinearImage, HwError> {
    let bad = |problem: String| HwError::Device { device: device.into(), problem };
    let (w, h) = (frame.width, frame.height);
    let mut out = LinearImage::new(w, h).map_err(|e| bad(e.to_string()))?;
    let lut: Vec<f32> = (0..256u32)
        .map(|v| {
            let c = v as f32 / 255.0;
            match response {
                CameraResponse::Srgb => srgb_to_linear(c),
                CameraResponse::Linear => c,
            }
        })
        .collect();
    let short = |len: usize| {
        bad(format!(
            "a {w}x{h} {} frame needs {} bytes, the driver gave {len}",
            frame.format,
            frame.format.frame_len(w, h).unwrap_or(0)
        ))
    };
    match frame.format {
        PixelFormat::Rgb3 | PixelFormat::Grey | PixelFormat::Yuyv => {
            let need = frame.format.frame_len(w, h).unwrap_or(0);
            if frame.bytes.len() < need {
                return Err(short(frame.bytes.len()));
            }
        }
        PixelFormat::Mjpg => {}
    }
    match frame.format {
        PixelFormat::Rgb3 => {
            for (px, rgb) in out.data.iter_mut().zip(frame.bytes.chunks_exact(3)) {
                *px = [lut[rgb[0] as usize], lut[rgb[1] as usize], lut[rgb[2] as usize]];
            }
        }
        PixelFormat::Grey => {
            for (px, &g) in out.data.iter_mut().zip(&frame.bytes) {
                *px = [lut[g as usize]; 3];
            }
        }
        PixelFormat::Yuyv => {
            if w % 2 != 0 {
                return Err(bad(format!("YUYV needs an even width, the frame is {w} wide")));
            }
            for (pair, yuyv) in out.data.chunks_exact_mut(2).zip(frame.bytes.chunks_exact(4)) {
                let (u, v) = (yuyv[1], yuyv[3]);
                pair[0] = yuv_to_rgb(yuyv[0], u, v).map(|c| lut[c as usize]);
                pair[1] = yuv_to_rgb(yuyv[2], u, v).map(|c| lut[c as usize]);
            }
        }
        PixelFormat::Mjpg => {
            let img = decode_jpeg(&frame.bytes).map_err(bad)?;
            if img.dimensions() != (w, h) {
                return Err(bad(format!(
                    "the JPEG frame is {}x{}, the stream was set to {w}x{h}",
                    img.width(),
                    img.height()
                )));
            }
            for (px, rgb) in out.data.iter_mut().zip(img.pixels()) {
                *px = rgb.0.map(|c| lut[c as usize]);
            }
        }
    }
    Ok(out)
}

#[cfg(feature = "hardware")]
fn decode_jpeg(bytes: &[u8]) -> Result<image::RgbImage, String> {
    image::load_from_memory_with_format(bytes, image::ImageFormat::Jpeg)
        .map(|i| i.to_rgb8())
        .map_err(|e| format!("cannot decode the MJPG frame: {e}"))
}

#[cfg(not(feature = "hardware"))]
fn decode_jpeg(_: &[u8]) -> Result<image::RgbImage, String> {
    Err("MJPG frames need the `hardware` feature (JPEG decoding); ask the camera for YUYV".into())
}

/// BT.601 limited-range YCbCr to 8-bit R'G'B' (what UVC webcams send).
pub fn yuv_to_rgb(y: u8, u: u8, v: u8) -> [u8; 3] {
    let c = 1.164_383 * (y as f32 - 16.0);
    let d = u as f32 - 128.0;
    let e = v as f32 - 128.0;
    let q = |x: f32| x.round().clamp(0.0, 255.0) as u8;
    [q(c + 1.596_027 * e), q(c - 0.391_762 * d - 0.812_968 * e), q(c + 2.017_232 * d)]
}

/// A source of raw frames in arrival order, e.g. a V4L2 memory-mapped stream.
pub trait FrameSource {
    /// Names the device in messages (e.g. `/dev/video0`).
    fn name(&self) -> String;
    /// How many frames the driver may already hold when we ask: frames exposed before the
    /// projectors changed, which a grab must throw away.
    fn queued(&self) -> usize;
    /// The next frame, blocking until one arrives.
    fn next_frame(&mut self) -> Result<RawFrame, HwError>;
}

/// How a [`StreamCamera`] takes one exposure.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GrabConfig {
    /// Fresh frames averaged per exposure (reduces noise; >= 1).
    pub average: u32,
    pub response: CameraResponse,
}

impl Default for GrabConfig {
    fn default() -> Self {
        Self { average: 1, response: CameraResponse::Srgb }
    }
}

/// A [`Camera`] over a [`FrameSource`] with known intrinsics.
#[derive(Debug)]
pub struct StreamCamera<S> {
    source: S,
    intrinsics: CameraIntrinsics,
    cfg: GrabConfig,
}

impl<S: FrameSource> StreamCamera<S> {
    pub fn new(source: S, intrinsics: CameraIntrinsics, cfg: GrabConfig) -> Result<Self, HwError> {
        if cfg.average == 0 {
            return Err(HwError::Device { device: source.name(), problem: "averaging 0 frames".into() });
        }
        Ok(Self { source, intrinsics, cfg })
    }

    pub fn source(&self) -> &S {
        &self.source
    }
}

impl<S: FrameSource> Camera for StreamCamera<S> {
    fn intrinsics(&self) -> CameraIntrinsics {
        self.intrinsics.clone()
    }

    fn grab(&mut self) -> Result<LinearImage, HwError> {
        // Frames already queued were exposed before the pattern changed.
        for _ in 0..self.source.queued() {
            self.source.next_frame()?;
        }
        let (w, h) = (self.intrinsics.width, self.intrinsics.height);
        let mut sum = vec![[0.0f32; 3]; w as usize * h as usize];
        for _ in 0..self.cfg.average {
            let frame = self.source.next_frame()?;
            if (frame.width, frame.height) != (w, h) {
                return Err(HwError::Device {
                    device: self.source.name(),
                    problem: format!(
                        "frames are {}x{} but the camera calibration is for {w}x{h}",
                        frame.width, frame.height
                    ),
                });
            }
            let img = to_linear(&frame, self.cfg.response, &self.source.name())?;
            for (s, p) in sum.iter_mut().zip(&img.data) {
                for c in 0..3 {
                    s[c] += p[c];
                }
            }
        }
        let n = self.cfg.average as f32;
        let data = sum.into_iter().map(|s| s.map(|c| c / n)).collect();
        Ok(LinearImage { width: w, height: h, data })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::VecDeque;

    #[test]
    fn yuv_grey_axis_and_primaries() {
        assert_eq!(yuv_to_rgb(16, 128, 128), [0, 0, 0]);
        assert_eq!(yuv_to_rgb(235, 128, 128), [255, 255, 255]);
        assert_eq!(yuv_to_rgb(126, 128, 128), [128, 128, 128]);
        // BT.601 red (R'=255, G'=B'=0) is Y=81, Cb=90, Cr=240.
        let [r, g, b] = yuv_to_rgb(81, 90, 240);
        assert!(r >= 254 && g <= 1 && b <= 1, "{r} {g} {b}");
    }

    #[test]
    fn formats_decode_to_the_same_linear_light() {
        let grey = RawFrame { width: 2, height: 1, format: PixelFormat::Grey, bytes: vec![0, 255] };
        let rgb =
            RawFrame { width: 2, height: 1, format: PixelFormat::Rgb3, bytes: vec![0, 0, 0, 255, 255, 255] };
        let yuyv =
            RawFrame { width: 2, height: 1, format: PixelFormat::Yuyv, bytes: vec![16, 128, 235, 128] };
        for f in [grey, rgb, yuyv] {
            let img = to_linear(&f, CameraResponse::Srgb, "test").unwrap();
            assert_eq!(img.data, vec![[0.0; 3], [1.0; 3]], "{}", f.format);
        }
        // sRGB mid-grey 128 is about 21.6 % of linear full scale; linear keeps it at 50 %.
        let mid = RawFrame { width: 1, height: 1, format: PixelFormat::Grey, bytes: vec![128] };
        let s = to_linear(&mid, CameraResponse::Srgb, "t").unwrap().data[0][0];
        let l = to_linear(&mid, CameraResponse::Linear, "t").unwrap().data[0][0];
        assert!((s - 0.2158).abs() < 1e-3 && (l - 128.0 / 255.0).abs() < 1e-6, "{s} {l}");
    }

    #[test]
    fn short_or_odd_frames_are_refused_with_the_device_name() {
        let f = RawFrame { width: 4, height: 2, format: PixelFormat::Yuyv, bytes: vec![0; 10] };
        let e = to_linear(&f, CameraResponse::Srgb, "/dev/video7").unwrap_err().to_string();
        assert!(e.contains("/dev/video7") && e.contains("16 bytes") && e.contains("gave 10"), "{e}");
        let f = RawFrame { width: 3, height: 1, format: PixelFormat::Yuyv, bytes: vec![0; 6] };
        assert!(to_linear(&f, CameraResponse::Srgb, "c").unwrap_err().to_string().contains("even width"));
        assert_eq!(PixelFormat::from_fourcc(*b"MJPG"), Some(PixelFormat::Mjpg));
        assert_eq!(PixelFormat::from_fourcc(*b"H264"), None);
    }

    /// A driver queue: frames come out in order, `queued` of them exposed before the last change.
    struct Scripted {
        queue: VecDeque<u8>,
        level: u8,
        depth: usize,
    }

    impl FrameSource for Scripted {
        fn name(&self) -> String {
            "scripted".into()
        }
        fn queued(&self) -> usize {
            self.depth
        }
        fn next_frame(&mut self) -> Result<RawFrame, HwError> {
            self.queue.push_back(self.level);
            let v = self.queue.pop_front().expect("just pushed");
            Ok(RawFrame { width: 2, height: 2, format: PixelFormat::Grey, bytes: vec![v; 4] })
        }
    }

    #[test]
    fn stale_frames_are_dropped_and_fresh_ones_averaged() {
        let cam = CameraIntrinsics {
            width: 2,
            height: 2,
            fx: 1.0,
            fy: 1.0,
            cx: 1.0,
            cy: 1.0,
            distortion: [0.0; 5],
        };
        let src = Scripted { queue: VecDeque::from(vec![0; 3]), level: 0, depth: 3 };
        let cfg = GrabConfig { average: 2, response: CameraResponse::Linear };
        let mut camera = StreamCamera::new(src, cam.clone(), cfg).unwrap();
        camera.source.level = 255; // the pattern changes: three black frames are still queued
        let img = camera.grab().unwrap();
        assert_eq!(img.data, vec![[1.0; 3]; 4]);
        // A source that hides its queue would hand back the old pattern.
        let src = Scripted { queue: VecDeque::from(vec![0; 3]), level: 0, depth: 0 };
        let mut naive = StreamCamera::new(src, cam.clone(), cfg).unwrap();
        naive.source.level = 255;
        assert_eq!(naive.grab().unwrap().data, vec![[0.0; 3]; 4]);
        // Calibration for another size is refused.
        let other = CameraIntrinsics { width: 4, ..cam };
        let src = Scripted { queue: VecDeque::new(), level: 9, depth: 0 };
        let e = StreamCamera::new(src, other, cfg).unwrap().grab().unwrap_err().to_string();
        assert!(e.contains("2x2") && e.contains("4x2"), "{e}");
    }
}
