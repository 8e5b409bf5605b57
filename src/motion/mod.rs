//! Trapezoid planner, step schedule and homing sequencer (SPEC §8.4–§8.6).
//! Filled by issue 3.
