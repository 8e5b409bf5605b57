//! The example programs of seed 000 chapter 6 (position with its multi-point
//! variants, velocity, homing) as frames through the dispatcher into a
//! device on a simulated axis (SPEC §8.1–§8.6). Frames are the seed's where
//! the SPEC lists them as valid (§10); the three misprinted 0x6081 frames are
//! replaced by correct ones (and checked to be CRC errors on the wire).

mod common;

use common::axis::{check_dynamics, Rig};
use modbus_drive::motion::sim::SimAxis;

const READY: u16 = 0x0021;
const SWITCHED_ON: u16 = 0x0033;
const ENABLED: u16 = 0x0037;
const RUNNING: u16 = 1 << 9;
const REACHED: u16 = 1 << 10;
const BIT12: u16 = 1 << 12;
const BIT13: u16 = 1 << 13;
const HALT: u16 = 1 << 8;

/// 10000 steps/rev (PA10 default): 1 r/s = 10000 steps/s.
fn power_up(rig: &mut Rig) {
    rig.send_ok("01 06 60 40 00 01 57 DE");
    assert_eq!(rig.statusword(), READY);
    assert!(!rig.bus.device.drive().outputs().brake_released());
    rig.send_ok("01 06 60 40 00 03 D6 1F");
    assert_eq!(rig.statusword(), SWITCHED_ON);
    assert!(rig.bus.device.drive().outputs().brake_released());
    assert!(!rig.bus.device.drive().outputs().power_stage());
    rig.send_ok("01 06 60 40 00 0F D6 1A");
    assert_eq!(rig.statusword(), ENABLED);
    assert!(rig.bus.device.drive().outputs().power_stage());
}

fn position_mode() -> Rig {
    let mut rig = Rig::new(SimAxis::new(10_000_000));
    power_up(&mut rig);
    rig.send_ok("01 06 60 60 00 01 56 14");
    assert_eq!(rig.bus.read(0x6061, 1), Ok(vec![1]));
    // at rest, nothing latched: slot free, target reached
    assert_eq!(rig.statusword(), ENABLED | BIT12 | REACHED);
    rig
}

/// Position mode, 10 r/s² both ways, 5 r/s to 200000 (not yet latched).
fn first_point_at_5_rps() -> Rig {
    let mut rig = position_mode();
    rig.send_ok("01 06 60 83 00 64 67 C9");
    rig.send_ok("01 06 60 84 00 64 D6 08");
    rig.send_ok("01 10 60 81 00 02 04 00 00 00 32 13 D4"); // 5 r/s
    rig.send_ok("01 10 60 7A 00 02 04 00 03 0D 40 29 96"); // 200000
    rig
}

/// Runs to rest and checks the end of SPEC §8.4: exact position, target
/// reached, slot free, the exactness bounds on the way.
fn arrives_at(rig: &mut Rig, target: i32) {
    arrives_at_with(rig, target, 100_000.0, 100_000.0);
}

#[test]
fn misprinted_seed_frames_are_crc_errors() {
    let mut rig = Rig::new(SimAxis::new(10_000_000));
    for f in [
        "01 10 60 81 00 02 04 00 00 0A 12 06",
        "01 10 60 81 00 04 08 00 00 0A 00 64 00 64 10 52",
        "01 10 60 81 00 02 04 00 00 0A 64 93 EA",
    ] {
        let reply = rig.send(f).expect("exception 10");
        assert_eq!(&reply[1..3], &[0x90, 10]);
    }
}

#[test]
fn seed_6_1_single_point() {
    let mut rig = position_mode();
    // "set speed 1 r/s" (seed frame misprinted), 10 r/s² both ways
    rig.write_i32(0x6081, 10);
    rig.send_ok("01 06 60 83 00 64 67 C9");
    rig.send_ok("01 06 60 84 00 64 D6 08");
    rig.send_ok("01 10 60 7A 00 02 04 00 03 0D 40 29 96");
    assert_eq!(
        rig.statusword(),
        ENABLED | BIT12 | REACHED,
        "no motion before bit 4"
    );
    rig.send_ok("01 06 60 40 00 1F D7 D6");
    // running, slot free again, target not reached
    assert_eq!(rig.statusword(), ENABLED | BIT12 | RUNNING);
    rig.send_ok("01 06 60 40 00 0F D6 1A");
    rig.run_us(5_000_000);
    let p = rig.position();
    assert!(
        (49_000..51_000).contains(&p),
        "5 s at 10000 steps/s after a 0.1 s ramp: {p}"
    );
    assert_eq!(rig.velocity_rpm(), 60);
    rig.run_until(30_000_000, |r| r.at_rest());
    assert_eq!(rig.position(), 200_000);
    assert_eq!(rig.axis.position(), 200_000);
    assert_eq!(rig.statusword(), ENABLED | BIT12 | REACHED);
    assert_eq!(rig.velocity_rpm(), 0);
    check_dynamics(&rig.steps, rig.tick_hz, 10_000.0, 100_000.0);
}

