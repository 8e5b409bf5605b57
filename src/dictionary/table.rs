//! The entry table of SPEC §5, in table order (seed 000 chapter 8): one
//! line per object in `od_table!` holds every fact about it — address,
//! type, access, where its value lives, range, default, name, unit and
//! record slot. The enum [`Object`], [`TABLE`], [`position`], the value
//! accessors and the factory [`OdValues`] are generated from that line;
//! the saved record (`params/record.rs`), the page and the generated docs
//! read [`TABLE`].
//!
//! [`Object`]'s discriminant is the entry's position in [`TABLE`], so a
//! request walks the table by position; [`position`] maps a Modbus address
//! to a position with one `match` (no scan).

use super::{DriveLayer, Identity, OdValues};
use crate::closed_loop::WINDOW_OFF;

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
    /// "RO", "RW" or "WO", as the docs and the page print it.
    pub const fn label(self) -> &'static str {
        match self {
            Self::Ro => "RO",
            Self::Rw => "RW",
            Self::Wo => "WO",
        }
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

    /// The value behind raw bits (one word zero-extended, or both words
    /// as one `u32`), signed types sign-extended; strings read 0.
    pub const fn value(self, raw: u32) -> i64 {
        match self {
            Self::U16 => raw as u16 as i64,
            Self::I16 => raw as u16 as i16 as i64,
            Self::U32 => raw as i64,
            Self::I32 => raw as i32 as i64,
            Self::Str => 0,
        }
    }
}

/// Width of the string entries 0x1008 / 0x1009 / 0x100A.
pub const STRING_WORDS: u16 = 8;
/// Bytes of a string entry.
pub const STRING_BYTES: usize = 2 * STRING_WORDS as usize;

/// The values a register accepts (§5.2 step 8, SPEC §7), on the wire and
/// when a saved record is loaded: one check for both ([`Range::contains`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Range {
    /// Every value of the type.
    Any,
    /// `min..=max`.
    Span(i32, i32),
    /// 0 ("off"), or `min..=max`.
    OffOr(i32, i32),
    /// One of the listed values.
    OneOf(&'static [i32]),
}

impl Range {
    /// Whether `v` is accepted. Inlined: with a constant range (as in
    /// [`Object::accepts`]) it folds into one or two compares.
    #[inline(always)]
    pub const fn contains(self, v: i64) -> bool {
        match self {
            Self::Any => true,
            Self::Span(min, max) => min as i64 <= v && v <= max as i64,
            Self::OffOr(min, max) => v == 0 || (min as i64 <= v && v <= max as i64),
            Self::OneOf(set) => {
                let mut i = 0;
                while i < set.len() {
                    if set[i] as i64 == v {
                        return true;
                    }
                    i += 1;
                }
                false
            }
        }
    }

    /// Smallest accepted value (`None`: the type's).
    pub const fn min(self) -> Option<i32> {
        match self {
            Self::Any => None,
            Self::Span(min, _) => Some(min),
            Self::OffOr(..) => Some(0),
            Self::OneOf(set) => {
                let (mut m, mut i) = (i32::MAX, 0);
                while i < set.len() {
                    if set[i] < m {
                        m = set[i];
                    }
                    i += 1;
                }
                Some(m)
            }
        }
    }

    /// Largest accepted value (`None`: the type's).
    pub const fn max(self) -> Option<i32> {
        match self {
            Self::Any => None,
            Self::Span(_, max) | Self::OffOr(_, max) => Some(max),
            Self::OneOf(set) => {
                let (mut m, mut i) = (i32::MIN, 0);
                while i < set.len() {
                    if set[i] > m {
                        m = set[i];
                    }
                    i += 1;
                }
                Some(m)
            }
        }
    }
}

impl core::fmt::Display for Range {
    /// As the docs and the page print it: `any`, `1..=8`, `0, 100..=65535`,
    /// `1, 3, 6`.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            Self::Any => f.write_str("any"),
            Self::Span(min, max) if min == max => write!(f, "{min}"),
            Self::Span(min, max) => write!(f, "{min}..={max}"),
            Self::OffOr(min, max) => write!(f, "0, {min}..={max}"),
            Self::OneOf(set) => {
                for (i, v) in set.iter().enumerate() {
                    if i > 0 {
                        f.write_str(", ")?;
                    }
                    write!(f, "{v}")?;
                }
                Ok(())
            }
        }
    }
}

