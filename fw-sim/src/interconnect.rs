//! What connects the timers to each other and to the DMA controllers:
//! timer events fired in time order across all timers, TRGO into the
//! slaves' ITRx inputs (chip::itr_source), the timers' DMA requests to
//! their DMA channel (F1: fixed, RM0008 table 78; G4: through DMAMUX1,
//! RM0440 table 91), the DMA transfers on the chip's bus, and the break
//! inputs from their pins. Methods of the machine, kept apart from its
//! register bus (machine.rs).

use crate::chip::{self, pins, tim, Kind};
use crate::machine::Machine;
use crate::periph::dma::Transfer;
use crate::periph::gpio::Mode;
use crate::periph::Access;

/// How deep one event may chain through slaves and DMA writes before the
/// set-up is taken for a loop (a timer clocking itself through others).
const MAX_CHAIN: u32 = 16;

impl Machine {
    /// Fires every timer event up to `t`, earliest first, each with what
    /// it requests (DMA, slave triggers) done at its own time; then brings
    /// every counter to `t`.
    pub(crate) fn run_timers(&mut self, t: u64) {
        loop {
            let mut best: Option<(usize, u64)> = None;
            for (i, tm) in self.tim.iter_mut().enumerate() {
                if let Some(e) = tm.next_internal() {
                    if e <= t && best.is_none_or(|b| e < b.1) {
                        best = Some((i, e));
                    }
                }
            }
            let Some((i, e)) = best else { break };
            self.tim[i].fire();
            self.timer_requests(e);
            if self.fault.is_some() {
                break;
            }
        }
        // the counters themselves stay lazy: a read or write catches its
        // timer up to its own time
    }

    /// Serves what the timers asked for at `t` (after an event or a
    /// register write), until nothing is left.
    pub(crate) fn timer_requests(&mut self, t: u64) {
        // a DMA write into a timer can request DMA again at the same
        // instant (UG through a burst); a chain this deep is a loop
        if self.chain_depth >= MAX_CHAIN {
            self.fail("timers and DMA request each other in a loop".into());
            return;
        }
        self.chain_depth += 1;
        self.timer_requests_inner(t);
        self.chain_depth -= 1;
    }

    fn timer_requests_inner(&mut self, t: u64) {
        for _ in 0..MAX_CHAIN {
            let Some(i) = self.tim.iter().position(|tm| !tm.fired.is_empty()) else {
                return;
            };
            let f = std::mem::take(&mut self.tim[i].fired);
            for bit in 0..7 {
                if f.dma & (1 << bit) != 0 {
                    self.dma_request(i, bit, t);
                }
            }
            if f.trgo_rise || f.trgo_fall {
                for j in 0..self.tim.len() {
                    let from_i = self.tim[j]
                        .slave_itr()
                        .and_then(|itr| chip::itr_source(self.chip.kind, j, itr))
                        == Some(i);
                    if j != i && from_i {
                        if f.trgo_rise {
                            self.tim[j].trigger_input(true, t);
                        }
                        if f.trgo_fall {
                            self.tim[j].trigger_input(false, t);
                        }
                    }
                }
            }
        }
        if self.tim.iter().any(|tm| !tm.fired.is_empty()) {
            self.fail("timers trigger each other in a loop (TRGO / DMA chain)".into());
        }
    }

    /// After a register write: a slave mode listening to an ITRx the chip
    /// has no timer for (or one the model lacks) is refused; a gated
    /// slave takes its master's TRGO level as it is now (the gate is a
    /// level, not an edge).
    pub(crate) fn check_slaves(&mut self, t: u64) -> Result<(), String> {
        for j in 0..self.tim.len() {
            let Some(itr) = self.tim[j].slave_itr() else {
                continue;
            };
            let Some(src) = chip::itr_source(self.chip.kind, j, itr) else {
                return Err(format!(
                    "slave mode on ITR{itr} of timer #{j}: no modelled timer there"
                ));
            };
            let level = self.tim[src].trgo_level();
            if self.tim[j].gated() && self.tim[j].trgi() != level {
                self.tim[j].trigger_input(level, t);
            }
        }
        self.timer_requests(t);
        Ok(())
    }

