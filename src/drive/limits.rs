//! Limit switches (SPEC §8.7): the stop towards an active limit, from the
//! control loop and from the step interrupt's limit brake.

use super::{Drive, DriveEvent, MODE_HOMING};
use crate::dictionary::OdValues;
use crate::motion::schedule::brake_rate;
use crate::motion::StepSchedule;

impl Drive {
    /// §8.7: an active limit blocks motion towards it with 0x6085.
    pub(super) fn check_limits(&mut self, od: &OdValues) {
        let heading = self.planner.heading();
        let blocked_cw = self.switches.cw_limit() && heading == Some(false);
        let blocked_ccw = self.switches.ccw_limit() && heading == Some(true);
        if blocked_cw || blocked_ccw {
            if !self.limit_stopping {
                self.limit_stop(blocked_cw);
                self.stop_with(self.s.quick_stop_decel(od));
            }
        } else if heading.is_none() {
            self.limit_stopping = false;
        }
    }

    /// Motion towards a limit is being stopped: the set-points go, the
    /// warning and the event are raised (§8.7).
    pub(super) fn limit_stop(&mut self, cw: bool) {
        self.limit_stopping = true;
        self.warning = true;
        self.active = None;
        self.buffered = None;
        self.event(DriveEvent::LimitStop { cw });
    }

    /// §8.7: the step interrupt brakes at a limit with 0x6085 on
    /// its own (`motion::schedule`, "Limit brake"). Armed outside homing
    /// (§8.6: there the sequencer decides at the limits); once it has
    /// engaged, the drive reports the stop and the planner forgets its plan
    /// and takes the position back when the brake is over.
    pub(super) fn limit_brake(&mut self, sched: &StepSchedule, od: &OdValues) {
        let tick_hz = self.planner.config().tick_hz();
        sched.set_brake_rate(
            (self.mode != MODE_HOMING).then(|| brake_rate(self.s.quick_stop_decel(od), tick_hz)),
        );
        match sched.limit_brake() {
            Some(b) if !self.limit_braked => {
                self.limit_braked = true;
                // the control loop may have seen the limit first (a call at
                // the edge step, before the interrupt's next step): one stop
                if !self.limit_stopping {
                    self.limit_stop(!b.forward());
                }
                self.planner.stop_at_once(sched);
            }
            Some(_) => {}
            None => self.limit_braked = false,
        }
    }
}
