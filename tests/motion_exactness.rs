//! Exactness of the planner and step schedule (SPEC §8.4/§8.5):
//! final position exact, step times within min(1 µs, 5 %) of the continuous
//! profile, velocity ≤ +0.5 %, acceleration ≤ +2 % after the first 10
//! steps, direction changes only at rest, nothing scheduled in the past.

mod common;

use common::axis::{
    check_dynamics, check_ideal_times, check_times, ideal_run, trapezoid_time, GoalChange,
    PlannerRun,
};
use modbus_drive::motion::sim::RunStop;
use modbus_drive::motion::{Goal, Ramp};
use proptest::prelude::*;

/// `v` steps/s, `a`/`d` steps/s² → the planner's 0.1 units.
fn ramp(v: f64, a: f64, d: f64) -> Ramp {
    Ramp::new((v * 10.0) as u64, (a * 10.0) as u64, (d * 10.0) as u64)
}

fn single_move(tick_hz: u32, dist: i64, v10: u64, a10: u64, d10: u64) {
    let mut run = PlannerRun::new(tick_hz, 1000);
    let r = Ramp::new(v10, a10, d10);
    run.control();
    assert!(run.planner.set_goal(Goal::Move {
        target: dist,
        ramp: r,
        end_velocity: 0
    }));
    run.control();
    let t0 = run.axis.now_ticks();
    run.run_until_rest(3_600_000_000);
    assert_eq!(run.axis.position(), dist, "final position");
    assert_eq!(run.steps.len() as i64, dist.abs());
    let (v, a, d) = (v10 as f64 / 10.0, a10 as f64 / 10.0, d10 as f64 / 10.0);
    check_times(&run.steps, tick_hz, t0, |k| {
        trapezoid_time(dist.abs() as f64, v, a, d, k)
    });
    check_dynamics(&run.steps, tick_hz, v, a.max(d));
    assert_eq!(run.planner.late_segments(), 0);
    assert_eq!(run.planner.underruns(), 0);
}

#[test]
fn seed_example_move_200000_steps() {
    // seed 000 ch. 6.1: 200000 steps at 5 r/s, 10 r/s², PA10 = 10000
    single_move(10_000_000, 200_000, 50 * 10_000, 100 * 10_000, 100 * 10_000);
}

#[test]
fn short_triangles_and_single_steps() {
    for dist in [1, 2, 3, 7, 10, 11, 64, 101] {
        single_move(8_000_000, dist, 200_000, 100_000, 300_000);
        single_move(8_000_000, -dist, 20_000, 100_000, 50_000);
    }
}

/// A triangle with a steep rise and a slow fall: its peak is rounded to
/// 2^-32 step, and a falling line continued from the rising line's v² at
/// that point would reach rest up to (1 + a/d)·2^-32 step early, which
/// moved the last of these 0.2 s steps by 1.1 µs (found by `random_moves`
/// with 50,000 cases: 113 steps, 183 steps/s, 1.38·10⁶ steps/s² up,
/// 49.9 down, 4 MHz). A triangle's fall now runs on its line through the
/// end.
#[test]
fn a_steep_rise_then_a_slow_fall_ends_on_time() {
    single_move(4_000_000, 113, 1832, 13_795_295, 499);
    single_move(10_000_000, -113, 1832, 20_000_000, 500);
    single_move(8_000_000, 1000, 100_000, 20_000_000, 500);
}

#[test]
fn at_the_maximum_step_rate() {
    single_move(10_000_000, 300_000, 2_000_000, 20_000_000, 20_000_000);
    single_move(4_000_000, -50_000, 2_000_000, 5_000_000, 20_000_000);
}

#[test]
fn slowest_ramps() {
    // 2 steps/s, 2 steps/s² (0.1 r/s and 0.1 r/s² at PA10 = 200)
    single_move(10_000_000, 12, 20, 20, 20);
}

