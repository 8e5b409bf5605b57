//! The object dictionary (SPEC §5) and the legacy map (SPEC §9): entries,
//! access rights, types, ranges, word order — and the values the master
//! writes.
//!
//! Values that live in the drive layer (statusword, mode display, actual
//! position and velocity, error register) are read through [`DriveLayer`];
//! everything the master writes is stored in [`OdValues`] / [`Params`] and
//! handed to the drive layer as [`Config`].

use crate::params::Params;

/// The RW/WO values of the SPEC §5 table as last written by the master.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct OdValues {
    /// 0x6000: 0 = high word first, 1 = low word first.
    pub word_order: u16,
    /// 0x605A quick stop option code (§8.3), ≥ 0.
    pub quick_stop_option: i16,
    /// 0x6040 controlword, as last written.
    pub controlword: u16,
    /// 0x6060 mode of operation, as last written (0 = none yet).
    pub mode: i16,
    /// 0x6081 profile velocity, 0.1 rev/s (signed in velocity mode).
    pub profile_velocity: i32,
    /// 0x6083 acceleration, 0.1 rev/s².
    pub acceleration: u16,
    /// 0x6084 deceleration, 0.1 rev/s².
    pub deceleration: u16,
    /// 0x6085 quick stop deceleration, 0.1 rev/s².
    pub quick_stop_deceleration: u16,
    /// 0x607A target position, steps.
    pub target_position: i32,
    /// 0x607C home offset, steps.
    pub home_offset: i32,
    /// 0x6098 homing method 1..=8 (0 = none).
    pub homing_method: i16,
    /// 0x6099 homing search (fast) speed, 0.1 rev/s.
    pub homing_speed: u32,
    /// 0x609A homing acceleration, 0.1 rev/s².
    pub homing_acceleration: u16,
    /// 0x609B homing zero (slow) speed, 0.1 rev/s.
    pub homing_zero_speed: u32,
}

/// Everything the master configures, as the drive layer sees it.
#[derive(Clone, Copy)]
pub struct Config<'a> {
    pub od: &'a OdValues,
    pub pa: &'a Params,
}

/// What the dictionary needs from the drive layer (implemented by
/// [`crate::drive::Drive`]; tests may use a double).
///
/// After an accepted write has stored all its values, the dispatcher calls
/// [`DriveLayer::values_written`], then [`DriveLayer::mode_written`] if the
/// request wrote 0x6060, then [`DriveLayer::controlword_written`] if it wrote
/// 0x6040 (SPEC §5.2: mode, then controlword, after the other values).
pub trait DriveLayer {
    /// 0x6041 (§8.2).
    fn statusword(&self) -> u16;
    /// 0x6061: the mode in force.
    fn mode_display(&self) -> i16;
    /// 0x6064, steps.
    fn actual_position(&self) -> i32;
    /// 0x606C, r/min.
    fn actual_velocity_rpm(&self) -> i32;
    /// 0x1001 (§8.7).
    fn error_register(&self) -> u16;
    /// Any accepted write stored new values (e.g. 0x6081 while running in
    /// velocity mode ramps to the new speed).
    fn values_written(&mut self, cfg: Config<'_>);
    /// 0x6060 was written with a valid mode (1, 3 or 6).
    fn mode_written(&mut self, mode: i16, cfg: Config<'_>);
    /// 0x6040 was written.
    fn controlword_written(&mut self, controlword: u16, cfg: Config<'_>);
}
