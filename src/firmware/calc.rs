//! The arithmetic of the firmware glue: receiver timeout, step-timer
//! prescaler and pulse timing, switch debounce, log rate limiting. (Switch
//! polarity, ENABLE/BRAKE and DIR inversion are the core's `drive::io`.)
//!
//! No HAL types here, so `tests/firmware_calc.rs` includes this file by path
//! and checks it on the host — the rest of `src/firmware/` only builds for
//! the boards.

use modbus_drive::dictionary::{DEFAULT_STEP_PULSE_NS, MAX_STEP_SHAPE_NS};
use modbus_drive::rtu::{DriverEnable, LineConfig};

// ---------------------------------------------------------------- serial line

/// t3.5 as a USART receiver timeout in bit times (STM32G4 `USART_RTOR.RTO`).
///
/// The G4 receiver-timeout counter runs in bit times from the end of the last
/// stop bit (RM0440, "Modbus/RTU" in the USART chapter), which is exactly the
/// silence SPEC §1 measures: 3.5 characters up to 19200 baud, 1750 µs above.
/// Rounded up, so the frame never closes early.
#[cfg_attr(not(feature = "board-g431"), allow(dead_code))] // F103: no receiver timeout
pub fn t35_rto_bits(line: LineConfig) -> u32 {
    if line.baud() <= 19_200 {
        (35 * line.format().bits_per_char()).div_ceil(10)
    } else {
        modbus_drive::arith::div_ceil_u64(1750 * u64::from(line.baud()), 1_000_000) as u32
    }
}

/// How long a wait of `delay_us` after the last byte must still run (the
/// F103's frame gap: t3.5 after the last byte, SPEC §1). Timestamps are
/// wrapping µs (`rtu::FrameAssembler`).
#[cfg_attr(feature = "board-g431", allow(dead_code))]
pub fn reply_wait_us(now_us: u32, last_byte_at_us: u32, delay_us: u32) -> u32 {
    delay_us.saturating_sub(now_us.wrapping_sub(last_byte_at_us))
}

/// Longest DE assertion / deassertion time the STM32G4 USART makes itself
/// (`USART_CR1.DEAT` / `DEDT`, 5 bits, in sample times: 1/16 bit, or 1/8
/// with OVER8).
pub const MAX_DE_SAMPLES: u32 = 31;

/// How the glue drives DE for PA57 / PA58 (docs/firmware.md, "RS-485 driver enable").
/// `Default`: the USART alone, no lead or tail (what the glue holds until
/// the line is first applied, before any reply).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DeDrive {
    /// `DEAT` / `DEDT` for the USART's hardware DE (sample times).
    pub deat: u8,
    pub dedt: u8,
    /// The glue drives DE as a GPIO: raised `lead_us` before the first byte
    /// is handed to the USART (whose `deat` adds to it), dropped `tail_us`
    /// after transmission complete. Otherwise the USART alone drives it,
    /// and the glue still waits `tail_us` before touching the USART again.
    pub software: bool,
    pub lead_us: u32,
    pub tail_us: u32,
}

impl DeDrive {
    /// `de` on `line`. `samples_per_bit`: 16 or 8 for a USART with hardware
    /// DE (the G431's), 0 for none (the F103's, DE a GPIO). The hardware
    /// does it alone while lead and tail fit `DEAT` / `DEDT`; beyond,
    /// software extends the lead by what `DEAT` lacks and times the tail.
    pub const fn new(de: DriverEnable, line: LineConfig, samples_per_bit: u32) -> Self {
        let lead = de.lead_bits() as u32 * samples_per_bit;
        let tail = de.tail_bits() as u32 * samples_per_bit;
        let fits = samples_per_bit > 0 && lead <= MAX_DE_SAMPLES && tail <= MAX_DE_SAMPLES;
        let deat = if lead > MAX_DE_SAMPLES {
            MAX_DE_SAMPLES
        } else {
            lead
        };
        // Software times the tail as a GPIO and hands the pin back to the
        // USART at its end: the USART's own DE must be low by then, so it
        // drops at the last stop bit (DEDT 0) whenever software drives.
        let dedt = if !fits { 0 } else { tail };
        let (lead_us, tail_us) = if fits || samples_per_bit == 0 {
            (de.lead_us(line), de.tail_us(line))
        } else {
            // what DEAT does not cover, rounded up (µs = samples / (baud·spb))
            // (u32: lead ≤ MAX_DE_BITS · 16 samples, so `rest` < 2^32)
            let rest = (lead - deat) * 1_000_000;
            let per_s = line.baud().saturating_mul(samples_per_bit);
            (rest.div_ceil(per_s), de.tail_us(line))
        };
        Self {
            deat: deat as u8,
            dedt: dedt as u8,
            software: !fits,
            lead_us,
            tail_us,
        }
    }
}

