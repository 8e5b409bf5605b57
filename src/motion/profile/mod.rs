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
//!
//! [`fixed`] holds that arithmetic, [`length`] the bounds on a schedule
//! segment's length.

mod fixed;
mod length;
#[cfg(test)]
mod tests;

pub(crate) use fixed::{div, isqrt, ratio, travel_ticks, w_along};
pub use length::{SegmentBudget, MAX_SEGMENT_LOG2};

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
    // generic u128 `div_ceil` (flash budget)
    div(w + (per_step - 1), per_step) as u64
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
    forward: bool,
    /// Whole steps to the end; `None` runs forever (velocity mode).
    steps: Option<u64>,
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
    /// The last travel time by division (`dx`, `v1 + v2`, ticks) and the
    /// last step time (`av`, [`Profile::step_ticks`]), kept with their
    /// arguments: every segment of a cruise asks the same two quotients,
    /// each a 128-bit division in software on a Cortex-M, longer than the
    /// rest of the segment's planning.
    travel_memo: (u128, u128, u64),
    step_memo: (u128, Option<u64>),
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
            // what travel_ticks gives for dx = 0; no v is u128::MAX
            travel_memo: (0, 0, 0),
            step_memo: (u128::MAX, None),
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

    /// The motion goes in the positive direction.
    pub fn forward(&self) -> bool {
        self.forward
    }

    /// Whole steps from the origin to the end; `None` runs forever
    /// (velocity mode).
    pub fn steps(&self) -> Option<u64> {
        self.steps
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
    pub fn step_ticks(&mut self) -> Option<u64> {
        if self.step_memo.0 != self.av {
            // 1/v in ticks per step = 10·f·2^V_FRAC / av = k_time·2^(V_FRAC-1) / av,
            // and 2^32 more for Q32.32
            let num = self.k_time << (V_FRAC - 1 + 32);
            self.step_memo = (
                self.av,
                (self.av > num >> 64).then(|| div(num, self.av) as u64),
            );
        }
        self.step_memo.1
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
    fn ticks_to(&mut self, dx: u128, v: u128, per_v: u64) -> u64 {
        if per_v != 0 {
            // Δt = Δv/a: a multiplication. The roots' rounding (one unit
            // of v, at most 1/256 tick here) does not add up: each v is
            // the end of one step and the start of the next.
            ((u128::from(v.abs_diff(self.av) as u64) * u128::from(per_v)) >> 40) as u64
        } else {
            let v_sum = self.av + v;
            if (dx, v_sum) != (self.travel_memo.0, self.travel_memo.1) {
                self.travel_memo = (dx, v_sum, travel_ticks(self.k_time, dx, v_sum));
            }
            self.travel_memo.2
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
        let ticks = self.ticks_to(dx, v, per_v);
        self.at = self.at.wrapping_add(ticks);
        self.ax = x;
        self.aw = w;
        self.av = v;
    }
}
