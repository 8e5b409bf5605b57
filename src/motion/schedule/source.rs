//! The step interrupt's side of the schedule: one delay per step, the
//! slow path and the limit brake's steps (module docs of the schedule).

use core::sync::atomic::{compiler_fence, AtomicU32, Ordering};

use super::brake::{
    brake_q, grown, BLOCK_BACKWARD, BLOCK_FORWARD, BRAKE_ACTIVE, BRAKE_DONE, BRAKE_FORWARD,
};
use super::ring::StepSchedule;
use super::segment::carried;
use super::{dir, END, HALF_TICK, MARK_BACKWARD, MARK_FORWARD, SCHEDULE_STEPS, TICK_FRAC_BITS};

/// What the timer must do next: wait `delay_ticks` (≥ 1) after the step
/// just made (or after the start), then pulse STEP with DIR = `forward`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct NextStep {
    delay_ticks: u32,
    forward: bool,
}

impl NextStep {
    #[inline]
    pub const fn delay_ticks(&self) -> u32 {
        self.delay_ticks
    }

    #[inline]
    pub const fn forward(&self) -> bool {
        self.forward
    }
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
    /// Braking steps left in the current stride, and what each adds to
    /// the interval ([`StepSource::brake_next`]).
    stride_left: u32,
    stride_add: u64,
    /// `interval` holds the start interval of the brake
    /// [`StepSource::limit_ahead`] announces, read ahead of it
    /// ([`StepSource::prepare_brake`]) for the entry at `next`; cleared by
    /// the slow path, which the brake's start always goes through.
    prepared: bool,
}

