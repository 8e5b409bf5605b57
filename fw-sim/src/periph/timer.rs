//! Timers: the general-purpose TIM2/3/4 (RM0440 §30 on the G4, RM0008 §15 on
//! the F1) and the advanced-control TIM1/TIM8 (RM0440 §29, RM0008 §14).
//!
//! Modelled:
//! - the time base: up-counting edge-aligned, prescaler, ARR / PSC / CCRx
//!   preloads loaded at the update event (UEV), UDIS / URS, UG, one-pulse
//!   mode (OPM clears CEN at the UEV), and on the advanced timers the
//!   repetition counter (a UEV only every RCR + 1 overflows);
//! - the channels as output compare: OCxM frozen, active / inactive /
//!   toggle on match, force, PWM 1 / 2; CCxE / CCxP; the rc_w0 flags and
//!   EGR's CCxG / TG / BG;
//! - interrupts (one line, or the advanced timers' four: BRK, UP, TRG_COM,
//!   CC) and DMA requests (UDE, CCxDE, TDE) handed to the DMA model, with
//!   the DMA burst through DCR / DMAR (DBA, DBL);
//! - master mode: CR2.MMS reset / enable / update / compare pulse /
//!   OC1REF..OC4REF on TRGO; slave mode: SMCR.SMS reset, gated, trigger,
//!   external clock mode 1 from an internal trigger ITRx (the machine wires
//!   ITRx to the other timers' TRGO), and the encoder modes 1..3 from TI1 /
//!   TI2;
//! - on the advanced timers: the complementary outputs OC1N..OC3N, BDTR's
//!   MOE (the outputs' master enable), AOE, OSSR / OSSI, the break input
//!   (BKE, BKP; a pin or EGR.BG) that clears MOE and sets BIF, and the idle
//!   levels OISx / OISxN the outputs take while MOE is 0.
//!
//! The counter is lazy: it is computed from the timer-clock edges since an
//! anchor, and the machine asks for the next event (a compare match or an
//! overflow) and fires events one at a time in time order, so that a DMA
//! transfer or a slave timer acts at the event's emulated time.
//!
//! Not modelled (selecting it stops the runner, `Unsupported`):
//! down-counting and centre-aligned modes, input capture, dead time
//! (complementary outputs are modelled without it), channels 5 and 6, the G4's extended output modes
//! (OCxM[3]), external clock mode 2 (ECE), slave modes triggered by a timer
//! input or ETR, break 2.

use super::Access;
use crate::clock::{clk_at, time_of_clk};

/// What one event of a timer asks of the rest of the chip.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Fired {
    /// DMA requests: bit 0 update, bits 1..4 CC1..CC4, bit 5 trigger, bit 6
    /// commutation.
    pub dma: u8,
    /// TRGO rose (a pulse or a level going high) / fell (a level).
    pub trgo_rise: bool,
    pub trgo_fall: bool,
}

impl Fired {
    pub fn is_empty(&self) -> bool {
        *self == Fired::default()
    }
}

pub const DMA_UP: u8 = 1;
pub const DMA_TRIG: u8 = 1 << 5;
pub const DMA_COM: u8 = 1 << 6;

/// The timer's interrupt lines: one, or (advanced) BRK, UP, TRG_COM, CC.
#[derive(Clone, Copy, Debug)]
pub enum Irqs {
    One(usize),
    Split {
        brk: usize,
        up: usize,
        trg_com: usize,
        cc: usize,
    },
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    General16,
    General32,
    Advanced,
}

