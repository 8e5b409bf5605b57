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
//! read-modify-write; none is used), the publishing store is `Release`.
//!
//! # Worst-case interrupt cost
//!
//! [`StepSource::advance`] per step: count the step (add, store), check the
//! flush flag (load, branch), decrement the segment's remaining count, three
//! 64-bit adds (time += interval, interval += add, add += add2) and one
//! subtraction of the integer parts — about 20 instructions plus field
//! loads/stores on a Cortex-M4. When a segment ends it also loads head/tail,
//! seven words of the slot and stores the tail (about 20 more). No division,
//! no multiplication, no loop. Segments hold at least one step, so the extra
//! work happens at most once per step.

use core::sync::atomic::{AtomicBool, AtomicI32, AtomicU32, Ordering};

/// Segments the ring holds (a power of two). At the maximum step rate and
/// the shortest segments the planner emits this covers its horizon.
pub const SCHEDULE_SLOTS: usize = 64;

/// Fractional bits of schedule times: Q32.32 ticks.
pub const TICK_FRAC_BITS: u32 = 32;

/// Largest `count` of one segment.
pub const MAX_SEGMENT_STEPS: u32 = 0x7FFF_FFFF;

const FORWARD_BIT: u32 = 0x8000_0000;

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
    /// Steps, 1..=[`MAX_SEGMENT_STEPS`].
    pub count: u32,
    /// Positive direction (position counts up).
    pub forward: bool,
}

struct Slot {
    words: [AtomicU32; 7],
}

impl Slot {
    const fn new() -> Self {
        Self {
            words: [const { AtomicU32::new(0) }; 7],
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
    /// Raw step counter, written by the consumer only (wrapping).
    position: AtomicI32,
    /// Set by thread mode: drop everything at the next step.
    flush: AtomicBool,
    /// The consumer has a step pending (steps are being generated).
    running: AtomicBool,
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
            position: AtomicI32::new(0),
            flush: AtomicBool::new(false),
            running: AtomicBool::new(false),
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
        self.flush.store(true, Ordering::Release);
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

    // ---- either side ----

    /// Raw step count: steps made forward minus steps made backward.
    pub fn position(&self) -> i32 {
        self.position.load(Ordering::Acquire)
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
#[derive(Clone, Debug, Default)]
pub struct StepSource {
    /// Time of the pending step, Q32.32 ticks, wrapping.
    time: u64,
    /// Interval to the step after the pending one, Q32.32.
    interval: u64,
    add: u64,
    add2: u64,
    /// Steps of the current segment not yet scheduled.
    remaining: u32,
    forward: bool,
    /// A step has been announced and not yet counted.
    pending: bool,
    position: i32,
}

impl StepSource {
    pub const fn new() -> Self {
        Self {
            time: 0,
            interval: 0,
            add: 0,
            add2: 0,
            remaining: 0,
            forward: true,
            pending: false,
            position: 0,
        }
    }

    /// See the type docs. Constant time; the cost is in the module docs.
    #[inline]
    pub fn advance(&mut self, sched: &StepSchedule) -> Option<NextStep> {
        if self.pending {
            self.position = self
                .position
                .wrapping_add(if self.forward { 1 } else { -1 });
            sched.position.store(self.position, Ordering::Release);
        } else {
            // Starting from rest: put the time origin half a tick in so that
            // the integer delays round every exact time to the nearest tick.
            self.time = 1 << (TICK_FRAC_BITS - 1);
        }
        if sched.flush.load(Ordering::Acquire) {
            self.drop_all(sched);
            return None;
        }
        if self.remaining == 0 && !self.load_segment(sched) {
            self.pending = false;
            sched.running.store(false, Ordering::Release);
            return None;
        }
        self.remaining -= 1;
        let before = self.time;
        self.time = before.wrapping_add(self.interval);
        self.interval = self.interval.wrapping_add(self.add);
        self.add = self.add.wrapping_add(self.add2);
        self.pending = true;
        let delay =
            ((self.time >> TICK_FRAC_BITS) as u32).wrapping_sub((before >> TICK_FRAC_BITS) as u32);
        Some(NextStep {
            delay_ticks: delay,
            forward: self.forward,
        })
    }

    /// The glue stopped the timer before the announced step was made (stop
    /// at once): forget it and drop the whole schedule. Call it in the
    /// interrupt's context (or with it masked).
    pub fn cancel(&mut self, sched: &StepSchedule) {
        self.drop_all(sched);
    }

    /// Exact time of the announced step (Q32.32 ticks since this run
    /// started at rest, wrapping): what the delays approximate to the
    /// nearest tick. For tests and traces; the interrupt does not need it.
    pub fn scheduled_time(&self) -> u64 {
        self.time.wrapping_sub(1 << (TICK_FRAC_BITS - 1))
    }

    /// Raw step count as the interrupt knows it.
    pub fn position(&self) -> i32 {
        self.position
    }

    fn load_segment(&mut self, sched: &StepSchedule) -> bool {
        let tail = sched.tail.load(Ordering::Relaxed);
        if sched.head.load(Ordering::Acquire) == tail {
            return false;
        }
        let w = &sched.slots[tail as usize % SCHEDULE_SLOTS].words;
        self.interval = u64::from(w[0].load(Ordering::Relaxed))
            | (u64::from(w[1].load(Ordering::Relaxed)) << 32);
        self.add = u64::from(w[2].load(Ordering::Relaxed))
            | (u64::from(w[3].load(Ordering::Relaxed)) << 32);
        self.add2 = u64::from(w[4].load(Ordering::Relaxed))
            | (u64::from(w[5].load(Ordering::Relaxed)) << 32);
        let count = w[6].load(Ordering::Relaxed);
        self.forward = count & FORWARD_BIT != 0;
        self.remaining = count & !FORWARD_BIT;
        sched.tail.store(tail.wrapping_add(1), Ordering::Release);
        sched.running.store(true, Ordering::Release);
        true
    }

    fn drop_all(&mut self, sched: &StepSchedule) {
        self.pending = false;
        self.remaining = 0;
        sched
            .tail
            .store(sched.head.load(Ordering::Acquire), Ordering::Release);
        sched.running.store(false, Ordering::Release);
        sched.flush.store(false, Ordering::Release);
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
}
