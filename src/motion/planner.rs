//! The planner: goals in, schedule segments out (thread mode).
//!
//! It keeps the state at the *end* of what is already queued (position,
//! direction, v², exact time) and appends to the [`StepSchedule`] from there:
//! queued steps are never rewritten, so no step is ever scheduled in the
//! past, and a change of goal takes effect after the queued horizon
//! ([`PlannerConfig::horizon_us`]). Only "stop at once" discards the queue.
//!
//! Compression: each segment of `n` steps takes from the [`Profile`] the
//! exact times of its first, next-to-last and last step. Its intervals are
//! the quadratic in the step number (`interval`, `add`, `add2`) whose first
//! and last interval are the exact ones and whose total is the exact span.
//! So every segment starts and ends exactly on the profile, consecutive
//! segments join with continuous interval *and* continuous interval change
//! (the motor sees no acceleration jump at a junction), and inside a
//! segment the error is the fourth-order remainder, kept negligible by
//! [`Profile::segment_len`] (velocity change ≤ 2^-5 per segment). Times the
//! interrupt will accumulate are tracked exactly (`t_isr`), so nothing
//! drifts.
//!
//! Cost per segment: three profile evaluations (a square root and a
//! division each, on 128-bit numbers but through 64-bit routines:
//! `profile::isqrt`, `profile::div`) and a few multiplications; the fit
//! divides by `C(n,2)` and `C(n,3)` the same way; segments hold tens to thousands of
//! steps once the speed is above `sqrt(64·a)` steps/s (below that they are
//! single steps, at a step rate low enough not to matter).

use super::profile::{div, isqrt, slope_of, stop_steps, w_of, Profile, V_FRAC};
use super::schedule::{Segment, StepSchedule, SCHEDULE_STEPS, TICK_FRAC_BITS};

/// Highest step rate the drive generates, steps/s. Faster requests are
/// clamped (like PA12): 5 µs between steps leaves a 170 MHz Cortex-M4 850
/// cycles per step, of which the step interrupt uses about 50.
pub const MAX_STEP_RATE: u32 = 200_000;

/// Highest acceleration, steps/s². Above it the start of a ramp would need
/// more single-step segments than [`SCHEDULE_SLOTS`] to cover a 2 ms
/// control period; larger register values are clamped.
pub const MAX_ACCEL: u64 = 2_000_000;

/// Largest segment the planner emits (steps): half the step ring, so
/// that a segment always fits an emptied ring. [`Planner::fill`] also cuts
/// segments to the ring's free steps.
const MAX_PLANNED_SEGMENT: u64 = SCHEDULE_STEPS as u64 / 2;

/// Segments the planner keeps track of between the interrupt's step and
/// the end of the queue (a power of two): while they are all queued, the
/// schedule counts as full. At the maximum step rate and the shortest
/// segments the planner emits this covers its horizon.
pub const SCHEDULE_SLOTS: usize = 64;

/// Velocity / acceleration limits of one motion, in 0.1 steps/s and
/// 0.1 steps/s² (the registers' units times PA10).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Ramp {
    pub velocity: u64,
    pub accel: u64,
    pub decel: u64,
}

impl Ramp {
    /// All three are non-zero: the motion can run (SPEC §8.2 bit 7).
    pub fn runnable(&self) -> bool {
        self.velocity > 0 && self.accel > 0 && self.decel > 0
    }

    /// Clamped to the drive's limits and to `max_velocity` (0.1 steps/s).
    pub fn clamped(self, max_velocity: u64) -> Self {
        let v_cap = max_velocity.min(u64::from(MAX_STEP_RATE) * 10);
        let a_cap = MAX_ACCEL * 10;
        Self {
            velocity: self.velocity.min(v_cap),
            accel: self.accel.min(a_cap),
            decel: self.decel.min(a_cap),
        }
    }
}

/// What the planner is asked to do next.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Goal {
    /// Go to raw position `target` and arrive with velocity `end_velocity`
    /// (0.1 steps/s; non-zero only when a blended move follows).
    Move {
        target: i64,
        ramp: Ramp,
        end_velocity: u64,
    },
    /// Run for ever in one direction (velocity mode, homing searches).
    Run { forward: bool, ramp: Ramp },
    /// Decelerate to rest with `decel` (0.1 steps/s²), on a whole step.
    Stop { decel: u64 },
}

