//! Power state machine, modes and statusword (SPEC §8). Placeholder until
//! issue 3: reports "switch on disabled" and ignores commands.

use crate::dictionary::{Config, DriveLayer};

/// The drive layer: state machine, modes and the motion it commands.
#[derive(Debug, Default)]
pub struct Drive {}

impl Drive {
    pub fn new() -> Self {
        Self {}
    }
}

impl DriveLayer for Drive {
    fn statusword(&self) -> u16 {
        0x0040 // switch on disabled
    }
    fn mode_display(&self) -> i16 {
        0
    }
    fn actual_position(&self) -> i32 {
        0
    }
    fn actual_velocity_rpm(&self) -> i32 {
        0
    }
    fn error_register(&self) -> u16 {
        0
    }
    fn values_written(&mut self, _cfg: Config<'_>) {}
    fn mode_written(&mut self, _mode: i16, _cfg: Config<'_>) {}
    fn controlword_written(&mut self, _controlword: u16, _cfg: Config<'_>) {}
}
