//! The planner: goals in, schedule segments out (thread mode).
//!
//! It keeps the state at the *end* of what is already planned (position,
//! direction, v², exact time) and appends to the [`StepSchedule`] from there:
//! pushed steps are never rewritten, so no step is ever scheduled in the
//! past. Only "stop at once" discards the queue.
//!
//! Compression: each segment of `n = 2^k` steps takes from the [`Profile`]
//! the exact time of its last step, and `dt/dx = 1/v` and `d²t/dx² =
//! −a/v³` at both ends; its step times follow the quintic matching all
//! six (quintic Hermite, `fit_segment`), handed to the interrupt as the
//! forward differences `interval, add, …, add4`. So every segment starts
//! and ends on the profile and consecutive segments join with continuous
//! velocity *and* acceleration; inside, the error bounds of
//! [`Profile::segment_len`] hold (time, acceleration, precision). Times the
//! interrupt will accumulate are tracked exactly (`t_isr`), so nothing
//! drifts.
//!
//! Latency: a segment is fitted and pushed whole (in parts only when the
//! ring lacks room), so most control calls find the horizon
//! ([`PlannerConfig::horizon_us`]) covered and return at once; a new goal
//! takes back the steps due after the horizon ([`StepSchedule::truncate`],
//! in the next fill) and goes back to the last step that stays
//! (`drop_pending`), so a change of goal takes effect after the horizon
//! however long the segments are.
//!
//! Cost per segment: one profile evaluation (a square root, and on a ramp
//! a multiplication, elsewhere a division, on 128-bit numbers but through
//! 64-bit routines: `profile::isqrt`, `profile::div`), the end slope (a
//! division), two curvatures (a few multiplications) and the length bounds
//! (logarithms); segments hold up to 2^7 steps on a ramp and 2^8 on a
//! cruise (single steps near rest only).

use super::profile::{isqrt, slope_of, stop_steps, w_along, w_of, Profile, SegmentBudget, V_FRAC};
use super::schedule::{Segment, StepSchedule, TICK_FRAC_BITS};

/// Highest step rate the drive generates, steps/s. Faster requests are
/// clamped (like PA12): 5 µs between steps leaves a 170 MHz Cortex-M4 850
/// cycles per step, of which the step interrupt uses about 50.
pub const MAX_STEP_RATE: u32 = 200_000;

/// Highest acceleration, steps/s². Above it the start of a ramp would need
/// more single-step segments than [`SCHEDULE_SLOTS`] to cover a 2 ms
/// control period; larger register values are clamped.
pub const MAX_ACCEL: u64 = 2_000_000;

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
    /// Step timer frequency, Hz: a whole number of MHz (the control clock
    /// in µs converts with one multiplication; the boards use 10 and
    /// 8 MHz), ≥ 1 MHz so that steps at the maximum rate are ≥ 5 ticks
    /// apart; sub-µs resolution keeps step times exact.
    pub tick_hz: u32,
    /// How far ahead of `now` the schedule is filled. Must exceed the
    /// control period; it is also the latency of a change of goal (what
    /// is pushed to the interrupt stays; a segment is fitted whole but
    /// pushed whole, and a new goal takes back its steps after the
    /// horizon).
    pub horizon_us: u32,
    /// Longest segment, µs (at most 2^22 ticks: the fit's numbers stay in
    /// 64 bits). Long segments cost the planner less per step; they do not
    /// delay a change of goal.
    pub max_segment_us: u32,
}

impl Default for PlannerConfig {
    fn default() -> Self {
        Self {
            // the primary board's
            tick_hz: crate::boards::Board::G431.step_tick_hz(),
            horizon_us: 3_000,
            max_segment_us: 100_000,
        }
    }
}

