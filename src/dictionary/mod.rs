//! The object dictionary (SPEC §5) and the legacy map (SPEC §9): entries,
//! access rights, types, ranges, word order — and the values the master
//! writes.
//!
//! Values that live in the drive layer (statusword, mode display, actual
//! position and velocity, error register) are read through [`DriveLayer`];
//! everything the master writes is stored in [`OdValues`] / [`Params`] and
//! handed to the drive layer as [`Config`].

mod ee_command;
mod legacy;
mod monitor;
mod pa;
mod table;

pub use ee_command::EeOp;
pub use legacy::{Block as LegacyBlock, PA_BASE, PA_LAST};
pub use monitor::{
    dp_value, DpItem, DriveMonitor, StoreStatus, DP_BASE, DP_ERR, DP_ITEMS, DP_LAST,
};
pub use pa::{
    pa_entries, PaDef, PaEntry, Params, DEFAULT_STEP_PULSE_NS, FIRMWARE_VERSION, MAX_STEP_SHAPE_NS,
    PA, PA_COUNT,
};
pub use table::{
    position, string_bytes, Access, DataType, Entry, Object, Range, Span, SAVED, SAVED_COUNT,
    STRING_BYTES, STRING_WORDS, TABLE,
};

use crate::rtu::pdu::{ReadRequest, WriteMultipleRequest};
use crate::rtu::Exception;

/// The RW/WO values of the SPEC §5 table as last written by the master.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OdValues {
    /// 0x6000: 0 = high word first, 1 = low word first.
    word_order: u16,
    /// 0x605A quick stop option code (§8.3), ≥ 0.
    quick_stop_option: i16,
    /// 0x6040 controlword, as last written.
    controlword: u16,
    /// 0x6060 mode of operation, as last written (0 = none yet).
    mode: i16,
    /// 0x6081 profile velocity, 0.1 rev/s (signed in velocity mode).
    profile_velocity: i32,
    /// 0x6083 acceleration, 0.1 rev/s².
    acceleration: u16,
    /// 0x6084 deceleration, 0.1 rev/s².
    deceleration: u16,
    /// 0x6085 quick stop deceleration, 0.1 rev/s².
    quick_stop_deceleration: u16,
    /// 0x607A target position, steps.
    target_position: i32,
    /// 0x607C home offset, steps.
    home_offset: i32,
    /// 0x6098 homing method 1..=8 (0 = none).
    homing_method: i16,
    /// 0x6099 homing search (fast) speed, 0.1 rev/s.
    homing_speed: u32,
    /// 0x609A homing acceleration, 0.1 rev/s².
    homing_acceleration: u16,
    /// 0x609B homing zero (slow) speed, 0.1 rev/s.
    homing_zero_speed: u32,
    /// 0x6065 following error window, steps (SPEC §8.8; `u32::MAX` = off).
    following_error_window: u32,
    /// 0x6066 following error time out, ms.
    following_error_timeout: u16,
}

impl OdValues {
    /// 0x6000: 0 = high word first, 1 = low word first.
    #[inline]
    pub const fn word_order(&self) -> u16 {
        self.word_order
    }

    /// 0x605A quick stop option code (§8.3), ≥ 0.
    #[inline]
    pub const fn quick_stop_option(&self) -> i16 {
        self.quick_stop_option
    }

    /// 0x6040 controlword, as last written.
    #[inline]
    pub const fn controlword(&self) -> u16 {
        self.controlword
    }

    /// 0x6060 mode of operation, as last written (0 = none yet).
    #[inline]
    pub const fn mode(&self) -> i16 {
        self.mode
    }

    /// 0x6081 profile velocity, 0.1 rev/s (signed in velocity mode).
    #[inline]
    pub const fn profile_velocity(&self) -> i32 {
        self.profile_velocity
    }

    /// 0x6083 acceleration, 0.1 rev/s².
    #[inline]
    pub const fn acceleration(&self) -> u16 {
        self.acceleration
    }