/// Result of [`Planner::fill`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Fill {
    /// The horizon is covered (or the ring is full).
    Full,
    /// The motion the last goal asked for has been planned to its end; the
    /// caller may give the next goal (seamlessly) and fill again.
    Ended,
    /// Nothing to plan.
    Idle,
    /// A stop-at-once is being carried out by the interrupt.
    Waiting,
}

/// Timing of the planner; the glue chooses the tick frequency.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PlannerConfig {
    /// Step timer frequency, Hz (≥ 1 MHz so that steps at the maximum rate
    /// are ≥ 5 ticks apart; sub-µs resolution keeps step times exact).
    pub tick_hz: u32,
    /// How far ahead of `now` the schedule is filled. Must exceed the
    /// control period; it is also the latency of a change of goal.
    pub horizon_us: u32,
    /// Longest segment, µs (bounds the horizon overshoot).
    pub max_segment_us: u32,
}

impl Default for PlannerConfig {
    fn default() -> Self {
        Self {
            tick_hz: 10_000_000,
            horizon_us: 3_000,
            max_segment_us: 2_000,
        }
    }
}

/// What the drive shows for the segment the interrupt is executing.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct SlotInfo {
    /// Ring index of the segment's last step ([`StepSchedule::step_index`]).
    last_index: u32,
    /// Signed velocity at the segment's end, 0.1 steps/s.
    velocity: i64,
    ramping: bool,
}

/// See the module docs.
#[derive(Clone, Debug)]
pub struct Planner {
    cfg: PlannerConfig,
    /// Raw position after the last queued step.
    pos: i64,
    /// Direction of the last motion.
    forward: bool,
    /// v² (fixed point) after the last queued step.
    w: u128,
    /// Exact time of the last queued step (Q32.32 ticks, wrapping).
    t_ideal: u64,
    /// The same time as the interrupt will have accumulated it.
    t_isr: u64,
    profile: Option<Profile>,
    /// Goal to resume after the current (stopping) profile.
    then: Option<Goal>,
    /// Fall slope of the current profile (for a stop nobody asked for).
    last_decel: u64,
    flushing: bool,
    /// Per pushed segment, by segment number modulo [`SCHEDULE_SLOTS`].
    slots: [SlotInfo; SCHEDULE_SLOTS],
    /// Segments pushed (wrapping).
    segments: u32,
    /// The oldest segment the interrupt may not have finished (wrapping;
    /// moved on in [`Planner::fill`]).
    oldest: u32,
    /// The schedule ran dry while the motor was moving.
    pub underruns: u32,
    /// Segments whose first step was already due when they were queued
    /// (the control loop ran late); never expected.
    pub late_segments: u32,
    /// `now` of the current fill (Q32.32 ticks).
    now: u64,
    /// Steps queued since start (wrapping; a stop at once drops some of
    /// them unmade): lets a test tell which profile timed a step.
    pub planned_steps: u64,
}

impl Planner {
    pub fn new(cfg: PlannerConfig) -> Self {
        Self {
            cfg,
            pos: 0,
            forward: true,
            w: 0,
            t_ideal: 0,
            t_isr: 0,
            profile: None,
            then: None,
            last_decel: 0,
            flushing: false,
            slots: [SlotInfo::default(); SCHEDULE_SLOTS],
            segments: 0,
            oldest: 0,
            underruns: 0,
            late_segments: 0,
            now: 0,
            planned_steps: 0,
        }
    }

    pub fn config(&self) -> PlannerConfig {
        self.cfg
    }

    /// Raw position after the last queued step.
    pub fn end_position(&self) -> i64 {
        self.pos
    }

    /// Velocity after the last queued step, 0.1 steps/s (signed).
    pub fn end_velocity(&self) -> i64 {
        let v = (isqrt(self.w) >> V_FRAC) as i64;
        if self.forward {
            v
        } else {
            -v
        }
    }

    /// Direction of the motion being planned, if any.
    pub fn heading(&self) -> Option<bool> {
        match &self.profile {
            Some(p) => Some(p.forward),
            None if self.w > 0 => Some(self.forward),
            None => None,
        }
    }

