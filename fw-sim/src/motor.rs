//! The motor behind the STEP pin and the quadrature encoder on its shaft
//! (`--encoder`, `--encoder-counts`, `--steps-per-rev`, `--stall-at`,
//! `--slip`, `--encoder-noise`; the virtual drive's flags of the same names,
//! docs/closed-loop.md).
//!
//! The shaft follows the STEP pulses the pin gave, with the stall and the
//! slip of the virtual drive's encoder (`closed_loop::sim::SimEncoder` of
//! the drive crate, so the two mean the same): a stall holds the shaft
//! where the steps reach a position until step output stops, a slip loses
//! steps once. Step output has stopped once no STEP pulse came for
//! [`STOPPED_AFTER_PS`].
//!
//! The encoder turns the shaft's position into two square waves A and B in
//! quadrature (A leads B when the shaft turns forward): its count is the
//! shaft position × counts per rev / steps per rev, rounded down, and each
//! change of one count is one edge of A or B, which the pins carry to the
//! timer. Noise is vibration of the shaft: every [`JITTER_PERIOD_PS`] the
//! count stands off by a new repeatable pseudo-random amount within
//! ±`--encoder-noise` counts (real edges, which the timer counts both ways),
//! where the virtual drive adds the same band to each reading.

use modbus_drive::closed_loop::sim::SimEncoder;

/// No STEP pulse for this long: step output has stopped (a stall ends).
pub const STOPPED_AFTER_PS: u64 = 20_000_000_000;
/// How often the vibration of `--encoder-noise` takes a new value.
pub const JITTER_PERIOD_PS: u64 = 250_000_000;

/// What the command line asks of the motor.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MotorOptions {
    /// Encoder counts per revolution after ×4 decoding (PA17's meaning).
    pub counts_per_rev: u32,
    /// Motor steps per revolution (PA10's meaning).
    pub steps_per_rev: u32,
    pub stall_at: Option<i64>,
    /// (steps lost, position)
    pub slip: Option<(i64, i64)>,
    pub noise_counts: u16,
}

impl Default for MotorOptions {
    /// The virtual drive's `--encoder`: a 1000-line encoder (4000 counts)
    /// on a motor at the drive's default 10 000 steps per revolution.
    fn default() -> Self {
        Self {
            counts_per_rev: 4000,
            steps_per_rev: 10_000,
            stall_at: None,
            slip: None,
            noise_counts: 0,
        }
    }
}

#[derive(Clone, Debug)]
pub struct Motor {
    opts: MotorOptions,
    shaft: SimEncoder,
    /// The step position the pin has given.
    steps: i64,
    /// The last STEP pulse, while step output has not been seen to stop.
    last_step: Option<u64>,
    /// Vibration now (counts) and when it changes next.
    jitter: i64,
    next_jitter: u64,
    rng: u32,
    /// The count the encoder's outputs stand at (A and B are its phase).
    count: i64,
}

impl Motor {
    pub fn new(opts: MotorOptions) -> Self {
        let mut shaft = SimEncoder::new();
        if let Some(at) = opts.stall_at {
            shaft = shaft.with_stall_at(at);
        }
        if let Some((steps, at)) = opts.slip {
            shaft = shaft.with_slip(steps, at);
        }
        // only the shaft position is used; the scale is needed for its
        // (unused) reading
        shaft.set_scale(4000, 10_000, false);
        shaft.update(0, false);
        Self {
            opts,
            shaft,
            steps: 0,
            last_step: None,
            jitter: 0,
            next_jitter: JITTER_PERIOD_PS,
            rng: 0x2545_F491,
            count: 0,
        }
    }

    /// A STEP pulse at `t` moved the step position to `steps`.
    pub fn step(&mut self, t: u64, steps: i64) {
        self.steps = steps;
        self.last_step = Some(t);
        self.shaft.update(steps, true);
    }

