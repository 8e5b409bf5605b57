//! The emulated chip outside the CPU: every modelled peripheral, the bus
//! that routes an address to one of them (anything else is a fault), the
//! interrupt lines into the NVIC, and the board around the chip (STEP/DIR
//! outputs into an axis position, the switches that position drives, the
//! RS-485 DE pin).

use std::hash::{BuildHasherDefault, Hasher};

use unicorn_engine::unicorn_const::MemType;

use crate::chip::{self, pins, Chip};
use crate::clock::Clock;
use crate::mem::HostMem;
use crate::motor::Motor;
use crate::periph::bank::Bank;
use crate::periph::dma::Dma;
use crate::periph::dmamux::DmaMux;
use crate::periph::exti::Exti;
use crate::periph::flash::{Flash, FlashWrite};
use crate::periph::gpio::{Mode, Port};
use crate::periph::iwdg::Iwdg;
use crate::periph::rcc::Rcc;
use crate::periph::timer::{Irqs, Kind as TimerKind, Timer};
use crate::periph::usart::Usart;
use crate::periph::Access;
use crate::pin_trace::PinTrace;
use crate::scs::Scs;
use crate::trace::StepTrace;

/// A hasher for code addresses (the block cache is asked once per block):
/// the address itself, spread by one multiplication.
#[derive(Default)]
pub struct AddrHasher(u64);

impl Hasher for AddrHasher {
    fn finish(&self) -> u64 {
        self.0.wrapping_mul(0x9E37_79B9_7F4A_7C15)
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 << 8) | b as u64;
        }
    }
    fn write_u64(&mut self, v: u64) {
        self.0 = v;
    }
}

/// What the CPU's hooks (cpu.rs) saw during a slice: kept here, with the
/// rest of the state the hooks write, so that the CPU depends on the
/// machine and not the other way round.
#[derive(Debug, Default, Clone, Copy)]
pub struct SliceEvents {
    /// A WFI (false) or WFE (true) was reached; PC is past it.
    pub sleep: Option<bool>,
    /// The firmware branched to EXC_RETURN (PC holds it).
    pub exc_return: bool,
    /// An access outside the memories: (kind, address, size).
    pub bad_access: Option<(MemType, u64, usize)>,
}

/// Switch windows in steps (same meaning as the virtual drive's options).
#[derive(Clone, Copy, Debug, Default)]
pub struct Switches {
    pub cw_limit: Option<i64>,
    pub ccw_limit: Option<i64>,
    pub home: Option<(i64, i64)>,
}

pub struct Machine {
    pub chip: Chip,
    pub clock: Clock,
    pub rcc: Rcc,
    pub pwr: Bank,
    pub syscfg: Bank,
    pub dbgmcu: Bank,
    pub flash: Flash,
    pub exti: Exti,
    pub gpio: [Port; 2],
    /// In the order of `chip::tim` (TIM2, TIM3, TIM4, TIM1, and the G4's TIM8).
    pub tim: Vec<Timer>,
    /// DMA1 (and the G4's DMA2).
    pub dma: Vec<Dma>,
    pub dmamux: DmaMux,
    /// SRAM and the code flash, shared with the CPU (cpu.rs maps them).
    pub sram: Option<HostMem>,
    pub code: Option<HostMem>,
    pub usart: Usart,
    pub iwdg: Iwdg,
    pub scs: Scs,
    /// Set by a bus access the model refuses; the runner stops.
    pub fault: Option<String>,
    /// The program counter when the fault was raised.
    pub fault_pc: Option<u32>,
    /// `fault_pc` is the start of the basic block holding the access.
    pub fault_in_block: bool,
    /// Instructions of the current slice so far (block granularity).
    pub slice_insns: u64,
    pub budget: u64,
    /// End the slice at the next block boundary.
    pub stop_soon: bool,
    /// Some interrupt is pending (refreshed after every peripheral access
    /// and at each slice's start: the only points where it can change), so
    /// the block hook need not scan the NVIC.
    pub pending_hint: bool,
    /// The block hook must ask the NVIC again (see `pending_hint`).
    pub recheck: bool,
    /// PRIMASK and BASEPRI when the block hook last asked.
    pub last_masks: (bool, u8),
    /// Start address of the basic block being executed.
    pub block_pc: u32,
    pub block_cache: std::collections::HashMap<u64, u32, BuildHasherDefault<AddrHasher>>,
    /// `--profile`: instructions per block.
    pub profile: Option<crate::profile::Profile>,
    /// The clocks derived from RCC (refreshed when RCC is written).
    pub clocks: crate::periph::rcc::Clocks,
    pub switches: Switches,
    pub position: i64,
    pub steps_total: u64,
    pub trace: Option<StepTrace>,
    /// `--trace-pins` (pin_trace.rs).
    pub pin_trace: Option<PinTrace>,
    /// `--trace-calls` (call_trace.rs).
    pub call_trace: Option<crate::call_trace::CallTrace>,
    /// Core cycles at the last reset.
    reset_cycles: u64,
    /// The motor and its encoder (`--encoder`), part of the world outside
    /// the chip: a reset keeps it.
    pub motor: Option<Motor>,
    /// The step timer's missed update interrupts already reported.
    missed_reported: u64,
    /// All timers' missed update interrupts when last looked at.
    missed_seen: u64,
    /// Some DMA interrupt line may be high (per controller).
    dma_lines_high: [bool; 2],
    pending_rise: Option<(u64, bool)>,
    /// Event register (WFE/SEV).
    pub event: bool,
    /// What the CPU hooks saw in the current slice.
    pub events: SliceEvents,
    /// Nesting of timer requests and DMA transfers within one instant.
    pub chain_depth: u32,
    /// The STEP pin's edges (unit tests).
    #[cfg(test)]
    pub step_log: Vec<(u64, bool)>,
}

