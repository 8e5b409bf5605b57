//! The step schedule between the planner (thread mode) and the step-timer
//! interrupt, and the interrupt side that consumes it ([`StepSource`]).
//!
//! A [`Segment`] is Klipper's `(interval, count, add)` with one more term:
//! `count` steps, the first `interval` after the previous step; after each
//! step the interval grows by `add` and `add` grows by `add2`. The intervals
//! are thus a quadratic in the step number, which lets the planner match the
//! exact first interval, last interval and total time of every segment, so
//! that the intervals are continuous from one segment to the next (the
//! acceleration the motor sees has no jumps). Times are timer ticks in Q32.32 fixed point,
//! so the interrupt accumulates exact fractional times and only rounds when it
//! hands a delay to the timer: rounding never accumulates.
//!
//! # Sharing between thread mode and the interrupt
//!
//! [`StepSchedule`] is a lock-free single-producer / single-consumer ring of
//! segments built from atomics only (no `unsafe`, no critical section): the
//! planner pushes with `&StepSchedule`, the interrupt pops with the same
//! shared reference. The firmware keeps it in a `static`
//! (`static SCHEDULE: StepSchedule = StepSchedule::new();`), hands
//! `&SCHEDULE` to [`crate::Device::control`] in the control loop and owns a
//! [`StepSource`] inside the step-timer interrupt. Exactly one context may
//! push and exactly one may pop. Relaxed atomic loads and stores compile to
//! plain `ldr`/`str` on Cortex-M (also on M0, which has no atomic
//! read-modify-write; none is used); `Release`/`Acquire` (a `dmb`) appear
//! only where a segment is published or taken, never per step.
//!
//! Per step the interrupt stores one word, `left` (steps of the running
//! segment not yet made), with a Relaxed store: on a single core the
//! interrupt is never preempted by thread mode, so thread mode sees each
//! value whole and in order, and no barrier is needed for a single writer.
//! The position is not stored per step: [`StepSchedule::position`] derives
//! it from the running segment's end position and direction (written at a
//! segment start under a sequence count) and `left`. Thread mode and the
//! limit-switch interrupt never make the interrupt read their flags per
//! step either: they store the flag (flush, limits, brake rate), then raise
//! `attention`, the one byte the interrupt reads per step; it clears the
//! byte before it reads the flags, so no change is lost.
//!
//! # Worst-case interrupt cost
//!
//! [`StepSource::advance`] per step inside a segment (the fast path): load
//! `left` and `attention`, two compares, store `left - 1`; the delay is the
//! interval's integer part plus the carry of its fraction into the
//! pending time's fraction (`frac`), then `interval += add`,
//! `add += add2` — three 64-bit adds on one block of seven words. About 25
//! Cortex-M4 instructions (README "Drive behaviour" has the measured
//! figure). No division, no multiplication, no loop. The slow path (a
//! segment ends, a start from rest, a flag raised) loads head/tail and the
//! seven words of the next slot and publishes the new segment (about 60
//! more); segments hold at least one step, so it runs at most once per
//! step. A braking step (below) costs six 64×64 → 128-bit multiplies and a
//! variable shift, still no division and no loop.
//!
//! # Limit brake (SPEC §8.7, issue 6)
//!
//! A limit switch must stop motion towards it with the quick stop
//! deceleration 0x6085 *at once*: the planner only appends behind its
//! queued horizon, and the control loop runs every millisecond. So the
//! limit-switch interrupt (a third context) writes the logical limit states
//! with [`StepSchedule::set_limits`] (raising `attention`), and
//! [`StepSource::advance`], when its next step goes towards an active limit
//! while the brake is armed (checked when `attention` is raised and at every
//! segment start, the only places where either can change)
//! ([`StepSchedule::set_brake_rate`], written by the drive: 0x6085 outside
//! homing, disarmed in homing where the sequencer decides at the limits),
//! stops taking segments and decelerates on its own: each interval grows by
//! the factor `(1 - 2q)^-1/2 ≈ 1 + q + 3/2 q² + 5/2 q³ + 35/8 q⁴` with `q = a·p²`
//! (`p` the interval, `a` the deceleration in steps/tick²), which is
//! `v² ← v² - 2a` per step, the constant deceleration, in a few multiplies.
//! It stops when `q ≥ 1/4` (less than two steps from rest), drops the queue
//! and latches ([`LimitBrake::done`]): any segment pushed before the planner
//! noticed is dropped, until thread mode calls
//! [`StepSchedule::release_brake`] (the planner does, once it has taken the
//! position back: [`crate::motion::Planner::stop_at_once`]). A flush
//! requested while braking is carried out when the brake ends.

