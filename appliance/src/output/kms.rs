//! DRM/KMS output for the stage machine: the appliance is DRM master of one card and drives
//! one connector per projector directly (no desktop), from double-buffered dumb buffers, all
//! heads in one atomic commit where the driver allows (legacy modeset and page flips
//! otherwise), with flip events and their vblank timestamps logged. Hot-plug: a HOTPLUG
//! uevent re-probes the connectors and a projector that came back is set up again.
//!
//! The decisions (connector map, mode choice, what to do after a hot-plug, pixel layout) are
//! pure functions below with unit tests; the emulated three-head test in
//! `tests/tests/kms_qemu.rs` runs the rest against a real kernel and virtio-gpu.

use std::collections::{HashMap, HashSet};
use std::fs::{File, OpenOptions};
use std::os::fd::{AsFd, BorrowedFd};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use drm::Device as _;
use drm::buffer::{Buffer as _, DrmFourcc};
use drm::control::dumbbuffer::DumbBuffer;
use drm::control::{
    AtomicCommitFlags, Device as _, Mode, ModeTypeFlags, PageFlipFlags, PlaneType, atomic, connector, crtc,
    framebuffer, plane, property,
};
use thiserror::Error;

use super::{FrameRef, Output, OutputError, check_frames};
use crate::clock::{monotonic_us, unix_us};
use crate::input::{InputEvent, InputSender};

/// How long to wait for the flip events of one commit. A real display flips within one
/// frame; the emulated machine (software CPU) can take far longer.
const FLIP_TIMEOUT: Duration = Duration::from_secs(2);
/// How often the connector states are read for drivers that send no HOTPLUG uevent.
const CONNECTOR_POLL: Duration = Duration::from_secs(1);

#[derive(Debug, Error)]
pub enum KmsError {
    #[error("cannot open: {0}")]
    Open(std::io::Error),
    #[error(
        "cannot become DRM master ({0}): another program drives this card (a display server, \
         a graphical login, or a second appliance); only one may drive the projectors"
    )]
    Master(std::io::Error),
    #[error("the card has no connector named {name:?} (it has: {available})")]
    UnknownConnector { name: String, available: String },
    #[error("connector {name} has nothing connected (is the projector on and plugged in?)")]
    NotConnected { name: String },
    #[error("no connector has anything connected (connectors: {available})")]
    NoneConnected { available: String },
    #[error("connector {name} is listed twice in output.connectors")]
    Duplicate { name: String },
    #[error("connector {connector} offers no {width}x{height} mode (it offers: {available})")]
    NoMode { connector: String, width: u32, height: u32, available: String },
    #[error("connector {connector}: no free CRTC can drive it")]
    NoCrtc { connector: String },
    #[error("connector {connector}: no primary plane for its CRTC")]
    NoPlane { connector: String },
    #[error("{what}: {source}")]
    Ioctl { what: String, source: std::io::Error },
    #[error("page flip: no completion event within {0:?}")]
    FlipTimeout(Duration),
}

fn ioctl(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> KmsError {
    let what = what.into();
    move |source| KmsError::Ioctl { what, source }
}

// ---------------------------------------------------------------------------------------
// Pure decisions (unit-tested).

/// A display mode as the decisions see it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ModeSummary {
    pub width: u32,
    pub height: u32,
    pub refresh_hz: u32,
    /// Asked for on the kernel command line (`video=NAME:WxH@60e`): the operator's choice.
    pub userdef: bool,
    /// The display's own preferred mode (EDID).
    pub preferred: bool,
}

impl ModeSummary {
    fn of(m: &Mode) -> ModeSummary {
        let (w, h) = m.size();
        ModeSummary {
            width: u32::from(w),
            height: u32::from(h),
            refresh_hz: m.vrefresh(),
            userdef: m.mode_type().contains(ModeTypeFlags::USERDEF),
            preferred: m.mode_type().contains(ModeTypeFlags::PREFERRED),
        }
    }
}

/// Index of the mode that shows `width x height` frames pixel for pixel: among the modes of
/// exactly that size, the operator's (USERDEF) first, then the display's preferred one, then
/// 60 Hz, then the first listed. `None` when no mode has that size (never scaled).
pub fn choose_mode(modes: &[ModeSummary], width: u32, height: u32) -> Option<usize> {
    modes
        .iter()
        .enumerate()
        .filter(|(_, m)| m.width == width && m.height == height)
        .max_by_key(|&(i, m)| (m.userdef, m.preferred, m.refresh_hz == 60, std::cmp::Reverse(i)))
        .map(|(i, _)| i)
}

/// A connector as the map sees it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ConnectorSummary {
    /// Kernel name, e.g. `HDMI-A-1`, `DP-2`, `Virtual-3`.
    pub name: String,
    pub connected: bool,
}

/// The connector index of every projector: by name in the configured order (connected now or
/// not), or, with no names configured, every connected connector in the card's order.
pub fn map_connectors(wanted: &[String], available: &[ConnectorSummary]) -> Result<Vec<usize>, KmsError> {
    let names = || available.iter().map(|c| c.name.as_str()).collect::<Vec<_>>().join(", ");
    if wanted.is_empty() {
        let out: Vec<usize> = (0..available.len()).filter(|&i| available[i].connected).collect();
        if out.is_empty() {
            return Err(KmsError::NoneConnected { available: names() });
        }
        return Ok(out);
    }
    let mut seen = HashSet::new();
    wanted
        .iter()
        .map(|name| {
            if !seen.insert(name.as_str()) {
                return Err(KmsError::Duplicate { name: name.clone() });
            }
            // A named connector with nothing connected is kept: its projector may be off or
            // unplugged now and is set up when it appears (refusing would turn a projector
            // off at boot into a service that never starts).
            available
                .iter()
                .position(|c| c.name == *name)
                .ok_or_else(|| KmsError::UnknownConnector { name: name.clone(), available: names() })
        })
        .collect()
}

