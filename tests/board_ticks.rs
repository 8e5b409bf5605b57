//! Every documented motion limit at each board's real step tick
//! (`boards::Board`, the planner as the firmware configures it): a move at
//! the limit starts, reaches its target, and its pulses follow the ideal
//! profile (the planner's step time bound) within the limit's velocity and
//! acceleration. Limits (docs/drive.md "Units and limits", SPEC §8.4–§8.6):
//! acceleration and deceleration up to 2 000 000 steps/s² (0x6083 / 0x6084
//! / 0x6085 / 0x609A = 2000 at PA10 = 10000), the board's own step rate
//! limit (`Board::max_step_rate`: 0x6081 at the planner's ceiling asks
//! for more and is clamped to the board's; PA15 gives the widest STEP
//! pulse that limit allows, PA12 its maximum), homing 0x6099 /
//! 0x609B up to 100000 capped at 300 r/min (methods 1–4) and 1200 r/min
//! (5–8), and at the board's limit.
//!
//! The frames reach the drive between control calls and the control loop
//! runs on its own 1 ms grid, as on the firmware: a set-point arrives a
//! period after the last fill, which is what stalled the F103 at the
//! maximum acceleration (its first step fell before the fill that planned
//! it and wrapped into a delay of minutes).

mod common;

use common::axis::{check_dynamics, check_ideal_times, ideal_goal, Rig};
use modbus_drive::boards::Board;
use modbus_drive::motion::sim::{RunStop, SimAxis};
use modbus_drive::motion::{MAX_ACCEL, MAX_STEP_RATE};

/// PA10 default: register units ×10000 steps.
const STEPS_PER_REV: f64 = 10_000.0;
/// 0x6083 / 0x6084 / 0x6085 / 0x609A at the acceleration limit (0.1 r/s²).
const ACCEL_LIMIT_REG: u16 = 2000;
/// 0x6081 at the planner's step rate ceiling (0.1 r/s), which each board
/// clamps to its own limit.
const VELOCITY_LIMIT_REG: i32 = (MAX_STEP_RATE / 1000) as i32;

const REACHED: u16 = 1 << 10;
const BIT12: u16 = 1 << 12;
const BIT13: u16 = 1 << 13;

/// Each board's limits are its planner's (`PlannerConfig::for_board`, as
/// the firmware and the virtual drive's `--board` configure it), within
/// the planner's ceilings.
#[test]
fn every_board_has_its_own_limits_within_the_ceiling() {
    use modbus_drive::motion::PlannerConfig;
    for board in Board::ALL {
        let cfg = PlannerConfig::for_board(board);
        assert_eq!(cfg.tick_hz(), board.step_tick_hz());
        assert_eq!(cfg.max_step_rate(), board.max_step_rate());
        assert_eq!(cfg.max_accel(), board.max_accel());
        assert!(board.max_step_rate() <= MAX_STEP_RATE, "{board:?}");
        assert!(board.max_accel() <= MAX_ACCEL, "{board:?}");
    }
    assert_eq!(
        PlannerConfig::default(),
        PlannerConfig::for_board(Board::G431)
    );
}

#[test]
fn the_register_limits_are_the_planners() {
    let a = f64::from(ACCEL_LIMIT_REG) / 10.0 * STEPS_PER_REV;
    assert_eq!(a, MAX_ACCEL as f64);
    let v = f64::from(VELOCITY_LIMIT_REG) / 10.0 * STEPS_PER_REV;
    assert_eq!(v, f64::from(MAX_STEP_RATE));
}

