//! General-purpose timers TIM2/3/4: RM0440 §29 (G4 TIM2..TIM5), RM0008 §15
//! (F1 TIM2..TIM5). Up-counting edge-aligned mode with prescaler, ARR and
//! CCRx preload (shadow registers loaded at the update event), UG, the
//! rc_w0 status flags, output compare / PWM modes 1 and 2 on the channels
//! (channel 1's output level is recorded as edges for the step trace), and
//! the encoder modes (SMS 001..011), where the counter follows TI1/TI2 only.
//! Centre-aligned and down-counting modes, input capture, DMA and slave
//! modes other than the encoder are not modelled: selecting one stops the
//! runner (`Unsupported`).

use super::Access;
use crate::clock::{clk_at, time_of_clk};

#[derive(Debug)]
pub struct Timer {
    pub irq: usize,
    g4: bool,
    bits32: bool,
    clk_hz: u64,
    cr1: u32,
    cr2: u32,
    smcr: u32,
    dier: u32,
    sr: u32,
    ccmr: [u32; 2],
    ccer: u32,
    psc: u32,
    arr: u32,
    ccr: [u32; 4],
    dcr: u32,
    /// G4 ECR, TISEL, AF1, AF2.
    g4_extra: [u32; 4],
    psc_sh: u32,
    arr_sh: u32,
    ccr_sh: [u32; 4],
    cnt: u32,
    /// Timer-clock edge at which `cnt` held, on a prescaler boundary.
    anchor_clk: u64,
    /// Channel 1 output level (after polarity), and its changes.
    out1: bool,
    pub edges1: Vec<(u64, bool)>,
    /// Update events that came with UIF still set and its interrupt
    /// enabled: an update interrupt that did not run between two of them
    /// (with preloads, the period before ran again unchanged).
    pub missed_updates: u64,
    /// The levels of the TI1 and TI2 inputs (the channel 1 and 2 pins).
    ti: [bool; 2],
}

const CEN: u32 = 1;
const UDIS: u32 = 1 << 1;
const URS: u32 = 1 << 2;
const DIR: u32 = 1 << 4;
const CMS: u32 = 3 << 5;
const ARPE: u32 = 1 << 7;
const UIFREMAP: u32 = 1 << 11;

impl Timer {
    pub fn new(irq: usize, g4: bool, bits32: bool) -> Self {
        let max = if bits32 { u32::MAX } else { 0xFFFF };
        Self {
            irq,
            g4,
            bits32,
            clk_hz: 8_000_000,
            cr1: 0,
            cr2: 0,
            smcr: 0,
            dier: 0,
            sr: 0,
            ccmr: [0; 2],
            ccer: 0,
            psc: 0,
            arr: max,
            ccr: [0; 4],
            dcr: 0,
            g4_extra: [0; 4],
            psc_sh: 0,
            arr_sh: max,
            ccr_sh: [0; 4],
            cnt: 0,
            anchor_clk: 0,
            out1: false,
            edges1: Vec::new(),
            missed_updates: 0,
            ti: [false; 2],
        }
    }

    fn max(&self) -> u32 {
        if self.bits32 {
            u32::MAX
        } else {
            0xFFFF
        }
    }
    fn encoder(&self) -> bool {
        matches!(self.smcr & 0x7, 1..=3)
    }
    fn counting(&self) -> bool {
        self.cr1 & CEN != 0 && !self.encoder()
    }

    /// The timer kernel clock changed (RCC): re-anchor at `now`.
    pub fn set_clock(&mut self, hz: u64, now: u64) {
        if hz != self.clk_hz {
            self.sync(now);
            self.clk_hz = hz;
            self.anchor_clk = clk_at(now, hz);
        }
    }

    pub fn irq_level(&self) -> bool {
        self.sr & self.dier & 0x5F != 0
    }

    fn ocm(&self, ch: usize) -> u32 {
        let r = self.ccmr[ch / 2] >> ((ch % 2) * 8);
        // OCxM[2:0] in bits 6:4, OCxM[3] in bit 16 (G4)
        ((r >> 4) & 7) | if self.g4 { ((r >> 16) & 1) << 3 } else { 0 }
    }
    fn is_output(&self, ch: usize) -> bool {
        (self.ccmr[ch / 2] >> ((ch % 2) * 8)) & 3 == 0
    }
    fn preload(&self, ch: usize) -> bool {
        (self.ccmr[ch / 2] >> ((ch % 2) * 8 + 3)) & 1 != 0
    }

