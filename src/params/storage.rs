//! Power-loss-safe parameter storage over `embedded-storage`'s blocking
//! [`NorFlash`] (SPEC §9): a journal of whole records over the pages of a
//! region.
//!
//! # API for the glue (firmware flash region, virtual drive `--state FILE`)
//!
//! ```text
//! let mut store = ParamStore::new(flash, 0..2 * 2048)?;   // ≥ 2 erase pages
//! let boot = store.boot();               // at power-up: saved set or defaults
//! device.apply_boot(&boot);              // working set := boot.set, DP-Err flags
//! log(boot.outcome);                     // Loaded / Blank / Unreadable(why)
//! // …then per frame: device.handle_rx(…); device.poll_storage(&mut store, …)
//! ```
//!
//! * `flash` is anything implementing `embedded_storage::nor_flash::NorFlash`
//!   (also `&mut F`) with a `READ_SIZE` of 1 and a `WRITE_SIZE` that divides
//!   8 (the STM32s: 8 on the G4, 2 on the F1). The range is in the flash's
//!   own offsets, page aligned, at least two erase pages, each page large
//!   enough for its header and two entries. Only this range is ever read,
//!   written or erased.
//! * [`ParamStore::load`] / [`ParamStore::save`] read and write one of the
//!   two sets, [`Slot::Saved`] (EE-Set / EE-rd) and [`Slot::Backup`]
//!   (EE-bA / EE-rS). The EE operations are [`super::execute`], which
//!   [`crate::Device::poll_storage`] runs for the EE frames.
//! * The virtual drive's state file is the raw image of the region: load it
//!   with [`super::SimFlash::from_image`], hand the `SimFlash` to this store,
//!   write [`super::SimFlash::image`] back after each EE operation (write a
//!   temporary file and rename it, so the file itself is replaced atomically).
//!
//! # Layout
//!
//! The pages of the region form a ring; one of them, the *current* page, is
//! the journal. A page starts with an 8-byte header, written last when the
//! page is taken into use: magic `7E 4A`, generation (u32, one more than
//! the page before), CRC-16/MODBUS of those 6 bytes. The current page is
//! the one with the highest generation whose header checks. Entries follow
//! the header, each 8-byte aligned:
//!
//! | bytes | field |
//! |---|---|
//! | 0 | `'E'` |
//! | 1 | slot: 0 saved, 1 backup |
//! | 2..4 | record length n (u16) |
//! | 4..8 | sequence number (u32, one more than the highest in the page) |
//! | 8..8+n | the record (`record.rs`: own magic, version and CRC) |
//! | 8+n..10+n | CRC-16/MODBUS of bytes 0..8+n |
//! | then | 0x00 up to the next multiple of 8 |
//!
//! Reading: the entries of the current page in order, up to the first
//! erased header or the first entry that does not check; of each slot the
//! valid entry with the highest sequence number is the set.
//!
//! Saving appends an entry after the last one of the current page. When it
//! does not fit (or the page holds an entry that does not check, or the
//! write fails), the next page of the ring is erased, the other slot's
//! entry is copied into it, the new entry written after it, and last the
//! page header with the next generation: only then does that page count.
//! Erasing is therefore only done on a page that is not current, whose sets
//! all have newer copies in the current page.
//!
//! # Power-loss argument
//!
//! A cut inside an append leaves an entry whose CRC fails, whose header
//! reads erased, or which the flash refuses to read (the G431's ECC error
//! on a double word left half programmed): the reader stops before it and
//! finds the previous entry of the slot, the writer turns to a new page at
//! the next save. (A page header the flash refuses to read makes the
//! region unreadable: the firmware then erases that page, `flash.rs`.) A cut inside
//! a page turn (erase, copies, header) leaves a page without a valid header
//! (the header is programmed last and has its own CRC): it does not count,
//! the previous current page is untouched, and the next save erases and
//! fills it again. Either way one set is one entry, so after a cut at any
//! instant the complete old or the complete new set is loaded, and the other
//! slot is untouched. The tests in `tests/params_power_loss.rs` cut an
//! EE-Set, EE-rS and EE-dEF at every word write and page erase to show it.
//!
//! Wear: a page is erased once per page of entries, one of which is the
//! copy of the other set, and the ring spreads the erases over every page;
//! `tests/params_power_loss.rs` holds 10,000 saves to the flash's erase
//! budget on both boards' geometries.
//!
//! # The layout before this one
//!
//! Firmware before the journal kept the same records in a
//! `sequential-storage` map (`migrate.rs` reads it). A region with no journal
//! page but such a map is taken over once, at boot or at the first save:
//! its two sets are written into the page the map kept free, and only when
//! that page's header is written does the journal count; a cut before leaves
//! the map as it was, read again at the next boot.