fn log_range(lo: f64, hi: f64) -> impl Strategy<Value = f64> {
    (lo.ln()..hi.ln()).prop_map(f64::exp)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    /// Random single moves: exact end, times, velocity, acceleration.
    #[test]
    fn random_moves(
        dist in prop_oneof![1i64..200, 200i64..20_000],
        neg in any::<bool>(),
        v in log_range(20.0, 1_000_000.0),
        a in log_range(50.0, 2_000_000.0),
        d in log_range(50.0, 2_000_000.0),
        tick in prop_oneof![Just(4_000_000u32), Just(8_000_000), Just(10_000_000), Just(72_000_000), Just(170_000_000)],
    ) {
        // keep each case short in simulated time
        let dur = dist as f64 / v + v / a + v / d;
        prop_assume!(dur < 20.0);
        let r = ramp(v, a, d);
        prop_assume!(r.velocity() > 0 && r.accel() > 0 && r.decel() > 0);
        single_move(tick, if neg { -dist } else { dist }, r.velocity(), r.accel(), r.decel());
    }

    /// Random changes of target while moving (bit 5 semantics: continue
    /// from the current velocity, reverse if the target is behind), with
    /// the step time bound against the ideal profile of each change: the
    /// steps queued when a goal arrives keep the old profile, the new one
    /// continues from the last of them (position, velocity, time) —
    /// `ideal_goal` models that independently of the planner, from the
    /// number of steps queued at the change.
    #[test]
    fn random_mid_move_changes(
        targets in prop::collection::vec((-20_000i64..20_000, 1u64..40), 1..5),
        v in log_range(200.0, 100_000.0),
        a in log_range(1_000.0, 1_000_000.0),
        d in log_range(1_000.0, 1_000_000.0),
    ) {
        let run = goal_changes(&targets, v, a, d);
        prop_assert_eq!(run.planner.late_segments(), 0);
        prop_assert_eq!(run.planner.underruns(), 0);
    }

    /// Velocity mode: signed speed changes while running, reversal through
    /// zero with the deceleration ramp (SPEC §8.5).
    #[test]
    fn random_velocity_changes(
        speeds in prop::collection::vec((-50_000.0f64..50_000.0, 1u64..60), 1..5),
        a in log_range(5_000.0, 1_000_000.0),
    ) {
        let tick = 8_000_000;
        let mut run = PlannerRun::new(tick, 1000);
        run.control();
        let mut vmax: f64 = 0.0;
        for (v, ms) in &speeds {
            if v.abs() < 10.0 { continue; }
            vmax = vmax.max(v.abs());
            let g = Goal::Run { forward: *v > 0.0, ramp: ramp(v.abs(), a, a) };
            assert!(run.planner.set_goal(g));
            for _ in 0..*ms {
                run.tick();
            }
        }
        assert!(run.planner.set_goal(Goal::Stop { decel: (a * 10.0) as u64 }));
        run.run_until_rest(600_000_000);
        let net: i64 = run.steps.iter().map(|s| if s.forward() { 1 } else { -1 }).sum();
        prop_assert_eq!(run.axis.position(), net);
        prop_assert_eq!(i64::from(run.sched.position()), net);
        if vmax > 0.0 {
            check_dynamics(&run.steps, tick, vmax, a);
        }
        prop_assert_eq!(run.planner.late_segments(), 0);
        prop_assert_eq!(run.planner.underruns(), 0);
    }
}

/// A goal that arrives during a triangle's slow fall meets a stop
/// distance of exactly a whole number of steps (the fall runs on its line
/// through the end): stopping there or one step later are both right. The
/// planner stops on the edge; the ideal model must not decide by the few
/// steps before the next goal (which fit both), but by the whole run, where
/// one more step before the reversal moves every step after it
/// (`random_mid_move_changes` at `PROPTEST_RNG_SEED=66`, 50,000 cases: 32,870
/// steps made against 32,872 of the model's greedy choice).
#[test]
fn a_stop_on_a_knife_edge_is_judged_over_the_whole_run() {
    let (v, a, d) = (8769.418050774098, 842456.1648962538, 2270.72602813759);
    let run = goal_changes(&[(-16435, 39), (0, 1), (0, 1)], v, a, d);
    // the planner reverses at the old target: the stop on the edge
    assert_eq!(run.steps.len(), 2 * 16435);
}

/// Hands the moves `targets` to the planner one after another, each for
/// its number of 1 ms control periods (cruise `v`, acceleration `a`,
/// deceleration `d`, steps/s and steps/s²; 10 MHz timer), runs to rest,
/// and checks the end position, the step times against the ideal profiles
/// of the changes (`ideal_run`) and the dynamics (`check_dynamics`).
fn goal_changes(targets: &[(i64, u64)], v: f64, a: f64, d: f64) -> PlannerRun {
    let tick = 10_000_000;
    let mut run = PlannerRun::new(tick, 1000);
    let r = ramp(v, a, d);
    let (vr, ar, dr) = (
        r.velocity() as f64 / 10.0,
        r.accel() as f64 / 10.0,
        r.decel() as f64 / 10.0,
    );
    run.control();
    let mut last = 0;
    let mut changes = Vec::new();
    for &(target, after_ms) in targets {
        assert!(run.planner.set_goal(Goal::Move {
            target,
            ramp: r,
            end_velocity: 0
        }));
        // the steps that keep the old profile: those queued when the
        // goal arrived (set_goal drops what was fitted but not yet
        // handed to the interrupt)
        let queued = run.planner.planned_steps();
        // a goal from rest starts at the first fill after it, if that fill
        // finds the interrupt idle (else after the last queued step)
        run.tick();
        changes.push(GoalChange {
            queued,
            idle_fill_us: run.idle_fill_us,
            target,
        });
        last = target;
        for _ in 1..after_ms {
            run.tick();
        }
    }
    run.run_until_rest(600_000_000);
    assert_eq!(run.axis.position(), last);
    let ideal = ideal_run(&changes, &run.steps, tick, vr, ar, dr);
    check_ideal_times(&run.steps, tick, &ideal);
    check_dynamics(&run.steps, tick, v, a.max(d));
    run
}

