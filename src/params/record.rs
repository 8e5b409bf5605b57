//! The stored form of one parameter set (SPEC §9 "what is saved"): PA0..PA59
//! and the RW entries of SPEC §5 except 0x607A, in a compact, versioned
//! record with its own length and CRC so that garbage is never loaded.
//!
//! Layout (little endian, [`RECORD_LEN`] bytes):
//!
//! | bytes | field |
//! |---|---|
//! | 0..2 | magic `"PS"` (0x50, 0x53) |
//! | 2 | format version, [`RECORD_VERSION`] |
//! | 3 | number of PA values that follow (60) |
//! | 4..124 | PA0..PA59, u16 each |
//! | 124..154 | 0x6000, 0x605A, 0x6081, 0x6083, 0x6084, 0x6085, 0x607C, 0x6098, 0x6099, 0x609A, 0x609B in their §5 widths |
//! | 154..156 | CRC-16/MODBUS of bytes 0..154 |
//!
//! The write-only 0x6040 / 0x6060 and the target position 0x607A are not
//! saved (SPEC §9); a loaded set leaves them as they are in the working set.

use crate::dictionary::{OdValues, Params, PA_COUNT};
use crate::rtu::crc16;

/// Format version written into every record; a record of another version is
/// not loaded (the store then reports it unreadable and defaults apply).
pub const RECORD_VERSION: u8 = 1;
/// Size of one encoded record.
pub const RECORD_LEN: usize = HEADER_LEN + 2 * PA_COUNT + OD_LEN + 2;

const MAGIC: [u8; 2] = *b"PS";
const HEADER_LEN: usize = 4;
const OD_LEN: usize = 30;

/// Why a record was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RecordError {
    /// Wrong length, magic or PA count.
    Malformed,
    /// A format version this firmware does not know.
    Version(u8),
    /// The CRC does not match.
    Crc,
}

/// One complete parameter set: what EE-Set saves and EE-rd loads.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ParamSet {
    pub pa: Params,
    /// Only the saved fields are meaningful (not 0x6040, 0x6060, 0x607A).
    pub od: OdValues,
}

impl ParamSet {
    /// The factory set (EE-dEF, blank store).
    pub fn defaults() -> Self {
        Self {
            pa: Params::defaults(),
            od: OdValues::default(),
        }
    }

    /// Snapshot of a working set.
    pub fn from_working(pa: &Params, od: &OdValues) -> Self {
        Self {
            pa: pa.clone(),
            od: od.clone(),
        }
    }

    /// Copies this set into a working set: all PA values and the saved OD
    /// fields; 0x6040, 0x6060 and 0x607A keep their working values.
    pub fn apply_to(&self, pa: &mut Params, od: &mut OdValues) {
        *pa = self.pa.clone();
        let keep = (od.controlword, od.mode, od.target_position);
        *od = self.od.clone();
        (od.controlword, od.mode, od.target_position) = keep;
    }

    /// Whether the saved parts of two sets are equal.
    pub fn same_saved_values(&self, other: &Self) -> bool {
        self.encode() == other.encode()
    }

    /// The record bytes.
    pub fn encode(&self) -> [u8; RECORD_LEN] {
        let mut out = [0u8; RECORD_LEN];
        let mut w = Writer {
            buf: &mut out,
            at: 0,
        };
        w.bytes(&MAGIC);
        w.bytes(&[RECORD_VERSION, PA_COUNT as u8]);
        for &v in self.pa.as_array() {
            w.bytes(&v.to_le_bytes());
        }
        let od = &self.od;
        w.bytes(&od.word_order.to_le_bytes());
        w.bytes(&od.quick_stop_option.to_le_bytes());
        w.bytes(&od.profile_velocity.to_le_bytes());
        w.bytes(&od.acceleration.to_le_bytes());
        w.bytes(&od.deceleration.to_le_bytes());
        w.bytes(&od.quick_stop_deceleration.to_le_bytes());
        w.bytes(&od.home_offset.to_le_bytes());
        w.bytes(&od.homing_method.to_le_bytes());
        w.bytes(&od.homing_speed.to_le_bytes());
        w.bytes(&od.homing_acceleration.to_le_bytes());
        w.bytes(&od.homing_zero_speed.to_le_bytes());
        let crc = crc16(&w.buf[..w.at]);
        w.bytes(&crc.to_le_bytes());
        debug_assert_eq!(w.at, RECORD_LEN);
        out
    }