#[derive(Debug)]
pub struct Timer {
    pub irqs: Irqs,
    kind: Kind,
    g4: bool,
    clk_hz: u64,
    cr1: u32,
    cr2: u32,
    smcr: u32,
    dier: u32,
    sr: u32,
    ccmr: [u32; 3],
    ccer: u32,
    psc: u32,
    arr: u32,
    rcr: u32,
    ccr: [u32; 6],
    bdtr: u32,
    dcr: u32,
    /// The DMA burst's position (DMAR accesses since DCR or the burst's end).
    burst_index: u32,
    /// G4 DTR2, ECR, TISEL, AF1, AF2.
    g4_extra: [u32; 5],
    psc_sh: u32,
    arr_sh: u32,
    ccr_sh: [u32; 4],
    /// Repetition down-counter (advanced timers).
    rep: u32,
    cnt: u32,
    /// Timer-clock edge at which `cnt` held, on a prescaler boundary.
    anchor_clk: u64,
    /// External clock mode 1: TRGI edges since the last counter tick.
    ext_psc: u32,
    /// TRGI level (gated mode) and the break input's level (active high
    /// after BKP).
    trgi: bool,
    break_in: bool,
    oc_ref: [bool; 4],
    /// Output level of each output (false while undriven) and its changes
    /// since the machine last took them: index `ch` for OCx, `4 + ch` for
    /// the complementary OCxN.
    out: [bool; 8],
    pub edges: [Vec<(u64, bool)>; 8],
    /// TRGO as a level (MMS enable / OCxREF).
    trgo_level: bool,
    /// What the events since the machine last asked requested.
    pub fired: Fired,
    /// DMA requests no enabled channel has taken yet: a request stays
    /// asserted until a DMA channel serves it (RM0008 §13.3.1, RM0440
    /// §12.4.1), so enabling the channel later serves it then.
    pub dma_pending: u8,
    /// Update events that came with UIF still set and its interrupt
    /// enabled: an update interrupt that did not run between two of them
    /// (with preloads, the period before ran again unchanged).
    pub missed_updates: u64,
    /// The levels of the TI1 and TI2 inputs (the channel 1 and 2 pins).
    ti: [bool; 2],
    /// `next_internal` as last computed; `None` once anything it depends
    /// on changed (a write, an event, a trigger, an input, the clock).
    next_cache: Option<Option<u64>>,
}

const CEN: u32 = 1;
const UDIS: u32 = 1 << 1;
const URS: u32 = 1 << 2;
const OPM: u32 = 1 << 3;
const DIR: u32 = 1 << 4;
const CMS: u32 = 3 << 5;
const ARPE: u32 = 1 << 7;
const UIFREMAP: u32 = 1 << 11;
const MOE: u32 = 1 << 15;
const AOE: u32 = 1 << 14;
const BKP: u32 = 1 << 13;
const BKE: u32 = 1 << 12;
const OSSI: u32 = 1 << 10;
const OSSR: u32 = 1 << 11;
const UIF: u32 = 1;
const TIF: u32 = 1 << 6;
const BIF: u32 = 1 << 7;

impl Timer {
    pub fn new(irqs: Irqs, g4: bool, kind: Kind) -> Self {
        let max = if kind == Kind::General32 {
            u32::MAX
        } else {
            0xFFFF
        };
        // G4 TIMx_AF1 resets with BKINE = 1 on the advanced timers
        let af1 = if g4 && kind == Kind::Advanced { 1 } else { 0 };
        Self {
            irqs,
            kind,
            g4,
            clk_hz: 8_000_000,
            cr1: 0,
            cr2: 0,
            smcr: 0,
            dier: 0,
            sr: 0,
            ccmr: [0; 3],
            ccer: 0,
            psc: 0,
            arr: max,
            rcr: 0,
            ccr: [0; 6],
            bdtr: 0,
            dcr: 0,
            burst_index: 0,
            g4_extra: [0, 0, 0, af1, 0],
            psc_sh: 0,
            arr_sh: max,
            ccr_sh: [0; 4],
            rep: 0,
            cnt: 0,
            anchor_clk: 0,
            ext_psc: 0,
            trgi: false,
            break_in: false,
            oc_ref: [false; 4],
            out: [false; 8],
            edges: Default::default(),
            trgo_level: false,
            fired: Fired::default(),
            dma_pending: 0,
            missed_updates: 0,
            ti: [false; 2],
            next_cache: None,
        }
    }

