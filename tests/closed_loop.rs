//! SPEC §8.8 on the wire: the following-error entries and PA17 / PA18 with
//! their exceptions and storage, and the drive's reaction to a stall or
//! lost steps on a simulated axis whose encoder the glue passes in every
//! control period (`tests/common` `Rig::encoder`).

mod common;

use common::axis::Rig;
use common::*;
use modbus_drive::closed_loop::sim::SimEncoder;
use modbus_drive::device::{Device, Identity};
use modbus_drive::dictionary::TABLE;
use modbus_drive::motion::sim::SimAxis;
use modbus_drive::params::{ParamStore, SimFlash};

const PA17: u16 = 0x0064 + 17;
const PA18: u16 = 0x0064 + 18;
const DP_EPO: u16 = 0x0005;
const DP_ERR: u16 = 0x0013;
/// Statusword bits 0–3, 5, 6 and the patterns of SPEC §8.1 (bit 5 is open
/// in the fault states: [`FAULT_MASK`]).
const STATE_MASK: u16 = 0x006F;
const FAULT_MASK: u16 = 0x004F;
const FAULT: u16 = 0x0008;
const FAULT_REACTION: u16 = 0x000F;
const OPERATION_ENABLED: u16 = 0x0027;
const BIT13: u16 = 1 << 13;
const TARGET_REACHED: u16 = 1 << 10;

fn i32_of(w: &[u16]) -> i32 {
    ((u32::from(w[0]) << 16) | u32::from(w[1])) as i32
}

// ---- the dictionary -------------------------------------------------------

#[test]
fn the_new_entries_follow_0x606c_in_table_order_with_their_defaults() {
    let mut bus = Bus::new();
    // 0x606C (2), 0x6065 (2), 0x6066 (1), 0x60F4 (2) in one request
    let w = bus.read(0x606C, 7).expect("table order walk");
    assert_eq!(
        &w[2..],
        &[0xFFFF, 0xFFFF, 0, 0, 0],
        "window off, time 0, error 0"
    );
    assert_eq!(bus.read(0x6065, 2), Ok(vec![0xFFFF, 0xFFFF]));
    assert_eq!(bus.read(0x6066, 1), Ok(vec![0]));
    assert_eq!(bus.read(0x60F4, 2), Ok(vec![0, 0]));
    // past the last entry (whichever the table ends with), or ending
    // inside one: exception 2
    let last = TABLE[TABLE.len() - 1];
    assert_eq!(bus.read(last.index(), last.words() + 1), Err(2));
    assert_eq!(bus.read(0x6065, 1), Err(2));
    assert_eq!(bus.read(0x606C, 3), Err(2));
    assert_eq!(bus.read(0x6067, 1), Err(11));
    assert_eq!(bus.read(0x60F5, 1), Err(11));
    assert_eq!(
        (bus.read(0x6064, 2), bus.read(DP_EPO, 2)),
        (Ok(vec![0, 0]), Ok(vec![0, 0]))
    );
}

#[test]
fn writes_to_the_new_entries_and_their_exceptions() {
    let mut bus = Bus::new();
    assert_eq!(bus.write(0x6065, &[0, 500, 20]), Ok(()));
    assert_eq!(bus.read(0x6065, 3), Ok(vec![0, 500, 20]));
    assert_eq!(bus.write_single(0x6066, 65535), Ok(()));
    assert_eq!(bus.read(0x6066, 1), Ok(vec![65535]));
    // 0x06 on a two-word entry: 8; 0x60F4 is read-only: 5
    assert_eq!(bus.write_single(0x6065, 7), Err(8));
    assert_eq!(bus.write(0x60F4, &[0, 1]), Err(5));
    assert_eq!(bus.write_single(0x60F4, 1), Err(8));
    // all-or-nothing: a request that reaches 0x60F4 stores nothing
    assert_eq!(bus.write(0x6065, &[0, 9, 9, 0, 0]), Err(5));
    assert_eq!(bus.read(0x6065, 3), Ok(vec![0, 500, 65535]));
    // word order 1 applies (§5.1)
    assert_eq!(bus.write_single(0x6000, 1), Ok(()));
    assert_eq!(bus.write(0x6065, &[0x86A0, 0x0001]), Ok(()));
    assert_eq!(bus.device.od().following_error_window(), 100_000);
}