    /// A DMA channel was enabled: the requests waiting for one.
    pub(crate) fn serve_pending(&mut self, t: u64) {
        for i in 0..self.tim.len() {
            let p = self.tim[i].dma_pending;
            for bit in 0..7 {
                if p & (1 << bit) != 0 {
                    self.dma_request(i, bit, t);
                }
            }
        }
        self.timer_requests(t);
    }

    /// Request `bit` of timer `i` (see `timer::Fired::dma`) to the DMA
    /// channels it reaches, served by priority then channel number; kept
    /// pending while no enabled channel takes it.
    fn dma_request(&mut self, i: usize, bit: u32, t: u64) {
        let mut chans: Vec<(usize, usize)> = Vec::new();
        match self.chip.kind {
            Kind::F103 => {
                if let Some(c) = chip::f1_dma_channel(i, bit) {
                    chans.push((0, c - 1));
                }
            }
            Kind::G431 => {
                if let Some(id) = chip::g4_request_id(i, bit) {
                    for m in self.dmamux.routes(id) {
                        chans.push((m / 6, m % 6));
                    }
                }
            }
        }
        chans.sort_by_key(|&(d, c)| (d, std::cmp::Reverse(self.dma[d].priority(c)), c));
        let taken = chans
            .iter()
            .any(|&(d, c)| self.dma[d].next_transfer(c).is_some());
        if taken {
            self.tim[i].dma_pending &= !(1 << bit);
        } else {
            self.tim[i].dma_pending |= 1 << bit;
        }
        for (d, c) in chans {
            // a burst through DMAR holds the request until DBL + 1 items
            while let Some(x) = self.dma[d].next_transfer(c) {
                let ok = self.bus_transfer(x, t);
                self.dma[d].done(c, ok);
                if !ok || !self.tim[i].burst_pending() || self.fault.is_some() {
                    break;
                }
            }
        }
    }

    /// A memory-to-memory channel enabled at `t` moves all its items.
    pub(crate) fn mem2mem(&mut self, d: usize, c: usize, t: u64) {
        while self.dma[d].mem2mem_ready(c) && self.fault.is_none() {
            let Some(x) = self.dma[d].next_transfer(c) else {
                break;
            };
            let ok = self.bus_transfer(x, t);
            self.dma[d].done(c, ok);
        }
    }

    /// One DMA item on the bus: `false` for a bus error (an address in no
    /// memory or peripheral region). A modelled region's missing register
    /// stops the run, as for the CPU.
    fn bus_transfer(&mut self, x: Transfer, t: u64) -> bool {
        let Some(v) = self.bus_read(x.src, x.src_size, t) else {
            return false;
        };
        let v = if x.dst_size < 4 {
            v & ((1u32 << (8 * x.dst_size)) - 1)
        } else {
            v
        };
        self.bus_write(x.dst, x.dst_size, v, t)
    }

    fn bus_read(&mut self, a: u32, n: usize, t: u64) -> Option<u32> {
        if let Some(m) = self.sram.as_ref().filter(|m| m.contains(a, n)) {
            return Some(m.read(a, n));
        }
        if let Some(m) = self.code.as_ref().filter(|m| m.contains(a, n)) {
            return Some(m.read(a, n));
        }
        let (pb, plen) = (self.flash.region_base, self.flash.data.len() as u32);
        if a >= pb && a - pb + n as u32 <= plen {
            return Some(self.flash.read_data(a, n) as u32);
        }
        if !(0x4000_0000..0x6000_0000).contains(&a) || !a.is_multiple_of(n as u32) {
            return None;
        }
        match self.dispatch_read(a & !3, t) {
            Access::Ok(v) => Some((v >> (8 * (a & 3))) & mask(n)),
            Access::Unmodelled => {
                self.fail(format!("DMA read of unmodelled register {a:#010x}"));
                None
            }
            Access::Unsupported(w) => {
                self.fail(format!("{w} at {a:#010x} is not modelled (DMA read)"));
                None
            }
        }
    }

    fn bus_write(&mut self, a: u32, n: usize, v: u32, t: u64) -> bool {
        if let Some(m) = self.sram.as_mut().filter(|m| m.contains(a, n)) {
            m.write(a, n, v);
            return true;
        }
        if !(0x4000_0000..0x6000_0000).contains(&a) || !a.is_multiple_of(n as u32) {
            return false;
        }
        let v32 = v << (8 * (a & 3));
        match self.dispatch_write(a & !3, v32, n, a, t) {
            Access::Ok(_) => {
                self.timer_requests(t);
                true
            }
            Access::Unmodelled => {
                self.fail(format!(
                    "DMA write of {v:#x} to unmodelled register {a:#010x}"
                ));
                false
            }
            Access::Unsupported(w) => {
                self.fail(format!("{w} at {a:#010x} is not modelled (DMA write)"));
                false
            }
        }
    }