    fn advanced(&self) -> bool {
        self.kind == Kind::Advanced
    }
    fn max(&self) -> u32 {
        if self.kind == Kind::General32 {
            u32::MAX
        } else {
            0xFFFF
        }
    }
    /// SMS with the G4's fourth bit (SMCR bit 16).
    fn sms(&self) -> u32 {
        (self.smcr & 7)
            | if self.g4 {
                ((self.smcr >> 16) & 1) << 3
            } else {
                0
            }
    }
    /// TS with the G4's high bits (SMCR bits 21:20).
    pub fn ts(&self) -> u32 {
        ((self.smcr >> 4) & 7)
            | if self.g4 {
                ((self.smcr >> 20) & 3) << 3
            } else {
                0
            }
    }
    /// The internal trigger ITRx the slave mode listens to, if any.
    pub fn slave_itr(&self) -> Option<u32> {
        if !matches!(self.sms(), 4..=7) {
            return None;
        }
        match self.ts() {
            x @ 0..=3 => Some(x),
            x @ 8..=15 => Some(x - 4),
            _ => None,
        }
    }
    /// Gated slave mode (SMS 101), and the TRGI level it holds.
    pub fn gated(&self) -> bool {
        self.sms() == 5
    }
    pub fn trgi(&self) -> bool {
        self.trgi
    }
    /// TRGO as a level (MMS enable / OCxREF; pulses are not levels).
    pub fn trgo_level(&self) -> bool {
        self.trgo_level
    }
    fn encoder(&self) -> bool {
        matches!(self.sms(), 1..=3)
    }
    /// The counter runs from the timer clock now.
    fn clocked(&self) -> bool {
        self.cr1 & CEN != 0
            && match self.sms() {
                1..=3 | 7 => false,
                5 => self.trgi,
                _ => true,
            }
    }
    fn period(&self) -> u64 {
        self.psc_sh as u64 + 1
    }

    /// The timer kernel clock changed (RCC): re-anchor at `now`.
    pub fn set_clock(&mut self, hz: u64, now: u64) {
        if hz != self.clk_hz {
            self.catch_up(now);
            self.next_cache = None;
            self.clk_hz = hz;
            self.anchor_clk = clk_at(now, hz);
        }
    }

    /// Interrupt lines with their levels (the first `n` of the array).
    pub fn irq_levels(&self) -> ([(usize, bool); 4], usize) {
        let p = self.sr & self.dier;
        match self.irqs {
            Irqs::One(n) => ([(n, p & 0xDF != 0); 4], 1),
            Irqs::Split {
                brk,
                up,
                trg_com,
                cc,
            } => (
                [
                    (brk, p & BIF != 0),
                    (up, p & UIF != 0),
                    (trg_com, p & (TIF | 1 << 5) != 0),
                    (cc, p & 0x1E != 0),
                ],
                4,
            ),
        }
    }

    fn ocm(&self, ch: usize) -> u32 {
        (self.ccmr[ch / 2] >> ((ch % 2) * 8 + 4)) & 7
    }
    fn is_output(&self, ch: usize) -> bool {
        (self.ccmr[ch / 2] >> ((ch % 2) * 8)) & 3 == 0
    }
    fn preload(&self, ch: usize) -> bool {
        (self.ccmr[ch / 2] >> ((ch % 2) * 8 + 3)) & 1 != 0
    }

    /// OCxREF after a compare match (`on_match`) or, for the level modes,
    /// at the current count.
    fn eval_ref(&mut self, ch: usize, on_match: bool) {
        let (c, ccr) = (self.cnt, self.ccr_sh[ch]);
        let mode = self.ocm(ch);
        let r = &mut self.oc_ref[ch];
        match mode {
            1 if on_match => *r = true,
            2 if on_match => *r = false,
            3 if on_match => *r = !*r,
            4 => *r = false,
            5 => *r = true,
            6 => *r = c < ccr,
            7 => *r = c >= ccr,
            _ => {}
        }
    }

    /// Output `ch` (OCx) or, with `n`, its complement OCxN drives its pin
    /// (TIM1/TIM8 have OC1N..OC3N).
    pub fn output_enabled(&self, ch: usize, n: bool) -> bool {
        let bit = if n { 4 * ch + 2 } else { 4 * ch };
        (!n || (self.advanced() && ch < 3)) && self.ccer & (1 << bit) != 0
    }