use core::ops::Range;

use embedded_storage::nor_flash::{NorFlash, NorFlashError, NorFlashErrorKind};

use super::migrate::read_old;
use super::record::{ParamSet, RecordError, RECORD_LEN};
use crate::rtu::crc16;

/// Which stored set.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Slot {
    /// What EE-Set writes and the drive loads at boot.
    Saved = 0,
    /// What EE-bA writes and EE-rS restores.
    Backup = 1,
}

/// Flash fault classes (`embedded-storage`'s, in a defmt-printable form).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FlashFault {
    NotAligned,
    OutOfBounds,
    Other,
}

/// Why a storage operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StorageError {
    /// The flash driver reported an error (or the power went).
    Flash(FlashFault),
    /// An entry was found but is not a valid record of this firmware.
    Record(RecordError),
    /// The region is not page aligned, smaller than two pages, the pages
    /// are too small, or the flash's word sizes do not fit (module docs).
    Config,
}

/// What [`ParamStore::boot`] found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BootOutcome {
    /// The saved set was loaded; `fixed` values were out of range and
    /// replaced by defaults.
    Loaded { fixed: usize },
    /// No saved set (new or erased flash): defaults.
    Blank,
    /// The saved set could not be read: defaults.
    Unreadable(StorageError),
}

/// The set to work with after power-up and how it was obtained.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Boot {
    set: ParamSet,
    outcome: BootOutcome,
}

impl Boot {
    #[inline]
    pub const fn set(&self) -> &ParamSet {
        &self.set
    }

    #[inline]
    pub const fn outcome(&self) -> BootOutcome {
        self.outcome
    }

    /// The set, taken out.
    #[inline]
    pub fn into_set(self) -> ParamSet {
        self.set
    }
}

/// The parameter store on a flash region.
pub struct ParamStore<F> {
    flash: F,
    range: Range<u32>,
}

/// Page header: magic, generation, CRC. The first magic byte has fewer than
/// four 0 bits, so a header programmed part-way never looks like a page
/// marker of the old layout, whatever bits the cut left.
const PAGE_MAGIC: [u8; 2] = [0x7E, 0x4A];
const PAGE_HEADER: u32 = 8;
const ENTRY_MAGIC: u8 = b'E';
const ENTRY_HEADER: usize = 8;
/// The flash room an entry of an `n`-byte record takes.
const fn entry_size(n: usize) -> usize {
    (ENTRY_HEADER + n + 2).next_multiple_of(8)
}
/// Longest record an entry may hold: room for records of other versions
/// than this firmware's (older ones are shorter, a later one may be
/// longer), so that the store keeps and copies them and `record.rs`
/// decides what it can read.
const RECORD_MAX: usize = 246;
const _: () = assert!(RECORD_LEN <= RECORD_MAX);
const ENTRY_MAX: usize = entry_size(RECORD_MAX);

/// One entry; word aligned for flash drivers that need aligned sources.
#[repr(align(8))]
struct EntryBuf([u8; ENTRY_MAX]);

impl EntryBuf {
    fn new() -> Self {
        Self([0; ENTRY_MAX])
    }

