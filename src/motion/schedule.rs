//! The step schedule between the planner (thread mode) and the step-timer
//! interrupt, and the interrupt side that consumes it ([`StepSource`]).
//!
//! A [`Segment`] is Klipper's `(interval, count, add)` with three more
//! terms: `count` steps, the first `interval` after the previous step;
//! after each step the interval grows by `add`, `add` by `add2`, `add2` by
//! `add3` and `add3` by `add4`. The intervals are thus a quartic in the
//! step number (the step times a quintic), which lets the planner match
//! the profile's time, velocity and acceleration at both ends of every
//! segment, so that the motor sees no velocity or acceleration jump from
//! one segment to the next. Times are timer ticks in Q32.32 fixed point.
//!
//! # A ring of per-step delays
//!
//! [`StepSchedule::push`] (thread mode) expands each segment — or, with
//! [`StepSchedule::push_steps`], its next steps — into its steps' integer
//! delays, one `u32` per step, in a ring of [`SCHEDULE_STEPS`] entries: it
//! accumulates the exact Q32.32 times (the five adds per step above) and
//! carries the fraction of each time into
//! the next (`frac`, whose origin is half a tick in when a run starts from
//! rest), so every delay rounds its exact time to the nearest tick and
//! rounding never accumulates. The interrupt only pops one delay per step.
//! An entry is a delay (1 ..= `MAX_DELAY_TICKS`), the end sentinel `END`
//! (0), or a direction marker (`MARK_FORWARD` / `MARK_BACKWARD`, the top two
//! values): a push whose direction differs from the previous push's starts
//! with a marker (directions change at rest only, so markers are rare).
//! Delays from 2^31 ticks on are valid too but, like markers and the
//! sentinel, go the slow way (below).
//!
//! # Sharing between thread mode and the interrupt
//!
//! [`StepSchedule`] is a lock-free single-producer / single-consumer ring
//! built from atomics only (no `unsafe`, no critical section): the planner
//! pushes with `&StepSchedule`, the interrupt pops with the same shared
//! reference. The firmware keeps it in a `static` (all zeros: .bss,
//! src/firmware/steps.rs), hands it to [`crate::Device::control`] in the
//! control loop and owns a [`StepSource`] inside the step-timer interrupt.
//! Exactly one context may push and exactly one may pop.
//!
//! The drive has one core, and the step interrupt is never preempted by
//! thread mode or by the limit-switch interrupt (it has the highest
//! priority): each context sees the other's stores whole and in program
//! order, so only the compiler must keep them in order. Every access is
//! therefore Relaxed (a plain `ldr`/`str` on Cortex-M, also on M0, which
//! has no atomic read-modify-write; none is used), with a `compiler_fence`
//! where the order matters; no `dmb` anywhere (it would matter only
//! between cores). Host builds run producer and consumer on one thread.
//!
//! - `head` (producer): the index the next push writes; `ring[head]` always
//!   holds `END`. A push writes its entries after `head`, then the new
//!   sentinel behind them, and only then overwrites the old sentinel with
//!   its first entry: the interrupt, which reads `ring[next]`, never sees a
//!   half-written push, and needs no look at `head` per step. One slot
//!   stays spare for the sentinel.
//! - `next` (consumer, one store per step): the index of the entry after
//!   the step announced and not yet made (the pending one, at `next − 1`),
//!   or, when idle, after the last entry taken. The producer never writes
//!   the slot at `next − 1`.
//! - The position is not stored per step: [`StepSchedule::position`]
//!   derives it as `base_pos + dir · (next − base_idx)`, where the base
//!   (position, index, direction) is rewritten only in the slow path under
//!   a sequence count.
//! - Thread mode and the limit-switch interrupt never make the interrupt
//!   read their flags per step either: they store the flag (flush, limits,
//!   brake rate), then raise attention (clear `quiet`, the one byte the
//!   interrupt reads per step besides the ring); the interrupt sets `quiet`
//!   before it reads the flags, so no change is lost. It clears `quiet`
//!   itself while it is idle or braking, so that a start from rest and
//!   every braking step go the slow way.
//! - A drop of the queue (flush, the limit brake's end, [`StepSource::cancel`])
//!   moves `next` to `head` and takes the direction of the last push
//!   (`head_backward`, stored before `head`), so that the markers it
//!   skipped cannot leave the interrupt in the wrong direction.
//!
//! With the `sim` feature (the simulated axis of the tests, the virtual
//! drive, the fuzz targets) the schedule also keeps each step's carried
//! fraction beside its delay (`exact_frac`), so that the simulation can
//! report the exact time every step was scheduled for
//! ([`StepSource::rounding_q32`]). The firmware and the benchmarks build
//! without it: one layout on every target, the one the firmware runs.
//!
//! # Worst-case interrupt cost
//!
//! [`StepSource::advance`] per step (the fast path): load `next`, store
//! `next + 1`, load the entry there and `quiet`, two compares. No
//! multiplication, no division, no loop, no `dmb`: 11 Cortex-M4
//! instructions besides the call (README "Drive behaviour" has the
//! measured figure). The slow path (a start from rest, the end of the
//! queue, a marker, a delay from 2^31 ticks, a flag raised) rewrites the
//! position base under the sequence count (about 65 instructions); it
//! takes at most one marker and one step, so it is constant time too. A
//! braking step (below) costs six 64×64 → 128-bit multiplies and a
//! variable shift, still no division and no loop. The expansion is thread
//! mode's, in [`StepSchedule::push`]: on the M4 14 instructions per step
//! when the higher terms fit 32 bits (`Expansion::narrow`, the common
//! segment; about 40 otherwise) plus a few dozen per push (README "Proof").
//!
//! # Limit brake (SPEC §8.7, issue 6)
//!
//! A limit switch must stop motion towards it with the quick stop
//! deceleration 0x6085 *at once*: the planner only appends behind its
//! queued horizon, and the control loop runs every millisecond. So the
//! limit-switch interrupt (a third context) writes the logical limit states
//! with [`StepSchedule::set_limits`] (raising attention), and
//! [`StepSource::advance`], when its next step goes towards an active limit
//! while the brake is armed (checked when attention is raised and at every
//! start from rest or direction marker, the only places where either can
//! change) ([`StepSchedule::set_brake_rate`], written by the drive: 0x6085
//! outside homing, disarmed in homing where the sequencer decides at the
//! limits), stops taking entries and decelerates on its own from the
//! interval of the step it would have made: each interval grows by
//! the factor `(1 - 2q)^-1/2 ≈ 1 + q + 3/2 q² + 5/2 q³ + 35/8 q⁴` with `q = a·p²`
//! (`p` the interval, `a` the deceleration in steps/tick²), which is
//! `v² ← v² - 2a` per step, the constant deceleration, in a few multiplies.
//! It stops when `q ≥ 1/4` (less than two steps from rest), drops the queue
//! and latches ([`LimitBrake::done`]): any segment pushed before the planner
//! noticed is dropped, until thread mode calls
//! [`StepSchedule::release_brake`] (the planner does, once it has taken the
//! position back: [`crate::motion::Planner::stop_at_once`]). A flush
//! requested while braking is carried out when the brake ends.

use core::sync::atomic::{compiler_fence, AtomicBool, AtomicI32, AtomicU32, AtomicU8, Ordering};

use super::profile::ratio;

/// Entries of the per-step ring (a power of two): delays plus the rare
/// direction markers, one slot for the end sentinel and the pending step.
/// At the highest step rate (200 000 steps/s) a full ring lasts 2.5 ms,
/// more than two 1 ms control periods.
pub const SCHEDULE_STEPS: usize = 512;

/// Fractional bits of schedule times: Q32.32 ticks.
pub const TICK_FRAC_BITS: u32 = 32;

/// Ring entry: end of the queue (the sentinel at `head`).
const END: u32 = 0;
/// Ring entries: the steps after it go in the positive / negative direction.
const MARK_FORWARD: u32 = u32::MAX;
const MARK_BACKWARD: u32 = u32::MAX - 1;
/// Longest delay an entry holds, ticks (the top two values are markers).
/// Longer ones are clamped; the planner's slowest interval (0.1 steps/s) is
/// 10 s, 2^32 ticks would be 429 s at 10 MHz.
const MAX_DELAY_TICKS: u32 = u32::MAX - 2;

/// Half a tick in Q0.32: the time origin of a run from rest.
const HALF_TICK: u32 = 1 << (TICK_FRAC_BITS - 1);

