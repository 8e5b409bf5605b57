//! The Cortex-M system control space (ARMv7-M ARM B3; PM0214 for the M4,
//! PM0056 for the M3): NVIC (ISER/ICER/ISPR/ICPR/IABR/IPR/STIR), SCB (CPUID,
//! ICSR, VTOR, AIRCR, SCR, CCR, SHPR, SHCSR, fault status, CPACR), SysTick,
//! DEMCR and the DWT cycle counter, and on the M4 the FPU's FPCCR/FPCAR.
//! Exception priority and preemption follow B1.5.4 (group priority from
//! AIRCR.PRIGROUP, PRIMASK and BASEPRI); 4 priority bits are implemented.

use crate::clock::clk_at;
use crate::periph::Access;

pub const PENDSV: usize = 14;
pub const SYSTICK: usize = 15;

#[derive(Debug)]
pub struct Scs {
    m4: bool,
    cpuid: u32,
    enabled: [bool; 16 + crate::chip::N_IRQ],
    pending: [bool; 16 + crate::chip::N_IRQ],
    /// Interrupt lines held high by peripherals (level-sensitive).
    level: [bool; crate::chip::N_IRQ],
    /// Active exceptions, innermost last.
    pub active: Vec<usize>,
    prio: [u8; 16 + crate::chip::N_IRQ],
    pub vtor: u32,
    aircr: u32,
    pub scr: u32,
    ccr: u32,
    shcsr: u32,
    cfsr: u32,
    hfsr: u32,
    cpacr: u32,
    fpccr: u32,
    fpcar: u32,
    fpdscr: u32,
    demcr: u32,
    dwt_ctrl: u32,
    /// CYCCNT = busy+sleep cycles - offset while enabled.
    cyc_offset: u64,
    cyc_frozen: u32,
    // SysTick
    st_csr: u32,
    st_rvr: u32,
    st_cvr_at: u32,
    st_anchor: u64,
    pub reset_request: bool,
}

impl Scs {
    pub fn new(m4: bool, cpuid: u32) -> Self {
        Self {
            m4,
            cpuid,
            enabled: [false; 16 + crate::chip::N_IRQ],
            pending: [false; 16 + crate::chip::N_IRQ],
            level: [false; crate::chip::N_IRQ],
            active: Vec::new(),
            prio: [0; 16 + crate::chip::N_IRQ],
            vtor: 0,
            aircr: 0,
            scr: 0,
            // STKALIGN: reset 1 on the M4, 0 on the M3 r1p1
            ccr: if m4 { 0x200 } else { 0 },
            shcsr: 0,
            cfsr: 0,
            hfsr: 0,
            cpacr: 0,
            fpccr: 0xC000_0000,
            fpcar: 0,
            fpdscr: 0,
            demcr: 0,
            dwt_ctrl: 0x4000_0000,
            cyc_offset: 0,
            cyc_frozen: 0,
            st_csr: 0,
            st_rvr: 0,
            st_cvr_at: 0,
            st_anchor: 0,
            reset_request: false,
        }
    }

    pub fn stkalign(&self) -> bool {
        self.ccr & 0x200 != 0
    }

    /// A peripheral's interrupt line. It pends its interrupt as the
    /// Cortex-M generic user guides put it ("Level-sensitive and pulse
    /// interrupts"): when the line is high and the interrupt not active,
    /// or on a rising edge. A line held high through its handler pends
    /// nothing more until the handler returns ([`Scs::exit`]).
    pub fn set_level(&mut self, irq: usize, high: bool) {
        let rising = high && !self.level[irq];
        self.level[irq] = high;
        if rising || (high && !self.active.contains(&(16 + irq))) {
            self.pending[16 + irq] = true;
        }
    }

    /// Group priority of exception `e` (negative for reset/NMI/HardFault).
    fn group_prio(&self, e: usize) -> i32 {
        match e {
            2 => -2,
            3 => -1,
            _ => {
                let g = ((self.aircr >> 8) & 7) + 1;
                ((self.prio[e] as u32 >> g) << g) as i32
            }
        }
    }
    fn is_enabled(&self, e: usize) -> bool {
        match e {
            2 | 3 | 11 | 14 | 15 => true,
            4..=6 => self.shcsr & (1 << (16 + e - 4)) != 0,
            _ => self.enabled[e],
        }
    }