#[test]
fn seed_6_1_two_points_stopping_between() {
    let mut rig = first_point_at_5_rps();
    rig.send_ok("01 06 60 40 00 1F D7 D6");
    rig.send_ok("01 06 60 40 00 0F D6 1A");
    rig.run_us(200_000);
    rig.send_ok("01 10 60 81 00 02 04 00 00 00 64 93 EA"); // 10 r/s
    rig.send_ok("01 10 60 7A 00 02 04 00 09 27 C0 17 54"); // 600000
    rig.send_ok("01 06 60 40 00 1F D7 D6");
    // buffered: the slot is taken
    assert_eq!(rig.statusword(), ENABLED | RUNNING);
    rig.run_until(30_000_000, |r| r.axis.position() >= 200_000);
    // the motor stopped at the first target: the step into it took at
    // least the time of a stop within one step at 100000 steps/s²
    assert!(
        rig.speed_at(200_000) < 500.0,
        "stopped at 200000: {}",
        rig.speed_at(200_000)
    );
    arrives_at(&mut rig, 600_000);
}

#[test]
fn seed_6_1_two_points_without_stopping() {
    let mut rig = first_point_at_5_rps();
    rig.send_ok("01 06 60 40 02 5F D7 46"); // bits 9, 6 (relative), 4
    rig.send_ok("01 06 60 40 02 4F D6 8A");
    rig.run_us(200_000);
    rig.send_ok("01 10 60 81 00 02 04 00 00 00 64 93 EA"); // 10 r/s
    rig.send_ok("01 10 60 7A 00 02 04 00 09 27 C0 17 54"); // +600000
    rig.send_ok("01 06 60 40 02 5F D7 46");
    assert_eq!(rig.statusword(), ENABLED | RUNNING);
    rig.run_until(30_000_000, |r| r.axis.position() >= 200_001);
    // SPEC §8.4 bit 9: reaches the first target at the first move's speed
    let v = rig.speed_at(200_000);
    assert!((v - 50_000.0).abs() < 50.0, "passes 200000 at 5 r/s: {v}");
    // the slot is free again once the second move runs
    assert_eq!(rig.statusword() & BIT12, BIT12);
    // 0x025F has bit 6 set: relative, 200000 + 600000
    arrives_at(&mut rig, 800_000);
}

#[test]
fn seed_6_1_change_immediately_relative() {
    let mut rig = first_point_at_5_rps();
    rig.send_ok("01 06 60 40 00 7F D7 FE"); // bits 6, 5, 4: relative, at once
    rig.send_ok("01 06 60 40 00 6F D6 32");
    rig.run_us(1_500_000);
    assert_eq!(rig.velocity_rpm(), 300);
    rig.send_ok("01 10 60 81 00 02 04 00 00 00 64 93 EA"); // 10 r/s
    rig.send_ok("01 10 60 7A 00 02 04 00 09 27 C0 17 54"); // +600000
    rig.send_ok("01 06 60 40 02 7F D6 9E");
    // replaced at once: the slot stays free, the motor speeds up
    assert_eq!(rig.statusword(), ENABLED | BIT12 | RUNNING);
    rig.run_us(1_000_000);
    assert_eq!(rig.velocity_rpm(), 600);
    // "the final position is the sum of the two positions"
    arrives_at(&mut rig, 800_000);
}