/// Enabled, in position mode, with the profile registers written, all
/// through frames with the control loop on its grid.
fn position_rig(board: Board, axis: impl FnOnce(SimAxis) -> SimAxis, velocity: i32) -> Rig {
    let mut rig = Rig::on_board(board, axis);
    // PA12 at 6000 r/min and PA15 at the widest pulse the board's limit
    // allows (1 / (2 × width)): the board's limit is the one that clamps
    let width_ns = 500_000_000 / board.max_step_rate();
    rig.bus.write_single(0x0064 + 12, 6000).expect("PA12");
    rig.bus
        .write_single(0x0064 + 15, (width_ns / 100).min(25) as u16)
        .expect("PA15");
    for cw in [0x0006, 0x0007, 0x000F] {
        rig.bus.write_single(0x6040, cw).expect("controlword");
        rig.run_us(rig.period_us);
    }
    rig.bus.write_single(0x6060, 1).expect("mode");
    rig.bus
        .write(0x6081, &[(velocity >> 16) as u16, velocity as u16])
        .expect("velocity");
    rig.bus.write(0x6083, &[ACCEL_LIMIT_REG; 3]).expect("ramps");
    rig.run_us(rig.period_us);
    assert_eq!(rig.statusword() & 0x006F, 0x0027, "{board:?}: enabled");
    rig
}

/// Latches `target` with a bit 4 edge between two control calls; returns
/// the time (µs) of the control call that plans it.
fn latch(rig: &mut Rig, target: i32) -> u64 {
    rig.bus
        .write(0x607A, &[(target >> 16) as u16, target as u16])
        .expect("target");
    rig.bus.write_single(0x6040, 0x001F).expect("bit 4");
    rig.bus.write_single(0x6040, 0x000F).expect("bit 4 back");
    rig.now_us + rig.period_us
}

/// A position move at the acceleration, deceleration and velocity limits:
/// the first step a control period after the set-point (√(2/a) = 1 ms from
/// rest), every step on the ideal trapezoid, the target reached.
fn move_at_the_limits(board: Board, velocity_reg: i32, target: i32) {
    let tick = board.step_tick_hz();
    let mut rig = position_rig(board, |a| a, velocity_reg);
    let t0_us = latch(&mut rig, target);
    rig.run_us(2 * rig.period_us);
    assert!(
        !rig.steps.is_empty(),
        "{board:?}: no step 2 ms after the set-point (statusword {:#06x})",
        rig.statusword()
    );
    rig.run_until(2_000_000, |r| r.at_rest() && r.statusword() & REACHED != 0);
    assert_eq!(rig.position(), target, "{board:?}");
    assert_eq!(rig.axis.position(), i64::from(target), "{board:?}");
    let (v, a) = (f64::from(board.max_step_rate()), board.max_accel() as f64);
    let ideal = ideal_goal(0, 0.0, t0_us as f64 * 1e-6, i64::from(target), v, a, a);
    assert_eq!(ideal.len(), 1);
    check_ideal_times(&rig.steps, tick, &ideal[0]);
    check_dynamics(&rig.steps, tick, v, a);
    let top = rig
        .steps
        .windows(2)
        .map(|w| f64::from(tick) / (w[1].tick() - w[0].tick()) as f64)
        .fold(0.0, f64::max);
    assert!(top > 0.99 * v, "{board:?}: cruise at {top} steps/s");
}

#[test]
fn a_move_at_the_acceleration_and_velocity_limits_runs_on_every_board() {
    for board in Board::ALL {
        let ramp = ramp_steps(board);
        // a ramp up, a cruise as long, a ramp down
        move_at_the_limits(board, VELOCITY_LIMIT_REG, 3 * ramp);
        // backwards, and a velocity above the limit clamped to it
        move_at_the_limits(board, 10 * VELOCITY_LIMIT_REG, -5 * ramp / 2);
    }
}

/// Steps from rest to the board's step rate limit at its acceleration
/// limit: v² / 2a.
fn ramp_steps(board: Board) -> i32 {
    let v = u64::from(board.max_step_rate());
    (v * v / (2 * board.max_accel())) as i32
}

