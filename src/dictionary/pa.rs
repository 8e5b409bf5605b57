//! The PA set: 60 16-bit parameters at legacy addresses 0x0064..=0x009F.

use super::table::Range::{self, Any, OffOr, OneOf, Span as Between};
use crate::closed_loop::COUNTS_PER_REV_MIN;
use crate::rtu::{DriverEnable, DEFAULT_DE_BITS, MAX_DE_BITS};

/// Number of parameters, PA0..=PA59.
pub const PA_COUNT: usize = 60;

/// Range, default and access of one parameter: what the wire and the
/// record check. Name and unit are the host's ([`PaEntry`]), kept apart so
/// that the firmware links no text.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PaDef {
    min: u16,
    max: u16,
    default: u16,
    read_only: bool,
    /// 0 is accepted too ("off"), below `min`.
    off: bool,
}

impl PaDef {
    /// The values a write may carry (SPEC §7).
    pub const fn range(&self) -> Range {
        match (self.off, self.min, self.max) {
            (true, min, max) => OffOr(min as i32, max as i32),
            (false, 0, u16::MAX) => Any,
            (false, min, max) => Between(min as i32, max as i32),
        }
    }
    /// Smallest value accepted.
    pub const fn min(&self) -> u16 {
        if self.off {
            0
        } else {
            self.min
        }
    }
    /// Largest value accepted.
    pub const fn max(&self) -> u16 {
        self.max
    }
    pub const fn default(&self) -> u16 {
        self.default
    }
    pub const fn read_only(&self) -> bool {
        self.read_only
    }
    /// Whether `v` is in range: on the wire (with the access check in
    /// [`Params::valid`]) and at load ([`Params::load`]), one check.
    #[inline(always)]
    pub const fn contains(&self, v: u16) -> bool {
        (self.min <= v && v <= self.max) || (self.off && v == 0)
    }
}

/// One parameter as a host sees it: number, address, name, unit and the
/// [`PaDef`] checks. From [`pa_entries`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PaEntry {
    n: usize,
}

impl PaEntry {
    /// PA number, 0..[`PA_COUNT`].
    pub const fn number(&self) -> usize {
        self.n
    }
    /// Its Modbus address.
    pub const fn address(&self) -> u16 {
        super::PA_BASE + self.n as u16
    }
    /// What it is, in drive terms ("reserved" for an unassigned one).
    pub const fn name(&self) -> &'static str {
        if self.assigned() {
            PA_TEXT[self.n].0
        } else {
            "reserved"
        }
    }
    /// Its unit ("" for codes and flags).
    pub const fn unit(&self) -> &'static str {
        PA_TEXT[self.n].1
    }
    /// Assigned by SPEC §7, not reserved.
    pub const fn assigned(&self) -> bool {
        !PA_TEXT[self.n].0.is_empty()
    }
    /// Range, default and access.
    pub const fn def(&self) -> PaDef {
        PA[self.n]
    }
}

/// Every parameter, PA0 first.
pub fn pa_entries() -> impl Iterator<Item = PaEntry> {
    (0..PA_COUNT).map(|n| PaEntry { n })
}

/// Firmware version reported in PA2 (≥ 7050: the new EE format, SPEC §7).
pub const FIRMWARE_VERSION: u16 = 7060;

/// One line of [`ASSIGNED`].
struct Pa {
    n: usize,
    name: &'static str,
    unit: &'static str,
    range: Range,
    default: u16,
    read_only: bool,
}

const fn rw(n: usize, name: &'static str, unit: &'static str, range: Range, default: u16) -> Pa {
    Pa {
        n,
        name,
        unit,
        range,
        default,
        read_only: false,
    }
}

/// The STEP pulse width at PA15 = 0, ns: long enough for opto-coupled
/// driver inputs, which is why it is the default (200 000 steps/s).
pub const DEFAULT_STEP_PULSE_NS: u32 = 2_500;
/// The longest STEP pulse or DIR set-up PA15 / PA16 may ask for, ns.
pub const MAX_STEP_SHAPE_NS: u32 = 100_000;

const FW: i32 = FIRMWARE_VERSION as i32;
const U16: i32 = u16::MAX as i32;
const DE: i32 = MAX_DE_BITS as i32;