/// One entry of the table. Fields are read through the accessors; what
/// only hosts read (range as a value, name, unit, slot) comes from the
/// same table line through [`Object`], so that the firmware links none of
/// the text it does not use.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Entry {
    index: u16,
    object: Object,
    access: Access,
    data_type: DataType,
    default: i32,
}

impl Entry {
    /// Its Modbus address.
    pub const fn index(&self) -> u16 {
        self.index
    }
    pub const fn object(&self) -> Object {
        self.object
    }
    pub const fn access(&self) -> Access {
        self.access
    }
    pub const fn data_type(&self) -> DataType {
        self.data_type
    }
    pub const fn words(&self) -> u16 {
        self.data_type.words()
    }
    /// The values a write may carry (§5.2 step 8).
    pub const fn range(&self) -> Range {
        self.object.range()
    }
    /// Value after power-up (numeric entries; strings come from [`Identity`]).
    pub const fn default(&self) -> i32 {
        self.default
    }
    /// What it is, in drive terms.
    pub const fn name(&self) -> &'static str {
        self.object.text().0
    }
    /// Its unit ("" for codes and flags).
    pub const fn unit(&self) -> &'static str {
        self.object.text().1
    }
    /// Its place among the saved entries of the parameter record (SPEC
    /// §9), `None` if it is not saved.
    pub const fn record_slot(&self) -> Option<u8> {
        self.object.record_slot()
    }

    /// Whether a written value is in range (§5.2 step 8). `raw` holds the
    /// value's bits: one word zero-extended, or both words as one `u32`.
    #[inline]
    pub const fn accepts(&self, raw: u32) -> bool {
        self.object.accepts(raw)
    }

    /// Whether a saved value may be loaded: in range, or the default
    /// (which a factory set saves even where the wire refuses it, e.g.
    /// homing method 0 = none).
    pub const fn loadable(&self, raw: u32) -> bool {
        self.accepts(raw) || self.data_type.value(raw) == self.default as i64
    }
}

/// A value's bits as [`Object::read_raw`] and [`Object::store_raw`] pass
/// them: one word zero-extended, or both words as one `u32`.
trait Raw: Sized {
    fn to_raw(self) -> u32;
    fn from_raw(raw: u32) -> Self;
}

impl Raw for u16 {
    #[inline(always)]
    fn to_raw(self) -> u32 {
        u32::from(self)
    }
    #[inline(always)]
    fn from_raw(raw: u32) -> Self {
        raw as u16
    }
}

impl Raw for i16 {
    #[inline(always)]
    fn to_raw(self) -> u32 {
        u32::from(self as u16)
    }
    #[inline(always)]
    fn from_raw(raw: u32) -> Self {
        raw as u16 as i16
    }
}

impl Raw for u32 {
    #[inline(always)]
    fn to_raw(self) -> u32 {
        self
    }
    #[inline(always)]
    fn from_raw(raw: u32) -> Self {
        raw
    }
}

impl Raw for i32 {
    #[inline(always)]
    fn to_raw(self) -> u32 {
        self as u32
    }
    #[inline(always)]
    fn from_raw(raw: u32) -> Self {
        raw as i32
    }
}

/// Where a value lives: `od(field)` in [`OdValues`], `live(method)` in
/// the [`DriveLayer`], `text(field)` in the [`Identity`]; `zero(_)`: a
/// read-only value this drive does not measure, read as 0.
macro_rules! stored_raw {
    (od, $f:tt, $od:ident) => {
        Raw::to_raw($od.$f)
    };
    ($other:ident, $f:tt, $od:ident) => {
        0
    };
}
macro_rules! live_raw {
    (live, $f:tt, $drive:ident) => {
        Raw::to_raw($drive.$f())
    };
    ($other:ident, $f:tt, $drive:ident) => {
        0
    };
}
macro_rules! store {
    (od, $f:tt, $od:ident, $raw:expr) => {
        $od.$f = Raw::from_raw($raw)
    };
    ($other:ident, $f:tt, $od:ident, $raw:expr) => {{}};
}
macro_rules! text {
    (text, $f:tt, $identity:ident) => {
        Some($identity.$f)
    };
    ($other:ident, $f:tt, $identity:ident) => {
        None
    };
}
macro_rules! is_live {
    (live) => {
        true
    };
    (zero) => {
        true
    };
    ($other:ident) => {
        false
    };
}
macro_rules! slot {
    (-) => {
        None
    };
    ($slot:literal) => {
        Some($slot)
    };
}