    /// Decodes a record. Values outside their entry's range (a record of an
    /// older firmware with other ranges) are replaced by defaults; the second
    /// result counts them.
    pub fn decode(bytes: &[u8]) -> Result<(Self, usize), RecordError> {
        if bytes.len() != RECORD_LEN || bytes[..2] != MAGIC {
            return Err(RecordError::Malformed);
        }
        if bytes[2] != RECORD_VERSION {
            return Err(RecordError::Version(bytes[2]));
        }
        if usize::from(bytes[3]) != PA_COUNT {
            return Err(RecordError::Malformed);
        }
        let body = RECORD_LEN - 2;
        if crc16(&bytes[..body]) != u16::from_le_bytes([bytes[body], bytes[body + 1]]) {
            return Err(RecordError::Crc);
        }
        let mut r = Reader { buf: bytes, at: 4 };
        let mut raw = [0u16; PA_COUNT];
        for v in raw.iter_mut() {
            *v = r.u16();
        }
        let mut pa = Params::defaults();
        let mut fixed = pa.load(&raw);
        let defaults = OdValues::default();
        let mut od = OdValues {
            word_order: r.u16(),
            quick_stop_option: r.u16() as i16,
            profile_velocity: r.u32() as i32,
            acceleration: r.u16(),
            deceleration: r.u16(),
            quick_stop_deceleration: r.u16(),
            home_offset: r.u32() as i32,
            homing_method: r.u16() as i16,
            homing_speed: r.u32(),
            homing_acceleration: r.u16(),
            homing_zero_speed: r.u32(),
            ..defaults.clone()
        };
        // The §5.2 step-8 ranges of the saved entries with a restricted range.
        if od.word_order > 1 {
            od.word_order = defaults.word_order;
            fixed += 1;
        }
        if od.quick_stop_option < 0 {
            od.quick_stop_option = defaults.quick_stop_option;
            fixed += 1;
        }
        if !(0..=8).contains(&od.homing_method) {
            od.homing_method = defaults.homing_method;
            fixed += 1;
        }
        Ok((Self { pa, od }, fixed))
    }
}

struct Writer<'a> {
    buf: &'a mut [u8; RECORD_LEN],
    at: usize,
}

impl Writer<'_> {
    fn bytes(&mut self, b: &[u8]) {
        self.buf[self.at..self.at + b.len()].copy_from_slice(b);
        self.at += b.len();
    }
}

/// Reads fields of a record whose length was checked.
struct Reader<'a> {
    buf: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn u16(&mut self) -> u16 {
        let v = u16::from_le_bytes([self.buf[self.at], self.buf[self.at + 1]]);
        self.at += 2;
        v
    }
    fn u32(&mut self) -> u32 {
        let lo = u32::from(self.u16());
        lo | u32::from(self.u16()) << 16
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> ParamSet {
        let mut s = ParamSet::defaults();
        s.pa.set_unchecked(10, 3200);
        s.pa.set_unchecked(51, 17);
        s.od.word_order = 1;
        s.od.profile_velocity = -1234;
        s.od.home_offset = i32::MIN;
        s.od.homing_speed = 100_000;
        s.od.homing_zero_speed = u32::MAX;
        s.od.homing_method = 8;
        s
    }

    #[test]
    fn round_trip_keeps_every_saved_field() {
        let s = sample();
        let (d, fixed) = ParamSet::decode(&s.encode()).expect("valid record");
        assert_eq!(fixed, 0);
        assert_eq!(d, s);
    }

    #[test]
    fn unsaved_entries_are_not_stored() {
        // SPEC §9: 0x607A is not saved; 0x6040/0x6060 are WO.
        let mut s = sample();
        s.od.target_position = 200_000;
        s.od.controlword = 0x0F;
        s.od.mode = 1;
        assert_eq!(s.encode(), sample().encode());
        let mut pa = Params::defaults();
        let mut od = OdValues {
            target_position: 5,
            controlword: 6,
            mode: 3,
            ..OdValues::default()
        };
        s.apply_to(&mut pa, &mut od);
        assert_eq!((od.target_position, od.controlword, od.mode), (5, 6, 3));
        assert_eq!(od.profile_velocity, -1234);
        assert_eq!(pa.get(10), 3200);
    }

    #[test]
    fn any_single_bit_flip_is_refused() {
        let good = sample().encode();
        for bit in 0..RECORD_LEN * 8 {
            let mut b = good;
            b[bit / 8] ^= 1 << (bit % 8);
            assert!(ParamSet::decode(&b).is_err(), "bit {bit} flip accepted");
        }
    }

    #[test]
    fn wrong_length_version_and_blank_are_refused() {
        let good = sample().encode();
        assert_eq!(
            ParamSet::decode(&good[..RECORD_LEN - 1]),
            Err(RecordError::Malformed)
        );
        assert_eq!(
            ParamSet::decode(&[0xFF; RECORD_LEN]),
            Err(RecordError::Malformed)
        );
        let mut v2 = good;
        v2[2] = 2;
        assert_eq!(ParamSet::decode(&v2), Err(RecordError::Version(2)));
    }

    #[test]
    fn out_of_range_values_with_a_good_crc_fall_back_to_defaults() {
        let mut s = sample();
        s.pa.set_unchecked(51, 0); // PA51 ∉ 1..=247
        s.pa.set_unchecked(2, 1); // PA2 is read-only: always the firmware's
        s.od.homing_method = 9;
        let (d, fixed) = ParamSet::decode(&s.encode()).expect("crc is good");
        assert_eq!(fixed, 2);
        assert_eq!(d.pa.get(51), 1);
        assert_eq!(d.pa.get(2), crate::dictionary::FIRMWARE_VERSION);
        assert_eq!(d.od.homing_method, 0);
    }
}
