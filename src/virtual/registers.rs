//! Names, units and ranges in words of the drive's registers, for the
//! page, the bus scan and the parameter files. The one place host tools
//! read them from: when the register description moves (one table per
//! kind), only this module changes.

pub use modbus_drive::dictionary::{position, DataType, TABLE};
pub use modbus_drive::params::{PaDef, PA, PA_COUNT};

/// PA0's legacy address (SPEC §9).
pub const PA_BASE: u16 = 0x0064;
/// The PA holding the firmware version (SPEC §7).
pub const PA_FIRMWARE: usize = 2;
/// Slave address, baud and format PAs (SPEC §7).
pub const PA_ADDRESS: usize = 51;
pub const PA_BAUD: usize = 52;
pub const PA_FORMAT: usize = 53;

/// The bauds of PA52, by value.
pub const BAUDS: [u32; 5] = [9600, 19200, 38400, 57600, 115200];
/// The character formats of PA53, by value.
pub const FORMATS: [&str; 4] = ["8N1", "8E1", "8O1", "8N2"];

/// Range, default and access of PA `n`.
pub fn pa_def(n: usize) -> Option<PaDef> {
    PA.get(n).copied()
}

/// Unit and range in words of a §5 entry (SPEC §5, §8).
pub fn od_meta(index: u16) -> (&'static str, &'static str) {
    match index {
        0x1001 => ("bits", "bit 0 generic, 4 communication, 5 following error"),
        0x6000 => ("", "0 high word first, 1 low word first"),
        0x605A => ("", "0..=32767 (1: 0x6084, 2: 0x6085, else at once)"),
        0x6040 => ("", "0..=0xFFFF"),
        0x6060 => ("", "1 position, 3 velocity, 6 homing"),
        0x6081 => ("0.1 rev/s", "i32 (signed in velocity mode)"),
        0x6083 | 0x6084 | 0x6085 | 0x609A => ("0.1 rev/s²", "0..=65535"),
        0x607A | 0x607C | 0x6064 => ("steps", "i32"),
        0x6098 => ("", "1..=8"),
        0x6099 | 0x609B => ("0.1 rev/s", "0..=100000"),
        0x6041 => ("bits", "§8.2"),
        0x6061 => ("", "1, 3, 6"),
        0x606C => ("r/min", "i32"),
        0x6065 => ("steps", "0xFFFFFFFF = off"),
        0x6066 => ("ms", "0..=65535"),
        0x60F4 => ("steps", "i32"),
        _ => ("", ""),
    }
}

/// Name and unit of an assigned PA (SPEC §7).
pub fn pa_meta(n: usize) -> (&'static str, &'static str) {
    match n {
        2 => ("firmware version", ""),
        10 => ("steps per revolution", "steps"),
        11 => ("direction invert", ""),
        12 => ("maximum speed", "r/min"),
        13 => ("switch polarity (bit 0 CW, 1 CCW, 2 home; 1 = NC)", "bits"),
        14 => ("limit switch enable (bit 0 CW, 1 CCW)", "bits"),
        15 => ("STEP pulse width (firmware)", "0.1 µs"),
        16 => ("DIR set-up time (firmware)", "0.1 µs"),
        17 => ("encoder counts per revolution (0 = none)", "counts"),
        18 => ("encoder direction invert", ""),
        20 => ("communication-loss timeout (0 = off)", "ms"),
        22 => ("brake release delay after power stage on", "ms"),
        23 => ("brake engage time (power stage held)", "ms"),
        51 => ("slave address", ""),
        52 => ("baud (0 9600 … 4 115200)", ""),
        53 => ("format (0 8N1, 1 8E1, 2 8O1, 3 8N2)", ""),
        54 => ("answer frame errors with 9/10", ""),
        55 => ("exception profile (0 vendor, 1 standard)", ""),
        56 => ("minimum response delay", "ms"),
        57 => ("RS-485 DE lead (firmware)", "bit times"),
        58 => ("RS-485 DE tail (firmware)", "bit times"),
        _ => ("reserved", ""),
    }
}