    /// The timed changes up to `t`: step output seen to stop, vibration.
    /// Returns the time of the first change, if any happened.
    pub fn advance(&mut self, t: u64) -> Option<u64> {
        let mut changed = None;
        if let Some(last) = self.last_step {
            let stop = last + STOPPED_AFTER_PS;
            if stop <= t {
                self.last_step = None;
                self.shaft.update(self.steps, false);
                changed = Some(stop);
            }
        }
        if self.opts.noise_counts > 0 {
            while self.next_jitter <= t {
                self.rng ^= self.rng << 13;
                self.rng ^= self.rng >> 17;
                self.rng ^= self.rng << 5;
                let n = i64::from(self.opts.noise_counts);
                self.jitter = i64::from(self.rng % (2 * n as u32 + 1)) - n;
                changed = Some(changed.map_or(self.next_jitter, |c: u64| c.min(self.next_jitter)));
                self.next_jitter += JITTER_PERIOD_PS;
            }
        }
        changed
    }

    /// When `advance` has something to do next.
    pub fn next_event(&self) -> Option<u64> {
        let stop = self.last_step.map(|l| l + STOPPED_AFTER_PS);
        let jitter = (self.opts.noise_counts > 0).then_some(self.next_jitter);
        [stop, jitter].into_iter().flatten().min()
    }

    /// The shaft position, steps.
    pub fn shaft(&self) -> i64 {
        self.shaft.motor_position()
    }

    /// The count the encoder should show now.
    fn target(&self) -> i64 {
        let c = i128::from(self.shaft()) * i128::from(self.opts.counts_per_rev);
        c.div_euclid(i128::from(self.opts.steps_per_rev.max(1))) as i64 + self.jitter
    }

    /// Moves the encoder one count towards the shaft: the new levels of A
    /// and B, or `None` when it is there.
    pub fn edge(&mut self) -> Option<(bool, bool)> {
        let target = self.target();
        if target == self.count {
            return None;
        }
        self.count += if target > self.count { 1 } else { -1 };
        Some(self.levels())
    }

    /// A and B now: phase 0 both low, 1 A high, 2 both high, 3 B high.
    pub fn levels(&self) -> (bool, bool) {
        match self.count.rem_euclid(4) {
            0 => (false, false),
            1 => (true, false),
            2 => (true, true),
            _ => (false, true),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn edges(m: &mut Motor) -> Vec<(bool, bool)> {
        std::iter::from_fn(|| m.edge()).collect()
    }

    #[test]
    fn forward_steps_give_a_leading_quadrature_and_back_reverses_it() {
        let mut m = Motor::new(MotorOptions::default());
        for s in 1..=10 {
            m.step(s as u64, s);
        }
        // 10 steps at 4000 counts / 10 000 steps = 4 counts: one cycle
        let fwd = edges(&mut m);
        assert_eq!(
            fwd,
            [(true, false), (true, true), (false, true), (false, false)]
        );
        m.step(11, 7);
        assert_eq!(
            edges(&mut m),
            [(false, true), (true, true)],
            "2.8 counts round down to 2: two edges back"
        );
    }

    #[test]
    fn a_stall_holds_the_shaft_until_step_output_stops() {
        let opts = MotorOptions {
            stall_at: Some(100),
            ..Default::default()
        };
        let mut m = Motor::new(opts);
        for s in 1..=300 {
            m.step(s as u64 * 1_000_000, s);
        }
        assert_eq!(m.shaft(), 100);
        assert_eq!(m.next_event(), Some(300 * 1_000_000 + STOPPED_AFTER_PS));
        assert_eq!(m.advance(STOPPED_AFTER_PS), None, "still stepping then");
        let stop = 300 * 1_000_000 + STOPPED_AFTER_PS;
        assert_eq!(m.advance(stop), Some(stop));
        m.step(stop + 1, 301);
        assert_eq!(m.shaft(), 101, "turns again, 200 steps lost");
    }

    #[test]
    fn noise_moves_the_count_within_its_band() {
        let opts = MotorOptions {
            noise_counts: 2,
            ..Default::default()
        };
        let mut m = Motor::new(opts);
        let mut seen = std::collections::BTreeSet::new();
        for k in 1..200 {
            m.advance(k * JITTER_PERIOD_PS);
            edges(&mut m);
            seen.insert(m.count);
        }
        assert_eq!(seen.into_iter().collect::<Vec<_>>(), [-2, -1, 0, 1, 2]);
    }
}