#[test]
fn seed_6_2_velocity() {
    let mut rig = Rig::new(SimAxis::new(10_000_000));
    power_up(&mut rig);
    rig.send_ok("01 06 60 60 00 03 D7 D5");
    rig.send_ok("01 06 60 40 01 0F D7 8A"); // halt
                                            // halted at rest: halt bit, speed 0 (bit 12), "with halt: velocity 0"
    assert_eq!(rig.statusword(), ENABLED | HALT | BIT12 | REACHED);
    rig.write_i32(0x6081, 10); // 1 r/s (seed frame misprinted)
    rig.send_ok("01 06 60 83 00 64 67 C9");
    rig.send_ok("01 06 60 84 00 64 D6 08");
    rig.run_us(100_000);
    assert_eq!(rig.axis.position(), 0, "halted: no motion");
    rig.send_ok("01 06 60 40 00 0F D6 1A"); // run
    rig.run_us(20_000);
    // ramping at the acceleration limit (bit 13), not yet at speed
    assert_eq!(rig.statusword(), ENABLED | RUNNING | BIT13);
    rig.run_us(200_000);
    assert_eq!(rig.statusword(), ENABLED | RUNNING | REACHED);
    assert_eq!(rig.velocity_rpm(), 60);
    rig.write_i32(0x6081, 100); // "set speed 10 r/s" (seed frame misprinted)
    rig.run_us(1_200_000);
    assert_eq!(rig.velocity_rpm(), 600);
    assert_eq!(rig.statusword(), ENABLED | RUNNING | REACHED);
    // reversal through zero with the deceleration ramp (SPEC §8.5)
    rig.write_i32(0x6081, -50);
    rig.run_us(2_000_000);
    assert_eq!(rig.velocity_rpm(), -300);
    rig.send_ok("01 06 60 40 01 0F D7 8A"); // pause
    assert_eq!(rig.statusword() & (HALT | REACHED), HALT, "decelerating");
    rig.run_until(2_000_000, |r| r.at_rest());
    assert_eq!(rig.statusword(), ENABLED | HALT | BIT12 | REACHED);
    let pos = rig.position();
    assert_eq!(i64::from(pos), rig.axis.position());
    check_dynamics(&rig.steps, rig.tick_hz, 100_000.0, 100_000.0);
}

#[test]
fn seed_6_3_homing_method_1() {
    // CW limit at -30000 (active at and below), home switch elsewhere
    let axis = SimAxis::new(10_000_000)
        .with_cw_limit(-30_000)
        .with_ccw_limit(30_000)
        .with_home(-5_000, -4_000);
    let mut rig = Rig::new(axis);
    power_up(&mut rig);
    rig.send_ok("01 06 60 60 00 06 17 D6");
    rig.send_ok("01 06 60 98 00 01 D7 E5");
    rig.send_ok("01 06 60 9A 03 E8 B7 5B"); // 100 r/s²
    rig.send_ok("01 10 60 99 00 02 04 00 00 00 64 93 40"); // 10 r/s (capped to 300 r/min)
    rig.send_ok("01 10 60 9B 00 02 04 00 00 00 64 12 99"); // 10 r/s
    rig.send_ok("01 10 60 7C 00 02 04 00 00 03 E8 5C 62"); // offset 1000
                                                           // the same in one frame
    rig.send_ok("01 10 60 7C 00 08 10 00 00 03 E8 00 01 00 00 00 64 03 E8 00 00 00 64 09 42");
    // not started: 001
    assert_eq!(rig.statusword(), ENABLED | REACHED);
    rig.send_ok("01 06 60 40 00 1F D7 D6");
    assert_eq!(rig.statusword(), ENABLED | RUNNING, "in progress: 000");
    rig.run_us(200_000);
    assert_eq!(rig.velocity_rpm(), -300, "method 1 capped at 300 r/min");
    rig.run_until(5_000_000, |r| r.statusword() & BIT12 != 0);
    // attained, offset move running: 010
    assert_eq!(rig.statusword() & (BIT13 | BIT12 | REACHED), BIT12);
    rig.run_until(5_000_000, |r| r.at_rest());
    assert_eq!(rig.statusword(), ENABLED | BIT12 | REACHED, "done: 011");
    // origin at the CW limit's edge, offset 1000 to the right, then 0
    assert_eq!(rig.axis.position(), -29_000);
    assert_eq!(rig.position(), 0);
    // pause / resume frame of the seed: halt at rest, nothing moves
    rig.send_ok("01 06 60 40 01 1F D6 46");
    rig.run_us(10_000);
    assert_eq!(rig.axis.position(), -29_000);
}