/// What a re-probe found for one projector's head.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HeadProbe {
    /// The head is set up and showing our buffers (as far as we know).
    pub up: bool,
    /// Its connector reports something connected.
    pub connected: bool,
    /// The connector (still) offers a mode of the bundle's frame size.
    pub offers_mode: bool,
    /// The CRTC scans out one of our buffers (false when the kernel or another client reset it).
    pub crtc_ours: bool,
}

/// What to do with one head after a hot-plug event.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HeadAction {
    /// Showing and fine: leave it alone (no flicker on the other heads' events).
    Keep,
    /// Gone (unplugged, or cannot show the frame size any more): switch its CRTC off.
    Lost,
    /// Present and usable but not showing our buffers (came back, or was reset): set it up
    /// again with the current frame.
    Restore,
    /// Still gone: nothing to do.
    StillGone,
}

/// The re-set-up decision for every head (pure: the hot-plug handler's only policy).
pub fn plan_hotplug(heads: &[HeadProbe]) -> Vec<HeadAction> {
    heads
        .iter()
        .map(|h| match (h.connected && h.offers_mode, h.up) {
            (true, true) if h.crtc_ours => HeadAction::Keep,
            (true, _) => HeadAction::Restore,
            (false, true) => HeadAction::Lost,
            (false, false) => HeadAction::StillGone,
        })
        .collect()
}

/// Copies a bundle frame (XRGB8888 little-endian, `width * 4` bytes a row) into a scan-out
/// buffer with `pitch` bytes a row; the unused X byte is written as 0. `None` copies black.
/// Rows beyond the frame and bytes beyond each row's pixels are left as they are.
pub fn copy_to_scanout(frame: Option<&FrameRef<'_>>, width: u32, height: u32, dst: &mut [u8], pitch: usize) {
    let row = width as usize * 4;
    for y in 0..height as usize {
        let Some(out) = dst.get_mut(y * pitch..y * pitch + row) else { return };
        match frame {
            Some(f) => {
                let src = &f.xrgb[y * row..(y + 1) * row];
                for (o, s) in out.chunks_exact_mut(4).zip(src.chunks_exact(4)) {
                    o[..3].copy_from_slice(&s[..3]);
                    o[3] = 0;
                }
            }
            None => out.fill(0),
        }
    }
}

/// The RGB8 picture a scan-out of this XRGB8888 frame shows (what a screen grab returns).
pub fn xrgb8888_to_rgb8(xrgb: &[u8]) -> Vec<u8> {
    xrgb.chunks_exact(4).flat_map(|p| [p[2], p[1], p[0]]).collect()
}

/// A short fingerprint of a frame's picture (the R, G, B bytes of every 61st pixel, FNV-1a):
/// logged with each presented frame so that a test watching the log knows which picture
/// was lit (tests/tests/power_qemu.rs).
pub fn frame_fingerprint(xrgb: &[u8]) -> u32 {
    let mut h: u32 = 0x811c_9dc5;
    for p in xrgb.chunks_exact(4).step_by(61) {
        for &b in &p[..3] {
            h = (h ^ u32::from(b)).wrapping_mul(0x0100_0193);
        }
    }
    h
}

// ---------------------------------------------------------------------------------------
// The device.

#[derive(Debug)]
struct Card(File);

impl AsFd for Card {
    fn as_fd(&self) -> BorrowedFd<'_> {
        self.0.as_fd()
    }
}
impl drm::Device for Card {}
impl drm::control::Device for Card {}

#[derive(Debug)]
struct Buf {
    db: DumbBuffer,
    fb: framebuffer::Handle,
}

/// Atomic property handles of one head's objects, by name.
#[derive(Debug, Default)]
struct Props {
    conn: HashMap<String, property::Handle>,
    crtc: HashMap<String, property::Handle>,
    plane: HashMap<String, property::Handle>,
}

#[derive(Debug)]
struct Head {
    name: String,
    conn: connector::Handle,
    crtc: crtc::Handle,
    plane: Option<plane::Handle>,
    props: Props,
    mode: Option<Mode>,
    blob: Option<u64>,
    bufs: Vec<Buf>,
    front: usize,
    /// Set up and scanning out our buffers.
    up: bool,
    /// The next commit must set the mode (first use, or after a hot-plug).
    modeset: bool,
}

/// The DRM/KMS output.
#[derive(Debug)]
pub struct KmsOutput {
    card: Card,
    path: PathBuf,
    atomic: bool,
    heads: Vec<Head>,
    sizes: Option<Vec<(u32, u32)>>,
    first_light: bool,
}

fn connector_name(info: &connector::Info) -> String {
    format!("{}-{}", info.interface().as_str(), info.interface_id())
}