/// The margins behind the README's precision figures, on the seed's move
/// (200000 steps, 5 r/s, 10 r/s² at PA10 = 10000, 10 MHz timer): step
/// times within 0.25 µs of the continuous trapezoid (measured 0.107 µs:
/// the segment fit may use up to half of the planner's 1 µs bound, `segment_len`),
/// velocity never above the commanded one (1e-9), acceleration ≤ +0.1 %
/// after the first 10 steps (measured +0.06 %), fewer than 5000 fitted
/// segments (measured 1565).
#[test]
fn seed_move_precision_margins() {
    let tick_hz = 10_000_000;
    let mut run = PlannerRun::new(tick_hz, 1000);
    let r = Ramp::new(500_000, 1_000_000, 1_000_000);
    run.control();
    assert!(run.planner.set_goal(Goal::Move {
        target: 200_000,
        ramp: r,
        end_velocity: 0
    }));
    run.control();
    let t0 = run.axis.now_ticks();
    run.run_until_rest(3_600_000_000);
    let f = f64::from(tick_hz);
    let q = common::axis::Q;
    let (mut a_max, mut v_max, mut t_err) = (0.0f64, 0.0f64, 0.0f64);
    let s = &run.steps;
    for i in 1..s.len() - 1 {
        let dt0 = s[i].exact().wrapping_sub(s[i - 1].exact()) as f64 / q / f;
        let dt1 = s[i + 1].exact().wrapping_sub(s[i].exact()) as f64 / q / f;
        if i > 10 {
            a_max = a_max.max((1.0 / dt1 - 1.0 / dt0).abs() / ((dt0 + dt1) / 2.0));
        }
        v_max = v_max.max(1.0 / dt1);
    }
    for (i, st) in s.iter().enumerate() {
        let want = trapezoid_time(200_000.0, 50_000.0, 100_000.0, 100_000.0, (i + 1) as f64);
        t_err = t_err.max(((st.tick() - t0) as f64 / f - want).abs());
    }
    assert_eq!(run.axis.position(), 200_000);
    assert!(t_err <= 0.25e-6, "time error {t_err}");
    assert!(v_max <= 50_000.0 * (1.0 + 1e-9), "velocity {v_max}");
    assert!(a_max <= 100_000.0 * 1.001, "acceleration {a_max}");
    assert!(
        run.planner.segments_fitted() < 5_000,
        "segments {}",
        run.planner.segments_fitted()
    );
}

/// 500 steps/s (2 ms per step), 5000 steps/s² both ways.
fn slow_ramp() -> Ramp {
    ramp(500.0, 5_000.0, 5_000.0)
}

/// A move of 100 000 steps with [`slow_ramp`], 400 ms in: cruising since
/// step 25, in segments of 64 steps (128 ms).
fn slow_cruise(tick_hz: u32) -> PlannerRun {
    let mut run = PlannerRun::new(tick_hz, 1000);
    run.control();
    assert!(run.planner.set_goal(Goal::Move {
        target: 100_000,
        ramp: slow_ramp(),
        end_velocity: 0
    }));
    for _ in 0..400 {
        run.tick();
    }
    run
}

