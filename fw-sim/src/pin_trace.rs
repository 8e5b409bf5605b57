//! `--trace-pins FILE`: what the drive's safety outputs drive, one CSV line
//! per change: emulated time in ns, core cycles since the last reset, the
//! pin (`enable`, `brake`, `step`, `de`) and its state: `0` / `1` a GPIO
//! output at that level, `af` a peripheral drives it (the step timer, the
//! G431 USART's DE), `z` not driven (an input or analog pin: the level is
//! the board's pull resistor's). Each reset adds a `reset` line (pin and
//! state empty) and then every pin's state again. The undriven window from
//! reset, the brake / enable sequence and the outputs after a watchdog
//! reset are read from it (tests/fw_sim).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use crate::chip::pins::Pin;
use crate::periph::gpio::{Mode, Port};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum State {
    Low,
    High,
    Peripheral,
    Undriven,
}

impl State {
    fn of(port: &Port, pin: u8) -> Self {
        match port.mode(pin) {
            Mode::Output if port.level(pin, None) => Self::High,
            Mode::Output => Self::Low,
            Mode::Alternate => Self::Peripheral,
            Mode::Input | Mode::Analog => Self::Undriven,
        }
    }
    fn name(self) -> &'static str {
        match self {
            Self::Low => "0",
            Self::High => "1",
            Self::Peripheral => "af",
            Self::Undriven => "z",
        }
    }
}

pub struct PinTrace {
    out: BufWriter<File>,
    /// (name, pin) of the traced outputs on this board.
    pins: [(&'static str, Pin); 4],
    last: [Option<State>; 4],
}

impl PinTrace {
    pub fn create(path: &Path, pins: [(&'static str, Pin); 4]) -> std::io::Result<Self> {
        let mut out = BufWriter::new(File::create(path)?);
        writeln!(out, "time_ns,cycles,pin,state")?;
        Ok(Self {
            out,
            pins,
            last: [None; 4],
        })
    }

    /// A reset at `t_ps`: every pin is reported again at the next look.
    pub fn reset(&mut self, t_ps: u64) {
        let _ = writeln!(self.out, "{},0,reset,", (t_ps + 500) / 1000);
        self.last = [None; 4];
        let _ = self.out.flush();
    }

    /// Looks at the pins after a GPIO write (or a reset) at `t_ps`,
    /// `cycles` core cycles after the last reset.
    pub fn look(&mut self, t_ps: u64, cycles: u64, gpio: &[Port; 2]) {
        let mut changed = false;
        for (i, (name, (port, pin))) in self.pins.into_iter().enumerate() {
            let s = State::of(&gpio[port], pin);
            if self.last[i] != Some(s) {
                self.last[i] = Some(s);
                changed = true;
                let _ = writeln!(
                    self.out,
                    "{},{cycles},{name},{}",
                    (t_ps + 500) / 1000,
                    s.name()
                );
            }
        }
        if changed {
            let _ = self.out.flush();
        }
    }
}
