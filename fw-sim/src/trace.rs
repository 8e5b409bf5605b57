//! `--trace-steps FILE`: one CSV line per STEP pulse on the pin (the timer
//! output that drives it in its alternate function): emulated time of the rising edge in ns, the
//! DIR pin level then, and the pulse width in ns.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

pub struct StepTrace {
    out: BufWriter<File>,
}

impl StepTrace {
    pub fn create(path: &Path) -> std::io::Result<Self> {
        let mut out = BufWriter::new(File::create(path)?);
        writeln!(out, "time_ns,dir,width_ns")?;
        Ok(Self { out })
    }
    pub fn step(&mut self, t_ps: u64, dir: bool, width_ps: u64) {
        // rounded to the ns; the error is reported in ps nowhere else
        let _ = writeln!(
            self.out,
            "{},{},{}",
            (t_ps + 500) / 1000,
            u8::from(dir),
            (width_ps + 500) / 1000
        );
        let _ = self.out.flush();
    }
}

/// `--trace-line FILE`: what happened on the RS-485 line, one CSV line per
/// event: emulated time in ns, the event (`rx`: a character from the master
/// ends; `tx`: a character of the firmware starts; `de`: the transceiver's
/// driver enable changes) and its value (the byte, or the DE level).
pub struct LineTrace {
    out: BufWriter<File>,
}

impl LineTrace {
    pub fn create(path: &Path) -> std::io::Result<Self> {
        let mut out = BufWriter::new(File::create(path)?);
        writeln!(out, "time_ns,event,value")?;
        Ok(Self { out })
    }
    pub fn event(&mut self, t_ps: u64, what: &str, value: u32) {
        let _ = writeln!(self.out, "{},{what},{value}", (t_ps + 500) / 1000);
        let _ = self.out.flush();
    }
}