/// A short move (a triangle that never cruises) at the limit, from a
/// set-point that comes at every phase of the control period: the first
/// step never lands before the fill that plans it.
#[test]
fn a_set_point_at_any_phase_of_the_control_period_starts() {
    for board in Board::ALL {
        for phase_us in [0, 1, 250, 999] {
            let mut rig = position_rig(board, |a| a, VELOCITY_LIMIT_REG);
            rig.run_us(phase_us);
            let t0_us = latch(&mut rig, 500);
            rig.run_until(200_000, |r| r.at_rest() && r.statusword() & REACHED != 0);
            assert_eq!(rig.axis.position(), 500, "{board:?} phase {phase_us}");
            let tick = board.step_tick_hz();
            let first = rig.steps[0].tick() as f64 / f64::from(tick);
            let want = t0_us as f64 * 1e-6 + (2.0 / board.max_accel() as f64).sqrt();
            assert!(
                (first - want).abs() < 1e-6,
                "{board:?} phase {phase_us}: first step at {first} s, ideal {want} s"
            );
        }
    }
}

/// Quick stop (0x605A = 2) with 0x6085 at the limit from the velocity
/// limit: it decelerates at 0x6085 and stops within v²/2d steps and the
/// planner's horizon.
#[test]
fn a_quick_stop_at_the_deceleration_limit_stops_on_every_board() {
    for board in Board::ALL {
        let tick = board.step_tick_hz();
        let mut rig = position_rig(board, |a| a, VELOCITY_LIMIT_REG);
        rig.bus.write_single(0x605A, 2).expect("option 2");
        latch(&mut rig, 10_000_000);
        let cruising = i64::from(2 * ramp_steps(board));
        rig.run_until(3_000_000, |r| r.axis.position() > cruising);
        let at = rig.axis.position();
        rig.bus.write_single(0x6040, 0x000B).expect("quick stop");
        rig.run_until(1_000_000, |r| r.at_rest());
        assert_eq!(
            rig.statusword() & 0x006F,
            0x0007,
            "{board:?}: quick stop active"
        );
        let v = f64::from(board.max_step_rate());
        let a = board.max_accel() as f64;
        let horizon_steps = v * 4e-3; // horizon plus a control period
        let over = (rig.axis.position() - at) as f64;
        let stop = v * v / (2.0 * a);
        assert!(
            over >= stop && over <= stop + horizon_steps + 1.0,
            "{board:?}: {over} steps from the quick stop, v²/2d = {stop}"
        );
        check_dynamics(&rig.steps, tick, v, a);
    }
}

