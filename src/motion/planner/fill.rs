//! The control call's fill: plans and pushes segments until the horizon
//! is covered or the ring is full (or, with a fill budget, in parts).

use super::segment::Pushed;
use super::{Fill, Goal, Planner, FIT_COST};
use crate::motion::{StepSchedule, StepSink};

impl Planner {
    /// Converts µs of the control clock to Q32.32 ticks (wrapping): one
    /// multiplication, the tick being a whole number of MHz
    /// ([`PlannerConfig::tick_hz`](super::PlannerConfig::tick_hz)).
    pub(super) fn ticks_q(&self, us: u64) -> u64 {
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
        self.fill_with(now_us, sched, &mut ())
    }

    /// [`Planner::fill`], telling `sink` of every push (the simulation's
    /// exact step times, [`StepSink`]).
    #[inline]
    pub fn fill_with<S: StepSink>(
        &mut self,
        now_us: u64,
        sched: &StepSchedule,
        sink: &mut S,
    ) -> Fill {
        let now = self.ticks_q(now_us);
        self.now = now;
        if self.covered && self.horizon_covered(now) && (sched.is_running() || !sched.is_empty()) {
            return Fill::Full;
        }
        self.step_budget = self.cfg.fill_budget;
        let fill = self.fill_from(sched, now, sink);
        self.covered = fill == Fill::Full && self.cut.is_none() && self.more_to_plan();
        fill
    }

    /// What is queued reaches `now` + the horizon.
    #[inline(always)]
    pub(super) fn horizon_covered(&self, now: u64) -> bool {
        self.t_isr.wrapping_sub(now) as i64 >= self.horizon_q as i64
    }

    /// What is queued reaches half the horizon past `now`: from here
    /// on a fill may pause at its budget ([`PlannerConfig::with_fill_budget`](super::PlannerConfig::with_fill_budget)).
    #[inline(always)]
    fn lead_covered(&self, now: u64) -> bool {
        self.t_isr.wrapping_sub(now) as i64 >= self.lead_q as i64
    }

    /// What is queued reaches a quarter of the horizon past `now`: from
    /// here on a fill may pause when its sink asks
    /// ([`crate::motion::StepSink::pause_wanted`]).
    #[inline(always)]
    fn asked_lead_covered(&self, now: u64) -> bool {
        self.t_isr.wrapping_sub(now) as i64 >= self.asked_lead_q as i64
    }

    /// Not waiting for a stop at once, and steps left to push or to plan.
    #[inline(always)]
    pub(super) fn more_to_plan(&self) -> bool {
        !self.flushing
            && (self.pending.rest.count() > 0
                || self.profile.as_ref().is_some_and(|p| p.remaining() != 0))
    }

    /// [`Planner::fill`] past its first check. `sched` before `now`: on a
    /// Cortex-M the `u64` takes an even register pair (r2:r3) and `sched`
    /// the r1 it would leave empty, so the sink (nothing, in the firmware)
    /// is the only argument passed on the stack.
    #[inline(never)]
    pub(super) fn fill_from<S: StepSink>(
        &mut self,
        sched: &StepSchedule,
        now: u64,
        sink: &mut S,
    ) -> Fill {
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
            let braking = sched.limit_brake().is_some_and(|b| !b.done());
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
            if self.w > 0 && (self.profile.is_some() || self.pending.rest.count() > 0) {
                self.underruns = self.underruns.wrapping_add(1);
            }
            if self.pending.rest.count() > 0 {
                // ran dry inside a segment (never expected): its rest
                // and what follows move later, to now
                let dt = now.wrapping_sub(self.t_isr);
                // (a cut would find its steps by the old times: none)
                self.pending.start.clear_steps();
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
        let fresh = self.step_budget;
        loop {
            if self.pending.rest.count() > 0 {
                if self.step_budget != fresh && sink.pause_wanted() && self.asked_lead_covered(now)
                {
                    return Fill::Paused;
                }
                if self.step_budget == 0 {
                    if self.lead_covered(now) {
                        return Fill::Paused;
                    }
                    // the queue is short: on, a budget at a time, so
                    // that the fill pauses soon after it is not
                    self.step_budget = self.cfg.fill_budget;
                }
                if self.push_pending(sched, sink, self.step_budget) == Pushed::Full {
                    return Fill::Full;
                }
                // (a push its budget or its length stopped is looked at
                // above)
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
            // a fit is the first thing a fill may always do: each part
            // makes progress, whatever the budget
            if self.step_budget != fresh
                && (self.step_budget < FIT_COST && self.lead_covered(now)
                    || sink.pause_wanted() && self.asked_lead_covered(now))
            {
                return Fill::Paused;
            }
            self.step_budget = self.step_budget.saturating_sub(FIT_COST);
            self.emit();
        }
    }
}