    /// 0x6084 deceleration, 0.1 rev/s².
    #[inline]
    pub const fn deceleration(&self) -> u16 {
        self.deceleration
    }

    /// 0x6085 quick stop deceleration, 0.1 rev/s².
    #[inline]
    pub const fn quick_stop_deceleration(&self) -> u16 {
        self.quick_stop_deceleration
    }

    /// 0x607A target position, steps.
    #[inline]
    pub const fn target_position(&self) -> i32 {
        self.target_position
    }

    /// 0x607C home offset, steps.
    #[inline]
    pub const fn home_offset(&self) -> i32 {
        self.home_offset
    }

    /// 0x6098 homing method 1..=8 (0 = none).
    #[inline]
    pub const fn homing_method(&self) -> i16 {
        self.homing_method
    }

    /// 0x6099 homing search (fast) speed, 0.1 rev/s.
    #[inline]
    pub const fn homing_speed(&self) -> u32 {
        self.homing_speed
    }

    /// 0x609A homing acceleration, 0.1 rev/s².
    #[inline]
    pub const fn homing_acceleration(&self) -> u16 {
        self.homing_acceleration
    }

    /// 0x609B homing zero (slow) speed, 0.1 rev/s.
    #[inline]
    pub const fn homing_zero_speed(&self) -> u32 {
        self.homing_zero_speed
    }

    /// 0x6065 following error window, steps (SPEC §8.8; `u32::MAX` = off).
    #[inline]
    pub const fn following_error_window(&self) -> u32 {
        self.following_error_window
    }

    /// 0x6066 following error time out, ms.
    #[inline]
    pub const fn following_error_timeout(&self) -> u16 {
        self.following_error_timeout
    }
}

impl OdValues {
    /// Every field 0: the start of `OdValues::default`, which the table
    /// (`table.rs`) fills with its defaults.
    pub(crate) const ZERO: Self = Self {
        word_order: 0,
        quick_stop_option: 0,
        controlword: 0,
        mode: 0,
        profile_velocity: 0,
        acceleration: 0,
        deceleration: 0,
        quick_stop_deceleration: 0,
        target_position: 0,
        home_offset: 0,
        homing_method: 0,
        homing_speed: 0,
        homing_acceleration: 0,
        homing_zero_speed: 0,
        following_error_window: 0,
        following_error_timeout: 0,
    };
}

/// Setters for glue and tests that preset values without a request: each
/// stores what a write of its register would, without the dictionary's
/// range checks (a value the table refuses is the caller's to avoid).
impl OdValues {
    /// Stores 0x6000.
    #[inline]
    pub fn set_word_order(&mut self, value: u16) {
        self.word_order = value;
    }

    /// Stores 0x6040.
    #[inline]
    pub fn set_controlword(&mut self, value: u16) {
        self.controlword = value;
    }

    /// Stores 0x6060.
    #[inline]
    pub fn set_mode(&mut self, value: i16) {
        self.mode = value;
    }

    /// Stores 0x6081.
    #[inline]
    pub fn set_profile_velocity(&mut self, value: i32) {
        self.profile_velocity = value;
    }

    /// Stores 0x6083.
    #[inline]
    pub fn set_acceleration(&mut self, value: u16) {
        self.acceleration = value;
    }

    /// Stores 0x607A.
    #[inline]
    pub fn set_target_position(&mut self, value: i32) {
        self.target_position = value;
    }

    /// Stores 0x607C.
    #[inline]
    pub fn set_home_offset(&mut self, value: i32) {
        self.home_offset = value;
    }

    /// Stores 0x6098.
    #[inline]
    pub fn set_homing_method(&mut self, value: i16) {
        self.homing_method = value;
    }

    /// Stores 0x6099.
    #[inline]
    pub fn set_homing_speed(&mut self, value: u32) {
        self.homing_speed = value;
    }

    /// Stores 0x609B.
    #[inline]
    pub fn set_homing_zero_speed(&mut self, value: u32) {
        self.homing_zero_speed = value;
    }

