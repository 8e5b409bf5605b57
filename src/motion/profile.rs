//! One planned motion in one direction, and the exact time of each of its
//! steps (SPEC §8.4, §8.5).
//!
//! A trapezoid with constant accelerations is a piecewise *linear* function
//! of position for v²: `v² = v0² + 2·a·x` on every piece. So the profile is
//! stored as up to three pieces (ramp to cruise, cruise, ramp to the end
//! velocity) with real-valued boundaries (Q32 steps), and the time between
//! two positions of one piece is `Δt = 2·Δx / (v1 + v2)` — one square root
//! and one division, no cancellation, no accumulation: every step time is
//! computed from the continuous profile, not from the previous interval.
//! On a ramp (from about 250 steps/s² at 10 MHz) the same time is
//! `Δt = (v2 − v1)/a`, a multiplication by a factor kept per piece: the
//! square root stays, the division goes (`Piece::per_v`).
//!
//! Units: velocity `V` in 0.1 steps/s (register 0.1 rev/s × PA10), held as
//! `V · 2^20`; v² as `V² · 2^40`; acceleration `A` in 0.1 steps/s², which
//! makes the v² slope `20·A` per step (`20·A·2^8` per Q32 position unit);
//! times in timer ticks, Q32.32, wrapping.
//!
//! This runs in thread mode once per schedule segment (u128 numbers, but
//! the root and the division go through 64-bit routines, `isqrt` and
//! `div`: a generic u128 division is a long software loop on a 32-bit
//! core), never in the step interrupt.

/// Fractional bits of fixed-point velocities.
pub const V_FRAC: u32 = 20;
/// Fractional bits of fixed-point v².
pub const W_FRAC: u32 = 2 * V_FRAC;
/// Fractional bits of positions inside a profile.
pub const X_FRAC: u32 = 32;
/// v² slope per Q32 position unit for a slope of 1 (V² per step).
const SLOPE_SHIFT: u32 = W_FRAC - X_FRAC;

/// v² in fixed point from a velocity in 0.1 steps/s.
pub const fn w_of(v: u64) -> u128 {
    (v as u128 * v as u128) << W_FRAC
}

/// v² slope per Q32 position unit from an acceleration in 0.1 steps/s².
pub const fn slope_of(a: u64) -> u128 {
    (20 * a as u128) << SLOPE_SHIFT
}

/// Steps needed to stop from `w` with slope `sd` (rounded up: stops end
/// on a whole step, with a deceleration at most the commanded one).
pub fn stop_steps(w: u128, sd: u128) -> u64 {
    if sd == 0 {
        return 0;
    }
    let per_step = sd << X_FRAC;
    // through `div` (w < 2^100: no overflow): smaller than an inlined
    // generic u128 `div_ceil` (flash budget, firmware README "Sizes")
    div(w + (per_step - 1), per_step) as u64
}

/// Largest segment, as a power of two (steps): the schedule's ring must
/// take a whole segment ([`crate::motion::schedule`]).
pub const MAX_SEGMENT_LOG2: u32 = 8;

/// What bounds a segment's length besides the fit (set once from the
/// planner's configuration).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SegmentBudget {
    /// 256·log2 of the longest segment, in Q32.32 ticks.
    pub log_max_ticks: i32,
    /// Timer ticks per µs, × 256 (the 1 µs error bound).
    pub us_q8: u64,
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

/// v² after `dx` (Q32 steps) on a piece of v² slope `slope` (per Q32
/// unit) from v² = `w`: v² is linear in the position on a piece.
pub(crate) fn w_along(w: u128, slope: i128, dx: u128) -> u128 {
    if slope >= 0 {
        w + slope as u128 * dx
    } else {
        w.saturating_sub(slope.unsigned_abs() * dx)
    }
}

/// Ticks (Q32.32) to travel `dx` (Q32 steps) between two points whose
/// velocities sum to `v_sum` (fixed point): `Δt = 2·Δx/(v1 + v2)`, with
/// `k_time` = 20 × the tick frequency. 0 for no distance or no speed.
pub(crate) fn travel_ticks(k_time: u128, dx: u128, v_sum: u128) -> u64 {
    if dx == 0 || v_sum == 0 {
        return 0;
    }
    div(k_time * dx * (1u128 << V_FRAC), v_sum) as u64
}

