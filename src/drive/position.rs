//! Position mode (SPEC §8.4): set-points, their one-slot buffer, relative
//! targets and blended moves.

use super::homing::HomingState;
use super::{cw, Drive, DriveEvent};
use crate::dictionary::OdValues;
use crate::motion::profile::isqrt;
use crate::motion::{Goal, Ramp};

/// One latched position set-point (SPEC §8.4).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct SetPoint {
    /// Target in user steps (0x6064's scale).
    pub(super) target: i64,
    pub(super) ramp: Ramp,
    /// Bit 9 when it was latched: the move before it does not stop.
    pub(super) blend: bool,
}

impl Drive {
    /// Base of a relative set-point (SPEC §8.4 bit 6: "relative to the
    /// previous target"). Without a previous target in this mode (after
    /// enabling, homing or a mode change) it is the position at which the
    /// motor comes to rest: where it is when at rest, or the end of the
    /// stop in progress (the one a mode change started), so a set-point
    /// latched during that stop counts from the same place as one latched
    /// after it. `None` while a stop at once is being carried out (the
    /// rest position is known one step later): bit 12 reads 0 then.
    pub(super) fn relative_base(&self) -> Option<i64> {
        self.last_target
            .or_else(|| Some(self.planner.rest_position()? - self.offset))
    }

    /// Statusword bit 12 in position mode (SPEC §8.4): the one-slot buffer
    /// is free and the base of a relative set-point is known.
    pub(super) fn set_point_slot_free(&self) -> bool {
        self.buffered.is_none() && self.relative_base().is_some()
    }

    /// Position mode, rising edge of bit 4 (SPEC §8.4).
    pub(super) fn latch_set_point(&mut self, controlword: u16, od: &OdValues) {
        let Some(base) = self.relative_base().filter(|_| self.set_point_slot_free()) else {
            return; // bit 12 = 0: ignored
        };
        let target = if controlword & cw::RELATIVE != 0 {
            base + i64::from(od.target_position())
        } else {
            i64::from(od.target_position())
        };
        let ramp = self.s.profile_ramp(od);
        let current = self.active.map_or(self.user_position(), |a| a.target);
        let towards_limit = (target < current && self.switches.cw_limit())
            || (target > current && self.switches.ccw_limit());
        if i32::try_from(target).is_err() || !ramp.runnable() || towards_limit {
            self.warning = true;
            self.event(DriveEvent::MotionRefused);
            return;
        }
        self.warning = false;
        self.last_target = Some(target);
        let sp = SetPoint {
            target,
            ramp,
            blend: controlword & cw::CHANGE_ON_SET_POINT != 0,
        };
        if controlword & cw::CHANGE_IMMEDIATELY != 0 || self.active.is_none() {
            self.active = Some(sp);
        } else {
            self.buffered = Some(sp);
        }
        self.replan = true;
    }

    /// Forgets the position set-points; a homing run in progress becomes
    /// "interrupted" (status 001).
    pub(super) fn drop_set_points(&mut self) {
        self.active = None;
        self.buffered = None;
        if matches!(
            self.homing,
            HomingState::Searching(_) | HomingState::Offset { .. }
        ) {
            self.homing = HomingState::Interrupted;
        }
    }

    pub(super) fn move_goal(&self, sp: SetPoint) -> Goal {
        let end_velocity = match self.buffered {
            Some(next) if next.blend => blend_velocity(sp, next, self.planner.heading()),
            _ => 0,
        };
        Goal::Move {
            target: sp.target + self.offset,
            ramp: sp.ramp,
            end_velocity,
        }
    }
}

/// Speed at which a blended move passes its target (SPEC §8.4 bit 9): the
/// slower of the two moves' speeds, and no faster than the next move can
/// stop from within its distance; 0 if the next move turns back
/// (`heading`: the direction the motor is going).
fn blend_velocity(sp: SetPoint, next: SetPoint, heading: Option<bool>) -> u64 {
    let dist = next.target - sp.target;
    if dist == 0 || heading != Some(dist > 0) {
        return 0;
    }
    let v = sp.ramp.velocity().min(next.ramp.velocity());
    // v² ≤ 2·d·s in 0.1 units: V² ≤ 20·D·s
    let limit = isqrt(20 * u128::from(next.ramp.decel()) * u128::from(dist.unsigned_abs()));
    v.min(limit.min(u128::from(u64::MAX)) as u64)
}