/// What the drive shows for the segment the interrupt is executing.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct SlotInfo {
    /// Ring index of the segment's last step ([`StepSchedule::step_index`]).
    last_index: u32,
    /// Steps of its segment after its last step (a segment is pushed in
    /// parts when the ring lacks room, and cut by a new goal), the
    /// segment's steps, and the signed
    /// velocities (0.1 steps/s) before the segment's first and at its last
    /// step: v² is linear in the steps within a segment (one profile
    /// piece), so the velocity of any of its steps follows without keeping
    /// v² per step.
    to_end: u32,
    count: u32,
    v_start: i32,
    v_end: i32,
    ramping: bool,
}

impl SlotInfo {
    /// Signed velocity (0.1 steps/s) at the step with ring index `step`.
    fn velocity_at(&self, step: u32) -> i64 {
        let left =
            u64::from(self.last_index.wrapping_sub(step).min(self.count)) + u64::from(self.to_end);
        let (a, b) = (i64::from(self.v_start), i64::from(self.v_end));
        if a == b || self.count == 0 {
            return b;
        }
        // v² = b² − (b² − a²)·left/count, in u64 (|v| < 2^22)
        let (a2, b2) = ((a * a) as u64, (b * b) as u64);
        let n = u64::from(self.count);
        // segments hold a power of two of steps: the division is a shift
        let (left, k) = (left.min(n), n.trailing_zeros());
        let w = if b2 >= a2 {
            b2 - (((b2 - a2) * left) >> k)
        } else {
            b2 + (((a2 - b2) * left) >> k)
        };
        let v = w.isqrt() as i64;
        if b < 0 || (b == 0 && a < 0) {
            -v
        } else {
            v
        }
    }
}

/// The segment being handed to the interrupt: fitted and pushed whole
/// (in parts when the ring lacks room), and cut at the horizon by a new
/// goal, so that its length (the fit's cost is per segment) does not delay
/// a change of goal (module docs).
#[derive(Clone, Copy, Debug, Default)]
struct Pending {
    /// Its steps not yet pushed, and their terms (`count` = 0: none).
    rest: Segment,
    /// Steps it holds.
    n: u64,
    /// The planner's state before it (position, v², exact time), and the
    /// v² slope of its piece: enough to find the state after any of its
    /// steps when a new goal cuts it.
    pos: i64,
    w: u128,
    t_ideal: u64,
    slope: i128,
    /// For the drive's 0x606C: the velocities at its ends.
    info: SlotInfo,
    /// Where it went, for a cut (`drop_pending`): its terms at its first
    /// step (`count` 0: its times are no longer those, as after the ring
    /// ran dry inside it, so no cut), the fraction carried into that
    /// step, the time before it as the interrupt will reach it, the ring
    /// index of its first step, and the steps pushed (0: none).
    start: Segment,
    start_frac: u32,
    t_start: u64,
    first: u32,
    pushed: u32,
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
    /// The last fill returned [`Fill::Full`] with more to plan, and no
    /// goal or stop has come since: the next fill may return at once
    /// while the horizon is covered ([`Planner::fill`]).
    covered: bool,
    /// Q32.32 ticks per µs of the control clock.
    tick_per_us: u64,
    /// Steps queued since start (wrapping; a stop at once drops some of
    /// them unmade): lets a test tell which profile timed a step.
    pub planned_steps: u64,
    /// Segments fitted since start (wrapping; each is pushed in one or
    /// more parts, [`Planner::segments_pushed`]).
    pub segments_fitted: u32,
    budget: SegmentBudget,
    pending: Pending,
    /// `horizon_us` in Q32.32 ticks.
    horizon_q: u64,
    /// A cut of the pending segment that [`Planner::fill`] has yet to
    /// make in the ring (`drop_pending`): the ring index of the first step
    /// taken back, the fraction carried there, and the goal planned from
    /// it (planned again from where the motor is if the interrupt got
    /// there first).
    cut: Option<(u32, u32, Goal)>,
    /// Time per step at the end of the last segment (Q32.32 ticks, 0 =
    /// none) and the v² it belongs to.
    s_end: u64,
    s_end_w: u128,
    /// The curvature there (Q32.32 ticks per step², [`Profile::curvature`]).
    c_end: i64,
    /// Time per step (Q32.32 ticks, 0 = none) of the steps already pushed
    /// where a new goal cut a segment ([`Planner::drop_pending`]): the
    /// next segment starts with it, so that the velocity stays continuous.
    s_join: u64,
}