    /// Header and CRC around the `n` record bytes already at 8..8+n; the
    /// room size.
    fn seal(&mut self, slot: usize, n: usize, seq: u32) -> usize {
        let b = &mut self.0;
        b[0] = ENTRY_MAGIC;
        b[1] = slot as u8;
        b[2..4].copy_from_slice(&(n as u16).to_le_bytes());
        b[4..8].copy_from_slice(&seq.to_le_bytes());
        let body = ENTRY_HEADER + n;
        let crc = crc(&b[..body]);
        b[body..body + 2].copy_from_slice(&crc.to_le_bytes());
        entry_size(n)
    }
}

/// A valid entry in flash.
#[derive(Clone, Copy)]
struct Entry {
    at: u32,
    len: usize,
    seq: u32,
}

/// The current page as a save or load finds it.
struct Journal {
    /// Page index in the region and its generation; `None`: no page yet.
    page: Option<(u32, u32)>,
    /// The newest valid entry of each slot.
    sets: [Option<Entry>; 2],
    /// Where the next entry goes; `None` after an entry that does not check.
    free: Option<u32>,
    /// Highest sequence number in the page.
    seq: u32,
}

impl<F: NorFlash> ParamStore<F> {
    const PAGE: u32 = F::ERASE_SIZE as u32;

    /// A store on `range` (page aligned, ≥ 2 erase pages) of `flash`.
    pub fn new(flash: F, range: Range<u32>) -> Result<Self, StorageError> {
        let page = Self::PAGE;
        let fits = range.start.is_multiple_of(page)
            && range.end.is_multiple_of(page)
            && range.end >= range.start.saturating_add(2 * page)
            && range.end as usize <= flash.capacity()
            && F::ERASE_SIZE >= PAGE_HEADER as usize + 2 * ENTRY_MAX
            && F::READ_SIZE == 1
            && 8 % F::WRITE_SIZE == 0;
        if !fits {
            return Err(StorageError::Config);
        }
        Ok(Self { flash, range })
    }

    /// The flash (tests look at erase counts; the virtual drive writes its
    /// image back).
    pub fn flash(&mut self) -> &mut F {
        &mut self.flash
    }

    pub fn into_inner(self) -> F {
        self.flash
    }

    /// Reads one set: `Ok(None)` if it was never written.
    pub fn load(&mut self, slot: Slot) -> Result<Option<(ParamSet, usize)>, StorageError> {
        let journal = self.journal()?;
        let mut buf = EntryBuf::new();
        let found = if journal.page.is_some() {
            journal.sets[slot as usize].map(|e| (e.at + ENTRY_HEADER as u32, e.len))
        } else {
            read_old(&mut self.flash, &self.range, &mut buf.0[..1 + RECORD_MAX])
                .map_err(flash_error)?
                .sets()[slot as usize]
        };
        let Some((at, len)) = found else {
            return Ok(None);
        };
        let record = &mut buf.0[..len];
        self.read(at, record)?;
        ParamSet::decode(record)
            .map(Some)
            .map_err(StorageError::Record)
    }

    /// Writes one set; after a power cut at any point inside, [`Self::load`]
    /// returns the complete previous set or the complete new one.
    pub fn save(&mut self, slot: Slot, set: &ParamSet) -> Result<(), StorageError> {
        self.take_over_old()?;
        let journal = self.journal()?;
        let mut new = EntryBuf::new();
        new.0[ENTRY_HEADER..ENTRY_HEADER + RECORD_LEN].copy_from_slice(&set.encode());
        let size = new.seal(slot as usize, RECORD_LEN, journal.seq.wrapping_add(1));
        if let (Some((page, _)), Some(free)) = (journal.page, journal.free) {
            let end = self.page_start(page) + Self::PAGE;
            if free + size as u32 <= end && self.flash.write(free, &new.0[..size]).is_ok() {
                return Ok(());
            }
        }
        self.turn_page(&journal, slot as usize, &new.0[..size])
    }

    /// At power-up: the saved set, or the defaults and why (SPEC §9).
    pub fn boot(&mut self) -> Boot {
        // If the take-over fails, the old layout is still there and read.
        let _ = self.take_over_old();
        match self.load(Slot::Saved) {
            Ok(Some((set, fixed))) => Boot {
                set,
                outcome: BootOutcome::Loaded { fixed },
            },
            Ok(None) => Boot {
                set: ParamSet::defaults(),
                outcome: BootOutcome::Blank,
            },
            Err(e) => Boot {
                set: ParamSet::defaults(),
                outcome: BootOutcome::Unreadable(e),
            },
        }
    }

