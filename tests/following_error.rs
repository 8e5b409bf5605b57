//! SPEC §8.8 closed loop, the core's part: a simulated axis whose motor can
//! stall or lose steps, read back through a simulated 16-bit encoder
//! counter, scaled to steps and checked every 1 ms control period.
//!
//! The drive's reaction (quick stop, fault state, statusword and 0x1001
//! bits) is not wired to the check yet; these tests pin down when the check
//! says "fault" and when it must not.

use modbus_drive::closed_loop::{
    CountsToSteps, Encoder, FollowingErrorMonitor, FollowingState, WINDOW_OFF,
};
use proptest::prelude::*;

const PERIOD_US: u32 = 1000;
/// PA10's default.
const STEPS_PER_REV: u16 = 10_000;
/// A 1000-line encoder after ×4 decoding.
const COUNTS_PER_REV: u16 = 4000;
/// Commanded speed, steps per control period (3 rev/s).
const SPEED: i64 = 30;
/// Long enough that the encoder counter wraps twice (240 000 counts).
const MOVE: i64 = 600_000;

#[derive(Clone, Copy, Default)]
struct Faults {
    /// The motor stops turning from this commanded position on.
    stall_at: Option<i64>,
    /// The motor loses this many steps once, at this commanded position.
    slip: Option<(i64, i64)>,
    /// ± counts of noise on every encoder reading.
    noise: i64,
}

struct Axis {
    commanded: i64,
    motor: i64,
    slipped: bool,
    faults: Faults,
    counter_offset: u16,
    rng: u32,
}

impl Axis {
    fn new(faults: Faults) -> Self {
        Self {
            commanded: 0,
            motor: 0,
            slipped: false,
            faults,
            // the counter does not start at 0 on a real board
            counter_offset: 0xF123,
            rng: 0x2545_F491,
        }
    }

    /// One control period of motion towards `target`.
    fn step(&mut self, target: i64) {
        let before = self.commanded;
        self.commanded += (target - self.commanded).clamp(-SPEED, SPEED);
        let stalled = self.faults.stall_at.is_some_and(|at| self.commanded >= at);
        if !stalled {
            self.motor += self.commanded - before;
        }
        if let Some((lost, at)) = self.faults.slip {
            if !self.slipped && self.commanded >= at {
                self.motor -= lost;
                self.slipped = true;
            }
        }
    }

    /// The timer's counter: the motor's position in counts, wrapped to 16
    /// bits, with noise.
    fn counter(&mut self) -> u16 {
        self.rng ^= self.rng << 13;
        self.rng ^= self.rng >> 17;
        self.rng ^= self.rng << 5;
        let noise = if self.faults.noise == 0 {
            0
        } else {
            i64::from(self.rng % (2 * self.faults.noise as u32 + 1)) - self.faults.noise
        };
        let counts = (self.motor * i64::from(COUNTS_PER_REV)).div_euclid(i64::from(STEPS_PER_REV));
        ((counts + noise) as u16).wrapping_add(self.counter_offset)
    }
}

/// The control loop's side: encoder → steps → check.
struct Loop {
    axis: Axis,
    encoder: Encoder,
    scale: CountsToSteps,
    monitor: FollowingErrorMonitor,
    /// Position the encoder's count 0 stands for (set when re-enabling).
    origin: i64,
}

impl Loop {
    fn new(faults: Faults, window: u32, timeout_ms: u16) -> Self {
        let mut axis = Axis::new(faults);
        let encoder = Encoder::new(axis.counter(), false);
        Self {
            axis,
            encoder,
            scale: CountsToSteps::new(COUNTS_PER_REV, STEPS_PER_REV).unwrap(),
            monitor: FollowingErrorMonitor::new(window, timeout_ms),
            origin: 0,
        }
    }

    fn measured(&mut self) -> i64 {
        let counts = self.encoder.update(self.axis.counter());
        self.origin + self.scale.steps(counts)
    }

    /// One period; the state the check reports.
    fn period(&mut self, target: i64) -> FollowingState {
        self.axis.step(target);
        let measured = self.measured();
        self.monitor
            .update(self.axis.commanded, measured, PERIOD_US, true)
    }

    /// Runs towards `target` until there or until the check faults; the
    /// period (from 1) at which it faulted and the largest error seen.
    fn run(&mut self, target: i64) -> (Option<u32>, i64) {
        let mut worst = 0i64;
        for n in 1.. {
            let state = self.period(target);
            worst = worst.max(self.monitor.error().abs());
            if state == FollowingState::Fault {
                return (Some(n), worst);
            }
            if self.axis.commanded == target && n > 50 {
                return (None, worst);
            }
        }
        unreachable!()
    }

    /// Fault reset and re-enable (SPEC §8.8): the measured position becomes
    /// the commanded one; the motor is free again.
    fn reset_and_reenable(&mut self) {
        self.monitor.reset();
        self.axis.faults = Faults::default();
        let measured = self.measured();
        self.axis.commanded = measured;
        self.axis.motor = measured;
        self.encoder.set_counts(0);
        self.origin = measured;
    }
}