/// `num / den ≈ m / 2^sh` with `m` in [2^30, 2^32) (`num`, `den` > 0,
/// `num` < 2^96): 30 bits of a ratio of any size, one division.
pub(crate) fn ratio(num: u128, den: u128) -> (u64, u32) {
    let sh = (31 + den.ilog2() as i32 - num.ilog2() as i32).max(0) as u32;
    (div(num << sh.min(127 - num.ilog2()), den) as u64, sh)
}

/// `⌊256·log2(1 + i/32)⌋`.
const LOG2_FRAC_Q8: [u8; 32] = [
    0, 11, 22, 33, 43, 53, 63, 73, 82, 91, 100, 109, 117, 125, 134, 141, 149, 157, 164, 172, 179,
    186, 193, 200, 206, 213, 219, 225, 232, 238, 244, 250,
];
/// `⌊256·log2 1000⌋`, `⌊256·log2 250⌋` (segment_len's fit constants).
const LOG2_Q8_1000: i32 = 2551;
const LOG2_Q8_250: i32 = 2039;
/// `⌈256·log2 40⌉`.
const LOG2_Q8_40_UP: i32 = 1363;
/// Longest segment on a ramp, as a power of two (steps).
const MAX_RAMP_SEGMENT_LOG2: u32 = 7;

/// How far below `256·log2 x` [`log2_q8`] may be (1/256 bits): adding it
/// gives an upper bound.
const LOG2_Q8_SLACK: i32 = 12;

/// A lower bound of `256·log2 x` (`x > 0`), at most [`LOG2_Q8_SLACK`]/256 bit below:
/// the exponent and five bits of mantissa through a table.
pub(crate) fn log2_q8(x: u128) -> i32 {
    // through the 64-bit one: its top 64 bits carry the same exponent
    // and mantissa (128-bit shifts are long on a 32-bit core)
    let hi = (x >> 64) as u64;
    if hi == 0 {
        return log2_q8_64(x as u64);
    }
    let z = hi.leading_zeros();
    let top = if z == 0 {
        hi
    } else {
        (hi << z) | (x as u64 >> (64 - z))
    };
    log2_q8_64(top) + (64 - z as i32) * 256
}

/// [`log2_q8`] of a 64-bit number.
fn log2_q8_64(x: u64) -> i32 {
    let e = 63 - x.leading_zeros();
    let top = (if e >= 5 { x >> (e - 5) } else { x << (5 - e) }) as usize & 31;
    e as i32 * 256 + i32::from(LOG2_FRAC_Q8[top])
}

/// An upper bound of `256·log2 x` (`x > 0`).
fn log2_q8_up(x: u64) -> i32 {
    log2_q8_64(x) + LOG2_Q8_SLACK
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Piece {
    /// End position, Q32 steps from the profile origin.
    end: u128,
    /// v² slope per Q32 unit (0 = cruise).
    slope: i128,
    /// The acceleration in steps/tick² as `m / 2^sh` ([`ratio`]): the
    /// step times' curvature is `t'' = ∓a·(dt/dx)³` ([`Profile::curvature`]).
    accel: (u64, u32),
    /// On a ramp, Q32.32 ticks per unit of velocity change, × 2^40
    /// (at least 2^47 significant: f ≥ 1 MHz and a ≤ [`crate::motion::MAX_ACCEL`]):
    /// `Δt = Δv/a` ([`Profile::ticks_to`]), when one unit of velocity
    /// error costs at most [`MAX_TICKS_PER_V`]; else 0.
    per_v: u64,
}

/// A ramp times its steps as `Δt = Δv/a` (a multiplication) when a
/// velocity rounded by one unit moves the time by at most this (Q32.32
/// ticks: 1/256 tick; about 250 steps/s² and more at 10 MHz), else as
/// `2·Δx/(v1 + v2)` (a division) like a cruise.
const MAX_TICKS_PER_V: u128 = 1 << 24;

/// See the module docs.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Profile {
    pub forward: bool,
    /// Whole steps to the end; `None` runs forever (velocity mode).
    pub steps: Option<u64>,
    pieces: [Piece; 3],
    n_pieces: usize,
    idx: usize,
    /// Steps already timed from the origin.
    done: u64,
    /// Anchor: Q32 position, v², v (fixed point) and time of a point on the
    /// current piece. Re-anchored at every timed step, so that the numbers
    /// stay small and cruise times stay exact.
    ax: u128,
    aw: u128,
    av: u128,
    at: u64,
    /// 20 × tick frequency.
    k_time: u128,
    /// v² at the end (exact; the pieces' rounded boundaries would leave a
    /// remainder of less than one slope unit).
    w_end: u128,
    /// v² of the cruise piece (exact: the ramp before it ends on a rounded
    /// boundary, whose v² is short by up to one slope unit — 3e-7 of the
    /// speed, 1 µs after 100 slow steps).
    w_cruise: u128,
}

