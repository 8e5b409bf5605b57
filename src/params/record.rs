//! The stored form of one parameter set (SPEC §9 "what is saved"): PA0..PA59
//! and the saved entries of SPEC §5, in a compact, versioned record with its
//! own length and CRC so that garbage is never loaded.
//!
//! Layout (little endian):
//!
//! | bytes | field |
//! |---|---|
//! | 0..2 | magic `"PS"` (0x50, 0x53) |
//! | 2 | format version, [`RECORD_VERSION`] |
//! | 3 | number of PA values that follow (60) |
//! | 4..124 | PA0..PA59, u16 each |
//! | 124.. | the saved entries of [`crate::dictionary::TABLE`] in record-slot order ([`SAVED`]), each in its §5 width |
//! | last 2 | CRC-16/MODBUS of the bytes before it |
//!
//! Which entries a version holds is [`LAYOUTS`]: a version holds the
//! slots below its count, so a newer firmware loads an older record with
//! the later entries at their defaults and an update keeps the saved set.
//! A new saved entry takes the next slot and a new line in [`LAYOUTS`].
//! The generated table (docs/generated/registers.md) lists the slots.
//!
//! The entries without a slot (0x6040, 0x6060, 0x607A: SPEC §9) are not
//! saved; a loaded set leaves them as they are in the working set.

use crate::dictionary::{OdValues, Params, PA_COUNT, SAVED, SAVED_COUNT};
use crate::rtu::crc16;

/// The record versions this firmware writes (the last) and loads: each
/// with the number of saved entries it holds (slots `0..n`). Version 1 is
/// the set before the closed loop (no 0x6065 / 0x6066).
pub const LAYOUTS: [(u8, usize); 2] = [(1, 11), (2, 13)];

/// Format version written into every record; a record of a version not in
/// [`LAYOUTS`] is not loaded (the store then reports it unreadable and
/// defaults apply).
pub const RECORD_VERSION: u8 = LAYOUTS[LAYOUTS.len() - 1].0;
/// Size of one encoded record.
pub const RECORD_LEN: usize = record_len(SAVED_COUNT);

const _: () = {
    assert!(
        LAYOUTS[LAYOUTS.len() - 1].1 == SAVED_COUNT,
        "a new saved entry needs a new record version in LAYOUTS"
    );
    let mut i = 1;
    while i < LAYOUTS.len() {
        assert!(LAYOUTS[i].0 > LAYOUTS[i - 1].0 && LAYOUTS[i].1 > LAYOUTS[i - 1].1);
        i += 1;
    }
};

const MAGIC: [u8; 2] = *b"PS";
const HEADER_LEN: usize = 4;

/// Length of a record that holds slots `0..saved`.
const fn record_len(saved: usize) -> usize {
    let mut n = HEADER_LEN + 2 * PA_COUNT + 2;
    let mut s = 0;
    while s < saved {
        n += 2 * SAVED[s].entry().words() as usize;
        s += 1;
    }
    n
}

/// Slots a record of `version` holds, if it is one this firmware loads.
fn saved_in(version: u8) -> Option<usize> {
    LAYOUTS.iter().find(|l| l.0 == version).map(|l| l.1)
}

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
    pa: Params,
    /// Only the saved fields are meaningful (not 0x6040, 0x6060, 0x607A).
    od: OdValues,
}

impl ParamSet {
    #[inline]
    pub const fn pa(&self) -> &Params {
        &self.pa
    }

    /// Only the saved fields are meaningful (not 0x6040, 0x6060, 0x607A).
    #[inline]
    pub const fn od(&self) -> &OdValues {
        &self.od
    }

    /// The parameters, to change before the set is saved.
    #[inline]
    pub fn pa_mut(&mut self) -> &mut Params {
        &mut self.pa
    }

