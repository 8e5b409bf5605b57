//! The entry table of SPEC §5, in table order (seed 000 chapter 8).
//!
//! [`Object`]'s discriminant is the entry's position in [`TABLE`], so a
//! request walks the table by position; [`position`] maps a Modbus address
//! to a position with one `match` (no scan).

use super::{DriveLayer, Identity, OdValues};

/// Who may read / write an entry.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Access {
    /// Read-only: a write gets exception 5 (§5.2 step 7).
    Ro,
    /// Read-write.
    Rw,
    /// Write-only: a read gets exception 7 (§5.2 step 7).
    Wo,
}

impl Access {
    pub const fn readable(self) -> bool {
        !matches!(self, Self::Wo)
    }
    pub const fn writable(self) -> bool {
        !matches!(self, Self::Ro)
    }
}

/// Data type of an entry; fixes its width in 16-bit words.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DataType {
    U16,
    I16,
    U32,
    I32,
    /// 16 ASCII bytes, NUL padded, first character in the high byte.
    Str,
}

impl DataType {
    pub const fn words(self) -> u16 {
        match self {
            Self::U16 | Self::I16 => 1,
            Self::U32 | Self::I32 => 2,
            Self::Str => STRING_WORDS,
        }
    }
}

/// Width of the string entries 0x1008 / 0x1009 / 0x100A.
pub const STRING_WORDS: u16 = 8;
/// Bytes of a string entry.
pub const STRING_BYTES: usize = 2 * STRING_WORDS as usize;

/// The entries of SPEC §5; the discriminant is the position in [`TABLE`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Object {
    ErrorRegister,
    DeviceName,
    HardwareVersion,
    SoftwareVersion,
    WordOrder,
    QuickStopOption,
    Controlword,
    ModeOfOperation,
    ProfileVelocity,
    Acceleration,
    Deceleration,
    QuickStopDeceleration,
    TargetPosition,
    HomeOffset,
    HomingMethod,
    HomingSpeed,
    HomingAcceleration,
    HomingZeroSpeed,
    Statusword,
    ModeDisplay,
    ActualPosition,
    ActualVelocity,
}

/// One entry of the table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Entry {
    /// Its Modbus address.
    pub index: u16,
    pub object: Object,
    pub access: Access,
    pub data_type: DataType,
    /// Value after power-up (numeric entries; strings come from [`Identity`]).
    pub default: i32,
}

impl Entry {
    pub const fn words(&self) -> u16 {
        self.data_type.words()
    }
}

const fn entry(index: u16, object: Object, access: Access, data_type: DataType) -> Entry {
    Entry {
        index,
        object,
        access,
        data_type,
        default: 0,
    }
}

use Access::{Ro, Rw, Wo};
use DataType::{Str, I16, I32, U16, U32};

/// SPEC §5, in table order. Every default is 0 (strings excepted).
pub const TABLE: [Entry; 22] = [
    entry(0x1001, Object::ErrorRegister, Ro, U16),
    entry(0x1008, Object::DeviceName, Ro, Str),
    entry(0x1009, Object::HardwareVersion, Ro, Str),
    entry(0x100A, Object::SoftwareVersion, Ro, Str),
    entry(0x6000, Object::WordOrder, Rw, U16),
    entry(0x605A, Object::QuickStopOption, Rw, I16),
    entry(0x6040, Object::Controlword, Wo, U16),
    entry(0x6060, Object::ModeOfOperation, Wo, I16),
    entry(0x6081, Object::ProfileVelocity, Rw, I32),
    entry(0x6083, Object::Acceleration, Rw, U16),
    entry(0x6084, Object::Deceleration, Rw, U16),
    entry(0x6085, Object::QuickStopDeceleration, Rw, U16),
    entry(0x607A, Object::TargetPosition, Rw, I32),
    entry(0x607C, Object::HomeOffset, Rw, I32),
    entry(0x6098, Object::HomingMethod, Rw, I16),
    entry(0x6099, Object::HomingSpeed, Rw, U32),
    entry(0x609A, Object::HomingAcceleration, Rw, U16),
    entry(0x609B, Object::HomingZeroSpeed, Rw, U32),
    entry(0x6041, Object::Statusword, Ro, U16),
    entry(0x6061, Object::ModeDisplay, Ro, I16),
    entry(0x6064, Object::ActualPosition, Ro, I32),
    entry(0x606C, Object::ActualVelocity, Ro, I32),
];