// ---------------------------------------------------------------- step output

/// Safe minimum DIR set-up time before the STEP edge: 5 µs.
pub const MIN_DIR_SETUP_NS: u32 = 5_000;
/// Longest period of the 16-bit step timer, in ticks.
pub const MAX_PERIOD_TICKS: u32 = 1 << 16;
/// The step engine's idle entry, also its longest: no step due, and the
/// pieces of a longer interval. The entries written ahead of the timer (two
/// buffer halves and the preload) then reach less than a control period
/// plus the planner's horizon ahead (docs/firmware.md).
pub const IDLE_PERIOD_NS: u32 = 50_000;

/// Nanoseconds → timer ticks at `tick_hz`, rounded up (a minimum stays a minimum).
pub const fn ns_to_ticks(ns: u32, tick_hz: u32) -> u32 {
    modbus_drive::arith::div_ceil_u64(ns as u64 * tick_hz as u64, 1_000_000_000) as u32
}

/// The step timer's prescaler register value (PSC) for a tick of `tick_hz`
/// from a timer clock of `timer_clock_hz`: `None` unless the division is
/// whole and fits the 16-bit register — the planner times every step in
/// these ticks (`PlannerConfig::tick_hz`), so an inexact tick would make
/// every move slower or faster than asked.
pub const fn step_prescaler(timer_clock_hz: u32, tick_hz: u32) -> Option<u16> {
    if tick_hz == 0 || !timer_clock_hz.is_multiple_of(tick_hz) {
        return None;
    }
    let div = timer_clock_hz / tick_hz;
    if div == 0 || div > 1 << 16 {
        None
    } else {
        Some((div - 1) as u16)
    }
}

/// A parameter in 0.1 µs as ns, raised to `min_ns` and capped at 100 µs.
const fn shape_ns(v_100ns: u16, min_ns: u32) -> u32 {
    let ns = v_100ns as u32 * 100;
    if ns < min_ns {
        min_ns
    } else if ns > MAX_STEP_SHAPE_NS {
        MAX_STEP_SHAPE_NS
    } else {
        ns
    }
}

/// STEP pulse width and DIR set-up time in step-timer ticks.
///
/// The pulse width is the core's reading of PA15
/// (`Params::step_pulse_ns`: 2.5 µs at 0, else as asked, which also caps
/// the step rate); PA16 (DIR set-up) is in 0.1 µs, where 0 or anything
/// below the safe minimum gives the minimum. SPEC §7 leaves both
/// unassigned (reserved, default 0); anything above 100 µs is capped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StepShape {
    pub pulse_ticks: u32,
    pub dir_setup_ticks: u32,
    pub idle_ticks: u32,
}

impl StepShape {
    pub const fn from_params(pulse_ns: u32, pa16_dir_setup_100ns: u16, tick_hz: u32) -> Self {
        let idle_ticks = ns_to_ticks(IDLE_PERIOD_NS, tick_hz);
        Self {
            pulse_ticks: ns_to_ticks(pulse_ns, tick_hz),
            dir_setup_ticks: ns_to_ticks(shape_ns(pa16_dir_setup_100ns, MIN_DIR_SETUP_NS), tick_hz),
            idle_ticks: if idle_ticks > MAX_PERIOD_TICKS {
                MAX_PERIOD_TICKS
            } else {
                idle_ticks
            },
        }
    }

