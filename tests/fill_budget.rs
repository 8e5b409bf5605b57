//! The planner's fill in parts (`PlannerConfig::with_fill_budget`, and a
//! sink that asks for a pause, `StepSink::pause_wanted`: what the
//! firmware's control loop uses so that a frame waits for one push of the
//! control call, not all of it): the parts push exactly the steps one
//! unbounded fill pushes, each part after the first stays within the
//! budget (within one push when asked), and the schedule never runs dry.

mod common;

use common::axis::Rig;
use modbus_drive::boards::Board;
use modbus_drive::motion::sim::{RunStop, SimAxis, StepRecord};
use modbus_drive::motion::{
    Fill, Goal, Planner, PlannerConfig, PushedSteps, Ramp, StepSchedule, StepSink,
    CONSTANT_STEPS_PER_BUDGET, FIT_COST, PUSH_STEPS,
};
use proptest::prelude::*;

const PERIOD_US: u64 = 1000;

/// The simulated axis as the fill's sink, asking for a pause at every
/// `every`-th question (never without `every`), as the firmware's
/// control loop asks while a frame waits.
struct Asking<'a> {
    axis: &'a mut SimAxis,
    every: Option<u32>,
    asked: &'a mut u32,
}

impl StepSink for Asking<'_> {
    fn pushed(&mut self, steps: &PushedSteps) {
        self.axis.pushed(steps);
    }

    fn pause_wanted(&mut self) -> bool {
        let Some(every) = self.every else {
            return false;
        };
        *self.asked += 1;
        self.asked.is_multiple_of(every)
    }
}

/// A planner on a simulated axis, called every millisecond; with a budget
/// it fills again after each [`Fill::Paused`] at the same `now`, as the
/// firmware's control loop does (with other work in between).
struct Run {
    sched: Box<StepSchedule>,
    planner: Planner,
    axis: SimAxis,
    steps: Vec<StepRecord>,
    now_us: u64,
    budget: Option<u32>,
    /// The sink asks for a pause at every this many questions.
    ask_every: Option<u32>,
    asked: u32,
    /// Fills that returned `Paused`.
    pauses: u64,
    /// The most ring entries one part after the first of a control call
    /// took (no step is made between the parts here).
    widest_later_part: usize,
}

impl Run {
    fn new(board: Board, budget: Option<u32>, ask_every: Option<u32>) -> Self {
        let cfg = PlannerConfig::for_board(board);
        let cfg = budget.map_or(cfg, |b| cfg.with_fill_budget(b));
        Self {
            sched: Box::new(StepSchedule::new()),
            planner: Planner::new(cfg),
            axis: SimAxis::new(cfg.tick_hz()),
            steps: Vec::new(),
            now_us: 0,
            budget,
            ask_every,
            asked: 0,
            pauses: 0,
            widest_later_part: 0,
        }
    }

    fn control(&mut self) {
        let mut first = true;
        for _ in 0..10_000 {
            let free = self.sched.free();
            let mut sink = Asking {
                axis: &mut self.axis,
                every: self.ask_every,
                asked: &mut self.asked,
            };
            let fill = self.planner.fill_with(self.now_us, &self.sched, &mut sink);
            if !first {
                self.widest_later_part = self.widest_later_part.max(free - self.sched.free());
            }
            first = false;
            match fill {
                Fill::Paused => {
                    assert!(
                        self.budget.is_some() || self.ask_every.is_some(),
                        "paused unasked, without a budget"
                    );
                    self.pauses += 1;
                }
                _ => break,
            }
        }
        self.axis.kick(&self.sched);
    }

    fn tick(&mut self) {
        let until = self.axis.us_to_ticks(self.now_us + PERIOD_US);
        let steps = &mut self.steps;
        while self.axis.run_until(&self.sched, until, |s| steps.push(s)) == RunStop::SwitchChanged {
        }
        self.now_us += PERIOD_US;
        self.control();
    }

    /// Gives the goals, each followed by its milliseconds, then a stop
    /// and runs to rest.
    fn drive(&mut self, goals: &[(Goal, u64)], stop_decel: u64) {
        self.control();
        for &(goal, ms) in goals {
            self.planner.set_goal(goal);
            for _ in 0..ms {
                self.tick();
            }
        }
        self.planner.set_goal(Goal::Stop { decel: stop_decel });
        for _ in 0..600_000 {
            if self.planner.at_rest(&self.sched) {
                return;
            }
            self.tick();
        }
        panic!("no rest");
    }
}