    /// The level output `ch` (OCx, or with `n` OCxN) drives on its pin
    /// (false while undriven), per RM0440 §29.6.11 / RM0008 §14.4.9 table
    /// "Output control bits for complementary OCx and OCxN channels with
    /// break feature":
    /// - general-purpose timers: OCx = OCxREF ^ CCxP while CCxE is set;
    /// - TIM1/TIM8 with MOE set: an output alone is OCxREF ^ its polarity
    ///   (CCxP / CCxNP); with both enabled OCxN is the complement,
    ///   !OCxREF ^ CCxNP (no dead time: DTG must be 0 then); a disabled
    ///   output with the other enabled shows its inactive level when OSSR
    ///   is set, else it is released;
    /// - with MOE clear an enabled output shows its idle level OISx /
    ///   OISxN when OSSI is set and is released when OSSI is clear.
    ///
    /// A released output reads low here.
    pub fn pin_level(&self, ch: usize, n: bool) -> bool {
        let e = self.output_enabled(ch, false);
        let ne = self.output_enabled(ch, true);
        let (me, other) = if n { (ne, e) } else { (e, ne) };
        let pol = self.ccer & (1 << (4 * ch + if n { 3 } else { 1 })) != 0;
        if !self.advanced() {
            return e && !n && self.oc_ref[ch] ^ pol;
        }
        if self.bdtr & MOE == 0 {
            let ois = self.cr2 & (1 << (8 + 2 * ch + usize::from(n))) != 0;
            return me && self.bdtr & OSSI != 0 && ois;
        }
        if !me {
            return other && self.bdtr & OSSR != 0 && pol;
        }
        let r = if n && e {
            !self.oc_ref[ch]
        } else {
            self.oc_ref[ch]
        };
        r ^ pol
    }

    /// Records edges of the outputs and TRGO's level after a change at `t`.
    fn refresh(&mut self, t: u64) {
        for i in 0..8 {
            let l = self.pin_level(i % 4, i >= 4);
            if l != self.out[i] {
                self.out[i] = l;
                self.edges[i].push((t, l));
            }
        }
        let level = match (self.cr2 >> 4) & 7 {
            1 => self.cr1 & CEN != 0,
            m @ 4..=7 => self.oc_ref[(m - 4) as usize],
            _ => false,
        };
        if level != self.trgo_level {
            self.trgo_level = level;
            if level {
                self.fired.trgo_rise = true;
            } else {
                self.fired.trgo_fall = true;
            }
        }
    }

    /// The update event: flags, preloads, DMA, TRGO, OPM, AOE.
    fn update_event(&mut self, from_counter: bool) {
        if self.cr1 & UDIS != 0 {
            return;
        }
        if from_counter || self.cr1 & URS == 0 {
            if self.sr & self.dier & UIF != 0 {
                self.missed_updates += 1;
            }
            self.sr |= UIF;
            if self.dier & (1 << 8) != 0 {
                self.fired.dma |= DMA_UP;
            }
        }
        self.psc_sh = self.psc;
        self.arr_sh = self.arr;
        self.rep = self.rcr;
        for ch in 0..4 {
            self.ccr_sh[ch] = self.ccr[ch];
        }
        // TRGO: MMS update on every UEV, MMS reset on UG (and a reset by
        // the slave controller)
        let mms = (self.cr2 >> 4) & 7;
        if mms == 2 || (mms == 0 && !from_counter) {
            self.fired.trgo_rise = true;
        }
        if self.cr1 & OPM != 0 && from_counter {
            self.cr1 &= !CEN;
        }
        if self.advanced() && self.bdtr & AOE != 0 && !self.break_active() {
            self.bdtr |= MOE;
        }
    }