    /// The defaults (PA15 = PA16 = 0).
    pub const fn safe(tick_hz: u32) -> Self {
        Self::from_params(DEFAULT_STEP_PULSE_NS, 0, tick_hz)
    }

    /// Pulse width and DIR set-up in one word, for an atomic hand-over to
    /// the step engine's refill (both are at most `MAX_STEP_SHAPE_NS` in ticks, which
    /// fits 16 bits at any tick up to 655 MHz).
    pub const fn packed(self) -> u32 {
        (self.pulse_ticks & 0xFFFF) | (self.dir_setup_ticks & 0xFFFF) << 16
    }

    /// This shape with the pulse width and DIR set-up of `packed`.
    pub const fn with_packed(self, packed: u32) -> Self {
        Self {
            pulse_ticks: packed & 0xFFFF,
            dir_setup_ticks: packed >> 16,
            ..self
        }
    }
}

/// Direction runs a [`StepLedger`] remembers: more than can be unmade at
/// once. A run starts only from rest (the planner's rule), with a move
/// planned at a control period; the step engine's buffer holds less than
/// a control period of entries, so at most two runs are ever unmade.
pub const LEDGER_RUNS: usize = 4;
/// A direction run this long ([`StepLedger`]) has more steps than the
/// step engine's buffer can hold ahead of the pin (its entries times the
/// most periods an entry repeats), and fewer than the counts' modulus.
pub const LONG_RUN: u16 = 1 << 15;
/// Words of a [`StepLedger`]'s hand-over.
pub const LEDGER_WORDS: usize = 1 + LEDGER_RUNS / 2;

/// What the step engine's refill hands [`StepLedger::pin_position`] for
/// the STEP pin's position (steps.rs): the steps given to the timer, where
/// each of the last direction runs started, and whether the schedule has
/// counted the last step. Counts modulo 2^16, like the pulse counter
/// (TIM3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StepLedger {
    given: u16,
    /// The newest run's index in `starts` (the ring's head).
    newest: u8,
    forward: bool,
    pending: bool,
    /// The newest run has [`LONG_RUN`] steps or more: more than can be
    /// ahead of the pin, and its start, modulo 2^16 like the counts, no
    /// longer tells its length.
    long: bool,
    /// Index of each run's first step; runs alternate in direction.
    starts: [u16; LEDGER_RUNS],
}

impl Default for StepLedger {
    fn default() -> Self {
        Self::new()
    }
}

impl StepLedger {
    /// At rest, forward (the direction a `StepSource` starts in).
    pub const fn new() -> Self {
        Self {
            given: 0,
            newest: 0,
            forward: true,
            pending: false,
            long: false,
            starts: [0; LEDGER_RUNS],
        }
    }

    /// Marks the newest run long once it is. Call it at least once every
    /// [`LONG_RUN`] steps given, so that the run's length is seen before
    /// it wraps: the refill's feed calls it once a fill (a fill gives far
    /// fewer), not once a step.
    pub fn check_long(&mut self) {
        let start = self.starts[usize::from(self.newest)];
        self.long |= self.given.wrapping_sub(start) >= LONG_RUN;
    }

    /// One `StepSource::advance`: `Some(forward)` is a step given to the
    /// timer, which the schedule counts from the next `advance` on (it
    /// counts the pending step at the next call, or when it runs dry).
    pub fn advanced(&mut self, step: Option<bool>) {
        self.pending = step.is_some();
        if let Some(forward) = step {
            if forward != self.forward {
                self.forward = forward;
                self.newest = (self.newest + 1) % LEDGER_RUNS as u8;
                self.starts[usize::from(self.newest)] = self.given;
                self.long = false;
            }
            self.given = self.given.wrapping_add(1);
        }
    }