impl Planner {
    pub fn new(cfg: PlannerConfig) -> Self {
        let mut p = Self {
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
            covered: false,
            tick_per_us: u64::from(cfg.tick_hz / 1_000_000) << TICK_FRAC_BITS,
            planned_steps: 0,
            segments_fitted: 0,
            budget: SegmentBudget::new(cfg.tick_hz, cfg.max_segment_us),
            pending: Pending::default(),
            horizon_q: 0,
            cut: None,
            s_end: 0,
            s_end_w: 0,
            c_end: 0,
            s_join: 0,
        };
        p.horizon_q = p.ticks_q(u64::from(cfg.horizon_us));
        p
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
        signed(self.forward, (isqrt(self.w) >> V_FRAC) as u64)
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
        self.profile.is_some()
            || self.then.is_some()
            || self.flushing
            || self.pending.rest.count > 0
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
        self.current_slot(sched)
            .map_or(0, |s| s.velocity_at(sched.step_index()))
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
        self.covered = false;
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
        // a motion being replaced is cut at the horizon; one planned to
        // its end (Fill::Ended) is continued from its end
        let cut = self.profile.is_some() || self.then.is_some();
        self.then = None;
        self.profile = None;
        match self.drop_pending(cut) {
            Some((at, frac)) => self.cut = Some((at, frac, goal)),
            // a cut still waiting (two goals before a fill): the latest
            None => {
                if let Some(c) = self.cut.as_mut() {
                    c.2 = goal;
                }
            }
        }
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
        self.covered = false;
        self.profile = None;
        self.then = None;
        self.w = 0;
        self.pending.rest.count = 0;
        self.pending.pushed = 0;
        self.cut = None;
        self.s_join = 0;
        if sched.is_running() || !sched.is_empty() || sched.limit_brake().is_some() {
            // also after the interrupt's limit brake (schedule.rs): wait
            // for its end, then take the position back and release it
            sched.request_flush();
            self.flushing = true;
        }
    }

    /// Converts µs of the control clock to Q32.32 ticks (wrapping): one
    /// multiplication, the tick being a whole number of MHz
    /// ([`PlannerConfig::tick_hz`]).
    fn ticks_q(&self, us: u64) -> u64 {
        us.wrapping_mul(self.tick_per_us)
    }

    /// Appends segments until `now_us + horizon` is covered, the ring is
    /// full, or the goal has been planned to its end.
    ///
    /// Most calls find the horizon still covered: with `covered` set (the
    /// last call returned [`Fill::Full`] with more to plan, and no goal or
    /// stop came since) that is one comparison and a look at the ring,
    /// without the set-up of the full fill.
    #[inline]
    pub fn fill(&mut self, now_us: u64, sched: &StepSchedule) -> Fill {
        let now = self.ticks_q(now_us);
        self.now = now;
        if self.covered && self.horizon_covered(now) && (sched.is_running() || !sched.is_empty()) {
            return Fill::Full;
        }
        let fill = self.fill_from(now, sched);
        self.covered = fill == Fill::Full && self.cut.is_none() && self.more_to_plan();
        fill
    }

    /// What is queued reaches `now` + the horizon.
    #[inline(always)]
    fn horizon_covered(&self, now: u64) -> bool {
        self.t_isr.wrapping_sub(now) as i64 >= self.horizon_q as i64
    }

    /// Not waiting for a stop at once, and steps left to push or to plan.
    #[inline(always)]
    fn more_to_plan(&self) -> bool {
        !self.flushing
            && (self.pending.rest.count > 0
                || self.profile.as_ref().is_some_and(|p| p.remaining() != 0))
    }

