//! Homing (SPEC §8.6): every method from several start positions with
//! switches of finite width, the origin at the deciding edge, the offset
//! move and zeroing, the 13/12/10 status combinations and the errors; the
//! origin latched at the edge when the glue samples the switches late (the
//! firmware's debounced 1 kHz loop, `Device::control_latched`), and stale
//! latched edges ignored.

mod common;

#[path = "../src/firmware/calc.rs"]
#[allow(dead_code)]
mod calc;

use calc::LatchedSwitch;
use common::axis::Rig;
use modbus_drive::drive::DriveEvent;
use modbus_drive::event::Event;
use modbus_drive::motion::sim::{RunStop, SimAxis};
use modbus_drive::motion::{Homing, HomingMethod, HomingStep, SwitchEdges, Switches};

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

/// Where method `m` started at `from` finds its origin (SPEC §8.6: the
/// deciding switch edge): 1/5 the CW edge, 2/6 the CCW edge, 7 home's
/// right edge, 8 its left edge. 3 ("left; if the CW limit is reached,
/// reverse; stop on the home switch"): from the right of the switch it
/// meets the right edge moving left; from its left it reverses at the CW
/// limit and meets the left edge moving right; started on the switch it
/// leaves it to the right and comes back to the right edge (docs/drive.md). 4 is
/// the mirror.
fn origin(m: i16, from: i64) -> i64 {
    match m {
        1 | 5 => CW_EDGE,
        2 | 6 => CCW_EDGE,
        3 if from < HOME.0 => HOME.0,
        3 | 7 => HOME.1,
        4 if from > HOME.1 => HOME.1,
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
            assert_eq!(
                end,
                origin(m, from) + i64::from(offset),
                "method {m} from {from}"
            );
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
    // SPEC §8.6: homing fails (bit 13) when the method is 0 (0x6098
    // unwritten), a speed (0x6099, 0x609B) is 0 or above 100000, or the
    // acceleration 0x609A is 0. The bus accepts speeds above 100000 (0x6099
    // and 0x609B are plain U32 registers); the start of homing refuses them.
    for (method, fast, slow, accel) in [
        (None, 50, 10, 1000),
        (Some(1), 0, 10, 1000),
        (Some(5), 50, 0, 1000),
        (Some(1), 50, 10, 0),
        (Some(3), 100_001, 10, 1000),
        (Some(7), 50, 100_001, 1000),
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

/// SPEC §8.1: halt decelerates with 0x6084 in homing too (not with the
/// homing ramp 0x609A), at once when 0x6084 = 0 (docs/drive.md); halted at rest
/// the status is 001 (§8.6 "interrupted"), and the search resumes.
#[test]
fn halt_decelerates_with_0x6084_and_resumes() {
    // 0x6084 = 20 r/s² = 2e5 steps/s²: from 5 r/s = 50000 steps/s that is
    // 6250 steps (0x609A's 1e6 steps/s² would be 1250), plus what was
    // queued (horizon 3 ms + a 1 ms segment: ≤ 200 steps). 0: at once, at
    // most the step on the timer.
    for (decel, min, max) in [(200u16, 6_250, 6_250 + 200), (0, 0, 1)] {
        let mut rig = rig_at(15_000, true);
        rig.write_single(0x6084, decel);
        start(&mut rig, 7, 0);
        rig.run_us(100_000);
        assert_eq!(rig.velocity_rpm(), -300, "cruising left at 5 r/s");
        let at = rig.axis.position();
        rig.write_single(0x6040, 0x011F); // halt
        rig.run_until(1_000_000, |r| r.at_rest());
        let braked = at - rig.axis.position();
        assert!(
            (min..=max).contains(&braked),
            "0x6084 = {decel}: {braked} steps to rest"
        );
        assert_eq!(
            rig.statusword() & (RUNNING | STATUS | (1 << 8)),
            (1 << 8) | REACHED,
            "halted at rest: 001"
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
}

/// SPEC §8.6 method 3, "left; if the CW limit is reached, reverse; stop on
/// the home switch", the origin at the deciding edge: started left of the
/// switch it runs into the CW limit, reverses and takes the first edge it
/// meets moving right, the switch's left edge (method 4 mirrored).
#[test]
fn methods_3_and_4_take_the_first_edge_after_reversing() {
    for (m, from, limit_reached) in [(3, -10_000, CW_EDGE), (4, 5_000, CCW_EDGE)] {
        let mut rig = rig_at(from, true);
        start(&mut rig, m, 0);
        let mut reached_limit = false;
        rig.run_until(20_000_000, |r| {
            let p = r.axis.position();
            reached_limit |= if m == 3 {
                p <= limit_reached
            } else {
                p >= limit_reached
            };
            r.statusword() & STATUS == BIT12 | REACHED && r.at_rest()
        });
        assert!(reached_limit, "method {m}: reversed at the limit");
        let edge = if m == 3 { HOME.0 } else { HOME.1 };
        assert_eq!(rig.axis.position(), edge, "method {m}");
        assert_eq!(rig.position(), 0);
    }
}

#[test]
fn homing_speed_100000_is_allowed() {
    // the largest valid register value (SPEC §8.6 fails only above it);
    // it runs at the method's cap
    let mut rig = rig_at(0, true);
    start(&mut rig, 1, 0);
    rig.write_i32(0x6099, 100_000);
    rig.write_single(0x6040, 0x000F);
    rig.write_single(0x6040, 0x001F);
    rig.run_us(300_000);
    assert_eq!(rig.statusword() & STATUS, 0, "in progress");
    assert_eq!(rig.velocity_rpm(), -300);
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

// ------------------------------------------- origin latched at the edge (SPEC §8.6)

/// The firmware's glue (src/firmware/control.rs, switches.rs) on the
/// simulated axis: `Device::control_latched(_with)` every 1 ms only, switch
/// states debounced over three samples (`calc::LatchedSwitch`, so 2–3 ms
/// after the edge), and — if `latch` — the step count the switch interrupt
/// latched at the edge (`StepSchedule::position`).
struct Firmware {
    sw: [LatchedSwitch; 3],
    latch: bool,
}

impl Firmware {
    fn new(rig: &Rig, latch: bool) -> Self {
        let s = rig.axis.switches();
        Self {
            sw: [s.cw_limit(), s.ccw_limit(), s.home()].map(LatchedSwitch::new),
            latch,
        }
    }

    /// The EXTI handler (and the control loop's own pin reading).
    fn read(&mut self, rig: &Rig) -> [bool; 3] {
        let s = rig.axis.switches();
        let raw = [s.cw_limit(), s.ccw_limit(), s.home()];
        for (l, r) in self.sw.iter_mut().zip(raw) {
            l.edge(r, rig.sched.position());
        }
        raw
    }

    /// One millisecond: the axis runs, the switch interrupt fires at each
    /// switch change, then the control loop samples.
    fn run_ms(&mut self, rig: &mut Rig) {
        let next = rig.now_us + rig.period_us;
        let until = rig.axis.us_to_ticks(next);
        while rig.axis.run_until(&rig.sched, until, |_| {}) == RunStop::SwitchChanged {
            self.read(rig);
        }
        rig.now_us = next;
        let raw = self.read(rig);
        let [cw, ccw, home] = [0, 1, 2].map(|i| self.sw[i].sample(raw[i]).flatten());
        let states = Switches::new(self.sw[0].state(), self.sw[1].state(), self.sw[2].state());
        let edges = if self.latch {
            SwitchEdges::new(cw, ccw, home)
        } else {
            SwitchEdges::default()
        };
        rig.bus
            .device
            .control_latched_with(rig.now_us, states, edges, &rig.sched, &mut rig.axis);
        rig.axis.kick(&rig.sched);
    }
}

/// Method `m` from `from` under the firmware's glue: (where the motor
/// ended, physical; the origin the drive reported, raw steps; the position
/// at the control call that found it, raw).
fn home_late(m: i16, from: i64, offset: i32, latch: bool) -> (i64, i64, i64) {
    let mut rig = rig_at(from, true);
    start(&mut rig, m, offset);
    rig.bus.events();
    let mut fw = Firmware::new(&rig, latch);
    let mut attained = None;
    for _ in 0..20_000 {
        fw.run_ms(&mut rig);
        for e in rig.bus.events() {
            if let Event::Drive(DriveEvent::HomingAttained { origin }) = e {
                attained = Some((i64::from(origin), rig.sched.position()));
            }
        }
        let s = rig.statusword();
        assert_eq!(s & BIT13, 0, "method {m} from {from}: error");
        if s & STATUS == BIT12 | REACHED && rig.at_rest() {
            assert_eq!(rig.position(), 0, "method {m} from {from}: zeroed");
            let (origin, at_call) = attained.expect("attained reported");
            // the call's position: the schedule's count when the event came
            return (rig.axis.position(), origin, i64::from(at_call));
        }
    }
    panic!("method {m} from {from}: not done in 20 s");
}

/// SPEC §8.6 "the origin is the position at which the deciding switch edge
/// was seen (latched at that step)": with the switches seen 2–3 ms late,
/// every method from every side ends exactly at latched edge + 0x607C, and
/// the origin differs from the position at the control call that found it.
#[test]
fn latched_edge_is_the_origin_for_every_method() {
    for m in 1..=8 {
        let offset = if m % 2 == 1 { 500 } else { -500 };
        for from in [-10_000, -1_500, 5_000, CW_EDGE - 300, CCW_EDGE + 300] {
            let (end, found, at_call) = home_late(m, from, offset, true);
            let want = origin(m, from);
            assert_eq!(found, want - from, "method {m} from {from}: origin (raw)");
            assert_eq!(end, want + i64::from(offset), "method {m} from {from}");
            assert_ne!(found, at_call, "method {m} from {from}: edge seen late");
        }
    }
}

/// The same glue without the latch takes the origin where the debounced
/// change was seen: late in the direction of travel (docs/drive.md "Homing
/// origin") — what the latch above corrects.
#[test]
fn without_the_latch_the_origin_is_late() {
    for m in 1..=8 {
        let from = if m % 2 == 1 { 5_000 } else { -10_000 };
        let (end, _, _) = home_late(m, from, 0, false);
        let want = origin(m, from);
        let late = if m % 2 == 1 { want - end } else { end - want };
        assert!(late > 0, "method {m}: origin {end}, edge {want}");
    }
}

const NONE: Switches = Switches::new(false, false, false);
const HOME_ON: Switches = Switches::new(false, false, true);

fn home_edge(at: i32) -> SwitchEdges {
    SwitchEdges::new(None, None, Some(at))
}

/// Method 1 searching left from 0 finds the CW limit at the call at -520:
/// the latched edge at -480 lies on the leg and is the origin; one behind
/// the leg's start or ahead of the present position is not (the position
/// at the call is then, as without a latch).
#[test]
fn latched_edge_counts_only_on_the_current_leg() {
    let cw_on = Switches::new(true, false, false);
    for (edge, origin) in [
        (Some(-480), -480),
        (Some(0), 0),
        (Some(10), -520),
        (Some(-600), -520),
        (None, -520),
    ] {
        let mut h = Homing::start(HomingMethod::CwLimit, NONE);
        assert_eq!(
            h.update(NONE, SwitchEdges::default(), 0),
            HomingStep::Continue
        );
        assert_eq!(
            h.update(NONE, SwitchEdges::default(), -500),
            HomingStep::Continue
        );
        // the CCW limit's edge is not the deciding switch's
        let edges = SwitchEdges::new(edge, Some(-510), Some(-510));
        assert_eq!(
            h.update(cw_on, edges, -520),
            HomingStep::Origin(origin),
            "edge {edge:?}"
        );
    }
}

/// Method 7: the fast search finds the switch, brakes left through it
/// (edges there are stale: the motor moves against the slow phase), turns
/// at -1950, passes the switch right, brakes right to -1390 and comes back
/// left. Only an edge between that turn and now is the origin; one latched
/// beyond the turn (passed while braking) is ignored.
#[test]
fn edges_passed_while_braking_are_stale() {
    for (edge, origin) in [(-1450, -1450), (-1390, -1390), (-1380, -1460)] {
        let mut h = Homing::start(HomingMethod::HomeLeftTwoSpeed, NONE);
        let none = SwitchEdges::default();
        assert_eq!(h.update(NONE, none, 0), HomingStep::Continue);
        assert_eq!(
            h.update(HOME_ON, home_edge(-1400), -1500),
            HomingStep::NextPhase
        );
        // braking left against "pass right": the release at the far edge
        // is not "passed"
        assert_eq!(h.update(HOME_ON, none, -1700), HomingStep::Continue);
        assert_eq!(
            h.update(NONE, home_edge(-1900), -1950),
            HomingStep::Continue
        );
        assert_eq!(h.update(NONE, none, -1940), HomingStep::Continue);
        assert_eq!(
            h.update(HOME_ON, home_edge(-1905), -1850),
            HomingStep::Continue
        );
        assert_eq!(
            h.update(NONE, home_edge(-1000), -900),
            HomingStep::NextPhase
        );
        // braking right against "seek left", then back
        assert_eq!(h.update(NONE, none, -1400), HomingStep::Continue);
        assert_eq!(h.update(NONE, none, -1390), HomingStep::Continue);
        assert_eq!(h.update(NONE, none, -1395), HomingStep::Continue);
        assert_eq!(
            h.update(HOME_ON, home_edge(edge), -1460),
            HomingStep::Origin(origin),
            "edge {edge}"
        );
    }
}

/// Latched edges are wrapping i32 step counts (`StepSchedule::position`);
/// the raw position is unwrapped i64: the edge is taken next to it.
#[test]
fn latched_edge_across_the_i32_wrap() {
    let p = 1i64 << 31;
    let ccw_on = Switches::new(false, true, false);
    let mut h = Homing::start(HomingMethod::CcwLimit, NONE);
    assert_eq!(
        h.update(NONE, SwitchEdges::default(), p - 100),
        HomingStep::Continue
    );
    let edges = SwitchEdges::new(None, Some((p + 5) as i32), None);
    assert_eq!(h.update(ccw_on, edges, p + 10), HomingStep::Origin(p + 5));
}