    fn compare(&mut self, ch: usize) {
        self.sr |= 2 << ch;
        if self.dier & (1 << (9 + ch)) != 0 {
            self.fired.dma |= 2 << ch;
        }
        if ch == 0 && (self.cr2 >> 4) & 7 == 3 {
            self.fired.trgo_rise = true;
        }
        self.eval_ref(ch, true);
    }

    /// The counter wrapped from ARR to 0.
    fn overflow(&mut self, at: u64) {
        self.cnt = 0;
        let uev = if self.advanced() {
            if self.rep == 0 {
                true
            } else {
                self.rep -= 1;
                false
            }
        } else {
            true
        };
        if uev {
            self.update_event(true);
        }
        for ch in 0..4 {
            if !self.is_output(ch) {
                continue;
            }
            if self.ccr_sh[ch] == 0 {
                self.compare(ch);
            } else {
                self.eval_ref(ch, false);
            }
        }
        self.refresh(at);
    }

    /// One counter clock (external clock, encoder up).
    fn tick(&mut self, at: u64) {
        if self.cnt >= self.arr_sh {
            self.overflow(at);
            return;
        }
        self.cnt += 1;
        for ch in 0..4 {
            if self.is_output(ch) && self.ccr_sh[ch] == self.cnt {
                self.compare(ch);
            } else if self.is_output(ch) {
                self.eval_ref(ch, false);
            }
        }
        self.refresh(at);
    }

    /// Ticks from `cnt` to the next event: (ticks, is_overflow, channels).
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

    /// The time of the next event of the counter running from the timer
    /// clock (a compare match or an overflow), if it runs.
    pub fn next_internal(&mut self) -> Option<u64> {
        if let Some(n) = self.next_cache {
            return n;
        }
        let n = self.compute_next();
        self.next_cache = Some(n);
        n
    }
    fn compute_next(&self) -> Option<u64> {
        if !self.clocked() {
            return None;
        }
        let (k, _, _) = self.next_step(self.cnt);
        Some(time_of_clk(
            self.anchor_clk + k * self.period(),
            self.clk_hz,
        ))
    }

    /// Brings the counter to time `t` without passing an event: one due
    /// at or before `t` stays for [`Timer::fire`].
    pub fn catch_up(&mut self, t: u64) {
        // a stopped counter needs no anchor: every way of starting it
        // (CEN, a trigger, the gate, SMCR) sets one
        if !self.clocked() {
            return;
        }
        let now_clk = clk_at(t, self.clk_hz);
        if now_clk <= self.anchor_clk {
            return;
        }
        let avail = (now_clk - self.anchor_clk) / self.period();
        let (k, _, _) = self.next_step(self.cnt);
        let n = avail.min(k - 1);
        self.cnt += n as u32;
        self.anchor_clk += n * self.period();
    }

    /// Fires the event [`Timer::next_internal`] names.
    pub fn fire(&mut self) {
        self.next_cache = None;
        let (k, ovf, chans) = self.next_step(self.cnt);
        self.anchor_clk += k * self.period();
        let at = time_of_clk(self.anchor_clk, self.clk_hz);
        if ovf {
            self.overflow(at);
            return;
        }
        self.cnt += k as u32;
        for ch in 0..4 {
            if chans & (1 << ch) != 0 {
                self.compare(ch);
            } else if self.is_output(ch) {
                self.eval_ref(ch, false);
            }
        }
        self.refresh(at);
    }

    /// A moment far enough ahead to check again, for the runner's slices:
    /// the next event.
    pub fn next_event(&self) -> Option<u64> {
        self.next_cache.unwrap_or_else(|| self.compute_next())
    }

