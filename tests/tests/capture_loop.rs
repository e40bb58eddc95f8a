//! The real-hardware acquisition path, run against the virtual stage: the camera is a
//! simulated V4L2 stream (8-bit sRGB YUYV frames, a driver queue holding frames exposed before
//! the last pattern change) behind the same `StreamCamera` that wraps `/dev/videoN`, and the
//! capture set it yields decodes like the one the virtual stage writes directly.

use std::cell::RefCell;
use std::collections::VecDeque;

use image::RgbImage;
use restage_authoring::acquire::{AcquireConfig, acquire};
use restage_authoring::calibrate::decode::{DecodeParams, ProjectorDecode};
use restage_authoring::calibrate::geometry::decode_capture;
use restage_authoring::devices::stream::{
    CameraResponse, FrameSource, GrabConfig, PixelFormat, RawFrame, StreamCamera,
};
use restage_authoring::hw::{Camera, DiffuseLight, FakeClock, HwError, ProjectorOutput, Rig};
use restage_authoring::imgio::{LinearImage, linear_to_srgb};
use restage_authoring::stage_sim::{SceneConfig, SceneName, SimRig, VirtualStage};

/// BT.601 limited range, the inverse of what the camera side decodes.
fn yuv(rgb: [u8; 3]) -> [f32; 3] {
    let [r, g, b] = rgb.map(|c| c as f32);
    let y = 16.0 + 0.256_788 * r + 0.504_129 * g + 0.097_906 * b;
    let u = 128.0 - 0.148_223 * r - 0.290_993 * g + 0.439_216 * b;
    let v = 128.0 + 0.439_216 * r - 0.367_788 * g - 0.071_427 * b;
    [y, u, v]
}

fn encode_yuyv(img: &LinearImage) -> Vec<u8> {
    let q = |x: f32| x.round().clamp(0.0, 255.0) as u8;
    let srgb = |p: [f32; 3]| p.map(|c| q(linear_to_srgb(c.clamp(0.0, 1.0)) * 255.0));
    let mut out = Vec::with_capacity(img.data.len() * 2);
    for pair in img.data.chunks_exact(2) {
        let (a, b) = (yuv(srgb(pair[0])), yuv(srgb(pair[1])));
        out.extend_from_slice(&[q(a[0]), q((a[1] + b[1]) / 2.0), q(b[0]), q((a[2] + b[2]) / 2.0)]);
    }
    out
}

/// The virtual stage's camera as a V4L2 driver would deliver it.
struct SimStream<'s, 'a> {
    rig: &'s RefCell<SimRig<'a>>,
    queue: VecDeque<RawFrame>,
    /// Whether `queued` tells the truth about the driver's queue.
    honest: bool,
}

impl<'s, 'a> SimStream<'s, 'a> {
    fn new(rig: &'s RefCell<SimRig<'a>>, depth: usize, honest: bool) -> Self {
        let mut s = Self { rig, queue: VecDeque::new(), honest };
        for _ in 0..depth {
            let f = s.expose().unwrap();
            s.queue.push_back(f);
        }
        s
    }

    fn expose(&self) -> Result<RawFrame, HwError> {
        let img = self.rig.borrow_mut().grab()?;
        Ok(RawFrame {
            width: img.width,
            height: img.height,
            format: PixelFormat::Yuyv,
            bytes: encode_yuyv(&img),
        })
    }
}

impl FrameSource for SimStream<'_, '_> {
    fn name(&self) -> String {
        "simulated /dev/video0".into()
    }
    fn queued(&self) -> usize {
        if self.honest { self.queue.len() } else { 0 }
    }
    fn next_frame(&mut self) -> Result<RawFrame, HwError> {
        // The driver fills a buffer with what the stage shows now; we get the oldest one.
        let fresh = self.expose()?;
        self.queue.push_back(fresh);
        Ok(self.queue.pop_front().expect("just pushed"))
    }
}

/// Projectors and room light of the same virtual stage.
struct SimDevices<'s, 'a>(&'s RefCell<SimRig<'a>>);