impl Machine {
    pub fn new(chip: Chip, flash: Flash, switches: Switches, trace: Option<StepTrace>) -> Self {
        let g4 = chip.is_g4();
        let mut m = Self {
            chip,
            clock: Clock::new(chip.reset_sysclk),
            rcc: Rcc::new(g4, chip.hse_hz),
            pwr: Bank::pwr(g4),
            syscfg: Bank::syscfg(g4),
            dbgmcu: Bank::dbgmcu(g4, chip.dbgmcu_idcode),
            flash,
            exti: Exti::new(g4),
            gpio: [Port::new(g4, 0), Port::new(g4, 1)],
            tim: Self::timers(g4),
            dma: if g4 {
                vec![
                    Dma::new(true, (11..17).collect()),
                    Dma::new(true, vec![56, 57, 58, 59, 60, 97]),
                ]
            } else {
                vec![Dma::new(false, (11..18).collect())]
            },
            dmamux: DmaMux::default(),
            sram: None,
            code: None,
            usart: Usart::new(g4),
            iwdg: Iwdg::new(g4, chip.lsi_hz),
            scs: Scs::new(chip.has_fpu, chip.cpuid),
            fault: None,
            fault_pc: None,
            fault_in_block: false,
            slice_insns: 0,
            budget: 0,
            stop_soon: false,
            pending_hint: false,
            recheck: true,
            last_masks: (false, 0),
            block_pc: 0,
            block_cache: Default::default(),
            profile: None,
            clocks: crate::periph::rcc::Clocks::default(),
            switches,
            position: 0,
            steps_total: 0,
            trace,
            pin_trace: None,
            call_trace: None,
            reset_cycles: 0,
            motor: None,
            missed_reported: 0,
            missed_seen: 0,
            dma_lines_high: [false; 2],
            pending_rise: None,
            event: false,
            events: Default::default(),
            chain_depth: 0,
            #[cfg(test)]
            step_log: Vec::new(),
        };
        m.apply_clocks();
        m.apply_switches();
        m
    }

    /// The chip's timers (interrupt numbers: RM0440 table 97 / RM0008
    /// table 63, the vector tables).
    fn timers(g4: bool) -> Vec<Timer> {
        let gp2 = if g4 {
            TimerKind::General32
        } else {
            TimerKind::General16
        };
        let mut t = vec![
            Timer::new(Irqs::One(chip::IRQ_TIM2), g4, gp2),
            Timer::new(Irqs::One(chip::IRQ_TIM3), g4, TimerKind::General16),
            Timer::new(Irqs::One(chip::IRQ_TIM4), g4, TimerKind::General16),
            Timer::new(
                Irqs::Split {
                    brk: 24,
                    up: 25,
                    trg_com: 26,
                    cc: 27,
                },
                g4,
                TimerKind::Advanced,
            ),
        ];
        if g4 {
            t.push(Timer::new(
                Irqs::Split {
                    brk: 43,
                    up: 44,
                    trg_com: 45,
                    cc: 46,
                },
                g4,
                TimerKind::Advanced,
            ));
        }
        t
    }

