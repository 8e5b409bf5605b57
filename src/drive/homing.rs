//! Homing mode (SPEC §8.6): the search, the move to the offset and the
//! goal each phase hands the planner.

use super::{Drive, DriveEvent};
use crate::dictionary::OdValues;
use crate::motion::{Goal, Homing, HomingError, HomingMethod, HomingStep, SwitchEdges};

/// Largest homing speed register value (SPEC §5, §8.6).
const HOMING_SPEED_MAX: u32 = 100_000;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum HomingState {
    NotStarted,
    Interrupted,
    Searching(Homing),
    /// Origin found; moving to origin + 0x607C (raw target).
    Offset {
        target: i64,
    },
    Done,
    Failed,
}

impl Drive {
    pub(super) fn homing_goal(&self, od: &OdValues) -> Option<Goal> {
        let accel = self.s.steps(u32::from(od.homing_acceleration()));
        match self.homing {
            HomingState::Searching(h) => {
                let p = h.phase();
                Some(Goal::Run {
                    forward: !p.left(),
                    ramp: self.s.homing_ramp(od, h.method(), p.slow()),
                })
            }
            HomingState::Offset { target } => {
                let method = HomingMethod::from_register(od.homing_method())?;
                Some(Goal::Move {
                    target,
                    ramp: self.s.homing_ramp(od, method, true),
                    end_velocity: 0,
                })
            }
            _ => Some(Goal::Stop { decel: accel }),
        }
    }

    pub(super) fn run_homing(&mut self, edges: SwitchEdges, od: &OdValues) {
        let HomingState::Searching(mut h) = self.homing else {
            return;
        };
        // Also while halted: an edge passed while braking is still the
        // edge (SPEC §8.6: the origin is where it was seen); the next
        // phase's motion waits for the resume (apply_goal).
        match h.update(self.switches, edges, self.raw_position) {
            HomingStep::Continue => {}
            HomingStep::NextPhase => {
                self.homing = HomingState::Searching(h);
                self.replan = true;
            }
            HomingStep::Origin(origin) => {
                let target = origin + i64::from(od.home_offset());
                self.homing = HomingState::Offset { target };
                self.event(DriveEvent::HomingAttained {
                    origin: origin as i32,
                });
                self.replan = true;
            }
            HomingStep::Failed(e) => {
                self.homing = HomingState::Failed;
                self.event(DriveEvent::HomingFailed(e));
                let accel = self.s.steps(u32::from(od.homing_acceleration()));
                self.stop_with(accel);
            }
        }
        if let HomingState::Searching(_) = self.homing {
            self.homing = HomingState::Searching(h);
        }
    }

    pub(super) fn start_homing(&mut self, od: &OdValues) {
        let error = match HomingMethod::from_register(od.homing_method()) {
            None => Some(HomingError::NoMethod),
            Some(_)
                if od.homing_speed() == 0
                    || od.homing_speed() > HOMING_SPEED_MAX
                    || od.homing_zero_speed() == 0
                    || od.homing_zero_speed() > HOMING_SPEED_MAX
                    || od.homing_acceleration() == 0 =>
            {
                Some(HomingError::BadSpeed)
            }
            Some(method) => {
                self.homing = HomingState::Searching(Homing::start(method, self.switches));
                self.replan = true;
                None
            }
        };
        if let Some(e) = error {
            self.homing = HomingState::Failed;
            self.event(DriveEvent::HomingFailed(e));
        }
    }
}