    /// The slot of the last segment pushed.
    #[inline(always)]
    fn last_slot(&mut self) -> &mut SlotInfo {
        &mut self.slots[self.segments.wrapping_sub(1) as usize % SCHEDULE_SLOTS]
    }

    /// [`Planner::fill`] past its first check.
    #[inline(never)]
    fn fill_from(&mut self, now: u64, sched: &StepSchedule) -> Fill {
        if let Some((at, frac, goal)) = self.cut.take() {
            if !sched.truncate(at, frac) {
                // The interrupt got to the cut first (the control loop ran
                // more than the horizon less a period late): stop at once
                // and plan the goal again from where the motor is.
                self.underruns = self.underruns.wrapping_add(1);
                self.stop_at_once(sched);
                if !self.flushing {
                    self.pos = self.actual_position(sched);
                }
                self.set_goal(goal);
            }
        }
        if self.horizon_covered(now)
            && self.more_to_plan()
            && (sched.is_running() || !sched.is_empty())
        {
            // the horizon is covered (after a goal or a cut, which clear
            // `covered`): what the loop below would find, without its
            // set-up
            return Fill::Full;
        }
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
            if self.w > 0 && (self.profile.is_some() || self.pending.rest.count > 0) {
                self.underruns = self.underruns.wrapping_add(1);
            }
            if self.pending.rest.count > 0 {
                // ran dry inside a segment (never expected): its rest
                // and what follows move later, to now
                let dt = now.wrapping_sub(self.t_isr);
                // (a cut would find its steps by the old times: none)
                self.pending.start.count = 0;
                self.t_ideal = self.t_ideal.wrapping_add(dt);
                self.pending.t_ideal = self.pending.t_ideal.wrapping_add(dt);
                if let Some(p) = self.profile.as_mut() {
                    p.delay(dt);
                }
            } else {
                // A profile planned from rest since the last fill (a goal
                // given between fills) started at the old end time, which
                // may be a control period or more ago: from there its first
                // step (√(2/a) from rest: a control period at the maximum
                // acceleration) could fall before now and wrap into a
                // delay of minutes. It starts from now instead.
                let dt = now.wrapping_sub(self.t_ideal);
                if let Some(p) = self.profile.as_mut() {
                    p.delay(dt);
                }
                self.t_ideal = now;
            }
            self.t_isr = now;
            self.s_join = 0;
        }
        self.oldest = self.first_unfinished(sched.step_index());
        loop {
            if self.pending.rest.count > 0 {
                if !self.push_pending(sched) {
                    return Fill::Full;
                }
                continue;
            }
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
            if self.horizon_covered(now) {
                return Fill::Full;
            }
            self.emit();
        }
    }

    /// Plans `goal` from the end state. False if it cannot run.
    fn start(&mut self, goal: Goal) -> bool {
        let hz = self.cfg.tick_hz;
        // a new profile: its curvature differs (emit's cached end values)
        self.s_end = 0;
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

    /// Times the next run of steps of the current profile and fits it
    /// ([`fit_segment`]) into the pending segment, which
    /// [`Planner::push_pending`] hands to the interrupt. Out of line:
    /// inlined into the firmware's control loop it cost the F103 flash.
    #[inline(never)]
    fn emit(&mut self) {
        let Some(profile) = self.profile.as_mut() else {
            return;
        };
        let (s0, c0) = if self.s_end_w == self.w && self.s_end != 0 {
            // the end slope and curvature of the previous segment, same
            // profile (start() clears them): a division and a curvature
            // saved
            (Some(self.s_end), self.c_end)
        } else {
            // after a cut (drop_pending), the slope of the steps made
            let s0 = match core::mem::take(&mut self.s_join) {
                0 => profile.step_ticks(),
                s => Some(s),
            };
            (s0, s0.map_or(0, |s0| profile.curvature(s0)))
        };
        let n = profile.segment_len(s0, c0, &self.budget);
        let (pos, w, t_ideal) = (self.pos, self.w, self.t_ideal);
        let slope = profile.piece_slope();
        let v_start = profile.velocity();
        let t_last = profile.advance(n);
        let s1 = profile.step_ticks();
        let c1 = s1.map_or(0, |s1| profile.curvature(s1));
        // the span the interrupt must make, from where it will be
        let span = t_last.wrapping_sub(self.t_isr);
        let [interval, add, add2, add3, add4] = match (n, s0, s1) {
            (2.., Some(s0), Some(s1)) => {
                let ends = [(s0, c0), (s1, c1)];
                fit_segment(n, ends, span)
            }
            // single steps (or no slope at the end: evenly, the rest of
            // the span is carried to the next segment through t_isr)
            _ => [span >> n.trailing_zeros(), 0, 0, 0, 0],
        };
        self.t_ideal = t_last;
        self.planned_steps = self.planned_steps.wrapping_add(n);
        self.segments_fitted = self.segments_fitted.wrapping_add(1);
        self.pos += signed(profile.forward, n);
        self.w = profile.w();
        self.forward = profile.forward;
        (self.s_end, self.c_end, self.s_end_w) = (s1.unwrap_or(0), c1, self.w);
        let seg = Segment {
            interval,
            add: add as i64,
            add2: add2 as i64,
            add3: add3 as i64,
            add4: add4 as i64,
            count: n as u32,
            forward: profile.forward,
        };
        self.pending = Pending {
            rest: seg,
            start: seg,
            start_frac: 0,
            t_start: 0,
            first: 0,
            pushed: 0,
            n,
            pos,
            w,
            t_ideal,
            slope,
            info: SlotInfo {
                last_index: 0,
                to_end: 0,
                count: n as u32,
                v_start: signed(profile.forward, v_start) as i32,
                v_end: signed(profile.forward, profile.velocity()) as i32,
                ramping: profile.ramping() || profile.remaining() == 0,
            },
        };
    }

    /// Pushes the pending segment whole, or as much of it as the ring
    /// takes (a new goal cuts it at the horizon, `drop_pending`). True when
    /// none is left; false when the ring or the segment bookkeeping
    /// stopped it.
    fn push_pending(&mut self, sched: &StepSchedule) -> bool {
        let tracked = self.segments.wrapping_sub(self.oldest) as usize;
        if tracked >= SCHEDULE_SLOTS {
            return false;
        }
        let pending = &mut self.pending;
        let seg = &mut pending.rest;
        let k = seg.count.min(sched.free() as u32);
        if (self.t_isr.wrapping_add(seg.interval).wrapping_sub(self.now) as i64) < 0 {
            self.late_segments = self.late_segments.wrapping_add(1);
        }
        let first_part = pending.pushed == 0;
        if first_part {
            pending.start_frac = sched.carry_in();
            pending.t_start = self.t_isr;
        }
        let Some(made) = sched.push_steps(seg, k) else {
            return false;
        };
        pending.pushed += k;
        self.t_isr = self.t_isr.wrapping_add(made);
        let last = sched.last_pushed_index();
        // one slot per segment, its end moved on with each part
        if first_part {
            pending.first = last.wrapping_sub(k - 1);
            self.slots[self.segments as usize % SCHEDULE_SLOTS] = pending.info;
            self.segments = self.segments.wrapping_add(1);
        }
        let to_end = pending.rest.count;
        let slot = self.last_slot();
        slot.last_index = last;
        slot.to_end = to_end;
        to_end == 0
    }

    /// A new goal: the state goes back to the last step of the pending
    /// segment that stays, so that the new goal continues from that step
    /// and takes effect within the horizon. The segment was pushed whole
    /// (or as far as the ring took it); with `cut` (a motion being
    /// replaced, not one planned to its end) its steps due after the
    /// horizon are taken back from the ring ([`StepSchedule::truncate`],
    /// in the next [`Planner::fill`]: returned here, kept in `cut`), and
    /// the steps not pushed are dropped. What the state goes back to:
    /// the position and v² (linear along its piece), and the time and
    /// slope of the steps made — where the interrupt will be, not the
    /// profile's exact time and `1/v` there: inside a segment the fit
    /// differs from those by up to its error bound, and the next segment
    /// must continue the steps made without a jump in time or velocity
    /// (a jump of 0.3 µs in one step would be a spike of 60 000 steps/s²
    /// at 6000 steps/s). The new profile starts from that time.
    fn drop_pending(&mut self, cut: bool) -> Option<(u32, u32)> {
        let p = self.pending;
        self.pending.rest.count = 0;
        self.pending.pushed = 0;
        // the steps dropped, the terms at the last step that stays, and
        // the cut to make in the ring (its first ring index, the fraction
        // carried there)
        let (mut left, mut r, mut taken) = (p.rest.count, p.rest, None);
        if cut && p.pushed > 1 && p.start.count > 0 {
            // the steps due before the horizon (at least one), found by
            // expanding the segment again from its start
            let (mut seg, mut frac) = (p.start, p.start_frac);
            let until = self
                .now
                .wrapping_add(self.horizon_q)
                .wrapping_sub(p.t_start);
            let (steps, time) = seg.advance_until(&mut frac, until, p.pushed);
            if steps < p.pushed {
                // taken back from the ring in the next fill (set_goal may
                // run where the schedule is not at hand)
                taken = Some((p.first.wrapping_add(steps), frac));
                (left, r) = (left + p.pushed - steps, seg);
                self.t_isr = p.t_start.wrapping_add(time);
                let slot = self.last_slot();
                slot.last_index = p.first.wrapping_add(steps - 1);
                slot.to_end = p.n as u32 - steps;
            }
        }
        if left == 0 {
            return None;
        }
        let (left, j) = (u64::from(left), p.n - u64::from(left));
        self.planned_steps = self.planned_steps.wrapping_sub(left);
        self.pos = p.pos + signed(p.rest.forward, j);
        self.w = w_along(p.w, p.slope, u128::from(j) << 32);
        self.t_ideal = self.t_isr;
        // T'(j) from the forward differences at j (D = ln(1 + Δ)):
        // Δ − Δ²/2 + Δ³/3 − Δ⁴/4 + Δ⁵/5, exact for the quintic
        let higher = (r.add.wrapping_mul(-30))
            .wrapping_add(r.add2.wrapping_mul(20))
            .wrapping_add(r.add3.wrapping_mul(-15))
            .wrapping_add(r.add4.wrapping_mul(12));
        self.s_join = r.interval.wrapping_add((higher / 60) as u64);
        self.s_end = 0;
        taken
    }
}