#[test]
fn pa17_takes_0_or_100_and_more_and_pa18_0_or_1() {
    for (v, ok) in [
        (0, true),
        (1, false),
        (99, false),
        (100, true),
        (4000, true),
        (65535, true),
    ] {
        let mut bus = Bus::new();
        let want = if ok { Ok(()) } else { Err(3) };
        assert_eq!(bus.write_single(PA17, v), want, "PA17 = {v}");
        assert_eq!(bus.write(PA17, &[v]), want, "PA17 = {v}");
        assert_eq!(bus.device.params().get(17), if ok { v } else { 0 });
    }
    let mut bus = Bus::new();
    assert_eq!(bus.read(PA17, 2), Ok(vec![0, 0]), "defaults: no encoder");
    assert_eq!(bus.write(PA17, &[4000, 2]), Err(3));
    assert_eq!(bus.read(PA17, 2), Ok(vec![0, 0]), "nothing stored");
    assert_eq!(bus.write(PA17, &[4000, 1]), Ok(()));
    assert_eq!(bus.read(PA17, 2), Ok(vec![4000, 1]));
    assert_eq!(bus.write_single(PA18, 2), Err(3));
    assert_eq!(bus.write_single(PA18, 0), Ok(()));
    assert!(!bus.device.params().encoder_inverted());
}

#[test]
fn the_closed_loop_settings_are_saved_with_the_others() {
    let mut store = ParamStore::new(SimFlash::<2>::new(), 0..4096).unwrap();
    let mut bus = Bus::new();
    assert_eq!(bus.write(0x6065, &[0, 300, 25]), Ok(()));
    assert_eq!(bus.write(PA17, &[4000, 1]), Ok(()));
    // EE-Set, new format
    let set = frame(1, &[0x10, 0x00, 0x3A, 0x00, 0x01, 0x02, 0x00, 0x01]);
    assert_eq!(bus.send(&set), None);
    assert_eq!(
        bus.poll_storage(&mut store),
        Some(frame(1, &[0x10, 0x00, 0x3A, 0x00, 0x01]))
    );
    let mut device = Device::new(Identity::new(TEST_HARDWARE));
    device.apply_boot(&store.boot());
    let mut bus = Bus::with_device(device);
    assert_eq!(bus.read(0x6065, 3), Ok(vec![0, 300, 25]));
    assert_eq!(bus.read(PA17, 2), Ok(vec![4000, 1]));
}

// ---- the drive's reaction --------------------------------------------------

/// A drive with an encoder of 4000 counts per revolution (PA10 = 10 000
/// steps), window `window` steps, time out `timeout_ms`, operation enabled.
fn closed_loop_rig(encoder: SimEncoder, window: u32, timeout_ms: u16) -> Rig {
    let mut rig = Rig::new(SimAxis::new(10_000_000));
    rig.encoder = Some(encoder);
    rig.write(PA17, &[4000]);
    rig.write(0x6065, &[(window >> 16) as u16, window as u16, timeout_ms]);
    for cw in [0x0006, 0x0007, 0x000F] {
        rig.controlword(cw);
    }
    assert_eq!(rig.statusword() & STATE_MASK, OPERATION_ENABLED);
    rig
}

fn following_error(rig: &mut Rig) -> i32 {
    i32_of(&rig.bus.read(0x60F4, 2).expect("0x60F4"))
}

fn dp_epo(rig: &mut Rig) -> i32 {
    // DP-EPo low word, DP-EPo. high word (SPEC §9)
    let w = rig.bus.read(DP_EPO, 2).expect("DP-EPo");
    ((u32::from(w[1]) << 16) | u32::from(w[0])) as i32
}

fn motor(rig: &Rig) -> i64 {
    rig.encoder.as_ref().expect("an encoder").motor_position()
}

