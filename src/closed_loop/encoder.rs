//! Quadrature encoder position from a 16-bit timer counter in encoder mode.

use crate::arith::div_u64;

/// Fewest counts per revolution (after ×4 decoding) PA17 accepts besides 0
/// (no encoder).
pub const COUNTS_PER_REV_MIN: u16 = 100;

/// The running encoder count, unwrapped from the timer's 16-bit counter.
///
/// The counter wraps at 0xFFFF ↔ 0; the difference between two readings
/// taken as a signed 16-bit number is the motion between them, so the
/// counter must be read before it has moved half its range (32 767 counts)
/// — at a 1 ms control period that is 32.7 million counts per second.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Encoder {
    last_raw: u16,
    counts: i64,
    invert: bool,
}

impl Encoder {
    /// Starts at count 0 from the counter's current value `raw`; `invert`
    /// (PA18) counts the other way.
    pub const fn new(raw: u16, invert: bool) -> Self {
        Self {
            last_raw: raw,
            counts: 0,
            invert,
        }
    }

    /// Takes the counter's value now and returns the running count.
    pub fn update(&mut self, raw: u16) -> i64 {
        let delta = i64::from(raw.wrapping_sub(self.last_raw) as i16);
        self.last_raw = raw;
        self.counts += if self.invert { -delta } else { delta };
        self.counts
    }

    /// The running count at the last [`update`](Self::update).
    pub const fn counts(&self) -> i64 {
        self.counts
    }

    /// Sets the running count (homing sets the position; the counter itself
    /// is left alone).
    pub fn set_counts(&mut self, counts: i64) {
        self.counts = counts;
    }
}

/// Scales encoder counts to motor steps: PA17 counts per revolution to
/// PA10 steps per revolution.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CountsToSteps {
    counts_per_rev: u16,
    steps_per_rev: u16,
}

impl CountsToSteps {
    /// `None` when `counts_per_rev` is below [`COUNTS_PER_REV_MIN`] (0 means
    /// no encoder) or `steps_per_rev` is 0.
    pub const fn new(counts_per_rev: u16, steps_per_rev: u16) -> Option<Self> {
        if counts_per_rev < COUNTS_PER_REV_MIN || steps_per_rev == 0 {
            return None;
        }
        Some(Self {
            counts_per_rev,
            steps_per_rev,
        })
    }