impl Profile {
    /// A move of `steps` whole steps from v² = `w0` to v² = `we`, cruising at
    /// `wc`, with rise slope `su` and fall slope `sd` (see [`slope_of`]),
    /// starting at time `t0` (Q32.32 ticks).
    ///
    /// The caller guarantees it can stop in time (`w0 ≤ we + sd·steps`),
    /// `wc > 0` and `sd > 0`, and `su > 0` if `w0 < wc`.
    #[allow(clippy::too_many_arguments)]
    pub fn new_move(
        forward: bool,
        w0: u128,
        wc: u128,
        we: u128,
        su: u128,
        sd: u128,
        steps: u64,
        t0: u64,
        tick_hz: u32,
    ) -> Self {
        let we = we.min(wc);
        let d = u128::from(steps) << X_FRAC;
        let sd_i = sd as i128;
        let fall_len = div(wc - we, sd.max(1));
        let x_ce = d.saturating_sub(fall_len);
        let mut p = Self::start(forward, Some(steps), w0, t0, tick_hz);
        p.w_end = we;
        p.w_cruise = wc;
        if w0 <= wc {
            let x_rc = if su == 0 { 0 } else { div(wc - w0, su) };
            if x_rc <= x_ce {
                p.push(x_rc, su as i128);
                p.push(x_ce, 0);
                p.push(d, -sd_i);
            } else {
                let x_p = div((we + sd * d).saturating_sub(w0), su + sd).min(d);
                p.push(x_p, su as i128);
                p.push(d, -sd_i);
            }
        } else {
            let x_fc = div(w0 - wc, sd.max(1)).min(x_ce);
            p.push(x_fc, -sd_i);
            p.push(x_ce, 0);
            p.push(d, -sd_i);
        }
        p
    }

    /// Ramp from `w0` to `wc` (rise `su` or fall `sd`) and cruise for ever.
    pub fn new_run(
        forward: bool,
        w0: u128,
        wc: u128,
        su: u128,
        sd: u128,
        t0: u64,
        tick_hz: u32,
    ) -> Self {
        let mut p = Self::start(forward, None, w0, t0, tick_hz);
        p.w_cruise = wc;
        // through `div` (flash budget, as `stop_steps`)
        if w0 <= wc {
            p.push(if su == 0 { 0 } else { div(wc - w0, su) }, su as i128);
        } else {
            p.push(div(w0 - wc, sd.max(1)), -(sd as i128));
        }
        p.push(u128::MAX, 0);
        p
    }

    /// Cruise at `w0` until the latest point from which slope `sd` stops on
    /// a whole step, then decelerate to rest there.
    pub fn new_stop(forward: bool, w0: u128, sd: u128, t0: u64, tick_hz: u32) -> Self {
        let steps = stop_steps(w0, sd);
        Self::new_move(forward, w0, w0, 0, 0, sd, steps, t0, tick_hz)
    }

    fn start(forward: bool, steps: Option<u64>, w0: u128, t0: u64, tick_hz: u32) -> Self {
        Self {
            forward,
            steps,
            pieces: [Piece::default(); 3],
            n_pieces: 0,
            idx: 0,
            done: 0,
            ax: 0,
            aw: w0,
            av: isqrt(w0),
            at: t0,
            k_time: 20 * u128::from(tick_hz),
            w_end: 0,
            w_cruise: w0,
        }
    }

