//! Projectors as full-screen windows, one per display output (winit + softbuffer): the way a
//! desktop machine shows patterns during acquisition. `show` returns once the frame has been
//! handed to the display; the acquisition's settle delay covers the projector's latency.

use std::num::NonZeroU32;
use std::rc::Rc;
use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::Duration;

use image::RgbImage;
use winit::application::ApplicationHandler;
use winit::event::WindowEvent;
use winit::event_loop::{ActiveEventLoop, EventLoop, EventLoopProxy};
use winit::window::{Fullscreen, Window, WindowId};

use crate::hw::{HwError, ProjectorOutput};

/// How long a frame may take to reach the display before the output counts as failed.
const SHOW_TIMEOUT: Duration = Duration::from_secs(5);

/// A display output as the window system reports it.
#[derive(Clone, Debug, PartialEq)]
pub struct MonitorInfo {
    pub name: String,
    pub width: u32,
    pub height: u32,
}

/// Picks the monitors for the projectors, in projector order. Each entry of `wanted` is a
/// monitor index (`0`, `1`, ...) or its exact name (e.g. `HDMI-1`, `DP-2`).
pub fn choose_monitors(available: &[MonitorInfo], wanted: &[String]) -> Result<Vec<usize>, String> {
    let list = || {
        available
            .iter()
            .enumerate()
            .map(|(i, m)| format!("{i}: {} {}x{}", m.name, m.width, m.height))
            .collect::<Vec<_>>()
            .join("; ")
    };
    if wanted.is_empty() {
        return Err(format!("name the projectors' outputs with --screens (available: {})", list()));
    }
    let mut chosen = Vec::with_capacity(wanted.len());
    for w in wanted {
        let index = match w.parse::<usize>() {
            Ok(i) if i < available.len() => i,
            Ok(i) => return Err(format!("there is no monitor {i} (available: {})", list())),
            Err(_) => available
                .iter()
                .position(|m| &m.name == w)
                .ok_or_else(|| format!("there is no monitor named {w:?} (available: {})", list()))?,
        };
        if chosen.contains(&index) {
            return Err(format!("monitor {w:?} is named twice; each projector needs its own output"));
        }
        chosen.push(index);
    }
    Ok(chosen)
}

/// A frame in softbuffer's layout: one `0x00RRGGBB` word per pixel.
pub fn to_softbuffer(frame: &RgbImage) -> Vec<u32> {
    frame.pixels().map(|p| u32::from_be_bytes([0, p[0], p[1], p[2]])).collect()
}

enum Msg {
    Show { projector: usize, width: u32, height: u32, pixels: Vec<u32> },
    Close,
}

type Opened = Result<Vec<MonitorInfo>, String>;

/// Full-screen windows on the chosen monitors; the window system runs on its own thread.
pub struct ScreenOutput {
    proxy: EventLoopProxy<Msg>,
    monitors: Vec<MonitorInfo>,
    shown: mpsc::Receiver<Result<(), String>>,
    thread: Option<JoinHandle<()>>,
}

impl std::fmt::Debug for ScreenOutput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ScreenOutput").field("monitors", &self.monitors).finish()
    }
}

impl ScreenOutput {
    /// Opens one black full-screen window per entry of `wanted` (see [`choose_monitors`]).
    pub fn open(wanted: Vec<String>) -> Result<Self, HwError> {
        let err = |problem: String| HwError::Device { device: "projector screens".into(), problem };
        let (opened_tx, opened_rx) = mpsc::channel::<Opened>();
        let (proxy_tx, proxy_rx) = mpsc::channel();
        let (shown_tx, shown_rx) = mpsc::channel();
        let thread = std::thread::spawn(move || {
            let mut builder = EventLoop::<Msg>::with_user_event();
            #[cfg(target_os = "linux")]
            {
                winit::platform::x11::EventLoopBuilderExtX11::with_any_thread(&mut builder, true);
                winit::platform::wayland::EventLoopBuilderExtWayland::with_any_thread(&mut builder, true);
            }
            let event_loop = match builder.build() {
                Ok(l) => l,
                Err(e) => {
                    let _ = opened_tx.send(Err(format!("no window system ({e}); is DISPLAY set?")));
                    return;
                }
            };
            let _ = proxy_tx.send(event_loop.create_proxy());
            let mut app = Screens { wanted, opened: Some(opened_tx), shown: shown_tx, windows: Vec::new() };
            if let Err(e) = event_loop.run_app(&mut app) {
                tracing::error!(%e, "projector windows failed");
            }
        });
        let opened = opened_rx.recv().map_err(|_| err("the window thread ended".into()))?;
        let monitors = opened.map_err(err)?;
        let proxy = proxy_rx.recv().map_err(|_| err("the window thread ended".into()))?;
        for (k, m) in monitors.iter().enumerate() {
            tracing::info!("projector {k}: monitor {} {}x{}", m.name, m.width, m.height);
        }
        Ok(Self { proxy, monitors, shown: shown_rx, thread: Some(thread) })
    }
}

impl ProjectorOutput for ScreenOutput {
    fn projector_count(&self) -> usize {
        self.monitors.len()
    }

    fn resolution(&self, projector: usize) -> Result<(u32, u32), HwError> {
        let m = self
            .monitors
            .get(projector)
            .ok_or(HwError::NoSuchProjector { projector, count: self.monitors.len() })?;
        Ok((m.width, m.height))
    }