    /// A system reset (watchdog, SYSRESETREQ): every peripheral to its reset
    /// state; SRAM, the flash file and the axis keep theirs. `flags`: the
    /// RCC_CSR reset flags the reset adds to those already set (RCC_CSR
    /// survives every reset but a power-on); `None` for a power-on.
    pub fn reset_peripherals(&mut self, flags: Option<u32>) {
        let kept = self.rcc.reset_flags();
        let pin_trace = self.pin_trace.take();
        let cycles = self.cycles();
        let fresh = Machine::new(
            self.chip,
            std::mem::replace(
                &mut self.flash,
                Flash::new(true, 0, 0, 1, 0, 0, None, 0, 0).unwrap(),
            ),
            self.switches,
            self.trace.take(),
        );
        let (clock, position, steps) = (self.clock.clone(), self.position, self.steps_total);
        let motor = self.motor.take();
        let (sram, code) = (self.sram.take(), self.code.take());
        *self = fresh;
        self.motor = motor;
        self.sram = sram;
        self.code = code;
        self.clock = clock;
        self.clock.set_sysclk(self.chip.reset_sysclk);
        self.position = position;
        self.steps_total = steps;
        self.flash.reset();
        if let Some(f) = flags {
            self.rcc.set_reset_flags(kept | f);
        }
        self.reset_cycles = cycles;
        self.pin_trace = pin_trace;
        let t = self.now();
        if let Some(pt) = self.pin_trace.as_mut() {
            pt.reset(t);
        }
        self.look_at_pins(t);
        self.apply_clocks();
        self.apply_switches();
    }

    /// `--trace-pins`: the traced outputs after a GPIO write or a reset.
    pub fn look_at_pins(&mut self, t: u64) {
        let cycles = self.cycles() - self.reset_cycles;
        if let Some(pt) = self.pin_trace.as_mut() {
            pt.look(t, cycles, &self.gpio);
        }
    }

    /// Time now, inside a slice: the slice's start plus its instructions.
    pub fn now(&self) -> u64 {
        self.clock.after_cycles(self.slice_insns)
    }
    /// Core cycles since start, busy and asleep (CYCCNT).
    fn cycles(&self) -> u64 {
        self.clock.busy_cycles() + self.clock.sleep_cycles() + self.slice_insns
    }

    fn apply_clocks(&mut self) {
        let c = self.rcc.clocks();
        self.clocks = c;
        let now = self.now();
        for (i, t) in self.tim.iter_mut().enumerate() {
            // TIM1 / TIM8 are on APB2, the others on APB1
            let hz = if i >= chip::tim::TIM1 {
                c.tim_apb2
            } else {
                c.tim_apb1
            };
            t.set_clock(hz as u64, now);
        }
        self.usart.fck = c.usart1 as u64;
    }
    pub fn hclk(&self) -> u32 {
        self.clocks.hclk
    }

    /// Brings every peripheral to time `t`.
    pub fn sync(&mut self, t: u64) {
        self.run_timers(t);
        self.update_breaks(t);
        self.step_edges();
        if let Some(at) = self.motor.as_mut().and_then(|m| m.advance(t)) {
            self.follow_encoder(at);
        }
        let de = self.gpio_de();
        // The pin changes hands (GPIO ↔ the G4 USART's DE function) or
        // level as a GPIO: an edge where its level changes. The USART's own
        // edges are its (usart.rs), recorded only while it has the pin.
        if de != self.usart.gpio_de {
            let usart_de = self.usart.de_output().unwrap_or(false);
            let was = self.usart.gpio_de.unwrap_or(usart_de);
            let now = de.unwrap_or(usart_de);
            if now != was {
                self.usart.de_edges.push((t, now));
            }
        }
        self.usart.gpio_de = de;
        self.usart.sync(t);
        if let Err(e) = self.flash.sync(t) {
            self.fault = Some(format!("--state file: {e}"));
        }
        let hclk = self.hclk();
        self.scs.systick_sync(t, hclk);
        self.update_irqs();
    }