    fn push(&mut self, end: u128, slope: i128) {
        // a = |slope|·2^32 / 2^40 / 200 steps/s² (V² per step over 2·10²),
        // over f² = (k_time/20)²: |slope| / (128·k_time²) steps/tick²
        let (accel, per_v) = match slope.unsigned_abs() {
            0 => ((0, 0), 0),
            sl => {
                // Δt = k_time·2^20·Δx/(v1 + v2) and v2² − v1² = sl·Δx on
                // a ramp: Δt = (k_time·2^20/sl)·(v2 − v1); the factor
                // below 2^24 (× 2^40 it fits 64 bits; k_time·2^20 < 2^48)
                let num = self.k_time << V_FRAC;
                let per_v = if num <= MAX_TICKS_PER_V * sl {
                    div(num << 40, sl) as u64
                } else {
                    0
                };
                (ratio(sl, 128 * self.k_time * self.k_time), per_v)
            }
        };
        self.pieces[self.n_pieces] = Piece {
            end,
            slope,
            accel,
            per_v,
        };
        self.n_pieces += 1;
    }

    /// Steps timed so far.
    pub fn done(&self) -> u64 {
        self.done
    }

    /// Whole steps left (`u64::MAX` when endless).
    pub fn remaining(&self) -> u64 {
        self.steps.map_or(u64::MAX, |s| s - self.done)
    }

    /// v² at the end of a finite profile (0: it ends at rest).
    pub fn w_end(&self) -> u128 {
        self.w_end
    }

    /// v² at the last timed step (or the start).
    pub fn w(&self) -> u128 {
        self.aw
    }

    /// Velocity at the last timed step, 0.1 steps/s (rounded down).
    pub fn velocity(&self) -> u64 {
        (self.av >> V_FRAC) as u64
    }

    /// The current piece changes speed (for statusword bit 13 in velocity
    /// mode).
    pub fn ramping(&self) -> bool {
        self.pieces[self.idx].slope != 0
            && u128::from(self.done) < self.pieces[self.idx].end >> X_FRAC
    }