/// The table: one line per entry, in table order. Generates [`Object`],
/// [`TABLE`], [`position`], the value accessors and `OdValues::default`.
macro_rules! od_table {
    ($(
        $object:ident = $index:literal, $access:ident $ty:ident, $src:ident($f:tt),
        range $range:expr, default $default:expr, $name:literal, $unit:literal, slot $slot:tt;
    )*) => {
        /// The entries of SPEC §5; the discriminant is the position in [`TABLE`].
        #[derive(Clone, Copy, Debug, PartialEq, Eq)]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        pub enum Object {
            $($object,)*
        }

        /// SPEC §5 and §8.8, in table order.
        pub const TABLE: [Entry; [$(Object::$object),*].len()] = [$(
            Entry {
                index: $index,
                object: Object::$object,
                access: Access::$access,
                data_type: DataType::$ty,
                default: $default,
            },
        )*];

        /// Position in [`TABLE`] of the entry whose index is `address`.
        pub const fn position(address: u16) -> Option<usize> {
            let object = match address {
                $($index => Object::$object,)*
                _ => return None,
            };
            Some(object as usize)
        }

        impl Object {
            /// The values a write may carry (§5.2 step 8).
            pub const fn range(self) -> Range {
                match self {
                    $(Self::$object => $range,)*
                }
            }

            /// Whether a written value is in range (§5.2 step 8), see
            /// [`Entry::accepts`]. One arm per entry with its range and
            /// type as constants: the compiler folds each into a compare.
            #[inline]
            pub const fn accepts(self, raw: u32) -> bool {
                match self {
                    $(Self::$object => {
                        const R: Range = $range;
                        R.contains(DataType::$ty.value(raw))
                    })*
                }
            }

            /// Name and unit.
            const fn text(self) -> (&'static str, &'static str) {
                match self {
                    $(Self::$object => ($name, $unit),)*
                }
            }

            /// Place in the saved record, if saved.
            pub const fn record_slot(self) -> Option<u8> {
                match self {
                    $(Self::$object => slot!($slot),)*
                }
            }

            /// The value of an entry stored in [`OdValues`] (0 for others).
            #[inline]
            pub fn read_stored(self, od: &OdValues) -> u32 {
                match self {
                    $(Self::$object => stored_raw!($src, $f, od),)*
                }
            }

            /// Whether the value lives in the drive layer.
            const fn live(self) -> bool {
                match self {
                    $(Self::$object => is_live!($src),)*
                }
            }

            /// The value of an entry that lives in the drive layer (0 for
            /// others).
            #[inline(never)]
            fn read_live<D: DriveLayer>(self, drive: &D) -> u32 {
                match self {
                    $(Self::$object => live_raw!($src, $f, drive),)*
                }
            }

            /// Stores a validated value of a writable entry; read-only ones
            /// are never passed here (§5.2 step 7 ran before). Inlined into
            /// the request walk: one store per entry.
            #[inline]
            pub fn store_raw(self, od: &mut OdValues, raw: u32) {
                match self {
                    $(Self::$object => store!($src, $f, od, raw),)*
                }
            }

            /// The identity string behind a string entry.
            pub const fn string(self, identity: &Identity) -> Option<&'static str> {
                match self {
                    $(Self::$object => text!($src, $f, identity),)*
                }
            }
        }

        impl Default for OdValues {
            /// The defaults of [`TABLE`] (SPEC §5, §8.8).
            fn default() -> Self {
                let mut od = OdValues::ZERO;
                $(store!($src, $f, od, ($default as u32));)*
                od
            }
        }
    };
}

use Range::{Any, OneOf, Span as Between};

