//! The whole drive as the glue sees it: frames in, replies out, time and
//! switch states in, steps out.

use crate::dictionary::OdValues;
use crate::drive::Drive;
use crate::params::Params;

/// One drive on the bus.
pub struct Device {
    pub od: OdValues,
    pub pa: Params,
    pub drive: Drive,
}

impl Device {
    pub fn new() -> Self {
        Self {
            od: OdValues::default(),
            pa: Params::defaults(),
            drive: Drive::new(),
        }
    }
}

impl Default for Device {
    fn default() -> Self {
        Self::new()
    }
}
