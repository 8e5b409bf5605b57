//! The step engine's timer entries (`motion::burst`) against the exact
//! trapezoid: random moves planned by the core at the boards' timer
//! clocks (the DMA engine's tick) and at today's step ticks, their
//! per-step delays written as DMA bursts in refills of random size, played
//! on a model of the timer. Every pulse lands on its schedule tick
//! (within half a tick of the core's exact time), so within the planner's
//! bound of the ideal trapezoid; one pulse per step; DIR right at each.

mod common;

use common::axis::{check_times, trapezoid_time, PlannerRun, Q};
use modbus_drive::motion::burst::{Burst, BurstWriter, PulseShape, MIN_ENTRY_TICKS};
use modbus_drive::motion::sim::StepRecord;
use modbus_drive::motion::{Goal, Ramp};
use proptest::prelude::*;

/// Pulse rises (ticks from the first entry) and DIR levels.
fn play(entries: &[Burst]) -> Vec<(u64, bool)> {
    let mut t = 0u64;
    let mut out = Vec::new();
    for b in entries {
        assert!(b.period_ticks() >= MIN_ENTRY_TICKS, "{b:?}");
        for _ in 0..b.periods() {
            if b.pulse_ticks() != 0 {
                out.push((t, b.dir_high()));
            }
            t += u64::from(b.period_ticks());
        }
    }
    out
}

fn burst_move(tick_hz: u32, dist: i64, v: f64, a: f64, d: f64, chunk: usize) {
    // what the registers hold: 0.1 steps/s and 0.1 steps/s²
    let reg = |x: f64| (x * 10.0) as u64 as f64 / 10.0;
    let (v, a, d) = (reg(v), reg(a), reg(d));
    let mut run = PlannerRun::new(tick_hz, 1000);
    run.control();
    assert!(run.planner.set_goal(Goal::Move {
        target: dist,
        ramp: Ramp::new((v * 10.0) as u64, (a * 10.0) as u64, (d * 10.0) as u64),
        end_velocity: 0,
    }));
    run.control();
    let t0 = run.axis.now_ticks();
    run.run_until_rest(3_600_000_000);
    let steps: &[StepRecord] = &run.steps;
    assert_eq!(steps.len() as i64, dist.abs());
    // the delays the engine is given: each step after the one before
    let mut prev = t0;
    let mut k = 0;
    let shape = PulseShape::new(tick_hz / 400_000, tick_hz / 200_000, tick_hz / 10_000);
    let mut w = BurstWriter::new(shape, dist > 0);
    let mut entries = Vec::new();
    let mut buf = vec![Burst::default(); chunk];
    while k < steps.len() || w.busy() {
        w.fill(&mut buf, &mut || {
            let s = steps.get(k)?;
            k += 1;
            let delay = s.tick() - prev;
            prev = s.tick();
            Some((delay as u32, s.forward()))
        });
        entries.extend_from_slice(&buf);
    }
    w.fill(&mut buf, &mut || None);
    entries.extend_from_slice(&buf);
    assert_eq!(w.late(), 0);
    let pulses = play(&entries);
    assert_eq!(pulses.len(), steps.len(), "one pulse per step");
    let (p0, s0) = (pulses[0].0, steps[0].tick());
    for (i, (p, s)) in pulses.iter().zip(steps).enumerate() {
        assert_eq!(
            p.0 - p0,
            s.tick() - s0,
            "step {}: on its schedule tick",
            i + 1
        );
        assert_eq!(p.1, s.forward(), "step {}: DIR", i + 1);
        // the schedule tick within half a tick of the core's exact time
        let off = s.exact().wrapping_sub(s.tick() << 32) as i64 as f64 / Q;
        assert!(
            off.abs() <= 0.5,
            "step {}: {off} ticks from the exact time",
            i + 1
        );
    }
    // and so the pulses against the ideal trapezoid, as the planner's steps
    let pin: Vec<StepRecord> = pulses
        .iter()
        .zip(steps)
        .map(|(p, s)| StepRecord::new(p.0 - p0 + s0, s.exact(), s.position(), s.forward()))
        .collect();
    check_times(&pin, tick_hz, t0, |x| {
        trapezoid_time(dist.abs() as f64, v, a, d, x)
    });
}

#[test]
fn a_move_at_each_boards_timer_clock() {
    for tick in [72_000_000, 170_000_000] {
        burst_move(tick, 20_000, 200_000.0, 2_000_000.0, 2_000_000.0, 16);
        burst_move(tick, -3_000, 5_000.0, 20_000.0, 50_000.0, 7);
    }
}

#[test]
fn slow_moves_are_exact_in_entries_no_longer_than_the_idle_one() {
    // 2 steps/s at 170 MHz: 85 M ticks an interval
    burst_move(170_000_000, 5, 2.0, 50.0, 50.0, 4);
}

fn log_range(lo: f64, hi: f64) -> impl Strategy<Value = f64> {
    (lo.ln()..hi.ln()).prop_map(f64::exp)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    #[test]
    fn random_moves_as_bursts(
        dist in prop_oneof![1i64..200, 200i64..20_000],
        neg in any::<bool>(),
        v in log_range(20.0, 200_000.0),
        a in log_range(50.0, 2_000_000.0),
        d in log_range(50.0, 2_000_000.0),
        tick in prop_oneof![Just(8_000_000u32), Just(10_000_000), Just(72_000_000), Just(170_000_000)],
        chunk in 1usize..64,
    ) {
        let dur = dist as f64 / v + v / a + v / d;
        prop_assume!(dur < 20.0 && v >= 0.1 && a >= 0.1 && d >= 0.1);
        // a cruise whose rounded intervals fall below the shortest entry
        // cannot be played on time at that tick: a board's limit keeps
        // its speeds above it
        prop_assume!(v <= f64::from(tick) / f64::from(MIN_ENTRY_TICKS + 1));
        burst_move(tick, if neg { -dist } else { dist }, v, a, d, chunk);
    }
}