    /// Where the motor comes to rest on its own (raw steps): here when
    /// nothing is planned, the end of a stop or of a move that ends at
    /// rest. `None` while a stop at once waits for the interrupt (the
    /// position is known again after it), for an endless run, a move that
    /// hands over at speed, or a stop with a follow-up goal.
    pub fn rest_position(&self) -> Option<i64> {
        if self.flushing || self.then.is_some() {
            return None;
        }
        let signed = |forward: bool, n: u64| if forward { n as i64 } else { -(n as i64) };
        match &self.profile {
            // a finite profile ending at rest (an endless run has no steps)
            Some(p) if p.w_end() == 0 => Some(self.pos + signed(p.forward, p.steps? - p.done())),
            Some(_) => None,
            // a profile ended at speed: fill stops it with the last ramp
            None if self.w > 0 => {
                Some(self.pos + signed(self.forward, stop_steps(self.w, slope_of(self.last_decel))))
            }
            None => Some(self.pos),
        }
    }

    /// A profile or a follow-up goal is being planned.
    pub fn busy(&self) -> bool {
        self.profile.is_some() || self.then.is_some() || self.flushing
    }

    /// The motor is at rest and nothing is planned: every queued step has
    /// been made.
    pub fn at_rest(&self, sched: &StepSchedule) -> bool {
        !self.busy() && !sched.is_running() && sched.is_empty()
    }

    /// The raw position the interrupt has reached, unwrapped around the
    /// planner's end position.
    pub fn actual_position(&self, sched: &StepSchedule) -> i64 {
        self.pos + i64::from(sched.position().wrapping_sub(self.pos as i32))
    }

    /// Signed velocity of the segment being executed, 0.1 steps/s.
    pub fn actual_velocity(&self, sched: &StepSchedule) -> i64 {
        self.current_slot(sched).map_or(0, |s| s.velocity)
    }

    /// The segment being executed belongs to an acceleration or
    /// deceleration.
    pub fn ramping(&self, sched: &StepSchedule) -> bool {
        self.current_slot(sched).is_some_and(|s| s.ramping)
    }

    /// Segments pushed so far (wrapping).
    pub fn segments_pushed(&self) -> u32 {
        self.segments
    }

    fn current_slot(&self, sched: &StepSchedule) -> Option<SlotInfo> {
        if !sched.is_running() {
            return None;
        }
        let k = self.first_unfinished(sched.step_index());
        (k != self.segments).then(|| self.slots[k as usize % SCHEDULE_SLOTS])
    }

    /// The first segment from `oldest` on whose last step is at or after
    /// ring index `step` (wrapping): its number, `segments` if none.
    fn first_unfinished(&self, step: u32) -> u32 {
        let mut k = self.oldest;
        while k != self.segments {
            let last = self.slots[k as usize % SCHEDULE_SLOTS].last_index;
            if last.wrapping_sub(step) as i32 >= 0 {
                break;
            }
            k = k.wrapping_add(1);
        }
        k
    }

    /// Sets the position (homing zeroing, SPEC §8.6). Only at rest.
    pub fn rebase_position(&mut self, raw: i64) {
        self.pos = raw;
    }

    /// Replaces whatever is being planned by `goal`, continuing from the
    /// end of the queue with the velocity there. Returns false (and plans
    /// nothing) if the goal cannot run (a zero velocity or ramp).
    pub fn set_goal(&mut self, goal: Goal) -> bool {
        if self.flushing {
            // plan it once the interrupt has dropped the queue and the
            // position is known again
            let ok = match goal {
                Goal::Move { ramp, .. } | Goal::Run { ramp, .. } => ramp.runnable(),
                Goal::Stop { .. } => true,
            };
            self.then = ok.then_some(goal);
            return ok;
        }
        self.then = None;
        self.profile = None;
        let ok = self.start(goal);
        if !ok && self.w > 0 {
            // keep the motor under control: stop with the last deceleration
            self.start(Goal::Stop {
                decel: self.last_decel,
            });
        }
        ok
    }

    /// Drops everything queued and the pending step: step output stops at
    /// once (SPEC §8.1, §8.3 option 0/3+). The interrupt carries it out at
    /// its next step; [`Planner::fill`] waits for that.
    pub fn stop_at_once(&mut self, sched: &StepSchedule) {
        self.profile = None;
        self.then = None;
        self.w = 0;
        if sched.is_running() || !sched.is_empty() || sched.limit_brake().is_some() {
            // also after the interrupt's limit brake (schedule.rs): wait
            // for its end, then take the position back and release it
            sched.request_flush();
            self.flushing = true;
        }
    }