    /// The DE pin as a GPIO (F1 always; G4 when PA12 is not in its AF).
    fn gpio_de(&self) -> Option<bool> {
        let (port, pin) = if self.chip.is_g4() {
            pins::DE_G431
        } else {
            pins::DE_F103
        };
        let p = &self.gpio[port];
        match p.mode(pin) {
            Mode::Alternate if self.chip.is_g4() => None,
            _ => Some(p.level(pin, None)),
        }
    }

    fn step_edges(&mut self) {
        // nothing moved since the last look (the common case: a register
        // access between two timer events)
        let missed: u64 = self.tim.iter().map(|tm| tm.missed_updates).sum();
        let quiet = self.tim.iter().all(|tm| tm.edges.iter().all(Vec::is_empty));
        if quiet && missed == self.missed_seen {
            return;
        }
        self.missed_seen = missed;
        let source = pins::STEP
            .iter()
            .filter_map(|&p| self.timer_output(p))
            .find(|o| self.tim[o.0].output_enabled(o.1, o.2));
        let dir_source = self.timer_output(pins::DIR);
        // a step interrupt that missed an update event let the timer repeat
        // the period it had preloaded: a STEP pulse the firmware never
        // counted (reported at the first and then at every doubling)
        let missed = source.map_or(0, |(i, _, _)| self.tim[i].missed_updates);
        let reported = self.missed_reported;
        if missed > reported && (reported == 0 || missed.ilog2() > reported.ilog2()) {
            eprintln!(
                "fw-sim: step timer: {missed} update event(s) with UIF still set (the step interrupt missed a period; its preloaded period ran again) at {} µs",
                self.clock.now() / 1_000_000
            );
        }
        self.missed_reported = missed;
        // the STEP pin in a timer's alternate function shows that timer
        // output's level (Timer::pin_level), with edges at the emulated
        // times the counter made them, whether the CPU or DMA wrote its
        // periods; DIR too may be a timer output, then its level at each
        // STEP edge comes from its own edges
        let mut edges = Vec::new();
        let mut dir_edges = Vec::new();
        for (i, tm) in self.tim.iter_mut().enumerate() {
            for k in 0..8 {
                let out = Some((i, k % 4, k >= 4));
                if out == source {
                    edges = std::mem::take(&mut tm.edges[k]);
                } else if out == dir_source {
                    dir_edges = std::mem::take(&mut tm.edges[k]);
                } else {
                    tm.edges[k].clear();
                }
            }
        }
        #[cfg(test)]
        self.step_log.extend(&edges);
        let mut dir_level = match (dir_source, dir_edges.first()) {
            (Some(_), Some(&(_, first))) => !first,
            (Some((i, ch, n)), None) => self.tim[i].pin_level(ch, n),
            (None, _) => self.gpio[pins::DIR.0].level(pins::DIR.1, None),
        };
        let mut dir_next = dir_edges.into_iter().peekable();
        for (t, level) in edges {
            // DIR edges up to this STEP edge (a tie: DIR first)
            while let Some(&(td, l)) = dir_next.peek() {
                if td > t {
                    break;
                }
                dir_level = l;
                dir_next.next();
            }
            if level {
                let dir = dir_level;
                self.pending_rise = Some((t, dir));
                self.position += if dir { 1 } else { -1 };
                self.steps_total += 1;
                self.apply_switches();
                if let Some(m) = self.motor.as_mut() {
                    m.step(t, self.position);
                    self.follow_encoder(t);
                }
            } else if let Some((t0, dir)) = self.pending_rise.take() {
                if let Some(tr) = self.trace.as_mut() {
                    tr.step(t0, dir, t - t0);
                }
            }
        }
    }

    /// The encoder's A and B (PB6, PB7) follow the motor's shaft, one edge
    /// at a time, into the TIM4 channel 1 and 2 inputs when the pins are
    /// routed there: on the G4 in their alternate function 2 (RM0440 §9.4,
    /// datasheet DS12589 table "Alternate functions"), on the F1 in any
    /// input or alternate mode with TIM4 not remapped (RM0008 §9.3.7,
    /// AFIO_MAPR TIM4_REMAP = 0).
    fn follow_encoder(&mut self, t: u64) {
        let (a, b) = pins::ENCODER;
        while let Some((la, lb)) = self.motor.as_mut().and_then(Motor::edge) {
            let port = &mut self.gpio[a.0];
            let before = [port.level(a.1, None), port.level(b.1, None)];
            port.external[a.1 as usize] = Some(la);
            port.external[b.1 as usize] = Some(lb);
            let after = [port.level(a.1, None), port.level(b.1, None)];
            for (pin, (x, y)) in [(a.1, (before[0], after[0])), (b.1, (before[1], after[1]))] {
                if x != y {
                    self.exti.edge(a.0, pin, y);
                }
            }
            let routed = self.tim4_inputs_routed();
            self.tim[chip::tim::TIM4].inputs([la, lb], t, routed);
            self.timer_requests(t);
        }
    }

