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
//! (logarithms); segments hold up to 2^7 steps on a ramp and 2^10 on a
//! cruise (single steps near rest only).

mod fill;
mod goal;
mod segment;
mod slots;
#[cfg(test)]
mod tests;

use crate::boards::Board;

use super::profile::{isqrt, slope_of, stop_steps, Profile, SegmentBudget, V_FRAC};
use super::schedule::{StepSchedule, TICK_FRAC_BITS};
use segment::{signed, Pending};
use slots::SlotInfo;

/// Ceiling of every board's step rate, steps/s: what the per-step ring
/// ([`crate::motion::SCHEDULE_STEPS`], more than two control periods at
/// this rate) and the planner's arithmetic are sized for. Each board's own
/// limit ([`crate::boards::Board::max_step_rate`], in
/// [`PlannerConfig::max_step_rate`]) is at most this; faster requests are
/// clamped to the board's limit (like PA12). An image checks its own
/// board against it at compile time (src/firmware); the host, which
/// simulates every board, has the longest ring.
#[cfg(feature = "longer-schedule")]
pub const MAX_STEP_RATE: u32 = 1_000_000;
#[cfg(all(feature = "long-schedule", not(feature = "longer-schedule")))]
pub const MAX_STEP_RATE: u32 = 500_000;
#[cfg(not(feature = "long-schedule"))]
pub const MAX_STEP_RATE: u32 = 250_000;

/// Ceiling of every board's acceleration, steps/s². Above it the start of a
/// ramp would need more single-step segments than [`SCHEDULE_SLOTS`] to
/// cover a 2 ms control period; larger register values are clamped to the
/// board's limit ([`PlannerConfig::max_accel`]).
pub const MAX_ACCEL: u64 = 2_000_000;

// No board's limits exceed the ceilings above (the step rate's where the
// ring is long: a short ring's image checks its own board).
const _: () = {
    let mut i = 0;
    while i < Board::ALL.len() {
        assert!(
            !cfg!(feature = "longer-schedule") || Board::ALL[i].max_step_rate() <= MAX_STEP_RATE
        );
        assert!(Board::ALL[i].max_accel() <= MAX_ACCEL);
        i += 1;
    }
};

/// What fitting a segment ([`Planner::fill`]'s per-segment work: a
/// profile evaluation, the quintic fit) counts against a fill's step
/// budget ([`PlannerConfig::with_fill_budget`]): about what expanding
/// that many steps into the ring costs, as the firmware's profile under
/// emulation shows (docs/firmware.md, "Reply latency while stepping").
pub const FIT_COST: u32 = 96;

/// Steps of a constant speed ([`crate::motion::Segment::is_constant`]) one
/// step of a fill's budget buys: the expansion writes each with one store
/// (four a loop round), where a ramp's step takes the forward differences.
/// A part of constant-speed steps then takes about as long as a part of
/// ramp steps, and a cruise needs fewer parts, each with the control
/// call's set-up. A power of two (a shift, no division).
pub const CONSTANT_STEPS_PER_BUDGET: u32 = 4;
const _: () = assert!(CONSTANT_STEPS_PER_BUDGET.is_power_of_two());

/// Most steps one push takes, whatever the budget left: a fill looks
/// whether its caller wants the thread back
/// ([`crate::motion::StepSink::pause_wanted`]) between two pushes, so a
/// caller asking waits for one push at most. As many as a fit counts
/// ([`FIT_COST`]): a push of ramp steps then takes about as long as a fit,
/// the longest wait anyway, and one of constant-speed steps a quarter of
/// that, where a budget's worth of them would take as long as a fit;
/// shorter pushes would cost each push's set-up on a ramp, where a step
/// costs most.
pub const PUSH_STEPS: u32 = FIT_COST;

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
    velocity: u64,
    accel: u64,
    decel: u64,
}

impl Ramp {
    /// Velocity, acceleration and deceleration, 0.1 steps/s and
    /// 0.1 steps/s².
    #[inline]
    pub const fn new(velocity: u64, accel: u64, decel: u64) -> Self {
        Self {
            velocity,
            accel,
            decel,
        }
    }

    #[inline]
    pub const fn velocity(&self) -> u64 {
        self.velocity
    }

    #[inline]
    pub const fn accel(&self) -> u64 {
        self.accel
    }

    #[inline]
    pub const fn decel(&self) -> u64 {
        self.decel
    }
}

impl Ramp {
    /// All three are non-zero: the motion can run (SPEC §8.2 bit 7).
    pub fn runnable(&self) -> bool {
        self.velocity > 0 && self.accel > 0 && self.decel > 0
    }

