//! The parameter region as the firmware before the journal left it — a
//! `sequential-storage` 8 map, key 0 the saved set and 1 the backup, each
//! value one record — written here by that crate itself, the way that
//! firmware's store did, on both boards' flash geometries. The journal
//! boots on it with both sets kept (SPEC §9: an update keeps the saved set),
//! a cut at any flash operation of the take-over leaves them readable, and a
//! region that firmware left with a save cut short loads its old or its new
//! set.

use core::future::Future;
use core::ops::Range;
use core::pin::pin;
use core::task::{Context, Poll, Waker};

use embedded_storage::nor_flash::NorFlash;
use embedded_storage_async::nor_flash as async_flash;
use modbus_drive::params::{BootOutcome, ParamSet, ParamStore, SimFlash, Slot};
use sequential_storage::cache::{Cache, Uncached};
use sequential_storage::map::{MapConfig, MapStorage};

const REGION: Range<u32> = 0..4096;
type G431 = SimFlash<2>;
type F103 = SimFlash<4, 1024, 2>;

/// A recognisable set.
fn numbered_set(n: u16) -> ParamSet {
    let mut s = ParamSet::defaults();
    s.pa_mut().set_unchecked(10, 200 + n);
    s.pa_mut().set_unchecked(51, 1 + n % 247);
    s.od_mut().set_home_offset(i32::from(n) << 12);
    s.od_mut().set_acceleration(n);
    s
}

const BACKUP: u16 = 9000;

/// The old store's save: one map item, key = slot, value = the record.
fn old_save<F: NorFlash>(flash: &mut F, slot: Slot, set: &ParamSet) -> Result<(), String> {
    #[repr(align(32))]
    struct Buf([u8; 192]);
    let mut buf = Buf([0; 192]);
    let record = set.encode();
    let config = MapConfig::new(REGION);
    let mut map: MapStorage<u8, _, Cache<Uncached, Uncached, Uncached, u8>> =
        MapStorage::new(Blocking(flash), config, Cache::new_uncached());
    block_on(map.store_item(&mut buf.0, &(slot as u8), &&record[..])).map_err(|e| format!("{e:?}"))
}

/// A region the old firmware wrote: the backup, then `history` saves.
fn old_region<F: NorFlash + Default>(history: u16, backup: bool) -> F {
    let mut flash = F::default();
    if backup {
        old_save(&mut flash, Slot::Backup, &numbered_set(BACKUP)).unwrap();
    }
    for n in 0..history {
        old_save(&mut flash, Slot::Saved, &numbered_set(n)).unwrap();
    }
    flash
}

fn check_takeover<const P: usize, const S: usize, const W: usize>() {
    for history in 0..60 {
        for backup in [true, false] {
            let what = format!("{P} x {S} B, history {history}, backup {backup}");
            let flash: SimFlash<P, S, W> = old_region(history, backup);
            let mut store = ParamStore::new(flash, REGION).unwrap();
            let boot = store.boot();
            if history == 0 {
                assert_eq!(boot.outcome(), BootOutcome::Blank, "{what}");
            } else {
                assert_eq!(boot.outcome(), BootOutcome::Loaded { fixed: 0 }, "{what}");
                assert_eq!(*boot.set(), numbered_set(history - 1), "{what}");
            }
            let want_backup = backup.then(|| (numbered_set(BACKUP), 0));
            assert_eq!(store.load(Slot::Backup).unwrap(), want_backup, "{what}");
            // Journal saves around the whole ring erase every old page; the
            // backup survives them and a reboot finds the last save.
            for n in 0..30 {
                store.save(Slot::Saved, &numbered_set(100 + n)).unwrap();
            }
            let mut store = ParamStore::new(store.into_inner(), REGION).unwrap();
            assert_eq!(*store.boot().set(), numbered_set(129), "{what}");
            assert_eq!(store.load(Slot::Backup).unwrap(), want_backup, "{what}");
        }
    }
}

#[test]
fn todays_saved_and_backup_sets_are_kept_by_the_new_store() {
    check_takeover::<2, 2048, 8>();
    check_takeover::<4, 1024, 2>();
}

/// A record of the format before the closed loop (version 1) in the old
/// map: loaded with the following-error entries at their defaults, as the
/// old firmware did.
#[test]
fn a_version_1_record_in_the_old_map_is_kept() {
    let set = numbered_set(7);
    let v2 = set.encode();
    let mut v1 = v2[..v2.len() - 6].to_vec();
    v1[2] = 1;
    let n = v1.len();
    let crc = crc16_modbus(&v1[..n - 2]);
    v1[n - 2..].copy_from_slice(&crc.to_le_bytes());
    let mut flash = G431::new();
    let mut buf = [0u8; 192];
    let mut map: MapStorage<u8, _, Cache<Uncached, Uncached, Uncached, u8>> = MapStorage::new(
        Blocking(&mut flash),
        MapConfig::new(REGION),
        Cache::new_uncached(),
    );
    block_on(map.store_item(&mut buf, &0u8, &&v1[..])).unwrap();
    let mut store = ParamStore::new(flash, REGION).unwrap();
    let boot = store.boot();
    assert_eq!(boot.outcome(), BootOutcome::Loaded { fixed: 0 });
    assert_eq!(*boot.set(), set);
}

