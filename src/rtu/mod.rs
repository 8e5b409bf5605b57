//! Modbus-RTU on the wire: CRC, character timing, frame assembly (SPEC §1),
//! request PDUs and exception codes (SPEC §4, §5.2). The lowest layer: it
//! imports nothing else of the crate.

mod assembler;
mod crc16;
mod driver_enable;
mod exception;
pub mod pdu;
mod timing;

pub use assembler::{FrameAssembler, RxEvent, RxFlags};
pub use crc16::{crc16, with_crc};
pub use driver_enable::{DriverEnable, DEFAULT_DE_BITS, MAX_DE_BITS};
pub use exception::Exception;
pub use timing::{CharFormat, FrameTiming, LineConfig};

/// Largest RTU frame (address + PDU of 253 + CRC).
pub const MAX_FRAME: usize = 256;
/// Shortest frame that is examined at all (address, function, CRC).
pub const MIN_FRAME: usize = 4;