/// [`StepSchedule::limits`] bits: the direction an active limit blocks.
const BLOCK_BACKWARD: u8 = 1; // CW limit: the negative end (SPEC §8.6)
const BLOCK_FORWARD: u8 = 2; // CCW limit: the positive end

/// [`StepSchedule::brake`] states (written by the interrupt, except
/// `DONE` → `NONE` by [`StepSchedule::release_brake`]).
const BRAKE_NONE: u8 = 0;
const BRAKE_ACTIVE: u8 = 1;
const BRAKE_DONE: u8 = 2;
const BRAKE_FORWARD: u8 = 4;

/// Mantissa bits of a brake rate ([`brake_rate`]); the shift sits above.
const RATE_MANTISSA_BITS: u32 = 24;
const RATE_MANTISSA: u32 = (1 << RATE_MANTISSA_BITS) - 1;
/// "At once": the first braking step already has `q ≥ 1/4`.
const RATE_AT_ONCE: u32 = RATE_MANTISSA;

/// Brake rate for the step interrupt: the deceleration `decel` (0.1
/// steps/s², the drive's unit, e.g. 0x6085 × PA10) in steps/tick² at
/// `tick_hz`, as a 24-bit mantissa and a shift (`a = mantissa / 2^shift`)
/// packed in one word so that it can be an atomic on every Cortex-M.
/// `decel == 0` means "stop at once" (SPEC §8.3); 0 is never returned
/// (it means "disarmed"). Thread mode; two divisions.
pub fn brake_rate(decel: u64, tick_hz: u32) -> u32 {
    // a = decel / (10 · tick_hz²) steps/tick²
    let den = 10 * u128::from(tick_hz.max(1)).pow(2);
    let num = u128::from(decel);
    if num == 0 {
        return RATE_AT_ONCE;
    }
    if RATE_MANTISSA_BITS as i32 - 1 + den.ilog2() as i32 - (num.ilog2() as i32) < 0 {
        return RATE_AT_ONCE; // more than 2^23 steps/tick²: no step fits
    }
    // the ratio as a 31/32-bit mantissa and a shift (profile::ratio, one
    // 128-by-64 division), cut to 24 bits: the same floor(num·2^s/den)
    let (m, sh) = ratio(num, den);
    let r = (64 - m.leading_zeros()) - RATE_MANTISSA_BITS;
    let (m, s) = (m >> r, sh - r);
    if s > 111 {
        // below 2^-88 steps/tick²: slower than anything the planner runs
        return 1 | (111 << RATE_MANTISSA_BITS);
    }
    (m as u32 & RATE_MANTISSA) | (s << RATE_MANTISSA_BITS)
}

/// The interval after `p` (Q32.32 ticks) when braking at `rate`
/// ([`brake_rate`]), or `None` if the motor is less than two steps from
/// rest (`q ≥ 1/4`) or slower than 2^24 ticks per step. Constant time: six
/// 64×64 multiplies, no division (module docs).
fn brake_interval(p: u64, rate: u32) -> Option<u64> {
    if p >> (TICK_FRAC_BITS + 24) != 0 {
        return None;
    }
    // Rounded, not truncated: near the end v² is a small difference of
    // large numbers, so a bias per step would show there.
    let p8 = p >> 8; // Q32.24, < 2^48
    let p2 = u128::from(p8) * u128::from(p8); // p², Q.48, < 2^96
    let shift = (rate >> RATE_MANTISSA_BITS) + 16;
    let half = 1u128 << (shift - 1);
    let q = (u128::from(rate & RATE_MANTISSA) * p2 + half) >> shift; // q, Q0.32
    if q >= 1 << 30 {
        return None;
    }
    let q = q as u64;
    let mul = |x: u64, y: u64| (x * y + (1 << 31)) >> 32;
    let (q2, q3) = (mul(q, q), mul(mul(q, q), q));
    let q4 = mul(q2, q2);
    // (1-2q)^-1/2 - 1 = q + 3/2 q² + 5/2 q³ + 35/8 q⁴ + …, Q0.32; the rest
    // is below 0.6 % at q = 1/4
    let f = q + q2 + (q2 >> 1) + 2 * q3 + (q3 >> 1) + 4 * q4 + (q4 >> 2) + (q4 >> 3);
    let grow = (u128::from(p) * u128::from(f) + (1 << 31)) >> 32;
    Some(p + grow as u64)
}

/// What the step interrupt's limit brake is doing (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LimitBrake {
    /// The motion it stopped went in the positive direction (towards the
    /// CCW limit).
    pub forward: bool,
    /// The motor is at rest; the schedule stays latched (empty) until
    /// [`StepSchedule::release_brake`].
    pub done: bool,
}

/// A run of steps with linearly changing interval (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Segment {
    /// Ticks (Q32.32) from the previous step to the first step of this one.
    pub interval: u64,
    /// Ticks (Q32.32) added to the interval after every step.
    pub add: i64,
    /// Ticks (Q32.32) added to `add` after every step.
    pub add2: i64,
    /// Added to `add2` after every step, and `add4` to it: the intervals
    /// are a quartic in the step number (the planner's quintic fit of the
    /// step times, planner.rs `fit_segment`).
    pub add3: i64,
    pub add4: i64,
    /// Steps, at least 1 and at most what [`StepSchedule::free`] allows.
    pub count: u32,
    /// Positive direction (position counts up).
    pub forward: bool,
}

impl Segment {
    /// Moves the terms on, as a push of the same steps would, by the
    /// fewest steps (at least one, at most `max`, and at most `count`)
    /// whose exact time reaches `until` (Q32.32 ticks, from the previous
    /// step); `frac` is the fraction carried in and comes out carried on.
    /// Returns the steps and their exact time, the same numbers a push
    /// gives (planner.rs `drop_pending` finds with it where to cut a
    /// segment pushed whole). Writes no entry.
    pub fn advance_until(&mut self, frac: &mut u32, until: u64, max: u32) -> (u32, u64) {
        let mut x = Expansion::of(self, (*frac, 0));
        let max = max.min(self.count);
        let (mut steps, mut time) = (0, 0);
        while steps < max && (steps == 0 || (time as i64) < until as i64) {
            x.step();
            steps += 1;
            time = time_made(*frac, (x.frac, x.sum));
        }
        x.store_terms(self);
        self.count -= steps;
        *frac = x.frac;
        (steps, time)
    }
}

/// The shared ring of per-step delays plus what the interrupt reports back
/// (see the module docs for who may call what). `repr(C)`: the ring at the
/// start and `next`/`quiet` right behind it, so that the interrupt's
/// fast path addresses all three from the schedule's own address.
#[repr(C)]
pub struct StepSchedule {
    ring: [AtomicU32; SCHEDULE_STEPS],
    /// Index (wrapping) of the entry after the pending one, or after the
    /// last one taken while idle (the consumer's one store per step).
    next: AtomicU32,
    /// Cleared ("attention raised") by whoever changes `flush`, `limits` or
    /// `brake_rate`, and by the consumer while it is idle or braking; set
    /// by the consumer when it has looked: its only per-step look at
    /// anything but the ring (module docs).
    quiet: AtomicBool,
    /// Index (wrapping) of the sentinel, where the next push starts
    /// (producer only).
    head: AtomicU32,
    /// Direction of the last push is negative (producer only; stored
    /// before `head`).
    head_backward: AtomicBool,
    /// Fraction of the last pushed step's exact time plus half a tick,
    /// Q0.32, which the next push carries on (producer only).
    frac: AtomicU32,
    /// Position base (consumer only, under `seq`): the position is
    /// `base_pos + base_dir · (next − base_idx)` (`base_dir` ±1, 0 before
    /// the first step).
    base_pos: AtomicI32,
    base_idx: AtomicU32,
    base_dir: AtomicI32,
    /// Sequence count around changes of the base and of `next` outside the
    /// per-step path (odd while they change).
    seq: AtomicU32,
    /// Set by thread mode: drop everything at the next step.
    flush: AtomicBool,
    /// The consumer has a step pending (steps are being generated).
    running: AtomicBool,
    /// Directions blocked by active limits (the limit-switch interrupt).
    limits: AtomicU8,
    /// Armed limit brake ([`brake_rate`]; 0 = disarmed), from the drive.
    brake_rate: AtomicU32,
    /// The limit brake's state (`BRAKE_*`).
    brake: AtomicU8,
    /// Feature `sim`: each entry's carried fraction, as `frac` after that
    /// step (module docs).
    #[cfg(feature = "sim")]
    exact_frac: [AtomicU32; SCHEDULE_STEPS],
}