/// Words of the whole table, in table order.
const TABLE_WORDS: usize = {
    let mut n = 0;
    let mut p = 0;
    while p < TABLE.len() {
        n += TABLE[p].words() as usize;
        p += 1;
    }
    n
};

/// `WORD_AT[p]`: words of the entries before position `p` (`WORD_AT[22]`
/// is [`TABLE_WORDS`]).
const WORD_AT: [u8; TABLE.len() + 1] = {
    let mut at = [0u8; TABLE.len() + 1];
    let mut p = 0;
    while p < TABLE.len() {
        at[p + 1] = at[p] + TABLE[p].words() as u8;
        p += 1;
    }
    at
};

/// Marks a word inside an entry in [`POSITION_AT_WORD`].
const INSIDE: u8 = u8::MAX;

/// `POSITION_AT_WORD[w]`: the position whose first word is word `w` of the
/// table ([`TABLE`]`.len()` at the end), [`INSIDE`] for a word inside an entry.
const POSITION_AT_WORD: [u8; TABLE_WORDS + 1] = {
    let mut pos = [INSIDE; TABLE_WORDS + 1];
    let mut p = 0;
    while p <= TABLE.len() {
        pos[WORD_AT[p] as usize] = p as u8;
        p += 1;
    }
    pos
};

/// What [`positions`] collects.
#[derive(Clone, Copy)]
enum Trait {
    ReadOnly,
    WriteOnly,
    Ranged,
}

/// Positions of the entries that have `t`, as bits.
const fn positions(t: Trait) -> u32 {
    let mut mask = 0;
    let mut p = 0;
    while p < TABLE.len() {
        let e = &TABLE[p];
        let has = match t {
            Trait::ReadOnly => !e.access.writable(),
            Trait::WriteOnly => !e.access.readable(),
            Trait::Ranged => e.object.ranged(),
        };
        if has {
            mask |= 1 << p;
        }
        p += 1;
    }
    mask
}

/// The entries one request covers: positions `first..end` of [`TABLE`].
///
/// Found with two table look-ups instead of a walk, so that a request is
/// checked (§5.2 steps 6, 7 and 8) before anything is read or stored: a
/// write then stores straight into the values, with no copy to commit or
/// throw away.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Span {
    entries: &'static [Entry],
    first: usize,
    /// Bit `p` set for every position covered.
    mask: u32,
}

impl Span {
    /// The span of `quantity` words from position `first`, if it ends on an
    /// entry boundary inside the table (else exception 2, §5.2 step 6).
    #[inline]
    pub fn new(first: usize, quantity: u16) -> Option<Self> {
        let end_word = usize::from(*WORD_AT.get(first)?) + usize::from(quantity);
        let end = usize::from(*POSITION_AT_WORD.get(end_word)?);
        // INSIDE (a word inside an entry) is no position: `get` refuses it
        let entries = TABLE.get(first..end)?;
        Some(Self {
            entries,
            first,
            // end ≤ 22: no shift overflows
            mask: ((1u32 << end) - 1) & !((1u32 << first) - 1),
        })
    }

    /// The covered entries, in table order.
    pub fn entries(self) -> &'static [Entry] {
        self.entries
    }

    /// A read-only entry is covered (a write gets exception 5).
    pub fn any_read_only(self) -> bool {
        const RO: u32 = positions(Trait::ReadOnly);
        self.mask & RO != 0
    }

    /// A write-only entry is covered (a read gets exception 7).
    pub fn any_write_only(self) -> bool {
        const WO: u32 = positions(Trait::WriteOnly);
        self.mask & WO != 0
    }

    /// `object` is covered.
    pub fn covers(self, object: Object) -> bool {
        self.mask & (1 << object as u32) != 0
    }

    /// The covered entries whose values have a range (§5.2 step 8), each
    /// with the index of its first word in the request.
    pub fn ranged(self) -> impl Iterator<Item = (&'static Entry, usize)> {
        const RANGED: u32 = positions(Trait::Ranged);
        let base = WORD_AT[self.first];
        let mut left = self.mask & RANGED;
        core::iter::from_fn(move || {
            let p = left.trailing_zeros() as usize;
            let e = TABLE.get(p)?;
            left &= left - 1;
            Some((e, usize::from(WORD_AT[p] - base)))
        })
    }
}