fn ramp(v: f64, a: f64) -> Ramp {
    Ramp::new((v * 10.0) as u64, (a * 10.0) as u64, (a * 10.0) as u64)
}

/// Both runs (one unbounded fill a period, and in parts with `budget`
/// and a sink asking for a pause at every `ask`-th question) over the
/// same goals: the same steps at the same ticks and exact times, nothing
/// late, nothing dry.
fn same_schedule(
    board: Board,
    goals: &[(Goal, u64)],
    decel: u64,
    budget: Option<u32>,
    ask: Option<u32>,
) -> Run {
    let mut whole = Run::new(board, None, None);
    whole.drive(goals, decel);
    let mut parts = Run::new(board, budget, ask);
    parts.drive(goals, decel);
    assert_eq!(whole.pauses, 0);
    assert_eq!(parts.steps.len(), whole.steps.len(), "steps made");
    if let Some(i) = (0..whole.steps.len()).find(|&i| parts.steps[i] != whole.steps[i]) {
        panic!(
            "step {i} differs: {:?} in parts, {:?} whole",
            parts.steps[i], whole.steps[i]
        );
    }
    for run in [&whole, &parts] {
        assert_eq!(run.planner.underruns(), 0, "ran dry");
        assert_eq!(run.planner.late_segments(), 0, "late segment");
    }
    // a part that follows a pause pushes at most the budget (one entry
    // more for a direction marker), in constant-speed steps at most
    // CONSTANT_STEPS_PER_BUDGET a budget step; asked at every question,
    // one push
    let widest = match (budget, ask) {
        (_, Some(1)) => PUSH_STEPS as usize + 1,
        (Some(b), _) => (b * CONSTANT_STEPS_PER_BUDGET) as usize + 1,
        (None, _) => usize::MAX,
    };
    assert!(
        parts.widest_later_part <= widest,
        "a part took {} entries, budget {budget:?}, asked every {ask:?}",
        parts.widest_later_part
    );
    parts
}

/// A run to the board's top rate at its acceleration limit, for the
/// ramp's time and then `cruise_ms` of cruise.
fn top_rate_run(board: Board, cruise_ms: u64) -> [(Goal, u64); 1] {
    let top = f64::from(board.max_step_rate());
    let accel = board.max_accel() as f64;
    [(
        Goal::Run {
            forward: true,
            ramp: ramp(top, accel),
        },
        (top / accel * 1000.0) as u64 + cruise_ms,
    )]
}

/// The firmware's case: cruise at the board's top rate with a budget of a
/// fraction of a period's steps: every control call fills in several
/// parts, and the schedule is the unbounded fill's.
#[test]
fn a_cruise_at_the_top_rate_is_filled_in_parts_to_the_same_schedule() {
    for board in Board::ALL {
        let goals = top_rate_run(board, 300);
        let budget = 16;
        let parts = same_schedule(board, &goals, board.max_accel() * 10, Some(budget), None);
        // at least two pauses a period while cruising
        assert!(parts.pauses > 400, "{board:?}: {} pauses", parts.pauses);
        // the cruise's steps count a quarter: its parts take more entries
        // than the budget
        assert!(
            parts.widest_later_part > budget as usize + 1,
            "{board:?}: widest part {}",
            parts.widest_later_part
        );
    }
}

/// A budget below the cost of one fit still makes progress (a fit is the
/// first thing a part may always do).
#[test]
fn a_budget_below_one_fit_still_fills() {
    const { assert!(FIT_COST > 1) };
    let goals = [(
        Goal::Move {
            target: 20_000,
            ramp: ramp(100_000.0, 1_000_000.0),
            end_velocity: 0,
        },
        60,
    )];
    let parts = same_schedule(Board::G431, &goals, 10_000_000, Some(1), None);
    assert!(parts.pauses > 0);
}

/// The firmware's case with a frame waiting at every question: without a
/// budget, a fill asked to pause does so after one push (once its lead
/// is covered), through a cruise at the board's top rate and its ramps,
/// and the parts still make the unbounded fill's schedule.
#[test]
fn a_fill_asked_to_pause_pauses_after_one_push() {
    for board in Board::ALL {
        let goals = top_rate_run(board, 100);
        let parts = same_schedule(board, &goals, board.max_accel() * 10, None, Some(1));
        // several pauses a period while cruising
        assert!(parts.pauses > 300, "{board:?}: {} pauses", parts.pauses);
    }
}