impl KmsOutput {
    /// Opens `card`, becomes its DRM master and routes one CRTC to each projector's connector
    /// (`connectors` by name, or every connected one in order when empty). Atomic modesetting
    /// is used when `atomic` is true and the driver offers it. HOTPLUG uevents are announced
    /// on `events` as `InputEvent::OutputsChanged` (the event loop then calls `reprobe`).
    pub fn open(
        card: &Path,
        connectors: &[String],
        atomic: bool,
        events: Option<InputSender>,
    ) -> Result<KmsOutput, OutputError> {
        let dev = |e: KmsError| OutputError::Device {
            output: format!("kms {}", card.display()),
            problem: e.to_string(),
        };
        let file =
            OpenOptions::new().read(true).write(true).open(card).map_err(|e| dev(KmsError::Open(e)))?;
        let c = Card(file);
        c.acquire_master_lock().map_err(|e| dev(KmsError::Master(e)))?;
        let atomic = atomic
            && c.set_client_capability(drm::ClientCapability::UniversalPlanes, true).is_ok()
            && c.set_client_capability(drm::ClientCapability::Atomic, true).is_ok();
        let heads = route(&c, connectors, atomic).map_err(dev)?;
        tracing::info!(
            card = %card.display(),
            atomic,
            heads = ?heads.iter().map(|h| h.name.as_str()).collect::<Vec<_>>(),
            "DRM master; projectors mapped to connectors"
        );
        if let Some(tx) = events {
            start_hotplug_listener(tx.clone());
            start_connector_poll(card, heads.iter().map(|h| h.conn).collect(), tx);
        }
        Ok(KmsOutput { card: c, path: card.to_path_buf(), atomic, heads, sizes: None, first_light: false })
    }

    fn err(&self, e: KmsError) -> OutputError {
        OutputError::Device { output: format!("kms {}", self.path.display()), problem: e.to_string() }
    }

    /// Names of the connectors driven, in projector order.
    pub fn connector_names(&self) -> Vec<String> {
        self.heads.iter().map(|h| h.name.clone()).collect()
    }

    fn free_buffers(&mut self, k: usize) {
        let h = &mut self.heads[k];
        for b in h.bufs.drain(..) {
            let _ = self.card.destroy_framebuffer(b.fb);
            let _ = self.card.destroy_dumb_buffer(b.db);
        }
        if let Some(blob) = h.blob.take() {
            let _ = self.card.destroy_property_blob(blob);
        }
    }

    /// Finds the mode of `size` on head `k`'s connector and makes its two scan-out buffers.
    /// The mode head `k` shows `w x h` frames in, or why it cannot.
    fn find_mode(&self, k: usize, (w, h): (u32, u32), probe: bool) -> Result<Mode, KmsError> {
        let info = self.card.get_connector(self.heads[k].conn, probe).map_err(ioctl("get connector"))?;
        let name = self.heads[k].name.clone();
        if info.state() != connector::State::Connected {
            return Err(KmsError::NotConnected { name });
        }
        let summaries: Vec<ModeSummary> = info.modes().iter().map(ModeSummary::of).collect();
        let i = choose_mode(&summaries, w, h).ok_or_else(|| {
            let mut offered: Vec<String> =
                summaries.iter().map(|m| format!("{}x{}@{}", m.width, m.height, m.refresh_hz)).collect();
            offered.dedup();
            KmsError::NoMode { connector: name.clone(), width: w, height: h, available: offered.join(", ") }
        })?;
        Ok(info.modes()[i])
    }

    /// Makes head `k`'s two scan-out buffers for `w x h` frames. Buffers of that size are
    /// kept: a projector set up again after a hot-plug shows what its front buffer holds, the
    /// current frame, written there while it was gone.
    fn ensure_buffers(&mut self, k: usize, (w, h): (u32, u32)) -> Result<(), KmsError> {
        if self.heads[k].bufs.first().is_some_and(|b| b.db.size() == (w, h)) {
            return Ok(());
        }
        self.free_buffers(k);
        let name = self.heads[k].name.clone();
        let mut bufs = Vec::new();
        for _ in 0..2 {
            let mut db = self
                .card
                .create_dumb_buffer((w, h), DrmFourcc::Xrgb8888, 32)
                .map_err(ioctl(format!("{name}: create {w}x{h} dumb buffer")))?;
            {
                let mut map = self.card.map_dumb_buffer(&mut db).map_err(ioctl("map dumb buffer"))?;
                map.as_mut().fill(0);
            }
            let fb = self.card.add_framebuffer(&db, 24, 32).map_err(ioctl("add framebuffer"))?;
            bufs.push(Buf { db, fb });
        }
        self.heads[k].bufs = bufs;
        self.heads[k].front = 0;
        Ok(())
    }

    /// Chooses head `k`'s mode for `size` and readies it for a modeset on the next commit.
    fn prepare(&mut self, k: usize, size: (u32, u32), probe: bool) -> Result<(), KmsError> {
        let mode = self.find_mode(k, size, probe)?;
        self.ensure_buffers(k, size)?;
        if let Some(blob) = self.heads[k].blob.take() {
            let _ = self.card.destroy_property_blob(blob);
        }
        let blob = if self.atomic {
            match self.card.create_property_blob(&mode).map_err(ioctl("mode blob"))? {
                property::Value::Blob(b) => Some(b),
                _ => None,
            }
        } else {
            None
        };
        let head = &mut self.heads[k];
        head.mode = Some(mode);
        head.blob = blob;
        head.modeset = true;
        head.up = true;
        tracing::info!(connector = %head.name, mode = ?ModeSummary::of(&mode), "projector mode chosen");
        Ok(())
    }