/// Position in [`TABLE`] of the entry whose index is `address`.
pub const fn position(address: u16) -> Option<usize> {
    let object = match address {
        0x1001 => Object::ErrorRegister,
        0x1008 => Object::DeviceName,
        0x1009 => Object::HardwareVersion,
        0x100A => Object::SoftwareVersion,
        0x6000 => Object::WordOrder,
        0x605A => Object::QuickStopOption,
        0x6040 => Object::Controlword,
        0x6060 => Object::ModeOfOperation,
        0x6081 => Object::ProfileVelocity,
        0x6083 => Object::Acceleration,
        0x6084 => Object::Deceleration,
        0x6085 => Object::QuickStopDeceleration,
        0x607A => Object::TargetPosition,
        0x607C => Object::HomeOffset,
        0x6098 => Object::HomingMethod,
        0x6099 => Object::HomingSpeed,
        0x609A => Object::HomingAcceleration,
        0x609B => Object::HomingZeroSpeed,
        0x6041 => Object::Statusword,
        0x6061 => Object::ModeDisplay,
        0x6064 => Object::ActualPosition,
        0x606C => Object::ActualVelocity,
        _ => return None,
    };
    Some(object as usize)
}

impl Object {
    /// Whether [`Object::accepts`] refuses some value.
    pub const fn ranged(self) -> bool {
        matches!(
            self,
            Self::WordOrder | Self::QuickStopOption | Self::ModeOfOperation | Self::HomingMethod
        )
    }

    /// Whether a written value is in range (§5.2 step 8). `raw` holds the
    /// value's bits: one word zero-extended, or both words as one `u32`.
    #[inline]
    pub const fn accepts(self, raw: u32) -> bool {
        match self {
            Self::WordOrder => raw <= 1,
            // §8.3: negative option codes are refused.
            Self::QuickStopOption => (raw as u16 as i16) >= 0,
            Self::ModeOfOperation => matches!(raw as u16 as i16, 1 | 3 | 6),
            Self::HomingMethod => matches!(raw as u16 as i16, 1..=8),
            // 0x6099 / 0x609B: any value is stored; above 100000 homing fails
            // with bit 13 (§8.6), which needs the value to be accepted.
            _ => true,
        }
    }

    /// The value of a numeric entry as raw bits (see [`Object::accepts`]).
    /// Strings read 0 here; [`string_bytes`] serves them.
    ///
    /// A stored value is one load, inlined into the request walk; the live
    /// entries go through the drive layer in [`Object::read_live`], kept
    /// out of line so that its size does not weigh on every read.
    #[inline]
    pub fn read_raw<D: DriveLayer>(self, od: &OdValues, drive: &D) -> u32 {
        match self {
            Self::DeviceName | Self::HardwareVersion | Self::SoftwareVersion => 0,
            Self::WordOrder => u32::from(od.word_order),
            Self::QuickStopOption => u32::from(od.quick_stop_option as u16),
            Self::Controlword => u32::from(od.controlword),
            Self::ModeOfOperation => u32::from(od.mode as u16),
            Self::ProfileVelocity => od.profile_velocity as u32,
            Self::Acceleration => u32::from(od.acceleration),
            Self::Deceleration => u32::from(od.deceleration),
            Self::QuickStopDeceleration => u32::from(od.quick_stop_deceleration),
            Self::TargetPosition => od.target_position as u32,
            Self::HomeOffset => od.home_offset as u32,
            Self::HomingMethod => u32::from(od.homing_method as u16),
            Self::HomingSpeed => od.homing_speed,
            Self::HomingAcceleration => u32::from(od.homing_acceleration),
            Self::HomingZeroSpeed => od.homing_zero_speed,
            Self::ErrorRegister
            | Self::Statusword
            | Self::ModeDisplay
            | Self::ActualPosition
            | Self::ActualVelocity => self.read_live(drive),
        }
    }

