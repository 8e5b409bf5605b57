//! The PA set: 60 16-bit parameters at legacy addresses 0x0064..=0x009F.

use crate::rtu::{DriverEnable, DEFAULT_DE_BITS, MAX_DE_BITS};

/// Number of parameters, PA0..=PA59.
pub const PA_COUNT: usize = 60;

/// Range, default and access of one parameter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PaDef {
    pub min: u16,
    pub max: u16,
    pub default: u16,
    pub read_only: bool,
}

const fn rw(min: u16, max: u16, default: u16) -> PaDef {
    PaDef {
        min,
        max,
        default,
        read_only: false,
    }
}

/// Unassigned parameters: stored and reserved, any value.
const RESERVED: PaDef = rw(0, u16::MAX, 0);

/// Firmware version reported in PA2 (≥ 7050: the new EE format, SPEC §7).
pub const FIRMWARE_VERSION: u16 = 7060;

/// The assignment of SPEC §7, indexed by PA number.
pub const PA: [PaDef; PA_COUNT] = {
    let mut t = [RESERVED; PA_COUNT];
    t[2] = PaDef {
        min: FIRMWARE_VERSION,
        max: FIRMWARE_VERSION,
        default: FIRMWARE_VERSION,
        read_only: true,
    };
    t[10] = rw(200, 60000, 10000); // steps per revolution
    t[11] = rw(0, 1, 0); // direction invert
    t[12] = rw(1, 6000, 3000); // maximum speed, r/min
    t[13] = rw(0, 7, 0); // switch polarity bits (1 = normally closed)
    t[14] = rw(0, 3, 3); // limit switch enable bits
                         // encoder counts per revolution after ×4 decoding: 0 = no encoder,
                         // else COUNTS_PER_REV_MIN..=65535 (the gap is checked in `in_range`)
    t[17] = rw(0, u16::MAX, 0);
    t[18] = rw(0, 1, 0); // encoder direction invert
    t[20] = rw(0, 60000, 0); // communication-loss timeout, ms
    t[22] = rw(0, 2000, 0); // brake release delay after the power stage is on, ms
    t[23] = rw(0, 2000, 0); // brake engage time: power stage held after the brake engages, ms
    t[51] = rw(1, 247, 1); // slave address
    t[52] = rw(0, 4, 4); // baud
    t[53] = rw(0, 3, 0); // character format
    t[54] = rw(0, 1, 1); // answer frame errors with 9/10
    t[55] = rw(0, 1, 0); // exception profile
    t[56] = rw(0, 100, 0); // minimum response delay, ms
    t[57] = rw(0, MAX_DE_BITS, DEFAULT_DE_BITS); // RS-485 DE lead, bit times
    t[58] = rw(0, MAX_DE_BITS, DEFAULT_DE_BITS); // RS-485 DE tail, bit times
    t
};

/// PA17 below this (and above 0) is refused: too coarse to check a
/// following error against (SPEC §8.8).
const ENCODER_PA: usize = 17;

/// Whether `v` is in PA`n`'s range (SPEC §7, §8.8): [`PA`]'s bounds, and
/// PA17's gap 1..=99 ([`crate::closed_loop::COUNTS_PER_REV_MIN`]).
#[inline(always)]
fn in_range(n: usize, d: PaDef, v: u16) -> bool {
    const GAP: u16 = crate::closed_loop::COUNTS_PER_REV_MIN - 1;
    // v - 1 < 99 ⇔ 1 ≤ v ≤ 99, one compare
    d.min <= v && v <= d.max && !(n == ENCODER_PA && v.wrapping_sub(1) < GAP)
}

/// The working set of parameters.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Params {
    values: [u16; PA_COUNT],
}

impl Default for Params {
    fn default() -> Self {
        Self::defaults()
    }
}

impl Params {
    pub const fn defaults() -> Self {
        let mut values = [0; PA_COUNT];
        let mut i = 0;
        while i < PA_COUNT {
            values[i] = PA[i].default;
            i += 1;
        }
        Self { values }
    }

    /// Value of PA`n`; `n` < 60.
    pub fn get(&self, n: usize) -> u16 {
        self.values[n]
    }