    fn tim4_inputs_routed(&self) -> bool {
        let (a, b) = pins::ENCODER;
        let port = &self.gpio[a.0];
        if self.chip.is_g4() {
            [a.1, b.1]
                .iter()
                .all(|&p| port.mode(p) == Mode::Alternate && port.af(p) == 2)
        } else {
            let remap = self.syscfg.get(0x04) & (1 << 12) != 0;
            !remap && [a.1, b.1].iter().all(|&p| port.mode(p) != Mode::Analog)
        }
    }

    /// Switch contacts from the axis position, into the GPIO inputs (and
    /// EXTI on a change).
    pub fn apply_switches(&mut self) {
        let p = self.position;
        let s = self.switches;
        let levels = [
            (pins::CW_LIMIT, s.cw_limit.is_some_and(|c| p <= c)),
            (pins::CCW_LIMIT, s.ccw_limit.is_some_and(|c| p >= c)),
            (pins::HOME, s.home.is_some_and(|(a, b)| a <= p && p <= b)),
        ];
        for ((port, pin), active) in levels {
            let before = self.gpio[port].level(pin, None);
            self.gpio[port].external[pin as usize] = Some(active);
            let after = self.gpio[port].level(pin, None);
            if before != after {
                self.exti.edge(port, pin, after);
            }
        }
    }

    pub fn update_irqs(&mut self) {
        for i in 0..self.tim.len() {
            let (lines, n) = self.tim[i].irq_levels();
            for &(irq, l) in &lines[..n] {
                self.scs.set_level(irq, l);
            }
        }
        for d in 0..self.dma.len() {
            // lines are only ever high with a flag set: once low they stay
            if self.dma[d].quiet() && !self.dma_lines_high[d] {
                continue;
            }
            self.dma_lines_high[d] = !self.dma[d].quiet();
            for c in 0..self.dma[d].channels() {
                let (irq, l) = self.dma[d].irq_level(c);
                self.scs.set_level(irq, l);
            }
        }
        let l = self.usart.irq_level();
        self.scs.set_level(chip::IRQ_USART1, l);
        let l = self.flash.irq_level();
        self.scs.set_level(chip::IRQ_FLASH, l);
        let p = self.exti.pending();
        for line in 0..5 {
            self.scs
                .set_level(chip::IRQ_EXTI0 + line, p & (1 << line) != 0);
        }
        self.scs.set_level(chip::IRQ_EXTI9_5, p & 0x3E0 != 0);
        self.scs.set_level(chip::IRQ_EXTI15_10, p & 0xFC00 != 0);
    }

    /// The next time a peripheral changes something the CPU may see.
    pub fn next_event(&self) -> Option<u64> {
        let hclk = self.hclk();
        let timers = self.tim.iter().filter_map(Timer::next_event).min();
        [
            timers,
            self.usart.next_event(),
            self.flash.next_event(),
            self.iwdg.next_event(),
            self.scs.systick_next(hclk),
            self.motor.as_ref().and_then(Motor::next_event),
        ]
        .into_iter()
        .flatten()
        .min()
    }

    fn idr(&self, port: usize) -> u32 {
        let mut v = 0;
        for pin in 0..16u8 {
            let af = self.af_output(port, pin);
            if self.gpio[port].level(pin, af) {
                v |= 1 << pin;
            }
        }
        v
    }
    pub(crate) fn af_output(&self, port: usize, pin: u8) -> Option<bool> {
        if port == 0 && pin == 12 && self.chip.is_g4() {
            return self.usart.de_output();
        }
        self.timer_output((port, pin))
            .map(|(t, ch, n)| self.tim[t].pin_level(ch, n))
    }