    /// An edge of TRGI (the selected ITRx, i.e. another timer's TRGO) at
    /// `t`: RM0440 §29.3.26 / §30.4.20, RM0008 §14.3.14 / §15.3.14.
    pub fn trigger_input(&mut self, rising: bool, t: u64) {
        self.catch_up(t);
        self.next_cache = None;
        let sms = self.sms();
        if !matches!(sms, 4..=7) {
            return;
        }
        // TIF on the active edge (both edges in gated mode)
        if rising || sms == 5 {
            self.sr |= TIF;
            if self.dier & (1 << 14) != 0 {
                self.fired.dma |= DMA_TRIG;
            }
        }
        match sms {
            4 if rising => {
                self.cnt = 0;
                self.ext_psc = 0;
                self.anchor_clk = clk_at(t, self.clk_hz);
                self.update_event(false);
                for ch in 0..4 {
                    self.eval_ref(ch, false);
                }
            }
            5 => {
                self.trgi = rising;
                self.anchor_clk = clk_at(t, self.clk_hz);
            }
            6 if rising && self.cr1 & CEN == 0 => {
                self.cr1 |= CEN;
                self.anchor_clk = clk_at(t, self.clk_hz);
            }
            7 if rising && self.cr1 & CEN != 0 => {
                // the prescaler divides the external clock too
                self.ext_psc += 1;
                if self.ext_psc > self.psc_sh {
                    self.ext_psc = 0;
                    self.tick(t);
                }
            }
            _ => {}
        }
        self.refresh(t);
    }

    /// The break input's level (the pin, before BKP) at `t`.
    pub fn break_pin(&mut self, level: bool, t: u64) {
        self.catch_up(t);
        let af1_bkine = !self.g4 || self.g4_extra[3] & 1 != 0;
        let pol_inv = self.g4 && self.g4_extra[3] & (1 << 9) != 0;
        self.break_in = af1_bkine && (level ^ pol_inv);
        if self.break_active() {
            self.do_break(t);
        }
    }
    /// BKE: the break input matters.
    pub fn break_enabled(&self) -> bool {
        self.advanced() && self.bdtr & BKE != 0
    }
    fn break_active(&self) -> bool {
        self.advanced() && self.bdtr & BKE != 0 && (self.break_in == (self.bdtr & BKP != 0))
    }
    fn do_break(&mut self, t: u64) {
        self.bdtr &= !MOE;
        self.sr |= BIF;
        self.refresh(t);
    }

    /// The TI1 / TI2 input pins are at `ti` from time `t` on. In encoder
    /// mode (SMS 001..011, with CEN) the counter follows each edge: RM0440
    /// §30.4.22 / RM0008 §15.3.12, table "Counting direction versus
    /// encoder signals". TI1FP1 and TI2FP2 are the inputs after the CC1P /
    /// CC2P polarity; the input filters are not modelled (clean edges).
    /// Encoder mode 1 counts on TI1FP1 edges, mode 2 on TI2FP2 edges (the
    /// SMCR field descriptions of RM0440), mode 3 on both. Only one input
    /// may change per call (a quadrature signal never moves both at once).
    /// `routed`: the pins reach the timer (their alternate function).
    pub fn inputs(&mut self, ti: [bool; 2], t: u64, routed: bool) {
        self.catch_up(t);
        self.next_cache = None;
        let before = self.ti;
        self.ti = ti;
        if !routed || !self.encoder() || self.cr1 & CEN == 0 {
            return;
        }
        let pol = [self.ccer & 2 != 0, self.ccer & (1 << 5) != 0];
        let fp = |l: [bool; 2]| [l[0] ^ pol[0], l[1] ^ pol[1]];
        let (old, new) = (fp(before), fp(ti));
        let sms = self.sms();
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
        if up {
            self.tick(t);
        } else if self.cnt == 0 {
            // underflow: the counter reloads ARR, a UEV
            self.cnt = self.arr_sh;
            self.update_event(true);
            self.refresh(t);
        } else {
            self.cnt -= 1;
            for ch in 0..4 {
                if self.is_output(ch) && self.ccr_sh[ch] == self.cnt {
                    self.compare(ch);
                }
            }
            self.refresh(t);
        }
    }

    /// The register DMAR reaches now (DBA + the burst index), and the
    /// index moved on: RM0440 §29.6.25 / RM0008 §14.4.19 (TIMx_DMAR).
    fn burst_target(&mut self) -> u32 {
        let dba = self.dcr & 0x1F;
        let dbl = (self.dcr >> 8) & 0x1F;
        let off = 4 * (dba + self.burst_index);
        self.burst_index = if self.burst_index >= dbl {
            0
        } else {
            self.burst_index + 1
        };
        off
    }
    /// A DMA burst is under way (more DMAR transfers belong to it).
    pub fn burst_pending(&self) -> bool {
        self.burst_index != 0
    }
    fn dmar_offset(&self) -> u32 {
        if self.g4 {
            0x3E0
        } else {
            0x4C
        }
    }

