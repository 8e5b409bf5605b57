//! How long each schedule segment may be: the curvature of the step times
//! and the bounds of the planner's fit (time, acceleration, precision).

use super::fixed::{log2_q8, log2_q8_64, log2_q8_up, LOG2_Q8_SLACK};
use super::{Profile, X_FRAC};
use crate::motion::schedule::MAX_FINE_BITS;

/// Largest segment, as a power of two (steps), reached on a cruise (a
/// ramp's are shorter, [`MAX_RAMP_SEGMENT_LOG2`]): a segment is pushed in
/// parts as the ring has room, so it may be longer than the ring, and at
/// a constant speed its fit is the per-step cost of the planner, which a
/// long segment spreads over many steps.
pub const MAX_SEGMENT_LOG2: u32 = 10;

/// What bounds a segment's length besides the fit (set once from the
/// planner's configuration).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SegmentBudget {
    /// 256·log2 of the longest segment, in Q32.32 ticks.
    log_max_ticks: i32,
    /// Timer ticks per µs, × 256 (the 1 µs error bound).
    us_q8: u64,
}

impl SegmentBudget {
    /// 256·log2 of the longest segment, in Q32.32 ticks.
    #[inline]
    pub const fn log_max_ticks(&self) -> i32 {
        self.log_max_ticks
    }

    /// Timer ticks per µs, × 256 (the 1 µs error bound).
    #[inline]
    pub const fn us_q8(&self) -> u64 {
        self.us_q8
    }
}

impl SegmentBudget {
    /// `tick_hz` a whole number of MHz (`PlannerConfig::tick_hz`): no
    /// 64-bit division.
    pub fn new(tick_hz: u32, max_segment_us: u32) -> Self {
        let per_us = u64::from(tick_hz / 1_000_000);
        // and at most 2^22 ticks: the segment fit's numbers stay in 64 bits
        let ticks = (u64::from(max_segment_us) * per_us).clamp(1, 1 << 22);
        Self {
            log_max_ticks: log2_q8(u128::from(ticks) << 32),
            us_q8: per_us << 8,
        }
    }
}

/// `⌊256·log2 1000⌋`, `⌊256·log2 250⌋` (segment_len's fit constants).
pub(super) const LOG2_Q8_1000: i32 = 2551;

pub(super) const LOG2_Q8_250: i32 = 2039;

/// `⌈256·log2 1000⌉`.
pub(super) const LOG2_Q8_1000_UP: i32 = 2552;

/// `⌈256·log2 40⌉`.
pub(super) const LOG2_Q8_40_UP: i32 = 1363;

/// Longest segment on a ramp, as a power of two (steps).
pub(super) const MAX_RAMP_SEGMENT_LOG2: u32 = 7;

impl Profile {
    /// `t''(x)`, the change of the time per step per step (Q32.32 ticks),
    /// at a point of the current piece where the time per step is `s`
    /// ([`Profile::step_ticks`]): `t' = 1/v`, `t'' = −v'/v² = −a/v³ =
    /// −a·s³` (negative while accelerating). Relative precision 2^-29:
    /// it shapes the segment fit's curvature, not its end points.
    pub fn curvature(&self, s: u64) -> i64 {
        let piece = self.pieces[self.idx];
        let (m, sh) = piece.accel;
        if m == 0 || s == 0 {
            return 0;
        }
        let z = s.leading_zeros();
        let sn = u128::from(s << z);
        let s3 = (((sn * sn) >> 64) * sn) >> 64; // (s·2^z)³ / 2^128
                                                 // a·s³/2^64 = m·s3 · 2^(128 − 3z − sh − 64)
        let prod = u128::from(m) * s3;
        let e = 64 - 3 * z as i32 - sh as i32;
        let c = if e >= 0 {
            if prod >> (127 - e.min(127)) != 0 {
                u128::from(u64::MAX >> 1)
            } else {
                prod << e
            }
        } else {
            prod >> (-e).min(127)
        };
        let c = c.min(u128::from(u64::MAX >> 1)) as i64;
        if piece.slope > 0 {
            -c
        } else {
            c
        }
    }

