//! CRC-16/MODBUS (SPEC §1): poly 0xA001 reflected, init 0xFFFF, low byte first.

use crc::{Crc, CRC_16_MODBUS};

/// Table-driven (256 entries, 512 bytes of flash).
const MODBUS: Crc<u16> = Crc::<u16>::new(&CRC_16_MODBUS);

// The loop below is the reflected form with no final XOR.
const _: () = assert!(CRC_16_MODBUS.refin && CRC_16_MODBUS.refout && CRC_16_MODBUS.xorout == 0);

/// The crate's table for CRC-16/MODBUS (reflected: one byte per lookup).
static TABLE: [u16; 256] = MODBUS.table()[0];

/// Two bytes per lookup pair: `TABLE_PAIR[i]` is the CRC register after
/// byte `i` and then a zero byte went through [`TABLE`] from 0. The CRC is
/// linear, so a pair `lo, hi` xored into the register costs
/// `TABLE_PAIR[lo'] ^ TABLE[hi']` (slicing by 2; 512 more bytes of flash,
/// feature `crc-pairs`).
#[cfg(feature = "crc-pairs")]
static TABLE_PAIR: [u16; 256] = {
    let mut t = [0u16; 256];
    let mut i = 0;
    while i < 256 {
        let once = TABLE[i];
        t[i] = (once >> 8) ^ TABLE[(once & 0xFF) as usize];
        i += 1;
    }
    t
};

/// CRC of `bytes` as a number; on the wire it goes low byte first.
///
/// The crate's own table, walked two bytes at a time with `crc-pairs` (a
/// last odd byte one at a time): fewer instructions per byte than the
/// one-byte loop or the generic `Crc::checksum` (the QEMU benchmark,
/// `benches/run-qemu.sh`, counts them); every frame is checked and every
/// reply signed, so this is a large part of a frame's cost. Without the
/// feature, one byte at a time. Equal to `MODBUS.checksum` on every length
/// (tested below).
#[inline(always)]
pub fn crc16(bytes: &[u8]) -> u16 {
    let mut crc = CRC_16_MODBUS.init;
    #[cfg(feature = "crc-pairs")]
    let bytes = {
        let mut pairs = bytes.chunks_exact(2);
        for pair in &mut pairs {
            let x = crc ^ u16::from_le_bytes([pair[0], pair[1]]);
            crc = TABLE_PAIR[usize::from(x as u8)] ^ TABLE[usize::from(x >> 8)];
        }
        pairs.remainder()
    };
    for &b in bytes {
        crc = (crc >> 8) ^ TABLE[usize::from(crc as u8 ^ b)];
    }
    crc
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
    fn the_table_loop_equals_the_crate() {
        let mut bytes = [0u8; 300];
        let mut x = 0x1234_5678u32;
        for b in bytes.iter_mut() {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            *b = x as u8;
        }
        for len in 0..bytes.len() {
            assert_eq!(
                crc16(&bytes[..len]),
                MODBUS.checksum(&bytes[..len]),
                "len {len}"
            );
        }
    }

    #[test]
    fn with_crc_appends_low_byte_first() {
        let mut buf = [0x01, 0x86, 0x0B, 0, 0];
        assert_eq!(with_crc(&mut buf, 3), 5);
        assert_eq!(buf, [0x01, 0x86, 0x0B, 0x03, 0xA7]);
    }
}
