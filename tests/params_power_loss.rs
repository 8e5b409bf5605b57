//! SPEC §9: "Saved data survives power loss at any instant: after a cut,
//! either the old or the new parameter set is loaded, never a mix or
//! garbage." Every EE operation that writes (EE-Set, EE-rS, EE-dEF) is cut
//! at each of its word writes and page erases, from many fill levels of the
//! two-page region (so the cuts also hit page turns: erases, copies and
//! page headers); then the drive "reboots" (a fresh store over the same cells)
//! and must load the complete old or the complete new saved set, with the
//! backup set untouched, and must still save afterwards.
//!
//! Also the wear budget: 10,000 EE-Sets on two STM32G4 pages.

use modbus_drive::dictionary::OdValues;
use modbus_drive::params::{
    execute, BootOutcome, EeOp, ParamSet, ParamStore, Params, SimFlash, Slot,
};

/// Both boards' regions: 4 KiB as two STM32G4 pages (2 KiB, programmed in
/// 8-byte words) and as four STM32F1 pages (1 KiB, 2-byte half-words).
const REGION: core::ops::Range<u32> = 0..4096;
type Flash = SimFlash<2>;
type F103Flash = SimFlash<4, 1024, 2>;

/// The flash geometries the sweep runs on.
trait Geometry: Clone + embedded_storage::nor_flash::NorFlash {
    const NAME: &str;
    fn blank() -> Self;
    fn zero_overwrite(&mut self, allowed: bool);
    fn ops(&self) -> u32;
    fn erases(&self) -> u32;
    fn cut_power_after(&mut self, n: u32);
    fn power_up(&mut self);
}

impl<const P: usize, const S: usize, const W: usize> Geometry for SimFlash<P, S, W> {
    const NAME: &str = if S == 2048 { "" } else { " (STM32F1 pages)" };
    fn blank() -> Self {
        Self::new()
    }
    fn zero_overwrite(&mut self, allowed: bool) {
        self.set_zero_overwrite(allowed);
    }
    fn ops(&self) -> u32 {
        SimFlash::ops(self)
    }
    fn erases(&self) -> u32 {
        self.erase_counts().iter().sum()
    }
    fn cut_power_after(&mut self, n: u32) {
        SimFlash::cut_power_after(self, n);
    }
    fn power_up(&mut self) {
        SimFlash::power_up(self);
    }
}

/// A recognisable set: every saved field derived from `n`.
fn numbered_set(n: u16) -> ParamSet {
    let mut s = ParamSet::defaults();
    s.pa_mut().set_unchecked(10, 200 + n);
    s.pa_mut().set_unchecked(12, 1 + n % 6000);
    s.pa_mut().set_unchecked(51, 1 + n % 247);
    s.pa_mut().set_unchecked(40, n.wrapping_mul(7)); // reserved, stored as is
    s.od_mut().set_profile_velocity(-i32::from(n) * 3);
    s.od_mut().set_home_offset(i32::from(n) << 12);
    s.od_mut().set_homing_speed(u32::from(n) * 11);
    s.od_mut().set_acceleration(n);
    s
}

fn working(set: &ParamSet) -> (Params, OdValues) {
    let mut pa = Params::defaults();
    let mut od = OdValues::default();
    set.apply_to(&mut pa, &mut od);
    (pa, od)
}

/// A flash that has seen `history` saves of the saved set (and a backup).
/// `strict`: no all-zero overwrite (the bare `NorFlash` contract) instead
/// of the STM32G4 rule.
fn prepared<G: Geometry>(history: u16, strict: bool) -> G {
    let mut flash = G::blank();
    flash.zero_overwrite(!strict);
    let mut store = ParamStore::new(flash, REGION).unwrap();
    store.save(Slot::Backup, &numbered_set(9000)).unwrap();
    for n in 0..history {
        store.save(Slot::Saved, &numbered_set(n)).unwrap();
    }
    store.into_inner()
}

/// What the saved set is before and after `op` run on `working_set`.
fn expected(op: EeOp, before: &ParamSet, working_set: &ParamSet) -> ParamSet {
    match op {
        EeOp::Save => working_set.clone(),
        EeOp::RestoreBackup => numbered_set(9000),
        EeOp::RestoreDefaults => ParamSet::defaults(),
        _ => before.clone(),
    }
}