impl Default for StepSchedule {
    fn default() -> Self {
        Self::new()
    }
}

/// The delay of a step `interval` (Q32.32 ticks) after the previous one:
/// its integer part plus the carry of its fraction into `frac`, the
/// fraction the exact times carry (module docs). The expansion's and the
/// limit brake's.
#[inline(always)]
fn carried(frac: &mut u32, interval: u64) -> u32 {
    let (f, carry) = frac.overflowing_add(interval as u32);
    *frac = f;
    ((interval >> TICK_FRAC_BITS) as u32).wrapping_add(u32::from(carry))
}

/// `delay` as a ring entry: 0 (from an interval below half a tick, never
/// planned: the sentinel's value) becomes 1 and a delay past the longest
/// (or a negative `interval`) [`MAX_DELAY_TICKS`].
#[inline(always)]
fn clamped(delay: u32, interval: u64) -> u32 {
    if delay.wrapping_sub(1) < MAX_DELAY_TICKS {
        delay
    } else if interval >> 63 != 0 {
        MAX_DELAY_TICKS
    } else {
        1
    }
}

/// The exact time (Q32.32 ticks, wrapping) of steps expanded from the
/// carried fraction `frac` to `carry` (fraction, delay sum): the sum of
/// their intervals, which is the delays' sum plus the fraction's change
/// (signed: a carry made it smaller).
fn time_made(frac: u32, carry: (u32, u32)) -> u64 {
    let dfrac = i64::from(carry.0) - i64::from(frac);
    (u64::from(carry.1) << TICK_FRAC_BITS).wrapping_add(dfrac as u64)
}

/// The producer's exact-time accumulator over one segment (module docs).
#[derive(Clone, Copy)]
struct Expansion {
    interval: u64,
    add: u64,
    add2: u64,
    add3: u64,
    add4: u64,
    frac: u32,
    /// The delays written, summed (wrapping): with `frac`'s change, the
    /// exact time they make (`StepSchedule::push_steps`).
    sum: u32,
}

impl Expansion {
    /// The next step's delay: the interval's integer part plus the carry
    /// of its fraction into the pending time's; then the interval one step
    /// on.
    #[inline(always)]
    fn step(&mut self) -> u32 {
        let delay = clamped(carried(&mut self.frac, self.interval), self.interval);
        self.interval = self.interval.wrapping_add(self.add);
        self.add = self.add.wrapping_add(self.add2);
        self.add2 = self.add2.wrapping_add(self.add3);
        self.add3 = self.add3.wrapping_add(self.add4);
        self.sum = self.sum.wrapping_add(delay);
        delay
    }

    /// `seg`'s terms with the carried fraction and delay sum `carry`.
    fn of(seg: &Segment, carry: (u32, u32)) -> Self {
        Self {
            interval: seg.interval,
            add: seg.add as u64,
            add2: seg.add2 as u64,
            add3: seg.add3 as u64,
            add4: seg.add4 as u64,
            frac: carry.0,
            sum: carry.1,
        }
    }

    /// Back into `seg`: its terms, moved on.
    fn store_terms(&self, seg: &mut Segment) {
        seg.interval = self.interval;
        seg.add = self.add as i64;
        seg.add2 = self.add2 as i64;
        seg.add3 = self.add3 as i64;
        seg.add4 = self.add4 as i64;
    }

    /// The next `steps` steps can take the narrow loop of
    /// [`Expansion::run`]: the terms from `add2` on stay inside `i32`
    /// (`add2 + j·add3 + C(j,2)·add4` and `add3 + j·add4` for every
    /// `j ≤ steps`, the terms after the last step included), so 32-bit
    /// sums give them exactly; and every interval stays between 1 and
    /// 2^31 ticks (`|interval_j − interval| ≤ Σ C(steps, k)·|term k|`),
    /// so no delay needs [`clamped`].
    fn narrow(&self, steps: usize) -> bool {
        const LIM: u64 = 1 << 31;
        let m = |t: u64| (t as i64).unsigned_abs();
        let (a1, a2, a3, a4) = (m(self.add), m(self.add2), m(self.add3), m(self.add4));
        if steps > SCHEDULE_STEPS || a1 >= 1 << 48 || (a2 | a3 | a4) >= LIM {
            return false;
        }
        // 32-bit factors from here (one `umull` per product): l ≤ 2^9,
        // C(l, 2) < 2^17, C(l, 3) < 2^25, C(l, 4) < 2^32
        let (l, a2, a3, a4) = (steps as u32, a2 as u32, a3 as u32, a4 as u32);
        let wide = |x: u32, y: u32| u64::from(x) * u64::from(y);
        let c2 = l * l.saturating_sub(1) / 2;
        let c3 = c2 * l.saturating_sub(2) / 3;
        let c4 = (wide(c3, l.saturating_sub(3)) / 4) as u32;
        // each product below 2^57, 2^48, 2^56, 2^63: no overflow
        let drift = a1 * u64::from(l) + wide(c2, a2) + wide(c3, a3) + wide(c4, a4);
        u64::from(a3) + wide(l, a4) < LIM
            && u64::from(a2) + wide(l, a3) + wide(c2, a4) < LIM
            && self.interval.saturating_sub(drift) >= 1 << TICK_FRAC_BITS
            && self.interval.saturating_add(drift) < 1 << 63
    }

    /// [`Expansion::step`] for every entry; with `add2`, `add3` and `add4`
    /// in 32-bit registers and no clamp when [`Expansion::narrow`] allows
    /// (the common push: the higher terms are small): the same delays
    /// and terms from a loop whose state fits the Cortex-M's registers.
    #[inline(always)]
    fn run(&mut self, entries: &[AtomicU32]) {
        if !self.narrow(entries.len()) {
            for entry in entries {
                entry.store(self.step(), Ordering::Relaxed);
            }
            return;
        }
        let (mut interval, mut add) = (self.interval, self.add);
        let (mut add2, mut add3, add4) = (self.add2 as i32, self.add3 as i32, self.add4 as i32);
        let (mut frac, mut sum) = (self.frac, self.sum);
        for entry in entries {
            let delay = carried(&mut frac, interval);
            entry.store(delay, Ordering::Relaxed);
            sum = sum.wrapping_add(delay);
            let next_add3 = add3.wrapping_add(add4);
            let next_add2 = add2.wrapping_add(add3);
            let next_add = add.wrapping_add(add2 as i64 as u64);
            interval = interval.wrapping_add(add);
            (add, add2, add3) = (next_add, next_add2, next_add3);
        }
        (self.interval, self.add) = (interval, add);
        (self.add2, self.add3) = (add2 as i64 as u64, add3 as i64 as u64);
        (self.frac, self.sum) = (frac, sum);
    }

    /// Writes the next steps' delays of `seg` to `first` (if given) and
    /// `entries`, in order, and moves `seg`'s terms and `carry` (fraction,
    /// delay sum) on: one call per push, straight from and to the segment.
    #[inline(never)]
    fn fill(
        seg: &mut Segment,
        carry: &mut (u32, u32),
        first: Option<&mut u32>,
        entries: &[AtomicU32],
    ) {
        let mut x = Self::of(seg, *carry);
        if let Some(first) = first {
            *first = x.step();
        }
        x.run(entries);
        x.store_terms(seg);
        *carry = (x.frac, x.sum);
    }
}

impl StepSchedule {
    /// All zeros (the sentinel is 0, the flags are chosen so), so that a
    /// `static` of it is zero-initialised memory (.bss), no flash image.
    pub const fn new() -> Self {
        Self {
            ring: [const { AtomicU32::new(END) }; SCHEDULE_STEPS],
            next: AtomicU32::new(0),
            quiet: AtomicBool::new(false),
            head: AtomicU32::new(0),
            head_backward: AtomicBool::new(false),
            frac: AtomicU32::new(0),
            base_pos: AtomicI32::new(0),
            base_idx: AtomicU32::new(0),
            base_dir: AtomicI32::new(0),
            seq: AtomicU32::new(0),
            flush: AtomicBool::new(false),
            running: AtomicBool::new(false),
            limits: AtomicU8::new(0),
            brake_rate: AtomicU32::new(0),
            brake: AtomicU8::new(BRAKE_NONE),
            #[cfg(feature = "sim")]
            exact_frac: [const { AtomicU32::new(0) }; SCHEDULE_STEPS],
        }
    }

    fn entry(&self, index: u32) -> &AtomicU32 {
        &self.ring[index as usize % SCHEDULE_STEPS]
    }