    /// The position in steps of `counts`, rounded towards −∞ so that a
    /// position moves by the same steps in both directions across 0.
    ///
    /// Whole revolutions and the remainder are scaled apart, so the result
    /// is exact wherever it fits in `i64`; a result beyond `i64` (more steps
    /// than counts, near the ends of the count's range) saturates. The
    /// count is split by a 64-by-16-bit division ([`div_u64`]: the 32-bit
    /// hardware divide, not the software `i64` one), and the remainder
    /// part, below 2^16 · 2^16, is scaled in `u32`.
    pub fn steps(&self, counts: i64) -> i64 {
        let cpr = u32::from(self.counts_per_rev);
        let spr = u32::from(self.steps_per_rev);
        let magnitude = counts.unsigned_abs();
        // whole revolutions towards 0, so their steps are never more than
        // the result; below 2^63 / 100, so they fit in i64
        let revs = div_u64(magnitude, u64::from(cpr));
        let part = (magnitude - revs * u64::from(cpr)) as u32 * spr;
        // the part revolution rounded down: towards 0 above 0, away below
        let (revs, part) = if counts < 0 {
            (-(revs as i64), -i64::from(part.div_ceil(cpr)))
        } else {
            (revs as i64, i64::from(part / cpr))
        };
        revs.saturating_mul(i64::from(spr)).saturating_add(part)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::strategy::Just;

    #[test]
    fn the_count_follows_the_counter_across_its_wrap_both_ways() {
        let mut e = Encoder::new(0xFFF0, false);
        assert_eq!(e.update(0x0010), 0x20); // forward over 0xFFFF → 0
        assert_eq!(e.update(0xFFF0), 0); // and back
        assert_eq!(e.update(0xFF00), -0xF0);
        assert_eq!(e.update(0x0100), 0x110); // forward over the wrap again
    }

    #[test]
    fn half_a_range_per_reading_is_the_limit() {
        let mut e = Encoder::new(0, false);
        assert_eq!(e.update(0x7FFF), 0x7FFF);
        // 0x8000 more looks like 0x8000 less: the documented limit
        assert_eq!(e.update(0xFFFF), 0x7FFF - 0x8000);
    }

    #[test]
    fn invert_counts_the_other_way() {
        let mut e = Encoder::new(100, true);
        assert_eq!(e.update(150), -50);
        assert_eq!(e.update(90), 10);
        e.set_counts(1000);
        assert_eq!(e.update(80), 1010);
        assert_eq!(e.counts(), 1010);
    }

    #[test]
    fn counts_scale_to_steps_rounding_down() {
        // 4000 counts (1000 lines ×4) per revolution, 10 000 steps
        let s = CountsToSteps::new(4000, 10_000).unwrap();
        assert_eq!(s.steps(0), 0);
        assert_eq!(s.steps(1), 2); // 2.5
        assert_eq!(s.steps(-1), -3); // −2.5
        assert_eq!(s.steps(4000), 10_000);
        assert_eq!(s.steps(-4001), -10_003);
        // fewer steps than counts
        let s = CountsToSteps::new(4000, 200).unwrap();
        assert_eq!(s.steps(19), 0);
        assert_eq!(s.steps(20), 1);
        assert_eq!(s.steps(-1), -1);
    }

    #[test]
    fn scaling_never_overflows() {
        let s = CountsToSteps::new(COUNTS_PER_REV_MIN, 60_000).unwrap();
        let big = i64::MAX / 600;
        assert_eq!(s.steps(big), big / 100 * 60_000 + big % 100 * 600);
        assert_eq!(s.steps(i64::MAX), i64::MAX);
        assert_eq!(s.steps(i64::MIN), i64::MIN);
        assert_eq!(s.steps(-big), -big * 600);
    }

    /// The `i64` arithmetic the scaling had before it was narrowed: the
    /// reference of the range proof below.
    fn steps_i64(cpr: u16, spr: u16, counts: i64) -> i64 {
        let (cpr, spr) = (i64::from(cpr), i64::from(spr));
        let (revs, rest) = (counts / cpr, counts % cpr);
        (revs.saturating_mul(spr)).saturating_add((rest * spr).div_euclid(cpr))
    }

    proptest::proptest! {
        /// Over every count and every accepted PA17 / PA10 pair, the narrow
        /// arithmetic gives what the `i64` arithmetic gave.
        #[test]
        fn narrow_scaling_equals_the_i64_one(
            cpr in COUNTS_PER_REV_MIN..=u16::MAX,
            spr in 1..=u16::MAX,
            counts in proptest::prop_oneof![
                proptest::num::i64::ANY,
                -1_000_000i64..1_000_000,
                proptest::prop_oneof![Just(i64::MIN), Just(i64::MAX), Just(0)],
            ],
        ) {
            let s = CountsToSteps::new(cpr, spr).unwrap();
            proptest::prop_assert_eq!(s.steps(counts), steps_i64(cpr, spr, counts));
        }
    }

    #[test]
    fn no_encoder_or_too_few_counts_is_refused() {
        assert_eq!(CountsToSteps::new(0, 10_000), None);
        assert_eq!(CountsToSteps::new(COUNTS_PER_REV_MIN - 1, 10_000), None);
        assert_eq!(CountsToSteps::new(COUNTS_PER_REV_MIN, 0), None);
        assert!(CountsToSteps::new(u16::MAX, 200).is_some());
    }
}
