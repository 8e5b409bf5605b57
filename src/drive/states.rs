//! The power state machine (SPEC §8.1): controlword transitions, faults,
//! quick stop, and the statusword the states and modes show (SPEC §8.2).

use super::homing::HomingState;
use super::{cw, sw, Drive, DriveEvent, FaultCause, PowerState};
use super::{MODE_HOMING, MODE_POSITION, MODE_VELOCITY};
use crate::dictionary::OdValues;
use crate::motion::HomingError;

impl Drive {
    pub(super) fn enter_fault(&mut self, cause: FaultCause, od: &OdValues) {
        self.fault = Some(cause);
        self.error_register |= cause.error_register_bit();
        self.event(DriveEvent::Fault(cause));
        if matches!(
            self.homing,
            HomingState::Searching(_) | HomingState::Offset { .. }
        ) {
            self.homing = HomingState::Failed;
            self.event(DriveEvent::HomingFailed(HomingError::Fault));
        }
        self.active = None;
        self.buffered = None;
        if self.state.moving_allowed() {
            // Fault reaction: the quick stop ramp, or at once without one.
            self.set_state(PowerState::FaultReactionActive);
            self.stop_with(self.s.quick_stop_decel(od));
        } else {
            self.set_state(PowerState::Fault);
            self.flush = true;
        }
    }

    /// Leaves the motion states: stop output at once, forget set-points
    /// (SPEC §8.1).
    pub(super) fn abort_motion(&mut self) {
        self.flush = true;
        self.replan = false;
        self.enable_after_stop = false;
        self.drop_set_points();
    }

    pub(super) fn quick_stop(&mut self, od: &OdValues) {
        self.set_state(PowerState::QuickStopActive);
        self.drop_set_points();
        let decel = match od.quick_stop_option() {
            1 => self.s.decel(od),
            2 => self.s.quick_stop_decel(od),
            _ => 0, // 0, 3..=32767: at once
        };
        self.stop_with(decel);
    }

    /// Statusword bits 10, 12 and 13 for the mode shown in 0x6061 (SPEC
    /// §8.2, §8.4–§8.6), in every power state: outside operation enabled
    /// the mode has no set-point and no search running, so the bits tell
    /// the same story as at rest in operation enabled (position: slot free,
    /// target reached once at rest; velocity: speed 0 once at rest; homing:
    /// 001 not started / interrupted, and done or error persist).
    pub(super) fn mode_bits(&self) -> u16 {
        let at_rest = self.at_rest;
        match self.mode {
            MODE_POSITION => {
                let mut b = 0;
                if self.set_point_slot_free() {
                    b |= sw::BIT12;
                }
                let reached = if self.halted {
                    at_rest
                } else {
                    self.active.is_none() && self.buffered.is_none() && at_rest
                };
                if reached {
                    b |= sw::TARGET_REACHED;
                }
                b
            }
            MODE_VELOCITY => {
                let mut b = 0;
                if at_rest {
                    b |= sw::BIT12;
                }
                if self.ramping {
                    b |= sw::BIT13;
                }
                let target = if self.halted || self.state != PowerState::OperationEnabled {
                    0
                } else {
                    i64::from(self.s.profile_velocity)
                };
                let reached = if target == 0 {
                    at_rest
                } else {
                    self.running && !self.ramping && (self.velocity > 0) == (target > 0)
                };
                if reached {
                    b |= sw::TARGET_REACHED;
                }
                b
            }
            MODE_HOMING => match self.homing {
                HomingState::NotStarted | HomingState::Interrupted => sw::TARGET_REACHED,
                HomingState::Searching(_) => {
                    if self.halted && at_rest {
                        sw::TARGET_REACHED
                    } else {
                        0
                    }
                }
                HomingState::Offset { .. } => sw::BIT12,
                HomingState::Done => sw::BIT12 | sw::TARGET_REACHED,
                HomingState::Failed => {
                    if at_rest {
                        sw::BIT13 | sw::TARGET_REACHED
                    } else {
                        sw::BIT13
                    }
                }
            },
            _ => 0,
        }
    }