    // ---- producer side (thread mode) ----

    /// Entries a push may write now: every slot from the sentinel's up to
    /// the one before the pending entry's (`next − 1`), less one for the
    /// new sentinel.
    fn room(&self) -> u32 {
        let pending = self.next.load(Ordering::Relaxed).wrapping_sub(1);
        let used = self.head.load(Ordering::Relaxed).wrapping_sub(pending);
        (SCHEDULE_STEPS as u32 - 1).saturating_sub(used)
    }

    /// Steps a push can take now, whatever its direction (one entry is
    /// kept for a direction marker). `SCHEDULE_STEPS - 3` when empty.
    pub fn free(&self) -> usize {
        self.room().saturating_sub(1) as usize
    }

    /// Appends a segment, expanded into its steps' delays (module docs);
    /// gives it back when it has no step or the ring lacks room for all of
    /// them (plus a direction marker if the direction changes).
    pub fn push(&self, seg: Segment) -> Result<(), Segment> {
        let mut rest = seg;
        match self.push_steps(&mut rest, seg.count) {
            Some(_) => Ok(()),
            None => Err(seg),
        }
    }

    /// Appends the first `count` steps of `seg` (all of them at most) and
    /// leaves in `seg` the rest: its terms moved on by those steps, its
    /// count reduced (the planner hands a segment over in parts when the
    /// ring lacks room for all of it). Returns the time the appended
    /// steps take, exactly ([`time_made`]). `None`, and
    /// nothing done, when `count` is 0 or the ring lacks room for them.
    #[inline(never)]
    pub fn push_steps(&self, seg: &mut Segment, count: u32) -> Option<u64> {
        let count = count.min(seg.count);
        let head = self.head.load(Ordering::Relaxed);
        let turn = seg.forward == self.head_backward.load(Ordering::Relaxed);
        let entries = count.saturating_add(u32::from(turn));
        if count == 0 || entries > self.room() {
            return None;
        }
        let frac = self.carry_in();
        let mut carry = (frac, 0);
        // ring[head], the old sentinel, is written last (module docs)
        let end = head.wrapping_add(entries);
        let first_step = self.expand(seg, &mut carry, head.wrapping_add(u32::from(turn)), end);
        let first = match (turn, seg.forward) {
            (false, _) => first_step,
            (true, forward) => {
                self.entry(head.wrapping_add(1))
                    .store(first_step, Ordering::Relaxed);
                if forward {
                    MARK_FORWARD
                } else {
                    MARK_BACKWARD
                }
            }
        };
        self.entry(end).store(END, Ordering::Relaxed);
        // one core: program order is all the interrupt needs (module docs)
        compiler_fence(Ordering::SeqCst);
        self.entry(head).store(first, Ordering::Relaxed);
        self.frac.store(carry.0, Ordering::Relaxed);
        compiler_fence(Ordering::SeqCst);
        self.head_backward.store(!seg.forward, Ordering::Relaxed);
        compiler_fence(Ordering::SeqCst);
        self.head.store(end, Ordering::Relaxed);
        seg.count -= count;
        Some(time_made(frac, carry))
    }

    /// The fraction the next push carries on (module docs): the last
    /// pushed step's, or half a tick for a run from rest (the interrupt
    /// idle, nothing queued: only the producer can change that), so that
    /// the delays round every exact time to the nearest tick.
    pub fn carry_in(&self) -> u32 {
        if !self.is_running() && self.is_empty() {
            HALF_TICK
        } else {
            self.frac.load(Ordering::Relaxed)
        }
    }

    /// Takes back the queued entries from ring index `at` on (producer
    /// only): the queue then ends before `at`, and the next push starts
    /// there, carrying the fraction `frac` (that of the step before `at`,
    /// [`Segment::advance_until`]). The planner cuts a segment pushed
    /// whole this way when a new goal arrives (planner.rs `drop_pending`).
    ///
    /// False, and nothing taken back, unless `at` is inside the queue and
    /// not behind the interrupt's next read.
    /// The interrupt reads `ring[next]` and never looks at `head` but to
    /// drop the queue (flush, the limit brake's end, `cancel`), which
    /// moves `next` to `head`. So: `head` first, then the sentinel at
    /// `at`, then a second look at `next`. At or before `at`: the
    /// interrupt has not read the entry there and will find the sentinel
    /// (or has dropped the queue to the new `head`: empty, consistent).
    /// Past it (it read the entry at `at` in between, or dropped the
    /// queue to the old `head`): `head` goes back, and what was written at
    /// `at` lies behind the interrupt, where nobody reads it.
    pub fn truncate(&self, at: u32, frac: u32) -> bool {
        let head = self.head.load(Ordering::Relaxed);
        let next = self.next.load(Ordering::Relaxed);
        if (at.wrapping_sub(next) as i32) < 0 || head.wrapping_sub(at) as i32 <= 0 {
            return false;
        }
        self.head.store(at, Ordering::Relaxed);
        compiler_fence(Ordering::SeqCst);
        self.entry(at).store(END, Ordering::Relaxed);
        compiler_fence(Ordering::SeqCst);
        if (at.wrapping_sub(self.next.load(Ordering::Relaxed)) as i32) < 0 {
            self.head.store(head, Ordering::Relaxed);
            return false;
        }
        self.frac.store(frac, Ordering::Relaxed);
        true
    }

    /// Expands the next steps of `seg` for the entries `from` up to `to`
    /// (excluded, at least one): writes all but the first, which it
    /// returns, so that the caller can write it last.
    fn expand(&self, seg: &mut Segment, carry: &mut (u32, u32), from: u32, to: u32) -> u32 {
        #[cfg(feature = "sim")]
        {
            let mut shadow = Expansion::of(seg, *carry);
            let mut i = from;
            while i != to {
                shadow.step();
                let slot = i as usize % SCHEDULE_STEPS;
                self.exact_frac[slot].store(shadow.frac, Ordering::Relaxed);
                i = i.wrapping_add(1);
            }
        }
        // the first into a local, the rest to the ring in at most two
        // contiguous pieces (the `min`s never cut: fewer than
        // SCHEDULE_STEPS entries)
        let mut first = END;
        let start = from.wrapping_add(1) as usize % SCHEDULE_STEPS;
        let n = to.wrapping_sub(from).wrapping_sub(1) as usize;
        let (before, after) = self.ring.split_at(start);
        let k = n.min(after.len());
        Expansion::fill(seg, carry, Some(&mut first), &after[..k]);
        if k < n {
            Expansion::fill(seg, carry, None, &before[..(n - k).min(before.len())]);
        }
        first
    }

    /// Ring index (wrapping) of the last entry pushed: after a push, its
    /// last step's. The planner keeps it per segment to tell which one
    /// the interrupt is executing ([`StepSchedule::step_index`]).
    pub fn last_pushed_index(&self) -> u32 {
        self.head.load(Ordering::Relaxed).wrapping_sub(1)
    }

    /// Ring index (wrapping) of the step the interrupt has announced and
    /// not yet made, while [`StepSchedule::is_running`] (during a limit
    /// brake: of the last step it took from the ring).
    pub fn step_index(&self) -> u32 {
        self.next.load(Ordering::Relaxed).wrapping_sub(1)
    }

    /// Asks the consumer to drop the pending step and every queued entry
    /// ("stop step output at once", SPEC §8.1/§8.3).
    pub fn request_flush(&self) {
        self.flush.store(true, Ordering::Relaxed);
        self.raise_attention();
    }

    /// Tells the consumer to look at `flush`, `limits` and `brake_rate`
    /// at its next step: the flag after the value (module docs).
    fn raise_attention(&self) {
        self.quiet.store(false, Ordering::Relaxed);
    }

    /// A flush was requested and the consumer has not yet carried it out.
    pub fn flush_pending(&self) -> bool {
        self.flush.load(Ordering::Relaxed)
    }

    /// Clears a flush request nobody will carry out because the interrupt
    /// is idle and the ring empty (the interrupt starts only on a non-empty
    /// ring, and only the producer fills it, so this cannot race).
    pub fn clear_flush_if_idle(&self) {
        if !self.is_running() && self.is_empty() {
            self.flush.store(false, Ordering::Relaxed);
        }
    }

    /// Arms the limit brake with a [`brake_rate`], or disarms it (`None`:
    /// homing, where the sequencer decides at the limits, SPEC §8.6).
    pub fn set_brake_rate(&self, rate: Option<u32>) {
        let rate = rate.unwrap_or(0);
        // thread mode is the only writer: compare, so that the drive may
        // call it every period without sending the interrupt the slow way
        if self.brake_rate.load(Ordering::Relaxed) != rate {
            self.brake_rate.store(rate, Ordering::Relaxed);
            self.raise_attention();
        }
    }