    /// Converts µs of the control clock to Q32.32 ticks (wrapping).
    fn ticks_q(&self, us: u64) -> u64 {
        let hz = self.cfg.tick_hz;
        // whole MHz (every timer the drive uses): one multiplication
        let ticks = if hz.is_multiple_of(1_000_000) {
            us.wrapping_mul(u64::from(hz / 1_000_000))
        } else {
            (u128::from(us) * u128::from(hz) / 1_000_000) as u64
        };
        ticks << TICK_FRAC_BITS
    }

    /// Appends segments until `now_us + horizon` is covered, the ring is
    /// full, or the goal has been planned to its end.
    pub fn fill(&mut self, now_us: u64, sched: &StepSchedule) -> Fill {
        let now = self.ticks_q(now_us);
        self.now = now;
        if self.flushing {
            let braking = sched.limit_brake().is_some_and(|b| !b.done);
            if braking || sched.flush_pending() && (sched.is_running() || !sched.is_empty()) {
                return Fill::Waiting;
            }
            // Carried out (or nothing was left to drop: clear it ourselves,
            // the interrupt is idle with an empty ring).
            sched.clear_flush_if_idle();
            sched.release_brake();
            self.flushing = false;
            self.pos = self.actual_position(sched);
            self.w = 0;
        }
        if !sched.is_running() && sched.is_empty() {
            // Everything queued has been stepped: start afresh from now.
            if self.w > 0 && self.profile.is_some() {
                self.underruns = self.underruns.wrapping_add(1);
            }
            self.t_isr = now;
            self.t_ideal = now;
        }
        self.oldest = self.first_unfinished(sched.step_index());
        let horizon = self.ticks_q(u64::from(self.cfg.horizon_us));
        loop {
            let Some(profile) = self.profile.as_mut() else {
                if let Some(goal) = self.then.take() {
                    self.start(goal);
                    continue;
                }
                if self.w > 0 {
                    // A profile ended at speed and nobody continued it.
                    let decel = self.last_decel;
                    self.start(Goal::Stop { decel });
                    continue;
                }
                return Fill::Idle;
            };
            if profile.remaining() == 0 {
                self.w = profile.w();
                self.profile = None;
                if self.then.is_some() {
                    continue;
                }
                return Fill::Ended;
            }
            // emit cuts the segment to the free steps: full when none is
            // free, or when the segment bookkeeping is
            let tracked = self.segments.wrapping_sub(self.oldest) as usize;
            if sched.free() == 0
                || tracked >= SCHEDULE_SLOTS
                || self.t_ideal.wrapping_sub(now) as i64 >= horizon as i64
            {
                return Fill::Full;
            }
            self.emit(sched);
        }
    }

    /// Plans `goal` from the end state. False if it cannot run.
    fn start(&mut self, goal: Goal) -> bool {
        let hz = self.cfg.tick_hz;
        match goal {
            Goal::Stop { decel } => {
                if self.w > 0 {
                    if decel == 0 {
                        return false;
                    }
                    self.last_decel = decel;
                    self.profile = Some(Profile::new_stop(
                        self.forward,
                        self.w,
                        slope_of(decel),
                        self.t_ideal,
                        hz,
                    ));
                }
                true
            }
            Goal::Move {
                target,
                ramp,
                end_velocity,
            } => {
                if !ramp.runnable() {
                    return false;
                }
                self.last_decel = ramp.decel;
                let (wc, we) = (w_of(ramp.velocity), w_of(end_velocity));
                let (su, sd) = (slope_of(ramp.accel), slope_of(ramp.decel));
                let dist = target - self.pos;
                let steps = dist.unsigned_abs();
                if self.w == 0 {
                    if dist == 0 {
                        return true;
                    }
                    self.forward = dist > 0;
                }
                let toward = dist != 0 && (dist > 0) == self.forward;
                if toward && self.w <= we.min(wc) + sd * (u128::from(steps) << 32) {
                    self.profile = Some(Profile::new_move(
                        self.forward,
                        self.w,
                        wc,
                        we,
                        su,
                        sd,
                        steps,
                        self.t_ideal,
                        hz,
                    ));
                } else {
                    // Behind us or too close to stop: decelerate, then plan
                    // again from rest (SPEC §8.4 bit 5, "decelerates,
                    // reverses and arrives").
                    self.stop_then(sd, goal);
                }
                true
            }
            Goal::Run { forward, ramp } => {
                if !ramp.runnable() {
                    return false;
                }
                self.last_decel = ramp.decel;
                let sd = slope_of(ramp.decel);
                if self.w > 0 && forward != self.forward {
                    self.stop_then(sd, goal);
                } else {
                    self.forward = forward;
                    let p = Profile::new_run(
                        forward,
                        self.w,
                        w_of(ramp.velocity),
                        slope_of(ramp.accel),
                        sd,
                        self.t_ideal,
                        hz,
                    );
                    self.profile = Some(p);
                }
                true
            }
        }
    }