    /// Time per step (Q32.32 ticks) at the last timed step: `dt/dx = 1/v`,
    /// the slope the planner's segment fit matches at each end. `None` at
    /// rest or below about 0.2 steps/s (the quotient would not fit), where
    /// segments are single steps anyway. Exact (rounded down): on a
    /// cruise the fit's higher terms are then exactly 0 (a slope good to
    /// 2^-30 only, a reciprocal by a 64-by-32 division, left them noise
    /// whose rounding over 256-step segments fed back from segment to
    /// segment: ±2·10^-5 of the velocity on the seed's cruise).
    pub fn step_ticks(&self) -> Option<u64> {
        // 1/v in ticks per step = 10·f·2^V_FRAC / av = k_time·2^(V_FRAC-1) / av,
        // and 2^32 more for Q32.32
        let num = self.k_time << (V_FRAC - 1 + 32);
        (self.av > num >> 64).then(|| div(num, self.av) as u64)
    }

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
    /// planner.rs `fit_segment`) stays within the exactness bounds
    /// (issue 3):
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
    ///   sees within 0.2 % (issue 3: ≤ +2 %).
    /// - Precision: `curv` is the curvature at the start
    ///   ([`Profile::curvature`] at `step_ticks`). The segment's terms are
    ///   rounded to 2^-32 tick, and the highest one's rounding (½ unit)
    ///   reaches the last interval `C(n−1, 4)` times: kept below 0.1 % of
    ///   the interval change per step (`|t''|`, which shrinks by up to
    ///   45 % along an accelerating segment), `n⁴ ≤ |t''|/40` in units of
    ///   2^-32 tick (0.5 % looked safe by this count, with the fit's
    ///   0.2 % under issue 3's 2 %, but let through acceleration spikes of
    ///   +2.1 % to +4.3 % in the random-move proptests, 2 runs in 36 of
    ///   300 cases: the margin is kept); its time error, `C(n, 5)` half
    ///   units, stays below 1/30 tick with ramp segments of at most 2^7
    ///   steps.
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
            let c = curv.unsigned_abs().max(1);
            k = k.min((log2_q8_64(c) - LOG2_Q8_40_UP).div_euclid(4 * 256));
            // and the time error of that rounding, C(n, 5)·½ of 2^-32
            // tick summed over the segment: ≤ 1/30 tick up to 2^7
            k = k.min(MAX_RAMP_SEGMENT_LOG2 as i32);
        }
        1 << k.clamp(0, MAX_SEGMENT_LOG2 as i32)
    }

    /// The v² slope (per Q32 position unit) of the current piece: 0 on a
    /// cruise, negative on a deceleration.
    pub(crate) fn piece_slope(&self) -> i128 {
        self.pieces[self.idx].slope
    }

    /// Moves the whole profile `dt` (Q32.32 ticks) later (the planner,
    /// when the interrupt ran dry and starts again).
    pub(crate) fn delay(&mut self, dt: u64) {
        self.at = self.at.wrapping_add(dt);
    }

    /// Time (Q32.32 ticks) of step `done + n`, which becomes the new anchor.
    pub fn advance(&mut self, n: u64) -> u64 {
        self.done += n;
        let x = u128::from(self.done) << X_FRAC;
        while x > self.pieces[self.idx].end && self.idx + 1 < self.n_pieces {
            let end = self.pieces[self.idx].end;
            self.move_anchor(end);
            self.idx += 1;
        }
        self.move_anchor(x);
        self.at
    }

    /// Ticks from the anchor to `dx` further on, where the velocity is
    /// `v`: `Δv/a` on a ramp's own line (`per_v` ≠ 0, [`Piece::per_v`]),
    /// else `2·Δx/(v1 + v2)`.
    #[inline(never)]
    fn ticks_to(&self, dx: u128, v: u128, per_v: u64) -> u64 {
        if per_v != 0 {
            // Δt = Δv/a: a multiplication. The roots' rounding (one unit
            // of v, at most 1/256 tick here) does not add up: each v is
            // the end of one step and the start of the next.
            ((u128::from(v.abs_diff(self.av) as u64) * u128::from(per_v)) >> 40) as u64
        } else {
            travel_ticks(self.k_time, dx, self.av + v)
        }
    }

    fn move_anchor(&mut self, x: u128) {
        let piece = self.pieces[self.idx];
        let slope = piece.slope;
        let dx = x - self.ax;
        // on the ramp's own line v² = aw + slope·dx (not the exact end
        // value, not a decelerating line run out at 0)
        let end = self.steps.map(|s| u128::from(s) << X_FRAC);
        let (w, on_line) = if end == Some(x) {
            (self.w_end, false)
        } else if slope == 0 {
            (self.w_cruise, false)
        } else {
            // A triangle's falling ramp runs on its line through the end
            // point, not through its peak: the peak is rounded to 2^-32
            // step, and the rising line's v² there, carried on with the
            // falling slope, would reach the end velocity up to
            // (1 + a/d)·2^-32 step early; with a ≫ d that moved the last
            // slow steps by a µs (1.4·10⁶ steps/s² up, 50 down). The v²
            // jump this leaves at the peak is (a + d)·2^-31 steps²/s².
            // (After a cruise the start is rounded the same way but not
            // amplified, < 2^-32 step; stops planned again at a whole step
            // of their own ramp keep the step they added then.)
            let last = self.idx + 1 == self.n_pieces;
            let (base, slope, dx) = match end {
                Some(end) if slope < 0 && last && self.pieces[self.idx - 1].slope > 0 => {
                    (self.w_end, -slope, end - x)
                }
                _ => (self.aw, slope, dx),
            };
            let w = w_along(base, slope, dx);
            (w, slope > 0 || w > 0)
        };
        // cruise: same v² as the anchor, same v (no root)
        let v = if w == self.aw { self.av } else { isqrt(w) };
        let per_v = if on_line { piece.per_v } else { 0 };
        self.at = self.at.wrapping_add(self.ticks_to(dx, v, per_v));
        self.ax = x;
        self.aw = w;
        self.av = v;
    }
}

/// `n / d`, through [`div_u128_by_u64`] when the quotient fits 64 bits
/// and `d` does (always, for the planner's numbers): a generic u128
/// division is a long software loop on a 32-bit core.
pub(crate) fn div(n: u128, d: u128) -> u128 {
    match u64::try_from(d) {
        Ok(d64) if d64 != 0 && n >> 64 < d => u128::from(div_u128_by_u64(n, d64)),
        _ => n / d,
    }
}