    /// The interrupt's limit brake, if it has engaged and not been
    /// released.
    pub fn limit_brake(&self) -> Option<LimitBrake> {
        let b = self.brake.load(Ordering::Relaxed);
        (b != BRAKE_NONE).then_some(LimitBrake {
            forward: b & BRAKE_FORWARD != 0,
            done: b & BRAKE_DONE != 0,
        })
    }

    /// Lets the interrupt take entries again after a finished brake (the
    /// planner calls it once it has the position back). No effect while
    /// the brake is still running.
    pub fn release_brake(&self) {
        if self.brake.load(Ordering::Relaxed) & BRAKE_DONE != 0 {
            self.brake.store(BRAKE_NONE, Ordering::Relaxed);
        }
    }

    // ---- the limit-switch interrupt (or whoever reads the switches) ----

    /// The enabled limits active now (logical, after PA13/PA14). Call it
    /// on every switch edge, from one context at a time.
    pub fn set_limits(&self, cw_limit: bool, ccw_limit: bool) {
        let bits =
            if cw_limit { BLOCK_BACKWARD } else { 0 } | if ccw_limit { BLOCK_FORWARD } else { 0 };
        if self.limits.load(Ordering::Relaxed) != bits {
            self.limits.store(bits, Ordering::Relaxed);
            self.raise_attention();
        }
    }

    // ---- either side ----

    /// Raw step count: steps made forward minus steps made backward.
    /// Derived from the position base and the index of the pending step
    /// (module docs: the interrupt stores no position per step). Call it
    /// from a context the interrupt may preempt, not from one that may
    /// preempt the interrupt.
    pub fn position(&self) -> i32 {
        loop {
            let seq = self.seq.load(Ordering::Relaxed);
            compiler_fence(Ordering::SeqCst);
            let pos = self.base_position(self.next.load(Ordering::Relaxed));
            compiler_fence(Ordering::SeqCst);
            if seq & 1 == 0 && self.seq.load(Ordering::Relaxed) == seq {
                return pos;
            }
        }
    }

    /// The position formula on the current base at `next` (the consumer,
    /// which writes the base, reads it without the sequence count).
    fn base_position(&self, next: u32) -> i32 {
        let pos = self.base_pos.load(Ordering::Relaxed);
        let idx = self.base_idx.load(Ordering::Relaxed);
        let dir = self.base_dir.load(Ordering::Relaxed);
        pos.wrapping_add(dir.wrapping_mul(next.wrapping_sub(idx) as i32))
    }

    /// Consumer only: `next` and a new base at it (position `pos`,
    /// direction `forward`), under the sequence count that
    /// [`StepSchedule::position`] reads them with.
    fn set_base(&self, pos: i32, next: u32, forward: bool) {
        let seq = self.seq.load(Ordering::Relaxed);
        self.seq.store(seq.wrapping_add(1), Ordering::Relaxed);
        compiler_fence(Ordering::SeqCst);
        self.base_pos.store(pos, Ordering::Relaxed);
        self.base_idx.store(next, Ordering::Relaxed);
        self.base_dir.store(dir(forward), Ordering::Relaxed);
        self.next.store(next, Ordering::Relaxed);
        compiler_fence(Ordering::SeqCst);
        self.seq.store(seq.wrapping_add(2), Ordering::Relaxed);
    }

    /// Steps are being generated (a step is scheduled on the timer).
    pub fn is_running(&self) -> bool {
        self.running.load(Ordering::Relaxed)
    }

    /// Nothing is queued behind the pending step (or behind the last step
    /// made, when idle).
    pub fn is_empty(&self) -> bool {
        self.head.load(Ordering::Relaxed) == self.next.load(Ordering::Relaxed)
    }
}

fn dir(forward: bool) -> i32 {
    if forward {
        1
    } else {
        -1
    }
}

/// What the timer must do next: wait `delay_ticks` (≥ 1) after the step
/// just made (or after the start), then pulse STEP with DIR = `forward`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct NextStep {
    pub delay_ticks: u32,
    pub forward: bool,
}

/// The interrupt side: owned by the step-timer interrupt.
///
/// Protocol: when idle and [`StepSchedule::is_empty`] is false, the glue
/// calls [`StepSource::advance`] (from the interrupt, e.g. by pending it) and
/// arms the timer with the returned delay from now. At each timer expiry it
/// pulses STEP and calls `advance` again, which counts that step and returns
/// the next delay, or `None` (stop the timer) when the schedule ran dry or a
/// flush was requested. DIR may be written as soon as `advance` returns: the
/// whole interval is DIR set-up time.
#[derive(Clone, Debug)]
pub struct StepSource {
    /// Direction of the pending step, and of the entries after it up to
    /// the next marker.
    forward: bool,
    /// A step has been announced and not yet made.
    pending: bool,
    /// The limit brake is running at this rate (0 = not braking).
    braking: u32,
    /// The limit brake's last interval (Q32.32 ticks) and the fraction it
    /// carries, as the producer's (module docs), from the braking start.
    interval: u64,
    frac: u32,
}

impl Default for StepSource {
    fn default() -> Self {
        Self::new()
    }
}

impl StepSource {
    /// Matches [`StepSchedule::new`]: idle, forward.
    pub const fn new() -> Self {
        Self {
            forward: true,
            pending: false,
            braking: 0,
            interval: 0,
            frac: 0,
        }
    }

    /// See the type docs. Constant time; the cost is in the module docs.
    #[inline]
    pub fn advance(&mut self, sched: &StepSchedule) -> Option<NextStep> {
        // The pending step has been made; the next entry is a plain delay
        // unless it is the sentinel, a marker or a long delay (≤ 0 as
        // i32), and nothing needs a look unless `quiet` is clear. `next`
        // moves on before its entry is looked at (one instruction fewer:
        // the old value need not be kept), the slow path puts it back;
        // nobody sees the value in between (module docs: one core, nothing
        // preempts this interrupt).
        let next = sched.next.load(Ordering::Relaxed);
        sched.next.store(next.wrapping_add(1), Ordering::Relaxed);
        let delay = sched.entry(next).load(Ordering::Relaxed);
        if delay as i32 <= 0 || !sched.quiet.load(Ordering::Relaxed) {
            return self.advance_slow(sched);
        }
        Some(NextStep {
            delay_ticks: delay,
            forward: self.forward,
        })
    }

    /// Everything but the next plain delay: starts from rest, the end of
    /// the queue, markers, long delays, flush, limits, the brake. Constant
    /// time too (at most one marker before a step, module docs).
    /// The fast path has moved `next` on by one; every way out of here
    /// stores it again ([`StepSchedule::set_base`]).
    #[inline(never)]
    fn advance_slow(&mut self, sched: &StepSchedule) -> Option<NextStep> {
        let next = sched.next.load(Ordering::Relaxed).wrapping_sub(1);
        let mut made = sched.base_position(next);
        if self.pending {
            made = made.wrapping_add(dir(self.forward));
        }
        if !sched.quiet.load(Ordering::Relaxed) {
            // Clear first, then read the flags: a change made after this
            // raises it again (the writers store the value, then the flag).
            sched.quiet.store(true, Ordering::Relaxed);
            compiler_fence(Ordering::SeqCst);
        }
        if self.braking != 0 {
            // brake steps are no ring entries: count them in the base
            sched.set_base(made, next, self.forward);
            return self.brake_step(sched, made);
        }
        if sched.flush.load(Ordering::Relaxed)
            || sched.brake.load(Ordering::Relaxed) & BRAKE_DONE != 0
        {
            self.drop_all(sched, made);
            return None;
        }
        // The next step, after a direction marker if there is one (a push
        // never ends on a marker: at most one before a step).
        let mut at = next;
        let delay = loop {
            match sched.entry(at).load(Ordering::Relaxed) {
                END => {
                    // the queue ran dry (or was empty): idle until pushed
                    self.pending = false;
                    sched.set_base(made, at, self.forward);
                    sched.running.store(false, Ordering::Relaxed);
                    sched.quiet.store(false, Ordering::Relaxed);
                    return None;
                }
                MARK_FORWARD => self.forward = true,
                MARK_BACKWARD => self.forward = false,
                delay => break delay,
            }
            at = at.wrapping_add(1);
        };
        let block = if self.forward {
            BLOCK_FORWARD
        } else {
            BLOCK_BACKWARD
        };
        if sched.limits.load(Ordering::Relaxed) & block != 0 {
            let rate = sched.brake_rate.load(Ordering::Relaxed);
            if rate != 0 {
                sched
                    .brake
                    .store(BRAKE_ACTIVE | self.brake_dir(), Ordering::Relaxed);
                self.braking = rate;
                // from the interval of the step it would have made, timed
                // from the tick of the one just made
                self.interval = u64::from(delay) << TICK_FRAC_BITS;
                self.frac = HALF_TICK;
                sched.set_base(made, at, self.forward);
                return self.brake_step(sched, made);
            }
        }
        self.pending = true;
        sched.set_base(made, at.wrapping_add(1), self.forward);
        sched.running.store(true, Ordering::Relaxed);
        Some(NextStep {
            delay_ticks: delay,
            forward: self.forward,
        })
    }