    /// A read by the CPU from peripheral space.
    pub fn read(&mut self, a: u32, size: usize) -> u64 {
        let t = self.now();
        self.sync(t);
        let word = a & !3;
        let r = self.dispatch_read(word, t);
        match r {
            Access::Ok(v) => ((v >> (8 * (a & 3))) as u64) & mask(size),
            Access::Unmodelled => {
                self.fail(format!(
                    "read of unmodelled register {a:#010x} ({})",
                    self.region_name(a)
                ));
                0
            }
            Access::Unsupported(w) => {
                self.fail(format!("{w} at {a:#010x} is not modelled"));
                0
            }
        }
    }

    pub fn write(&mut self, a: u32, size: usize, v: u64) {
        let t = self.now();
        self.sync(t);
        let word = a & !3;
        let v32 = (v as u32) << (8 * (a & 3));
        let r = self.dispatch_write(word, v32, size, a, t);
        match r {
            Access::Ok(_) => {}
            Access::Unmodelled => self.fail(format!(
                "write of {v:#x} to unmodelled register {a:#010x} ({})",
                self.region_name(a)
            )),
            Access::Unsupported(w) => self.fail(format!("{w} at {a:#010x} is not modelled")),
        }
        self.timer_requests(t);
        if let Err(e) = self.check_slaves(t) {
            self.fail(format!("{e} (write to {a:#010x})"));
        }
        if word & !0x3FF == chip::RCC {
            self.apply_clocks();
        }
        let hz = self.hclk();
        if hz != self.clock.sysclk() {
            // the instructions so far ran at the old clock
            self.clock.run_cycles(self.slice_insns);
            self.budget = self.budget.saturating_sub(self.slice_insns);
            self.slice_insns = 0;
            self.clock.set_sysclk(hz);
        }
        self.sync(t);
    }

    pub fn fail(&mut self, msg: String) {
        if self.fault.is_none() {
            self.fault = Some(msg);
        }
    }