    /// Channel 1 reference (OC1REF) at the current count; `None` = unchanged.
    fn ref1(&self, on_match: bool) -> Option<bool> {
        let c = self.cnt;
        let ccr = self.ccr_sh[0];
        match self.ocm(0) {
            0 => None,
            1 => on_match.then_some(true),
            2 => on_match.then_some(false),
            3 => on_match.then_some(!self.ref_level()),
            4 => Some(false),
            5 => Some(true),
            6 => Some(c < ccr),
            7 => Some(c >= ccr),
            _ => None,
        }
    }
    fn ref_level(&self) -> bool {
        self.out1 ^ (self.ccer & 2 != 0)
    }
    fn update_out1(&mut self, t: u64, on_match: bool) {
        if self.ccer & 1 == 0 {
            return;
        }
        if let Some(r) = self.ref1(on_match) {
            let level = r ^ (self.ccer & 2 != 0);
            if level != self.out1 {
                self.out1 = level;
                self.edges1.push((t, level));
            }
        }
    }

    fn update_event(&mut self) {
        self.psc_sh = self.psc;
        self.arr_sh = self.arr;
        for ch in 0..4 {
            self.ccr_sh[ch] = self.ccr[ch];
        }
    }

    /// Ticks from the count `cnt` to the next event: (ticks, is_overflow).
    fn next_step(&self, cnt: u32) -> (u64, bool, u32) {
        let top = if cnt <= self.arr_sh {
            self.arr_sh
        } else {
            self.max()
        };
        let mut k = top as u64 - cnt as u64 + 1;
        let mut ovf = true;
        let mut chans = 0;
        for ch in 0..4 {
            let c = self.ccr_sh[ch];
            if self.is_output(ch) && c > cnt && c <= top {
                let kc = (c - cnt) as u64;
                if kc < k {
                    k = kc;
                    ovf = false;
                    chans = 0;
                }
                if kc == k && !ovf {
                    chans |= 1 << ch;
                }
            }
        }
        (k, ovf, chans)
    }

    /// Advances the counter to time `t`, setting flags and recording edges.
    pub fn sync(&mut self, t: u64) {
        let now_clk = clk_at(t, self.clk_hz);
        if !self.counting() {
            self.anchor_clk = now_clk.max(self.anchor_clk);
            return;
        }
        let period = self.psc_sh as u64 + 1;
        loop {
            if now_clk < self.anchor_clk {
                return;
            }
            let avail = (now_clk - self.anchor_clk) / period;
            if avail == 0 {
                return;
            }
            let (k, ovf, chans) = self.next_step(self.cnt);
            if k > avail {
                self.cnt += avail as u32;
                self.anchor_clk += avail * period;
                return;
            }
            self.anchor_clk += k * period;
            let at = time_of_clk(self.anchor_clk, self.clk_hz);
            if ovf {
                self.cnt = 0;
                if self.cr1 & UDIS == 0 {
                    if self.sr & self.dier & 1 != 0 {
                        self.missed_updates += 1;
                    }
                    self.sr |= 1;
                    self.update_event();
                }
                self.update_out1(at, false);
                for ch in 0..4 {
                    if self.is_output(ch) && self.ccr_sh[ch] == 0 {
                        self.sr |= 2 << ch;
                        if ch == 0 {
                            self.update_out1(at, true);
                        }
                    }
                }
                // a new period: the prescaler may have changed
                return self.sync(t);
            }
            self.cnt += k as u32;
            for ch in 0..4 {
                if chans & (1 << ch) != 0 {
                    self.sr |= 2 << ch;
                }
            }
            if chans & 1 != 0 {
                self.update_out1(at, true);
            }
        }
    }

    /// Time of the next event that sets an interrupt-enabled flag, or of the
    /// next update event (a point where preloads change), if counting.
    pub fn next_event(&self) -> Option<u64> {
        if !self.counting() {
            return None;
        }
        let period = self.psc_sh as u64 + 1;
        let mut cnt = self.cnt;
        // the first event with an enabled interrupt within this period, else
        // the period's update
        loop {
            let (k, ovf, chans) = self.next_step(cnt);
            let at_clk = self.anchor_clk + (k + (cnt - self.cnt) as u64) * period;
            let at = time_of_clk(at_clk, self.clk_hz);
            let enabled =
                ovf || (chans << 1) & self.dier != 0 || (chans & 1 != 0 && self.ccer & 1 != 0);
            if enabled || ovf {
                return Some(at);
            }
            cnt += k as u32;
        }
    }

