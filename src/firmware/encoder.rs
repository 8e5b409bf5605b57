//! The encoder input (SPEC §8.8): a quadrature encoder on TIM4 in encoder
//! mode (×4: both edges of both channels), pins in the board file. Read
//! once per control period and handed to the core, which unwraps the
//! 16-bit counter and runs the following-error check.
//!
//! The timer is set up the first time PA17 names a resolution, not at
//! start-up: a drive without an encoder leaves TIM4 and its pins alone.

use embassy_stm32::peripherals::TIM4;
use embassy_stm32::timer::qei::{self, Qei};

use super::board::EncoderPins;

/// The pins until PA17 asks for the encoder, then the running decoder.
pub enum EncoderInput {
    Idle(Option<EncoderPins>),
    Running(Qei<'static, TIM4>),
}

impl EncoderInput {
    pub fn new(pins: EncoderPins) -> Self {
        Self::Idle(Some(pins))
    }

    /// The counter now, once `wanted` (PA17 > 0) has started the timer;
    /// `None` before: the drive stays open loop.
    pub fn read(&mut self, wanted: bool) -> Option<u16> {
        if let Self::Idle(pins) = self {
            if !wanted {
                return None;
            }
            let p = pins.take()?;
            defmt::info!("encoder: TIM4 in encoder mode");
            *self = Self::Running(Qei::new(p.timer, p.a, p.b, qei::Config::default()));
        }
        match self {
            Self::Running(q) => Some(q.count()),
            Self::Idle(_) => None,
        }
    }
}
