//! A V4L2 camera (`/dev/videoN`) as a [`FrameSource`]: sets the size and pixel format the
//! calibration is for, locks exposure, white balance and gain so every pattern is seen
//! through the same camera, and streams memory-mapped buffers.

use std::path::{Path, PathBuf};

use v4l::buffer::Type;
use v4l::control::{Control, Value};
use v4l::io::mmap::Stream;
use v4l::io::traits::CaptureStream;
use v4l::video::Capture;
use v4l::{Device, FourCC};

use super::stream::{FrameSource, PixelFormat, RawFrame};
use crate::hw::HwError;

/// Control ids from `linux/v4l2-controls.h` (stable kernel ABI).
const CID_AUTO_WHITE_BALANCE: u32 = 0x0098_090c;
const CID_AUTOGAIN: u32 = 0x0098_0912;
const CID_EXPOSURE_AUTO: u32 = 0x009a_0901;
const CID_EXPOSURE_ABSOLUTE: u32 = 0x009a_0902;
/// `V4L2_EXPOSURE_MANUAL` for `CID_EXPOSURE_AUTO`.
const EXPOSURE_MANUAL: i64 = 1;
/// Buffers in the memory-mapped queue: each may hold a frame exposed before a pattern change.
const BUFFERS: u32 = 4;

/// What to ask of the camera.
#[derive(Clone, Debug)]
pub struct V4lSettings {
    pub width: u32,
    pub height: u32,
    /// Formats to try, best first.
    pub formats: Vec<PixelFormat>,
    /// Manual exposure in the driver's units (usually 100 µs); `None` keeps the current one
    /// but still switches automatic exposure off.
    pub exposure: Option<i64>,
}

/// An open V4L2 capture stream.
pub struct V4lSource {
    path: PathBuf,
    format: PixelFormat,
    width: u32,
    height: u32,
    stride: u32,
    // The stream maps the device's buffers; declared before the device so it drops first.
    stream: Stream<'static>,
    _device: Device,
}

impl std::fmt::Debug for V4lSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("V4lSource").field("path", &self.path).field("format", &self.format).finish()
    }
}

impl V4lSource {
    pub fn open(path: &Path, settings: &V4lSettings) -> Result<Self, HwError> {
        let name = path.display().to_string();
        let err = |problem: String| HwError::Device { device: name.clone(), problem };
        let device = Device::with_path(path).map_err(|e| err(format!("cannot open: {e}")))?;
        let caps = device.query_caps().map_err(|e| err(format!("not a V4L2 device: {e}")))?;
        tracing::info!("camera {name}: {} ({})", caps.card, caps.driver);

        let mut chosen = None;
        for &want in &settings.formats {
            let mut fmt = device.format().map_err(|e| err(format!("cannot read the format: {e}")))?;
            fmt.width = settings.width;
            fmt.height = settings.height;
            fmt.fourcc = FourCC::new(&want.fourcc());
            let got = device.set_format(&fmt).map_err(|e| err(format!("cannot set the format: {e}")))?;
            if got.fourcc.repr == want.fourcc()
                && (got.width, got.height) == (settings.width, settings.height)
            {
                chosen = Some((want, got.stride));
                break;
            }
            tracing::debug!("camera {name}: {want} at {}x{} refused", settings.width, settings.height);
        }
        let wanted: Vec<String> = settings.formats.iter().map(|f| f.to_string()).collect();
        let (format, stride) = chosen.ok_or_else(|| {
            err(format!(
                "cannot deliver {}x{} in any of {} (the camera calibration's size; check `v4l2-ctl --list-formats-ext`)",
                settings.width,
                settings.height,
                wanted.join(", ")
            ))
        })?;
        lock_exposure(&device, settings.exposure, &name)?;
        let stream = Stream::with_buffers(&device, Type::VideoCapture, BUFFERS)
            .map_err(|e| err(format!("cannot start streaming: {e}")))?;
        tracing::info!("camera {name}: {format} {}x{}, exposure locked", settings.width, settings.height);
        Ok(Self {
            path: path.into(),
            format,
            width: settings.width,
            height: settings.height,
            stride,
            stream,
            _device: device,
        })
    }
}

/// Switches automatic exposure, gain and white balance off so that images of different
/// patterns are comparable. Missing controls are fine (many cameras lack some); a camera
/// that refuses manual exposure is not.
fn lock_exposure(device: &Device, exposure: Option<i64>, name: &str) -> Result<(), HwError> {
    let set = |id: u32, value: Value| device.set_control(Control { id, value });
    if let Err(e) = set(CID_EXPOSURE_AUTO, Value::Integer(EXPOSURE_MANUAL)) {
        tracing::warn!(
            "camera {name}: cannot switch automatic exposure off ({e}); keep the scene's light constant"
        );
    }
    if let Some(value) = exposure {
        set(CID_EXPOSURE_ABSOLUTE, Value::Integer(value)).map_err(|e| HwError::Device {
            device: name.into(),
            problem: format!("cannot set exposure {value}: {e}"),
        })?;
    }
    for (id, what) in [(CID_AUTOGAIN, "automatic gain"), (CID_AUTO_WHITE_BALANCE, "automatic white balance")]
    {
        if let Err(e) = set(id, Value::Boolean(false)) {
            tracing::debug!("camera {name}: {what} not switched off ({e})");
        }
    }
    Ok(())
}

impl FrameSource for V4lSource {
    fn name(&self) -> String {
        self.path.display().to_string()
    }

    fn queued(&self) -> usize {
        BUFFERS as usize
    }

    fn next_frame(&mut self) -> Result<RawFrame, HwError> {
        let (buf, meta) = self.stream.next().map_err(|e| HwError::Device {
            device: self.path.display().to_string(),
            problem: format!("no frame: {e}"),
        })?;
        let used = (meta.bytesused as usize).min(buf.len());
        let bytes = match self.format.frame_len(self.width, self.height) {
            // Packed formats: drop the row padding, if the driver adds any.
            Some(len) => {
                let row = len / self.height as usize;
                let stride = (self.stride as usize).max(row);
                let mut packed = Vec::with_capacity(len);
                for y in 0..self.height as usize {
                    let start = y * stride;
                    packed.extend_from_slice(buf.get(start..(start + row).min(used)).unwrap_or(&[]));
                }
                packed
            }
            None => buf[..used].to_vec(),
        };
        Ok(RawFrame { width: self.width, height: self.height, format: self.format, bytes })
    }
}
