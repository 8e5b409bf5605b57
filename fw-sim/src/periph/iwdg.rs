//! Independent watchdog: RM0440 §42.4 / RM0008 §19.4. KR 0xCCCC starts it,
//! 0xAAAA reloads the counter, 0x5555 unlocks PR/RLR/WINR; the counter runs
//! down at LSI / (4 << PR) from RLR and resets the chip at zero. PVU/RVU/WVU
//! stay set for five LSI periods after a write (the register update).

use super::Access;
use crate::clock::PS_PER_S;

#[derive(Debug)]
pub struct Iwdg {
    g4: bool,
    lsi: u64,
    pr: u32,
    rlr: u32,
    winr: u32,
    unlocked: bool,
    running: bool,
    /// Time of the last reload, and the time the counter reaches zero.
    expires: Option<u64>,
    busy_until: [u64; 3],
}

impl Iwdg {
    pub fn new(g4: bool, lsi: u32) -> Self {
        Self {
            g4,
            lsi: lsi as u64,
            pr: 0,
            rlr: 0xFFF,
            winr: 0xFFF,
            unlocked: false,
            running: false,
            expires: None,
            busy_until: [0; 3],
        }
    }
    fn tick_ps(&self) -> u64 {
        ((4u128 << self.pr.min(6)) * PS_PER_S / self.lsi as u128) as u64
    }
    fn reload(&mut self, t: u64) {
        self.expires = Some(t + (self.rlr as u64 + 1) * self.tick_ps());
    }
    pub fn next_event(&self) -> Option<u64> {
        self.expires
    }
    /// True once the counter has reached zero at `t` (a reset is due).
    pub fn expired(&self, t: u64) -> bool {
        self.running && self.expires.is_some_and(|e| e <= t)
    }
    pub fn read(&mut self, off: u32, t: u64) -> Access {
        Access::Ok(match off {
            0x04 => self.pr,
            0x08 => self.rlr,
            0x0C => (0..3)
                .filter(|&i| self.busy_until[i] > t)
                .map(|i| 1 << i)
                .sum(),
            0x10 if self.g4 => self.winr,
            _ => return Access::Unmodelled,
        })
    }
    pub fn write(&mut self, off: u32, v: u32, t: u64) -> Access {
        let five = 5 * (PS_PER_S / self.lsi as u128) as u64;
        match off {
            0x00 => match v & 0xFFFF {
                0xCCCC => {
                    self.running = true;
                    self.reload(t);
                }
                0xAAAA => {
                    if self.running {
                        self.reload(t)
                    }
                }
                0x5555 => self.unlocked = true,
                _ => self.unlocked = false,
            },
            0x04 if self.unlocked => {
                self.pr = v & 7;
                self.busy_until[0] = t + five;
            }
            0x08 if self.unlocked => {
                self.rlr = v & 0xFFF;
                self.busy_until[1] = t + five;
            }
            0x10 if self.g4 && self.unlocked => {
                self.winr = v & 0xFFF;
                self.busy_until[2] = t + five;
                if self.running {
                    self.reload(t);
                }
            }
            0x04 | 0x08 => {}
            0x10 if self.g4 => {}
            _ => return Access::Unmodelled,
        }
        Access::Ok(0)
    }
}