    /// One step of the limit brake (module docs), or its end; `made` is
    /// the position reached.
    fn brake_step(&mut self, sched: &StepSchedule, made: i32) -> Option<NextStep> {
        match brake_interval(self.interval, self.braking) {
            Some(p) => {
                let delay = carried(&mut self.frac, p);
                self.interval = p;
                self.pending = true;
                sched.running.store(true, Ordering::Relaxed);
                // every braking step goes the slow way
                sched.quiet.store(false, Ordering::Relaxed);
                Some(NextStep {
                    delay_ticks: delay.max(1),
                    forward: self.forward,
                })
            }
            None => {
                self.braking = 0;
                self.drop_all(sched, made);
                sched
                    .brake
                    .store(BRAKE_DONE | self.brake_dir(), Ordering::Relaxed);
                None
            }
        }
    }

    /// The brake state's direction bit for the current direction.
    fn brake_dir(&self) -> u8 {
        if self.forward {
            BRAKE_FORWARD
        } else {
            0
        }
    }

    /// The glue stopped the timer before the announced step was made (stop
    /// at once): forget it and drop the whole schedule. Call it in the
    /// interrupt's context (or with it masked).
    pub fn cancel(&mut self, sched: &StepSchedule) {
        if self.braking != 0 {
            // a brake cut short is still a brake: latch it for the planner
            sched
                .brake
                .store(BRAKE_DONE | self.brake_dir(), Ordering::Relaxed);
            self.braking = 0;
        }
        // the base counts every step made (the pending one is not)
        self.drop_all(
            sched,
            sched.base_position(sched.next.load(Ordering::Relaxed)),
        );
    }

    /// Exact time of the pending step minus the tick it is announced at
    /// (Q32.32, signed, within ±½ tick): the rounding its delay carries.
    /// Feature `sim` only (module docs), for the simulation's step records.
    #[cfg(feature = "sim")]
    pub fn rounding_q32(&self, sched: &StepSchedule) -> i64 {
        let frac = if self.braking != 0 {
            self.frac
        } else {
            let pending = sched.next.load(Ordering::Relaxed).wrapping_sub(1);
            sched.exact_frac[pending as usize % SCHEDULE_STEPS].load(Ordering::Relaxed)
        };
        i64::from(frac) - i64::from(HALF_TICK)
    }