    /// The statusword (SPEC §8.2): the state's bits, the flags and the
    /// mode's bits 10, 12 and 13.
    pub(super) fn status(&self) -> u16 {
        let mut w = self.state.status_bits();
        if self.warning {
            w |= sw::WARNING;
        }
        if self.halted && self.state == PowerState::OperationEnabled {
            w |= sw::HALT;
        }
        if self.running {
            w |= sw::RUNNING;
        }
        w |= self.mode_bits();
        if self.following_error_latched() {
            w |= sw::BIT13;
        }
        if self.switches.home() {
            w |= sw::HOME_SWITCH;
        }
        if self.switches.cw_limit() {
            w |= sw::CW_LIMIT;
        }
        if self.switches.ccw_limit() {
            w |= sw::CCW_LIMIT;
        }
        w
    }

    /// A controlword write (SPEC §8.1): the transition it asks for, halt,
    /// and the mode's new set-point bit.
    pub(super) fn apply_controlword(&mut self, controlword: u16, od: &OdValues) {
        use PowerState::*;
        let prev = self.controlword;
        self.controlword = controlword;
        let rising = |bit: u16| controlword & bit != 0 && prev & bit == 0;

        match self.state {
            Fault => {
                // §8.1: fault reset on the rising edge of bit 7, only if the
                // cause is gone (a frame arrived: communication is back).
                let cause_gone = match self.fault {
                    Some(FaultCause::BothLimits) => {
                        !(self.switches.cw_limit() && self.switches.ccw_limit())
                    }
                    _ => true,
                };
                if rising(cw::FAULT_RESET) && cause_gone {
                    self.fault = None;
                    self.reset_following_error();
                    self.error_register = 0;
                    self.warning = false;
                    self.set_state(SwitchOnDisabled);
                }
                return;
            }
            FaultReactionActive => return,
            _ => {}
        }

        let (on, voltage, qs, enable) = (
            controlword & cw::SWITCH_ON != 0,
            controlword & cw::ENABLE_VOLTAGE != 0,
            controlword & cw::QUICK_STOP != 0,
            controlword & cw::ENABLE_OPERATION != 0,
        );
        let was = self.state;
        let next = if !voltage {
            if on {
                ReadyToSwitchOn
            } else {
                SwitchOnDisabled
            }
        } else if !qs {
            match was {
                OperationEnabled | QuickStopActive => QuickStopActive,
                _ if on => SwitchedOn,
                _ => SwitchOnDisabled,
            }
        } else if !on {
            ReadyToSwitchOn
        } else if !enable {
            SwitchedOn
        } else {
            OperationEnabled
        };

        match (was, next) {
            (OperationEnabled, QuickStopActive) => {
                self.quick_stop(od);
                return;
            }
            (QuickStopActive, OperationEnabled) => {
                // §8.1: back once the stop has finished (after_motion)
                self.enable_after_stop = true;
                self.halted = controlword & cw::HALT != 0;
                return;
            }
            (QuickStopActive, QuickStopActive) => return,
            (OperationEnabled | QuickStopActive, _) if next != OperationEnabled => {
                self.abort_motion();
            }
            _ => {}
        }
        self.set_state(next);
        if next != OperationEnabled {
            self.halted = false;
            return;
        }
        if was != OperationEnabled {
            self.frame_seen = true;
            self.last_target = None;
            self.take_measured_position();
        }

        // Operation enabled: halt and the mode bits.
        let halted = controlword & cw::HALT != 0;
        if halted != self.halted || was != OperationEnabled {
            self.halted = halted;
            self.replan = true;
        }
        match self.mode {
            MODE_POSITION if rising(cw::NEW_SET_POINT) => self.latch_set_point(controlword, od),
            MODE_HOMING if rising(cw::NEW_SET_POINT) => self.start_homing(od),
            _ => {}
        }
    }
}