    /// `n` more steps given in the direction of the last one, which is
    /// still pending (`StepSource::advance_plain`'s steps).
    pub fn advanced_plain(&mut self, n: u16) {
        self.given = self.given.wrapping_add(n);
    }

    /// `n` steps of the newest run, given before the pending one, are
    /// not made after all (`StepSource::take_back`).
    pub fn taken_back(&mut self, n: u16) {
        self.given = self.given.wrapping_sub(n);
    }

    /// The STEP pin's position, from the schedule's position `pos` and the
    /// pulses the timer has made (`made`, mod 2^16): the steps the schedule
    /// counted and the timer has not made yet are taken back, run by run
    /// from the newest, each in its direction.
    pub fn pin_position(&self, pos: i32, made: u16) -> i32 {
        let mut end = self.given.wrapping_sub(u16::from(self.pending));
        let mut ahead = end.wrapping_sub(made);
        let mut dir: i32 = if self.forward { 1 } else { -1 };
        let mut at = usize::from(self.newest);
        let mut pin = pos;
        for _ in 0..LEDGER_RUNS {
            if ahead == 0 {
                break;
            }
            let start = self.starts[at];
            let n = if at == usize::from(self.newest) && self.long {
                ahead
            } else {
                end.wrapping_sub(start).min(ahead)
            };
            pin = pin.wrapping_sub(dir * i32::from(n));
            ahead -= n;
            end = start;
            dir = -dir;
            at = (at + LEDGER_RUNS - 1) % LEDGER_RUNS;
        }
        pin
    }

    /// The hand-over through atomics is [`StepLedger::head_word`] and the
    /// [`StepLedger::start_word`]s, read back by [`StepLedger::from_words`];
    /// all zeros is [`StepLedger::new`]. The head word changes with every
    /// step, the others only when a new run starts
    /// ([`StepLedger::newest_run`]).
    /// The steps given, the newest run and the flags.
    pub fn head_word(&self) -> u32 {
        u32::from(self.given)
            | u32::from(self.newest) << 16
            | u32::from(!self.forward) << 24
            | u32::from(self.pending) << 25
            | u32::from(self.long) << 26
    }

    /// The starts of runs `2k` and `2k + 1`.
    pub fn start_word(&self, k: usize) -> u32 {
        u32::from(self.starts[2 * k]) | u32::from(self.starts[2 * k + 1]) << 16
    }

    /// Where the newest run is kept: it moves on with each new run.
    pub fn newest_run(&self) -> u8 {
        self.newest
    }

    /// From the head word and the start words, in that order.
    pub fn from_words(w: &[u32; LEDGER_WORDS]) -> Self {
        let mut starts = [0; LEDGER_RUNS];
        for (k, pair) in starts.chunks_mut(2).enumerate() {
            pair[0] = w[1 + k] as u16;
            pair[1] = (w[1 + k] >> 16) as u16;
        }
        Self {
            given: w[0] as u16,
            newest: (w[0] >> 16) as u8 % LEDGER_RUNS as u8,
            forward: w[0] >> 24 & 1 == 0,
            pending: w[0] >> 25 & 1 != 0,
            long: w[0] >> 26 & 1 != 0,
            starts,
        }
    }
}

// ---------------------------------------------------------------- switches

/// Samples needed before a switch change is believed (at 1 kHz: 3 ms).
pub const DEBOUNCE_SAMPLES: u8 = 3;

/// Integrating debounce for one switch, sampled by the control loop.
#[derive(Clone, Copy, Debug, Default)]
pub struct Debounce {
    stable: bool,
    count: u8,
}

impl Debounce {
    pub const fn new(initial: bool) -> Self {
        Self {
            stable: initial,
            count: 0,
        }
    }

    pub fn state(&self) -> bool {
        self.stable
    }

    /// One raw sample; returns the new stable state when it changes.
    pub fn sample(&mut self, raw: bool) -> Option<bool> {
        if raw == self.stable {
            self.count = 0;
            return None;
        }
        self.count += 1;
        if self.count >= DEBOUNCE_SAMPLES {
            self.stable = raw;
            self.count = 0;
            Some(raw)
        } else {
            None
        }
    }
}