/// A fast brake goes in strides of this many steps (a power of two)...
const STRIDE_LOG: u32 = 4;
const STRIDE: u32 = 1 << STRIDE_LOG;
/// ...while a stride's `q` ([`brake_q`] times [`STRIDE`]) is at most 2^-9
/// (Q0.32): its last interval is exact, and the ones before it, on a
/// straight line, differ from the exact ones by a tiny fraction of an
/// interval, and their step-to-step change (the deceleration) by `3/2`
/// of the stride's `q` at most (the exact intervals' growth rises by a
/// factor `1 + 3q` a step).
const STRIDE_MAX_Q: u32 = 1 << (32 - 9 - STRIDE_LOG);
/// Delays the limit brake's first interval is the mean of (a power of
/// two): [`mean_ahead`].
const MEAN_WINDOW: u32 = 32;

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
            stride_left: 0,
            stride_add: 0,
            prepared: false,
        }
    }

    /// See the type docs. Constant time; the cost is in the module docs.
    #[inline]
    pub fn advance(&mut self, sched: &StepSchedule) -> Option<NextStep> {
        // The pending step has been made; the next entry is a plain delay
        // unless it is the sentinel, a marker or a long delay (≤ 0 as
        // i32), and nothing needs a look unless `quiet` is clear.
        match self.advance_plain(sched) {
            Some(delay_ticks) => Some(NextStep {
                delay_ticks,
                forward: self.forward,
            }),
            None => self.advance_slow(sched),
        }
    }

    /// [`StepSource::advance`]'s fast path on its own: when the next step
    /// is a plain delay in the pending step's direction with nothing to
    /// look at, that delay, the step taken; `None`, nothing done, for
    /// everything else (what `advance` hands its slow path). For a caller
    /// that knows the direction already (the step engine's cruise path).
    #[inline(always)]
    pub fn advance_plain(&mut self, sched: &StepSchedule) -> Option<u32> {
        let next = sched.next.load(Ordering::Relaxed);
        let delay = sched.entry(next).load(Ordering::Relaxed);
        if delay as i32 <= 0 || !sched.quiet.load(Ordering::Relaxed) {
            // braking keeps `quiet` clear: its steps come from here too
            return if self.braking != 0 {
                self.brake_plain(sched)
            } else {
                None
            };
        }
        sched.next.store(next.wrapping_add(1), Ordering::Relaxed);
        Some(delay)
    }

    /// The limit brake's next step while it goes on, made with nothing
    /// else to look at (the brake does not look at the flags): the pending
    /// step counted by one store of the base's position (brake steps are
    /// no ring entries, and the base's index stays where the brake began).
    /// `None`, nothing done, where the brake ends: the slow path ends it.
    #[inline(never)]
    fn brake_plain(&mut self, sched: &StepSchedule) -> Option<u32> {
        let p = self.brake_next()?;
        sched.move_base(dir(self.forward));
        Some(carried(&mut self.frac, p).max(1))
    }

    /// The limit brake's next interval, now its last, or `None` (nothing
    /// changed) where it ends. Each step is `v² ← v² - 2a` from the last
    /// ([`brake_q`], [`grown`]); while the motor is fast that changes each
    /// interval by little, and the brake goes in strides of [`STRIDE`]
    /// steps: the stride's last interval from the series at once (`q`
    /// times the stride), the ones before it on the straight line there,
    /// an addition each. Where the stride ends is thus the exact
    /// deceleration's, and the brake costs a series per stride, not per
    /// step, at the speeds where steps are shortest.
    #[inline(always)]
    fn brake_next(&mut self) -> Option<u64> {
        let p = if self.stride_left != 0 {
            self.stride_left -= 1;
            self.interval + self.stride_add
        } else {
            let q = brake_q(self.interval, self.braking)?;
            if q <= STRIDE_MAX_Q {
                let end = grown(self.interval, q << STRIDE_LOG);
                self.stride_add = (end - self.interval) >> STRIDE_LOG;
                self.stride_left = STRIDE - 1;
                self.interval + self.stride_add
            } else {
                grown(self.interval, q)
            }
        };
        self.interval = p;
        Some(p)
    }

    /// Up to `max()` more steps of [`StepSource::advance_plain`] whose
    /// delay is `delay`, taken at once: the steps taken. `delay` is one
    /// `advance_plain` has just given (a plain delay); `max` is asked only
    /// if the next step is one. A constant speed is a run of equal delays,
    /// which the step engine repeats in one timer entry; this takes them
    /// with one store of `next` and one look at `quiet` for the run
    /// (nothing that could raise attention runs while the consumer does):
    /// the ones the producer noted as a run ([`StepSchedule::run_ahead`])
    /// at once, any after them at a compare each.
    #[inline(always)]
    pub fn advance_run(
        &mut self,
        sched: &StepSchedule,
        delay: u32,
        max: impl FnOnce() -> u32,
    ) -> u32 {
        let start = sched.next.load(Ordering::Relaxed);
        if sched.entry(start).load(Ordering::Relaxed) != delay
            || !sched.quiet.load(Ordering::Relaxed)
        {
            return 0;
        }
        // up to the ring's end at most (a run across it becomes two
        // entries, once a ring round): the scan stays one contiguous loop
        let i = start as usize % SCHEDULE_STEPS;
        let max = (max() as usize).min(SCHEDULE_STEPS - i);
        let known = sched.run_ahead(start, delay).min(max);
        let taken = known + alike(&sched.ring()[i + known..i + max], delay);
        sched
            .next
            .store(start.wrapping_add(taken as u32), Ordering::Relaxed);
        taken as u32
    }

    /// Up to `runs` runs of `per()` entries each, from the next entry on,
    /// that the producer's noted run says hold `delay`
    /// ([`Self::advance_run`] without the compares): taken at once (up to
    /// the ring's end at most); how many runs. `per` is called only once
    /// the next entry is in such a run.
    #[inline(always)]
    pub fn advance_whole_runs(
        &mut self,
        sched: &StepSchedule,
        delay: u32,
        per: &mut dyn FnMut() -> u32,
        runs: u32,
    ) -> u32 {
        let start = sched.next.load(Ordering::Relaxed);
        let known = sched.run_ahead(start, delay);
        if known == 0 || !sched.quiet.load(Ordering::Relaxed) {
            return 0;
        }
        let per = per().max(1);
        let i = start as usize % SCHEDULE_STEPS;
        let known = known.min(SCHEDULE_STEPS - i) as u32;
        let taken = (known / per).min(runs);
        sched
            .next
            .store(start.wrapping_add(taken * per), Ordering::Relaxed);
        taken
    }

    /// The pending step runs into an active limit that brakes (0x6085 set)
    /// and the brake has not started: the next `advance` starts it. The
    /// step engine, which is handed steps ahead of its timer, then takes
    /// back the ones it has not made yet ([`StepSource::take_back`]).
    pub fn limit_ahead(&self, sched: &StepSchedule) -> bool {
        let block = if self.forward {
            BLOCK_FORWARD
        } else {
            BLOCK_BACKWARD
        };
        self.pending
            && self.braking == 0
            && sched.limits.load(Ordering::Relaxed) & block != 0
            && sched.brake_rate.load(Ordering::Relaxed) != 0
    }

    /// If [`StepSource::limit_ahead`], reads the brake's start speed now,
    /// for the `advance` that starts it: a step engine calls it where it
    /// learns of the limit, so that the refill that starts the brake,
    /// whose deadline is the steps already handed to the timer, does not
    /// read the delays ahead as well. That `advance` is the next one and
    /// takes the slow path (the limits or the brake rate raised attention
    /// when they were set, and no slow path has run since, or the brake
    /// would have started); it takes what was read if the brake starts at
    /// that entry (always, unless a marker comes first), and forgets it
    /// otherwise.
    pub fn prepare_brake(&mut self, sched: &StepSchedule) {
        if !self.limit_ahead(sched) {
            return;
        }
        let at = sched.next.load(Ordering::Relaxed);
        let delay = sched.entry(at).load(Ordering::Relaxed);
        if delay as i32 > 0 {
            self.interval = mean_ahead(sched, at, delay);
            self.prepared = true;
        }
    }

    /// `steps` steps given before the pending one, in its direction, are
    /// not made after all: the position goes back by them. What they were
    /// part of is dropped by the limit brake that follows
    /// ([`StepSource::limit_ahead`]), so nothing gives them again.
    pub fn take_back(&mut self, sched: &StepSchedule, steps: u32) {
        let next = sched.next.load(Ordering::Relaxed);
        let back = dir(self.forward).wrapping_mul(steps as i32);
        sched.set_base(
            sched.base_position(next).wrapping_sub(back),
            next,
            self.forward,
        );
    }

    /// Everything but the next plain delay: starts from rest, the end of
    /// the queue, markers, long delays, flush, limits, the brake. Constant
    /// time too (at most one marker before a step, module docs).
    /// `next` is the entry the fast path looked at; every way out of here
    /// stores it again ([`StepSchedule::set_base`]).
    #[inline(never)]
    fn advance_slow(&mut self, sched: &StepSchedule) -> Option<NextStep> {
        let prepared = core::mem::take(&mut self.prepared);
        let next = sched.next.load(Ordering::Relaxed);
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
                // from the interval of the step it would have made (its
                // exact one, which the rounded delays ahead tell), timed
                // from the tick of the one just made
                if !(prepared && at == next) {
                    self.interval = mean_ahead(sched, at, delay);
                }
                self.frac = HALF_TICK;
                self.stride_left = 0;
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
        match self.brake_next() {
            Some(p) => {
                let delay = carried(&mut self.frac, p);
                self.pending = true;
                sched.running.store(true, Ordering::Relaxed);
                // the braking steps after it go the brake's own way
                // (`brake_plain`), not the ring's
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

    /// While the limit brake runs, the fraction its pending step's time
    /// carries on (Q0.32, as a push's, [`super::PushedSteps::fractions`]):
    /// braking steps are no ring entries, so no push reported them.
    pub fn braking_frac(&self) -> Option<u32> {
        (self.braking != 0).then_some(self.frac)
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

/// The exact interval of the step at `at`, whose delay is `delay`, as
/// the delays from there on tell it (Q32.32 ticks): the mean of the
/// [`MEAN_WINDOW`] delays from `at` if they keep to two neighbouring
/// whole ticks, as a constant speed's do whatever its fraction of a tick,
/// else `delay` itself (the window reaches the sentinel, a marker, or a
/// speed that changes by more than a tick across it, where the mean would
/// be that of the steps ahead and lead the speed by more than one delay's
/// rounding; or a delay the brake does not slow, 2^24 ticks). Each delay
/// rounds its step's exact time with the fraction carried (module docs),
/// so their sum is within a tick of their exact span and their mean
/// within `1 / MEAN_WINDOW` tick of their exact mean interval, where the
/// one delay is off by up to half a tick: at the highest step rates, a
/// few hundred ticks a step, enough to put the brake's start speed, and
/// its distance twice as much, visibly off. A fixed window, read whole
/// without a branch an entry, and a shift for the mean: this runs once a
/// brake, in the step interrupt, where the time before the brake's first
/// steps are due is a few steps at the top rates. Thread mode never
/// writes the entries between `at` and the sentinel (`ring[head]`,
/// always `END`); a window that reaches past them holds the sentinel, 0,
/// and takes `delay`.
fn mean_ahead(sched: &StepSchedule, at: u32, delay: u32) -> u64 {
    const SHIFT: u32 = TICK_FRAC_BITS - MEAN_WINDOW.ilog2();
    // the window as the ring's slices up to its end and from its start:
    // no index arithmetic an entry
    let (i, n) = (at as usize % SCHEDULE_STEPS, MEAN_WINDOW as usize);
    let ring = sched.ring();
    let head = &ring[i..SCHEDULE_STEPS.min(i + n)];
    let (s0, lo0, hi0) = sum_min_max(head);
    let (s1, lo1, hi1) = sum_min_max(&ring[..n - head.len()]);
    let (sum, lo, hi) = (s0.wrapping_add(s1), lo0.min(lo1), hi0.max(hi1));
    // one shift for both outcomes: two would be merged into a shift by a
    // variable, a library call on these cores
    let total = if lo == 0 || hi - lo > 1 || hi >= 1 << 24 {
        u64::from(delay) * u64::from(MEAN_WINDOW)
    } else {
        u64::from(sum)
    };
    total << SHIFT
}

/// The wrapping sum, the least and the greatest of `entries`: one plain
/// loop, its state in registers (a chained iterator, or a closure over
/// the sums, kept it in memory).
fn sum_min_max(entries: &[AtomicU32]) -> (u32, u32, u32) {
    let (mut sum, mut lo, mut hi) = (0u32, u32::MAX, 0u32);
    for e in entries {
        let d = e.load(Ordering::Relaxed);
        sum = sum.wrapping_add(d);
        (lo, hi) = (lo.min(d), hi.max(d));
    }
    (sum, lo, hi)
}

const _: () = assert!(MEAN_WINDOW.is_power_of_two() && MEAN_WINDOW < (SCHEDULE_STEPS as u32) / 2);

/// How many of `entries`, from the first, hold `delay`: four compares to
/// a loop round (written out: the images' size-optimised builds do not
/// unroll), the constant-speed step's whole cost in a run.
#[inline(always)]
fn alike(entries: &[AtomicU32], delay: u32) -> usize {
    let mut rest = entries;
    while let [a, b, c, d, tail @ ..] = rest {
        if a.load(Ordering::Relaxed) != delay {
            break;
        }
        if b.load(Ordering::Relaxed) != delay {
            rest = &rest[1..];
            break;
        }
        if c.load(Ordering::Relaxed) != delay {
            rest = &rest[2..];
            break;
        }
        if d.load(Ordering::Relaxed) != delay {
            rest = &rest[3..];
            break;
        }
        rest = tail;
    }
    while let [a, tail @ ..] = rest {
        if a.load(Ordering::Relaxed) != delay {
            break;
        }
        rest = tail;
    }
    entries.len() - rest.len()
}