    /// The register values, to change before the set is saved.
    #[inline]
    pub fn od_mut(&mut self) -> &mut OdValues {
        &mut self.od
    }
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
        for object in SAVED {
            object.store_raw(od, object.read_stored(&self.od));
        }
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
        for object in SAVED {
            let raw = object.read_stored(&self.od);
            if object.entry().words() == 1 {
                w.bytes(&(raw as u16).to_le_bytes());
            } else {
                w.bytes(&raw.to_le_bytes());
            }
        }
        let crc = crc16(&w.buf[..w.at]);
        w.bytes(&crc.to_le_bytes());
        debug_assert_eq!(w.at, RECORD_LEN);
        out
    }

    /// Decodes a record. Values outside their entry's range (a record of an
    /// older firmware with other ranges) are replaced by defaults; the second
    /// result counts them.
    pub fn decode(bytes: &[u8]) -> Result<(Self, usize), RecordError> {
        if bytes.len() < 4 || bytes[..2] != MAGIC {
            return Err(RecordError::Malformed);
        }
        let saved = saved_in(bytes[2]).ok_or(RecordError::Version(bytes[2]))?;
        let len = record_len(saved);
        if bytes.len() != len || usize::from(bytes[3]) != PA_COUNT {
            return Err(RecordError::Malformed);
        }
        let body = len - 2;
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
        // Slots beyond the record's version keep their defaults; a value
        // out of its entry's range (an older firmware's) falls back to it.
        let mut od = OdValues::default();
        for object in &SAVED[..saved] {
            let e = object.entry();
            let raw = if e.words() == 1 {
                u32::from(r.u16())
            } else {
                r.u32()
            };
            if e.loadable(raw) {
                object.store_raw(&mut od, raw);
            } else {
                fixed += 1;
            }
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
        s.od.set_word_order(1);
        s.od.set_profile_velocity(-1234);
        s.od.set_home_offset(i32::MIN);
        s.od.set_homing_speed(100_000);
        s.od.set_homing_zero_speed(u32::MAX);
        s.od.set_homing_method(8);
        s.od.set_following_error_window(500);
        s.od.set_following_error_timeout(20);
        s.pa.set_unchecked(17, 4000);
        s.pa.set_unchecked(18, 1);
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
        s.od.set_target_position(200_000);
        s.od.set_controlword(0x0F);
        s.od.set_mode(1);
        assert_eq!(s.encode(), sample().encode());
        let mut pa = Params::defaults();
        let mut od = OdValues::default();
        od.set_target_position(5);
        od.set_controlword(6);
        od.set_mode(3);
        s.apply_to(&mut pa, &mut od);
        assert_eq!(
            (od.target_position(), od.controlword(), od.mode()),
            (5, 6, 3)
        );
        assert_eq!(od.profile_velocity(), -1234);
        assert_eq!(pa.get(10), 3200);
    }

    #[test]
    fn the_layout_is_the_one_saved_sets_have() {
        // Saved sets in the field must keep loading: the byte offsets of
        // version 2 (SPEC §9) do not move when the table is reordered.
        let b = sample().encode();
        assert_eq!((RECORD_LEN, RECORD_VERSION), (162, 2));
        assert_eq!(&b[..4], &[b'P', b'S', 2, 60]);
        assert_eq!(u16::from_le_bytes([b[4 + 2 * 10], b[5 + 2 * 10]]), 3200);
        let at = |o: usize, n: usize| &b[o..o + n];
        assert_eq!(at(124, 2), &1u16.to_le_bytes()); // 0x6000
        assert_eq!(at(128, 4), &(-1234i32).to_le_bytes()); // 0x6081
        assert_eq!(at(138, 4), &i32::MIN.to_le_bytes()); // 0x607C
        assert_eq!(at(142, 2), &8i16.to_le_bytes()); // 0x6098
        assert_eq!(at(144, 4), &100_000u32.to_le_bytes()); // 0x6099
        assert_eq!(at(150, 4), &u32::MAX.to_le_bytes()); // 0x609B
        assert_eq!(at(154, 4), &500u32.to_le_bytes()); // 0x6065
        assert_eq!(at(158, 2), &20u16.to_le_bytes()); // 0x6066
        assert_eq!(at(160, 2), &crc16(&b[..160]).to_le_bytes());
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
        let mut v3 = good;
        v3[2] = 3;
        assert_eq!(ParamSet::decode(&v3), Err(RecordError::Version(3)));
        // a version-2 body under a version-1 header has the wrong length
        let mut v1 = good;
        v1[2] = 1;
        assert_eq!(ParamSet::decode(&v1), Err(RecordError::Malformed));
    }

    #[test]
    fn a_version_1_record_loads_with_the_following_error_check_off() {
        // The layout before the closed loop: bytes 0..154, then its CRC.
        const RECORD_LEN_1: usize = 156;
        assert_eq!(
            record_len(saved_in(1).expect("version 1 loads")),
            RECORD_LEN_1
        );
        let s = sample();
        let v2 = s.encode();
        let mut v1 = [0u8; RECORD_LEN_1];
        v1[..RECORD_LEN_1 - 2].copy_from_slice(&v2[..RECORD_LEN_1 - 2]);
        v1[2] = 1;
        let crc = crc16(&v1[..RECORD_LEN_1 - 2]);
        v1[RECORD_LEN_1 - 2..].copy_from_slice(&crc.to_le_bytes());
        let (d, fixed) = ParamSet::decode(&v1).expect("a version-1 record loads");
        assert_eq!(fixed, 0);
        assert_eq!(d.pa, s.pa);
        assert_eq!(d.od.homing_zero_speed(), u32::MAX);
        assert_eq!(d.od.following_error_window(), u32::MAX);
        assert_eq!(d.od.following_error_timeout(), 0);
    }

    #[test]
    fn pa17_between_1_and_99_falls_back_to_no_encoder() {
        let mut s = sample();
        s.pa.set_unchecked(17, 99);
        let (d, fixed) = ParamSet::decode(&s.encode()).expect("crc is good");
        assert_eq!((fixed, d.pa.get(17)), (1, 0));
    }

    #[test]
    fn out_of_range_values_with_a_good_crc_fall_back_to_defaults() {
        let mut s = sample();
        s.pa.set_unchecked(51, 0); // PA51 ∉ 1..=247
        s.pa.set_unchecked(2, 1); // PA2 is read-only: always the firmware's
        s.od.set_homing_method(9);
        let (d, fixed) = ParamSet::decode(&s.encode()).expect("crc is good");
        assert_eq!(fixed, 2);
        assert_eq!(d.pa.get(51), 1);
        assert_eq!(d.pa.get(2), crate::dictionary::FIRMWARE_VERSION);
        assert_eq!(d.od.homing_method(), 0);
    }
}
