//! Goals in: a new goal, a stop, a stop at once, and the profile each
//! one starts from the end of what is planned.

use super::{Goal, Planner};
use crate::motion::profile::{slope_of, w_of, Profile};
use crate::motion::StepSchedule;

impl Planner {
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
        self.pending.rest.clear_steps();
        self.pending.pushed = 0;
        self.cut = None;
        self.s_join = 0;
        if sched.is_running() || !sched.is_empty() || sched.limit_brake().is_some() {
            // also after the interrupt's limit brake (motion/schedule/mod.rs): wait
            // for its end, then take the position back and release it
            sched.request_flush();
            self.flushing = true;
        }
    }

    /// Plans `goal` from the end state. False if it cannot run.
    pub(super) fn start(&mut self, goal: Goal) -> bool {
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
    pub(super) fn stop_then(&mut self, sd: u128, goal: Goal) {
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
}