    /// Clamped to `max_velocity` (0.1 steps/s: PA12 and the board's step
    /// rate, [`PlannerConfig::velocity_cap`]) and `max_accel` (0.1
    /// steps/s², [`PlannerConfig::accel_cap`]).
    pub fn clamped(self, max_velocity: u64, max_accel: u64) -> Self {
        Self {
            velocity: self.velocity.min(max_velocity),
            accel: self.accel.min(max_accel),
            decel: self.decel.min(max_accel),
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
    /// The fill's step budget ran out before the horizon was covered
    /// ([`PlannerConfig::with_fill_budget`]), or its sink asked for the
    /// thread back ([`crate::motion::StepSink::pause_wanted`]); never
    /// without one of them: fill again, with the same or a later `now`,
    /// to go on where it paused.
    Paused,
}

/// Timing of the planner; the glue chooses the tick frequency.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PlannerConfig {
    /// Step timer frequency, Hz: a whole number of MHz (the control clock
    /// in µs converts with one multiplication; the boards use 10 and
    /// 8 MHz), ≥ 1 MHz so that steps at the maximum rate are ≥ 5 ticks
    /// apart; sub-µs resolution keeps step times exact.
    tick_hz: u32,
    /// How far ahead of `now` the schedule is filled. Must exceed the
    /// control period; it is also the latency of a change of goal (what
    /// is pushed to the interrupt stays; a segment is fitted whole but
    /// pushed whole, and a new goal takes back its steps after the
    /// horizon).
    horizon_us: u32,
    /// Longest segment, µs (at most 2^22 ticks: the fit's numbers stay in
    /// 64 bits). Long segments cost the planner less per step; they do not
    /// delay a change of goal.
    max_segment_us: u32,
    /// Highest step rate, steps/s, and acceleration, steps/s², the board's
    /// step engine keeps on time ([`Board::max_step_rate`],
    /// [`Board::max_accel`]; at most [`MAX_STEP_RATE`] / [`MAX_ACCEL`]):
    /// every ramp is clamped to them ([`Ramp::clamped`]).
    max_step_rate: u32,
    max_accel: u64,
    /// Steps one fill may push, a fitted segment counting as
    /// [`FIT_COST`] of them and [`CONSTANT_STEPS_PER_BUDGET`]
    /// constant-speed steps as one, once the queue reaches half the horizon
    /// past `now` (before that a fill never pauses); `u32::MAX`: no limit.
    fill_budget: u32,
}

impl PlannerConfig {
    /// Step timer frequency, Hz: a whole number of MHz (the control clock
    /// in µs converts with one multiplication; the boards use 10 and
    /// 8 MHz), ≥ 1 MHz so that steps at the maximum rate are ≥ 5 ticks
    /// apart; sub-µs resolution keeps step times exact.
    #[inline]
    pub const fn tick_hz(&self) -> u32 {
        self.tick_hz
    }

    /// How far ahead of `now` the schedule is filled. Must exceed the
    /// control period; it is also the latency of a change of goal (what
    /// is pushed to the interrupt stays; a segment is fitted whole but
    /// pushed whole, and a new goal takes back its steps after the
    /// horizon).
    #[inline]
    pub const fn horizon_us(&self) -> u32 {
        self.horizon_us
    }

    /// Longest segment, µs (at most 2^22 ticks: the fit's numbers stay in
    /// 64 bits). Long segments cost the planner less per step; they do not
    /// delay a change of goal.
    #[inline]
    pub const fn max_segment_us(&self) -> u32 {
        self.max_segment_us
    }

    /// Highest step rate, steps/s, and acceleration, steps/s², the board's
    /// step engine keeps on time ([`Board::max_step_rate`],
    /// [`Board::max_accel`]; at most [`MAX_STEP_RATE`] / [`MAX_ACCEL`]):
    /// every ramp is clamped to them ([`Ramp::clamped`]).
    #[inline]
    pub const fn max_step_rate(&self) -> u32 {
        self.max_step_rate
    }

    #[inline]
    pub const fn max_accel(&self) -> u64 {
        self.max_accel
    }

    /// Steps one fill may push ([`PlannerConfig::with_fill_budget`]).
    #[inline]
    pub const fn fill_budget(&self) -> u32 {
        self.fill_budget
    }
}

impl PlannerConfig {
    /// The board's step tick and limits, the default horizon and segment
    /// length: what the firmware runs with on `board`, and what the host
    /// runs for it.
    pub const fn for_board(board: Board) -> Self {
        Self {
            tick_hz: board.step_tick_hz(),
            horizon_us: 3_000,
            max_segment_us: 100_000,
            max_step_rate: board.max_step_rate(),
            max_accel: board.max_accel(),
            fill_budget: u32::MAX,
        }
    }

    /// [`PlannerConfig::max_step_rate`] in 0.1 steps/s (the ramps' unit),
    /// never above the ceiling.
    pub fn velocity_cap(&self) -> u64 {
        u64::from(self.max_step_rate.min(MAX_STEP_RATE)) * 10
    }

    /// [`PlannerConfig::max_accel`] in 0.1 steps/s², never above the
    /// ceiling.
    pub fn accel_cap(&self) -> u64 {
        self.max_accel.min(MAX_ACCEL) * 10
    }

