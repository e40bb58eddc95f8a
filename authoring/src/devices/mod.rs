//! Real stage hardware behind the `hw` traits: a camera over a stream of raw driver frames
//! (V4L2 with the `hardware` feature), projector outputs as full-screen windows (winit, also
//! `hardware`), and the room light switched by the operator on request.

#[cfg(feature = "hardware")]
pub mod screens;
pub mod stream;
#[cfg(feature = "hardware")]
pub mod v4l_camera;

use std::io::{BufRead, Write};

use crate::hw::{DiffuseLight, HwError};

/// The room's diffuse light, switched by a person: asks on `prompt` and waits for Enter on
/// `answer`. Asks only when the state changes.
#[derive(Debug)]
pub struct AskedLight<R, W> {
    answer: R,
    prompt: W,
    on: Option<bool>,
}

impl<R: BufRead, W: Write> AskedLight<R, W> {
    pub fn new(answer: R, prompt: W) -> Self {
        Self { answer, prompt, on: None }
    }
}

impl<R: BufRead, W: Write> DiffuseLight for AskedLight<R, W> {
    fn set_diffuse(&mut self, on: bool) -> Result<(), HwError> {
        if self.on == Some(on) {
            return Ok(());
        }
        let err = |problem: String| HwError::Device { device: "room light".into(), problem };
        let what = if on { "ON (diffuse light for the photo)" } else { "OFF (darkness for the patterns)" };
        writeln!(self.prompt, "Switch the room light {what}, then press Enter.")
            .and_then(|_| self.prompt.flush())
            .map_err(|e| err(format!("cannot ask: {e}")))?;
        let mut line = String::new();
        match self.answer.read_line(&mut line) {
            Ok(0) => return Err(err("no answer (standard input closed)".into())),
            Ok(_) => {}
            Err(e) => return Err(err(format!("cannot read the answer: {e}"))),
        }
        self.on = Some(on);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn asks_once_per_change_and_needs_an_answer() {
        let mut said = Vec::new();
        let mut light = AskedLight::new(std::io::Cursor::new("\n\n"), &mut said);
        light.set_diffuse(true).unwrap();
        light.set_diffuse(true).unwrap();
        light.set_diffuse(false).unwrap();
        let e = light.set_diffuse(true).unwrap_err().to_string();
        assert!(e.contains("room light") && e.contains("closed"), "{e}");
        let said = String::from_utf8(said).unwrap();
        assert_eq!(said.matches("press Enter").count(), 3, "{said}");
        assert!(said.starts_with("Switch the room light ON"));
    }
}