    /// How many steps the next schedule segment should hold: a power of
    /// two, inside the current piece and the profile, within `budget`'s
    /// length bound, and short enough that the planner's quintic Hermite
    /// fit of the step times (it matches `t`, `t'` and `t''` at both ends,
    /// planner's `fit_segment`) stays within the exactness bounds:
    ///
    /// - Time: on a ramp the step time is `t(x) ∝ √(m + x)` (`m` steps from
    ///   the rest point of the ramp's slope), and the fit misses it by at
    ///   most `max|t⁽⁶⁾|·n⁶/46080 = p·n⁶/(1562·m⁵)` ticks (`p` the
    ///   interval). That error plus the timer's ½-tick rounding must stay
    ///   inside `min(1 µs, 5 % of the interval)`: the fit may use
    ///   `E = B/2 − ¼` ticks of `B = min(1 µs, p/25)` (p/25: the interval
    ///   shrinks by up to 18 % along an accelerating segment), so
    ///   `n⁶ ≤ K·E·m⁵/p` with `K = 1000` when accelerating, and `K = 250`
    ///   when decelerating, whose worst point is the segment's end
    ///   (`m − n ≥ 3m/4`, `p` 15 % longer there).
    /// - Acceleration: the fit's `t''` is exact at both ends and misses by
    ///   at most `t⁽⁶⁾·n⁴/1920`, i.e. `0.031·(n/m)⁴` relative, inside:
    ///   `n ≤ m/2` (`m/4` decelerating) keeps the acceleration the motor
    ///   sees within 0.2 % (the bound is +2 %).
    /// - Precision: `curv` is the curvature at the start
    ///   ([`Profile::curvature`] at `step_ticks`). The segment's terms are
    ///   rounded to 2^-32 tick, `add2` on to 2^-(32 + f) with the fit's
    ///   `f = min(16, 3k − 1)` fine bits, and the highest one's rounding
    ///   (½ unit) reaches the last interval `C(n−1, 4)` times: kept below
    ///   0.1 % of the interval change per step (`|t''|`, which shrinks by
    ///   up to 45 % along an accelerating segment), `n⁴ ≤ 2^f·|t''|/40` in
    ///   units of 2^-32 tick (0.5 % looked safe by this count, with the
    ///   fit's 0.2 % under the 2 % bound, but let through acceleration
    ///   spikes of +2.1 % to +4.3 % in the random-move proptests, 2 runs
    ///   in 36 of 300 cases: the margin is kept); its time error, `C(n, 5)`
    ///   half units, stays below 1/30 tick with ramp segments of at most
    ///   2^7 steps. `add`, which drops the fraction of the fine `add2` at
    ///   each step, is off by at most `n` units at the end: `n ≤
    ///   |t''|/1000` keeps that within 0.1 % too. The fine bits are what
    ///   keeps a ramp's segments long at high speed, where `|t''|` is
    ///   small.
    ///
    /// No division or root: the bounds are compared as logarithms
    /// (`log2_q8`, 1/256 bit, rounded towards shorter segments).
    pub fn segment_len(&self, step_ticks: Option<u64>, curv: i64, budget: &SegmentBudget) -> u64 {
        let piece = self.pieces[self.idx];
        let piece_end = (piece.end >> X_FRAC).min(u128::from(u64::MAX)) as u64;
        let avail = piece_end.saturating_sub(self.done).min(self.remaining());
        let Some(s0) = step_ticks.filter(|_| avail > 1) else {
            return 1;
        };
        // length bound: n·p ≤ the longest segment
        let mut k = (budget.log_max_ticks - log2_q8_up(s0)) >> 8;
        k = k.min(avail.ilog2() as i32);
        if piece.slope != 0 {
            let sl = piece.slope.unsigned_abs();
            // m = aw / (sl·2^32) steps
            // (the slope's upper bound: its log2_q8 plus the slack)
            let log_m =
                log2_q8(self.aw.max(1)) - (log2_q8(sl) + LOG2_Q8_SLACK) - (X_FRAC as i32) * 256;
            let accel = piece.slope > 0;
            k = k.min((log_m - if accel { 256 } else { 512 }) >> 8);
            if !avail.is_power_of_two() {
                // at most half the piece's rest: its last segments get
                // shorter by halves, each taking over the small time
                // error of the one before as a change of acceleration
                // far below the bound; a short segment after a long one
                // would take over a long one's error
                k = k.min((avail / 2).ilog2() as i32);
            }
            // E (ticks·256) = B/2 − ¼ with B = min(1 µs, p/25)
            let p_q8 = s0 >> 24;
            let b_q8 = budget.us_q8.min((p_q8 * 41) >> 10);
            let e_q8 = (b_q8 >> 1).saturating_sub(64);
            if e_q8 == 0 {
                return 1;
            }
            let log_k = if accel { LOG2_Q8_1000 } else { LOG2_Q8_250 };
            let log_e = log2_q8_64(e_q8) - 8 * 256;
            let log_p = log2_q8_up(s0) - 32 * 256;
            let x = log_k + log_e + 5 * log_m - log_p;
            k = k.min(x.div_euclid(6 * 256));
            let log_c = log2_q8_64(curv.unsigned_abs().max(1));
            // with the fit's fine bits f(k) = min(16, 3k − 1): 4k − f(k)
            // ≤ log2(|t''|/40), and n ≤ |t''|/1000. The second makes the
            // first hold where 3k − 1 < 16 (k ≤ 5: it needs k + 1 ≤
            // log2(|t''|/40)), so the first is checked with f = 16 only.
            let fine = MAX_FINE_BITS as i32 * 256;
            k = k.min((log_c - LOG2_Q8_40_UP + fine).div_euclid(4 * 256));
            k = k.min((log_c - LOG2_Q8_1000_UP).div_euclid(256));
            // and the time error of that rounding, C(n, 5)·½ of 2^-32
            // tick summed over the segment: ≤ 1/30 tick up to 2^7
            k = k.min(MAX_RAMP_SEGMENT_LOG2 as i32);
        }
        1 << k.clamp(0, MAX_SEGMENT_LOG2 as i32)
    }
}