    /// Decelerates with slope `sd` to rest on a whole step, then plans
    /// `goal` again from there.
    fn stop_then(&mut self, sd: u128, goal: Goal) {
        let hz = self.cfg.tick_hz;
        self.profile = Some(Profile::new_stop(
            self.forward,
            self.w,
            sd,
            self.t_ideal,
            hz,
        ));
        self.then = Some(goal);
    }

    /// Times the next run of steps of the current profile and queues it.
    /// Out of line: inlined into the firmware's control loop it cost the
    /// F103 156 B more flash.
    #[inline(never)]
    fn emit(&mut self, sched: &StepSchedule) {
        let Some(profile) = self.profile.as_mut() else {
            return;
        };
        // Longest segment allowed by the latency bound at the current speed.
        let v = profile.velocity();
        let by_time = div(
            u128::from(self.cfg.max_segment_us) * u128::from(v),
            10_000_000,
        );
        let max_steps = (by_time as u64)
            .clamp(1, MAX_PLANNED_SEGMENT)
            .min(sched.free() as u64);
        let n = profile.segment_len(max_steps);
        let t_first = profile.advance(1);
        if (t_first.wrapping_sub(self.now) as i64) < 0 {
            self.late_segments = self.late_segments.wrapping_add(1);
        }
        let first = t_first.wrapping_sub(self.t_isr);
        let (t_last, (add, add2)) = match n {
            1 => (t_first, (0, 0)),
            2 => {
                let t2 = profile.advance(1);
                (t2, (t2.wrapping_sub(t_first) as i64 - first as i64, 0))
            }
            _ => {
                let t_pen = profile.advance(n - 2);
                let t_last = profile.advance(1);
                let last = t_last.wrapping_sub(t_pen);
                let span = t_last.wrapping_sub(self.t_isr);
                (t_last, fit_segment(n, first, last, span))
            }
        };
        let (c2, c3) = pair_triple(n);
        let span = i128::from(n) * i128::from(first)
            + i128::from(c2) * i128::from(add)
            + i128::from(c3) * i128::from(add2);
        self.t_isr = self.t_isr.wrapping_add(span as u64);
        self.t_ideal = t_last;
        self.planned_steps = self.planned_steps.wrapping_add(n);
        self.pos += if profile.forward {
            n as i64
        } else {
            -(n as i64)
        };
        self.w = profile.w();
        self.forward = profile.forward;
        let speed = profile.velocity() as i64;
        let mut info = SlotInfo {
            last_index: 0,
            velocity: if profile.forward { speed } else { -speed },
            ramping: profile.ramping() || profile.remaining() == 0,
        };
        let seg = Segment {
            interval: first,
            add,
            add2,
            count: n as u32,
            forward: profile.forward,
        };
        if sched.push(seg).is_ok() {
            info.last_index = sched.last_pushed_index();
            self.slots[self.segments as usize % SCHEDULE_SLOTS] = info;
            self.segments = self.segments.wrapping_add(1);
        }
    }
}

/// `add` and `add2` (Q32.32) of a segment of `n ≥ 3` steps whose first
/// interval is `first`, last interval `last` and total `span`:
/// `(n−1)·add + C(n−1,2)·add2 = last − first` and
/// `C(n,2)·add + C(n,3)·add2 = span − n·first`. `add2` is solved from both,
/// `add` from the second (so the end time is exact up to rounding of `add`,
/// which the caller accounts for).
fn fit_segment(n: u64, first: u64, last: u64, span: u64) -> (i64, i64) {
    let n = i128::from(n);
    let p = i128::from(last) - i128::from(first);
    let s = i128::from(span) - n * i128::from(first);
    let (c2, c3) = pair_triple(n as u64);
    let add2 = round_div(n * p - 2 * s, c3);
    let add = round_div(s - i128::from(c3) * add2, c2);
    (add as i64, add2 as i64)
}