/// SPEC §8.4: units convert with PA10 steps per revolution and the cruise
/// speed |0x6081| is clamped to PA12 (r/min): the peak step rate measured
/// on the steps made, and 0x606C while cruising.
#[test]
fn pa10_scales_and_pa12_caps_the_move() {
    // (PA10, PA12 r/min, 0x6081 in 0.1 r/s, expected cruise steps/s)
    for (pa10, pa12, velocity, cruise) in [
        (10_000u16, 3000u16, 50, 50_000.0), // defaults: 5 r/s
        (2_000, 3000, 50, 10_000.0),        // same 0x6081, a fifth of the steps
        (2_000, 600, 150, 20_000.0),        // 15 r/s asked, PA12 = 10 r/s
    ] {
        let mut rig = Rig::new(SimAxis::new(10_000_000));
        rig.bus.write_single(0x0064 + 10, pa10).unwrap();
        rig.bus.write_single(0x0064 + 12, pa12).unwrap();
        power_up(&mut rig);
        rig.send_ok("01 06 60 60 00 01 56 14");
        rig.write_i32(0x6081, velocity);
        rig.write(0x6083, &[500, 500]); // 50 r/s² × PA10
        let target = 2 * cruise as i32;
        rig.write_i32(0x607A, target);
        rig.write(0x6040, &[0x001F]);
        rig.write(0x6040, &[0x000F]);
        rig.run_us(500_000);
        let rpm = (cruise * 60.0 / f64::from(pa10)) as i32;
        assert_eq!(rig.velocity_rpm(), rpm, "PA10 {pa10}, PA12 {pa12}");
        arrives_at_with(&mut rig, target, cruise, 50.0 * f64::from(pa10));
        let peak = peak_rate(&rig);
        assert!(
            (cruise * 0.995..=cruise * 1.005).contains(&peak),
            "PA10 {pa10}, PA12 {pa12}: peak {peak} steps/s"
        );
    }
}

/// The STEP pulse width (PA15) caps the step rate at 1 / (2 × width), as
/// PA12 caps it (docs/drive.md): the default 2.5 µs at 200 000 steps/s, a
/// shorter pulse up to the board's own limit, a longer one lower.
#[test]
fn pa15_caps_the_step_rate_at_its_pulse_width() {
    let board = modbus_drive::boards::Board::G431;
    let limit = f64::from(board.max_step_rate());
    // (PA15 in 0.1 µs, expected cruise steps/s) with 100 r/s asked
    for (pa15, cruise) in [
        (0u16, 200_000.0),
        (50, 100_000.0),
        (5, limit.min(1_000_000.0)),
    ] {
        let mut rig = Rig::on_board(board, |a| a);
        rig.bus.write_single(0x0064 + 12, 6000).unwrap();
        rig.bus.write_single(0x0064 + 15, pa15).unwrap();
        power_up(&mut rig);
        rig.send_ok("01 06 60 60 00 01 56 14");
        rig.write_i32(0x6081, 1000);
        rig.write(0x6083, &[2000, 2000]); // 200 r/s² × PA10: 2e6 steps/s²
        let target = 2 * cruise as i32;
        rig.write_i32(0x607A, target);
        rig.write(0x6040, &[0x001F]);
        rig.write(0x6040, &[0x000F]);
        arrives_at_with(&mut rig, target, cruise, 2_000_000.0);
        let peak = peak_rate(&rig);
        assert!(
            (cruise * 0.995..=cruise * 1.005).contains(&peak),
            "PA15 {pa15}: peak {peak} steps/s, cap {cruise}"
        );
    }
}

/// The highest step rate between two steps of the move, from their exact
/// times.
fn peak_rate(rig: &Rig) -> f64 {
    rig.steps
        .windows(2)
        .map(|w| {
            f64::from(rig.tick_hz) * common::axis::Q
                / w[1].exact().wrapping_sub(w[0].exact()) as f64
        })
        .fold(0.0, f64::max)
}

/// `arrives_at` with the velocity and acceleration bounds of the move.
fn arrives_at_with(rig: &mut Rig, target: i32, v_max: f64, a_max: f64) {
    rig.run_until(30_000_000, |r| r.at_rest());
    assert_eq!(rig.position(), target);
    assert_eq!(rig.axis.position(), i64::from(target));
    assert_eq!(rig.statusword(), ENABLED | BIT12 | REACHED);
    check_dynamics(&rig.steps, rig.tick_hz, v_max, a_max);
}