    /// This configuration with another step timer frequency (see
    /// [`Self::tick_hz`]).
    #[inline]
    pub const fn with_tick_hz(self, tick_hz: u32) -> Self {
        Self { tick_hz, ..self }
    }

    /// This configuration with another horizon (see [`Self::horizon_us`]).
    #[inline]
    pub const fn with_horizon_us(self, horizon_us: u32) -> Self {
        Self { horizon_us, ..self }
    }

    /// This configuration with each fill bounded to `steps` pushed steps
    /// (at least 1), a fitted segment counting as [`FIT_COST`] of them
    /// and [`CONSTANT_STEPS_PER_BUDGET`] constant-speed steps as one, so
    /// that one fill holds the caller for a bounded time: a fill that
    /// reaches it returns [`Fill::Paused`] and the caller fills again
    /// (after it has let other work run) until it does not. The parts
    /// push exactly the steps one unbounded fill would have pushed
    /// (unless the interrupt frees ring room or a goal comes in
    /// between). A fill pauses only once the queue reaches half the
    /// horizon past `now`: from rest, and after the queue ran short, the
    /// schedule is first made safe; what runs between the parts must take
    /// less than that. Without it (the default) a fill never pauses.
    #[inline]
    pub const fn with_fill_budget(self, steps: u32) -> Self {
        Self {
            fill_budget: if steps == 0 { 1 } else { steps },
            ..self
        }
    }

    /// This configuration with another longest segment (see
    /// [`Self::max_segment_us`]).
    #[inline]
    pub const fn with_max_segment_us(self, max_segment_us: u32) -> Self {
        Self {
            max_segment_us,
            ..self
        }
    }
}

impl Default for PlannerConfig {
    /// The primary board's ([`PlannerConfig::for_board`]).
    fn default() -> Self {
        Self::for_board(Board::G431)
    }
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
    underruns: u32,
    /// Segments whose first step was already due when they were queued
    /// (the control loop ran late); never expected.
    late_segments: u32,
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
    planned_steps: u64,
    /// Segments fitted since start (wrapping; each is pushed in one or
    /// more parts, [`Planner::segments_pushed`]).
    segments_fitted: u32,
    budget: SegmentBudget,
    pending: Pending,
    /// `horizon_us` in Q32.32 ticks.
    horizon_q: u64,
    /// Half of `horizon_q`: a fill pauses at its budget only once what
    /// is queued reaches this far past `now`.
    lead_q: u64,
    /// A quarter of `horizon_q`: a fill whose sink asks for a pause
    /// ([`crate::motion::StepSink::pause_wanted`]) pauses once what is
    /// queued reaches this far past `now`.
    asked_lead_q: u64,
    /// Steps the current fill may still push (`PlannerConfig::fill_budget`
    /// at its start).
    step_budget: u32,
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
            lead_q: 0,
            asked_lead_q: 0,
            step_budget: u32::MAX,
            cut: None,
            s_end: 0,
            s_end_w: 0,
            c_end: 0,
            s_join: 0,
        };
        p.horizon_q = p.ticks_q(u64::from(cfg.horizon_us));
        // half the horizon: the parts after the pause may be spread over
        // more than a control period by the frames passed their turn
        // between them, and the queue must outlast that
        p.lead_q = p.ticks_q(u64::from(cfg.horizon_us / 2));
        // a quarter for a pause asked for: it comes only while a frame
        // waits, at most once a frame, and what runs in it (the frame's
        // poll) is short beside that; at the top step rate the ring holds
        // little more than the half, which the fill would then have to
        // reach, unpaused, at the start of every control call
        p.asked_lead_q = p.ticks_q(u64::from(cfg.horizon_us / 4));
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
            Some(p) => Some(p.forward()),
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
            Some(p) if p.w_end() == 0 => {
                Some(self.pos + signed(p.forward(), p.steps()? - p.done()))
            }
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
            || self.pending.rest.count() > 0
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

    /// Times the schedule ran dry while the motor was moving (wrapping).
    pub fn underruns(&self) -> u32 {
        self.underruns
    }

    /// Segments whose first step was already due when they were queued
    /// (the control loop ran late; wrapping); never expected.
    pub fn late_segments(&self) -> u32 {
        self.late_segments
    }

    /// Steps queued since start (wrapping; a stop at once drops some of
    /// them unmade): lets a test tell which profile timed a step.
    pub fn planned_steps(&self) -> u64 {
        self.planned_steps
    }

    /// Segments fitted since start (wrapping; each is pushed in one or
    /// more parts, [`Planner::segments_pushed`]).
    pub fn segments_fitted(&self) -> u32 {
        self.segments_fitted
    }

    /// Segments pushed so far (wrapping).
    pub fn segments_pushed(&self) -> u32 {
        self.segments
    }

    /// Sets the position (homing zeroing, SPEC §8.6). Only at rest.
    pub fn rebase_position(&mut self, raw: i64) {
        self.pos = raw;
    }
}
