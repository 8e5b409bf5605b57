//! The request PDUs this slave serves (SPEC §4): function codes and
//! quantity limits.

/// Function codes (§4).
pub mod function {
    pub const READ_HOLDING_REGISTERS: u8 = 0x03;
    pub const WRITE_SINGLE_REGISTER: u8 = 0x06;
    pub const DIAGNOSTICS: u8 = 0x08;
    pub const WRITE_MULTIPLE_REGISTERS: u8 = 0x10;
    pub const ENCAPSULATED_INTERFACE: u8 = 0x2B;
}

/// Largest quantity of a 0x03 read (§4).
pub const MAX_READ_QUANTITY: u16 = 125;
/// Largest quantity of a 0x10 write (§4).
pub const MAX_WRITE_QUANTITY: u16 = 123;