/// `n / d` for `n >> 64 < d` (the quotient fits 64 bits): Knuth's
/// algorithm D with two 32-bit digits (Hacker's Delight `divlu`), two
/// 64-by-32 divisions.
fn div_u128_by_u64(n: u128, d: u64) -> u64 {
    const B: u64 = 1 << 32;
    let (u1, u0) = ((n >> 64) as u64, n as u64);
    let s = d.leading_zeros();
    let v = d << s;
    let (vn1, vn0) = (v >> 32, v & (B - 1));
    let un32 = if s == 0 {
        u1
    } else {
        (u1 << s) | (u0 >> (64 - s))
    };
    let un10 = u0 << s;
    let (un1, un0) = (un10 >> 32, un10 & (B - 1));
    // one quotient digit of (hi:lo) / v, Knuth's estimate from the top
    // digit then at most two corrections
    let digit = |hi: u64, lo: u64| {
        let (mut q, mut r) = if hi >> 32 >= vn1 {
            (B - 1, hi - (B - 1) * vn1)
        } else {
            let q = u64::from(div_u64_by_u32(hi, vn1 as u32));
            (q, hi - q * vn1)
        };
        while r < B && q * vn0 > (r << 32) + lo {
            q -= 1;
            r += vn1;
        }
        q
    };
    let q1 = digit(un32, un1);
    let un21 = (un32 << 32)
        .wrapping_add(un1)
        .wrapping_sub(q1.wrapping_mul(v));
    let q0 = digit(un21, un0);
    (q1 << 32) | q0
}

/// `u / v` for a normalised `v` (top bit set) and `u >> 32 < v`, with
/// 32-bit divisions only (the Cortex-M `udiv`; a 64-bit division is a
/// software routine there): `divlu` on 16-bit half digits.
fn div_u64_by_u32(u: u64, v: u32) -> u32 {
    const B: u32 = 1 << 16;
    let (vn1, vn0) = (v >> 16, v & (B - 1));
    let un32 = (u >> 32) as u32;
    let un10 = u as u32;
    let (un1, un0) = (un10 >> 16, un10 & (B - 1));
    let digit = |hi: u32, lo: u32| {
        let mut q = hi / vn1;
        let mut r = hi - q * vn1;
        while q >= B || q * vn0 > (r << 16) + lo {
            q -= 1;
            r += vn1;
            if r >= B {
                break;
            }
        }
        q
    };
    let q1 = digit(un32, un1);
    let un21 = (un32 << 16)
        .wrapping_add(un1)
        .wrapping_sub(q1.wrapping_mul(v));
    let q0 = digit(un21, un0);
    (q1 << 16) | q0
}

