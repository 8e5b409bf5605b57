//! GPIO ports A and B: RM0440 §9.4 (MODER/OTYPER/OSPEEDR/PUPDR/IDR/ODR/
//! BSRR/LCKR/AFR/BRR) and RM0008 §9.2 (CRL/CRH/IDR/ODR/BSRR/BRR/LCKR).
//! IDR reads each pin's level: an output its ODR bit, an input what the
//! emulated world drives (switches) or else its pull resistor; a pin in an
//! alternate function takes the level of the peripheral output routed to it
//! (the caller supplies those).

use super::Access;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    Input,
    Output,
    Alternate,
    Analog,
}

#[derive(Debug)]
pub struct Port {
    g4: bool,
    /// G4: MODER OTYPER OSPEEDR PUPDR; F1: CRL CRH.
    cfg: [u32; 4],
    odr: u32,
    lckr: u32,
    afr: [u32; 2],
    /// Levels driven from outside (switch contacts), by pin.
    pub external: [Option<bool>; 16],
}

impl Port {
    pub fn new(g4: bool, index: usize) -> Self {
        let cfg = if g4 {
            if index == 0 {
                [0xABFF_FFFF, 0, 0x0C00_0000, 0x6400_0000]
            } else {
                [0xFFFF_FEBF, 0, 0, 0x0000_0100]
            }
        } else {
            [0x4444_4444, 0x4444_4444, 0, 0]
        };
        Self {
            g4,
            cfg,
            odr: 0,
            lckr: 0,
            afr: [0; 2],
            external: [None; 16],
        }
    }

    pub fn mode(&self, pin: u8) -> Mode {
        if self.g4 {
            match (self.cfg[0] >> (2 * pin)) & 3 {
                0 => Mode::Input,
                1 => Mode::Output,
                2 => Mode::Alternate,
                _ => Mode::Analog,
            }
        } else {
            let nib = (self.cfg[(pin / 8) as usize] >> (4 * (pin % 8))) & 0xF;
            match (nib & 3, nib >> 2) {
                (0, 0) => Mode::Analog,
                (0, _) => Mode::Input,
                (_, 0) | (_, 1) => Mode::Output,
                _ => Mode::Alternate,
            }
        }
    }

    /// Pull: Some(true) up, Some(false) down, None floating.
    fn pull(&self, pin: u8) -> Option<bool> {
        if self.g4 {
            match (self.cfg[3] >> (2 * pin)) & 3 {
                1 => Some(true),
                2 => Some(false),
                _ => None,
            }
        } else {
            let nib = (self.cfg[(pin / 8) as usize] >> (4 * (pin % 8))) & 0xF;
            (nib == 0b1000).then_some(self.odr & (1 << pin) != 0)
        }
    }

    /// G4: the alternate function number AFRL/AFRH select for `pin`.
    pub fn af(&self, pin: u8) -> u32 {
        (self.afr[(pin / 8) as usize] >> (4 * (pin % 8))) & 0xF
    }

    pub fn odr_bit(&self, pin: u8) -> bool {
        self.odr & (1 << pin) != 0
    }

    /// The level of a pin; `af` gives the peripheral output for a pin in its
    /// alternate function (None: the peripheral does not drive it).
    pub fn level(&self, pin: u8, af: Option<bool>) -> bool {
        match self.mode(pin) {
            Mode::Output => self.odr_bit(pin),
            // a peripheral input (a timer channel) leaves the pin to the
            // world outside
            Mode::Alternate => af.or(self.external[pin as usize]).unwrap_or(true),
            Mode::Analog => false,
            Mode::Input => self.external[pin as usize]
                .or(self.pull(pin))
                .unwrap_or(false),
        }
    }

    pub fn read(&mut self, off: u32, idr: u32) -> Access {
        Access::Ok(if self.g4 {
            match off {
                0x00..=0x0C => self.cfg[(off / 4) as usize],
                0x10 => idr,
                0x14 => self.odr,
                0x18 => 0,
                0x1C => self.lckr,
                0x20 | 0x24 => self.afr[((off - 0x20) / 4) as usize],
                0x28 => 0,
                _ => return Access::Unmodelled,
            }
        } else {
            match off {
                0x00 | 0x04 => self.cfg[(off / 4) as usize],
                0x08 => idr,
                0x0C => self.odr,
                0x10 | 0x14 => 0,
                0x18 => self.lckr,
                _ => return Access::Unmodelled,
            }
        })
    }

    pub fn write(&mut self, off: u32, v: u32) -> Access {
        let (odr, bsrr, brr) = if self.g4 {
            (0x14, 0x18, 0x28)
        } else {
            (0x0C, 0x10, 0x14)
        };
        match off {
            o if o == odr => self.odr = v & 0xFFFF,
            o if o == bsrr => self.odr = (self.odr & !(v >> 16)) | (v & 0xFFFF),
            o if o == brr => self.odr &= !(v & 0xFFFF),
            0x00..=0x0C if self.g4 => self.cfg[(off / 4) as usize] = v,
            0x00 | 0x04 if !self.g4 => self.cfg[(off / 4) as usize] = v,
            0x1C if self.g4 => self.lckr = v,
            0x18 if !self.g4 => self.lckr = v,
            0x20 | 0x24 if self.g4 => self.afr[((off - 0x20) / 4) as usize] = v,
            0x10 if self.g4 => {}
            0x08 if !self.g4 => {}
            _ => return Access::Unmodelled,
        }
        Access::Ok(0)
    }
}
