//! Closed loop (SPEC §8.8): encoder feedback and the following-error check.
//!
//! Sans-IO like the rest of the core: the glue reads the encoder timer's
//! counter and passes it in with the time since the last control period;
//! what comes out is the measured position in steps and whether the drive
//! must fault. With no encoder or with the window off the drive stays open
//! loop.
//!
//! Per control period: [`Encoder::update`] (16-bit counter → running count)
//! → [`CountsToSteps::steps`] (PA17 counts per revolution → PA10 steps) →
//! [`FollowingErrorMonitor::update`] (commanded − measured against 0x6065 /
//! 0x6066).

mod encoder;
mod following_error;

pub use encoder::{CountsToSteps, Encoder, COUNTS_PER_REV_MIN};
pub use following_error::{FollowingErrorMonitor, FollowingState, WINDOW_OFF};
