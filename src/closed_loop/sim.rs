//! A simulated quadrature encoder on the simulated axis, with the faults a
//! closed loop must notice (SPEC §8.8): for the virtual drive and the host
//! tests (no_std, no heap, no clock).
//!
//! The motor follows the step count the axis made, except that
//! - a *stall* at a position stops the motor there while steps keep coming;
//!   once step output stops (the drive stopped) the obstruction is gone and
//!   the motor turns again from where it stood: the steps sent meanwhile are
//!   lost;
//! - a *slip* loses a number of steps once, the first time the step count
//!   passes a position (against the direction of travel);
//! - *noise* adds a pseudo-random ±N counts to every reading (repeatable).
//!
//! [`SimEncoder::update`] returns what the encoder timer's 16-bit counter
//! holds: the motor position in counts (PA17 per PA10 steps, PA18 inverts),
//! plus the noise, wrapping.

/// See the module docs.
#[derive(Clone, Debug)]
pub struct SimEncoder {
    counts_per_rev: u16,
    steps_per_rev: u16,
    invert: bool,
    stall_at: Option<i64>,
    /// Where the motor stands while stalled.
    stalled: Option<i64>,
    slip: Option<(i64, i64)>,
    noise: u16,
    /// Step count − motor position.
    lost: i64,
    last_axis: Option<i64>,
    /// The counter's value at motor position 0 (a board's counter does not
    /// start at 0).
    counter_offset: u16,
    rng: u32,
}

impl SimEncoder {
    /// No faults; scaled by [`SimEncoder::set_scale`] before use.
    pub const fn new() -> Self {
        Self {
            counts_per_rev: 0,
            steps_per_rev: 1,
            invert: false,
            stall_at: None,
            stalled: None,
            slip: None,
            noise: 0,
            lost: 0,
            last_axis: None,
            counter_offset: 0xF000,
            rng: 0x2545_F491,
        }
    }

    /// The motor stops at step position `at` (once, see the module docs).
    pub const fn with_stall_at(mut self, at: i64) -> Self {
        self.stall_at = Some(at);
        self
    }

    /// The motor loses `steps` once where the step count passes `at`.
    pub const fn with_slip(mut self, steps: i64, at: i64) -> Self {
        self.slip = Some((steps, at));
        self
    }

    /// ± `counts` of noise on every reading.
    pub const fn with_noise(mut self, counts: u16) -> Self {
        self.noise = counts;
        self
    }

    /// PA17 counts per revolution, PA10 steps per revolution, PA18 invert:
    /// the glue passes the drive's parameters in, as a wired encoder would
    /// match them.
    pub fn set_scale(&mut self, counts_per_rev: u16, steps_per_rev: u16, invert: bool) {
        self.counts_per_rev = counts_per_rev;
        self.steps_per_rev = steps_per_rev.max(1);
        self.invert = invert;
    }

    /// The motor's position, steps.
    pub fn motor_position(&self) -> i64 {
        self.stalled
            .unwrap_or(self.last_axis.unwrap_or(0) - self.lost)
    }

    /// The axis made steps up to `axis_position`; `running` = step output
    /// goes on. Returns the encoder counter's value now.
    pub fn update(&mut self, axis_position: i64, running: bool) -> u16 {
        let before = self.last_axis.unwrap_or(axis_position);
        self.last_axis = Some(axis_position);
        let passed =
            |at: i64| (before < at && at <= axis_position) || (before > at && at >= axis_position);
        if let Some((steps, at)) = self.slip {
            if passed(at) {
                self.slip = None;
                self.lost += if axis_position >= before {
                    steps
                } else {
                    -steps
                };
            }
        }
        if let Some(at) = self.stall_at {
            if passed(at) {
                self.stall_at = None;
                self.stalled = Some(at - self.lost);
            }
        }
        if let Some(motor) = self.stalled {
            self.lost = axis_position - motor;
            if !running {
                self.stalled = None;
            }
        }
        let motor = self.motor_position();
        let cpr = i64::from(self.counts_per_rev);
        let spr = i64::from(self.steps_per_rev);
        let mut counts = (i128::from(motor) * i128::from(cpr)).div_euclid(i128::from(spr)) as i64;
        if self.noise > 0 {
            // xorshift32: repeatable noise, no dependency
            self.rng ^= self.rng << 13;
            self.rng ^= self.rng >> 17;
            self.rng ^= self.rng << 5;
            let span = 2 * u32::from(self.noise) + 1;
            counts += i64::from(self.rng % span) - i64::from(self.noise);
        }
        if self.invert {
            counts = -counts;
        }
        self.counter_offset.wrapping_add(counts as u16)
    }
}

impl Default for SimEncoder {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::closed_loop::{CountsToSteps, Encoder};

    fn read_back(e: &mut SimEncoder, moves: &[(i64, bool)]) -> i64 {
        let mut enc = Encoder::new(e.update(0, false), false);
        let scale = CountsToSteps::new(4000, 10_000).unwrap();
        let mut last = 0;
        for &(p, running) in moves {
            last = scale.steps(enc.update(e.update(p, running)));
        }
        last
    }

    fn sim() -> SimEncoder {
        let mut e = SimEncoder::new();
        e.set_scale(4000, 10_000, false);
        e
    }

    #[test]
    fn an_intact_motor_reads_back_its_steps_across_counter_wraps() {
        let moves: Vec<_> = (1..=200).map(|i| (i * 1000, true)).collect();
        // 200 000 steps = 80 000 counts: the 16-bit counter wraps
        assert_eq!(read_back(&mut sim(), &moves), 200_000);
        assert_eq!(read_back(&mut sim(), &[(-12_345, true)]), -12_345);
        // 1 step = 0.4 counts: a step between two counts reads the count below
        assert_eq!(read_back(&mut sim(), &[(-12_346, true)]), -12_348);
    }

    #[test]
    fn a_stall_holds_the_motor_until_step_output_stops() {
        let mut e = sim().with_stall_at(5000);
        read_back(&mut e, &[(4000, true), (6000, true), (9000, true)]);
        assert_eq!(e.motor_position(), 5000);
        e.update(9500, false); // the drive stopped: the stall is over
        assert_eq!(e.motor_position(), 5000);
        e.update(10_500, true);
        assert_eq!(e.motor_position(), 6000, "turns again, 4500 steps lost");
    }

    #[test]
    fn a_slip_loses_steps_once_in_the_direction_of_travel() {
        let mut e = sim().with_slip(300, 1000);
        read_back(&mut e, &[(900, true), (1100, true), (5000, true)]);
        assert_eq!(e.motor_position(), 4700);
        e.update(-2000, true); // passing 1000 again: no second slip
        assert_eq!(e.motor_position(), -2300);
    }

    #[test]
    fn noise_stays_within_its_bound_and_inversion_counts_down() {
        let mut e = sim().with_noise(2);
        let zero = sim().update(0, false);
        let mut seen = [false; 5];
        for _ in 0..1000 {
            let d = e.update(0, false).wrapping_sub(zero) as i16;
            assert!((-2..=2).contains(&d), "{d}");
            seen[(d + 2) as usize] = true;
        }
        assert_eq!(seen, [true; 5], "every value of the band occurs");
        let mut e = sim();
        e.set_scale(4000, 10_000, true);
        let a = e.update(0, false);
        let b = e.update(10_000, true);
        assert_eq!(b.wrapping_sub(a) as i16, -4000);
    }
}
