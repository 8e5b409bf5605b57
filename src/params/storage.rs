//! Power-loss-safe parameter storage over `embedded-storage`'s blocking
//! [`NorFlash`] (SPEC §9).
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
//!   (also `&mut F`). The range is in the flash's own offsets, page aligned,
//!   at least two erase pages. Only this range is ever read, written or
//!   erased. Any `WRITE_SIZE` up to 32 bytes works; erase pages must hold at
//!   least one record (~190 bytes), 2 KiB pages hold ten.
//! * [`ParamStore::load`] / [`ParamStore::save`] read and write one of the
//!   two sets, [`Slot::Saved`] (EE-Set / EE-rd) and [`Slot::Backup`]
//!   (EE-bA / EE-rS). The EE operations are [`super::execute`], which
//!   [`crate::Device::poll_storage`] runs for the EE frames.
//! * The virtual drive's state file is the raw image of the region: load it
//!   with [`super::SimFlash::from_image`], hand the `SimFlash` to this store,
//!   write [`super::SimFlash::image`] back after each EE operation (write a
//!   temporary file and rename it, so the file itself is replaced atomically).
//!
//! # Layout and power-loss argument
//!
//! The region is a [`sequential_storage`] map with two keys, 0 = saved set and
//! 1 = backup set; each value is one [`ParamSet`] record (156 bytes, own
//! version, length and CRC-16, `record.rs`). A save *appends* a new item: the
//! crate writes the item header (length with its CRC-16, data CRC-32) and
//! then the data; a fetch returns the last item of the key whose header and
//! data CRCs check, so an item cut short is skipped and the previous one is
//! found. When a page is full the crate moves the live items to the next page
//! before it erases the old page, and it marks page states in the first/last
//! word of each page so that an interrupted move is redone at the next
//! operation (its "repair"). Either way one set is one item, so a cut at any
//! instant leaves the complete old or the complete new set — never a mix —
//! and our own record CRC refuses anything else as garbage. The tests in
//! `tests/params_power_loss.rs` cut an EE-Set, EE-rS and EE-dEF at every word
//! write and page erase to show it.
//!
//! Wear: each save writes ~200 bytes; a 2 KiB page takes 10 before it is
//! erased, so 10,000 saves cost ~1,000 erases over a two-page region, ~500 per
//! page (STM32G4: 10,000 cycles guaranteed).
//!
//! `sequential-storage` 8 is async-only; the flash here is blocking, so
//! [`Blocking`] presents it as `embedded-storage-async` and [`block_on`] polls
//! the future, which is ready on its first poll (nothing in it waits).

use core::future::Future;
use core::ops::Range;
use core::pin::pin;
use core::task::{Context, Poll, Waker};

use embedded_storage::nor_flash::{NorFlash, NorFlashError, NorFlashErrorKind};
use embedded_storage_async::nor_flash as async_flash;
use sequential_storage::cache::Cache;
use sequential_storage::map::{MapConfig, MapStorage};

use super::record::{ParamSet, RecordError, RECORD_LEN};

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
    /// The region's layout is broken beyond the crate's repair.
    Corrupted,
    /// No room left (cannot happen with two sets in ≥ 2 pages of ≥ 512 B).
    Full,
    /// An item was found but is not a valid record of this firmware.
    Record(RecordError),
    /// The region is not page aligned, smaller than two pages, or the
    /// pages are too small; or the crate reported a logic error.
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
    pub set: ParamSet,
    pub outcome: BootOutcome,
}

/// The parameter store on a flash region.
pub struct ParamStore<F> {
    flash: F,
    range: Range<u32>,
}

/// Working buffer of the map: key (1 byte) + record, rounded up to the
/// largest word size the crate supports; word aligned for flash drivers
/// that need aligned source buffers.
#[repr(align(32))]
struct ItemBuffer([u8; ITEM_BUFFER]);
const ITEM_BUFFER: usize = 192;
const _: () = assert!((1 + RECORD_LEN).next_multiple_of(32) <= ITEM_BUFFER);