/// A change of goal takes effect within the horizon however long the
/// segments are (docs/drive.md "Planner and precision"): at a slow cruise the
/// segments are fitted 64 steps (128 ms) long, yet a stop given mid-cruise
/// starts decelerating after at most the horizon (3 ms) and one step —
/// its steps pushed beyond the horizon are taken back.
#[test]
fn a_new_goal_takes_effect_within_the_horizon() {
    let (tick_hz, r) = (10_000_000, slow_ramp());
    let mut run = slow_cruise(tick_hz);
    let fitted_before = run.planner.segments_fitted();
    for _ in 0..200 {
        run.tick();
    }
    let fitted = run.planner.segments_fitted() - fitted_before;
    assert!(fitted <= 4, "{fitted} segments for 100 cruise steps");
    let now_s = run.now_us as f64 * 1e-6;
    assert!(run.planner.set_goal(Goal::Stop { decel: r.decel() }));
    run.run_until_rest(10_000_000);
    // the first interval longer than the cruise's 2 ms marks the stop
    let f = f64::from(tick_hz);
    let first_slow = run
        .steps
        .windows(2)
        .find(|w| {
            w[0].tick() as f64 / f > now_s
                && w[1].exact().wrapping_sub(w[0].exact()) as f64 / common::axis::Q / f
                    > 0.002 * 1.0001
        })
        .expect("a deceleration");
    // it begins at the step before it: after what was pushed (≤ the 3 ms
    // horizon) and at most one more cruise step (a stop ends on a whole
    // step, so it may cruise up to one step before it brakes)
    let late = first_slow[0].tick() as f64 / f - now_s;
    assert!(late <= 0.003 + 0.002 * 1.01, "stop began {late} s late");
    // and it is the commanded stop: 500²/(2·5000) = 25 steps
    let made_after = run
        .steps
        .iter()
        .filter(|s| s.tick() as f64 / f > now_s)
        .count();
    assert!(
        (25..=30).contains(&made_after),
        "{made_after} steps after the stop"
    );
}

/// A segment is pushed whole and a new goal takes back its steps due
/// after the horizon in the next control call (docs/drive.md "Planner and
/// precision"). If that call comes so late that the interrupt has already
/// reached the cut, the planner stops at once (counted as an underrun)
/// and plans the goal again from where the motor is: the move still ends
/// exactly on its target.
#[test]
fn a_cut_the_interrupt_passed_first_plans_the_goal_again() {
    let (r, mut run) = (slow_ramp(), slow_cruise(10_000_000));
    let queued = run
        .sched
        .last_pushed_index()
        .wrapping_sub(run.sched.step_index());
    assert!(queued > 4, "a long segment is queued ({queued} steps)");
    assert!(run.planner.set_goal(Goal::Move {
        target: 200,
        ramp: r,
        end_velocity: 0
    }));
    assert_eq!(run.planner.underruns(), 0);
    // the control loop stalls for 20 ms (10 steps): the interrupt runs on
    // into the steps the new goal meant to take back
    let until = run.axis.us_to_ticks(run.now_us + 20_000);
    let steps = &mut run.steps;
    while run.axis.run_until(&run.sched, until, |s| steps.push(s)) == RunStop::SwitchChanged {}
    run.now_us += 20_000;
    run.control();
    assert_eq!(run.planner.underruns(), 1, "the cut came too late");
    run.run_until_rest(10_000_000);
    assert_eq!(run.planner.actual_position(&run.sched), 200);
    assert_eq!(i64::from(run.sched.position()), 200);
}

/// A goal that cuts a pushed segment continues the steps made without a
/// jump (docs/drive.md "Planner and precision"). The sequence is the one
/// `random_velocity_changes` found (its regression file keeps it too):
/// three speed changes while accelerating, a reversal, and a stop with the
/// same deceleration given 4 to 11 ms into the reversal, so at several
/// points inside its segments; the acceleration between consecutive
/// intervals must stay within the planner's +2 % bound across every cut. Starting
/// the next segment from the profile's exact time and `1/v` at the cut
/// instead (where the fit is off by up to its error bound), 4 of these 8
/// stops fail, by up to +3.0 %.
#[test]
fn a_cut_segment_continues_the_steps_made() {
    let tick = 8_000_000;
    let a = 72_327.919_231_136_18;
    let speeds = [
        (43_559.732_431_885_77, 30),
        (44_437.635_945_552_96, 31),
        (49_233.039_954_760_105, 22),
    ];
    for stop_after_ms in 4..12 {
        let mut run = PlannerRun::new(tick, 1000);
        run.control();
        for (v, ms) in speeds {
            assert!(run.planner.set_goal(Goal::Run {
                forward: true,
                ramp: ramp(v, a, a),
            }));
            for _ in 0..ms {
                run.tick();
            }
        }
        assert!(run.planner.set_goal(Goal::Run {
            forward: false,
            ramp: ramp(10_599.300_280_016_108, a, a),
        }));
        for _ in 0..stop_after_ms {
            run.tick();
        }
        assert!(run.planner.set_goal(Goal::Stop {
            decel: (a * 10.0) as u64
        }));
        run.run_until_rest(600_000_000);
        let net: i64 = run
            .steps
            .iter()
            .map(|s| if s.forward() { 1 } else { -1 })
            .sum();
        assert_eq!(run.axis.position(), net);
        check_dynamics(&run.steps, tick, 49_233.039_954_760_105, a);
    }
}