    /// The value of an entry that lives in the drive layer (0 for others).
    #[inline(never)]
    fn read_live<D: DriveLayer>(self, drive: &D) -> u32 {
        match self {
            Self::ErrorRegister => u32::from(drive.error_register()),
            Self::Statusword => u32::from(drive.statusword()),
            Self::ModeDisplay => u32::from(drive.mode_display() as u16),
            Self::ActualPosition => drive.actual_position() as u32,
            Self::ActualVelocity => drive.actual_velocity_rpm() as u32,
            _ => 0,
        }
    }

    /// Stores a validated value of a writable entry; read-only ones are
    /// never passed here (§5.2 step 7 ran before). Inlined into the
    /// request walk: one store per entry.
    #[inline]
    pub fn store_raw(self, od: &mut OdValues, raw: u32) {
        match self {
            Self::WordOrder => od.word_order = raw as u16,
            Self::QuickStopOption => od.quick_stop_option = raw as u16 as i16,
            Self::Controlword => od.controlword = raw as u16,
            Self::ModeOfOperation => od.mode = raw as u16 as i16,
            Self::ProfileVelocity => od.profile_velocity = raw as i32,
            Self::Acceleration => od.acceleration = raw as u16,
            Self::Deceleration => od.deceleration = raw as u16,
            Self::QuickStopDeceleration => od.quick_stop_deceleration = raw as u16,
            Self::TargetPosition => od.target_position = raw as i32,
            Self::HomeOffset => od.home_offset = raw as i32,
            Self::HomingMethod => od.homing_method = raw as u16 as i16,
            Self::HomingSpeed => od.homing_speed = raw,
            Self::HomingAcceleration => od.homing_acceleration = raw as u16,
            Self::HomingZeroSpeed => od.homing_zero_speed = raw,
            Self::ErrorRegister
            | Self::DeviceName
            | Self::HardwareVersion
            | Self::SoftwareVersion
            | Self::Statusword
            | Self::ModeDisplay
            | Self::ActualPosition
            | Self::ActualVelocity => {}
        }
    }

    /// The identity string behind a string entry.
    pub const fn string(self, identity: &Identity) -> Option<&'static str> {
        match self {
            Self::DeviceName => Some(identity.product),
            Self::HardwareVersion => Some(identity.hardware),
            Self::SoftwareVersion => Some(identity.software),
            _ => None,
        }
    }
}