    fn pages(&self) -> u32 {
        (self.range.end - self.range.start) / Self::PAGE
    }

    fn page_start(&self, page: u32) -> u32 {
        self.range.start + page * Self::PAGE
    }

    fn read(&mut self, at: u32, buf: &mut [u8]) -> Result<(), StorageError> {
        self.flash.read(at, buf).map_err(flash_error)
    }

    fn write(&mut self, at: u32, buf: &[u8]) -> Result<(), StorageError> {
        self.flash.write(at, buf).map_err(flash_error)
    }

    /// The page's generation, if its header is complete.
    fn generation(&mut self, page: u32) -> Result<Option<u32>, StorageError> {
        let mut h = [0u8; PAGE_HEADER as usize];
        self.read(self.page_start(page), &mut h)?;
        let generation = u32::from_le_bytes([h[2], h[3], h[4], h[5]]);
        Ok((h == page_header(generation)).then_some(generation))
    }

    /// Finds the current page and reads its entries.
    fn journal(&mut self) -> Result<Journal, StorageError> {
        let mut j = Journal {
            page: None,
            sets: [None, None],
            free: None,
            seq: 0,
        };
        for p in 0..self.pages() {
            if let Some(g) = self.generation(p)? {
                if j.page.is_none_or(|(_, best)| g > best) {
                    j.page = Some((p, g));
                }
            }
        }
        let Some((page, _)) = j.page else {
            return Ok(j);
        };
        let end = self.page_start(page) + Self::PAGE;
        let mut at = self.page_start(page) + PAGE_HEADER;
        let mut buf = EntryBuf::new();
        while at + ENTRY_HEADER as u32 <= end {
            // An entry the flash cannot read (the G431's ECC error on a
            // double word a power cut left half programmed) is one that
            // does not check: the entries before it still count.
            let h = &mut buf.0[..ENTRY_HEADER];
            if self.read(at, h).is_err() {
                return Ok(j);
            }
            if h.iter().all(|&b| b == 0xFF) {
                break;
            }
            let Some(e) = self.entry(at, end, &mut buf) else {
                return Ok(j);
            };
            let slot = usize::from(buf.0[1]);
            if j.sets[slot].is_none_or(|old| e.seq > old.seq) {
                j.sets[slot] = Some(e);
            }
            j.seq = j.seq.max(e.seq);
            at += entry_size(e.len) as u32;
        }
        j.free = Some(at);
        Ok(j)
    }

    /// The entry at `at` whose header is in `buf`, if it is whole and
    /// readable.
    fn entry(&mut self, at: u32, end: u32, buf: &mut EntryBuf) -> Option<Entry> {
        let b = &mut buf.0;
        let len = usize::from(u16::from_le_bytes([b[2], b[3]]));
        let size = entry_size(len);
        if b[0] != ENTRY_MAGIC || b[1] > 1 || !(4..=RECORD_MAX).contains(&len) {
            return None;
        }
        if at + size as u32 > end {
            return None;
        }
        self.read(at + ENTRY_HEADER as u32, &mut b[ENTRY_HEADER..size])
            .ok()?;
        let body = ENTRY_HEADER + len;
        if crc(&b[..body]).to_le_bytes() != b[body..body + 2] {
            return None;
        }
        let seq = u32::from_le_bytes([b[4], b[5], b[6], b[7]]);
        Some(Entry { at, len, seq })
    }