od_table! {
    ErrorRegister = 0x1001, Ro U16, live(error_register),
        range Any, default 0,
        "error register (bit 0 generic, 4 communication, 5 following error)", "bits", slot -;
    DeviceName = 0x1008, Ro Str, text(product),
        range Any, default 0, "device name", "", slot -;
    HardwareVersion = 0x1009, Ro Str, text(hardware),
        range Any, default 0, "hardware version", "", slot -;
    SoftwareVersion = 0x100A, Ro Str, text(software),
        range Any, default 0, "software version", "", slot -;
    WordOrder = 0x6000, Rw U16, od(word_order),
        range Between(0, 1), default 0,
        "word order of 32-bit values (0 high word first, 1 low word first)", "", slot 0;
    // §8.3: negative option codes are refused.
    QuickStopOption = 0x605A, Rw I16, od(quick_stop_option),
        range Between(0, 32767), default 0,
        "quick stop option (1 ramp 0x6084, 2 ramp 0x6085, else at once)", "", slot 1;
    Controlword = 0x6040, Wo U16, od(controlword),
        range Any, default 0, "controlword", "bits", slot -;
    ModeOfOperation = 0x6060, Wo I16, od(mode),
        range OneOf(&[1, 3, 6]), default 0,
        "mode of operation (1 position, 3 velocity, 6 homing)", "", slot -;
    ProfileVelocity = 0x6081, Rw I32, od(profile_velocity),
        range Any, default 0, "profile velocity (signed in velocity mode)", "0.1 rev/s", slot 2;
    Acceleration = 0x6083, Rw U16, od(acceleration),
        range Any, default 0, "acceleration", "0.1 rev/s²", slot 3;
    Deceleration = 0x6084, Rw U16, od(deceleration),
        range Any, default 0, "deceleration", "0.1 rev/s²", slot 4;
    QuickStopDeceleration = 0x6085, Rw U16, od(quick_stop_deceleration),
        range Any, default 0, "quick stop deceleration", "0.1 rev/s²", slot 5;
    TargetPosition = 0x607A, Rw I32, od(target_position),
        range Any, default 0, "target position (not saved, SPEC §9)", "steps", slot -;
    HomeOffset = 0x607C, Rw I32, od(home_offset),
        range Any, default 0, "home offset", "steps", slot 6;
    HomingMethod = 0x6098, Rw I16, od(homing_method),
        range Between(1, 8), default 0, "homing method (0 = none yet)", "", slot 7;
    // 0x6099 / 0x609B: any value is stored; above 100000 homing fails
    // with bit 13 (§8.6), which needs the value to be accepted.
    HomingSpeed = 0x6099, Rw U32, od(homing_speed),
        range Any, default 0, "homing search speed (above 100000: homing error)", "0.1 rev/s",
        slot 8;
    HomingAcceleration = 0x609A, Rw U16, od(homing_acceleration),
        range Any, default 0, "homing acceleration", "0.1 rev/s²", slot 9;
    HomingZeroSpeed = 0x609B, Rw U32, od(homing_zero_speed),
        range Any, default 0, "homing zero speed (above 100000: homing error)", "0.1 rev/s",
        slot 10;
    Statusword = 0x6041, Ro U16, live(statusword),
        range Any, default 0, "statusword (SPEC §8.2)", "bits", slot -;
    ModeDisplay = 0x6061, Ro I16, live(mode_display),
        range Any, default 0, "mode in force (0 none, 1, 3, 6)", "", slot -;
    ActualPosition = 0x6064, Ro I32, live(actual_position),
        range Any, default 0, "actual position", "steps", slot -;
    ActualVelocity = 0x606C, Ro I32, live(actual_velocity_rpm),
        range Any, default 0, "actual velocity", "r/min", slot -;
    FollowingErrorWindow = 0x6065, Rw U32, od(following_error_window),
        range Any, default WINDOW_OFF as i32,
        "following error window (0xFFFFFFFF = check off)", "steps", slot 11;
    FollowingErrorTimeout = 0x6066, Rw U16, od(following_error_timeout),
        range Any, default 0, "following error time out", "ms", slot 12;
    FollowingErrorActual = 0x60F4, Ro I32, live(following_error),
        range Any, default 0, "following error actual value (0 open loop)", "steps", slot -;
}