/// One switch input: the control loop's [`Debounce`] plus the step count
/// at which its pending change began (SPEC §8.6: the homing origin is the
/// position at the deciding edge, not where the debounce believed it).
///
/// With a bouncing contact the latch keeps the *first* raw reading away from
/// the stable state (the contact's first touch or release: where the switch
/// physically is) and forgets it only at a sample that reads the stable
/// state again — a filtered glitch, or a bounce long enough for the
/// debounce to restart its count, which then latches anew from there.
#[derive(Clone, Copy, Debug, Default)]
pub struct LatchedSwitch {
    debounce: Debounce,
    edge: Option<i32>,
}

impl LatchedSwitch {
    pub const fn new(initial: bool) -> Self {
        Self {
            debounce: Debounce::new(initial),
            edge: None,
        }
    }

    pub fn state(&self) -> bool {
        self.debounce.state()
    }

    /// A raw reading at step count `position` (the switch interrupt at each
    /// edge, and the control loop before each sample).
    pub fn edge(&mut self, raw: bool, position: i32) {
        if raw != self.state() && self.edge.is_none() {
            self.edge = Some(position);
        }
    }

    /// One control-loop sample of the raw reading: `Some(edge)` when the
    /// stable state changes now, with the latched step count if any.
    pub fn sample(&mut self, raw: bool) -> Option<Option<i32>> {
        let changed = self.debounce.sample(raw).is_some();
        // at the stable state (just changed to it, or back after a glitch)
        // the latch is spent
        let edge = if raw == self.state() {
            self.edge.take()
        } else {
            None
        };
        changed.then_some(edge)
    }
}

// ---------------------------------------------------------------- logging

/// Lets one log line through per `period_ms` and counts the rest, so a noisy
/// bus cannot flood the RTT channel.
#[derive(Clone, Copy, Debug)]
pub struct RateLimit {
    period_ms: u32,
    last_ms: Option<u32>,
    suppressed: u32,
}

impl RateLimit {
    pub const fn new(period_ms: u32) -> Self {
        Self {
            period_ms,
            last_ms: None,
            suppressed: 0,
        }
    }

    /// `Some(n)` if this event may be logged, `n` = events suppressed since
    /// the last one logged.
    pub fn allow(&mut self, now_ms: u32) -> Option<u32> {
        match self.last_ms {
            Some(last) if now_ms.wrapping_sub(last) < self.period_ms => {
                self.suppressed = self.suppressed.saturating_add(1);
                None
            }
            _ => {
                self.last_ms = Some(now_ms);
                Some(core::mem::take(&mut self.suppressed))
            }
        }
    }
}

// ---------------------------------------------------------------- faults

/// IWDG timeout (fault.rs says why this figure).
pub const WATCHDOG_TIMEOUT_US: u32 = 500_000;
/// The longest the control loop may legitimately not run: an EE operation
/// on the dispatcher (same thread), a page erase of up to 40 ms on either
/// chip plus a page move that rewrites a few records (RM0440 / RM0008 flash
/// timings), rounded up.
pub const LONGEST_STALL_US: u32 = 100_000;
/// The longest a supervised task (fault.rs: the dispatcher) may
/// legitimately stay busy with one event: a frame's
/// reply wait (PA56 up to 100 ms, plus t3.5), the longest reply at the
/// slowest line (256 characters of 12 bits at 9600 baud: 320 ms), DE lead
/// and tail, and an EE operation ([`LONGEST_STALL_US`]); with room for the
/// control loop sharing the thread. `tests/firmware_calc.rs` checks the sum.
pub const TASK_LIMIT_US: u32 = 1_000_000;
/// The LSI the IWDG counts: nominal frequency (what the driver computes the
/// reload from) and the top of its datasheet tolerance, per board.
#[cfg_attr(feature = "board-f103", allow(dead_code))]
pub const LSI_G431_HZ: (u32, u32) = (32_000, 34_000);
#[cfg_attr(feature = "board-g431", allow(dead_code))]
pub const LSI_F103_HZ: (u32, u32) = (40_000, 60_000);

