//! EE operations and a moving axis (SPEC §9): an EE operation requested
//! while steps are being generated (statusword bit 9) is refused with
//! exception 6 and changes nothing; the move goes on to its target, and the
//! same request succeeds once the axis is at rest. Flash work stalls the
//! processor, so the firmware must never start it under a moving axis.

mod common;

use common::axis::Rig;
use common::*;
use modbus_drive::device::{Device, Identity};
use modbus_drive::dictionary::DriveLayer;
use modbus_drive::event::Event;
use modbus_drive::motion::sim::SimAxis;
use modbus_drive::params::{EeError, EeOp, ParamStore, SimFlash, Slot};

type Store = ParamStore<SimFlash<2>>;

const RUNNING: u16 = 1 << 9;
const TARGET: i32 = 200_000;

fn store() -> Store {
    ParamStore::new(SimFlash::new(), 0..4096).unwrap()
}

/// A drive booted from `store`, enabled, on a simulated axis.
fn rig(store: &mut Store) -> Rig {
    let mut device = Device::new(Identity::new(TEST_HARDWARE));
    device.apply_boot(&store.boot());
    let mut rig = Rig::with_bus(Bus::with_device(device), SimAxis::new(10_000_000));
    rig.controlword(0x000F);
    rig.bus.events();
    rig
}

fn ee_new(k: u8) -> Vec<u8> {
    frame(1, &[0x10, 0x00, 0x3A, 0x00, 0x01, 0x02, 0x00, k])
}

fn ee_old(k: u8) -> Vec<u8> {
    frame(1, &[0x06, 0x00, 0x00, 0x00, k])
}

/// Diagnostics 0x08 sub-function `sub` (a §6 counter).
fn counter(rig: &mut Rig, sub: u8) -> u16 {
    let r = rig
        .bus
        .send(&frame(1, &[0x08, 0x00, sub, 0x00, 0x00]))
        .expect("diagnostics reply");
    u16::from_be_bytes([r[4], r[5]])
}

/// Runs to rest and checks the move reached its target, step for step.
fn finish_move(rig: &mut Rig) {
    rig.run_until(5_000_000, |r| r.at_rest());
    rig.run_us(2_000);
    assert_eq!(rig.axis.position(), i64::from(TARGET), "every step made");
    assert_eq!(rig.position(), TARGET, "0x6064 = distance");
    assert_eq!(rig.statusword() & RUNNING, 0);
}

#[test]
fn ee_requests_mid_move_get_6_change_nothing_and_work_at_rest() {
    let mut s = store();
    let mut rig = rig(&mut s);
    // a working-set change the refused saves must not store
    rig.bus.write_single(0x0064 + 56, 3).expect("PA56 accepted");
    rig.start_position_move(TARGET);
    rig.run_us(50_000);
    assert_ne!(rig.statusword() & RUNNING, 0, "steps are being generated");
    let busy_before = counter(&mut rig, 0x11);

    for k in 1..=5 {
        assert_eq!(
            rig.bus.send(&ee_new(k)),
            Some(exception(1, 0x10, 6)),
            "new format EE {k} while moving"
        );
        assert_eq!(
            rig.bus.send(&ee_old(k)),
            Some(exception(1, 0x06, 6)),
            "old format EE {k} while moving"
        );
        assert!(!rig.bus.device.busy(), "nothing waits");
        assert_eq!(rig.bus.device.pending_ee(), None);
        rig.run_us(1_000);
    }
    assert_eq!(counter(&mut rig, 0x11), busy_before + 10, "§6 busy counter");
    assert_eq!(rig.bus.poll_storage(&mut s), None, "nothing to run");
    assert_eq!(s.load(Slot::Saved), Ok(None), "the flash was not touched");
    assert_eq!(
        rig.bus.read(0x0064 + 56, 1),
        Ok(vec![3]),
        "EE-rd/dEF did nothing"
    );
    // the master still drives the axis meanwhile
    assert!(rig.bus.read(0x6064, 2).is_ok());

    finish_move(&mut rig);

    // at rest the same request is run and answered
    assert_eq!(
        rig.bus.send(&ee_new(1)),
        None,
        "the reply waits for the flash"
    );
    assert_eq!(
        rig.bus.poll_storage(&mut s),
        Some(frame(1, &[0x10, 0x00, 0x3A, 0x00, 0x01]))
    );
    let (saved, _) = s.load(Slot::Saved).unwrap().expect("a saved set");
    let mut pa = modbus_drive::params::Params::defaults();
    let mut od = modbus_drive::dictionary::OdValues::default();
    saved.apply_to(&mut pa, &mut od);
    assert_eq!(pa.get(56), 3);
}