    /// Stores 0x6065.
    #[inline]
    pub fn set_following_error_window(&mut self, value: u32) {
        self.following_error_window = value;
    }

    /// Stores 0x6066.
    #[inline]
    pub fn set_following_error_timeout(&mut self, value: u16) {
        self.following_error_timeout = value;
    }
}

/// Everything the master configures, as the drive layer sees it.
#[derive(Clone, Copy)]
pub struct Config<'a> {
    od: &'a OdValues,
    pa: &'a Params,
}

impl<'a> Config<'a> {
    #[inline]
    pub const fn new(od: &'a OdValues, pa: &'a Params) -> Self {
        Self { od, pa }
    }

    /// The register values.
    #[inline]
    pub const fn od(&self) -> &'a OdValues {
        self.od
    }

    /// The parameters.
    #[inline]
    pub const fn pa(&self) -> &'a Params {
        self.pa
    }
}

/// What the dictionary needs from the drive layer (implemented by
/// [`crate::drive::Drive`]; tests may use a double).
///
/// After an accepted write has stored all its values, the dispatcher calls
/// [`DriveLayer::values_written`], then [`DriveLayer::mode_written`] if the
/// request wrote 0x6060, then [`DriveLayer::controlword_written`] if it wrote
/// 0x6040 (SPEC §5.2: mode, then controlword, after the other values).
/// `values_written` always comes first, with the same values: the drive
/// takes its copy there and the two others may rely on it.
pub trait DriveLayer {
    /// 0x6041 (§8.2).
    fn statusword(&self) -> u16;
    /// Steps are being generated (statusword bit 9): EE operations are
    /// refused with exception 6 (SPEC §9).
    fn generating_steps(&self) -> bool {
        self.statusword() & STATUS_STEPS_RUNNING != 0
    }
    /// 0x6061: the mode in force.
    fn mode_display(&self) -> i16;
    /// 0x6064, steps.
    fn actual_position(&self) -> i32;
    /// 0x606C, r/min.
    fn actual_velocity_rpm(&self) -> i32;
    /// 0x1001 (§8.7).
    fn error_register(&self) -> u16;
    /// 0x60F4, steps: commanded − measured position (§8.8); 0 without an
    /// encoder.
    fn following_error(&self) -> i32 {
        0
    }
    /// Live values of the legacy DP monitor (SPEC §9, [`dp_value`])
    /// beyond the entries above; a drive that does not know reports zeros.
    fn monitor(&self) -> DriveMonitor {
        DriveMonitor::default()
    }
    /// Any accepted write stored new values (e.g. 0x6081 while running in
    /// velocity mode ramps to the new speed).
    fn values_written(&mut self, cfg: Config<'_>);
    /// 0x6060 was written with a valid mode (1, 3 or 6).
    fn mode_written(&mut self, mode: i16, cfg: Config<'_>);
    /// 0x6040 was written.
    fn controlword_written(&mut self, controlword: u16, cfg: Config<'_>);
}

/// Statusword bit 9: the motor is running, steps are being generated
/// (SPEC §8.2).
pub const STATUS_STEPS_RUNNING: u16 = 1 << 9;

/// Strings of 0x1008 / 0x1009 / 0x100A (SPEC §5), 16 ASCII bytes at most
/// (longer ones are cut).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Identity {
    /// Device name (0x1008).
    product: &'static str,
    /// Hardware version (0x1009): the board, e.g. "STM32G431CB" or "virtual".
    hardware: &'static str,
    /// Software version (0x100A).
    software: &'static str,
}

impl Identity {
    /// Device name (0x1008).
    #[inline]
    pub const fn product(&self) -> &'static str {
        self.product
    }

    /// Hardware version (0x1009): the board, e.g. "STM32G431CB" or "virtual".
    #[inline]
    pub const fn hardware(&self) -> &'static str {
        self.hardware
    }