use core::sync::atomic::{fence, AtomicBool, AtomicI32, AtomicU32, AtomicU8, Ordering};

use super::profile::div;

/// Segments the ring holds (a power of two). At the maximum step rate and
/// the shortest segments the planner emits this covers its horizon.
pub const SCHEDULE_SLOTS: usize = 64;

/// Fractional bits of schedule times: Q32.32 ticks.
pub const TICK_FRAC_BITS: u32 = 32;

/// Largest `count` of one segment.
pub const MAX_SEGMENT_STEPS: u32 = 0x7FFF_FFFF;

const FORWARD_BIT: u32 = 0x8000_0000;

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
    let (lnum, lden) = (num.ilog2() as i32, den.ilog2() as i32);
    // num · 2^s / den lands in [2^22, 2^24) with this s, [2^23, 2^24) after
    // at most one doubling.
    let mut s = RATE_MANTISSA_BITS as i32 - 1 + lden - lnum;
    if s < 0 {
        return RATE_AT_ONCE; // more than 2^23 steps/tick²: no step fits
    }
    // profile::div: the 64-bit route, and one shared copy of the generic
    // u128 division instead of two inlined ones (1.6 KiB on a Cortex-M)
    let mut m = div(num << s, den);
    if m < 1 << (RATE_MANTISSA_BITS - 1) {
        s += 1;
        m = div(num << s, den);
    }
    if s > 111 {
        // below 2^-88 steps/tick²: slower than anything the planner runs
        return 1 | (111 << RATE_MANTISSA_BITS);
    }
    (m as u32 & RATE_MANTISSA) | ((s as u32) << RATE_MANTISSA_BITS)
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
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Segment {
    /// Ticks (Q32.32) from the previous step to the first step of this one.
    pub interval: u64,
    /// Ticks (Q32.32) added to the interval after every step.
    pub add: i64,
    /// Ticks (Q32.32) added to `add` after every step.
    pub add2: i64,
    /// Added to `add2` after every step, and `add4` to it: the intervals
    /// are a quartic in the step number.
    pub add3: i64,
    pub add4: i64,
    /// Steps, 1..=[`MAX_SEGMENT_STEPS`].
    pub count: u32,
    /// Positive direction (position counts up).
    pub forward: bool,
}

struct Slot {
    words: [AtomicU32; 11],
}

impl Slot {
    const fn new() -> Self {
        Self {
            words: [const { AtomicU32::new(0) }; 11],
        }
    }
}

/// The shared queue of segments plus what the interrupt reports back
/// (see the module docs for who may call what).
pub struct StepSchedule {
    slots: [Slot; SCHEDULE_SLOTS],
    /// Segments pushed (written by the producer only, wrapping).
    head: AtomicU32,
    /// Segments taken (written by the consumer only, wrapping).
    tail: AtomicU32,
    /// Steps of the running segment not yet made, the pending one
    /// included (the consumer's per-step counter, module docs).
    left: AtomicU32,
    /// Raw position once the running segment is made (consumer only).
    seg_end: AtomicI32,
    /// Direction of the running segment: +1 or -1 (consumer only).
    seg_dir: AtomicI32,
    /// Sequence count around changes of `seg_end` / `seg_dir` / `left`
    /// outside the per-step path (odd while they change).
    seq: AtomicU32,
    /// Set by whoever changes `flush`, `limits` or `brake_rate`; the
    /// consumer's only per-step look at them (module docs).
    attention: AtomicBool,
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
}