/// Re-enables after a fault with fault reset, as SPEC §8.1 says.
fn reset_and_enable(rig: &mut Rig) {
    rig.controlword(0x0000);
    rig.controlword(0x0080);
    assert_eq!(rig.statusword() & 0x004F, 0x0040, "switch on disabled");
    for cw in [0x0006, 0x0007, 0x000F] {
        rig.controlword(cw);
    }
    assert_eq!(rig.statusword() & STATE_MASK, OPERATION_ENABLED);
}

#[test]
fn a_stall_mid_move_faults_within_the_time_out_and_stops_with_the_quick_stop_ramp() {
    let mut rig = closed_loop_rig(SimEncoder::new().with_stall_at(20_000), 200, 10);
    rig.start_position_move(100_000);
    rig.run_until(1_000_000, |r| r.axis.position() >= 20_000);
    let stalled_us = rig.now_us;
    assert_eq!(rig.statusword() & BIT13, 0);
    rig.run_until(100_000, |r| {
        r.statusword() & STATE_MASK != OPERATION_ENABLED
    });
    let reaction_us = rig.now_us - stalled_us;
    let sw = rig.statusword();
    assert_eq!(sw & FAULT_MASK, FAULT_REACTION, "{sw:#06x}");
    assert_ne!(sw & BIT13, 0, "following error shown at once");
    // At 100 000 steps/s the error passes the 200-step window after 2 ms;
    // above it for longer than 10 ms faults: not before, one period after.
    assert!((12_000..=14_000).contains(&reaction_us), "{reaction_us} µs");
    let steps_at_fault = rig.axis.position();
    rig.run_until(200_000, |r| r.statusword() & FAULT_MASK == FAULT);
    assert!(rig.at_rest());
    // quick stop deceleration 0x6085 = 200 r/s² = 2e6 steps/s²: v²/2a =
    // 2500 steps, after what the planner had queued (3 ms horizon, at most
    // 300 steps); not the 0x6084 ramp (5000) and not at once (≤ 300)
    let ramp = rig.axis.position() - steps_at_fault;
    assert!((2_400..=2_800).contains(&ramp), "{ramp} steps on the ramp");
    let sw = rig.statusword();
    assert_ne!(sw & BIT13, 0);
    assert_eq!(rig.error_register(), 1 << 5);
    assert_eq!(rig.bus.read(DP_ERR, 1), Ok(vec![1 << 5]));
    // the error is live: commanded − measured, in 0x60F4 and DP-EPo
    let e = following_error(&mut rig);
    assert_eq!(dp_epo(&mut rig), e);
    let lost = rig.axis.position() - motor(&rig);
    assert!((e as i64 - lost).abs() <= 2, "error {e}, steps lost {lost}");
    // 0x6064 is the measured position
    let p = rig.position() as i64;
    assert!((p - 20_000).abs() <= 2, "measured {p}");

    // fault reset clears bit 13 and 0x1001; re-enabling takes the
    // measured position: the error starts from 0 and a move back works
    reset_and_enable(&mut rig);
    assert_eq!(rig.statusword() & BIT13, 0);
    assert_eq!(rig.error_register(), 0);
    assert!(following_error(&mut rig).abs() <= 2);
    rig.start_position_move(0);
    rig.run_until(2_000_000, |r| {
        r.statusword() & TARGET_REACHED != 0 && r.at_rest()
    });
    assert_eq!(rig.statusword() & (STATE_MASK | BIT13), OPERATION_ENABLED);
    assert!(rig.position().abs() <= 2, "{}", rig.position());
    assert!(
        motor(&rig).abs() <= 2,
        "the motor is back at 0: {}",
        motor(&rig)
    );
}