    /// Execution priority from the active exceptions and the masks.
    pub fn exec_prio(&self, primask: bool, basepri: u8) -> i32 {
        let mut p = 256;
        for &e in &self.active {
            p = p.min(self.group_prio(e));
        }
        if basepri != 0 {
            let g = ((self.aircr >> 8) & 7) + 1;
            p = p.min(((basepri as u32 >> g) << g) as i32);
        }
        if primask {
            p = p.min(0);
        }
        p
    }

    /// The level of external interrupt line `irq`, as the peripherals set it.
    #[cfg(test)]
    pub fn line(&self, irq: usize) -> bool {
        self.level[irq]
    }

    /// The pending enabled exception with the highest priority.
    pub fn best_pending(&self) -> Option<(usize, i32)> {
        let mut best: Option<(usize, i32)> = None;
        for e in 2..self.pending.len() {
            if self.pending[e] && self.is_enabled(e) {
                let p = self.group_prio(e);
                if best.is_none_or(|(_, bp)| p < bp) {
                    best = Some((e, p));
                }
            }
        }
        best
    }

    /// The exception to take now, if any.
    pub fn take(&self, primask: bool, basepri: u8) -> Option<usize> {
        let (e, p) = self.best_pending()?;
        (p < self.exec_prio(primask, basepri)).then_some(e)
    }

    /// WFI/WFE wake-up: an exception that would preempt with PRIMASK clear.
    pub fn wakes(&self, basepri: u8) -> bool {
        self.take(false, basepri).is_some()
    }

    pub fn enter(&mut self, e: usize) {
        self.pending[e] = false;
        self.active.push(e);
    }

    pub fn exit(&mut self) -> Option<usize> {
        let e = self.active.pop()?;
        // a level-sensitive line still high pends its interrupt again
        if e >= 16 && self.level[e - 16] {
            self.pending[e] = true;
        }
        Some(e)
    }

    pub fn ipsr(&self) -> u32 {
        self.active.last().copied().unwrap_or(0) as u32
    }

    // SysTick, counting down at HCLK (CLKSOURCE = 1) or HCLK / 8
    fn st_hz(&self, hclk: u32) -> u64 {
        if self.st_csr & 4 != 0 {
            hclk as u64
        } else {
            hclk as u64 / 8
        }
    }
    pub fn systick_sync(&mut self, t: u64, hclk: u32) {
        if self.st_csr & 1 == 0 || self.st_rvr == 0 {
            return;
        }
        let hz = self.st_hz(hclk);
        let now = clk_at(t, hz);
        let elapsed = now.saturating_sub(self.st_anchor);
        if elapsed > self.st_cvr_at as u64 {
            let wraps = (elapsed - self.st_cvr_at as u64 - 1) / (self.st_rvr as u64 + 1) + 1;
            let used = self.st_cvr_at as u64 + 1 + (wraps - 1) * (self.st_rvr as u64 + 1);
            self.st_anchor += used;
            self.st_cvr_at = self.st_rvr;
            self.st_csr |= 1 << 16;
            if self.st_csr & 2 != 0 {
                self.pending[SYSTICK] = true;
            }
        }
    }
    pub fn systick_next(&self, hclk: u32) -> Option<u64> {
        if self.st_csr & 3 != 3 || self.st_rvr == 0 {
            return None;
        }
        let hz = self.st_hz(hclk);
        Some(crate::clock::time_of_clk(
            self.st_anchor + self.st_cvr_at as u64 + 1,
            hz,
        ))
    }
    fn systick_cvr(&self, t: u64, hclk: u32) -> u32 {
        if self.st_csr & 1 == 0 {
            return self.st_cvr_at;
        }
        let e = clk_at(t, self.st_hz(hclk)).saturating_sub(self.st_anchor);
        self.st_cvr_at.saturating_sub(e as u32)
    }