    /// Takes the next page of the ring into use with the other slot's set
    /// and `new` (a sealed entry of `slot`).
    fn turn_page(&mut self, j: &Journal, slot: usize, new: &[u8]) -> Result<(), StorageError> {
        let (page, generation) = j.page.unwrap_or((self.pages() - 1, 0));
        let target = (page + 1) % self.pages();
        let start = self.page_start(target);
        self.flash
            .erase(start, start + Self::PAGE)
            .map_err(flash_error)?;
        let mut at = start + PAGE_HEADER;
        if let Some(e) = j.sets[1 - slot] {
            let mut buf = EntryBuf::new();
            let copy = &mut buf.0[..entry_size(e.len)];
            self.read(e.at, copy)?;
            self.write(at, copy)?;
            at += copy.len() as u32;
        }
        self.write(at, new)?;
        self.write(start, &page_header(generation.wrapping_add(1)))
    }

    /// A region without a journal page but with sets of the layout before
    /// it: copies them into the page that layout left free and makes it the
    /// first journal page. Does nothing on a journal or a blank region.
    fn take_over_old(&mut self) -> Result<(), StorageError> {
        for p in 0..self.pages() {
            if self.generation(p)?.is_some() {
                return Ok(());
            }
        }
        let mut scratch = EntryBuf::new();
        let old = read_old(
            &mut self.flash,
            &self.range,
            &mut scratch.0[..1 + RECORD_MAX],
        )
        .map_err(flash_error)?;
        if old.sets() == [None, None] {
            return Ok(());
        }
        let start = self.page_start(old.free_page());
        self.flash
            .erase(start, start + Self::PAGE)
            .map_err(flash_error)?;
        let mut at = start + PAGE_HEADER;
        for (slot, found) in old.sets().into_iter().enumerate() {
            let Some((from, len)) = found else {
                continue;
            };
            let mut buf = EntryBuf::new();
            self.read(from, &mut buf.0[ENTRY_HEADER..ENTRY_HEADER + len])?;
            let size = buf.seal(slot, len, slot as u32 + 1);
            self.write(at, &buf.0[..size])?;
            at += size as u32;
        }
        self.write(start, &page_header(1))
    }
}

/// The header of a page of `generation`.
fn page_header(generation: u32) -> [u8; PAGE_HEADER as usize] {
    let mut h = [0u8; PAGE_HEADER as usize];
    h[..2].copy_from_slice(&PAGE_MAGIC);
    h[2..6].copy_from_slice(&generation.to_le_bytes());
    let crc = crc(&h[..6]);
    h[6..].copy_from_slice(&crc.to_le_bytes());
    h
}

/// The Modbus CRC, called rather than inlined at each of the store's uses
/// (flash: none of them is on a hot path).
#[inline(never)]
fn crc(bytes: &[u8]) -> u16 {
    crc16(bytes)
}

fn flash_error<E: NorFlashError>(e: E) -> StorageError {
    StorageError::Flash(match e.kind() {
        NorFlashErrorKind::NotAligned => FlashFault::NotAligned,
        NorFlashErrorKind::OutOfBounds => FlashFault::OutOfBounds,
        _ => FlashFault::Other,
    })
}

#[cfg(all(test, feature = "sim"))]
mod tests {
    use super::super::SimFlash;
    use super::*;

    fn set_with(pa10: u16) -> ParamSet {
        let mut s = ParamSet::defaults();
        s.pa_mut().set_unchecked(10, pa10);
        s
    }

    #[test]
    fn blank_flash_boots_with_defaults_and_says_so() {
        let mut store = ParamStore::new(SimFlash::<2>::new(), 0..4096).unwrap();
        let boot = store.boot();
        assert_eq!(boot.outcome, BootOutcome::Blank);
        assert_eq!(boot.set, ParamSet::defaults());
    }

    #[test]
    fn saved_and_backup_sets_are_independent() {
        let mut store = ParamStore::new(SimFlash::<2>::new(), 0..4096).unwrap();
        store.save(Slot::Saved, &set_with(1000)).unwrap();
        store.save(Slot::Backup, &set_with(2000)).unwrap();
        store.save(Slot::Saved, &set_with(3000)).unwrap();
        assert_eq!(store.load(Slot::Saved).unwrap(), Some((set_with(3000), 0)));
        assert_eq!(store.load(Slot::Backup).unwrap(), Some((set_with(2000), 0)));
        // A fresh store over the same flash (a reboot) sees the same.
        let mut store = ParamStore::new(store.into_inner(), 0..4096).unwrap();
        assert_eq!(store.boot().outcome, BootOutcome::Loaded { fixed: 0 });
        assert_eq!(store.boot().set, set_with(3000));
    }