    /// Writes `frames` (None = black) into the back buffers of the heads that are up, then
    /// shows them all together and waits for the flips.
    fn present(&mut self, frames: Option<&[FrameRef<'_>]>) -> Result<(), KmsError> {
        let sizes = self.sizes.clone().unwrap_or_default();
        let live: Vec<usize> =
            (0..self.heads.len()).filter(|&k| self.heads[k].up && !self.heads[k].bufs.is_empty()).collect();
        let with_buffers: Vec<usize> =
            (0..self.heads.len()).filter(|&k| !self.heads[k].bufs.is_empty()).collect();
        for k in with_buffers {
            let (w, h) = sizes[k];
            // A head that is up gets the frame in its back buffer (flipped below); one that
            // is gone gets it in its front buffer, shown as soon as it is set up again.
            let back = if self.heads[k].up { 1 - self.heads[k].front } else { self.heads[k].front };
            let head = &mut self.heads[k];
            let pitch = head.bufs[back].db.pitch() as usize;
            let mut map =
                self.card.map_dumb_buffer(&mut head.bufs[back].db).map_err(ioctl("map dumb buffer"))?;
            copy_to_scanout(frames.map(|f| &f[k]), w, h, map.as_mut(), pitch);
        }
        let lit =
            frames.is_some_and(|f| f.iter().any(|f| f.xrgb.chunks_exact(4).any(|p| p[..3] != [0, 0, 0])));
        // Before the commit, what may be lit from now on and the wall clock: the picture can
        // show before the flip completes (a power cut may come in between).
        if tracing::enabled!(tracing::Level::DEBUG) {
            let prints: Vec<String> = match frames {
                Some(f) => f.iter().map(|f| format!("{:08x}", frame_fingerprint(f.xrgb))).collect(),
                None => vec!["black".into()],
            };
            tracing::debug!(unix_us = unix_us(), lit, frames = %prints.join(","), "presenting");
        }
        let commit_us = monotonic_us();
        let flips = self.commit(&live, true)?;
        let flip_us = self.wait_flips(flips)?;
        for &k in &live {
            let head = &mut self.heads[k];
            head.front = 1 - head.front;
            head.modeset = false;
        }
        tracing::info!(
            commit_mono_us = commit_us,
            flip_mono_us = flip_us,
            unix_us = unix_us(),
            heads = live.len(),
            lit,
            "page flip complete"
        );
        if lit && !self.first_light {
            self.first_light = true;
            tracing::info!(flip_mono_us = flip_us, "first light");
        }
        Ok(())
    }

    /// Commits heads `ks` (their back buffer when `back`, else their front one), one atomic
    /// commit for all; returns the CRTCs whose flip events are awaited.
    fn commit(&self, ks: &[usize], back: bool) -> Result<Vec<crtc::Handle>, KmsError> {
        if ks.is_empty() {
            return Ok(Vec::new());
        }
        let fb = |h: &Head| h.bufs[if back { 1 - h.front } else { h.front }].fb;
        if self.atomic {
            let mut req = atomic::AtomicModeReq::new();
            let mut modeset = false;
            for &k in ks {
                let h = &self.heads[k];
                let prop = |m: &HashMap<String, property::Handle>, n: &str| {
                    m.get(n).copied().ok_or_else(|| KmsError::Ioctl {
                        what: format!("{}: property {n}", h.name),
                        source: std::io::Error::from(std::io::ErrorKind::NotFound),
                    })
                };
                let plane = h.plane.ok_or_else(|| KmsError::NoPlane { connector: h.name.clone() })?;
                let (w, hh) = h.mode.map(|m| m.size()).unwrap_or((0, 0));
                if h.modeset {
                    modeset = true;
                    req.add_property(
                        h.conn,
                        prop(&h.props.conn, "CRTC_ID")?,
                        property::Value::CRTC(Some(h.crtc)),
                    );
                    req.add_property(
                        h.crtc,
                        prop(&h.props.crtc, "MODE_ID")?,
                        property::Value::Blob(h.blob.unwrap_or(0)),
                    );
                    req.add_property(h.crtc, prop(&h.props.crtc, "ACTIVE")?, property::Value::Boolean(true));
                }
                let p = &h.props.plane;
                req.add_property(plane, prop(p, "FB_ID")?, property::Value::Framebuffer(Some(fb(h))));
                req.add_property(plane, prop(p, "CRTC_ID")?, property::Value::CRTC(Some(h.crtc)));
                req.add_property(plane, prop(p, "SRC_X")?, property::Value::UnsignedRange(0));
                req.add_property(plane, prop(p, "SRC_Y")?, property::Value::UnsignedRange(0));
                req.add_property(
                    plane,
                    prop(p, "SRC_W")?,
                    property::Value::UnsignedRange(u64::from(w) << 16),
                );
                req.add_property(
                    plane,
                    prop(p, "SRC_H")?,
                    property::Value::UnsignedRange(u64::from(hh) << 16),
                );
                req.add_property(plane, prop(p, "CRTC_X")?, property::Value::SignedRange(0));
                req.add_property(plane, prop(p, "CRTC_Y")?, property::Value::SignedRange(0));
                req.add_property(plane, prop(p, "CRTC_W")?, property::Value::UnsignedRange(u64::from(w)));
                req.add_property(plane, prop(p, "CRTC_H")?, property::Value::UnsignedRange(u64::from(hh)));
            }
            let mut flags = AtomicCommitFlags::PAGE_FLIP_EVENT;
            if modeset {
                flags |= AtomicCommitFlags::ALLOW_MODESET;
            }
            self.card.atomic_commit(flags, req).map_err(ioctl("atomic commit"))?;
            Ok(ks.iter().map(|&k| self.heads[k].crtc).collect())
        } else {
            let mut flips = Vec::new();
            for &k in ks {
                let h = &self.heads[k];
                if h.modeset || !back {
                    // A modeset is synchronous and has no event.
                    self.card
                        .set_crtc(h.crtc, Some(fb(h)), (0, 0), &[h.conn], h.mode)
                        .map_err(ioctl(format!("{}: set CRTC", h.name)))?;
                } else {
                    self.card
                        .page_flip(h.crtc, fb(h), PageFlipFlags::EVENT, None)
                        .map_err(ioctl(format!("{}: page flip", h.name)))?;
                    flips.push(h.crtc);
                }
            }
            Ok(flips)
        }
    }

    /// Waits for a flip event of every CRTC in `crtcs`; returns the latest event timestamp
    /// (CLOCK_MONOTONIC, us), or now when nothing was awaited (synchronous modeset).
    fn wait_flips(&self, crtcs: Vec<crtc::Handle>) -> Result<u64, KmsError> {
        let mut pending: HashSet<crtc::Handle> = crtcs.into_iter().collect();
        let mut latest = 0u64;
        let start = Instant::now();
        while !pending.is_empty() {
            let left = FLIP_TIMEOUT.saturating_sub(start.elapsed());
            if left.is_zero() {
                return Err(KmsError::FlipTimeout(FLIP_TIMEOUT));
            }
            let mut fds = [nix::poll::PollFd::new(self.card.as_fd(), nix::poll::PollFlags::POLLIN)];
            let ms = u16::try_from(left.as_millis().max(1)).unwrap_or(u16::MAX);
            match nix::poll::poll(&mut fds, nix::poll::PollTimeout::from(ms)) {
                Ok(0) => continue,
                Ok(_) => {}
                Err(nix::errno::Errno::EINTR) => continue,
                Err(e) => return Err(KmsError::Ioctl { what: "poll card".into(), source: e.into() }),
            }
            for ev in self.card.receive_events().map_err(ioctl("read events"))? {
                if let drm::control::Event::PageFlip(f) = ev {
                    pending.remove(&f.crtc);
                    latest = latest.max(f.duration.as_micros() as u64);
                }
            }
        }
        Ok(if latest == 0 { monotonic_us() } else { latest })
    }

    /// Switches head `k`'s CRTC off (a lost projector, or dark before any mode is known).
    fn disable(&mut self, ks: &[usize]) -> Result<(), KmsError> {
        if ks.is_empty() {
            return Ok(());
        }
        if self.atomic {
            let mut req = atomic::AtomicModeReq::new();
            for &k in ks {
                let h = &self.heads[k];
                let get = |m: &HashMap<String, property::Handle>, n: &str| m.get(n).copied();
                if let Some(p) = get(&h.props.conn, "CRTC_ID") {
                    req.add_property(h.conn, p, property::Value::CRTC(None));
                }
                if let Some(p) = get(&h.props.crtc, "ACTIVE") {
                    req.add_property(h.crtc, p, property::Value::Boolean(false));
                }
                if let Some(p) = get(&h.props.crtc, "MODE_ID") {
                    req.add_property(h.crtc, p, property::Value::Blob(0));
                }
                if let Some(plane) = h.plane {
                    if let Some(p) = get(&h.props.plane, "FB_ID") {
                        req.add_property(plane, p, property::Value::Framebuffer(None));
                    }
                    if let Some(p) = get(&h.props.plane, "CRTC_ID") {
                        req.add_property(plane, p, property::Value::CRTC(None));
                    }
                }
            }
            self.card
                .atomic_commit(AtomicCommitFlags::ALLOW_MODESET, req)
                .map_err(ioctl("atomic commit (off)"))?;
        } else {
            for &k in ks {
                let h = &self.heads[k];
                self.card
                    .set_crtc(h.crtc, None, (0, 0), &[], None)
                    .map_err(ioctl(format!("{}: CRTC off", h.name)))?;
            }
        }
        for &k in ks {
            self.heads[k].up = false;
            self.heads[k].modeset = true;
        }
        Ok(())
    }

    /// Re-probes every projector's connector (after a HOTPLUG uevent) and acts on
    /// `plan_hotplug`: lost heads are switched off, heads that came back are set up again
    /// with the frame they should show, the others are left alone.
    fn reprobe_heads(&mut self) -> Result<(), KmsError> {
        let Some(sizes) = self.sizes.clone() else { return Ok(()) };
        let mut probes = Vec::new();
        for (k, h) in self.heads.iter().enumerate() {
            let info = self.card.get_connector(h.conn, true).map_err(ioctl("get connector"))?;
            let modes: Vec<ModeSummary> = info.modes().iter().map(ModeSummary::of).collect();
            let crtc = self.card.get_crtc(h.crtc).map_err(ioctl("get CRTC"))?;
            probes.push(HeadProbe {
                up: h.up,
                connected: info.state() == connector::State::Connected,
                offers_mode: choose_mode(&modes, sizes[k].0, sizes[k].1).is_some(),
                crtc_ours: crtc.framebuffer().is_some_and(|fb| h.bufs.iter().any(|b| b.fb == fb)),
            });
        }
        let plan = plan_hotplug(&probes);
        tracing::info!(?plan, "hot-plug: connectors re-probed");
        let lost: Vec<usize> = (0..plan.len()).filter(|&k| plan[k] == HeadAction::Lost).collect();
        self.disable(&lost)?;
        for &k in &lost {
            tracing::warn!(connector = %self.heads[k].name, "projector lost; its output is off until it returns");
        }
        let mut restored = Vec::new();
        for k in (0..plan.len()).filter(|&k| plan[k] == HeadAction::Restore) {
            // The front buffer (kept) holds what this head should show now.
            self.prepare(k, sizes[k], false)?;
            restored.push(k);
        }
        if !restored.is_empty() {
            let flips = self.commit(&restored, false)?;
            let flip_us = self.wait_flips(flips)?;
            for &k in &restored {
                self.heads[k].modeset = false;
                tracing::info!(connector = %self.heads[k].name, flip_mono_us = flip_us, "projector set up again after hot-plug");
            }
        }
        Ok(())
    }
}

/// Finds every projector's connector and gives each a CRTC (and, for atomic, its primary
/// plane and property handles).
fn route(card: &Card, wanted: &[String], atomic: bool) -> Result<Vec<Head>, KmsError> {
    let res = card.resource_handles().map_err(ioctl("get resources"))?;
    let mut infos = Vec::new();
    for &c in res.connectors() {
        // A forced probe at start: the connector state may be stale otherwise.
        infos.push(card.get_connector(c, true).map_err(ioctl("get connector"))?);
    }
    let summaries: Vec<ConnectorSummary> = infos
        .iter()
        .map(|i| ConnectorSummary {
            name: connector_name(i),
            connected: i.state() == connector::State::Connected,
        })
        .collect();
    let map = map_connectors(wanted, &summaries)?;
    let planes = if atomic { card.plane_handles().map_err(ioctl("get planes"))? } else { Vec::new() };
    let mut used_crtcs = HashSet::new();
    let mut used_planes = HashSet::new();
    let mut heads = Vec::new();
    for i in map {
        let info = &infos[i];
        let name = summaries[i].name.clone();
        let mut chosen = None;
        // The connector's current CRTC first (no needless reshuffle), then any possible one.
        let current = info.current_encoder().and_then(|e| card.get_encoder(e).ok()).and_then(|e| e.crtc());
        let mut candidates: Vec<crtc::Handle> = current.into_iter().collect();
        for &e in info.encoders() {
            if let Ok(enc) = card.get_encoder(e) {
                candidates.extend(res.filter_crtcs(enc.possible_crtcs()));
            }
        }
        for c in candidates {
            if !used_crtcs.contains(&c) {
                chosen = Some(c);
                break;
            }
        }
        let crtc = chosen.ok_or_else(|| KmsError::NoCrtc { connector: name.clone() })?;
        used_crtcs.insert(crtc);
        let mut props = Props::default();
        let mut plane = None;
        if atomic {
            for &p in &planes {
                if used_planes.contains(&p) {
                    continue;
                }
                let Ok(pi) = card.get_plane(p) else { continue };
                if !res.filter_crtcs(pi.possible_crtcs()).contains(&crtc) {
                    continue;
                }
                let pprops = named_props(card, p)?;
                let primary = card.get_properties(p).ok().is_some_and(|set| {
                    set.iter().any(|(id, val)| {
                        pprops.get("type") == Some(id) && *val == u64::from(PlaneType::Primary as u32)
                    })
                });
                if primary {
                    plane = Some(p);
                    props.plane = pprops;
                    break;
                }
            }
            let p = plane.ok_or_else(|| KmsError::NoPlane { connector: name.clone() })?;
            used_planes.insert(p);
            props.conn = named_props(card, info.handle())?;
            props.crtc = named_props(card, crtc)?;
        }
        heads.push(Head {
            name,
            conn: info.handle(),
            crtc,
            plane,
            props,
            mode: None,
            blob: None,
            bufs: Vec::new(),
            front: 0,
            up: false,
            modeset: true,
        });
    }
    Ok(heads)
}

fn named_props<H: drm::control::ResourceHandle>(
    card: &Card,
    h: H,
) -> Result<HashMap<String, property::Handle>, KmsError> {
    let set = card.get_properties(h).map_err(ioctl("get properties"))?;
    let map = set.as_hashmap(card).map_err(ioctl("get property"))?;
    Ok(map.into_iter().map(|(k, v)| (k, v.handle())).collect())
}

impl Output for KmsOutput {
    fn projector_count(&self) -> usize {
        self.heads.len()
    }