    /// `cycles`: core cycles since reset (busy + asleep), for CYCCNT.
    pub fn read(&mut self, a: u32, t: u64, hclk: u32, cycles: u64) -> Access {
        Access::Ok(match a {
            0xE000_1000 => self.dwt_ctrl,
            0xE000_1004 => {
                if self.dwt_ctrl & 1 != 0 {
                    (cycles - self.cyc_offset) as u32
                } else {
                    self.cyc_frozen
                }
            }
            0xE000_E004 => (crate::chip::N_IRQ as u32 / 32) - 1,
            0xE000_E010 => {
                self.systick_sync(t, hclk);
                let v = self.st_csr;
                self.st_csr &= !(1 << 16);
                v
            }
            0xE000_E014 => self.st_rvr,
            0xE000_E018 => self.systick_cvr(t, hclk),
            0xE000_E01C => 0x4000_0000,
            0xE000_E100..=0xE000_E13C => self.bits(&self.enabled, a - 0xE000_E100),
            0xE000_E180..=0xE000_E1BC => self.bits(&self.enabled, a - 0xE000_E180),
            0xE000_E200..=0xE000_E23C => self.bits(&self.pending, a - 0xE000_E200),
            0xE000_E280..=0xE000_E2BC => self.bits(&self.pending, a - 0xE000_E280),
            0xE000_E300..=0xE000_E33C => {
                let mut v = 0;
                for i in 0..32 {
                    let e = 16 + ((a - 0xE000_E300) * 8 + i) as usize;
                    if self.active.contains(&e) {
                        v |= 1 << i;
                    }
                }
                v
            }
            0xE000_E400..=0xE000_E46C => {
                let i = 16 + (a - 0xE000_E400) as usize;
                u32::from_le_bytes([
                    self.prio[i],
                    self.prio[i + 1],
                    self.prio[i + 2],
                    self.prio[i + 3],
                ])
            }
            0xE000_ED00 => self.cpuid,
            0xE000_ED04 => {
                let mut v = self.ipsr();
                if let Some((e, _)) = self.best_pending() {
                    v |= (e as u32) << 12;
                }
                if self.pending[16..].iter().any(|&p| p) {
                    v |= 1 << 22;
                }
                if self.pending[PENDSV] {
                    v |= 1 << 28;
                }
                if self.pending[SYSTICK] {
                    v |= 1 << 26;
                }
                if self.active.len() <= 1 {
                    v |= 1 << 11; // RETTOBASE
                }
                v
            }
            0xE000_ED08 => self.vtor,
            0xE000_ED0C => 0xFA05_0000 | (self.aircr & 0x700),
            0xE000_ED10 => self.scr,
            0xE000_ED14 => self.ccr,
            0xE000_ED18 | 0xE000_ED1C | 0xE000_ED20 => {
                let i = 4 + (a - 0xE000_ED18) as usize;
                u32::from_le_bytes([
                    self.prio[i],
                    self.prio[i + 1],
                    self.prio[i + 2],
                    self.prio[i + 3],
                ])
            }
            0xE000_ED24 => self.shcsr,
            0xE000_ED28 => self.cfsr,
            0xE000_ED2C => self.hfsr,
            0xE000_ED30 | 0xE000_ED34 | 0xE000_ED38 | 0xE000_ED3C => 0,
            0xE000_ED88 if self.m4 => self.cpacr,
            0xE000_EDF0 => 0, // DHCSR: no debugger attached (C_DEBUGEN = 0)
            0xE000_EDFC => self.demcr,
            0xE000_EF34 if self.m4 => self.fpccr,
            0xE000_EF38 if self.m4 => self.fpcar,
            0xE000_EF3C if self.m4 => self.fpdscr,
            0xE000_EF40 if self.m4 => 0x1011_0021,
            0xE000_EF44 if self.m4 => 0x1100_0011,
            _ => return Access::Unmodelled,
        })
    }

    fn bits(&self, v: &[bool], off: u32) -> u32 {
        let mut r = 0;
        for i in 0..32 {
            let e = 16 + (off * 8 + i) as usize;
            if e < v.len() && v[e] {
                r |= 1 << i;
            }
        }
        r
    }
    fn set_bits(v: &mut [bool], off: u32, w: u32, to: bool) {
        for i in 0..32 {
            let e = 16 + (off * 8 + i) as usize;
            if w & (1 << i) != 0 && e < v.len() {
                v[e] = to;
            }
        }
    }