    #[test]
    fn survives_many_page_turns() {
        let mut store = ParamStore::new(SimFlash::<2>::new(), 0..4096).unwrap();
        store.save(Slot::Backup, &set_with(777)).unwrap();
        for i in 0..100 {
            store.save(Slot::Saved, &set_with(200 + i)).unwrap();
            assert_eq!(
                store.load(Slot::Saved).unwrap(),
                Some((set_with(200 + i), 0))
            );
        }
        assert_eq!(store.load(Slot::Backup).unwrap(), Some((set_with(777), 0)));
    }

    #[test]
    fn garbage_in_the_region_is_not_loaded() {
        let mut flash = SimFlash::<2>::new();
        flash.write(0, &[0x00; 64]).unwrap();
        let mut store = ParamStore::new(flash, 0..4096).unwrap();
        let boot = store.boot();
        assert!(
            matches!(
                boot.outcome,
                BootOutcome::Blank | BootOutcome::Unreadable(_)
            ),
            "{:?}",
            boot.outcome
        );
        assert_eq!(boot.set, ParamSet::defaults());
    }

    #[test]
    fn a_record_of_another_firmware_is_unreadable_and_defaults_apply() {
        let mut store = ParamStore::new(SimFlash::<2>::new(), 0..4096).unwrap();
        let mut record = set_with(999).encode();
        record[2] = RECORD_VERSION_NEXT;
        let mut buf = EntryBuf::new();
        buf.0[ENTRY_HEADER..ENTRY_HEADER + RECORD_LEN].copy_from_slice(&record);
        let size = buf.seal(Slot::Saved as usize, RECORD_LEN, 1);
        let journal = store.journal().unwrap();
        store.turn_page(&journal, 0, &buf.0[..size]).unwrap();
        let boot = store.boot();
        assert_eq!(
            boot.outcome,
            BootOutcome::Unreadable(StorageError::Record(RecordError::Version(
                RECORD_VERSION_NEXT
            )))
        );
        assert_eq!(boot.set, ParamSet::defaults());
    }
    const RECORD_VERSION_NEXT: u8 = super::super::RECORD_VERSION + 1;

    #[test]
    fn a_longer_record_of_a_later_firmware_is_kept_through_page_turns() {
        // a downgrade must not lose the other set: its entry is copied as is
        let mut store = ParamStore::new(SimFlash::<2>::new(), 0..4096).unwrap();
        let n = RECORD_MAX;
        let mut buf = EntryBuf::new();
        buf.0[ENTRY_HEADER..ENTRY_HEADER + n].fill(0x33);
        buf.0[ENTRY_HEADER..ENTRY_HEADER + 3].copy_from_slice(&[b'P', b'S', 9]);
        let size = buf.seal(Slot::Backup as usize, n, 1);
        let journal = store.journal().unwrap();
        store.turn_page(&journal, 1, &buf.0[..size]).unwrap();
        for i in 0..30 {
            store.save(Slot::Saved, &set_with(200 + i)).unwrap();
        }
        assert_eq!(store.load(Slot::Saved).unwrap(), Some((set_with(229), 0)));
        assert_eq!(
            store.load(Slot::Backup),
            Err(StorageError::Record(RecordError::Version(9)))
        );
    }

    #[test]
    fn a_bad_region_is_refused() {
        assert!(ParamStore::new(SimFlash::<2>::new(), 0..2048).is_err());
        assert!(ParamStore::new(SimFlash::<2>::new(), 100..4096).is_err());
    }

    #[test]
    fn a_flash_failure_is_reported() {
        let mut store = ParamStore::new(SimFlash::<2>::new(), 0..4096).unwrap();
        store.flash().fail_after(0);
        assert_eq!(
            store.save(Slot::Saved, &set_with(300)),
            Err(StorageError::Flash(FlashFault::Other))
        );
    }
}
