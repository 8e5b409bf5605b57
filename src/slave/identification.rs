//! Function 0x2B / MEI 0x0E, read device identification (SPEC §4; Modbus
//! Application Protocol V1.1b3 §6.21): the basic objects 0..=2 from the
//! strings of 0x1008 / 0x1009 / 0x100A.

use super::{function, Exception, Handled, Reply};
use crate::dictionary::{string_bytes, Identity, Registers};

/// MEI type of read device identification.
const MEI_READ_DEVICE_ID: u8 = 0x0E;
/// Basic identification level, stream and individual access.
const CONFORMITY_LEVEL: u8 = 0x81;
/// Objects 0 VendorName, 1 ProductCode, 2 MajorMinorRevision.
const LAST_BASIC_OBJECT: u8 = 2;

/// Read device ID codes.
const STREAM_BASIC: u8 = 1;
const STREAM_EXTENDED: u8 = 3;
const INDIVIDUAL: u8 = 4;

/// Object `id`'s value: the register string without its NUL padding.
fn object(identity: &Identity, id: u8) -> &'static str {
    match id {
        0 => identity.product(),
        1 => identity.hardware(),
        _ => identity.software(),
    }
}

/// `2B 0E code object` → `2B 0E code 81 00 00 n {id len value}…`.
///
/// Stream codes 2 (regular) and 3 (extended) ask for more than this
/// device's basic level and are answered like code 1, as the standard
/// requires; a stream starting at an unknown object restarts at object 0;
/// individual access (code 4) to an unknown object is exception 2.
pub(super) fn read_device_id<D>(pdu: &[u8], regs: &Registers<'_, D>, out: &mut [u8]) -> Handled {
    let (code, first) = match pdu {
        [_, MEI_READ_DEVICE_ID, code, object] => (*code, *object),
        [_, MEI_READ_DEVICE_ID, ..] | [_] => return Err(Exception::ByteCountMismatch),
        _ => return Err(Exception::IllegalFunction), // other MEI types
    };
    let ids = match code {
        STREAM_BASIC..=STREAM_EXTENDED if first <= LAST_BASIC_OBJECT => first..=LAST_BASIC_OBJECT,
        STREAM_BASIC..=STREAM_EXTENDED => 0..=LAST_BASIC_OBJECT,
        INDIVIDUAL if first <= LAST_BASIC_OBJECT => first..=first,
        INDIVIDUAL => return Err(Exception::IllegalDataAddress),
        _ => return Err(Exception::IllegalDataValue),
    };
    if regs.busy {
        return Err(Exception::Busy); // SPEC §9, after validation (§5.2)
    }
    out[..6].copy_from_slice(&[
        function::ENCAPSULATED_INTERFACE,
        MEI_READ_DEVICE_ID,
        code,
        CONFORMITY_LEVEL,
        0x00, // more follows: everything fits in one reply
        0x00, // next object id
    ]);
    let mut len = 7;
    let mut count = 0u8;
    for id in ids {
        let bytes = string_bytes(object(regs.identity, id));
        let n = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
        out[len] = id;
        out[len + 1] = n as u8;
        out[len + 2..len + 2 + n].copy_from_slice(&bytes[..n]);
        len += 2 + n;
        count += 1;
    }
    out[6] = count;
    Ok(Reply::Pdu(len))
}