    /// The break inputs from their pins: F1 TIM1_BKIN on PB12 (PA6 with
    /// TIM1's partial remap, RM0008 §9.3.7), read whatever the pin's mode
    /// (an input path always exists); G4 the BKIN pins in their alternate
    /// function (chip::G4_BKIN), low when none is.
    pub(crate) fn update_breaks(&mut self, t: u64) {
        if !self.tim.iter().any(|tm| tm.break_enabled()) {
            return;
        }
        match self.chip.kind {
            Kind::F103 => {
                let partial = (self.syscfg.get(0x04) >> 6) & 3 == 1;
                let (port, pin) = if partial { (0, 6) } else { (1, 12) };
                let af = self.af_output(port, pin);
                let level = self.gpio[port].level(pin, af);
                self.tim[tim::TIM1].break_pin(level, t);
            }
            Kind::G431 => {
                for ti in [tim::TIM1, tim::TIM8] {
                    let level = chip::G4_BKIN
                        .iter()
                        .filter(|b| b.0 == ti)
                        .find(|b| {
                            let p = &self.gpio[b.1];
                            p.mode(b.2) == Mode::Alternate && p.af(b.2) == b.3
                        })
                        .is_some_and(|b| self.gpio[b.1].level(b.2, None));
                    self.tim[ti].break_pin(level, t);
                }
            }
        }
    }

    /// The timer output driving a pin now, if the pin is in a timer's
    /// alternate function: of the candidates, the enabled one.
    pub(crate) fn timer_output(&self, (port, pin): pins::Pin) -> Option<chip::TimerOut> {
        if self.gpio[port].mode(pin) != Mode::Alternate {
            return None;
        }
        let af = self.gpio[port].af(pin);
        let remap = (self.syscfg.get(0x04) >> 6) & 3;
        let c = chip::timer_outputs_at(self.chip.kind, (port, pin), af, remap);
        let present = |o: &chip::TimerOut| o.0 < self.tim.len();
        let mut it = c.iter().flatten().filter(|o| present(o));
        let first = it.clone().next().copied();
        it.find(|o| self.tim[o.0].output_enabled(o.1, o.2))
            .copied()
            .or(first)
    }
}

