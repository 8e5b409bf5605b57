//! The host's step schedule for a position move from rest, as the firmware
//! would plan it on a board: the core's planner at that board's step tick
//! (`boards::Board`, `PlannerConfig` as src/firmware/mod.rs sets it), the
//! control loop every millisecond, the core's simulated step interrupt.
//! Prints one line per step: its timer tick, relative to the first step.
//! The firmware-in-the-loop tests compare the emulated STEP pin with it
//! (tests/fw_sim/test_motion.py).
//!
//! `cargo run --example step_schedule -- g431|f103 DISTANCE VELOCITY ACCEL DECEL`
//! (steps, steps/s, steps/s²).

use modbus_drive::boards::Board;
use modbus_drive::motion::sim::{RunStop, SimAxis};
use modbus_drive::motion::{Fill, Goal, Planner, PlannerConfig, Ramp, StepSchedule};

/// The firmware's control period (src/firmware/control.rs).
const PERIOD_US: u64 = 1000;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: step_schedule g431|f103 DISTANCE VELOCITY ACCEL DECEL";
    assert_eq!(args.len(), 5, "{usage}");
    let board = match args[0].as_str() {
        "g431" => Board::G431,
        "f103" => Board::F103,
        _ => panic!("{usage}"),
    };
    let n = |i: usize| -> u64 { args[i].parse().expect(usage) };
    let tick_hz = board.step_tick_hz();
    let sched = Box::new(StepSchedule::new());
    let mut planner = Planner::new(PlannerConfig::for_board(board));
    let mut axis = SimAxis::new(tick_hz);
    // register units are 0.1 steps/s and 0.1 steps/s²
    let goal = Goal::Move {
        target: n(1) as i64,
        ramp: Ramp::new(n(2) * 10, n(3) * 10, n(4) * 10),
        end_velocity: 0,
    };
    assert!(planner.set_goal(goal), "goal refused");
    let mut ticks = Vec::new();
    let mut now_us = 0;
    loop {
        let _: Fill = planner.fill_with(now_us, &sched, &mut axis);
        axis.kick(&sched);
        let until = axis.us_to_ticks(now_us + PERIOD_US);
        while axis.run_until(&sched, until, |s| ticks.push(s.tick())) == RunStop::SwitchChanged {}
        now_us += PERIOD_US;
        if planner.at_rest(&sched) || now_us > 60_000_000 {
            break;
        }
    }
    let first = ticks.first().copied().unwrap_or(0);
    for t in ticks {
        println!("{}", t - first);
    }
}