#[test]
fn ee_accepted_at_rest_is_refused_when_steps_run_at_its_turn() {
    // The move is commanded, the EE request follows before the control loop
    // has queued a step (bit 9 still 0): accepted. When its turn comes the
    // axis is moving, so it is refused then, with nothing changed.
    let mut s = store();
    let mut rig = rig(&mut s);
    rig.bus.write_single(0x6060, 1).unwrap();
    rig.write_i32(0x6081, 100);
    rig.write(0x6083, &[1000, 1000, 2000]);
    rig.write_i32(0x607A, TARGET);
    rig.bus.write_single(0x6040, 0x001F).unwrap(); // no control step yet
    assert_eq!(rig.statusword() & RUNNING, 0);
    assert_eq!(rig.bus.send(&ee_new(1)), None, "accepted, reply deferred");
    assert_eq!(rig.bus.device.pending_ee(), Some(EeOp::Save));
    rig.control(); // the control loop queues the first steps
    rig.run_us(1_000);
    // (register reads get 6 while the operation waits: ask the drive layer)
    assert_ne!(rig.bus.device.drive().statusword() & RUNNING, 0);
    rig.bus.events();
    assert_eq!(rig.bus.poll_storage(&mut s), Some(exception(1, 0x10, 6)));
    assert!(rig.bus.events().contains(&Event::EeDone {
        op: EeOp::Save,
        error: Some(EeError::StepsRunning),
    }));
    assert_eq!(s.load(Slot::Saved), Ok(None), "the flash was not touched");
    rig.bus.write_single(0x6040, 0x000F).unwrap();
    finish_move(&mut rig);
    assert_eq!(rig.bus.send(&ee_old(1)), None);
    assert_eq!(
        rig.bus.poll_storage(&mut s),
        Some(ee_old(1)),
        "echo once saved"
    );
    assert!(s.load(Slot::Saved).unwrap().is_some());
}

#[test]
fn the_glue_refuses_a_waiting_ee_operation_when_its_step_output_is_busy() {
    // The firmware checks its own step schedule before any flash work and
    // refuses through Device::refuse_storage.
    let mut s = store();
    let mut rig = rig(&mut s);
    assert_eq!(rig.bus.send(&ee_new(5)), None);
    rig.bus.events();
    let mut reply = [0u8; modbus_drive::rtu::MAX_FRAME];
    let r = rig.bus.device.refuse_storage(&mut reply);
    let Some(modbus_drive::device::Response::Reply(n)) = r else {
        panic!("a deferred reply, got {r:?}");
    };
    assert_eq!(reply[..n].to_vec(), exception(1, 0x10, 6));
    assert!(!rig.bus.device.busy());
    assert_eq!(rig.bus.device.refuse_storage(&mut reply), None, "once");
    assert!(rig.bus.events().contains(&Event::EeDone {
        op: EeOp::RestoreDefaults,
        error: Some(EeError::StepsRunning),
    }));
    assert_eq!(s.load(Slot::Saved), Ok(None));
    // a broadcast EE refused the same way stays silent
    assert_eq!(
        rig.bus
            .send(&frame(0, &[0x10, 0x00, 0x3A, 0x00, 0x01, 0x02, 0x00, 1])),
        None
    );
    assert_eq!(
        rig.bus.device.refuse_storage(&mut reply),
        Some(modbus_drive::device::Response::Silent)
    );
}