    /// Drops the pending step and every queued entry; `made` is the
    /// position reached. The next push's entries follow the last pushed
    /// one, in the last push's direction (module docs).
    fn drop_all(&mut self, sched: &StepSchedule, made: i32) {
        self.pending = false;
        let head = sched.head.load(Ordering::Relaxed);
        self.forward = !sched.head_backward.load(Ordering::Relaxed);
        sched.set_base(made, head, self.forward);
        sched.running.store(false, Ordering::Relaxed);
        sched.flush.store(false, Ordering::Relaxed);
        sched.quiet.store(false, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ONE: u64 = 1 << TICK_FRAC_BITS;

    fn seg(interval: u64, add: i64, add2: i64, count: u32, forward: bool) -> Segment {
        Segment {
            interval,
            add,
            add2,
            add3: 0,
            add4: 0,
            count,
            forward,
        }
    }

    /// The narrow loop of `Expansion::run` gives the same delays, terms,
    /// fraction and delay sum as `Expansion::step` one step at a time, on
    /// random segments from tiny to huge terms; it is taken for most
    /// (small higher terms) and refused at the edges of its bounds.
    #[test]
    fn the_narrow_loop_expands_like_step_by_step() {
        let mut x: u64 = 0x2545_F491_4F6C_DD1D;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let narrow_ring = [const { AtomicU32::new(0) }; SCHEDULE_STEPS];
        let (mut narrow, mut wide) = (0, 0);
        let check = |x: Expansion, steps: usize| {
            let mut a = x;
            let mut b = x;
            let took_narrow = a.narrow(steps);
            a.run(&narrow_ring[..steps]);
            for (k, entry) in narrow_ring[..steps].iter().enumerate() {
                assert_eq!(entry.load(Ordering::Relaxed), b.step(), "step {k}");
            }
            let terms = |e: &Expansion| (e.interval, e.add, e.add2, e.add3, e.add4, e.frac, e.sum);
            assert_eq!(terms(&a), terms(&b));
            took_narrow
        };
        for i in 0..20_000u32 {
            // each term's size drawn on its own, signs at random
            let mut term = |lo: u32, span: u64| {
                let t = next() >> (lo + (next() % span) as u32);
                if next() & 1 == 0 {
                    t
                } else {
                    t.wrapping_neg()
                }
            };
            let interval = term(1, 1) >> (i % 40);
            let x = Expansion {
                interval,
                add: term(8, 50),
                add2: term(16, 48),
                add3: term(24, 40),
                add4: term(30, 34),
                frac: term(0, 1) as u32,
                sum: term(0, 1) as u32,
            };
            let steps = 1 + (term(0, 1) % (SCHEDULE_STEPS as u64 - 1)) as usize;
            if check(x, steps) {
                narrow += 1;
            } else {
                wide += 1;
            }
        }
        assert!(
            narrow > 1_000 && wide > 1_000,
            "narrow {narrow}, wide {wide}"
        );
        // at the edges: add2 reaching i32::MAX exactly after 100 steps
        // (taken), one unit beyond (refused); intervals from exactly 1 tick
        // (taken) and just below (refused)
        let edge = |add2: u64, add3: u64, interval: u64| Expansion {
            interval,
            add: 0,
            add2,
            add3,
            add4: 0,
            frac: 0,
            sum: 0,
        };
        let top = (1u64 << 31) - 1 - 100 * 1000;
        assert!(check(edge(top, 1000, 1 << 50), 100));
        assert!(!check(edge(top + 1, 1000, 1 << 50), 100));
        assert!(check(edge(0, 0, ONE), 300));
        assert!(!check(edge(0, 0, ONE - 1), 300));
    }

    fn drain(src: &mut StepSource, sched: &StepSchedule) -> ([u32; 64], usize) {
        let mut out = [0; 64];
        let mut n = 0;
        while let Some(s) = src.advance(sched) {
            out[n] = s.delay_ticks;
            n += 1;
        }
        (out, n)
    }

    #[test]
    fn steps_counted_equal_schedule_and_intervals_are_exact() {
        let sched = StepSchedule::new();
        let mut src = StepSource::new();
        sched.push(seg(10 * ONE, ONE as i64, 0, 3, true)).unwrap();
        sched.push(seg(5 * ONE + ONE / 2, 0, 0, 4, false)).unwrap();
        let (d, n) = drain(&mut src, &sched);
        assert_eq!(n, 7);
        assert_eq!(&d[..3], &[10, 11, 12]);
        // 5.5 ticks each: the fraction is carried, never lost (sum = 22).
        assert_eq!(d[3..7].iter().sum::<u32>(), 22);
        assert!(d[..n].iter().all(|&x| x > 0));
        assert_eq!(sched.position(), 3 - 4);
        assert!(!sched.is_running());
        assert!(sched.is_empty());
    }

    /// The position is derived (no per-step store): after every call it
    /// counts exactly the steps made, across segment ends, reversals, a
    /// flush and a stop (issue 3: steps counted equal the schedule).
    #[test]
    fn derived_position_counts_the_steps_made() {
        let sched = StepSchedule::new();
        let mut src = StepSource::new();
        sched.push(seg(10 * ONE, 0, 0, 3, true)).unwrap();
        sched.push(seg(10 * ONE, 0, 0, 2, false)).unwrap();
        sched.push(seg(10 * ONE, 0, 0, 4, true)).unwrap();
        let mut made = 0i32;
        let mut pending: Option<bool> = None;
        for _ in 0..6 {
            if let Some(fwd) = pending {
                made += if fwd { 1 } else { -1 };
            }
            pending = src.advance(&sched).map(|s| s.forward);
            assert_eq!(sched.position(), made);
        }
        sched.request_flush();
        made += if pending.unwrap() { 1 } else { -1 };
        assert_eq!(src.advance(&sched), None);
        assert_eq!(sched.position(), made);
        assert_eq!(made, 3 - 2 + 1);
        sched.push(seg(10 * ONE, 0, 0, 2, false)).unwrap();
        while src.advance(&sched).is_some() {}
        assert_eq!(sched.position(), made - 2);
    }

    #[test]
    fn second_difference_term() {
        let sched = StepSchedule::new();
        let mut src = StepSource::new();
        sched
            .push(seg(10 * ONE, ONE as i64, ONE as i64, 4, true))
            .unwrap();
        let (d, n) = drain(&mut src, &sched);
        // intervals 10, 11, 13, 16
        assert_eq!(&d[..n], &[10, 11, 13, 16]);
    }

    #[test]
    fn negative_add_and_flush() {
        let sched = StepSchedule::new();
        let mut src = StepSource::new();
        sched
            .push(seg(100 * ONE, -(ONE as i64), 0, 50, true))
            .unwrap();
        assert_eq!(src.advance(&sched).map(|s| s.delay_ticks), Some(100));
        assert_eq!(src.advance(&sched).map(|s| s.delay_ticks), Some(99));
        assert!(sched.is_running());
        sched.request_flush();
        // the step announced before the flush was made: counted, then stop.
        assert_eq!(src.advance(&sched), None);
        assert_eq!(sched.position(), 2);
        assert!(!sched.flush_pending());
        assert!(!sched.is_running());
        assert!(sched.is_empty());
    }

    /// Steps until the source stops, each checked for its delay and
    /// direction.
    fn run_out(src: &mut StepSource, sched: &StepSchedule, delay: u32, forward: bool) -> i32 {
        let mut n = 0;
        while let Some(s) = src.advance(sched) {
            assert_eq!((s.delay_ticks, s.forward), (delay, forward), "step {n}");
            n += 1;
        }
        n
    }

    #[test]
    fn ring_full_refuses_and_wraps() {
        let sched = StepSchedule::new();
        let mut src = StepSource::new();
        let steps = |count: usize, forward: bool| seg(ONE, 0, 0, count as u32, forward);
        let one = steps(1, true);
        assert_eq!(sched.free(), SCHEDULE_STEPS - 3);
        assert!(sched.push(steps(0, true)).is_err());
        // all or nothing: one step more than the room is refused whole
        let big = steps(SCHEDULE_STEPS - 1, true);
        assert_eq!(sched.push(big), Err(big));
        assert!(sched.is_empty());
        // the same direction needs no marker: the whole room, then full
        sched.push(steps(SCHEDULE_STEPS - 2, true)).unwrap();
        assert_eq!((sched.free(), sched.push(one)), (0, Err(one)));
        // the start frees the slot kept while idle, each step made one
        // more; the pending step's slot is never written
        for made in 0..2 {
            assert_eq!(src.advance(&sched).map(|s| s.delay_ticks), Some(1));
            assert_eq!(sched.position(), made);
            sched.push(one).unwrap();
            assert_eq!((sched.free(), sched.push(one)), (0, Err(one)));
        }
        assert_eq!(
            run_out(&mut src, &sched, 1, true),
            SCHEDULE_STEPS as i32 - 2
        );
        assert_eq!(sched.position(), SCHEDULE_STEPS as i32);
        // round and round the ring (40 × 200..435 entries), each round turning
        // round (one marker), refilled while running
        let mut expect = sched.position();
        let mut forward = true;
        for round in 0..40 {
            forward = !forward;
            let count = 100 + 3 * round;
            sched.push(steps(count, forward)).unwrap();
            assert_eq!(src.advance(&sched).map(|s| s.forward), Some(forward));
            sched.push(steps(count, forward)).unwrap();
            let made = 1 + run_out(&mut src, &sched, 1, forward);
            assert_eq!(made, 2 * count as i32);
            expect += if forward { made } else { -made };
            assert_eq!(sched.position(), expect);
            assert!(sched.is_empty() && !sched.is_running());
        }
    }

    /// A flush that drops a queued direction marker leaves the interrupt
    /// in the last push's direction: the next push (which needs no marker)
    /// goes the right way.
    #[test]
    fn a_dropped_marker_does_not_lose_the_direction() {
        let sched = StepSchedule::new();
        let mut src = StepSource::new();
        sched.push(seg(10 * ONE, 0, 0, 3, true)).unwrap();
        sched.push(seg(10 * ONE, 0, 0, 3, false)).unwrap();
        assert!(src.advance(&sched).unwrap().forward);
        sched.request_flush();
        assert_eq!(src.advance(&sched), None);
        assert_eq!(sched.position(), 1);
        sched.push(seg(10 * ONE, 0, 0, 2, false)).unwrap();
        assert_eq!(run_out(&mut src, &sched, 10, false), 2);
        assert_eq!(sched.position(), -1);
    }

    /// A cut (planner.rs `drop_pending`): the entries from the cut on are
    /// taken back, the next push continues there with the fraction carried
    /// to the cut, and `advance_until` finds the same steps and time as
    /// the push made; a cut behind the interrupt's next read, or outside
    /// the queue, changes nothing.
    #[test]
    fn truncate_takes_back_the_entries_ahead_of_the_interrupt() {
        let sched = StepSchedule::new();
        let mut src = StepSource::new();
        // 7.25 ticks growing by a quarter: delays with carried fractions
        let whole = seg(7 * ONE + ONE / 4, (ONE / 4) as i64, 0, 10, true);
        let (mut rest, frac0) = (whole, sched.carry_in());
        let pushed = sched.push_steps(&mut rest, 10).unwrap();
        let first = sched.last_pushed_index().wrapping_sub(9);
        // the time of all ten, found again without the ring
        let (mut again, mut frac) = (whole, frac0);
        assert_eq!(
            again.advance_until(&mut frac, u64::MAX >> 1, 10),
            (10, pushed)
        );
        // the interrupt makes three steps
        let made: Vec<u32> = (0..3)
            .map(|_| src.advance(&sched).unwrap().delay_ticks)
            .collect();
        // behind its next read (the pending step's entry), or at the
        // sentinel, or past it: refused
        assert!(!sched.truncate(first.wrapping_add(1), 0));
        assert!(!sched.truncate(first.wrapping_add(10), 0));
        assert!(!sched.truncate(first.wrapping_add(12), 0));
        // cut after six steps: the time of the sixth is where they end
        let (mut cut, mut frac) = (whole, frac0);
        let until = 6 * 7 * ONE + 15 * (ONE / 4) - 1; // just before the sixth
        let (steps, time) = cut.advance_until(&mut frac, until, 10);
        assert_eq!(steps, 6);
        assert_eq!(cut.count, 4);
        assert_eq!(cut.interval, whole.interval + 6 * (ONE / 4));
        assert!(sched.truncate(first.wrapping_add(6), frac));
        assert_eq!(sched.last_pushed_index(), first.wrapping_add(5));
        // a new push follows the sixth step, carrying its fraction
        sched.push(seg(3 * ONE, 0, 0, 2, true)).unwrap();
        let (d, n) = drain(&mut src, &sched);
        let mut all = made.clone();
        all.extend_from_slice(&d[..n]);
        assert_eq!(all.len(), 6 + 2);
        assert_eq!(
            all[..6].iter().map(|&d| u64::from(d)).sum::<u64>(),
            time >> 32
        );
        assert_eq!(&all[6..], &[3, 3]);
        assert_eq!(sched.position(), 8);
        assert!(sched.is_empty());
    }

    /// Delays from 2^31 ticks on share their top bit with the markers: they
    /// go the slow way and still come out whole; an interval below half a
    /// tick is a delay of 1, never the sentinel (0).
    #[test]
    fn long_and_zero_delays() {
        let sched = StepSchedule::new();
        let mut src = StepSource::new();
        sched.push(seg(3_000_000_000 * ONE, 0, 0, 3, true)).unwrap();
        sched.push(seg(ONE / 4, 0, 0, 2, true)).unwrap();
        sched.push(seg(7 * ONE, 0, 0, 1, true)).unwrap();
        let (d, n) = drain(&mut src, &sched);
        let long = 3_000_000_000;
        assert_eq!(&d[..n], &[long, long, long, 1, 1, 7]);
        assert_eq!(sched.position(), 6);
    }

    /// The exact time of each step is its tick plus the rounding its
    /// delay carried, within ±½ tick.
    #[cfg(feature = "sim")]
    #[test]
    fn rounding_gives_the_exact_times() {
        let sched = StepSchedule::new();
        let mut src = StepSource::new();
        // 5.5, then 5.5 + 1/3 per step, ticks
        let third = (ONE / 3) as i64;
        sched.push(seg(ONE * 11 / 2, third, 0, 6, true)).unwrap();
        let (mut tick, mut exact) = (0u64, 0u64);
        let mut interval = ONE * 11 / 2;
        while let Some(s) = src.advance(&sched) {
            tick += u64::from(s.delay_ticks);
            exact += interval;
            interval += third as u64;
            let r = src.rounding_q32(&sched);
            assert!(r.abs() <= 1 << 31, "{r}");
            assert_eq!((tick << 32).wrapping_add(r as u64), exact);
        }
        assert_eq!(tick, 6 * 11 / 2 + 5); // 33 + 15 × ⅓ = 38
    }

    #[test]
    fn cancel_forgets_the_announced_step() {
        let sched = StepSchedule::new();
        let mut src = StepSource::new();
        sched.push(seg(ONE, 0, 0, 5, false)).unwrap();
        src.advance(&sched);
        src.advance(&sched);
        src.cancel(&sched);
        assert_eq!(sched.position(), -1);
        assert_eq!(src.advance(&sched), None);
        assert_eq!(sched.position(), -1);
    }

    // ---- limit brake (SPEC §8.7, issue 6) ----

    const HZ: u32 = 10_000_000;

    /// A long run at `interval` ticks per step in one direction.
    fn cruise(sched: &StepSchedule, interval: u64, forward: bool) {
        let count = sched.free() as u32;
        sched
            .push(seg(interval * ONE, 0, 0, count, forward))
            .unwrap();
    }

    #[test]
    fn brake_rate_encodes_the_deceleration() {
        for (decel, hz) in [
            (1u64, 1_000_000u32),
            (20, HZ),
            (10_000_000, HZ),
            (20_000_000, 8_000_000),
        ] {
            let r = brake_rate(decel, hz);
            let (m, s) = (f64::from(r & RATE_MANTISSA), r >> RATE_MANTISSA_BITS);
            let a = m / 2f64.powi(s as i32);
            let exact = decel as f64 / 10.0 / f64::from(hz).powi(2);
            assert!(
                (a / exact - 1.0).abs() < 1.0 / f64::from(1u32 << 22),
                "{decel} {hz}: {a} vs {exact}"
            );
            assert!(m >= f64::from(1u32 << 23));
        }
        assert_eq!(
            brake_rate(0, HZ),
            RATE_AT_ONCE,
            "0x6085 = 0: at once (§8.3)"
        );
    }

    /// Steps of the limit brake from `v0` steps/s with `a` steps/s²: their
    /// intervals follow v² = v0² - 2an, and the motor stops within the
    /// quick stop distance v0²/2a (SPEC §8.7: stop with 0x6085).
    #[test]
    fn limit_brake_decelerates_at_the_quick_stop_rate() {
        for (v0, a) in [
            (50_000.0f64, 1.0e6f64),
            (2_000.0, 20_000.0),
            (200_000.0, 2.0e6),
        ] {
            let sched = StepSchedule::new();
            let mut src = StepSource::new();
            sched.set_brake_rate(Some(brake_rate((a * 10.0) as u64, HZ)));
            let p0 = (f64::from(HZ) / v0) as u64;
            cruise(&sched, p0, true);
            for _ in 0..10 {
                assert_eq!(src.advance(&sched).unwrap().delay_ticks as u64, p0);
            }
            sched.set_limits(false, true); // the CCW limit: forward blocked
            let mut n = 0u32;
            let mut t = 0f64;
            while let Some(s) = src.advance(&sched) {
                assert!(s.forward);
                n += 1;
                t += f64::from(s.delay_ticks);
                let v2 = v0 * v0 - 2.0 * a * f64::from(n);
                let exact = f64::from(HZ) / v2.sqrt();
                let got = f64::from(s.delay_ticks);
                assert!(
                    (got - exact).abs() <= 1.0 + 0.02 * exact,
                    "v0 {v0}, a {a}: step {n}: {got} ticks, exact {exact}"
                );
                assert_eq!(
                    sched.limit_brake(),
                    Some(LimitBrake {
                        forward: true,
                        done: false
                    })
                );
                assert!(n < 1_000_000);
            }
            let dist = v0 * v0 / (2.0 * a);
            assert!(
                f64::from(n) <= dist && f64::from(n) + 3.0 >= dist,
                "v0 {v0}, a {a}: {n} braking steps, quick stop distance {dist}"
            );
            // time of a constant deceleration: v0/a (minus the last steps)
            let t_exact = v0 / a * f64::from(HZ);
            assert!(t <= t_exact * 1.01, "{t} ticks vs {t_exact}");
            assert_eq!(
                sched.limit_brake(),
                Some(LimitBrake {
                    forward: true,
                    done: true
                })
            );
            assert!(!sched.is_running() && sched.is_empty());
            assert_eq!(sched.position(), 10 + n as i32);
        }
    }

    #[test]
    fn limit_brake_only_towards_the_active_limit_and_only_when_armed() {
        let sched = StepSchedule::new();
        let mut src = StepSource::new();
        cruise(&sched, 2000, false);
        src.advance(&sched);
        // armed, but the CCW limit blocks the other direction
        sched.set_brake_rate(Some(brake_rate(10_000_000, HZ)));
        sched.set_limits(false, true);
        assert_eq!(src.advance(&sched).map(|s| s.delay_ticks), Some(2000));
        assert_eq!(sched.limit_brake(), None);
        // disarmed (homing, §8.6): the CW limit is passed on to the planner
        sched.set_brake_rate(None);
        sched.set_limits(true, false);
        assert_eq!(src.advance(&sched).map(|s| s.delay_ticks), Some(2000));
        assert_eq!(sched.limit_brake(), None);
        // armed: brakes (the interval grows)
        sched.set_brake_rate(Some(brake_rate(10_000_000, HZ)));
        assert!(src.advance(&sched).unwrap().delay_ticks > 2000);
        assert_eq!(
            sched.limit_brake(),
            Some(LimitBrake {
                forward: false,
                done: false
            })
        );
    }

    #[test]
    fn limit_brake_latches_until_released_and_defers_a_flush() {
        let sched = StepSchedule::new();
        let mut src = StepSource::new();
        sched.set_brake_rate(Some(brake_rate(10_000_000, HZ)));
        cruise(&sched, 200, true);
        src.advance(&sched);
        sched.set_limits(false, true);
        src.advance(&sched);
        // a flush while braking waits for the end of the brake
        sched.request_flush();
        assert!(src.advance(&sched).is_some());
        while src.advance(&sched).is_some() {}
        assert!(!sched.flush_pending());
        // segments pushed before thread mode noticed are dropped, also
        // away from the limit, until the planner releases the brake
        sched.set_limits(false, false);
        cruise(&sched, 200, false);
        assert_eq!(src.advance(&sched), None);
        assert!(sched.is_empty());
        sched.release_brake();
        assert_eq!(sched.limit_brake(), None);
        cruise(&sched, 200, false);
        assert_eq!(src.advance(&sched).map(|s| s.delay_ticks), Some(200));
    }

    #[test]
    fn limit_at_once_and_from_rest_make_no_step() {
        let sched = StepSchedule::new();
        let mut src = StepSource::new();
        sched.set_brake_rate(Some(brake_rate(0, HZ)));
        sched.set_limits(true, false);
        cruise(&sched, 200, false);
        assert_eq!(src.advance(&sched), None, "0x6085 = 0: no further step");
        assert_eq!(
            sched.limit_brake(),
            Some(LimitBrake {
                forward: false,
                done: true
            })
        );
        sched.release_brake();
        // from rest towards an active limit, at an ordinary deceleration:
        // the first interval from rest is already within two steps of rest
        sched.set_brake_rate(Some(brake_rate(10_000_000, HZ)));
        sched.push(seg(14_142 * ONE, 0, 0, 10, false)).unwrap(); // √(2/a) s
        assert_eq!(src.advance(&sched), None);
        assert_eq!(sched.position(), 0);
    }
}