impl ProjectorOutput for SimDevices<'_, '_> {
    fn projector_count(&self) -> usize {
        self.0.borrow().projector_count()
    }
    fn resolution(&self, projector: usize) -> Result<(u32, u32), HwError> {
        self.0.borrow().resolution(projector)
    }
    fn show(&mut self, projector: usize, frame: &RgbImage) -> Result<(), HwError> {
        self.0.borrow_mut().show(projector, frame)
    }
}

impl DiffuseLight for SimDevices<'_, '_> {
    fn set_diffuse(&mut self, on: bool) -> Result<(), HwError> {
        self.0.borrow_mut().set_diffuse(on)
    }
}

fn capture_through_stream(stage: &VirtualStage, dir: &std::path::Path, acq: &AcquireConfig, honest: bool) {
    let sim = RefCell::new(SimRig::new(stage));
    let camera = StreamCamera::new(
        SimStream::new(&sim, 4, honest),
        stage.setup().camera.clone(),
        GrabConfig { average: 2, response: CameraResponse::Srgb },
    )
    .unwrap();
    let mut rig = Rig { camera, projectors: SimDevices(&sim), light: SimDevices(&sim) };
    acquire(&mut rig, &mut FakeClock::default(), acq, dir, "simulated v4l", &mut |_, _| {}).unwrap();
}

/// Fraction of the pixels decoded in `reference` that `other` decodes within 1 projector px.
fn agreement(reference: &[ProjectorDecode], other: &[ProjectorDecode]) -> f64 {
    let (mut both, mut total) = (0usize, 0usize);
    for (a, b) in reference.iter().zip(other) {
        for i in 0..a.x.len() {
            if a.is_valid(i) {
                total += 1;
                if b.is_valid(i) && (a.x[i] - b.x[i]).abs() <= 1.0 && (a.y[i] - b.y[i]).abs() <= 1.0 {
                    both += 1;
                }
            }
        }
    }
    both as f64 / total.max(1) as f64
}

#[test]
fn hardware_acquisition_loop_on_the_virtual_stage_matches_direct_capture() {
    let cfg = SceneConfig { projectors: 2, ..SceneConfig::tiny(SceneName::Jar, 5) };
    let stage = VirtualStage::new(&cfg).unwrap();
    let acq = AcquireConfig {
        dot_spacing: 2,
        ramp_levels: 3,
        phase_period: 8,
        phase_steps: 4,
        ..Default::default()
    };
    let params = DecodeParams::default();

    let direct = tempfile::tempdir().unwrap();
    let manifest = stage.write_capture_set(direct.path(), &acq, &mut |_, _| {}).unwrap();
    let reference = decode_capture(direct.path(), &manifest, &params, &mut |_| {}).unwrap();

    let streamed = tempfile::tempdir().unwrap();
    capture_through_stream(&stage, streamed.path(), &acq, true);
    let m = restage_authoring::capture_set::CaptureManifest::load(streamed.path()).unwrap();
    assert_eq!(m.projectors.len(), 2);
    assert_eq!(m.camera, stage.setup().camera);
    let ours = decode_capture(streamed.path(), &m, &params, &mut |_| {}).unwrap();
    let decoded: usize = reference.iter().map(|d| d.quality.decoded).sum();
    assert!(decoded > 1000, "the reference decodes too little to compare: {decoded}");
    let agree = agreement(&reference, &ours);
    assert!(agree > 0.97, "8-bit YUYV capture agrees with direct capture on only {:.1} %", agree * 100.0);

    // A camera that keeps the frames queued before each pattern change sees the previous
    // pattern: the same comparison then fails, so the check above means something.
    let stale = tempfile::tempdir().unwrap();
    capture_through_stream(&stage, stale.path(), &acq, false);
    let m = restage_authoring::capture_set::CaptureManifest::load(stale.path()).unwrap();
    let bad = decode_capture(stale.path(), &m, &params, &mut |_| {}).map(|d| agreement(&reference, &d));
    assert!(bad.as_ref().map_or(true, |&a| a < 0.5), "stale frames still agree: {bad:?}");
}
