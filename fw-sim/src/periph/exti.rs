//! EXTI lines 0..15 from GPIO pins: RM0440 §15.5 (IMR1/EMR1/RTSR1/FTSR1/
//! SWIER1/PR1 and the second bank) and RM0008 §10.3; the port of each line
//! comes from SYSCFG_EXTICRx (G4) / AFIO_EXTICRx (F1), kept here.

use super::Access;

#[derive(Debug)]
pub struct Exti {
    g4: bool,
    /// IMR EMR RTSR FTSR SWIER PR, banks 1 and 2 (G4).
    r: [[u32; 6]; 2],
    /// Port index (0 = A) of lines 0..15.
    pub exticr: [u32; 4],
}

impl Exti {
    pub fn new(g4: bool) -> Self {
        let mut r = [[0; 6]; 2];
        if g4 {
            // direct (internal) lines are unmasked at reset
            r[0][0] = 0x1F84_0000;
            r[1][0] = 0x0000_003C;
        }
        Self {
            g4,
            r,
            exticr: [0; 4],
        }
    }

    pub fn port_of(&self, line: u8) -> usize {
        ((self.exticr[(line / 4) as usize] >> (4 * (line % 4))) & 0xF) as usize
    }

    /// A level change on `line` from port `port`.
    pub fn edge(&mut self, port: usize, line: u8, rising: bool) {
        if self.port_of(line) != port {
            return;
        }
        let trig = if rising { self.r[0][2] } else { self.r[0][3] };
        if trig & (1 << line) != 0 {
            self.r[0][5] |= 1 << line;
        }
    }

    /// Pending and unmasked lines.
    pub fn pending(&self) -> u32 {
        self.r[0][5] & self.r[0][0]
    }

    pub fn read(&mut self, off: u32) -> Access {
        let (bank, i) = (off / 0x20, (off % 0x20) / 4);
        if (bank > 0 && !self.g4) || bank > 1 || i > 5 {
            return Access::Unmodelled;
        }
        Access::Ok(self.r[bank as usize][i as usize])
    }

    pub fn write(&mut self, off: u32, v: u32) -> Access {
        let (bank, i) = ((off / 0x20) as usize, ((off % 0x20) / 4) as usize);
        if (bank > 0 && !self.g4) || bank > 1 || i > 5 {
            return Access::Unmodelled;
        }
        match i {
            // PR: rc_w1
            5 => self.r[bank][5] &= !v,
            // SWIER: a 0 -> 1 write pends the line (if unmasked)
            4 => self.r[bank][5] |= v & self.r[bank][0],
            _ => self.r[bank][i] = v,
        }
        Access::Ok(0)
    }
}