    fn set_modes(&mut self, sizes: &[(u32, u32)]) -> Result<(), OutputError> {
        if sizes.len() != self.heads.len() {
            return Err(OutputError::FrameCount { expected: self.heads.len(), got: sizes.len() });
        }
        if self.sizes.as_deref() == Some(sizes) && self.heads.iter().all(|h| !h.bufs.is_empty()) {
            return Ok(());
        }
        // Every connected projector must be able to show its frames before anything changes:
        // a bundle the stage cannot show is refused with the current picture left as it is.
        // A projector with nothing connected (off, unplugged) cannot be asked; it is set up
        // when it appears, like one that comes back after a hot-plug.
        let mut missing = vec![false; sizes.len()];
        for (k, &size) in sizes.iter().enumerate() {
            match self.find_mode(k, size, false) {
                Ok(_) => {}
                Err(KmsError::NotConnected { .. }) => missing[k] = true,
                Err(e) => return Err(self.err(e)),
            }
        }
        self.sizes = Some(sizes.to_vec());
        for (k, &size) in sizes.iter().enumerate() {
            let done = if missing[k] {
                tracing::warn!(connector = %self.heads[k].name, "projector not connected; it is set up when it appears");
                self.heads[k].up = false;
                self.heads[k].modeset = true;
                self.ensure_buffers(k, size)
            } else {
                self.prepare(k, size, false)
            };
            if let Err(e) = done {
                self.sizes = None;
                return Err(self.err(e));
            }
        }
        Ok(())
    }