    fn show(&mut self, projector: usize, frame: &RgbImage) -> Result<(), HwError> {
        let (want_w, want_h) = self.resolution(projector)?;
        if frame.dimensions() != (want_w, want_h) {
            return Err(HwError::FrameSize {
                projector,
                got_w: frame.width(),
                got_h: frame.height(),
                want_w,
                want_h,
            });
        }
        let device = format!("projector {projector} ({})", self.monitors[projector].name);
        let err = |problem: String| HwError::Device { device: device.clone(), problem };
        let msg = Msg::Show { projector, width: want_w, height: want_h, pixels: to_softbuffer(frame) };
        self.proxy.send_event(msg).map_err(|_| err("the window was closed".into()))?;
        match self.shown.recv_timeout(SHOW_TIMEOUT) {
            Ok(r) => r.map_err(err),
            Err(_) => Err(err(format!("the frame did not reach the display within {SHOW_TIMEOUT:?}"))),
        }
    }
}

impl Drop for ScreenOutput {
    fn drop(&mut self) {
        let _ = self.proxy.send_event(Msg::Close);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

struct Screen {
    window: Rc<Window>,
    surface: softbuffer::Surface<Rc<Window>, Rc<Window>>,
}

struct Screens {
    wanted: Vec<String>,
    opened: Option<mpsc::Sender<Opened>>,
    shown: mpsc::Sender<Result<(), String>>,
    windows: Vec<Screen>,
}

impl Screens {
    fn open_windows(&mut self, event_loop: &ActiveEventLoop) -> Opened {
        let handles: Vec<_> = event_loop.available_monitors().collect();
        let infos: Vec<MonitorInfo> = handles
            .iter()
            .enumerate()
            .map(|(i, m)| MonitorInfo {
                name: m.name().unwrap_or_else(|| format!("monitor {i}")),
                width: m.size().width,
                height: m.size().height,
            })
            .collect();
        let chosen = choose_monitors(&infos, &self.wanted)?;
        for &i in &chosen {
            let attrs = Window::default_attributes()
                .with_title(format!("restage projector on {}", infos[i].name))
                .with_decorations(false)
                .with_fullscreen(Some(Fullscreen::Borderless(Some(handles[i].clone()))));
            let window = Rc::new(event_loop.create_window(attrs).map_err(|e| e.to_string())?);
            window.set_cursor_visible(false);
            let surface = softbuffer::Context::new(window.clone())
                .and_then(|c| softbuffer::Surface::new(&c, window.clone()))
                .map_err(|e| format!("cannot draw on {}: {e}", infos[i].name))?;
            self.windows.push(Screen { window, surface });
        }
        Ok(chosen.into_iter().map(|i| infos[i].clone()).collect())
    }

    fn draw(&mut self, projector: usize, width: u32, height: u32, pixels: &[u32]) -> Result<(), String> {
        let screen = self.windows.get_mut(projector).ok_or("no such window")?;
        let (Some(w), Some(h)) = (NonZeroU32::new(width), NonZeroU32::new(height)) else {
            return Err("empty frame".into());
        };
        screen.surface.resize(w, h).map_err(|e| e.to_string())?;
        let mut buffer = screen.surface.buffer_mut().map_err(|e| e.to_string())?;
        buffer.copy_from_slice(pixels);
        buffer.present().map_err(|e| e.to_string())?;
        screen.window.request_redraw();
        Ok(())
    }
}

impl ApplicationHandler<Msg> for Screens {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        let Some(opened) = self.opened.take() else { return };
        let result = self.open_windows(event_loop);
        let failed = result.is_err();
        let _ = opened.send(result);
        if failed {
            event_loop.exit();
        }
    }

    fn user_event(&mut self, event_loop: &ActiveEventLoop, msg: Msg) {
        match msg {
            Msg::Show { projector, width, height, pixels } => {
                let r = self.draw(projector, width, height, &pixels);
                let _ = self.shown.send(r);
            }
            Msg::Close => {
                // Dark before the windows go, so the object is not lit by whatever is behind.
                for k in 0..self.windows.len() {
                    let size = self.windows[k].window.inner_size();
                    let black = vec![0u32; size.width as usize * size.height as usize];
                    let _ = self.draw(k, size.width, size.height, &black);
                }
                self.windows.clear();
                event_loop.exit();
            }
        }
    }

    fn window_event(&mut self, _: &ActiveEventLoop, _: WindowId, _: WindowEvent) {}
}

#[cfg(test)]
mod tests {
    use super::*;

    fn monitors() -> Vec<MonitorInfo> {
        ["eDP-1", "HDMI-1", "DP-2"]
            .iter()
            .map(|n| MonitorInfo { name: n.to_string(), width: 1920, height: 1080 })
            .collect()
    }

    #[test]
    fn monitors_by_index_or_name_in_projector_order() {
        let m = monitors();
        let w = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert_eq!(choose_monitors(&m, &w(&["DP-2", "1"])).unwrap(), vec![2, 1]);
        let e = choose_monitors(&m, &w(&["HDMI-2"])).unwrap_err();
        assert!(e.contains("HDMI-2") && e.contains("1: HDMI-1 1920x1080"), "{e}");
        assert!(choose_monitors(&m, &w(&["3"])).unwrap_err().contains("no monitor 3"));
        assert!(choose_monitors(&m, &w(&["1", "HDMI-1"])).unwrap_err().contains("twice"));
        assert!(choose_monitors(&m, &[]).unwrap_err().contains("--screens"));
    }

    #[test]
    fn frames_become_xrgb_words() {
        let mut f = RgbImage::new(2, 1);
        f.put_pixel(0, 0, image::Rgb([0x12, 0x34, 0x56]));
        f.put_pixel(1, 0, image::Rgb([255, 0, 1]));
        assert_eq!(to_softbuffer(&f), vec![0x0012_3456, 0x00ff_0001]);
    }
}