/// `n` steps (or 0.1 steps/s) as a signed count in the direction
/// `forward`.
fn signed(forward: bool, n: u64) -> i64 {
    if forward {
        n as i64
    } else {
        -(n as i64)
    }
}

/// `[interval, add, add2, add3, add4]` (Q32.32, two's complement) of a
/// segment of `n = 2^k ≥ 2` steps whose step times follow the quintic
/// `T(j)` with `T(0) = 0`, `T(n) = span` and the slopes and curvatures
/// `ends = [(T'(0), T''(0)), (T'(n), T''(n))]` (quintic Hermite: the
/// profile's `dt/dx = 1/v` and `d²t/dx² = −a/v³` at both ends, so that
/// consecutive segments join with continuous velocity *and*
/// acceleration). With `T(j) = s0·j + c0/2·j² + (N3·j³ + N4·j⁴/n +
/// N5·j⁵/n²)/n³` the terms are the forward differences of `T` at 0, each
/// rounded once from exact numerators over `n⁵` (a shift): the rounding
/// of the highest term, summed over the segment, stays below 1/100 tick.
/// The caller accounts the rest: it tracks the time the interrupt will
/// really reach.
fn fit_segment(n: u64, ends: [(u64, i64); 2], span: u64) -> [u64; 5] {
    let [(s0, c0), (s1, c1)] = ends;
    let k = n.trailing_zeros();
    // R, R1 are small remainders of large numbers: wrapping arithmetic
    // gives them exactly. Sizes: R ≈ t‴·n³/6 ≤ span·2^27 (n ≤ m/2), and
    // spans ≤ 2^22 ticks (SegmentBudget): every number below < 2^62.
    let h = n as i64;
    let r = span
        .wrapping_sub(s0.wrapping_mul(n))
        .wrapping_sub((c0.wrapping_mul(h * h) >> 1) as u64) as i64;
    let r1 = s1.wrapping_sub(s0).wrapping_sub(c0.wrapping_mul(h) as u64) as i64;
    let r2h2 = (c1.wrapping_sub(c0) << (2 * k)) >> 1;
    let r1h = r1 << k;
    let n3 = 10 * r - 4 * r1h + r2h2;
    let n4 = -15 * r + 7 * r1h - 2 * r2h2;
    let n5 = 6 * r - 3 * r1h + r2h2;
    // a3 = N3/n³, a4 = N4/n⁴, a5 = N5/n⁵; Δ^k of j^m at 0 is k!·S(m,k):
    // (1,6,6), (1,14,36,24), (1,30,150,240,120). Each term rounded
    // separately (≤ 1.5 units of 2^-32 tick), the highest once.
    let rnd = |x: i64, sh: u32| ((x >> (sh - 1)) + 1) >> 1;
    let t = |c3: i64, c4: i64, c5: i64| {
        (rnd(c3 * n3, 3 * k) + rnd(c4 * n4, 4 * k) + rnd(c5 * n5, 5 * k)) as u64
    };
    [
        s0.wrapping_add((c0 >> 1) as u64).wrapping_add(t(1, 1, 1)),
        (c0 as u64).wrapping_add(t(6, 14, 30)),
        t(6, 36, 150),
        t(0, 24, 240),
        t(0, 0, 120),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A goal or a stop given between two fills is acted on by the next
    /// fill, also one at the same `now` as the last: the quick return of a
    /// covered horizon (`Planner::covered`) must not hide the cut of the
    /// queued steps or the wait for a stop at once.
    #[test]
    fn a_goal_between_fills_is_planned_by_the_next_fill() {
        use crate::motion::schedule::StepSource;
        let sched = StepSchedule::new();
        let mut src = StepSource::new();
        let mut p = Planner::new(PlannerConfig::default());
        // 500 steps/s, 5000 steps/s²: cruising after 25 steps, in segments
        // of 64 steps (128 ms), the horizon covered in most fills
        let ramp = Ramp {
            velocity: 5_000,
            accel: 50_000,
            decel: 50_000,
        };
        assert!(p.set_goal(Goal::Move {
            target: 100_000,
            ramp,
            end_velocity: 0
        }));
        let (mut now_us, mut at) = (0u64, None::<u64>);
        while now_us < 400_000 {
            p.fill(now_us, &sched);
            at = at.or((!sched.is_empty()).then_some(now_us * 10));
            while let Some(t) = at.filter(|&t| t < (now_us + 1000) * 10) {
                at = src.advance(&sched).map(|s| t + u64::from(s.delay_ticks));
            }
            now_us += 1000;
        }
        assert_eq!(p.fill(now_us, &sched), Fill::Full);
        let free = sched.free();
        let faster = Ramp {
            velocity: 8_000,
            ..ramp
        };
        assert!(p.set_goal(Goal::Run {
            forward: true,
            ramp: faster
        }));
        // the steps after the horizon taken back at once (the new goal is
        // appended when the horizon needs it)
        assert_eq!(p.fill(now_us, &sched), Fill::Full);
        assert!(sched.free() > free, "no cut: {free} -> {}", sched.free());
        p.stop_at_once(&sched);
        assert_eq!(p.fill(now_us, &sched), Fill::Waiting);
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
