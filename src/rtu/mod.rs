//! Modbus-RTU on the wire: CRC, character timing and frame assembly (SPEC §1).

mod assembler;
mod crc16;
mod driver_enable;
mod timing;

pub use assembler::{FrameAssembler, RxEvent, RxFlags};
pub use crc16::{crc16, with_crc};
pub use driver_enable::{DriverEnable, DEFAULT_DE_BITS, MAX_DE_BITS};
pub use timing::{CharFormat, FrameTiming, LineConfig};

/// Largest RTU frame (address + PDU of 253 + CRC).
pub const MAX_FRAME: usize = 256;
/// Shortest frame that is examined at all (address, function, CRC).
pub const MIN_FRAME: usize = 4;