impl Default for StepSchedule {
    fn default() -> Self {
        Self::new()
    }
}

impl StepSchedule {
    pub const fn new() -> Self {
        Self {
            slots: [const { Slot::new() }; SCHEDULE_SLOTS],
            head: AtomicU32::new(0),
            tail: AtomicU32::new(0),
            left: AtomicU32::new(0),
            seg_end: AtomicI32::new(0),
            seg_dir: AtomicI32::new(1),
            seq: AtomicU32::new(0),
            attention: AtomicBool::new(false),
            flush: AtomicBool::new(false),
            running: AtomicBool::new(false),
            limits: AtomicU8::new(0),
            brake_rate: AtomicU32::new(0),
            brake: AtomicU8::new(BRAKE_NONE),
        }
    }

    // ---- producer side (thread mode) ----

    /// Free slots.
    pub fn free(&self) -> usize {
        let used = self
            .head
            .load(Ordering::Relaxed)
            .wrapping_sub(self.tail.load(Ordering::Acquire));
        SCHEDULE_SLOTS - used as usize
    }

    /// Appends a segment; gives it back when the ring is full.
    pub fn push(&self, seg: Segment) -> Result<(), Segment> {
        if self.free() == 0 || seg.count == 0 || seg.count > MAX_SEGMENT_STEPS {
            return Err(seg);
        }
        let head = self.head.load(Ordering::Relaxed);
        let w = &self.slots[head as usize % SCHEDULE_SLOTS].words;
        w[0].store(seg.interval as u32, Ordering::Relaxed);
        w[1].store((seg.interval >> 32) as u32, Ordering::Relaxed);
        w[2].store(seg.add as u32, Ordering::Relaxed);
        w[3].store((seg.add >> 32) as u32, Ordering::Relaxed);
        w[4].store(seg.add2 as u32, Ordering::Relaxed);
        w[5].store((seg.add2 >> 32) as u32, Ordering::Relaxed);
        w[7].store(seg.add3 as u32, Ordering::Relaxed);
        w[8].store((seg.add3 >> 32) as u32, Ordering::Relaxed);
        w[9].store(seg.add4 as u32, Ordering::Relaxed);
        w[10].store((seg.add4 >> 32) as u32, Ordering::Relaxed);
        let dir = if seg.forward { FORWARD_BIT } else { 0 };
        w[6].store(seg.count | dir, Ordering::Relaxed);
        self.head.store(head.wrapping_add(1), Ordering::Release);
        Ok(())
    }

    /// Segments pushed so far (wrapping); the slot of segment `n` is
    /// `n % SCHEDULE_SLOTS`.
    pub fn pushed(&self) -> u32 {
        self.head.load(Ordering::Relaxed)
    }

    /// Segments the interrupt has started (wrapping). The one it is
    /// executing is `taken() - 1` while [`StepSchedule::is_running`].
    pub fn taken(&self) -> u32 {
        self.tail.load(Ordering::Acquire)
    }

    /// Asks the consumer to drop the pending step and every queued segment
    /// ("stop step output at once", SPEC §8.1/§8.3).
    pub fn request_flush(&self) {
        self.flush.store(true, Ordering::Relaxed);
        self.raise_attention();
    }

    /// Tells the consumer to look at `flush`, `limits` and `brake_rate`
    /// at its next step: the flag after the value (module docs).
    fn raise_attention(&self) {
        self.attention.store(true, Ordering::Release);
    }

    /// A flush was requested and the consumer has not yet carried it out.
    pub fn flush_pending(&self) -> bool {
        self.flush.load(Ordering::Acquire)
    }

