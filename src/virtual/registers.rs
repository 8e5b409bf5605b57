//! Names, units and ranges in words of the drive's registers, for the
//! page, the bus scan and the parameter files. The one place host tools
//! read them from: when the register description moves (one table per
//! kind), only this module changes.

pub use modbus_drive::dictionary::{pa_entries, position, DataType, TABLE};
pub use modbus_drive::params::{PaDef, PA, PA_COUNT};

/// PA0's legacy address (SPEC §9).
pub const PA_BASE: u16 = 0x0064;
/// The PA holding the firmware version (SPEC §7).
pub const PA_FIRMWARE: usize = 2;
/// Slave address, baud and format PAs (SPEC §7).
pub const PA_ADDRESS: usize = 51;
pub const PA_BAUD: usize = 52;
pub const PA_FORMAT: usize = 53;

/// The bauds of PA52, by value, as the drive's line takes them.
pub fn bauds() -> Vec<u32> {
    (0..)
        .map_while(modbus_drive::rtu::LineConfig::baud_from_pa52)
        .collect()
}
/// The character formats of PA53, by value.
pub const FORMATS: [&str; 4] = ["8N1", "8E1", "8O1", "8N2"];

/// Range, default and access of PA `n`.
pub fn pa_def(n: usize) -> Option<PaDef> {
    PA.get(n).copied()
}

/// Unit and range in words of a §5 entry, from the drive's table; a
/// read-only entry takes no write, so its range reads "—".
pub fn od_meta(index: u16) -> (&'static str, String) {
    match TABLE.iter().find(|e| e.index() == index) {
        Some(e) if e.access().writable() => (e.unit(), e.range().to_string()),
        Some(e) => (e.unit(), "—".to_string()),
        None => ("", String::new()),
    }
}

/// Name and unit of PA `n` ("reserved" for an unassigned one), from the
/// drive's table.
pub fn pa_meta(n: usize) -> (&'static str, &'static str) {
    pa_entries()
        .nth(n)
        .map_or(("reserved", ""), |p| (p.name(), p.unit()))
}