/// `C(n,2)` and `C(n,3)`: exact in 64 bits for `n ≤ 2^20` (far above
/// `MAX_PLANNED_SEGMENT`).
fn pair_triple(n: u64) -> (u64, u64) {
    let c2 = (n * n.saturating_sub(1)) >> 1;
    // C(n,2)·(n−2) is a multiple of 3: dividing it exactly is multiplying
    // by the inverse of 3 modulo 2^64 (a u64 division is a software
    // routine on a 32-bit core)
    const INV3: u64 = 0xAAAA_AAAA_AAAA_AAAB;
    (c2, (c2 * n.saturating_sub(2)).wrapping_mul(INV3))
}

/// `num / den` rounded to nearest, ties away from zero, through the fast
/// 128-by-64 division (profile.rs) on the magnitude.
fn round_div(num: i128, den: u64) -> i128 {
    let q = super::profile::div(
        2 * num.unsigned_abs() + u128::from(den),
        2 * u128::from(den),
    );
    if num < 0 {
        -(q as i128)
    } else {
        q as i128
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The 32-bit-division form of C(n,2), C(n,3) equals the plain one
    /// up to 2^20 steps.
    #[test]
    fn pair_triple_is_exact() {
        let check = |n: u64| {
            let c2 = n * n.saturating_sub(1) / 2;
            assert_eq!(pair_triple(n), (c2, c2 * n.saturating_sub(2) / 3), "{n}");
        };
        (0..5000).for_each(check);
        ((1 << 20) - 5000..=1 << 20).for_each(check);
    }

    /// 0x606C / statusword bit 13 follow the segment the interrupt is
    /// executing (SPEC §8.2): over a move of many laps of the step ring,
    /// the velocity shown at every step matches that step's own interval
    /// within a segment's velocity change (≤ 1/32, `Profile::segment_len`),
    /// also during the ramps, where a segment queued ahead (3 ms at
    /// 2e6 steps/s²) would be off by up to 6000 steps/s.
    #[test]
    fn the_velocity_shown_is_the_executing_segments() {
        use crate::motion::schedule::StepSource;
        let sched = StepSchedule::new();
        let mut src = StepSource::new();
        let cfg = PlannerConfig::default();
        let hz = f64::from(cfg.tick_hz);
        let mut p = Planner::new(cfg);
        let ramp = Ramp {
            velocity: 1_000_000, // 100 000 steps/s
            accel: 20_000_000,   // 2e6 steps/s²
            decel: 20_000_000,
        };
        assert!(p.set_goal(Goal::Move {
            target: 30_000,
            ramp,
            end_velocity: 0
        }));
        let ticks_per_us = u64::from(cfg.tick_hz / 1_000_000);
        let (mut now_us, mut at, mut steps, mut ramping) = (0u64, None::<u64>, 0u32, 0u32);
        while now_us < 1_000_000 {
            p.fill(now_us, &sched);
            if at.is_none() && !sched.is_empty() {
                at = Some(now_us * ticks_per_us);
            }
            let end = (now_us + 1000) * ticks_per_us;
            while let Some(t) = at.filter(|&t| t < end) {
                let Some(s) = src.advance(&sched) else {
                    at = None;
                    break;
                };
                at = Some(t + u64::from(s.delay_ticks));
                steps += 1;
                let shown = p.actual_velocity(&sched) as f64 / 10.0;
                let own = hz / f64::from(s.delay_ticks);
                if own > 5_000.0 {
                    assert!(
                        (shown / own - 1.0).abs() < 0.06,
                        "step {steps}: shown {shown} steps/s, interval {own}"
                    );
                }
                ramping += u32::from(p.ramping(&sched));
            }
            now_us += 1000;
        }
        assert_eq!((steps, sched.position()), (30_000, 30_000));
        assert_eq!(p.actual_velocity(&sched), 0);
        // both ramps (2500 steps each) shown as ramping, the cruise not
        assert!((4_000..6_000).contains(&ramping), "{ramping}");
        assert!(p.segments_pushed() > 100);
    }
}