/// `⌊√w⌋`: the root of the top 64 bits, then one Newton step with a
/// 128-by-64 division (within ±1, then corrected). Used for every u128
/// root of the crate, so that core's generic `u128::isqrt` (1.5 KiB on a
/// Cortex-M) is not linked into the firmware (README "Firmware", Sizes).
pub(crate) fn isqrt(w: u128) -> u128 {
    let bits = 128 - w.leading_zeros();
    if bits <= 64 {
        return u128::from((w as u64).isqrt());
    }
    if bits > 124 {
        // the Newton step below is exact to ±1 up to here; above (never
        // for the planner's capped speeds) digit by digit: short and exact
        let (mut rem, mut root, mut bit) = (w, 0u128, 1u128 << ((bits - 1) & !1));
        while bit != 0 {
            if rem >= root + bit {
                rem -= root + bit;
                root = (root >> 1) + bit;
            } else {
                root >>= 1;
            }
            bit >>= 2;
        }
        return root;
    }
    let k = (bits - 63) / 2; // w >> 2k keeps 63 or 64 bits
    let y0 = u128::from(((w >> (2 * k)) as u64).isqrt()) << k;
    // y0 ≤ √w within 2^-31; w / y0 < 2^64 since √w < 2^64
    let y = (y0 + div(w, y0)) / 2;
    if y * y > w {
        y - 1
    } else if (y + 1) * (y + 1) <= w {
        y + 1
    } else {
        y
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The tests' random numbers: xorshift on 128 bits.
    const SEED: u128 = 0x9E37_79B9_7F4A_7C15_F39C_C060_5CED_C834;
    fn xorshift(x: &mut u128) -> u128 {
        *x ^= *x << 13;
        *x ^= *x >> 7;
        *x ^= *x << 17;
        *x
    }

    const F: u32 = 10_000_000;

    fn ticks(t: u64) -> f64 {
        t as f64 / 4294967296.0
    }

    #[test]
    fn triangle_from_rest_matches_closed_form() {
        // 1000 steps/s² (A = 10000), cruise far above: a triangle. The peak
        // is at 50 steps.
        let su = slope_of(10_000);
        let mut p = Profile::new_move(true, 0, w_of(1_000_000), 0, su, su, 100, 0, F);
        let a: f64 = 1000.0;
        for k in 1..=100u64 {
            let t = ticks(p.advance(1)) / f64::from(F);
            let peak = (2.0 * 50.0 / a).sqrt();
            let ideal = if k <= 50 {
                (2.0 * k as f64 / a).sqrt()
            } else {
                2.0 * peak - (2.0 * (100 - k) as f64 / a).sqrt()
            };
            assert!((t - ideal).abs() < 1e-9, "step {k}: {t} vs {ideal}");
        }
        assert_eq!(p.remaining(), 0);
        assert_eq!(p.w(), 0);
    }

    /// On a ramp, `Δt = Δv/a` (a multiplication, `Piece::per_v`) times
    /// the steps as exactly as `2·Δx/(v1 + v2)` (a division) does: both
    /// within 1/32 tick of the closed form over a triangle of 4000 steps
    /// advanced by uneven counts, accelerating and decelerating. The
    /// multiplication is used from 244.2 steps/s² at 10 MHz, where one
    /// unit of velocity is 1/256 tick; below, the division (whose own
    /// error reaches 0.3 tick at 10 steps/s², where a step takes 0.3 s).
    #[test]
    fn ramp_times_by_velocity_change_match_the_division() {
        for a in [100u64, 2_441, 2_442, 10_000, 1_000_000, 20_000_000] {
            let su = slope_of(a);
            let mut fast = Profile::new_move(true, 0, w_of(2_000_000), 0, su, su, 4000, 0, F);
            assert_eq!(fast.pieces[0].per_v != 0, a >= 2_442, "a = {a}");
            assert_eq!(fast.pieces[1].per_v, fast.pieces[0].per_v);
            let mut slow = fast.clone();
            for piece in slow.pieces.iter_mut() {
                piece.per_v = 0;
            }
            let acc = a as f64 / 10.0;
            let peak = (2.0 * 2000.0 / acc).sqrt();
            let mut n = 1;
            while fast.remaining() > 0 {
                let k = n.min(fast.remaining());
                let (tf, ts) = (ticks(fast.advance(k)), ticks(slow.advance(k)));
                let x = fast.done() as f64;
                let ideal = f64::from(F)
                    * if x <= 2000.0 {
                        (2.0 * x / acc).sqrt()
                    } else {
                        2.0 * peak - (2.0 * (4000.0 - x) / acc).sqrt()
                    };
                if a < 2_442 {
                    // the division, both (within 0.3 tick at 10 steps/s²)
                    assert_eq!(tf, ts, "a = {a}, x = {x}");
                    assert!(
                        (tf - ideal).abs() < 0.5,
                        "a = {a}, x = {x}: {tf} vs {ideal}"
                    );
                } else {
                    for (t, how) in [(tf, "Δv/a"), (ts, "division")] {
                        let err = (t - ideal).abs();
                        assert!(err < 1.0 / 32.0, "a = {a}, x = {x}, {how}: {t} vs {ideal}");
                    }
                }
                n = n * 5 % 61 + 1;
            }
            assert_eq!((fast.w(), slow.w()), (0, 0));
        }
    }

    #[test]
    fn cruise_times_are_exact_over_long_runs() {
        // 123.4 steps/s from the start (w0 = wc): every step 1/123.4 s.
        let w = w_of(1234);
        let mut p = Profile::new_run(true, w, w, slope_of(1), slope_of(1), 0, F);
        let mut t = 0;
        // 0.4 s segments: 32 steps each (a power of two), 300 × 32 steps =
        // 78 s, inside the 2^32-tick wrap of Q32.32 times
        let budget = SegmentBudget::new(F, 400_000);
        // (the ramp piece before the cruise has no length: one step)
        for i in 0..300 {
            let n = p.segment_len(
                p.step_ticks(),
                p.step_ticks().map_or(0, |s| p.curvature(s)),
                &budget,
            );
            assert_eq!(n, if i == 0 { 1 } else { 32 });
            t = p.advance(n);
        }
        let expect = p.done() as f64 / 123.4 * f64::from(F);
        assert!((ticks(t) - expect).abs() < 1e-3, "{} vs {expect}", ticks(t));
    }

    #[test]
    fn stop_ends_on_a_whole_step_at_rest() {
        let w0 = w_of(5000); // 500 steps/s
        let sd = slope_of(10_000); // 1000 steps/s²: 125 steps to stop
        assert_eq!(stop_steps(w0, sd), 125);
        let mut p = Profile::new_stop(false, w0, sd, 0, F);
        assert_eq!(p.steps, Some(125));
        let budget = SegmentBudget::new(F, 100_000);
        let mut segments = 0;
        while p.remaining() > 0 {
            let n = p.segment_len(
                p.step_ticks(),
                p.step_ticks().map_or(0, |s| p.curvature(s)),
                &budget,
            );
            assert!(n.is_power_of_two() && n <= p.remaining(), "{n}");
            p.advance(n);
            segments += 1;
        }
        assert_eq!(p.w(), 0);
        // single steps only near rest, where the fit bound is tight
        assert!(segments <= 40, "{segments} segments");
    }

    /// The fast root and divisions agree with the generic ones, at the
    /// edges of their ranges and on random numbers.
    #[test]
    fn fast_isqrt_and_division_are_exact() {
        let mut y: u64 = 0x2545_F491_4F6C_DD1D;
        for i in 0..100_000u32 {
            y ^= y << 13;
            y ^= y >> 7;
            y ^= y << 17;
            let v = (y as u32) | 1 << 31;
            let u = (y >> (i % 64)) % (u64::from(v) << 32);
            assert_eq!(
                u64::from(div_u64_by_u32(u, v)),
                u / u64::from(v),
                "{u} / {v}"
            );
        }
        let mut x = SEED;
        let mut next = || xorshift(&mut x);
        for i in 0..20_000u32 {
            let w = next() >> (i % 128);
            assert_eq!(isqrt(w), w.isqrt(), "isqrt {w}");
            let d = (next() >> (64 + i % 64)).max(1);
            let n = next() >> (i % 128);
            assert_eq!(div(n, d), n / d, "{n} / {d}");
        }
        for w in [
            0u128,
            1,
            3,
            4,
            u128::from(u64::MAX),
            1 << 64,
            (1 << 84) - 1,
            // around the digit-by-digit range (> 124 bits)
            (1 << 124) - 1,
            1 << 124,
            (1 << 126) - 1,
            u128::from(u64::MAX) * u128::from(u64::MAX) - 1,
            u128::from(u64::MAX) * u128::from(u64::MAX),
            u128::MAX - 1,
            u128::MAX,
        ] {
            assert_eq!(isqrt(w), w.isqrt(), "isqrt {w}");
        }
        for (n, d) in [
            (u128::MAX, u128::MAX),
            ((1 << 64) - 1, 1),
            (u128::from(u64::MAX) << 64 | 5, u128::from(u64::MAX)),
        ] {
            assert_eq!(div(n, d), n / d);
        }
    }

    #[test]
    fn segments_stay_inside_pieces() {
        let su = slope_of(100_000);
        let p = Profile::new_move(true, 0, w_of(100_000), 0, su, su, 1_000_000, 0, F);
        // at rest: single steps
        let budget = SegmentBudget::new(F, 2000);
        assert_eq!(
            p.segment_len(
                p.step_ticks(),
                p.step_ticks().map_or(0, |s| p.curvature(s)),
                &budget
            ),
            1
        );
    }

    /// The logarithms bracket the exact ones within 12/256 bit.
    #[test]
    fn log2_bounds() {
        let mut x = SEED;
        for i in 0..20_000u32 {
            let v = (xorshift(&mut x) >> (i % 127)).max(1);
            let exact = 256.0 * (v as f64).log2();
            let (lo, hi) = (f64::from(log2_q8(v)), f64::from(log2_q8(v) + LOG2_Q8_SLACK));
            if let Ok(v64) = u64::try_from(v) {
                assert_eq!(log2_q8_64(v64), log2_q8(v));
                assert_eq!(log2_q8_up(v64), log2_q8(v) + LOG2_Q8_SLACK);
            }
            assert!(lo <= exact + 1e-9 && exact <= hi, "{v}: {lo} {exact} {hi}");
        }
        assert_eq!(log2_q8(1), 0);
        assert_eq!(log2_q8(160) >> 8, 7);
    }
}