    fn region_name(&self, a: u32) -> &'static str {
        let g4 = self.chip.is_g4();
        match a {
            0x4000_0000..=0x4000_03FF => "TIM2",
            0x4000_0400..=0x4000_07FF => "TIM3",
            0x4000_0800..=0x4000_0BFF => "TIM4",
            0x4001_2C00..=0x4001_2FFF => "TIM1",
            0x4001_3400..=0x4001_37FF if g4 => "TIM8",
            0x4002_0000..=0x4002_03FF => "DMA1",
            0x4002_0400..=0x4002_07FF if g4 => "DMA2",
            0x4002_0800..=0x4002_0BFF if g4 => "DMAMUX1",
            0x4000_3000..=0x4000_33FF => "IWDG",
            0x4000_7000..=0x4000_73FF => "PWR",
            0x4001_0000..=0x4001_03FF => {
                if g4 {
                    "SYSCFG"
                } else {
                    "AFIO"
                }
            }
            0x4001_0400..=0x4001_07FF => "EXTI",
            0x4001_3800..=0x4001_3BFF => "USART1",
            0x4002_1000..=0x4002_13FF => "RCC",
            0x4002_2000..=0x4002_23FF => "FLASH",
            0xE000_0000..=0xE00F_FFFF => "Cortex-M private peripheral bus",
            _ if a == self.chip.gpioa & !0x3FF || (a & !0x3FF) == self.chip.gpioa => "GPIOA",
            _ if (a & !0x3FF) == self.chip.gpiob => "GPIOB",
            _ => "no peripheral modelled here",
        }
    }

    pub fn dispatch_read(&mut self, a: u32, t: u64) -> Access {
        let off = a & 0x3FF;
        let g4 = self.chip.is_g4();
        let ga = self.chip.gpioa;
        let gb = self.chip.gpiob;
        match a & !0x3FF {
            chip::TIM2 => self.tim[0].read(off, t),
            chip::TIM3 => self.tim[1].read(off, t),
            chip::TIM4 => self.tim[2].read(off, t),
            chip::TIM1 => self.tim[3].read(off, t),
            chip::TIM8 if g4 => self.tim[4].read(off, t),
            chip::DMA1 => self.dma[0].read(off),
            chip::DMA2 if g4 => self.dma[1].read(off),
            chip::DMAMUX1 if g4 => self.dmamux.read(off),
            chip::IWDG => self.iwdg.read(off, t),
            chip::PWR => self.pwr.read(off),
            chip::SYSCFG_AFIO => self.syscfg.read(off),
            chip::EXTI => self.exti.read(off),
            chip::USART1 => self.usart.read(off),
            chip::RCC => self.rcc.read(off),
            chip::FLASH_IF => self.flash.read(off, t),
            chip::DBGMCU => self.dbgmcu.read(off),
            x if x == ga => {
                let idr = self.idr(0);
                self.gpio[0].read(off, idr)
            }
            x if x == gb => {
                let idr = self.idr(1);
                self.gpio[1].read(off, idr)
            }
            _ if (0xE000_0000..0xE010_0000).contains(&a) => {
                let (hclk, cyc) = (self.hclk(), self.cycles());
                self.scs.read(a, t, hclk, cyc)
            }
            _ => Access::Unmodelled,
        }
    }

    pub fn dispatch_write(&mut self, a: u32, v: u32, size: usize, exact: u32, t: u64) -> Access {
        let off = a & 0x3FF;
        let g4 = self.chip.is_g4();
        let ga = self.chip.gpioa;
        let gb = self.chip.gpiob;
        match a & !0x3FF {
            chip::TIM2 => self.tim[0].write(off, v, t),
            chip::TIM3 => self.tim[1].write(off, v, t),
            chip::TIM4 => self.tim[2].write(off, v, t),
            chip::TIM1 => self.tim[3].write(off, v, t),
            chip::TIM8 if g4 => self.tim[4].write(off, v, t),
            x if x == chip::DMA1 || (g4 && x == chip::DMA2) => {
                let d = usize::from(x == chip::DMA2);
                let (r, started) = self.dma[d].write(off, v);
                if let Some(c) = started {
                    self.mem2mem(d, c, t);
                    self.serve_pending(t);
                }
                r
            }
            chip::DMAMUX1 if g4 => self.dmamux.write(off, v),
            chip::IWDG => self.iwdg.write(off, v, t),
            chip::PWR => self.pwr.write(off, v),
            chip::SYSCFG_AFIO => {
                // AFIO_MAPR: the timers' pins are modelled unremapped
                // (TIM1 partial remap only moves its break input)
                if !g4 && off == 0x04 && (v & 0x1F00 != 0 || (v >> 6) & 3 > 1) {
                    return Access::Unsupported("AFIO_MAPR timer remap");
                }
                let r = self.syscfg.write(off, v);
                for i in 0..4 {
                    self.exti.exticr[i] = self.syscfg.get(0x08 + 4 * i as u32);
                }
                r
            }
            chip::EXTI => self.exti.write(off, v),
            chip::USART1 => self.usart.write(off, v, t),
            chip::RCC => self.rcc.write(off, v),
            chip::FLASH_IF => match self.flash.write(off, v, t) {
                Ok(r) => r,
                Err(e) => {
                    self.fail(e);
                    Access::Ok(0)
                }
            },
            chip::DBGMCU => self.dbgmcu.write(off, v),
            x if x == ga || x == gb => {
                let port = usize::from(x == gb);
                let before = self.idr(port);
                let r = self.gpio[port].write(off, v);
                self.look_at_pins(t);
                let after = self.idr(port);
                for pin in 0..16u8 {
                    if (before ^ after) & (1 << pin) != 0 {
                        self.exti.edge(port, pin, after & (1 << pin) != 0);
                    }
                }
                r
            }
            _ if (0xE000_0000..0xE010_0000).contains(&a) => {
                let (hclk, cyc) = (self.hclk(), self.cycles());
                self.scs
                    .write(exact, v >> (8 * (exact & 3)), size, t, hclk, cyc)
            }
            _ => Access::Unmodelled,
        }
    }

    /// The CPU wrote to the flash memory array (a program attempt).
    pub fn flash_store(&mut self, a: u32, size: usize, v: u64) {
        let t = self.now();
        self.sync(t);
        if let FlashWrite::Fault(m) = self.flash.write_data(a, size, v, t) {
            self.fail(m);
        }
        self.sync(t);
    }

    /// Whether the firmware has its receiver armed (boot finished).
    pub fn line_ready(&self) -> bool {
        self.usart.rx_armed()
    }
}

fn mask(size: usize) -> u64 {
    if size >= 8 {
        u64::MAX
    } else {
        (1u64 << (8 * size)) - 1
    }
}