    /// Software version (0x100A).
    #[inline]
    pub const fn software(&self) -> &'static str {
        self.software
    }
}

impl Identity {
    pub const fn new(hardware: &'static str) -> Self {
        Self {
            product: "modbus-drive",
            hardware,
            software: env!("CARGO_PKG_VERSION"),
        }
    }
}

/// Where a request's start address points (SPEC §5: the address space is
/// 0x0000..=0xFFFF; the §5 table and the legacy map do not overlap).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Region {
    /// Position in [`TABLE`]: the request walks the table order.
    Table(usize),
    /// A legacy block: the request walks addresses.
    Legacy(LegacyBlock),
}

impl Region {
    #[inline]
    fn at(address: u16) -> Option<Self> {
        match position(address) {
            Some(p) => Some(Self::Table(p)),
            None => LegacyBlock::at(address).map(Self::Legacy),
        }
    }
}

/// The register space as one request sees it: the values, the drive layer
/// behind the live entries and the state of the parameter store.
pub struct Registers<'a, D> {
    pub(crate) od: &'a mut OdValues,
    pub(crate) pa: &'a mut Params,
    pub(crate) drive: &'a mut D,
    pub(crate) identity: &'a Identity,
    /// A parameter-storage operation is running: register requests that
    /// pass validation get exception 6 (§5.2 step 9). Set by the parameter
    /// store.
    pub(crate) busy: bool,
    /// State of the parameter store, for DP-Err (SPEC §9).
    pub(crate) store_status: StoreStatus,
    /// Set by an accepted write of an EE command register (0x003A, or
    /// 0x0000 in the old format): the operation to run. The reply waits
    /// until it is done (`Device::poll_storage`).
    pub(crate) ee_request: Option<EeOp>,
}

impl<'a, D> Registers<'a, D> {
    /// The register space of a drive that is not busy and whose store is
    /// fine ([`Self::with_store`] tells otherwise).
    pub fn new(
        od: &'a mut OdValues,
        pa: &'a mut Params,
        drive: &'a mut D,
        identity: &'a Identity,
    ) -> Self {
        Self {
            od,
            pa,
            drive,
            identity,
            busy: false,
            store_status: StoreStatus::default(),
            ee_request: None,
        }
    }

    /// The parameter store's side: busy with an operation (§5.2 step 9),
    /// and its state for DP-Err (SPEC §9).
    pub fn with_store(mut self, busy: bool, store_status: StoreStatus) -> Self {
        self.busy = busy;
        self.store_status = store_status;
        self
    }

    /// The EE operation an accepted write asked for, if any.
    pub fn ee_request(&self) -> Option<EeOp> {
        self.ee_request
    }
}

/// Word `i` of big-endian request data (0 past its end; the dispatcher has
/// checked the length, this only keeps bad input from panicking).
fn word(data: &[u8], i: usize) -> u16 {
    match data.get(2 * i..2 * i + 2) {
        Some(&[hi, lo]) => u16::from_be_bytes([hi, lo]),
        _ => 0,
    }
}

/// Puts word `i` into a reply; words past `out` are dropped (an entry that
/// ends after the requested quantity fails step 6 anyway).
fn put_word(out: &mut [u8], i: usize, w: u16) {
    if let Some(slot) = out.get_mut(2 * i..2 * i + 2) {
        slot.copy_from_slice(&w.to_be_bytes());
    }
}

/// The last address of a legacy request, if it stays inside `block`.
fn legacy_span(block: LegacyBlock, start: u16, quantity: u16) -> Result<u16, Exception> {
    // quantity ≥ 1 before it is used: `start + quantity - 1` never wraps
    let Some(extra) = quantity.checked_sub(1) else {
        return Err(Exception::IllegalDataAddress);
    };
    match start.checked_add(extra) {
        Some(last) if last <= block.last() => Ok(last),
        _ => Err(Exception::IllegalDataAddress),
    }
}

