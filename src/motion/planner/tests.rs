//! The planner's unit tests.

use super::*;

/// A goal or a stop given between two fills is acted on by the next
/// fill, also one at the same `now` as the last: the quick return of a
/// covered horizon (`Planner::covered`) must not hide the cut of the
/// queued steps or the wait for a stop at once.
#[test]
fn a_goal_between_fills_is_planned_by_the_next_fill() {
    use crate::motion::schedule::StepSource;
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    let mut p = Planner::new(PlannerConfig::default());
    // 500 steps/s, 5000 steps/s²: cruising after 25 steps, in segments
    // of 64 steps (128 ms), the horizon covered in most fills
    let ramp = Ramp::new(5_000, 50_000, 50_000);
    assert!(p.set_goal(Goal::Move {
        target: 100_000,
        ramp,
        end_velocity: 0
    }));
    let (mut now_us, mut at) = (0u64, None::<u64>);
    while now_us < 400_000 {
        p.fill(now_us, &sched);
        at = at.or((!sched.is_empty()).then_some(now_us * 10));
        while let Some(t) = at.filter(|&t| t < (now_us + 1000) * 10) {
            at = src.advance(&sched).map(|s| t + u64::from(s.delay_ticks()));
        }
        now_us += 1000;
    }
    assert_eq!(p.fill(now_us, &sched), Fill::Full);
    let free = sched.free();
    let faster = Ramp {
        velocity: 8_000,
        ..ramp
    };
    assert!(p.set_goal(Goal::Run {
        forward: true,
        ramp: faster
    }));
    // the steps after the horizon taken back at once (the new goal is
    // appended when the horizon needs it)
    assert_eq!(p.fill(now_us, &sched), Fill::Full);
    assert!(sched.free() > free, "no cut: {free} -> {}", sched.free());
    p.stop_at_once(&sched);
    assert_eq!(p.fill(now_us, &sched), Fill::Waiting);
}

/// 0x606C / statusword bit 13 follow the segment the interrupt is
/// executing (SPEC §8.2): over a move of many laps of the step ring,
/// the velocity shown at every step matches that step's own interval
/// within a segment's velocity change (≤ 1/32, `Profile::segment_len`),
/// also during the ramps, where a segment queued ahead (3 ms at
/// 2e6 steps/s²) would be off by up to 6000 steps/s.
#[test]
fn the_velocity_shown_is_the_executing_segments() {
    use crate::motion::schedule::StepSource;
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    let cfg = PlannerConfig::default();
    let hz = f64::from(cfg.tick_hz);
    let mut p = Planner::new(cfg);
    // 100 000 steps/s, 2e6 steps/s²
    let ramp = Ramp::new(1_000_000, 20_000_000, 20_000_000);
    assert!(p.set_goal(Goal::Move {
        target: 30_000,
        ramp,
        end_velocity: 0
    }));
    let ticks_per_us = u64::from(cfg.tick_hz / 1_000_000);
    let (mut now_us, mut at, mut steps, mut ramping) = (0u64, None::<u64>, 0u32, 0u32);
    while now_us < 1_000_000 {
        p.fill(now_us, &sched);
        if at.is_none() && !sched.is_empty() {
            at = Some(now_us * ticks_per_us);
        }
        let end = (now_us + 1000) * ticks_per_us;
        while let Some(t) = at.filter(|&t| t < end) {
            let Some(s) = src.advance(&sched) else {
                at = None;
                break;
            };
            at = Some(t + u64::from(s.delay_ticks()));
            steps += 1;
            let shown = p.actual_velocity(&sched) as f64 / 10.0;
            let own = hz / f64::from(s.delay_ticks());
            if own > 5_000.0 {
                assert!(
                    (shown / own - 1.0).abs() < 0.06,
                    "step {steps}: shown {shown} steps/s, interval {own}"
                );
            }
            ramping += u32::from(p.ramping(&sched));
        }
        now_us += 1000;
    }
    assert_eq!((steps, sched.position()), (30_000, 30_000));
    assert_eq!(p.actual_velocity(&sched), 0);
    // both ramps (2500 steps each) shown as ramping, the cruise not
    assert!((4_000..6_000).contains(&ramping), "{ramping}");
    assert!(p.segments_pushed() > 100);
}