/// IWDG prescaler register value (PR: divider 4 << PR) and reload (RLR) for
/// a timeout of at least `timeout_us` at an LSI of `lsi_hz`: the smallest
/// divider whose 12-bit reload reaches it (the finest resolution). `None`
/// if even the largest divider (256) cannot.
pub const fn iwdg_settings(timeout_us: u32, lsi_hz: u32) -> Option<(u8, u16)> {
    let mut pr = 0;
    while pr <= 6 {
        let divider = 4u64 << pr;
        // counts of the divided LSI, rounded up: the timeout is a minimum
        let counts = (timeout_us as u64 * lsi_hz as u64).div_ceil(divider * 1_000_000);
        if counts >= 1 && counts <= 0x1000 {
            return Some((pr as u8, (counts - 1) as u16));
        }
        pr += 1;
    }
    None
}

/// The IWDG's timeout for [`iwdg_settings`]' `(pr, rl)` at `lsi_hz`, µs.
pub const fn iwdg_timeout_us(pr: u8, rl: u16, lsi_hz: u32) -> u32 {
    ((rl as u64 + 1) * (4u64 << pr) * 1_000_000 / lsi_hz as u64) as u32
}

/// The NMI of a flash ECC error (STM32G4 `FLASH_ECCR`): is it a double
/// error in the parameter pages, which the next flash read reports as a
/// read error (the store then loads the defaults and says why), rather
/// than a fault? `addr` is `ADDR_ECC`, the byte offset from the start of
/// the flash; `system_flash` is `SYSF_ECC`. An error anywhere else is in
/// code or constants: the fault path.
#[cfg_attr(not(feature = "board-g431"), allow(dead_code))] // F103: no flash ECC
pub fn ecc_error_is_parameter_read(
    double_error: bool,
    system_flash: bool,
    addr: u32,
    param_pages: core::ops::Range<u32>,
) -> bool {
    double_error && !system_flash && param_pages.contains(&addr)
}

// ---------------------------------------------------------------- reset cause

/// DP-rES (0x0017) codes of the reset cause (docs/parameters.md).
pub mod reset_cause {
    pub const POWER_ON: u16 = 0;
    pub const PIN: u16 = 1;
    pub const INDEPENDENT_WATCHDOG: u16 = 2;
    pub const SOFTWARE: u16 = 3;
    pub const WINDOW_WATCHDOG: u16 = 4;
    pub const LOW_POWER: u16 = 5;
    pub const OPTION_BYTES: u16 = 6;
    pub const NONE_FLAGGED: u16 = 7;
}

/// The reset cause from `RCC_CSR`'s flags, which the two chips place alike
/// (RM0440 RCC_CSR, RM0008 RCC_CSR): bit 31 LPWRRSTF, 30 WWDGRSTF, 29
/// IWDGRSTF, 28 SFTRSTF, 27 PORRSTF (F1) / BORRSTF (G4), 26 PINRSTF, 25
/// OBLRSTF (G4 only). Every internal reset also pulls NRST, so PINRSTF comes
/// with each of them and names the pin only when alone; a power-on sets the
/// pin flag too. The flags add up until cleared (RMVF), so the glue clears
/// them after reading.
pub fn reset_cause_from_csr(csr: u32) -> u16 {
    use reset_cause::*;
    let flag = |bit: u32| csr & (1 << bit) != 0;
    if flag(27) {
        POWER_ON
    } else if flag(31) {
        LOW_POWER
    } else if flag(30) {
        WINDOW_WATCHDOG
    } else if flag(29) {
        INDEPENDENT_WATCHDOG
    } else if flag(28) {
        SOFTWARE
    } else if flag(25) {
        OPTION_BYTES
    } else if flag(26) {
        PIN
    } else {
        NONE_FLAGGED
    }
}
