//! CRC-16/MODBUS (SPEC §1): poly 0xA001 reflected, init 0xFFFF, low byte first.

use crc::{Crc, CRC_16_MODBUS};

/// Table-driven (256 entries, 512 bytes of flash).
const MODBUS: Crc<u16> = Crc::<u16>::new(&CRC_16_MODBUS);

/// CRC of `bytes` as a number; on the wire it goes low byte first.
pub fn crc16(bytes: &[u8]) -> u16 {
    MODBUS.checksum(bytes)
}

/// Appends the CRC (low byte first) to the `len` bytes already in `buf` and
/// returns the new length. `buf` must have two bytes of room.
pub fn with_crc(buf: &mut [u8], len: usize) -> usize {
    let crc = crc16(&buf[..len]);
    buf[len] = crc as u8;
    buf[len + 1] = (crc >> 8) as u8;
    len + 2
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seed_frames_have_the_printed_crc() {
        // SPEC §10: `01 06 60 40 00 01 57 DE`, `01 03 60 7A 00 02 FB D2`.
        assert_eq!(crc16(&[0x01, 0x06, 0x60, 0x40, 0x00, 0x01]), 0xDE57);
        assert_eq!(crc16(&[0x01, 0x03, 0x60, 0x7A, 0x00, 0x02]), 0xD2FB);
        // A whole frame including its CRC checks to zero.
        assert_eq!(crc16(&[0x01, 0x86, 0x0B, 0x03, 0xA7]), 0);
    }

    #[test]
    fn with_crc_appends_low_byte_first() {
        let mut buf = [0x01, 0x86, 0x0B, 0, 0];
        assert_eq!(with_crc(&mut buf, 3), 5);
        assert_eq!(buf, [0x01, 0x86, 0x0B, 0x03, 0xA7]);
    }
}
