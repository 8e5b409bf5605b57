//! Peripherals that are storage with a reset value and a write mask, plus a
//! few read-only status bits: PWR (RM0440 §6.4: CR1 VOS, SR2 VOSF clear at
//! once, CR5 R1MODE; RM0008 §5.4), SYSCFG (RM0440 §10.2) / AFIO (RM0008
//! §9.4) and DBGMCU (RM0440 §47.15 / RM0008 §31.16).

use super::Access;

#[derive(Debug)]
pub struct Bank {
    /// (offset, value, writable mask)
    regs: Vec<(u32, u32, u32)>,
}

impl Bank {
    fn new(regs: &[(u32, u32, u32)]) -> Self {
        Self {
            regs: regs.to_vec(),
        }
    }
    pub fn pwr(g4: bool) -> Self {
        if g4 {
            let mut r = vec![
                (0x00, 0x0000_0200, 0x0000_4707), // CR1: LPR, VOS (range 1), DBP, LPMS
                (0x04, 0, 0x0000_00FF),           // CR2
                (0x08, 0x0000_8000, 0x0000_C5FF), // CR3
                (0x0C, 0, 0x0000_03FF),           // CR4
                (0x10, 0, 0),                     // SR1
                (0x14, 0, 0),                     // SR2: REGLPF = 0, VOSF = 0 (ready)
                (0x18, 0, 0x0000_011F),           // SCR
                (0x80, 0x0000_0100, 0x0000_0100), // CR5: R1MODE (1 = no boost)
            ];
            // PUCRA/PDCRA .. PUCRG/PDCRG
            for o in (0x20..=0x4C).step_by(4) {
                r.push((o, 0, 0xFFFF));
            }
            Self::new(&r)
        } else {
            Self::new(&[(0x00, 0, 0x1FF), (0x04, 0, 0x100)])
        }
    }
    pub fn syscfg(g4: bool) -> Self {
        if g4 {
            Self::new(&[
                (0x00, 0, 0x107),
                (0x04, 0x7C00_0001, 0xFC3F_0300),
                (0x08, 0, 0xFFFF),
                (0x0C, 0, 0xFFFF),
                (0x10, 0, 0xFFFF),
                (0x14, 0, 0xFFFF),
                (0x18, 0, 1),
                (0x1C, 0, 0x10F),
                (0x20, 0, u32::MAX),
                (0x24, 0, 0xFF),
            ])
        } else {
            Self::new(&[
                (0x00, 0, 0xFF),
                (0x04, 0, 0x071F_FFFF),
                (0x08, 0, 0xFFFF),
                (0x0C, 0, 0xFFFF),
                (0x10, 0, 0xFFFF),
                (0x14, 0, 0xFFFF),
                (0x1C, 0, 0x7E0),
            ])
        }
    }
    pub fn dbgmcu(g4: bool, idcode: u32) -> Self {
        if g4 {
            Self::new(&[
                (0x00, idcode, 0),
                (0x04, 0, 0x27),
                (0x08, 0, u32::MAX),
                (0x0C, 0, u32::MAX),
                (0x10, 0, u32::MAX),
            ])
        } else {
            Self::new(&[(0x00, idcode, 0), (0x04, 0, 0x7FFF_FF27)])
        }
    }

    pub fn get(&self, off: u32) -> u32 {
        self.regs.iter().find(|r| r.0 == off).map_or(0, |r| r.1)
    }

    pub fn read(&mut self, off: u32) -> Access {
        match self.regs.iter().find(|r| r.0 == off) {
            Some(r) => Access::Ok(r.1),
            None => Access::Unmodelled,
        }
    }

    pub fn write(&mut self, off: u32, v: u32) -> Access {
        match self.regs.iter_mut().find(|r| r.0 == off) {
            Some(r) => {
                r.1 = (r.1 & !r.2) | (v & r.2);
                Access::Ok(0)
            }
            None => Access::Unmodelled,
        }
    }
}