fn log_range(lo: f64, hi: f64) -> impl Strategy<Value = f64> {
    (lo.ln()..hi.ln()).prop_map(f64::exp)
}

/// A goal: a move to a target, a run in one direction, or a stop.
fn goal(a: f64) -> impl Strategy<Value = Goal> {
    prop_oneof![
        (-30_000i64..30_000, log_range(100.0, 250_000.0)).prop_map(move |(target, v)| Goal::Move {
            target,
            ramp: ramp(v, a),
            end_velocity: 0,
        }),
        (any::<bool>(), log_range(100.0, 250_000.0)).prop_map(move |(forward, v)| Goal::Run {
            forward,
            ramp: ramp(v, a),
        }),
        Just(Goal::Stop {
            decel: (a * 10.0) as u64
        }),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    /// Random goals changed mid-motion (cuts of the queued steps, reversals,
    /// stops), at each board's tick, with random budgets and pauses asked
    /// for at random: the parts make the schedule one unbounded fill
    /// makes, step for step.
    #[test]
    fn filling_in_parts_makes_the_same_schedule(
        (a, goals) in log_range(2_000.0, 2_000_000.0).prop_flat_map(|a| {
            (Just(a), prop::collection::vec((goal(a), 1u64..40), 1..6))
        }),
        budget in prop::option::of(prop_oneof![1u32..8, 8u32..300]),
        ask in prop::option::of(1u32..5),
        f103 in any::<bool>(),
    ) {
        let board = if f103 { Board::F103 } else { Board::G431 };
        same_schedule(board, &goals, (a * 10.0) as u64, budget, ask);
    }
}

/// The whole device with the firmware's budget, driven through frames
/// with the control loop on its grid, its control calls whole
/// (`Device::control_latched` makes the parts back to back) and as the
/// firmware makes them (`Device::begin_control_latched`, then `top_up`
/// while `fill_paused`): the same steps, the same statusword and position
/// read at every period as the device without a budget, over moves at the
/// board's limits and a target changed mid-move.
#[test]
fn the_device_in_parts_moves_as_the_device_whole() {
    for board in Board::ALL {
        let cfg = PlannerConfig::for_board(board);
        let mut rigs = [
            Rig::with_planner(cfg),
            Rig::with_planner(cfg.with_fill_budget(64)),
            Rig::with_planner(cfg.with_fill_budget(64)),
        ];
        // the third as the firmware calls it: the drive's update, then
        // the fill's parts (Device::begin_control_latched, top_up)
        rigs[2].in_parts = true;
        // 0.1 r/min at PA10 = 10 000 steps/rev: the board's step rate;
        // ramps at its acceleration limit (0.1 r/s²)
        let velocity = (u64::from(board.max_step_rate()) * 60 / 1000) as u16;
        let accel = (board.max_accel() / 1000) as u16;
        let mut seen = [Vec::new(), Vec::new(), Vec::new()];
        for (rig, seen) in rigs.iter_mut().zip(&mut seen) {
            for cw in [0x0006, 0x0007, 0x000F] {
                rig.bus.write_single(0x6040, cw).expect("controlword");
                rig.run_us(rig.period_us);
            }
            rig.bus.write_single(0x6060, 1).expect("mode");
            rig.bus.write(0x6081, &[0, velocity]).expect("velocity");
            rig.bus.write(0x6083, &[accel; 3]).expect("ramps");
            for (target, ms) in [(60_000i32, 150), (-20_000, 700)] {
                rig.bus
                    .write(0x607A, &[(target >> 16) as u16, target as u16])
                    .expect("target");
                rig.bus
                    .write_single(0x6040, 0x003F)
                    .expect("bit 4, at once");
                rig.bus.write_single(0x6040, 0x000F).expect("bit 4 back");
                for _ in 0..ms {
                    rig.run_us(rig.period_us);
                    seen.push((rig.statusword(), rig.position()));
                }
            }
            assert!(rig.at_rest(), "{board:?}: at rest");
            assert_eq!(rig.position(), -20_000, "{board:?}");
        }
        let whole = &rigs[0];
        for (parts, seen_in_parts) in rigs[1..].iter().zip(&seen[1..]) {
            assert_eq!(
                &seen[0], seen_in_parts,
                "{board:?}: statusword and position"
            );
            assert_eq!(whole.steps.len(), parts.steps.len(), "{board:?}: steps");
            assert!(whole.steps == parts.steps, "{board:?}: the steps differ");
        }
    }
}
