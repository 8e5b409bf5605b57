//! Homing (SPEC §8.6): every method from several start positions with
//! switches of finite width, the origin at the deciding edge, the offset
//! move and zeroing, the 13/12/10 status combinations and the errors.

mod common;

use common::axis::Rig;
use modbus_drive::motion::sim::SimAxis;

const ENABLED: u16 = 0x0037;
const RUNNING: u16 = 1 << 9;
const REACHED: u16 = 1 << 10;
const BIT12: u16 = 1 << 12;
const BIT13: u16 = 1 << 13;
const STATUS: u16 = BIT13 | BIT12 | REACHED;

const CW_EDGE: i64 = -20_000;
const CCW_EDGE: i64 = 20_000;
const HOME: (i64, i64) = (-2_000, -1_000);

fn rig_at(start: i64, with_home: bool) -> Rig {
    let mut axis = SimAxis::new(10_000_000)
        .with_cw_limit(CW_EDGE)
        .with_ccw_limit(CCW_EDGE)
        .at(start);
    if with_home {
        axis = axis.with_home(HOME.0, HOME.1);
    }
    let mut rig = Rig::new(axis);
    rig.write_single(0x6040, 0x000F);
    rig.write_single(0x6060, 6);
    rig
}

impl RigExt for Rig {
    fn write_single(&mut self, reg: u16, v: u16) {
        self.bus.write_single(reg, v).expect("accepted");
        self.control();
    }
}

trait RigExt {
    fn write_single(&mut self, reg: u16, v: u16);
}

/// Sets up method `m` (fast 5 r/s, slow 1 r/s, 100 r/s², `offset`) and
/// starts it.
fn start(rig: &mut Rig, m: i16, offset: i32) {
    rig.write_single(0x6098, m as u16);
    rig.write_i32(0x6099, 50);
    rig.write_i32(0x609B, 10);
    rig.write_single(0x609A, 1000);
    rig.write_i32(0x607C, offset);
    assert_eq!(rig.statusword() & STATUS, REACHED, "not started: 001");
    rig.write_single(0x6040, 0x001F);
}

/// Runs method `m` from physical position `from`; returns where the motor
/// ended (physical) after checking the done status and zeroing.
fn home(m: i16, from: i64, offset: i32) -> i64 {
    let mut rig = rig_at(from, true);
    start(&mut rig, m, offset);
    let mut saw_attained = false;
    rig.run_until(20_000_000, |r| {
        let s = r.statusword();
        assert_eq!(
            s & BIT13,
            0,
            "method {m} from {from}: error at {}",
            r.axis.position()
        );
        if s & STATUS == BIT12 {
            saw_attained = true; // 010: attained, offset move running
        }
        s & STATUS == BIT12 | REACHED && r.at_rest()
    });
    assert!(
        saw_attained || offset == 0,
        "method {m} from {from}: 010 never seen"
    );
    assert_eq!(rig.position(), 0, "method {m} from {from}: zeroed");
    rig.axis.position()
}

/// Where each method's origin is (SPEC §8.6 and the README's choice of
/// edges): 1/5 CW edge, 2/6 CCW edge, 3/7 home's right edge, 4/8 its left.
fn origin(m: i16) -> i64 {
    match m {
        1 | 5 => CW_EDGE,
        2 | 6 => CCW_EDGE,
        3 | 7 => HOME.1,
        _ => HOME.0,
    }
}

#[test]
fn every_method_from_every_side() {
    let left_of_home = -10_000;
    let on_home = -1_500;
    let right_of_home = 5_000;
    let on_cw = CW_EDGE - 300;
    let on_ccw = CCW_EDGE + 300;
    for m in 1..=8 {
        // towards the inside of the travel
        let offset = if m % 2 == 1 { 500 } else { -500 };
        for from in [left_of_home, on_home, right_of_home, on_cw, on_ccw] {
            let end = home(m, from, offset);
            assert_eq!(end, origin(m) + i64::from(offset), "method {m} from {from}");
        }
    }
}