    /// Whether `v` is in the range of PA`n` (read-only ones accept nothing).
    pub fn valid(n: usize, v: u16) -> bool {
        let d = PA[n];
        !d.read_only && in_range(n, d, v)
    }

    /// Stores `v` in PA`n` without checks: the caller has validated it.
    pub fn set_unchecked(&mut self, n: usize, v: u16) {
        self.values[n] = v;
    }

    pub fn as_array(&self) -> &[u16; PA_COUNT] {
        &self.values
    }

    /// Loads a whole set (from storage), replacing out-of-range values by
    /// defaults and restoring read-only ones. Returns how many were replaced.
    pub fn load(&mut self, values: &[u16; PA_COUNT]) -> usize {
        let mut fixed = 0;
        for (n, &v) in values.iter().enumerate() {
            let d = PA[n];
            if d.read_only {
                self.values[n] = d.default;
            } else if in_range(n, d, v) {
                self.values[n] = v;
            } else {
                self.values[n] = d.default;
                fixed += 1;
            }
        }
        fixed
    }

    pub fn steps_per_rev(&self) -> u16 {
        self.values[10]
    }
    pub fn direction_inverted(&self) -> bool {
        self.values[11] != 0
    }
    pub fn max_speed_rpm(&self) -> u16 {
        self.values[12]
    }
    pub fn switch_polarity(&self) -> u16 {
        self.values[13]
    }
    pub fn limit_enable(&self) -> u16 {
        self.values[14]
    }
    /// PA15: STEP pulse width, 0.1 µs (0: the board's safe minimum).
    pub fn step_pulse_width(&self) -> u16 {
        self.values[15]
    }
    /// PA16: DIR set-up time before the STEP edge, 0.1 µs (0: the board's
    /// safe minimum).
    pub fn dir_setup(&self) -> u16 {
        self.values[16]
    }
    /// PA17: encoder counts per revolution after ×4 decoding (0: no
    /// encoder, open loop).
    pub fn encoder_counts_per_rev(&self) -> u16 {
        self.values[ENCODER_PA]
    }
    /// PA18: encoder direction invert.
    pub fn encoder_inverted(&self) -> bool {
        self.values[18] != 0
    }
    pub fn comm_loss_ms(&self) -> u16 {
        self.values[20]
    }
    /// PA22: brake release delay after the power stage is on, ms.
    pub fn brake_release_delay_ms(&self) -> u16 {
        self.values[22]
    }
    /// PA23: brake engage time, ms (the power stage holds the axis that
    /// long after the brake is told to engage).
    pub fn brake_engage_ms(&self) -> u16 {
        self.values[23]
    }
    pub fn address(&self) -> u8 {
        self.values[51] as u8
    }
    pub fn answer_frame_errors(&self) -> bool {
        self.values[54] != 0
    }
    pub fn standard_exceptions(&self) -> bool {
        self.values[55] != 0
    }
    pub fn response_delay_ms(&self) -> u16 {
        self.values[56]
    }
    /// PA57 / PA58: the RS-485 driver-enable lead and tail.
    pub fn driver_enable(&self) -> DriverEnable {
        DriverEnable::new(self.values[57], self.values[58])
    }
    pub fn line(&self) -> crate::rtu::LineConfig {
        crate::rtu::LineConfig::from_params(self.values[52], self.values[53]).unwrap_or_default()
    }

    // Setters for the glue's own configuration ([`crate::Device::configure`]).

    /// PA51: the slave address.
    pub fn set_address(&mut self, address: u8) {
        self.values[51] = u16::from(address);
    }
    /// PA54: answer frame errors with exception 9/10.
    pub fn set_answer_frame_errors(&mut self, on: bool) {
        self.values[54] = u16::from(on);
    }
    /// PA17: encoder counts per revolution (0: none; else at least
    /// [`crate::closed_loop::COUNTS_PER_REV_MIN`], which this keeps).
    pub fn set_encoder_counts_per_rev(&mut self, counts: u16) {
        if in_range(ENCODER_PA, PA[ENCODER_PA], counts) {
            self.values[ENCODER_PA] = counts;
        }
    }
    /// PA55: the standard Modbus exception profile.
    pub fn set_standard_exceptions(&mut self, on: bool) {
        self.values[55] = u16::from(on);
    }
}
