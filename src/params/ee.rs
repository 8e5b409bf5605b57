//! The EE operations of seed 001 (SPEC §9) on a working set and a store.
//!
//! | code | name | effect |
//! |---|---|---|
//! | 1 | EE-Set | save the working set |
//! | 2 | EE-rd | working set := saved set (defaults if none was ever saved) |
//! | 3 | EE-bA | backup set := working set |
//! | 4 | EE-rS | saved set := backup set, then working set := it |
//! | 5 | EE-dEF | saved set := defaults, then working set := defaults |
//!
//! Each is all-or-nothing towards the working set: it changes only after the
//! flash did what the operation needs; on an error (→ exception 4) the
//! working set is as before and the flash holds the old or the new set
//! (storage.rs). How the frames reach this and how the deferred reply is
//! produced: [`crate::Device::poll_storage`].

use embedded_storage::nor_flash::NorFlash;

pub use crate::dictionary::EeOp;
use crate::dictionary::{OdValues, Params};

use super::record::ParamSet;
use super::storage::{ParamStore, Slot, StorageError};

/// Why an EE operation failed (the master sees exception 4, or 6 for
/// [`EeError::StepsRunning`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EeError {
    /// The flash or the store failed.
    Storage(StorageError),
    /// EE-rS without a backup ever made with EE-bA.
    NoBackup,
    /// Refused, nothing changed: steps were being generated when it was to
    /// run (SPEC §9; flash work would stall the step interrupt).
    StepsRunning,
}

impl From<StorageError> for EeError {
    fn from(e: StorageError) -> Self {
        Self::Storage(e)
    }
}

/// An EE operation accepted but not yet run, with the reply it will get.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PendingEe {
    op: EeOp,
    /// The success reply the dispatcher built (the 0x10 reply, or the echo
    /// of the old 0x06 frame); `None` for a broadcast.
    reply: Option<([u8; EE_REPLY_MAX], u8)>,
}

/// Longest EE success reply: `addr 10 00 3A 00 01 CRC` / `addr 06 … CRC`.
pub const EE_REPLY_MAX: usize = 8;

impl PendingEe {
    /// `reply`: the dispatcher's reply to the request, `None` when it was a
    /// broadcast. A reply longer than an EE reply is not kept.
    /// The operation to run.
    #[inline]
    pub const fn op(&self) -> EeOp {
        self.op
    }

    pub fn new(op: EeOp, reply: Option<&[u8]>) -> Self {
        let reply = reply.filter(|r| r.len() <= EE_REPLY_MAX).map(|r| {
            let mut b = [0; EE_REPLY_MAX];
            b[..r.len()].copy_from_slice(r);
            (b, r.len() as u8)
        });
        Self { op, reply }
    }

    /// The success reply, if the request was not a broadcast.
    pub fn reply(&self) -> Option<&[u8]> {
        self.reply.as_ref().map(|(b, n)| &b[..usize::from(*n)])
    }
}

/// Runs `op` on the working set (`pa`, `od`) and the store.
pub fn execute<F: NorFlash>(
    op: EeOp,
    pa: &mut Params,
    od: &mut OdValues,
    store: &mut ParamStore<F>,
) -> Result<(), EeError> {
    match op {
        EeOp::Save => store.save(Slot::Saved, &ParamSet::from_working(pa, od))?,
        EeOp::Backup => store.save(Slot::Backup, &ParamSet::from_working(pa, od))?,
        EeOp::Reload => {
            let set = match store.load(Slot::Saved)? {
                Some((set, _fixed)) => set,
                None => ParamSet::defaults(),
            };
            set.apply_to(pa, od);
        }
        EeOp::RestoreBackup => {
            let (set, _fixed) = store.load(Slot::Backup)?.ok_or(EeError::NoBackup)?;
            store.save(Slot::Saved, &set)?;
            set.apply_to(pa, od);
        }
        EeOp::RestoreDefaults => {
            let set = ParamSet::defaults();
            store.save(Slot::Saved, &set)?;
            set.apply_to(pa, od);
        }
    }
    Ok(())
}