/// The assigned parameters of SPEC §7, one line each: number, name, unit,
/// range, default. Every other number is reserved: any value, default 0.
#[rustfmt::skip]
const ASSIGNED: &[Pa] = &[
    Pa { read_only: true, ..rw(2, "firmware version", "", Between(FW, FW), FIRMWARE_VERSION) },
    rw(10, "steps per revolution", "steps", Between(200, 60000), 10000),
    rw(11, "direction invert", "", Between(0, 1), 0),
    rw(12, "maximum speed", "r/min", Between(1, 6000), 3000),
    rw(13, "switch polarity (bit 0 CW, 1 CCW, 2 home; 1 = NC)", "bits", Between(0, 7), 0),
    rw(14, "limit switch enable (bit 0 CW, 1 CCW)", "bits", Between(0, 3), 3),
    rw(15, "STEP pulse width (0 = 2.5 µs; caps the step rate at 1 / (2 × width))", "0.1 µs", Any, 0),
    rw(16, "DIR set-up time (0 = the board's minimum)", "0.1 µs", Any, 0),
    // 1..COUNTS_PER_REV_MIN: too coarse to check a following error against (SPEC §8.8)
    rw(17, "encoder counts per revolution (0 = none)", "counts",
       OffOr(COUNTS_PER_REV_MIN as i32, U16), 0),
    rw(18, "encoder direction invert", "", Between(0, 1), 0),
    rw(20, "communication-loss timeout (0 = off)", "ms", Between(0, 60000), 0),
    rw(22, "brake release delay after the power stage is on", "ms", Between(0, 2000), 0),
    rw(23, "brake engage time (power stage held)", "ms", Between(0, 2000), 0),
    rw(51, "slave address", "", Between(1, 247), 1),
    rw(52, "baud (0 9600 … 4 115200)", "", Between(0, 4), 4),
    rw(53, "format (0 8N1, 1 8E1, 2 8O1, 3 8N2)", "", Between(0, 3), 0),
    rw(54, "answer frame errors with 9/10", "", Between(0, 1), 1),
    rw(55, "exception profile (0 vendor, 1 standard)", "", Between(0, 1), 0),
    rw(56, "minimum response delay", "ms", Between(0, 100), 0),
    rw(57, "RS-485 DE lead", "bit times", Between(0, DE), DEFAULT_DE_BITS),
    rw(58, "RS-485 DE tail", "bit times", Between(0, DE), DEFAULT_DE_BITS),
];

/// Unassigned parameters: stored and reserved, any value.
const RESERVED: PaDef = PaDef {
    min: 0,
    max: u16::MAX,
    default: 0,
    read_only: false,
    off: false,
};

/// Range, default and access of every parameter, indexed by PA number.
pub const PA: [PaDef; PA_COUNT] = {
    let mut t = [RESERVED; PA_COUNT];
    let mut i = 0;
    while i < ASSIGNED.len() {
        let a = &ASSIGNED[i];
        let (min, max, off) = match a.range {
            Any => (0, U16, false),
            Between(min, max) => (min, max, false),
            OffOr(min, max) => (min, max, true),
            OneOf(_) => panic!("a PA range is a span"),
        };
        assert!(0 <= min && min <= max && max <= U16);
        assert!(
            a.range.contains(a.default as i64),
            "a default out of its range"
        );
        t[a.n] = PaDef {
            min: min as u16,
            max: max as u16,
            default: a.default,
            read_only: a.read_only,
            off,
        };
        i += 1;
    }
    t
};

/// Name and unit of every parameter ("" for a reserved one).
const PA_TEXT: [(&str, &str); PA_COUNT] = {
    let mut t = [("", ""); PA_COUNT];
    let mut i = 0;
    while i < ASSIGNED.len() {
        let a = &ASSIGNED[i];
        assert!(
            t[a.n].0.is_empty() && !a.name.is_empty(),
            "a PA number assigned twice"
        );
        t[a.n] = (a.name, a.unit);
        i += 1;
    }
    t
};

/// PA17: encoder counts per revolution.
const ENCODER_PA: usize = 17;

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
            values[i] = PA[i].default();
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
        !d.read_only && d.contains(v)
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
            } else if d.contains(v) {
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
    /// PA15: STEP pulse width, 0.1 µs (0: [`DEFAULT_STEP_PULSE_NS`]).
    pub fn step_pulse_width(&self) -> u16 {
        self.values[15]
    }
    /// The STEP pulse width PA15 asks for, ns: [`DEFAULT_STEP_PULSE_NS`]
    /// at 0, at most [`MAX_STEP_SHAPE_NS`]. The step output keeps it and
    /// as long low, so it bounds the step rate ([`Params::step_rate_cap`]).
    pub fn step_pulse_ns(&self) -> u32 {
        match self.values[15] {
            0 => DEFAULT_STEP_PULSE_NS,
            v => (u32::from(v) * 100).min(MAX_STEP_SHAPE_NS),
        }
    }
    /// The highest step rate whose period holds the STEP pulse
    /// ([`Params::step_pulse_ns`]) high and as long low, steps/s: the
    /// drive clamps every speed to it as to PA12 (SPEC §8.4).
    pub fn step_rate_cap(&self) -> u32 {
        500_000_000 / self.step_pulse_ns()
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
        if PA[ENCODER_PA].contains(counts) {
            self.values[ENCODER_PA] = counts;
        }
    }
    /// PA55: the standard Modbus exception profile.
    pub fn set_standard_exceptions(&mut self, on: bool) {
        self.values[55] = u16::from(on);
    }
}