    pub fn read(&mut self, off: u32, t: u64) -> Access {
        self.catch_up(t);
        if off == self.dmar_offset() {
            let target = self.burst_target();
            if target == off {
                return Access::Unsupported("DMAR addressing itself");
            }
            return self.read(target, t);
        }
        let adv = self.advanced();
        let g4 = self.g4;
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
                let uifcpy = if g4 && self.cr1 & UIFREMAP != 0 {
                    (self.sr & 1) << 31
                } else {
                    0
                };
                self.cnt | uifcpy
            }
            0x28 => self.psc,
            0x2C => self.arr,
            0x30 if adv => self.rcr,
            // reserved in the general-purpose timers' map (RM0440 §30.5,
            // RM0008 §15.4): a DMA burst from ARR to CCR1 passes it
            0x30 => 0,
            0x34..=0x40 => self.ccr[((off - 0x34) / 4) as usize],
            0x44 if adv => self.bdtr,
            0x48 if adv && g4 => self.ccr[4],
            0x4C if adv && g4 => self.ccr[5],
            0x50 if adv && g4 => self.ccmr[2],
            0x54 if adv && g4 => self.g4_extra[0],
            0x48 if !g4 => self.dcr,
            0x3DC if g4 => self.dcr,
            0x58..=0x64 if g4 => self.g4_extra[((off - 0x58) / 4 + 1) as usize],
            _ => return Access::Unmodelled,
        })
    }

    pub fn write(&mut self, off: u32, v: u32, t: u64) -> Access {
        self.catch_up(t);
        self.next_cache = None;
        if off == self.dmar_offset() {
            let target = self.burst_target();
            if target == off {
                return Access::Unsupported("DMAR addressing itself");
            }
            return self.write(target, v, t);
        }
        let max = self.max();
        let adv = self.advanced();
        let g4 = self.g4;
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
                let sms = (v & 7) | if g4 { ((v >> 16) & 1) << 3 } else { 0 };
                let ts = ((v >> 4) & 7) | if g4 { ((v >> 20) & 3) << 3 } else { 0 };
                if sms > 7 {
                    return Access::Unsupported("combined reset + trigger slave mode");
                }
                if v & (1 << 14) != 0 {
                    return Access::Unsupported("external clock mode 2 (ECE)");
                }
                if matches!(sms, 4..=7) && matches!(ts, 4..=7) {
                    return Access::Unsupported(
                        "slave mode triggered by TI1F_ED/TI1FP1/TI2FP2/ETRF",
                    );
                }
                self.catch_up(t);
                self.smcr = v;
                self.anchor_clk = clk_at(t, self.clk_hz);
            }
            0x0C => {
                self.dier = v & 0x7FFF;
                // a request whose enable is cleared is withdrawn
                let de = (self.dier >> 8) & 0x7F;
                self.dma_pending &= de as u8;
            }
            // rc_w0: writing 1 leaves a flag, 0 clears it
            0x10 => self.sr &= v | !0x1FFF,
            0x14 => {
                if v & 1 != 0 {
                    self.cnt = 0;
                    self.ext_psc = 0;
                    self.anchor_clk = clk_at(t, self.clk_hz);
                    self.update_event(false);
                    for ch in 0..4 {
                        self.eval_ref(ch, false);
                    }
                }
                for ch in 0..4 {
                    if v & (2 << ch) != 0 {
                        self.compare(ch);
                    }
                }
                if v & (1 << 5) != 0 && adv {
                    self.sr |= 1 << 5;
                    if self.dier & (1 << 13) != 0 {
                        self.fired.dma |= DMA_COM;
                    }
                }
                if v & (1 << 6) != 0 {
                    self.sr |= TIF;
                    if self.dier & (1 << 14) != 0 {
                        self.fired.dma |= DMA_TRIG;
                    }
                }
                if v & (1 << 7) != 0 && adv {
                    self.do_break(t);
                }
            }
            0x18 | 0x1C => {
                let i = ((off - 0x18) / 4) as usize;
                if g4 && v & ((1 << 16) | (1 << 24)) != 0 {
                    return Access::Unsupported("extended output compare mode (OCxM[3])");
                }
                self.ccmr[i] = v;
                for ch in 2 * i..2 * i + 2 {
                    self.eval_ref(ch, false);
                }
            }
            0x20 => {
                if adv && v & (1 << 14) != 0 {
                    return Access::Unsupported("the complementary output OC4N (CC4NE)");
                }
                let both = (0..3).any(|ch| v & (5 << (4 * ch)) == 5 << (4 * ch));
                if adv && both && self.bdtr & 0xFF != 0 {
                    return Access::Unsupported("dead-time insertion (DTG with CCxE and CCxNE)");
                }
                for ch in 0..4 {
                    let enabled = v & (1 << (4 * ch)) != 0;
                    // TI1 / TI2 on their own channel feed the encoder
                    // mode; captures are not modelled
                    let ccs = (self.ccmr[ch / 2] >> ((ch % 2) * 8)) & 3;
                    let ti_input = ch < 2 && ccs == 1;
                    if enabled && !self.is_output(ch) && !ti_input {
                        return Access::Unsupported("input capture");
                    }
                }
                self.ccer = v;
            }
            0x24 => {
                self.cnt = v & max;
                self.anchor_clk = clk_at(t, self.clk_hz);
                for ch in 0..4 {
                    self.eval_ref(ch, false);
                }
            }
            0x28 => self.psc = v & 0xFFFF,
            0x2C => {
                self.arr = v & max;
                if self.cr1 & ARPE == 0 {
                    self.arr_sh = self.arr;
                }
            }
            0x30 if adv => self.rcr = v & if g4 { 0xFFFF } else { 0xFF },
            0x30 => {}
            0x34..=0x40 => {
                let ch = ((off - 0x34) / 4) as usize;
                self.ccr[ch] = v & max;
                if !self.preload(ch) {
                    self.ccr_sh[ch] = self.ccr[ch];
                    self.eval_ref(ch, false);
                }
            }
            0x44 if adv => {
                if g4 && v & (1 << 24) != 0 {
                    return Access::Unsupported("break 2 (BK2E)");
                }
                let both = (0..3).any(|ch| self.ccer & (5 << (4 * ch)) == 5 << (4 * ch));
                if both && v & 0xFF != 0 {
                    return Access::Unsupported("dead-time insertion (DTG with CCxE and CCxNE)");
                }
                // an active break input clears MOE again as the machine
                // reads the pin right after this write (Machine::write)
                self.bdtr = v;
            }
            0x48 if adv && g4 => self.ccr[4] = v,
            0x4C if adv && g4 => self.ccr[5] = v,
            0x50 if adv && g4 => {
                if v & 0x0101_7070 != 0 && self.ccer & 0x0011_0000 != 0 {
                    return Access::Unsupported("channels 5 and 6");
                }
                self.ccmr[2] = v
            }
            0x54 if adv && g4 => self.g4_extra[0] = v,
            0x48 if !g4 => {
                self.dcr = v & 0x1F1F;
                self.burst_index = 0;
            }
            0x3DC if g4 => {
                self.dcr = v & 0x1F1F;
                self.burst_index = 0;
            }
            0x58..=0x64 if g4 => self.g4_extra[((off - 0x58) / 4 + 1) as usize] = v,
            _ => return Access::Unmodelled,
        }
        self.refresh(t);
        Access::Ok(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// TIM4 as embassy's Qei sets it up: CC1S = CC2S = 01, SMS = 011, ARR.
    fn encoder(arr: u32) -> Timer {
        let mut t = Timer::new(Irqs::One(30), false, Kind::General16);
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
