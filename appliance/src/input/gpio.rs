//! A push button on a Raspberry Pi GPIO pin (rppal): edge interrupts with the kernel's
//! debounce, delivered from rppal's interrupt thread into the event loop.

use std::time::Duration;

use rppal::gpio::{Gpio, InputPin, Trigger};

use super::{InputEvent, InputSender, send_button};
use crate::config::GpioConfig;

/// Sets up the pin; keep the returned pin alive for the interrupts to keep coming.
pub fn start(config: &GpioConfig, tx: InputSender) -> Result<InputPin, rppal::gpio::Error> {
    let pin = Gpio::new()?.get(config.pin)?;
    let mut pin = if config.active_low { pin.into_input_pullup() } else { pin.into_input_pulldown() };
    let active_low = config.active_low;
    pin.set_async_interrupt(Trigger::Both, Some(Duration::from_millis(config.debounce_ms)), move |event| {
        let down = matches!(event.trigger, Trigger::FallingEdge) == active_low;
        let ev =
            if down { InputEvent::Press { source: "gpio" } } else { InputEvent::Release { source: "gpio" } };
        send_button(&tx, ev);
    })?;
    tracing::info!(pin = config.pin, "GPIO button ready");
    Ok(pin)
}