    /// The TI1 / TI2 input pins are at `ti` from time `t` on. In encoder
    /// mode (SMS 001..011, with CEN) the counter follows each edge: RM0440
    /// §29.3.22 / RM0008 §15.3.12, table "Counting direction versus
    /// encoder signals". TI1FP1 and TI2FP2 are the inputs after the CC1P /
    /// CC2P polarity; the input filters are not modelled (clean edges).
    /// Encoder mode 1 counts on TI1FP1 edges, mode 2 on TI2FP2 edges (the
    /// SMCR field descriptions of RM0440), mode 3 on both. Only one input
    /// may change per call (a quadrature signal never moves both at once).
    /// `routed`: the pins reach the timer (their alternate function).
    pub fn inputs(&mut self, ti: [bool; 2], t: u64, routed: bool) {
        self.sync(t);
        let before = self.ti;
        self.ti = ti;
        if !routed || !self.encoder() || self.cr1 & CEN == 0 {
            return;
        }
        let pol = [self.ccer & 2 != 0, self.ccer & (1 << 5) != 0];
        let fp = |l: [bool; 2]| [l[0] ^ pol[0], l[1] ^ pol[1]];
        let (old, new) = (fp(before), fp(ti));
        let sms = self.smcr & 7;
        let up = if old[0] != new[0] {
            if sms == 2 {
                return;
            }
            // TI1FP1 edge: rising with TI2FP2 low counts up
            new[0] != new[1]
        } else if old[1] != new[1] {
            if sms == 1 {
                return;
            }
            // TI2FP2 edge: rising with TI1FP1 high counts up
            new[0] == new[1]
        } else {
            return;
        };
        self.cr1 = if up { self.cr1 & !DIR } else { self.cr1 | DIR };
        let wrapped = if up {
            if self.cnt >= self.arr_sh {
                self.cnt = 0;
                true
            } else {
                self.cnt += 1;
                false
            }
        } else if self.cnt == 0 {
            self.cnt = self.arr_sh;
            true
        } else {
            self.cnt -= 1;
            false
        };
        if wrapped && self.cr1 & UDIS == 0 {
            self.sr |= 1;
            self.update_event();
        }
    }

    pub fn read(&mut self, off: u32, t: u64) -> Access {
        self.sync(t);
        Access::Ok(match off {
            0x00 => self.cr1,
            0x04 => self.cr2,
            0x08 => self.smcr,
            0x0C => self.dier,
            0x10 => self.sr,
            0x14 => 0,
            0x18 => self.ccmr[0],
            0x1C => self.ccmr[1],
            0x20 => self.ccer,
            0x24 => {
                let uifcpy = if self.g4 && self.cr1 & UIFREMAP != 0 {
                    (self.sr & 1) << 31
                } else {
                    0
                };
                self.cnt | uifcpy
            }
            0x28 => self.psc,
            0x2C => self.arr,
            0x34..=0x40 => self.ccr[((off - 0x34) / 4) as usize],
            0x48 if !self.g4 => self.dcr,
            0x4C if !self.g4 => 0,
            0x3DC if self.g4 => self.dcr,
            0x3E0 if self.g4 => 0,
            0x58..=0x64 if self.g4 => self.g4_extra[((off - 0x58) / 4) as usize],
            _ => return Access::Unmodelled,
        })
    }

