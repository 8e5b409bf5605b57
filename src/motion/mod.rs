//! Trapezoid planner, step schedule and homing sequencer (SPEC §8.4–§8.6).
//!
//! Follow one set-point: [`planner::Planner`] turns goals (move to a
//! position, run at a velocity, stop) into [`profile::Profile`]s, times
//! their steps exactly and compresses the times into [`schedule::Segment`]s;
//! the shared [`schedule::StepSchedule`] expands them into per-step timer
//! delays, which the step-timer interrupt's [`schedule::StepSource`] pops.
//! `sim::SimAxis` (feature `sim`) plays the interrupt and the motor.

pub mod burst;
pub mod homing;
pub mod planner;
pub mod profile;
pub mod schedule;
// a test double: out of the firmware, which needs none of it; it keeps the
// exact step times itself (module docs of `schedule`)
#[cfg(feature = "sim")]
pub mod sim;

pub use homing::{Homing, HomingError, HomingMethod, HomingStep};
pub use planner::{
    Fill, Goal, Planner, PlannerConfig, Ramp, CONSTANT_STEPS_PER_BUDGET, FIT_COST, MAX_ACCEL,
    MAX_STEP_RATE, PUSH_STEPS, SCHEDULE_SLOTS,
};
pub use schedule::{
    LimitBrake, NextStep, PushedSteps, Segment, StepSchedule, StepSink, StepSource, SCHEDULE_STEPS,
};

/// Logical switch states, after the polarity of PA13 (true = active).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Switches {
    /// CW limit: the negative ("left") end of travel (SPEC §8.6).
    cw_limit: bool,
    /// CCW limit: the positive ("right") end.
    ccw_limit: bool,
    home: bool,
}

impl Switches {
    /// The logical states (true = active).
    #[inline]
    pub const fn new(cw_limit: bool, ccw_limit: bool, home: bool) -> Self {
        Self {
            cw_limit,
            ccw_limit,
            home,
        }
    }

    /// CW limit: the negative ("left") end of travel (SPEC §8.6).
    #[inline]
    pub const fn cw_limit(&self) -> bool {
        self.cw_limit
    }

    /// CCW limit: the positive ("right") end.
    #[inline]
    pub const fn ccw_limit(&self) -> bool {
        self.ccw_limit
    }

    #[inline]
    pub const fn home(&self) -> bool {
        self.home
    }
}

/// Where each switch's current state began, latched by glue whose control
/// calls come later than the switch edges (SPEC §8.6: "the origin is the
/// position at which the deciding switch edge was seen (latched at that
/// step)"). Positions are raw step counts as [`StepSchedule::position`]
/// reads them (wrapping `i32`); `None` = not latched (the drive then takes
/// the position at the control call, as for glue that calls
/// [`crate::device::Device::control`] at the edge's step). Only homing uses
/// them, and only an edge on its current search leg
/// ([`Homing::update`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SwitchEdges {
    cw_limit: Option<i32>,
    ccw_limit: Option<i32>,
    home: Option<i32>,
}

impl SwitchEdges {
    /// Where each switch's current state began (`None`: not latched).
    #[inline]
    pub const fn new(cw_limit: Option<i32>, ccw_limit: Option<i32>, home: Option<i32>) -> Self {
        Self {
            cw_limit,
            ccw_limit,
            home,
        }
    }

    #[inline]
    pub const fn cw_limit(&self) -> Option<i32> {
        self.cw_limit
    }

    #[inline]
    pub const fn ccw_limit(&self) -> Option<i32> {
        self.ccw_limit
    }

    #[inline]
    pub const fn home(&self) -> Option<i32> {
        self.home
    }
}