fn mask(n: usize) -> u32 {
    if n >= 4 {
        u32::MAX
    } else {
        (1 << (8 * n)) - 1
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chip::Chip;
    use crate::machine::Switches;
    use crate::mem::HostMem;
    use crate::periph::flash::Flash;

    const SRAM: u32 = 0x2000_0100;
    const DMA_CCR3: u32 = chip::DMA1 + 0x08 + 0x14 * 2;
    /// EN, TCIE, HTIE, DIR (memory → peripheral), MINC, PSIZE = MSIZE = 16.
    const TO_PERIPH_16: u32 = 1 | 2 | 4 | (1 << 4) | (1 << 7) | (1 << 8) | (1 << 10);

    fn machine(kind: Kind) -> Machine {
        let chip = Chip::new(kind);
        let flash = Flash::new(
            chip.is_g4(),
            chip.flash_base,
            chip.flash_end(),
            chip.page,
            chip.flash_end() - 0x1000,
            0x1000,
            None,
            chip.t_prog_ps,
            chip.t_erase_ps,
        )
        .unwrap();
        let mut m = Machine::new(chip, flash, Switches::default(), None);
        m.sram = Some(HostMem::new(chip.sram_base, chip.sram_len as usize));
        m
    }
    /// Timer ticks at reset: F1 HSI 8 MHz, G4 HSI16.
    fn tick_ps(m: &Machine) -> u64 {
        if m.chip.is_g4() {
            62_500
        } else {
            125_000
        }
    }
    fn at_tick(m: &mut Machine, ticks: u64) {
        let t = ticks * tick_ps(m);
        m.clock.sleep_until(t);
        m.sync(t);
    }
    fn w(m: &mut Machine, a: u32, v: u32) {
        m.write(a, 4, v as u64);
        assert_eq!(m.fault, None);
    }
    fn r(m: &mut Machine, a: u32) -> u32 {
        m.read(a, 4) as u32
    }
    fn fill16(m: &mut Machine, at: u32, values: &[u32]) {
        for (i, &v) in values.iter().enumerate() {
            m.sram.as_mut().unwrap().write(at + 2 * i as u32, 2, v);
        }
    }
    /// The STEP pin's rising edges so far, in timer ticks.
    fn rising(m: &mut Machine) -> Vec<u64> {
        let tick = tick_ps(m);
        std::mem::take(&mut m.step_log)
            .into_iter()
            .filter(|e| e.1)
            .map(|e| e.0 / tick)
            .collect()
    }

    /// TIM3 channel 1 in PWM 1 with CCR1 = 10: a pulse from each update,
    /// on the STEP pin PA6 in its alternate function.
    fn step_timer(m: &mut Machine, arr: u32, dier: u32) {
        if m.chip.is_g4() {
            let moder = r(m, 0x4800_0000);
            w(m, 0x4800_0000, (moder & !(3 << 12)) | (2 << 12));
            w(m, 0x4800_0020, 2 << 24);
        } else {
            w(m, 0x4001_0800, 0x4B44_4444);
        }
        let t3 = chip::TIM3;
        w(m, t3 + 0x2C, arr);
        w(m, t3 + 0x34, 10);
        w(m, t3 + 0x18, 6 << 4);
        w(m, t3 + 0x20, 1);
        w(m, t3 + 0x0C, dier);
    }

    #[test]
    fn f1_tim3_update_requests_reload_arr_through_dma1_channel_3() {
        let mut m = machine(Kind::F103);
        fill16(&mut m, SRAM, &[100, 200, 300, 400]);
        w(&mut m, DMA_CCR3 + 4, 4);
        w(&mut m, DMA_CCR3 + 8, chip::TIM3 + 0x2C);
        w(&mut m, DMA_CCR3 + 12, SRAM);
        w(&mut m, DMA_CCR3, TO_PERIPH_16);
        step_timer(&mut m, 50, 1 << 8); // UDE
        w(&mut m, chip::TIM3, 1);
        at_tick(&mut m, 200);
        assert_eq!(
            r(&mut m, chip::DMA1) >> 8,
            0b0101,
            "HTIF3 + GIF3 after 2 items"
        );
        at_tick(&mut m, 1500);
        // each period is the ARR the DMA wrote at the update before it;
        // after the 4th item (CNDTR 0) ARR stays
        assert_eq!(rising(&mut m), [0, 51, 152, 353, 654, 1055, 1456]);
        assert_eq!(r(&mut m, DMA_CCR3 + 4), 0);
        assert_eq!(r(&mut m, chip::DMA1) >> 8, 0b0111, "TCIF3 too");
        assert!(m.scs.line(13), "DMA1_Channel3 interrupt");
    }

    #[test]
    fn f1_dma_burst_through_dmar_writes_psc_then_arr_at_each_update() {
        let mut m = machine(Kind::F103);
        fill16(&mut m, SRAM, &[1, 20, 0, 30]);
        w(&mut m, DMA_CCR3 + 4, 4);
        w(&mut m, DMA_CCR3 + 8, chip::TIM3 + 0x4C);
        w(&mut m, DMA_CCR3 + 12, SRAM);
        w(&mut m, DMA_CCR3, TO_PERIPH_16);
        // DCR: DBA = PSC (0x28 / 4), DBL = 1: two registers per update
        w(&mut m, chip::TIM3 + 0x48, 10 | (1 << 8));
        step_timer(&mut m, 9, 1 << 8);
        w(&mut m, chip::TIM3, 1);
        at_tick(&mut m, 11);
        assert_eq!(r(&mut m, chip::TIM3 + 0x28), 1, "PSC from the first item");
        assert_eq!(r(&mut m, chip::TIM3 + 0x2C), 20, "ARR from the second");
        assert_eq!(r(&mut m, DMA_CCR3 + 4), 2);
        // ARR (not preloaded) is 20 at once; PSC's ÷2 waits for the next
        // update, which brings the second pair
        at_tick(&mut m, 32);
        assert_eq!(r(&mut m, chip::TIM3 + 0x28), 0);
        assert_eq!(r(&mut m, chip::TIM3 + 0x2C), 30);
        assert_eq!(r(&mut m, DMA_CCR3 + 4), 0);
        at_tick(&mut m, 100);
        // CCR1 = 10 is out of reach while ARR = 9 (no pulse at 10); then
        // 21 ticks, then 31 counts of 2 ticks
        assert_eq!(rising(&mut m), [0, 31, 93]);
    }

    #[test]
    fn f1_tim2_in_external_clock_mode_counts_tim3_trgo_pulses() {
        let mut m = machine(Kind::F103);
        w(&mut m, chip::TIM3 + 0x04, 2 << 4); // MMS = update
        w(&mut m, chip::TIM3 + 0x2C, 9);
        // TIM2: SMS = 111 (external clock mode 1), TS = ITR2 (TIM3)
        w(&mut m, chip::TIM2 + 0x08, 7 | (2 << 4));
        w(&mut m, chip::TIM2 + 0x2C, 0xFFFF);
        w(&mut m, chip::TIM2, 1);
        w(&mut m, chip::TIM3, 1);
        at_tick(&mut m, 105);
        assert_eq!(r(&mut m, chip::TIM2 + 0x24), 10, "one count per update");
        assert_eq!(r(&mut m, chip::TIM2 + 0x10) & (1 << 6), 1 << 6, "TIF");
        // a slave on an ITR without a timer of this chip (TIM1's ITR0 is
        // TIM5) is refused
        m.write(chip::TIM1 + 0x08, 4, 7);
        assert!(m.fault.as_deref().unwrap().contains("ITR0"));
    }

    #[test]
    fn g4_tim1_gated_by_tim3_counts_only_while_oc1ref_is_high() {
        let mut m = machine(Kind::G431);
        // TIM3: ARR 99, OC1 PWM1 with CCR1 = 10, MMS = OC1REF
        step_timer(&mut m, 99, 0);
        w(&mut m, chip::TIM3 + 0x04, 4 << 4);
        // TIM1: gated (SMS 101) by ITR2 = TIM3
        w(&mut m, chip::TIM1 + 0x08, 5 | (2 << 4));
        w(&mut m, chip::TIM1, 1);
        w(&mut m, chip::TIM3, 1);
        at_tick(&mut m, 250);
        // high 10 ticks of each 100: 0..10, 100..110, 200..210
        assert_eq!(r(&mut m, chip::TIM1 + 0x24), 30);
    }

    #[test]
    fn repetition_counter_and_one_pulse_mode_stop_after_rcr_plus_one_periods() {
        let mut m = machine(Kind::F103);
        let t1 = chip::TIM1;
        w(&mut m, t1 + 0x2C, 9);
        w(&mut m, t1 + 0x30, 2);
        w(&mut m, t1 + 0x14, 1); // UG loads RCR
        w(&mut m, t1 + 0x10, 0);
        w(&mut m, t1, 1 | (1 << 3)); // CEN, OPM
        at_tick(&mut m, 29);
        assert_eq!(r(&mut m, t1 + 0x10) & 1, 0, "no update before 3 periods");
        assert_eq!(r(&mut m, t1) & 1, 1);
        at_tick(&mut m, 31);
        assert_eq!(r(&mut m, t1 + 0x10) & 1, 1);
        assert_eq!(r(&mut m, t1) & 1, 0, "OPM: CEN cleared at the update");
        assert_eq!(r(&mut m, t1 + 0x24), 0);
    }

    #[test]
    fn the_break_input_clears_moe_and_the_output_stops() {
        let mut m = machine(Kind::F103);
        let t1 = chip::TIM1;
        m.gpio[1].external[12] = Some(true); // PB12 = TIM1_BKIN, inactive
        w(&mut m, t1 + 0x18, 5 << 4); // OC1: forced active
        w(&mut m, t1 + 0x20, 1);
        w(&mut m, t1 + 0x0C, 1 << 7); // BIE
        w(&mut m, t1 + 0x44, (1 << 15) | (1 << 12)); // MOE, BKE, BKP = 0
        at_tick(&mut m, 5);
        assert!(m.tim[tim::TIM1].pin_level(0, false));
        m.gpio[1].external[12] = Some(false);
        at_tick(&mut m, 6);
        assert_eq!(r(&mut m, t1 + 0x44) & (1 << 15), 0, "MOE cleared");
        assert_eq!(r(&mut m, t1 + 0x10) & (1 << 7), 1 << 7, "BIF");
        assert!(!m.tim[tim::TIM1].pin_level(0, false), "output released");
        assert!(m.scs.line(24), "TIM1_BRK");
        // MOE cannot be set while the break is active
        w(&mut m, t1 + 0x44, (1 << 15) | (1 << 12));
        assert_eq!(r(&mut m, t1 + 0x44) & (1 << 15), 0);
        // software break (EGR.BG) with the pin inactive again
        m.gpio[1].external[12] = Some(true);
        at_tick(&mut m, 7);
        w(&mut m, t1 + 0x44, (1 << 15) | (1 << 12));
        assert!(m.tim[tim::TIM1].pin_level(0, false));
        w(&mut m, t1 + 0x14, 1 << 7);
        assert!(!m.tim[tim::TIM1].pin_level(0, false));
    }

    #[test]
    fn g4_dmamux_routes_tim3_up_to_the_dma1_channel_it_names() {
        let mut m = machine(Kind::G431);
        fill16(&mut m, SRAM, &[7, 8]);
        w(&mut m, chip::DMAMUX1, 65); // channel 0 → DMA1 channel 1: TIM3_UP
        let c1 = chip::DMA1 + 0x08;
        w(&mut m, c1 + 4, 2);
        w(&mut m, c1 + 8, chip::TIM3 + 0x34);
        w(&mut m, c1 + 12, SRAM);
        w(&mut m, c1, TO_PERIPH_16);
        step_timer(&mut m, 49, 1 << 8);
        w(&mut m, chip::TIM3, 1);
        at_tick(&mut m, 120);
        assert_eq!(r(&mut m, chip::TIM3 + 0x34), 8);
        assert_eq!(
            r(&mut m, chip::DMA1) & 0xF,
            0b0111,
            "TC, HT, GIF of channel 1"
        );
        assert!(m.scs.line(11));
        // a request ID nobody selected reaches no channel
        w(&mut m, chip::DMAMUX1, 71);
        assert_eq!(r(&mut m, c1 + 4), 0);
    }

    #[test]
    fn a_dma_transfer_to_no_memory_is_a_transfer_error() {
        let mut m = machine(Kind::F103);
        w(&mut m, DMA_CCR3 + 4, 2);
        w(&mut m, DMA_CCR3 + 8, 0x3000_0000);
        w(&mut m, DMA_CCR3 + 12, SRAM);
        w(&mut m, DMA_CCR3, TO_PERIPH_16 | (1 << 3));
        step_timer(&mut m, 9, 1 << 8);
        w(&mut m, chip::TIM3, 1);
        at_tick(&mut m, 15);
        assert_eq!(r(&mut m, chip::DMA1) >> 8, 0b1001, "TEIF3 + GIF3");
        assert_eq!(r(&mut m, DMA_CCR3) & 1, 0, "channel disabled");
        assert_eq!(m.fault, None);
    }

    #[test]
    fn a_request_waits_for_its_channel_to_be_enabled() {
        let mut m = machine(Kind::F103);
        fill16(&mut m, SRAM, &[33]);
        step_timer(&mut m, 9, 1 << 8);
        w(&mut m, chip::TIM3, 1);
        at_tick(&mut m, 15);
        // the update at tick 10 asked; channel 3 is enabled at 15
        w(&mut m, DMA_CCR3 + 4, 1);
        w(&mut m, DMA_CCR3 + 8, chip::TIM3 + 0x38);
        w(&mut m, DMA_CCR3 + 12, SRAM);
        w(&mut m, DMA_CCR3, TO_PERIPH_16);
        assert_eq!(
            r(&mut m, chip::TIM3 + 0x38),
            33,
            "served as the channel starts"
        );
        assert_eq!(r(&mut m, DMA_CCR3 + 4), 0);
        // clearing UDE withdraws a request no channel took
        at_tick(&mut m, 25);
        w(&mut m, chip::TIM3 + 0x0C, 0);
        assert_eq!(m.tim[tim::TIM3].dma_pending, 0);
    }

    /// The F103 engine of docs/firmware.md's design: TIM1 with its partial
    /// remap, STEP = CH1N on PA7 and DIR = CH2N on PB0, one DMA burst
    /// (ARR, RCR, CCR1, CCR2) per update from DMA1 channel 5 (TIM1_UP),
    /// TIM3 counting TIM1's OC1REF through ITR0, a software break.
    #[test]
    fn f1_tim1_burst_engine_steps_counts_and_stops_on_a_break() {
        let mut m = machine(Kind::F103);
        w(&mut m, 0x4001_0004, 1 << 6); // AFIO_MAPR: TIM1 partial remap
        w(&mut m, 0x4001_0800, 0xB444_4444); // PA7 AF push-pull
        w(&mut m, 0x4001_0C00, 0x4444_444B); // PB0 AF push-pull
        burst_engine(&mut m, 4); // F1: TIM1_UP is DMA1 channel 5
    }

    /// The same on the G431: PA7 / PB0 in AF6, TIM1_UP (request 46)
    /// through DMAMUX channel 0 to DMA1 channel 1.
    #[test]
    fn g4_tim1_burst_engine_through_dmamux_steps_counts_and_stops_on_a_break() {
        let mut m = machine(Kind::G431);
        let moder_a = r(&mut m, 0x4800_0000);
        w(&mut m, 0x4800_0000, (moder_a & !(3 << 14)) | (2 << 14));
        w(&mut m, 0x4800_0020, 6 << 28);
        let moder_b = r(&mut m, 0x4800_0400);
        w(&mut m, 0x4800_0400, (moder_b & !3) | 2);
        w(&mut m, 0x4800_0420, 6);
        w(&mut m, chip::DMAMUX1, 46);
        burst_engine(&mut m, 0);
    }

    /// The engine on TIM1 with its DMA channel `ch` (0-based) of DMA1.
    fn burst_engine(m: &mut Machine, ch: u32) {
        let t1 = chip::TIM1;
        // three entries: (ARR, RCR, CCR1, CCR2)
        let entries = [99, 0, 50, 0xFFFF, 199, 0, 50, 0xFFFF, 99, 1, 50, 0];
        fill16(m, SRAM, &entries);
        let c5 = chip::DMA1 + 0x08 + 0x14 * ch;
        w(m, c5 + 4, 12);
        // DCR / DMAR: G4 0x3DC / 0x3E0, F1 0x48 / 0x4C
        let (dcr, dmar) = if m.chip.is_g4() {
            (0x3DC, 0x3E0)
        } else {
            (0x48, 0x4C)
        };
        w(m, c5 + 8, t1 + dmar);
        w(m, c5 + 12, SRAM);
        w(m, c5, TO_PERIPH_16);
        w(m, t1 + dcr, 11 | (3 << 8)); // DBA = ARR, DBL = 3
        w(m, t1 + 0x2C, 99);
        w(m, t1 + 0x34, 50);
        w(m, t1 + 0x38, 0xFFFF);
        // OC1 PWM 2, OC2 PWM 1, both preloaded; CC1NE, CC2NE; MOE
        w(m, t1 + 0x18, (7 << 4) | (1 << 3) | (6 << 12) | (1 << 11));
        w(m, t1 + 0x20, (1 << 2) | (1 << 6));
        w(m, t1 + 0x44, 1 << 15);
        w(m, t1 + 0x04, 4 << 4); // MMS = OC1REF
        w(m, t1 + 0x14, 1); // UG
        w(m, t1 + 0x0C, 1 << 8); // UDE

        // TIM3: external clock mode 1 on ITR0 (TIM1)
        w(m, chip::TIM3 + 0x08, 7);
        w(m, chip::TIM3, 1);
        w(m, t1, 1 | (1 << 7)); // CEN, ARPE
        at_tick(m, 680);
        // each entry acts from the update after the one that loaded it:
        // 100, 100, 100 (entry 0), 200 (entry 1), then entry 2's period
        // twice (RCR = 1) with DIR low from its update at 500
        assert_eq!(rising(m), [50, 150, 250, 350, 550, 650]);
        assert_eq!(m.position, 2, "4 steps forward, 2 back");
        assert_eq!(r(m, chip::TIM3 + 0x24), 6, "the slave counted every pulse");
        assert_eq!(r(m, c5 + 4), 0);
        w(m, t1 + 0x14, 1 << 7); // BG: the fault path's software break
        at_tick(m, 900);
        assert!(rising(m).is_empty(), "no pulse after the break");
        assert!(!m.tim[tim::TIM1].pin_level(0, true));
    }
}