/// Checks the table once at compile time: the request walk reads one
/// word for each ranged entry, write-only and read-only entries are not
/// saved, saved entries sit in distinct slots `0..n`, and the access
/// masks below fit their width. (A default may lie outside the range a
/// write must meet, e.g. homing method 0 = none yet; a saved default
/// still loads, [`Entry::loadable`].)
const _: () = {
    assert!(TABLE.len() <= MASK_BITS, "widen `Mask`");
    let mut p = 0;
    let mut slots = 0u64;
    while p < TABLE.len() {
        let e = &TABLE[p];
        assert!(e.object as usize == p);
        if !matches!(e.object.range(), Range::Any) {
            assert!(e.words() == 1, "a ranged entry is one word");
        }
        if let Some(s) = e.object.record_slot() {
            assert!(matches!(e.access, Access::Rw), "only RW entries are saved");
            assert!(!e.object.live(), "a saved entry is stored in OdValues");
            assert!(slots & (1 << s) == 0, "two entries in one record slot");
            slots |= 1 << s;
        }
        p += 1;
    }
    assert!(
        slots & (slots + 1) == 0,
        "record slots are 0..n without a gap"
    );
};

/// The number of saved entries ([`Entry::record_slot`] is below it).
pub const SAVED_COUNT: usize = {
    let mut n = 0;
    let mut p = 0;
    while p < TABLE.len() {
        if TABLE[p].object.record_slot().is_some() {
            n += 1;
        }
        p += 1;
    }
    n
};

/// The saved entries, by record slot.
pub const SAVED: [Object; SAVED_COUNT] = {
    let mut out = [Object::ErrorRegister; SAVED_COUNT];
    let mut p = 0;
    while p < TABLE.len() {
        if let Some(s) = TABLE[p].object.record_slot() {
            out[s as usize] = TABLE[p].object;
        }
        p += 1;
    }
    out
};

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

/// `WORD_AT[p]`: words of the entries before position `p`
/// (`WORD_AT[TABLE.len()]` is [`TABLE_WORDS`]).
const WORD_AT: [u8; TABLE.len() + 1] = {
    assert!(TABLE_WORDS < u8::MAX as usize, "widen WORD_AT");
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

/// A set of table positions, one bit each.
type Mask = u32;
/// Positions a [`Mask`] holds; [`Span::new`] shifts by up to
/// `TABLE.len()`, so the table must stay below it (checked above).
const MASK_BITS: usize = Mask::BITS as usize - 1;

/// What [`positions`] collects.
#[derive(Clone, Copy)]
enum Trait {
    ReadOnly,
    WriteOnly,
    Ranged,
}

/// Positions of the entries that have `t`, as bits.
const fn positions(t: Trait) -> Mask {
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
    mask: Mask,
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
            // end ≤ TABLE.len() ≤ MASK_BITS (a const assert): no shift overflows
            mask: ((1 << end) - 1) & !((1 << first) - 1),
        })
    }

    /// The covered entries, in table order.
    pub fn entries(self) -> &'static [Entry] {
        self.entries
    }

    /// A read-only entry is covered (a write gets exception 5).
    pub fn any_read_only(self) -> bool {
        const RO: Mask = positions(Trait::ReadOnly);
        self.mask & RO != 0
    }

    /// A write-only entry is covered (a read gets exception 7).
    pub fn any_write_only(self) -> bool {
        const WO: Mask = positions(Trait::WriteOnly);
        self.mask & WO != 0
    }

    /// `object` is covered.
    pub fn covers(self, object: Object) -> bool {
        self.mask & (1 << object as u32) != 0
    }

    /// The covered entries whose values have a range (§5.2 step 8), each
    /// with the index of its first word in the request.
    pub fn ranged(self) -> impl Iterator<Item = (&'static Entry, usize)> {
        const RANGED: Mask = positions(Trait::Ranged);
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

impl Object {
    /// Its entry in [`TABLE`].
    pub const fn entry(self) -> &'static Entry {
        &TABLE[self as usize]
    }

    /// Whether [`Object::accepts`] refuses some value.
    pub const fn ranged(self) -> bool {
        !matches!(self.range(), Range::Any)
    }

    /// The value of a numeric entry as raw bits (see [`Object::accepts`]).
    /// Strings read 0 here; [`string_bytes`] serves them.
    ///
    /// A stored value is one load, inlined into the request walk; the live
    /// entries go through the drive layer in `read_live`, kept out of line
    /// so that its size does not weigh on every read.
    #[inline]
    pub fn read_raw<D: DriveLayer>(self, od: &OdValues, drive: &D) -> u32 {
        if self.live() {
            self.read_live(drive)
        } else {
            self.read_stored(od)
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
mod tests;
