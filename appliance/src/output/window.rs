//! A development window (winit + softbuffer): the projectors side by side, scaled to fit.
//! Space bar or a mouse click is the visitor's button; closing the window stops the program.

use std::num::NonZeroU32;
use std::rc::Rc;
use std::thread::JoinHandle;

use winit::application::ApplicationHandler;
use winit::event::{ElementState, MouseButton, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop, EventLoopProxy};
use winit::keyboard::{Key, NamedKey};
use winit::window::{Window, WindowId};

use super::{FrameRef, Output, OutputError, check_frames};
use crate::input::{InputEvent, InputSender, send_button};

enum UserEvent {
    Frames(Vec<(u32, u32, Vec<u8>)>),
    Blank,
}

/// The window output; the window lives on its own thread.
pub struct WindowOutput {
    proxy: EventLoopProxy<UserEvent>,
    projectors: usize,
    sizes: Option<Vec<(u32, u32)>>,
    _thread: JoinHandle<()>,
}

impl std::fmt::Debug for WindowOutput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WindowOutput").field("projectors", &self.projectors).finish()
    }
}

impl WindowOutput {
    /// Opens the window; presses go to `inputs`.
    pub fn open(projectors: usize, inputs: InputSender) -> Result<WindowOutput, OutputError> {
        let (tx, rx) = std::sync::mpsc::channel();
        let thread = std::thread::spawn(move || {
            let mut builder = EventLoop::<UserEvent>::with_user_event();
            #[cfg(target_os = "linux")]
            {
                winit::platform::x11::EventLoopBuilderExtX11::with_any_thread(&mut builder, true);
                winit::platform::wayland::EventLoopBuilderExtWayland::with_any_thread(&mut builder, true);
            }
            let event_loop = match builder.build() {
                Ok(l) => l,
                Err(e) => {
                    let _ = tx.send(Err(e.to_string()));
                    return;
                }
            };
            let _ = tx.send(Ok(event_loop.create_proxy()));
            let mut app = App { inputs, window: None, surface: None, frames: Vec::new() };
            if let Err(e) = event_loop.run_app(&mut app) {
                tracing::error!(%e, "window event loop failed");
            }
        });
        let err = |problem: String| OutputError::Device { output: "window".into(), problem };
        let proxy = rx.recv().map_err(|e| err(e.to_string()))?.map_err(err)?;
        Ok(WindowOutput { proxy, projectors, sizes: None, _thread: thread })
    }

    fn send(&self, e: UserEvent) -> Result<(), OutputError> {
        self.proxy.send_event(e).map_err(|_| OutputError::Device {
            output: "window".into(),
            problem: "the window was closed".into(),
        })
    }
}

impl Output for WindowOutput {
    fn projector_count(&self) -> usize {
        self.projectors
    }

    fn set_modes(&mut self, sizes: &[(u32, u32)]) -> Result<(), OutputError> {
        self.projectors = sizes.len();
        self.sizes = Some(sizes.to_vec());
        Ok(())
    }

    fn show(&mut self, frames: &[FrameRef<'_>]) -> Result<(), OutputError> {
        check_frames(self.projectors, self.sizes.as_deref(), frames)?;
        self.send(UserEvent::Frames(frames.iter().map(|f| (f.width, f.height, f.xrgb.to_vec())).collect()))
    }

    fn blank(&mut self) -> Result<(), OutputError> {
        self.send(UserEvent::Blank)
    }
}

impl Drop for WindowOutput {
    fn drop(&mut self) {
        let _ = self.proxy.send_event(UserEvent::Blank);
    }
}

struct App {
    inputs: InputSender,
    window: Option<Rc<Window>>,
    surface: Option<softbuffer::Surface<Rc<Window>, Rc<Window>>>,
    frames: Vec<(u32, u32, Vec<u8>)>,
}

impl App {
    fn redraw(&mut self) {
        let (Some(window), Some(surface)) = (&self.window, &mut self.surface) else { return };
        let size = window.inner_size();
        let (Some(w), Some(h)) = (NonZeroU32::new(size.width), NonZeroU32::new(size.height)) else { return };
        if surface.resize(w, h).is_err() {
            return;
        }
        let Ok(mut buffer) = surface.buffer_mut() else { return };
        buffer.fill(0);
        let (w, h) = (size.width as usize, size.height as usize);
        let n = self.frames.len().max(1);
        let cell = w / n;
        for (k, (fw, fh, px)) in self.frames.iter().enumerate() {
            let (fw, fh) = (*fw as usize, *fh as usize);
            if fw == 0 || fh == 0 {
                continue;
            }
            // Nearest-neighbour scale, keeping the aspect ratio.
            let scale = (cell as f64 / fw as f64).min(h as f64 / fh as f64);
            let (dw, dh) = ((fw as f64 * scale) as usize, (fh as f64 * scale) as usize);
            for y in 0..dh.min(h) {
                let sy = (y as f64 / scale) as usize;
                for x in 0..dw.min(cell) {
                    let sx = (x as f64 / scale) as usize;
                    let i = (sy.min(fh - 1) * fw + sx.min(fw - 1)) * 4;
                    buffer[y * w + k * cell + x] = u32::from_le_bytes([px[i], px[i + 1], px[i + 2], 0]);
                }
            }
        }
        let _ = buffer.present();
    }
}

impl ApplicationHandler<UserEvent> for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.window.is_some() {
            return;
        }
        let attrs = Window::default_attributes().with_title("restage appliance (space or click = button)");
        match event_loop.create_window(attrs) {
            Ok(window) => {
                let window = Rc::new(window);
                match softbuffer::Context::new(window.clone())
                    .and_then(|c| softbuffer::Surface::new(&c, window.clone()))
                {
                    Ok(surface) => self.surface = Some(surface),
                    Err(e) => tracing::error!(%e, "cannot draw in the window"),
                }
                self.window = Some(window);
            }
            Err(e) => {
                tracing::error!(%e, "cannot open the window");
                event_loop.exit();
            }
        }
    }

    fn user_event(&mut self, _: &ActiveEventLoop, event: UserEvent) {
        match event {
            UserEvent::Frames(f) => self.frames = f,
            UserEvent::Blank => self.frames.clear(),
        }
        if let Some(w) = &self.window {
            w.request_redraw();
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested => {
                let _ = self.inputs.try_send(InputEvent::Quit);
                event_loop.exit();
            }
            WindowEvent::RedrawRequested => self.redraw(),
            WindowEvent::KeyboardInput { event, .. } if event.logical_key == Key::Named(NamedKey::Space) => {
                match (event.state, event.repeat) {
                    (ElementState::Pressed, false) => {
                        send_button(&self.inputs, InputEvent::Press { source: "window" })
                    }
                    (ElementState::Released, _) => {
                        send_button(&self.inputs, InputEvent::Release { source: "window" })
                    }
                    _ => {}
                }
            }
            WindowEvent::MouseInput { state, button: MouseButton::Left, .. } => match state {
                ElementState::Pressed => send_button(&self.inputs, InputEvent::Press { source: "window" }),
                ElementState::Released => send_button(&self.inputs, InputEvent::Release { source: "window" }),
            },
            _ => {}
        }
    }
}