    /// Clears a flush request nobody will carry out because the interrupt
    /// is idle and the ring empty (the interrupt starts only on a non-empty
    /// ring, and only the producer fills it, so this cannot race).
    pub fn clear_flush_if_idle(&self) {
        if !self.is_running() && self.is_empty() {
            self.flush.store(false, Ordering::Release);
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
        let b = self.brake.load(Ordering::Acquire);
        (b != BRAKE_NONE).then_some(LimitBrake {
            forward: b & BRAKE_FORWARD != 0,
            done: b & BRAKE_DONE != 0,
        })
    }

    /// Lets the interrupt take segments again after a finished brake (the
    /// planner calls it once it has the position back). No effect while
    /// the brake is still running.
    pub fn release_brake(&self) {
        if self.brake.load(Ordering::Acquire) & BRAKE_DONE != 0 {
            self.brake.store(BRAKE_NONE, Ordering::Release);
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
    /// Derived from the running segment's end position and the steps of
    /// it not yet made (module docs: the interrupt stores no position per
    /// step). Call it from a context the interrupt may preempt, not from
    /// one that may preempt the interrupt.
    pub fn position(&self) -> i32 {
        loop {
            let seq = self.seq.load(Ordering::Acquire);
            let end = self.seg_end.load(Ordering::Relaxed);
            let dir = self.seg_dir.load(Ordering::Relaxed);
            let left = self.left.load(Ordering::Relaxed);
            fence(Ordering::Acquire);
            if seq & 1 == 0 && self.seq.load(Ordering::Relaxed) == seq {
                return end.wrapping_sub(dir.wrapping_mul(left as i32));
            }
        }
    }

    /// Steps are being generated (a step is scheduled on the timer).
    pub fn is_running(&self) -> bool {
        self.running.load(Ordering::Acquire)
    }

    /// No segment is queued (the running one, if any, has been taken).
    pub fn is_empty(&self) -> bool {
        self.head.load(Ordering::Acquire) == self.tail.load(Ordering::Acquire)
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
// repr(C): the per-step words in one block, so that the compiler can load
// and store them with few instructions (module docs: worst-case cost).
#[repr(C)]
#[derive(Clone, Debug, Default)]
pub struct StepSource {
    /// Fraction of the pending step's exact time plus half a tick, Q0.32:
    /// the delays round every exact time to the nearest tick and carry the
    /// rest, so rounding never accumulates.
    frac: u32,
    /// Interval to the step after the pending one, Q32.32 ticks, as
    /// (low, high) words; then `add` and `add2` the same way. Words, not
    /// u64: the seven are loaded and stored as one block.
    interval: [u32; 2],
    add: [u32; 2],
    add2: [u32; 2],
    add3: [u32; 2],
    add4: [u32; 2],
    forward: bool,
    /// A step has been announced and not yet made.
    pending: bool,
    /// The limit brake is running at this rate (0 = not braking).
    braking: u32,
}

fn join(w: [u32; 2]) -> u64 {
    u64::from(w[0]) | (u64::from(w[1]) << 32)
}

fn split(x: u64) -> [u32; 2] {
    [x as u32, (x >> 32) as u32]
}

impl StepSource {
    pub const fn new() -> Self {
        Self {
            frac: 0,
            interval: [0; 2],
            add: [0; 2],
            add2: [0; 2],
            add3: [0; 2],
            add4: [0; 2],
            forward: true,
            pending: false,
            braking: 0,
        }
    }

    /// See the type docs. Constant time; the cost is in the module docs.
    #[inline]
    pub fn advance(&mut self, sched: &StepSchedule) -> Option<NextStep> {
        // The pending step has been made: one fewer left in the segment.
        // Relaxed: one core, one writer; thread mode only reads it
        // (StepSchedule::position), so no barrier is needed per step.
        let (left, idle) = sched.left.load(Ordering::Relaxed).overflowing_sub(1);
        if sched.attention.load(Ordering::Relaxed) || idle || left == 0 {
            // the segment is done, the interrupt was idle, or a flag changed
            return self.advance_slow(sched);
        }
        sched.left.store(left, Ordering::Relaxed);
        Some(self.announce())
    }

    /// The next step of the current run: interval from the state, then the
    /// state one step on.
    #[inline(always)]
    fn announce(&mut self) -> NextStep {
        let [ilo, ihi] = self.interval;
        let (frac, carry) = self.frac.overflowing_add(ilo);
        let add = join(self.add);
        self.frac = frac;
        self.interval = split(join(self.interval).wrapping_add(add));
        self.add = split(add.wrapping_add(join(self.add2)));
        self.add2 = split(join(self.add2).wrapping_add(join(self.add3)));
        self.add3 = split(join(self.add3).wrapping_add(join(self.add4)));
        NextStep {
            delay_ticks: ihi.wrapping_add(u32::from(carry)),
            forward: self.forward,
        }
    }

    /// Everything but the next step of a running segment: segment ends,
    /// starts from rest, flush, limits, the brake. Constant time too.
    #[inline(never)]
    fn advance_slow(&mut self, sched: &StepSchedule) -> Option<NextStep> {
        let mut left = sched.left.load(Ordering::Relaxed);
        if self.pending {
            if self.braking != 0 {
                // brake steps belong to no segment: count them in seg_end
                let dir = sched.seg_dir.load(Ordering::Relaxed);
                let end = sched.seg_end.load(Ordering::Relaxed).wrapping_add(dir);
                sched.set_segment_state(end, dir, 0);
            } else {
                left = left.wrapping_sub(1);
                sched.left.store(left, Ordering::Relaxed);
            }
        } else {
            // Starting from rest: put the time origin half a tick in so
            // that the integer delays round every exact time to the nearest
            // tick.
            self.frac = 1 << (TICK_FRAC_BITS - 1);
        }
        if sched.attention.load(Ordering::Relaxed) {
            // Clear first, then read the flags: a change made after this
            // raises it again (the writers store the value, then the flag).
            sched.attention.store(false, Ordering::Relaxed);
            fence(Ordering::SeqCst);
        }
        if self.braking != 0 {
            return self.brake_step(sched, self.braking);
        }
        if sched.flush.load(Ordering::Acquire)
            || sched.brake.load(Ordering::Relaxed) & BRAKE_DONE != 0
        {
            self.drop_all(sched);
            return None;
        }
        if left == 0 && !self.load_segment(sched) {
            self.pending = false;
            sched.running.store(false, Ordering::Release);
            return None;
        }
        let block = if self.forward {
            BLOCK_FORWARD
        } else {
            BLOCK_BACKWARD
        };
        if sched.limits.load(Ordering::Acquire) & block != 0 {
            let rate = sched.brake_rate.load(Ordering::Relaxed);
            if rate != 0 {
                let dir = if self.forward { BRAKE_FORWARD } else { 0 };
                sched.brake.store(BRAKE_ACTIVE | dir, Ordering::Release);
                self.braking = rate;
                // the rest of the segment is not made: position = made
                sched.set_segment_state(sched.position(), Self::dir(self.forward), 0);
                return self.brake_step(sched, rate);
            }
        }
        self.pending = true;
        Some(self.announce())
    }

    fn dir(forward: bool) -> i32 {
        if forward {
            1
        } else {
            -1
        }
    }

    /// The step after the pending one `interval` (Q32.32) after it.
    fn announce_interval(&mut self, interval: u64) -> NextStep {
        self.interval = split(interval);
        self.add = [0; 2];
        self.add2 = [0; 2];
        self.add3 = [0; 2];
        self.add4 = [0; 2];
        self.pending = true;
        self.announce()
    }

    /// One step of the limit brake (module docs), or its end.
    fn brake_step(&mut self, sched: &StepSchedule, rate: u32) -> Option<NextStep> {
        match brake_interval(join(self.interval), rate) {
            Some(p) => Some(self.announce_interval(p)),
            None => {
                self.braking = 0;
                self.drop_all(sched);
                let dir = if self.forward { BRAKE_FORWARD } else { 0 };
                sched.brake.store(BRAKE_DONE | dir, Ordering::Release);
                None
            }
        }
    }

    /// The glue stopped the timer before the announced step was made (stop
    /// at once): forget it and drop the whole schedule. Call it in the
    /// interrupt's context (or with it masked).
    pub fn cancel(&mut self, sched: &StepSchedule) {
        if self.braking != 0 {
            // a brake cut short is still a brake: latch it for the planner
            let dir = if self.forward { BRAKE_FORWARD } else { 0 };
            sched.brake.store(BRAKE_DONE | dir, Ordering::Release);
            self.braking = 0;
        }
        self.drop_all(sched);
    }

    /// Exact time of the announced step minus the tick it is announced at
    /// (Q32.32, signed, within ±½ tick): the rounding the delays carry.
    /// For tests and traces; the interrupt does not need it.
    pub fn rounding_q32(&self) -> i64 {
        i64::from(self.frac) - (1 << (TICK_FRAC_BITS - 1))
    }

    fn load_segment(&mut self, sched: &StepSchedule) -> bool {
        let tail = sched.tail.load(Ordering::Relaxed);
        if sched.head.load(Ordering::Acquire) == tail {
            return false;
        }
        let w = &sched.slots[tail as usize % SCHEDULE_SLOTS].words;
        let word = |i: usize| w[i].load(Ordering::Relaxed);
        self.interval = [word(0), word(1)];
        self.add = [word(2), word(3)];
        self.add2 = [word(4), word(5)];
        self.add3 = [word(7), word(8)];
        self.add4 = [word(9), word(10)];
        let count = w[6].load(Ordering::Relaxed);
        self.forward = count & FORWARD_BIT != 0;
        let count = count & !FORWARD_BIT;
        let dir = Self::dir(self.forward);
        // the made position is the old segment's end (left == 0)
        let end = sched
            .seg_end
            .load(Ordering::Relaxed)
            .wrapping_add(dir.wrapping_mul(count as i32));
        sched.set_segment_state(end, dir, count);
        sched.tail.store(tail.wrapping_add(1), Ordering::Release);
        sched.running.store(true, Ordering::Release);
        true
    }

    fn drop_all(&mut self, sched: &StepSchedule) {
        self.pending = false;
        let made = sched.position();
        sched.set_segment_state(made, sched.seg_dir.load(Ordering::Relaxed), 0);
        sched
            .tail
            .store(sched.head.load(Ordering::Acquire), Ordering::Release);
        sched.running.store(false, Ordering::Release);
        sched.flush.store(false, Ordering::Release);
    }
}

impl StepSchedule {
    /// Consumer only: the running segment's end position, direction and
    /// steps left, under the sequence count that [`StepSchedule::position`]
    /// reads them with.
    fn set_segment_state(&self, end: i32, dir: i32, left: u32) {
        let seq = self.seq.load(Ordering::Relaxed);
        self.seq.store(seq.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        self.seg_end.store(end, Ordering::Relaxed);
        self.seg_dir.store(dir, Ordering::Relaxed);
        self.left.store(left, Ordering::Relaxed);
        self.seq.store(seq.wrapping_add(2), Ordering::Release);
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

    #[test]
    fn ring_full_refuses_and_wraps() {
        let sched = StepSchedule::new();
        let mut src = StepSource::new();
        let seg = seg(ONE, 0, 0, 1, true);
        for _ in 0..SCHEDULE_SLOTS {
            sched.push(seg).unwrap();
        }
        assert_eq!(sched.push(seg), Err(seg));
        assert!(sched.push(Segment { count: 0, ..seg }).is_err());
        for round in 0..3 {
            let (_, n) = drain(&mut src, &sched);
            assert_eq!(n, if round == 0 { SCHEDULE_SLOTS } else { 10 });
            for _ in 0..10 {
                sched.push(seg).unwrap();
            }
        }
        assert_eq!(sched.position(), SCHEDULE_SLOTS as i32 + 20);
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
        sched
            .push(seg(interval * ONE, 0, 0, 100_000, forward))
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