/// 32-bit value from its two words as they arrived (SPEC §5.1).
fn join_words(first: u16, second: u16, low_word_first: bool) -> u32 {
    let (hi, lo) = if low_word_first {
        (second, first)
    } else {
        (first, second)
    };
    (u32::from(hi) << 16) | u32::from(lo)
}

impl<D: DriveLayer> Registers<'_, D> {
    /// Function 0x03 (length and quantity checked by [`ReadRequest`]): §5.2 steps 4, 6,
    /// 7 and 9, then `quantity` words big-endian into `out`.
    pub fn read(&self, request: ReadRequest, out: &mut [u8]) -> Result<(), Exception> {
        let (start, quantity) = (request.start(), request.quantity());
        let region = Region::at(start).ok_or(Exception::NoSuchRegister)?;
        match region {
            Region::Table(first) => {
                // §5.2 order: range 2, access 7, busy 6 — all known from
                // the span before a word is read.
                let span = Span::new(first, quantity).ok_or(Exception::IllegalDataAddress)?;
                if span.any_write_only() {
                    return Err(Exception::ReadWriteOnly);
                }
                if self.busy {
                    return Err(Exception::Busy);
                }
                match span.entries() {
                    // One entry (a statusword, a position: the usual poll)
                    // without the walk, whose set-up costs more than the
                    // entry itself.
                    [e] => self.put_entry(e, out, 0),
                    entries => {
                        let mut at = 0;
                        for e in entries {
                            self.put_entry(e, out, at);
                            at += usize::from(e.words());
                        }
                    }
                }
            }
            Region::Legacy(block) => {
                let last = legacy_span(block, start, quantity)?;
                if (start..=last).any(|a| block.write_only(a)) {
                    return Err(Exception::ReadWriteOnly);
                }
                if self.busy {
                    return Err(Exception::Busy);
                }
                for (i, a) in (start..=last).enumerate() {
                    put_word(out, i, block.read(a, self));
                }
            }
        }
        Ok(())
    }

    /// The value of `e` as words big-endian into `out` from word `at`, in
    /// the word order in force (§5.1).
    #[inline(always)]
    fn put_entry(&self, e: &Entry, out: &mut [u8], at: usize) {
        match e.data_type() {
            DataType::U16 | DataType::I16 => {
                put_word(out, at, e.object().read_raw(self.od, self.drive) as u16)
            }
            DataType::U32 | DataType::I32 => {
                let v = e.object().read_raw(self.od, self.drive);
                let (first_word, second_word) = if self.od.word_order == 1 {
                    (v as u16, (v >> 16) as u16)
                } else {
                    ((v >> 16) as u16, v as u16)
                };
                put_word(out, at, first_word);
                put_word(out, at + 1, second_word);
            }
            DataType::Str => {
                let s = e.object().string(self.identity).unwrap_or("");
                for (i, pair) in string_bytes(s).chunks_exact(2).enumerate() {
                    put_word(out, at + i, u16::from_be_bytes([pair[0], pair[1]]));
                }
            }
        }
    }

    /// Function 0x06 after the length check: §5.2 steps 4..=10 for one
    /// word. A table entry takes the same checks as in [`Self::write`]
    /// without a walk.
    pub fn write_single(&mut self, address: u16, value: u16) -> Result<(), Exception> {
        let e = match Region::at(address).ok_or(Exception::NoSuchRegister)? {
            Region::Table(p) => TABLE.get(p).ok_or(Exception::NoSuchRegister)?,
            Region::Legacy(block) => {
                return self.write_legacy(block, address, &value.to_be_bytes())
            }
        };
        if e.words() > 1 {
            return Err(Exception::ByteCountMismatch); // step 5
        }
        if !e.access().writable() {
            return Err(Exception::WriteReadOnly);
        }
        let raw = u32::from(value);
        if !e.object().accepts(raw) {
            return Err(Exception::IllegalDataValue);
        }
        if self.busy {
            return Err(Exception::Busy);
        }
        e.object().store_raw(self.od, raw);
        self.notify(
            (e.object() == Object::ModeOfOperation).then_some(self.od.mode),
            (e.object() == Object::Controlword).then_some(self.od.controlword),
        );
        Ok(())
    }

    /// Function 0x10 (length, byte count and quantity checked by
    /// [`WriteMultipleRequest`]): §5.2 steps
    /// 4..=10, all-or-nothing. `data` holds `quantity` big-endian words.
    /// Stores every value, then tells the drive layer: values, then mode,
    /// then controlword (§5.2).
    pub fn write(&mut self, request: WriteMultipleRequest<'_>) -> Result<(), Exception> {
        let (start, quantity, data) = (request.start(), request.quantity(), request.data());
        let region = Region::at(start).ok_or(Exception::NoSuchRegister)?;
        match region {
            Region::Table(first) => {
                // Checked in the §5.2 order (range 2, access 5, value 3,
                // busy 6) before anything is stored, then stored straight
                // into the values: all-or-nothing without a copy.
                // Only the entries with a range look at their values.
                let span = Span::new(first, quantity).ok_or(Exception::IllegalDataAddress)?;
                if span.any_read_only() {
                    return Err(Exception::WriteReadOnly);
                }
                // Ranged entries are one word each (table.rs): their word
                // is found without decoding the others.
                for (e, at) in span.ranged() {
                    if !e.object().accepts(u32::from(word(data, at))) {
                        return Err(Exception::IllegalDataValue);
                    }
                }
                if self.busy {
                    return Err(Exception::Busy);
                }
                // The order in force when the request arrived applies to all
                // of it, even to a request that writes 0x6000 (§5.1).
                let low_word_first = self.od.word_order == 1;
                let mut words = data
                    .chunks_exact(2)
                    .map(|c| u16::from_be_bytes([c[0], c[1]]));
                for e in span.entries() {
                    // the span ends on an entry boundary: no word is missing
                    let first_word = words.next().unwrap_or(0);
                    let raw = if e.words() == 2 {
                        join_words(first_word, words.next().unwrap_or(0), low_word_first)
                    } else {
                        u32::from(first_word)
                    };
                    e.object().store_raw(self.od, raw);
                }
                self.notify(
                    span.covers(Object::ModeOfOperation).then_some(self.od.mode),
                    span.covers(Object::Controlword)
                        .then_some(self.od.controlword),
                );
            }
            Region::Legacy(block) => self.write_legacy(block, start, data)?,
        }
        Ok(())
    }

    /// A write to a legacy block (`data`: big-endian words from `start`).
    fn write_legacy(
        &mut self,
        block: LegacyBlock,
        start: u16,
        data: &[u8],
    ) -> Result<(), Exception> {
        let words = || {
            data.chunks_exact(2)
                .map(|c| u16::from_be_bytes([c[0], c[1]]))
        };
        let last = legacy_span(block, start, (data.len() / 2) as u16)?;
        if (start..=last).any(|a| block.read_only(a)) {
            return Err(Exception::WriteReadOnly);
        }
        if !(start..=last)
            .zip(words())
            .all(|(a, v)| block.accepts(a, v))
        {
            return Err(Exception::IllegalDataValue);
        }
        if self.busy {
            return Err(Exception::Busy);
        }
        // SPEC §9: an EE operation under a moving axis is refused (step 9)
        // and changes nothing; the check at the run is Device::poll_storage.
        if block.runs_ee_operation() && self.drive.generating_steps() {
            return Err(Exception::Busy);
        }
        for (a, v) in (start..=last).zip(words()) {
            block.store(a, v, self)?;
        }
        self.notify(None, None);
        Ok(())
    }

    fn notify(&mut self, mode: Option<i16>, controlword: Option<u16>) {
        let cfg = Config::new(self.od, self.pa);
        self.drive.values_written(cfg);
        if let Some(m) = mode {
            self.drive.mode_written(m, cfg);
        }
        if let Some(cw) = controlword {
            self.drive.controlword_written(cw, cfg);
        }
    }
}