    pub fn write(&mut self, off: u32, v: u32, t: u64) -> Access {
        self.sync(t);
        let max = self.max();
        match off {
            0x00 => {
                // DIR is read-only in encoder mode (the count's direction)
                let v = if self.encoder() {
                    (v & !DIR) | (self.cr1 & DIR)
                } else {
                    v
                };
                if !self.encoder() && v & (DIR | CMS) != 0 {
                    return Access::Unsupported("down-counting / centre-aligned mode");
                }
                let start = v & CEN != 0 && self.cr1 & CEN == 0;
                self.cr1 = v & 0xBFF;
                if start {
                    self.anchor_clk = clk_at(t, self.clk_hz);
                }
            }
            0x04 => self.cr2 = v,
            0x08 => {
                let sms = (v & 7) | ((v >> 13) & 8);
                if !matches!(sms, 0..=3) {
                    return Access::Unsupported("slave mode other than encoder");
                }
                self.smcr = v;
                self.anchor_clk = clk_at(t, self.clk_hz);
            }
            0x0C => self.dier = v & 0x5F5F,
            // rc_w0: writing 1 leaves a flag, 0 clears it
            0x10 => self.sr &= v,
            0x14 => {
                if v & 1 != 0 {
                    self.cnt = 0;
                    self.anchor_clk = clk_at(t, self.clk_hz);
                    self.update_event();
                    if self.cr1 & UDIS == 0 && self.cr1 & URS == 0 {
                        self.sr |= 1;
                    }
                    self.update_out1(t, false);
                }
                self.sr |= v & 0x1E;
            }
            0x18 => self.ccmr[0] = v,
            0x1C => self.ccmr[1] = v,
            0x20 => {
                self.ccer = v;
                self.update_out1(t, false);
            }
            0x24 => {
                self.cnt = v & max;
                self.anchor_clk = clk_at(t, self.clk_hz);
            }
            0x28 => self.psc = v & 0xFFFF,
            0x2C => {
                self.arr = v & max;
                if self.cr1 & ARPE == 0 {
                    self.arr_sh = self.arr;
                }
            }
            0x34..=0x40 => {
                let ch = ((off - 0x34) / 4) as usize;
                self.ccr[ch] = v & max;
                if !self.preload(ch) {
                    self.ccr_sh[ch] = self.ccr[ch];
                }
            }
            0x48 if !self.g4 => self.dcr = v,
            0x3DC if self.g4 => self.dcr = v,
            0x58..=0x64 if self.g4 => self.g4_extra[((off - 0x58) / 4) as usize] = v,
            _ => return Access::Unmodelled,
        }
        Access::Ok(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// TIM4 as embassy's Qei sets it up: CC1S = CC2S = 01, SMS = 011, ARR.
    fn encoder(arr: u32) -> Timer {
        let mut t = Timer::new(30, false, false);
        t.write(0x18, 0x0101, 0);
        t.write(0x08, 3, 0);
        t.write(0x2C, arr, 0);
        t.write(0x00, CEN, 0);
        t
    }

    fn quadrature(t: &mut Timer, phases: impl Iterator<Item = i64>) {
        for p in phases {
            let ab = match p.rem_euclid(4) {
                0 => [false, false],
                1 => [true, false],
                2 => [true, true],
                _ => [false, true],
            };
            t.inputs(ab, 0, true);
        }
    }

    #[test]
    fn encoder_mode_counts_every_edge_up_and_down_and_wraps_at_arr() {
        let mut t = encoder(99);
        quadrature(&mut t, 1..=10);
        assert!(matches!(t.read(0x24, 0), Access::Ok(10)));
        assert!(matches!(t.read(0x00, 0), Access::Ok(v) if v & DIR == 0));
        quadrature(&mut t, (-2..=9).rev());
        // 10 → -2: down through 0 to ARR, an update event on the way
        assert!(matches!(t.read(0x24, 0), Access::Ok(98)));
        assert!(matches!(t.read(0x00, 0), Access::Ok(v) if v & DIR != 0));
        assert!(matches!(t.read(0x10, 0), Access::Ok(v) if v & 1 != 0));
        // the firmware's read-modify-write of CR1 keeps the direction
        t.write(0x00, CEN | DIR, 0);
        quadrature(&mut t, -1..=0);
        assert!(matches!(t.read(0x24, 0), Access::Ok(0)));
    }

    #[test]
    fn encoder_modes_one_and_two_count_one_input_and_polarity_reverses() {
        let mut t = encoder(0xFFFF);
        t.write(0x08, 1, 0); // TI1FP1 edges only
        quadrature(&mut t, 1..=8);
        assert!(matches!(t.read(0x24, 0), Access::Ok(4)));
        t.write(0x08, 2, 0); // TI2FP2 edges only
        quadrature(&mut t, 9..=16);
        assert!(matches!(t.read(0x24, 0), Access::Ok(8)));
        t.write(0x08, 3, 0);
        t.write(0x20, 1 << 1, 0); // CC1P: TI1 inverted, the count reverses
        quadrature(&mut t, 17..=20);
        assert!(matches!(t.read(0x24, 0), Access::Ok(4)));
        t.write(0x00, 0, 0); // CEN off: edges are not counted
        quadrature(&mut t, 21..=24);
        assert!(matches!(t.read(0x24, 0), Access::Ok(4)));
    }
}
