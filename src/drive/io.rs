//! The drive's plain pins through embedded-hal 1.0 digital traits, shared by
//! the firmware boards and the host doubles (SPEC §7 PA11/PA13, §8.1).
//!
//! - [`SwitchInputs`]: CW limit, CCW limit and home inputs, read with the
//!   polarity of PA13 (bit set = normally closed: active when the pin is
//!   low). A pin that cannot be read counts as active: a limit that may be
//!   hit must block motion.
//! - [`PowerOutputs`]: ENABLE (power stage) and BRAKE (high = released),
//!   both active high; boards with inverted drivers invert in their pin
//!   setup.
//! - [`DirectionOutput`]: DIR, high for the positive direction unless PA11
//!   inverts it. It belongs to the step interrupt, which writes it after each
//!   [`crate::motion::StepSource::advance`] (the whole interval is set-up
//!   time).

use embedded_hal::digital::{InputPin, OutputPin, PinState};

use super::Outputs;
use crate::motion::Switches;

/// PA13 bits: 0 CW limit, 1 CCW limit, 2 home (1 = normally closed).
pub const POLARITY_CW: u16 = 1 << 0;
pub const POLARITY_CCW: u16 = 1 << 1;
pub const POLARITY_HOME: u16 = 1 << 2;

/// The three switch inputs.
pub struct SwitchInputs<Cw, Ccw, Home> {
    cw_limit: Cw,
    ccw_limit: Ccw,
    home: Home,
}

fn active<P: InputPin>(pin: &mut P, normally_closed: bool) -> bool {
    match pin.is_high() {
        Ok(high) => high != normally_closed,
        Err(_) => true,
    }
}

impl<Cw, Ccw, Home> SwitchInputs<Cw, Ccw, Home> {
    #[inline]
    pub const fn new(cw_limit: Cw, ccw_limit: Ccw, home: Home) -> Self {
        Self {
            cw_limit,
            ccw_limit,
            home,
        }
    }
}

impl<Cw: InputPin, Ccw: InputPin, Home: InputPin> SwitchInputs<Cw, Ccw, Home> {
    /// Logical states with the polarity bits of PA13.
    pub fn read(&mut self, polarity: u16) -> Switches {
        Switches::new(
            active(&mut self.cw_limit, polarity & POLARITY_CW != 0),
            active(&mut self.ccw_limit, polarity & POLARITY_CCW != 0),
            active(&mut self.home, polarity & POLARITY_HOME != 0),
        )
    }
}

/// ENABLE and BRAKE.
pub struct PowerOutputs<Enable, Brake> {
    enable: Enable,
    brake: Brake,
}

impl<Enable, Brake> PowerOutputs<Enable, Brake> {
    #[inline]
    pub const fn new(enable: Enable, brake: Brake) -> Self {
        Self { enable, brake }
    }
}

impl<Enable: OutputPin, Brake: OutputPin> PowerOutputs<Enable, Brake> {
    /// Drives both pins; false if a pin reported an error.
    pub fn apply(&mut self, out: Outputs) -> bool {
        let a = self
            .enable
            .set_state(PinState::from(out.power_stage))
            .is_ok();
        let b = self
            .brake
            .set_state(PinState::from(out.brake_released))
            .is_ok();
        a && b
    }
}

/// DIR.
pub struct DirectionOutput<Dir> {
    dir: Dir,
}

impl<Dir> DirectionOutput<Dir> {
    #[inline]
    pub const fn new(dir: Dir) -> Self {
        Self { dir }
    }
}

impl<Dir: OutputPin> DirectionOutput<Dir> {
    /// Sets DIR for a step in the positive (`forward`) direction, inverted
    /// by PA11. False if the pin reported an error.
    pub fn set(&mut self, forward: bool, inverted: bool) -> bool {
        self.dir
            .set_state(PinState::from(forward != inverted))
            .is_ok()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::convert::Infallible;
    use embedded_hal::digital::{ErrorKind, ErrorType};

    struct Pin(Option<bool>);
    #[derive(Debug)]
    struct Broken;
    impl embedded_hal::digital::Error for Broken {
        fn kind(&self) -> ErrorKind {
            ErrorKind::Other
        }
    }
    impl ErrorType for Pin {
        type Error = Broken;
    }
    impl InputPin for Pin {
        fn is_high(&mut self) -> Result<bool, Broken> {
            self.0.ok_or(Broken)
        }
        fn is_low(&mut self) -> Result<bool, Broken> {
            self.0.map(|h| !h).ok_or(Broken)
        }
    }
    struct Out(bool);
    impl ErrorType for Out {
        type Error = Infallible;
    }
    impl OutputPin for Out {
        fn set_low(&mut self) -> Result<(), Infallible> {
            self.0 = false;
            Ok(())
        }
        fn set_high(&mut self) -> Result<(), Infallible> {
            self.0 = true;
            Ok(())
        }
    }

    #[test]
    fn pa13_polarity_and_unreadable_pins() {
        let mut sw = SwitchInputs {
            cw_limit: Pin(Some(true)),
            ccw_limit: Pin(Some(false)),
            home: Pin(None),
        };
        // normally open: high = active
        assert_eq!(sw.read(0), Switches::new(true, false, true));
        // CW and CCW normally closed: low = active
        assert_eq!(
            sw.read(POLARITY_CW | POLARITY_CCW),
            Switches::new(false, true, true)
        );
    }

    #[test]
    fn outputs_and_direction_invert() {
        let mut p = PowerOutputs {
            enable: Out(false),
            brake: Out(false),
        };
        assert!(p.apply(Outputs::new(true, false)));
        assert!(p.enable.0 && !p.brake.0);
        let mut d = DirectionOutput { dir: Out(false) };
        d.set(true, false);
        assert!(d.dir.0);
        d.set(true, true); // PA11 = 1
        assert!(!d.dir.0);
        d.set(false, true);
        assert!(d.dir.0);
    }
}