/// The step interrupt's own limit brake at 0x6085 = the limit, from the
/// velocity limit, at each board's tick.
#[test]
fn the_limit_brake_at_the_deceleration_limit_stops_on_every_board() {
    for (board, edge) in Board::ALL
        .into_iter()
        .flat_map(|b| [(b, 4 * ramp_steps(b)), (b, ramp_steps(b) * 9 / 10)])
    {
        let tick = board.step_tick_hz();
        let edge = i64::from(edge);
        let mut rig = position_rig(board, |a| a.with_ccw_limit(edge), VELOCITY_LIMIT_REG);
        latch(&mut rig, 10_000_000);
        // the control loop every period until the edge, which goes to the
        // schedule at once (the firmware's EXTI handler), then the
        // interrupt alone
        loop {
            let next = rig.now_us + rig.period_us;
            let until = rig.axis.us_to_ticks(next);
            let steps = &mut rig.steps;
            if rig.axis.run_until(&rig.sched, until, |s| steps.push(s)) == RunStop::SwitchChanged {
                break;
            }
            assert!(next < 3_000_000, "{board:?}: no edge");
            rig.now_us = next;
            rig.control();
        }
        let sw = rig.axis.switches();
        rig.sched.set_limits(sw.cw_limit(), sw.ccw_limit());
        // the brake's time from the limit, v / d, and 50 ms
        let brake_us = u64::from(board.max_step_rate()) * 1_000_000 / board.max_accel();
        let until = rig.axis.now_ticks() + rig.axis.us_to_ticks(brake_us + 50_000);
        let steps = &mut rig.steps;
        rig.axis.run_until(&rig.sched, until, |s| steps.push(s));
        assert!(
            !rig.axis.is_running(),
            "{board:?}: stopped by the interrupt"
        );
        let v_edge = rig.speed_at(edge);
        assert!(
            v_edge > 0.9 * f64::from(board.max_step_rate()),
            "{board:?}: {v_edge}"
        );
        let dist = v_edge * v_edge / (2.0 * board.max_accel() as f64);
        let over = (rig.axis.position() - edge) as f64;
        eprintln!("TMP {board:?} edge {edge}: over {over} dist {dist}");
        if edge < 100_000_000 {
            continue;
        }
        assert!(
            over <= dist + 2.0 && over >= dist - 4.0,
            "{board:?}: {over} steps past the edge, quick stop distance {dist}"
        );
        rig.run_us(10_000);
        let reg = rig.bus.read(0x6064, 2).expect("0x6064");
        let reported = (u32::from(reg[0]) << 16 | u32::from(reg[1])) as i32;
        assert_eq!(
            i64::from(reported),
            rig.axis.position(),
            "{board:?}: 0x6064"
        );
        check_dynamics(
            &rig.steps,
            tick,
            f64::from(board.max_step_rate()),
            board.max_accel() as f64,
        );
    }
}

/// Homing at the largest valid speeds (100000 = 10 000 r/s, capped to the
/// method's limit) and 0x609A at the acceleration limit: method 1 (capped
/// at 300 r/min) and method 5 (1200 r/min = the ceiling, so the board's
/// step rate limit) find the CW edge and zero there.
#[test]
fn homing_at_the_speed_and_acceleration_limits_on_every_board() {
    const CW_EDGE: i64 = -60_000;
    for board in Board::ALL {
        for (method, cap_rpm) in [(1u16, 300.0), (5, 1200.0)] {
            let tick = board.step_tick_hz();
            let mut rig = position_rig(board, |a| a.with_cw_limit(CW_EDGE), 0);
            rig.bus.write_single(0x6060, 6).expect("homing mode");
            rig.bus.write_single(0x6098, method).expect("method");
            for reg in [0x6099, 0x609B] {
                rig.bus.write(reg, &[1, 0x86A0]).expect("100000"); // 0x000186A0
            }
            rig.bus.write_single(0x609A, ACCEL_LIMIT_REG).expect("ramp");
            rig.bus.write(0x607C, &[0, 0]).expect("offset");
            rig.run_us(rig.period_us);
            assert_eq!(rig.statusword() & (BIT13 | BIT12 | REACHED), REACHED);
            rig.bus.write_single(0x6040, 0x001F).expect("start");
            rig.run_until(5_000_000, |r| {
                let s = r.statusword();
                assert_eq!(s & BIT13, 0, "{board:?} method {method}: homing error");
                s & (BIT12 | REACHED) == BIT12 | REACHED && r.at_rest()
            });
            assert_eq!(rig.position(), 0, "{board:?} method {method}: zeroed");
            assert_eq!(rig.axis.position(), CW_EDGE, "{board:?} method {method}");
            let v_cap = f64::min(
                cap_rpm / 60.0 * STEPS_PER_REV,
                f64::from(board.max_step_rate()),
            );
            check_dynamics(&rig.steps, tick, v_cap, board.max_accel() as f64);
            let top = rig
                .steps
                .windows(2)
                .map(|w| f64::from(tick) / (w[1].tick() - w[0].tick()) as f64)
                .fold(0.0, f64::max);
            assert!(
                top > 0.99 * v_cap,
                "{board:?} method {method}: fast phase at {top} steps/s, cap {v_cap}"
            );
        }
    }
}