    fn show(&mut self, frames: &[FrameRef<'_>]) -> Result<(), OutputError> {
        check_frames(self.heads.len(), self.sizes.as_deref(), frames)?;
        if self.sizes.is_none() {
            let sizes: Vec<(u32, u32)> = frames.iter().map(|f| (f.width, f.height)).collect();
            self.set_modes(&sizes)?;
        }
        self.present(Some(frames)).map_err(|e| self.err(e))
    }

    fn blank(&mut self) -> Result<(), OutputError> {
        if self.sizes.is_none() {
            // No mode yet: dark by switching the heads off (whatever showed there before).
            let all: Vec<usize> = (0..self.heads.len()).collect();
            return self.disable(&all).map_err(|e| self.err(e));
        }
        self.present(None).map_err(|e| self.err(e))
    }

    fn reprobe(&mut self) -> Result<(), OutputError> {
        self.reprobe_heads().map_err(|e| self.err(e))
    }
}

impl Drop for KmsOutput {
    fn drop(&mut self) {
        // Dark before the card closes (the kernel then restores its console framebuffer,
        // which the documented `fbcon=map:9` keeps black).
        let dark = if self.sizes.is_some() { self.present(None) } else { Ok(()) };
        if let Err(e) = dark {
            tracing::error!(%e, "could not blank the projectors on exit");
        }
        for k in 0..self.heads.len() {
            self.free_buffers(k);
        }
        let _ = self.card.release_master_lock();
    }
}

/// Listens for kernel uevents and announces DRM change (HOTPLUG) ones to the event loop. Runs on its
/// own thread for the program's life; without the socket (no permission) hot-plug is off.
fn start_hotplug_listener(tx: InputSender) {
    use nix::sys::socket::{
        AddressFamily, MsgFlags, NetlinkAddr, SockFlag, SockProtocol, SockType, bind, recv, socket,
    };
    use std::os::fd::AsRawFd;
    let sock = match socket(
        AddressFamily::Netlink,
        SockType::Datagram,
        SockFlag::SOCK_CLOEXEC,
        SockProtocol::NetlinkKObjectUEvent,
    ) {
        Ok(s) => s,
        Err(e) => {
            tracing::warn!(%e, "no uevent socket: hot-plug is noticed by the connector-state watch only");
            return;
        }
    };
    // Group 1: the kernel's own uevents.
    if let Err(e) = bind(sock.as_raw_fd(), &NetlinkAddr::new(0, 1)) {
        tracing::warn!(%e, "cannot bind the uevent socket: hot-plug is noticed by the connector-state watch only");
        return;
    }
    std::thread::spawn(move || {
        let mut buf = vec![0u8; 8192];
        loop {
            let n = match recv(sock.as_raw_fd(), &mut buf, MsgFlags::empty()) {
                Ok(n) => n,
                Err(nix::errno::Errno::EINTR | nix::errno::Errno::ENOBUFS) => continue,
                Err(e) => {
                    tracing::warn!(%e, "uevent socket failed: hot-plug is noticed by the connector-state watch only");
                    return;
                }
            };
            if is_drm_hotplug(&buf[..n]) {
                tracing::info!("DRM change uevent (hot-plug)");
                if tx.blocking_send(InputEvent::OutputsChanged).is_err() {
                    return;
                }
            }
        }
    });
}

/// Watches the projectors' connector states from a second (non-master) handle on the card
/// and announces changes like a HOTPLUG uevent: some drivers (virtio-gpu among them) change a
/// connector's state without sending one. Reads the kernel's cached state (no forced probe),
/// so it costs one cheap ioctl per connector and `CONNECTOR_POLL`.
fn start_connector_poll(path: &Path, conns: Vec<connector::Handle>, tx: InputSender) {
    let file = match OpenOptions::new().read(true).write(true).open(path) {
        Ok(f) => Card(f),
        Err(e) => {
            tracing::warn!(%e, "cannot watch connector states: only HOTPLUG uevents will be noticed");
            return;
        }
    };
    std::thread::spawn(move || {
        let state = |c: &Card| -> Vec<Option<connector::State>> {
            conns.iter().map(|&h| c.get_connector(h, false).ok().map(|i| i.state())).collect()
        };
        let mut last = state(&file);
        loop {
            std::thread::sleep(CONNECTOR_POLL);
            let now = state(&file);
            if now != last {
                tracing::info!(?now, "connector state changed");
                last = now;
                if tx.blocking_send(InputEvent::OutputsChanged).is_err() {
                    return;
                }
            }
        }
    });
}

/// Whether a kernel uevent (a `ACTION@DEVPATH` header, then NUL-separated `KEY=VALUE`
/// fields) asks for a re-probe: a DRM `change` event. That is the drivers' HOTPLUG=1 event,
/// and also what an operator's `udevadm trigger --action=change --subsystem-match=drm` (or a
/// write to the card's sysfs `uevent`) sends; re-probing is idempotent, so any of them is
/// worth one.
pub fn is_drm_hotplug(msg: &[u8]) -> bool {
    let fields: Vec<&[u8]> = msg.split(|&b| b == 0).collect();
    fields.contains(&&b"SUBSYSTEM=drm"[..]) && fields.contains(&&b"ACTION=change"[..])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn m(width: u32, height: u32, refresh_hz: u32, userdef: bool, preferred: bool) -> ModeSummary {
        ModeSummary { width, height, refresh_hz, userdef, preferred }
    }

    #[test]
    fn mode_choice_prefers_userdef_then_preferred_and_never_scales() {
        // What a forced virtio-gpu head lists: a huge first mode, the asked one USERDEF.
        let forced =
            [m(5120, 2160, 50, false, false), m(640, 480, 75, false, false), m(640, 480, 60, true, false)];
        assert_eq!(choose_mode(&forced, 640, 480), Some(2));
        let edid =
            [m(1920, 1080, 60, false, true), m(1920, 1080, 50, false, false), m(1280, 720, 60, false, false)];
        assert_eq!(choose_mode(&edid, 1920, 1080), Some(0));
        let no_flags = [m(1400, 1050, 75, false, false), m(1400, 1050, 60, false, false)];
        assert_eq!(choose_mode(&no_flags, 1400, 1050), Some(1));
        assert_eq!(choose_mode(&edid, 1400, 1050), None);
        assert_eq!(choose_mode(&[], 640, 480), None);
    }

    fn c(name: &str, connected: bool) -> ConnectorSummary {
        ConnectorSummary { name: name.into(), connected }
    }

    #[test]
    fn connectors_map_by_name_or_in_order() {
        let card = [c("Virtual-1", true), c("Virtual-2", false), c("Virtual-3", true)];
        assert_eq!(map_connectors(&[], &card).unwrap(), vec![0, 2]);
        let names = |n: &[&str]| n.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert_eq!(map_connectors(&names(&["Virtual-3", "Virtual-1"]), &card).unwrap(), vec![2, 0]);
        let e = map_connectors(&names(&["HDMI-A-1"]), &card).unwrap_err().to_string();
        assert!(e.contains("HDMI-A-1") && e.contains("Virtual-1, Virtual-2, Virtual-3"), "{e}");
        // Named but nothing connected now: kept (set up when it appears).
        assert_eq!(map_connectors(&names(&["Virtual-2", "Virtual-1"]), &card).unwrap(), vec![1, 0]);
        let e = map_connectors(&names(&["Virtual-1", "Virtual-1"]), &card).unwrap_err().to_string();
        assert!(e.contains("twice"), "{e}");
        assert!(matches!(map_connectors(&[], &[c("DP-1", false)]), Err(KmsError::NoneConnected { .. })));
    }

    fn p(up: bool, connected: bool, offers_mode: bool, crtc_ours: bool) -> HeadProbe {
        HeadProbe { up, connected, offers_mode, crtc_ours }
    }

    #[test]
    fn hotplug_plan_restores_returning_projectors_and_leaves_the_others() {
        use HeadAction::*;
        // Three heads: fine, unplugged, plugged back in.
        let plan = plan_hotplug(&[
            p(true, true, true, true),
            p(true, false, false, true),
            p(false, true, true, false),
        ]);
        assert_eq!(plan, vec![Keep, Lost, Restore]);
        // A head reset behind our back (CRTC no longer ours) is set up again.
        assert_eq!(plan_hotplug(&[p(true, true, true, false)]), vec![Restore]);
        // A projector that came back unable to show the frame size stays off; one still gone too.
        assert_eq!(
            plan_hotplug(&[p(true, true, false, true), p(false, true, false, false)]),
            vec![Lost, StillGone]
        );
        assert_eq!(plan_hotplug(&[p(false, false, false, false)]), vec![StillGone]);
        // The sequence unplug -> re-plug, fed back through the state it produces.
        let mut up = true;
        for (connected, want) in
            [(true, Keep), (false, Lost), (false, StillGone), (true, Restore), (true, Keep)]
        {
            let a = plan_hotplug(&[p(up, connected, connected, up)])[0];
            assert_eq!(a, want);
            up = matches!(a, Keep | Restore);
        }
    }

    #[test]
    fn frame_copies_into_a_pitched_buffer_and_reads_back_as_rgb() {
        // 2x2 frame, pitch 12 (one pixel of padding per row), X bytes set in the source.
        let xrgb = [1u8, 2, 3, 99, 4, 5, 6, 99, 7, 8, 9, 99, 10, 11, 12, 99];
        let f = FrameRef { width: 2, height: 2, xrgb: &xrgb };
        let mut dst = vec![0xAAu8; 24];
        copy_to_scanout(Some(&f), 2, 2, &mut dst, 12);
        assert_eq!(&dst[..8], &[1, 2, 3, 0, 4, 5, 6, 0]);
        assert_eq!(&dst[8..12], &[0xAA; 4], "padding untouched");
        assert_eq!(&dst[12..20], &[7, 8, 9, 0, 10, 11, 12, 0]);
        copy_to_scanout(None, 2, 2, &mut dst, 12);
        assert_eq!(&dst[..8], &[0; 8]);
        assert_eq!(&dst[12..20], &[0; 8]);
        // Little-endian XRGB8888 is B, G, R, X in memory.
        assert_eq!(xrgb8888_to_rgb8(&xrgb[..8]), vec![3, 2, 1, 6, 5, 4]);
        // A buffer too short for the frame is filled as far as it goes, no panic.
        let mut short = vec![0u8; 10];
        copy_to_scanout(Some(&f), 2, 2, &mut short, 8);
        assert_eq!(&short[..8], &[1, 2, 3, 0, 4, 5, 6, 0]);
    }

    #[test]
    fn recognises_drm_hotplug_uevents_only() {
        let hp = b"change@/devices/pci0000:00/0000:00:02.0/drm/card0\0ACTION=change\0DEVPATH=/devices/x\0SUBSYSTEM=drm\0HOTPLUG=1\0DEVNAME=/dev/dri/card0\0SEQNUM=1\0";
        assert!(is_drm_hotplug(hp));
        // udevadm trigger / a sysfs `uevent` write: a change without HOTPLUG=1.
        let synth = b"change@/devices/x/drm/card0\0ACTION=change\0SUBSYSTEM=drm\0SYNTH_UUID=0\0";
        assert!(is_drm_hotplug(synth));
        let other = b"change@/devices/x\0ACTION=change\0SUBSYSTEM=usb\0HOTPLUG=1\0";
        assert!(!is_drm_hotplug(other));
        // A card appearing or going away is not a re-probe of ours.
        assert!(!is_drm_hotplug(b"add@/x\0ACTION=add\0SUBSYSTEM=drm\0"));
        assert!(!is_drm_hotplug(b""));
    }

    #[test]
    fn a_missing_card_is_a_clear_error() {
        let e = KmsOutput::open(Path::new("/nonexistent/card9"), &[], true, None).unwrap_err().to_string();
        assert!(e.contains("/nonexistent/card9") && e.contains("cannot open"), "{e}");
    }
}