    /// A write; `size` < 4 only for the byte-accessible priority registers.
    pub fn write(&mut self, a: u32, v: u32, size: usize, t: u64, hclk: u32, cycles: u64) -> Access {
        match a {
            0xE000_1000 => {
                if v & 1 != 0 && self.dwt_ctrl & 1 == 0 {
                    self.cyc_offset = cycles - self.cyc_frozen as u64;
                } else if v & 1 == 0 && self.dwt_ctrl & 1 != 0 {
                    self.cyc_frozen = (cycles - self.cyc_offset) as u32;
                }
                self.dwt_ctrl = (self.dwt_ctrl & 0xFFFF_0000) | (v & 0xFFFF);
            }
            0xE000_1004 => {
                self.cyc_frozen = v;
                self.cyc_offset = cycles.wrapping_sub(v as u64);
            }
            0xE000_E010 => {
                self.systick_sync(t, hclk);
                let start = v & 1 != 0 && self.st_csr & 1 == 0;
                self.st_csr = (self.st_csr & (1 << 16)) | (v & 7);
                if start {
                    self.st_anchor = clk_at(t, self.st_hz(hclk));
                }
            }
            0xE000_E014 => self.st_rvr = v & 0xFF_FFFF,
            // ARMv7-M ARM B3.3.1: a write clears the counter and COUNTFLAG
            // and does not trigger the exception logic; the next clock
            // reloads RVR, so the counter next reaches 0 RVR + 1 clocks on.
            // (Read back before that clock it shows RVR here, not 0.)
            0xE000_E018 => {
                self.st_cvr_at = self.st_rvr;
                self.st_anchor = clk_at(t, self.st_hz(hclk));
                self.st_csr &= !(1 << 16);
            }
            0xE000_E100..=0xE000_E13C => {
                Self::set_bits(&mut self.enabled, a - 0xE000_E100, v, true)
            }
            0xE000_E180..=0xE000_E1BC => {
                Self::set_bits(&mut self.enabled, a - 0xE000_E180, v, false)
            }
            0xE000_E200..=0xE000_E23C => {
                Self::set_bits(&mut self.pending, a - 0xE000_E200, v, true)
            }
            0xE000_E280..=0xE000_E2BC => {
                Self::set_bits(&mut self.pending, a - 0xE000_E280, v, false)
            }
            0xE000_E400..=0xE000_E46F => {
                let i = 16 + (a - 0xE000_E400) as usize;
                for k in 0..size {
                    self.prio[i + k] = ((v >> (8 * k)) as u8) & 0xF0;
                }
            }
            0xE000_ED04 => {
                if v & (1 << 28) != 0 {
                    self.pending[PENDSV] = true;
                }
                if v & (1 << 27) != 0 {
                    self.pending[PENDSV] = false;
                }
                if v & (1 << 26) != 0 {
                    self.pending[SYSTICK] = true;
                }
                if v & (1 << 25) != 0 {
                    self.pending[SYSTICK] = false;
                }
                if v & (1 << 31) != 0 {
                    self.pending[2] = true;
                }
            }
            0xE000_ED08 => self.vtor = v & 0xFFFF_FF80,
            0xE000_ED0C => {
                if v >> 16 == 0x05FA {
                    self.aircr = v & 0x700;
                    if v & 4 != 0 {
                        self.reset_request = true;
                    }
                }
            }
            0xE000_ED10 => self.scr = v & 0x16,
            0xE000_ED14 => self.ccr = v & 0x31B,
            0xE000_ED18..=0xE000_ED23 => {
                let i = 4 + (a - 0xE000_ED18) as usize;
                for k in 0..size {
                    self.prio[i + k] = ((v >> (8 * k)) as u8) & 0xF0;
                }
            }
            0xE000_ED24 => self.shcsr = v & 0x0007_0000,
            0xE000_ED28 => self.cfsr &= !v,
            0xE000_ED2C => self.hfsr &= !v,
            0xE000_ED88 if self.m4 => self.cpacr = v & 0x00F0_0000,
            0xE000_EDFC => self.demcr = v & 0x010F_07F1,
            0xE000_EF00 => {
                let e = 16 + (v & 0x1FF) as usize;
                if e < self.pending.len() {
                    self.pending[e] = true;
                }
            }
            0xE000_EF34 if self.m4 => self.fpccr = (self.fpccr & !0xC000_0000) | (v & 0xC000_0000),
            0xE000_EF38 if self.m4 => self.fpcar = v & !7,
            0xE000_EF3C if self.m4 => self.fpdscr = v & 0x07C0_0000,
            _ => return Access::Unmodelled,
        }
        Access::Ok(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_line_high_through_its_handler_pends_again_only_on_an_edge_or_at_return() {
        let (irq, e) = (11, 16 + 11);
        let mut s = Scs::new(true, 0);
        s.set_level(irq, true);
        assert!(s.pending[e], "high while not active");
        s.enter(e);
        assert!(!s.pending[e]);
        s.set_level(irq, true); // the handler has not cleared its flag yet
        assert!(!s.pending[e], "held high while active");
        s.set_level(irq, false); // now it has
        s.exit();
        assert!(!s.pending[e], "low at return");

        s.set_level(irq, true);
        s.enter(e);
        s.exit();
        assert!(s.pending[e], "still high at return");

        s.enter(e);
        s.set_level(irq, false);
        s.set_level(irq, true);
        assert!(s.pending[e], "a rising edge while active");
    }
}