fn crc16_modbus(bytes: &[u8]) -> u16 {
    let mut crc = 0xFFFFu16;
    for &b in bytes {
        crc ^= u16::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0xA001
            } else {
                crc >> 1
            };
        }
    }
    crc
}

/// The take-over writes a journal page; a cut at any of its operations
/// leaves the old sets loaded at the next boot, which finishes it.
fn cut_takeover<const P: usize, const S: usize, const W: usize>() -> u32 {
    let mut cuts = 0;
    for history in [1, 3, 9, 10, 11, 12, 20, 31] {
        let base: SimFlash<P, S, W> = old_region(history, true);
        let mut dry = ParamStore::new(base.clone(), REGION).unwrap();
        dry.boot();
        let total = dry.flash().ops() - base.ops();
        assert!(total > 0, "the take-over writes");
        for cut in 0..total {
            let what = format!("{P} x {S} B, history {history}, cut {cut}/{total}");
            let mut flash = base.clone();
            flash.cut_power_after(cut);
            let mut store = ParamStore::new(flash, REGION).unwrap();
            store.boot();
            let mut flash = store.into_inner();
            assert!(!flash.powered(), "{what}: not cut");
            flash.power_up();
            let mut store = ParamStore::new(flash, REGION).unwrap();
            let boot = store.boot();
            assert_eq!(boot.outcome(), BootOutcome::Loaded { fixed: 0 }, "{what}");
            assert_eq!(*boot.set(), numbered_set(history - 1), "{what}");
            assert_eq!(
                store.load(Slot::Backup).unwrap(),
                Some((numbered_set(BACKUP), 0)),
                "{what}"
            );
            store.save(Slot::Saved, &numbered_set(777)).unwrap();
            assert_eq!(*store.boot().set(), numbered_set(777), "{what}");
            cuts += 1;
        }
    }
    cuts
}

#[test]
fn a_cut_during_the_take_over_keeps_todays_sets() {
    let cuts = cut_takeover::<2, 2048, 8>() + cut_takeover::<4, 1024, 2>();
    println!("take-over cut at {cuts} flash operations: every reboot loaded the old sets");
}

/// The old firmware cut inside a save (item writes, page closes, item moves,
/// erases): the new store loads the old or the new saved set and the backup.
fn cut_old_save<F: NorFlash + Default + Clone + Cut>() -> u32 {
    let mut cuts = 0;
    for history in 0..40 {
        let base: F = old_region(history, true);
        let old = (history > 0).then(|| numbered_set(history - 1));
        let new = numbered_set(5000);
        let mut dry = base.clone();
        let before = dry.op_count();
        old_save(&mut dry, Slot::Saved, &new).unwrap();
        let total = dry.op_count() - before;
        for cut in 0..total {
            let what = format!("history {history}, cut {cut}/{total}");
            let mut flash = base.clone();
            flash.cut_at(cut);
            assert!(old_save(&mut flash, Slot::Saved, &new).is_err(), "{what}");
            flash.restore_power();
            let mut store = ParamStore::new(flash, REGION).unwrap();
            let boot = store.boot();
            match &old {
                None if boot.outcome() == BootOutcome::Blank => {}
                _ => {
                    assert_eq!(boot.outcome(), BootOutcome::Loaded { fixed: 0 }, "{what}");
                    assert!(
                        Some(boot.set()) == old.as_ref() || *boot.set() == new,
                        "{what}: {:?}",
                        boot.set()
                    );
                }
            }
            assert_eq!(
                store.load(Slot::Backup).unwrap(),
                Some((numbered_set(BACKUP), 0)),
                "{what}"
            );
            cuts += 1;
        }
    }
    cuts
}

#[test]
fn a_save_todays_firmware_cut_short_loads_the_old_or_the_new_set() {
    let cuts = cut_old_save::<G431>() + cut_old_save::<F103>();
    println!("old map cut at {cuts} flash operations of a save: old or new set loaded");
}

/// The power-cut controls of both geometries.
trait Cut {
    fn op_count(&self) -> u32;
    fn cut_at(&mut self, n: u32);
    fn restore_power(&mut self);
}

impl<const P: usize, const S: usize, const W: usize> Cut for SimFlash<P, S, W> {
    fn op_count(&self) -> u32 {
        self.ops()
    }
    fn cut_at(&mut self, n: u32) {
        self.cut_power_after(n);
    }
    fn restore_power(&mut self) {
        self.power_up();
    }
}

/// A blocking flash as `embedded-storage-async` (the old store's adapter).
struct Blocking<'f, F>(&'f mut F);

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

/// The old store's futures never wait: the first poll finishes them.
fn block_on<T>(fut: impl Future<Output = T>) -> T {
    let mut fut = pin!(fut);
    let mut cx = Context::from_waker(Waker::noop());
    loop {
        if let Poll::Ready(v) = fut.as_mut().poll(&mut cx) {
            return v;
        }
    }
}