/// Cuts `op` at every operation of the flash.
fn cut_everywhere<G: Geometry>(op: EeOp, history: u16, strict: bool) -> Sweep {
    let base: G = prepared(history, strict);
    let old = ParamStore::new(base.clone(), REGION)
        .unwrap()
        .boot()
        .into_set();
    let new_working = numbered_set(5000 + history);
    let new = expected(op, &old, &new_working);
    // (EE-dEF on a blank store saves what the blank store already means.)
    assert!(!new.same_saved_values(&old) || history == 0);

    // Dry run: how many flash operations the EE operation takes here.
    let mut store = ParamStore::new(base.clone(), REGION).unwrap();
    let (mut pa, mut od) = working(&new_working);
    let before = store.flash().ops();
    execute(op, &mut pa, &mut od, &mut store).unwrap();
    let total = store.flash().ops() - before;
    let erases = store.flash().erases() - base.erases();
    assert!(total > 0);
    let mut stuck = 0;

    for cut in 0..total {
        let mut flash = base.clone();
        flash.cut_power_after(cut);
        let mut store = ParamStore::new(flash, REGION).unwrap();
        let (mut pa, mut od) = working(&new_working);
        let res = execute(op, &mut pa, &mut od, &mut store);
        assert!(res.is_err(), "{op:?} history {history} cut {cut}: not cut");

        // Reboot.
        let mut flash = store.into_inner();
        flash.power_up();
        let mut store = ParamStore::new(flash, REGION).unwrap();
        let boot = store.boot();
        let what = format!(
            "{op:?} history {history} cut {cut}/{total}: {:?}",
            boot.outcome()
        );
        if history == 0 && boot.outcome() == BootOutcome::Blank {
            // Nothing was saved before: "old" is the blank store.
        } else {
            assert_eq!(boot.outcome(), BootOutcome::Loaded { fixed: 0 }, "{what}");
            assert!(
                *boot.set() == old || *boot.set() == new,
                "{what}: neither the old nor the new set: {:?}",
                boot.set()
            );
        }
        assert_eq!(
            store.load(Slot::Backup).unwrap(),
            Some((numbered_set(9000), 0)),
            "{what}: backup damaged"
        );
        // The store still works after the cut.
        match store.save(Slot::Saved, &numbered_set(7777)) {
            Ok(()) => assert_eq!(*store.boot().set(), numbered_set(7777), "{what}"),
            Err(e) if strict => {
                stuck += 1;
                // Even a store that cannot write any more loads a whole set.
                let set = store.boot().into_set();
                assert!(
                    set == old || set == new || set == ParamSet::defaults(),
                    "{what}"
                );
                let _ = e;
            }
            Err(e) => panic!("{what}: save after cut: {e:?}"),
        }
    }
    Sweep {
        cuts: total,
        erase_cuts: erases,
        stuck,
    }
}

#[derive(Default)]
struct Sweep {
    /// Cut points tried.
    cuts: u32,
    /// Of them, inside a page erase.
    erase_cuts: u32,
    /// After the cut and reboot, a save failed (strict flash only).
    stuck: u32,
}

/// Start states: blank saved set, then every fill level over five full
/// turns of the two pages (~10 records per page).
const HISTORIES: core::ops::Range<u16> = 0..100;

fn sweep<G: Geometry>(op: EeOp, strict: bool) -> Sweep {
    let mut all = Sweep::default();
    for history in HISTORIES {
        let s = cut_everywhere::<G>(op, history, strict);
        all.cuts += s.cuts;
        all.erase_cuts += s.erase_cuts;
        all.stuck += s.stuck;
    }
    println!(
        "SPEC §9 power loss, {op:?}{}{}: {} cut points over {} start states \
         ({} inside a page erase); every reboot loaded the old or the new set; \
         {} left a store that could not save again",
        if strict {
            " (strict write-once flash)"
        } else {
            ""
        },
        G::NAME,
        all.cuts,
        HISTORIES.len(),
        all.erase_cuts,
        all.stuck,
    );
    // Each op writes at least one record (≥ 20 double words) per start state,
    // and the sweep crosses page turns, so erases were cut too.
    assert!(all.cuts >= 20 * HISTORIES.len() as u32);
    assert!(all.erase_cuts >= 8);
    all
}

#[test]
fn ee_set_cut_at_every_point_loads_old_or_new() {
    assert_eq!(sweep::<Flash>(EeOp::Save, false).stuck, 0);
}

#[test]
fn ee_rs_cut_at_every_point_loads_old_or_new() {
    assert_eq!(sweep::<Flash>(EeOp::RestoreBackup, false).stuck, 0);
}

#[test]
fn ee_def_cut_at_every_point_loads_old_or_new() {
    assert_eq!(sweep::<Flash>(EeOp::RestoreDefaults, false).stuck, 0);
}

/// On a flash that never allows a second write to a word (not the STM32G4
/// rule, which lets zeros be written over anything): the journal never
/// writes a word twice, so every cut still leaves a store that saves again.
#[test]
fn strict_write_once_flash_still_loads_old_or_new() {
    assert_eq!(sweep::<Flash>(EeOp::Save, true).stuck, 0);
}

/// The F103's region: four 1 KiB pages programmed in half-words, so a cut
/// falls between any two half-words of an entry and the ring has four pages.
#[test]
fn f103_pages_cut_at_every_point_load_old_or_new() {
    for op in [EeOp::Save, EeOp::RestoreBackup, EeOp::RestoreDefaults] {
        assert_eq!(sweep::<F103Flash>(op, false).stuck, 0, "{op:?}");
    }
}

/// STM32G4 flash: 10,000 program/erase cycles guaranteed per page.
const ERASE_BUDGET: u32 = 10_000;

#[test]
fn ten_thousand_ee_sets_stay_within_the_erase_budget() {
    wear::<2, 2048, 8>();
    // STM32F103: also 10,000 cycles (DS5319)
    wear::<4, 1024, 2>();
}

fn wear<const P: usize, const S: usize, const W: usize>() {
    let mut store = ParamStore::new(SimFlash::<P, S, W>::new(), REGION).unwrap();
    let (mut pa, mut od) = working(&ParamSet::defaults());
    execute(EeOp::Backup, &mut pa, &mut od, &mut store).unwrap();
    for n in 0..10_000u16 {
        pa.set_unchecked(10, 200 + n % 50_000);
        execute(EeOp::Save, &mut pa, &mut od, &mut store).unwrap();
    }
    let erases = store.flash().erase_counts();
    println!(
        "wear: 10000 EE-Set on {P} x {S} B pages: erases per page {erases:?} (budget {ERASE_BUDGET})"
    );
    assert_eq!(store.boot().set().pa().get(10), 200 + 9_999);
    for e in erases {
        assert!(e > 0, "every page is used");
        assert!(
            e <= ERASE_BUDGET / 10,
            "{e} erases: over a tenth of the budget"
        );
    }
}