#[test]
fn an_intact_axis_stays_within_a_tight_window_through_two_counter_wraps() {
    let mut l = Loop::new(Faults::default(), 3, 0);
    let (fault, worst) = l.run(MOVE);
    assert_eq!(fault, None);
    // one count is 2.5 steps: the scaled position lags by less than that
    assert!(worst <= 3, "worst {worst}");
    let (fault, worst) = l.run(-MOVE);
    assert_eq!(fault, None);
    assert!(worst <= 3, "worst {worst}");
}

#[test]
fn a_stall_mid_move_faults_once_the_time_out_has_passed() {
    let (window, timeout_ms) = (200u32, 20u16);
    let stall_at = 300_000;
    let mut l = Loop::new(
        Faults {
            stall_at: Some(stall_at),
            ..Faults::default()
        },
        window,
        timeout_ms,
    );
    let (fault, _) = l.run(MOVE);
    let fault = fault.expect("a stall must fault") as i64;
    // from the first period at the stall the error grows by SPEED a
    // period; it is above the window from `above_from` on, and the check
    // faults in the period that makes the time above longer than the time
    // out (the 21st period above a 20 ms time out)
    let stalled_from = (stall_at + SPEED - 1) / SPEED;
    let above_from = stalled_from + i64::from(window) / SPEED;
    assert_eq!(
        fault,
        above_from + i64::from(timeout_ms),
        "fault at period {fault}"
    );
    assert!(l.monitor.error() > i64::from(window));
    assert!(l.monitor.is_fault());
}

#[test]
fn a_slip_below_the_window_does_not_fault() {
    let mut l = Loop::new(
        Faults {
            slip: Some((150, 100_000)),
            noise: 1,
            ..Faults::default()
        },
        200,
        10,
    );
    let (fault, worst) = l.run(MOVE);
    assert_eq!(fault, None);
    // the lost steps are in the error for good
    assert!((150..=156).contains(&worst), "worst {worst}");
    assert!((145..=156).contains(&l.monitor.error()));
}

#[test]
fn a_slip_above_the_window_faults_after_the_time_out() {
    let slip_at = 100_000;
    let mut l = Loop::new(
        Faults {
            slip: Some((250, slip_at)),
            ..Faults::default()
        },
        200,
        10,
    );
    let (fault, _) = l.run(MOVE);
    // above from the first period at the slip on; faults in the 11th
    // period above a 10 ms time out
    let slipped_at = (slip_at + SPEED - 1) / SPEED;
    assert_eq!(fault, Some(slipped_at as u32 + 10));
}

#[test]
fn reset_and_re_enable_after_a_stall_then_a_clean_move() {
    let mut l = Loop::new(
        Faults {
            stall_at: Some(50_000),
            ..Faults::default()
        },
        200,
        5,
    );
    assert!(l.run(MOVE).0.is_some());
    // latched until reset, whatever the positions do
    assert_eq!(l.period(l.axis.commanded), FollowingState::Fault);
    l.reset_and_reenable();
    assert!(!l.monitor.is_fault());
    let (fault, worst) = l.run(MOVE);
    assert_eq!(fault, None);
    assert!(worst <= 3, "worst {worst}");
}

#[test]
fn with_the_window_off_a_stall_never_faults() {
    let mut l = Loop::new(
        Faults {
            stall_at: Some(10_000),
            ..Faults::default()
        },
        WINDOW_OFF,
        0,
    );
    let (fault, worst) = l.run(MOVE);
    assert_eq!(fault, None);
    // the live error is still there for the monitor: all the steps the
    // motor did not make
    assert!((worst - (MOVE - l.axis.motor)).abs() <= 3, "worst {worst}");
    assert!(worst > MOVE - 10_000 - 3);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// The running count equals the sum of the motion whatever the counter's
    /// start and however it wraps, as long as a reading moves less than half
    /// the counter's range.
    #[test]
    fn the_encoder_count_is_the_sum_of_the_motion(
        start in any::<u16>(),
        moves in proptest::collection::vec(-32_767i64..=32_767, 1..200),
        invert in any::<bool>(),
    ) {
        let mut e = Encoder::new(start, invert);
        let mut total = 0i64;
        for m in moves {
            total += m;
            let raw = (i64::from(start) + total) as u16;
            let expected = if invert { -total } else { total };
            prop_assert_eq!(e.update(raw), expected);
        }
    }

    /// Scaling is floor(counts × steps / counts per revolution), exactly.
    #[test]
    fn scaling_is_the_exact_floor(
        counts in any::<i64>(),
        cpr in 100u16..,
        spr in 1u16..,
    ) {
        let s = CountsToSteps::new(cpr, spr).unwrap();
        let exact = (i128::from(counts) * i128::from(spr)).div_euclid(i128::from(cpr));
        let expected = exact.clamp(i128::from(i64::MIN), i128::from(i64::MAX)) as i64;
        prop_assert_eq!(s.steps(counts), expected);
    }
}