#[test]
fn zero_offset_and_two_speed_caps() {
    // offset 0: the motor returns to the edge itself
    assert_eq!(home(1, 0, 0), CW_EDGE);
    // methods 1–4 capped at 300 r/min, 5–8 at 1200 r/min
    for (m, cap) in [(1, -300), (5, -1200)] {
        let mut rig = Rig::new(SimAxis::new(10_000_000).with_cw_limit(-1_000_000));
        rig.write_single(0x6040, 0x000F);
        rig.write_single(0x6060, 6);
        start(&mut rig, m, 0);
        rig.write_i32(0x6099, 1000); // 100 r/s asked
        rig.write_single(0x6040, 0x000F);
        rig.write_single(0x6040, 0x001F);
        rig.run_us(300_000);
        assert_eq!(rig.velocity_rpm(), cap, "method {m}");
    }
}

#[test]
fn opposite_limit_after_reversing_is_an_error() {
    // no home switch: method 3 reverses at the CW limit, then meets CCW
    let mut rig = rig_at(0, false);
    start(&mut rig, 3, 0);
    rig.run_until(20_000_000, |r| r.statusword() & BIT13 != 0);
    // error while moving: 100 (decelerating at the CCW limit)
    assert_eq!(rig.statusword() & STATUS, BIT13);
    assert!(rig.axis.position() >= CCW_EDGE);
    rig.run_until(1_000_000, |r| r.at_rest());
    assert_eq!(
        rig.statusword() & STATUS,
        BIT13 | REACHED,
        "error at standstill: 101"
    );
    // the two-speed variant too
    let mut rig = rig_at(0, false);
    start(&mut rig, 8, 0);
    rig.run_until(20_000_000, |r| r.statusword() & BIT13 != 0 && r.at_rest());
    assert!(rig.axis.position() <= CW_EDGE);
}

#[test]
fn bad_parameters_fail_at_standstill() {
    // (0x6098 unwritten = 0, or a method), 0x6099, 0x609B, 0x609A; values
    // above 100000 are refused on the bus (exception 3)
    for (method, fast, slow, accel) in [
        (None, 50, 10, 1000),
        (Some(1), 0, 10, 1000),
        (Some(5), 50, 0, 1000),
        (Some(1), 50, 10, 0),
    ] {
        let mut rig = rig_at(0, true);
        if let Some(m) = method {
            rig.write_single(0x6098, m);
        }
        rig.write_i32(0x6099, fast);
        rig.write_i32(0x609B, slow);
        rig.write_single(0x609A, accel);
        rig.write_single(0x6040, 0x001F);
        rig.run_us(10_000);
        assert_eq!(
            rig.statusword(),
            ENABLED | BIT13 | REACHED,
            "{method:?} {fast} {slow} {accel}: 101"
        );
        assert_eq!(rig.axis.position(), 0);
    }
}

#[test]
fn halt_pauses_and_resumes() {
    let mut rig = rig_at(0, true);
    start(&mut rig, 7, 0);
    rig.run_us(100_000);
    rig.write_single(0x6040, 0x011F); // halt
    rig.run_until(1_000_000, |r| r.at_rest());
    let s = rig.statusword();
    assert_eq!(
        s & (RUNNING | STATUS | (1 << 8)),
        (1 << 8) | REACHED,
        "halted: velocity 0"
    );
    let paused_at = rig.axis.position();
    rig.run_us(100_000);
    assert_eq!(rig.axis.position(), paused_at);
    rig.write_single(0x6040, 0x001F); // resume
    rig.run_until(20_000_000, |r| {
        r.statusword() & STATUS == BIT12 | REACHED && r.at_rest()
    });
    assert_eq!(rig.axis.position(), HOME.1);
}

#[test]
fn leaving_operation_enabled_interrupts() {
    let mut rig = rig_at(0, true);
    start(&mut rig, 1, 0);
    rig.run_us(100_000);
    rig.write_single(0x6040, 0x0007); // switched on: stop at once
    rig.run_us(2_000);
    assert!(rig.at_rest());
    rig.write_single(0x6040, 0x000F);
    assert_eq!(rig.statusword() & STATUS, REACHED, "interrupted: 001");
}