#[cfg(all(test, feature = "sim"))]
mod tests {
    use super::super::SimFlash;
    use super::*;

    struct Rig {
        pa: Params,
        od: OdValues,
        store: ParamStore<SimFlash<2>>,
    }

    impl Rig {
        fn new() -> Self {
            Self {
                pa: Params::defaults(),
                od: OdValues::default(),
                store: ParamStore::new(SimFlash::new(), 0..4096).unwrap(),
            }
        }
        fn run(&mut self, op: EeOp) -> Result<(), EeError> {
            execute(op, &mut self.pa, &mut self.od, &mut self.store)
        }
    }

    #[test]
    fn codes_are_those_of_seed_001() {
        for (code, op) in [
            (1, EeOp::Save),
            (2, EeOp::Reload),
            (3, EeOp::Backup),
            (4, EeOp::RestoreBackup),
            (5, EeOp::RestoreDefaults),
        ] {
            assert_eq!(EeOp::from_code(code), Some(op));
            assert_eq!(op.code(), code);
        }
        assert_eq!(EeOp::from_code(0), None);
        assert_eq!(EeOp::from_code(6), None);
    }

    #[test]
    fn set_then_rd_restores_the_saved_values() {
        let mut r = Rig::new();
        r.pa.set_unchecked(10, 400);
        r.od.set_acceleration(50);
        r.run(EeOp::Save).unwrap();
        r.pa.set_unchecked(10, 800);
        r.od.set_acceleration(60);
        r.run(EeOp::Reload).unwrap();
        assert_eq!((r.pa.get(10), r.od.acceleration()), (400, 50));
    }

    #[test]
    fn rd_on_a_blank_store_loads_defaults() {
        let mut r = Rig::new();
        r.pa.set_unchecked(10, 400);
        r.run(EeOp::Reload).unwrap();
        assert_eq!(r.pa, Params::defaults());
    }

    #[test]
    fn ba_then_rs_restores_and_saves_the_backup() {
        let mut r = Rig::new();
        r.pa.set_unchecked(10, 1000);
        r.run(EeOp::Backup).unwrap();
        r.pa.set_unchecked(10, 2000);
        r.run(EeOp::Save).unwrap();
        r.run(EeOp::RestoreBackup).unwrap();
        assert_eq!(r.pa.get(10), 1000);
        r.pa.set_unchecked(10, 3000);
        r.run(EeOp::Reload).unwrap();
        assert_eq!(r.pa.get(10), 1000, "EE-rS saved the backup");
    }

    #[test]
    fn rs_without_backup_fails_and_changes_nothing() {
        let mut r = Rig::new();
        r.pa.set_unchecked(10, 1234);
        assert_eq!(r.run(EeOp::RestoreBackup), Err(EeError::NoBackup));
        assert_eq!(r.pa.get(10), 1234);
    }

    #[test]
    fn def_restores_and_saves_defaults_but_keeps_the_backup() {
        let mut r = Rig::new();
        r.pa.set_unchecked(51, 9);
        r.run(EeOp::Backup).unwrap();
        r.run(EeOp::Save).unwrap();
        r.run(EeOp::RestoreDefaults).unwrap();
        assert_eq!(r.pa, Params::defaults());
        assert_eq!(*r.store.boot().set(), ParamSet::defaults());
        r.run(EeOp::RestoreBackup).unwrap();
        assert_eq!(r.pa.get(51), 9);
    }

    #[test]
    fn a_flash_failure_leaves_the_working_set_alone() {
        let mut r = Rig::new();
        r.run(EeOp::Backup).unwrap();
        r.pa.set_unchecked(10, 5000);
        r.store.flash().fail_after(0);
        assert!(matches!(
            r.run(EeOp::RestoreBackup),
            Err(EeError::Storage(_))
        ));
        assert_eq!(r.pa.get(10), 5000);
        assert!(matches!(
            r.run(EeOp::RestoreDefaults),
            Err(EeError::Storage(_))
        ));
        assert_eq!(r.pa.get(10), 5000);
    }
}