#[test]
fn a_slip_below_the_window_does_not_fault_and_shows_in_the_error() {
    let enc = SimEncoder::new().with_slip(150, 30_000).with_noise(2);
    let mut rig = closed_loop_rig(enc, 200, 10);
    rig.start_position_move(100_000);
    rig.run_until(2_000_000, |r| {
        r.statusword() & TARGET_REACHED != 0 && r.at_rest()
    });
    assert_eq!(rig.statusword() & (STATE_MASK | BIT13), OPERATION_ENABLED);
    assert_eq!(rig.error_register(), 0);
    assert_eq!(motor(&rig), 100_000 - 150);
    // two noisy readings count: the one the encoder's reference was taken
    // from at enable and the last; ±2 counts each are ±10 steps, and each
    // of the two count-to-step conversions rounds down by less than a step
    let e = following_error(&mut rig);
    assert!((139..=161).contains(&e), "error {e}");
    let p = rig.position();
    assert!((99_839..=99_861).contains(&p), "measured {p}");
}

#[test]
fn a_slip_above_the_window_faults_and_reset_and_re_enable_work() {
    let mut rig = closed_loop_rig(SimEncoder::new().with_slip(500, 30_000), 200, 10);
    rig.start_position_move(100_000);
    rig.run_until(2_000_000, |r| r.statusword() & FAULT_MASK == FAULT);
    let slipped_at = 30_000;
    assert!(rig.axis.position() > slipped_at && rig.axis.position() < 100_000);
    assert_ne!(rig.statusword() & BIT13, 0);
    assert_eq!(rig.error_register(), 1 << 5);
    let e = following_error(&mut rig);
    assert!((498..=502).contains(&e), "error {e}");
    reset_and_enable(&mut rig);
    // the measured position is taken: the remaining move reaches the
    // target on the motor, with no fault
    rig.start_position_move(100_000);
    rig.run_until(2_000_000, |r| {
        r.statusword() & TARGET_REACHED != 0 && r.at_rest()
    });
    assert_eq!(rig.statusword() & (STATE_MASK | BIT13), OPERATION_ENABLED);
    assert!((motor(&rig) - 100_000).abs() <= 2, "motor {}", motor(&rig));
}

#[test]
fn a_stall_in_velocity_mode_faults_with_bit_13() {
    let mut rig = closed_loop_rig(SimEncoder::new().with_stall_at(10_000), 100, 5);
    rig.bus.write_single(0x6060, 3).expect("velocity mode");
    rig.write(0x6083, &[1000, 1000, 0]); // 0x6085 = 0: stop at once
    rig.write_i32(0x6081, 50);
    rig.run_until(2_000_000, |r| r.statusword() & FAULT_MASK == FAULT);
    assert!(rig.at_rest());
    assert_ne!(rig.statusword() & BIT13, 0);
    assert_eq!(rig.error_register(), 1 << 5);
}

#[test]
fn with_the_window_off_a_stall_never_faults_but_the_error_is_shown() {
    let mut rig = closed_loop_rig(SimEncoder::new().with_stall_at(20_000), u32::MAX, 0);
    rig.start_position_move(60_000);
    rig.run_until(2_000_000, |r| {
        r.statusword() & TARGET_REACHED != 0 && r.at_rest()
    });
    assert_eq!(rig.statusword() & (STATE_MASK | BIT13), OPERATION_ENABLED);
    let e = following_error(&mut rig);
    assert!((e - 40_000).abs() <= 2, "error {e}");
    assert!((rig.position() - 20_000).abs() <= 2);
}

#[test]
fn without_pa17_the_drive_stays_open_loop_whatever_the_encoder_says() {
    let mut rig = Rig::new(SimAxis::new(10_000_000));
    rig.encoder = Some(SimEncoder::new().with_stall_at(20_000));
    rig.write(0x6065, &[0, 10, 0]);
    for cw in [0x0006, 0x0007, 0x000F] {
        rig.controlword(cw);
    }
    rig.start_position_move(60_000);
    rig.run_until(2_000_000, |r| {
        r.statusword() & TARGET_REACHED != 0 && r.at_rest()
    });
    assert_eq!(rig.statusword() & (STATE_MASK | BIT13), OPERATION_ENABLED);
    assert_eq!(rig.position(), 60_000, "0x6064 is the commanded count");
    assert_eq!(following_error(&mut rig), 0);
    assert_eq!(dp_epo(&mut rig), 0);
}