impl<F: NorFlash> ParamStore<F> {
    /// A store on `range` (page aligned, ≥ 2 erase pages) of `flash`.
    pub fn new(flash: F, range: Range<u32>) -> Result<Self, StorageError> {
        MapConfig::<Blocking<'_, F>>::try_new(range.clone()).map_err(|_| StorageError::Config)?;
        if F::ERASE_SIZE < 2 * ITEM_BUFFER {
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
        let range = self.range.clone();
        let mut buf = ItemBuffer([0; ITEM_BUFFER]);
        let found = block_on(async {
            let mut map = map(&mut self.flash, range);
            map.fetch_item::<&[u8]>(&mut buf.0, &(slot as u8)).await
        })
        .map_err(StorageError::from)?;
        match found {
            None => Ok(None),
            Some(bytes) => ParamSet::decode(bytes)
                .map(Some)
                .map_err(StorageError::Record),
        }
    }

    /// Writes one set; after a power cut at any point inside, [`Self::load`]
    /// returns the complete previous set or the complete new one.
    pub fn save(&mut self, slot: Slot, set: &ParamSet) -> Result<(), StorageError> {
        let range = self.range.clone();
        let record = set.encode();
        let mut buf = ItemBuffer([0; ITEM_BUFFER]);
        block_on(async {
            let mut map = map(&mut self.flash, range);
            map.store_item(&mut buf.0, &(slot as u8), &&record[..])
                .await
        })
        .map_err(StorageError::from)
    }

    /// At power-up: the saved set, or the defaults and why (SPEC §9).
    pub fn boot(&mut self) -> Boot {
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
}

type Map<'f, F> = MapStorage<u8, Blocking<'f, F>, Cache<Uncached, Uncached, Uncached, u8>>;
use sequential_storage::cache::Uncached;

/// A map over the region. Uncached: all state is in flash, so a map made
/// for each operation is always consistent with it (and a reboot is no
/// different from the next operation).
fn map<F: NorFlash>(flash: &mut F, range: Range<u32>) -> Map<'_, F> {
    // `new` checked the range, so the fallback is never taken.
    let config = match MapConfig::try_new(range.clone()) {
        Ok(c) => c,
        Err(_) => MapConfig::new(0..0),
    };
    MapStorage::new(Blocking(flash), config, Cache::new_uncached())
}

impl<E: NorFlashError> From<sequential_storage::Error<E>> for StorageError {
    fn from(e: sequential_storage::Error<E>) -> Self {
        use sequential_storage::Error as S;
        match e {
            S::Storage { value, .. } => Self::Flash(match value.kind() {
                NorFlashErrorKind::NotAligned => FlashFault::NotAligned,
                NorFlashErrorKind::OutOfBounds => FlashFault::OutOfBounds,
                _ => FlashFault::Other,
            }),
            S::FullStorage | S::ItemTooBig => Self::Full,
            S::Corrupted { .. } => Self::Corrupted,
            S::SerializationError(_) => Self::Record(RecordError::Malformed),
            _ => Self::Config,
        }
    }
}

/// A blocking [`NorFlash`] seen as an `embedded-storage-async` one: every
/// future it returns is ready at once.
pub struct Blocking<'f, F>(&'f mut F);

impl<F: NorFlash> async_flash::ErrorType for Blocking<'_, F> {
    type Error = F::Error;
}

impl<F: NorFlash> async_flash::ReadNorFlash for Blocking<'_, F> {
    const READ_SIZE: usize = F::READ_SIZE;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.0.read(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.0.capacity()
    }
}

impl<F: NorFlash> async_flash::NorFlash for Blocking<'_, F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.0.erase(from, to)
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.0.write(offset, bytes)
    }
}

/// Runs a future to completion by polling it (no_std, no executor). The
/// futures of this module never wait, so the first poll finishes them.
pub fn block_on<T>(fut: impl Future<Output = T>) -> T {
    let mut fut = pin!(fut);
    let mut cx = Context::from_waker(Waker::noop());
    loop {
        if let Poll::Ready(v) = fut.as_mut().poll(&mut cx) {
            return v;
        }
    }
}

#[cfg(all(test, feature = "sim"))]
mod tests {
    use super::super::SimFlash;
    use super::*;

    fn set_with(pa10: u16) -> ParamSet {
        let mut s = ParamSet::defaults();
        s.pa.set_unchecked(10, pa10);
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
        let mut buf = ItemBuffer([0; ITEM_BUFFER]);
        block_on(map(store.flash(), 0..4096).store_item(
            &mut buf.0,
            &(Slot::Saved as u8),
            &&record[..],
        ))
        .unwrap();
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
