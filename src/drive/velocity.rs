//! Velocity mode (SPEC §8.5): the run or stop the profile velocity asks
//! for.

use super::Drive;
use crate::dictionary::OdValues;
use crate::motion::Goal;

impl Drive {
    pub(super) fn velocity_goal(&mut self, od: &OdValues) -> Goal {
        let ramp = self.s.profile_ramp(od);
        let v = od.profile_velocity();
        let forward = v > 0;
        let blocked =
            (forward && self.switches.ccw_limit()) || (!forward && self.switches.cw_limit());
        if v == 0 || blocked || !ramp.runnable() {
            if v != 0 && (blocked || !ramp.runnable()) {
                self.warning = true;
            }
            let decel = if ramp.decel() > 0 {
                ramp.decel()
            } else {
                self.s.quick_stop_decel(od)
            };
            return Goal::Stop { decel };
        }
        self.warning = false;
        Goal::Run { forward, ramp }
    }
}