/// A string entry's 16 bytes: ASCII, cut at 16, NUL padded (SPEC §5). In
/// register order the first character is the high byte of the first word.
pub fn string_bytes(s: &str) -> [u8; STRING_BYTES] {
    let mut out = [0u8; STRING_BYTES];
    for (o, &b) in out.iter_mut().zip(s.as_bytes()) {
        *o = b;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn object_discriminants_are_table_positions_and_lookup_agrees() {
        for (i, e) in TABLE.iter().enumerate() {
            assert_eq!(e.object as usize, i);
            assert_eq!(position(e.index), Some(i));
        }
        // SPEC §5: 0x6090 and the legacy addresses are not entries.
        for a in [0x6090, 0x0000, 0x0064, 0x6082, 0x607B, 0xFFFF] {
            assert_eq!(position(a), None);
        }
    }

    #[test]
    fn ranges_of_section_5_2_step_8() {
        use Object::*;
        assert!(WordOrder.accepts(0) && WordOrder.accepts(1) && !WordOrder.accepts(2));
        for m in [1, 3, 6] {
            assert!(ModeOfOperation.accepts(m));
        }
        for m in [0, 2, 4, 5, 7, 0xFFFF] {
            assert!(!ModeOfOperation.accepts(m), "mode {m}");
        }
        assert!(HomingMethod.accepts(1) && HomingMethod.accepts(8));
        assert!(!HomingMethod.accepts(0) && !HomingMethod.accepts(9));
        assert!(QuickStopOption.accepts(0) && QuickStopOption.accepts(0x7FFF));
        assert!(!QuickStopOption.accepts(0x8000) && !QuickStopOption.accepts(0xFFFF));
        assert!(HomingSpeed.accepts(100_001) && ProfileVelocity.accepts(u32::MAX));
    }

    #[test]
    fn defaults_are_what_a_fresh_dictionary_reads() {
        struct Idle;
        impl DriveLayer for Idle {
            fn statusword(&self) -> u16 {
                0
            }
            fn mode_display(&self) -> i16 {
                0
            }
            fn actual_position(&self) -> i32 {
                0
            }
            fn actual_velocity_rpm(&self) -> i32 {
                0
            }
            fn error_register(&self) -> u16 {
                0
            }
            fn values_written(&mut self, _: super::super::Config<'_>) {}
            fn mode_written(&mut self, _: i16, _: super::super::Config<'_>) {}
            fn controlword_written(&mut self, _: u16, _: super::super::Config<'_>) {}
        }
        let od = OdValues::default();
        for e in TABLE {
            assert_eq!(e.object.read_raw(&od, &Idle) as i32, e.default, "{e:?}");
        }
    }

    /// The entries a request of `quantity` words from `first` covers, by
    /// walking the table word by word (what `Span` finds with look-ups).
    fn walk(first: usize, quantity: u16) -> Option<core::ops::Range<usize>> {
        let (mut at, mut p) = (0, first);
        while at < usize::from(quantity) {
            at += usize::from(TABLE.get(p)?.words());
            p += 1;
        }
        (at == usize::from(quantity)).then_some(first..p)
    }

    #[test]
    fn spans_agree_with_a_walk_of_the_table() {
        // SPEC §5.2 steps 6 and 7: a request must end on an entry boundary
        // inside the table; its access is that of every entry it covers.
        for first in 0..TABLE.len() {
            for quantity in 0..=60 {
                let span = Span::new(first, quantity);
                let Some(range) = walk(first, quantity) else {
                    assert_eq!(span, None, "first {first} quantity {quantity}");
                    continue;
                };
                let span = span.expect("the walk found a span");
                let entries = &TABLE[range.clone()];
                assert_eq!(span.entries(), entries);
                assert_eq!(
                    span.any_read_only(),
                    entries.iter().any(|e| e.access == Access::Ro)
                );
                assert_eq!(
                    span.any_write_only(),
                    entries.iter().any(|e| e.access == Access::Wo)
                );
                for e in TABLE {
                    assert_eq!(span.covers(e.object), range.contains(&(e.object as usize)));
                }
                let mut word = 0;
                let mut ranged = std::vec::Vec::new();
                for e in entries {
                    if e.object.ranged() {
                        ranged.push((e.object, word));
                    }
                    word += usize::from(e.words());
                }
                let found: std::vec::Vec<_> = span.ranged().map(|(e, w)| (e.object, w)).collect();
                assert_eq!(found, ranged, "first {first} quantity {quantity}");
            }
        }
    }

    #[test]
    fn only_ranged_one_word_entries_refuse_values() {
        // `Registers::write` checks §5.2 step 8 on the ranged entries only,
        // reading one word for each.
        for e in TABLE {
            if e.object.ranged() {
                assert_eq!(e.words(), 1, "{e:?}");
            } else {
                for raw in [0, 1, 0x7FFF, 0x8000, 0xFFFF, 0x1_0000, u32::MAX] {
                    assert!(e.object.accepts(raw), "{e:?} {raw:#x}");
                }
            }
        }
    }

    #[test]
    fn strings_are_cut_and_nul_padded() {
        assert_eq!(&string_bytes("ab")[..3], b"ab\0");
        assert_eq!(string_bytes("0123456789abcdefXYZ"), *b"0123456789abcdef");
    }
}
