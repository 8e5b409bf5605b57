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

/// Relative velocity change allowed within one segment: 2^-5 ≈ 3 %. The
/// segment's intervals are a quadratic in the step number matched to the
/// exact ones at both ends; the ideal ones go as 1/v, whose next term makes
/// the shown acceleration deviate by about 15·δ²/12 ≈ 0.1 % (SPEC
/// exactness: ≤ +2 %).
const SEGMENT_DV_SHIFT: u32 = 5;

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

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Piece {
    /// End position, Q32 steps from the profile origin.
    end: u128,
    /// v² slope per Q32 unit (0 = cruise).
    slope: i128,
}

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
        let fall_len = (wc - we) / sd.max(1);
        let x_ce = d.saturating_sub(fall_len);
        let mut p = Self::start(forward, Some(steps), w0, t0, tick_hz);
        p.w_end = we;
        p.w_cruise = wc;
        if w0 <= wc {
            let x_rc = (wc - w0).checked_div(su).unwrap_or(0);
            if x_rc <= x_ce {
                p.push(x_rc, su as i128);
                p.push(x_ce, 0);
                p.push(d, -sd_i);
            } else {
                let x_p = ((we + sd * d).saturating_sub(w0) / (su + sd)).min(d);
                p.push(x_p, su as i128);
                p.push(d, -sd_i);
            }
        } else {
            let x_fc = ((w0 - wc) / sd.max(1)).min(x_ce);
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
        if w0 <= wc {
            p.push((wc - w0).checked_div(su).unwrap_or(0), su as i128);
        } else {
            p.push((w0 - wc) / sd.max(1), -(sd as i128));
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
        self.pieces[self.n_pieces] = Piece { end, slope };
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

    /// How many steps the next schedule segment should hold: whole steps
    /// inside the current piece, short enough that the velocity changes by at
    /// most 2^-8 over it (1 if the next step crosses a piece boundary).
    pub fn segment_len(&self, max_steps: u64) -> u64 {
        let piece = self.pieces[self.idx];
        let piece_end = (piece.end >> X_FRAC).min(u128::from(u64::MAX)) as u64;
        let avail = piece_end.saturating_sub(self.done).min(self.remaining());
        if avail == 0 {
            return 1;
        }
        let n = if piece.slope == 0 {
            avail
        } else {
            let s = piece.slope.unsigned_abs();
            // m: steps from here to rest at this slope (w over the slope)
            let m = div(self.aw, s << X_FRAC).min(1 << 28) as u64;
            let n = m >> (SEGMENT_DV_SHIFT - 1);
            let n = if piece.slope < 0 { n - (n >> 6) } else { n };
            // Time error of the fit: the quadratic in the step number misses
            // the exact intervals (∝ 1/v) by their fourth-order term, about
            // p·n·δ³/8 ticks mid-segment (p the interval, δ = n/2m the
            // relative velocity change): n⁴ ≤ 8·e·m³/p with p = 20·f/(10·v)
            // ticks (v in 0.1 steps/s) and e = 1/16 tick.
            let mv = m * (self.av >> V_FRAC) as u64; // < 2^28 · 2^21
            let n_fit = isqrt(isqrt(div(u128::from(m * m) * u128::from(mv), self.k_time)));
            // Precision of the fit: add2 is rounded to 2^-32 ticks, which
            // moves the last interval by up to n²/6 · 2^-33 ticks; keep that
            // below 1/1536 of the interval change per step, f/(2·m·v) ticks,
            // so that the acceleration at a junction stays exact to 0.07 %:
            // n² ≤ 2^23 · 20f / (m · v).
            let n_prec = isqrt(div(self.k_time << 23, u128::from(mv.max(1))));
            let n = u128::from(n).min(n_fit).min(n_prec);
            n.min(u128::from(avail)) as u64
        };
        n.clamp(1, max_steps.max(1))
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

    fn move_anchor(&mut self, x: u128) {
        let slope = self.pieces[self.idx].slope;
        let dx = x - self.ax;
        let w = if self.steps.is_some_and(|s| x == u128::from(s) << X_FRAC) {
            self.w_end
        } else if slope == 0 {
            self.w_cruise
        } else if slope > 0 {
            self.aw + slope as u128 * dx
        } else {
            self.aw.saturating_sub(slope.unsigned_abs() * dx)
        };
        // cruise: same v² as the anchor, same v (no root)
        let v = if w == self.aw { self.av } else { isqrt(w) };
        let den = self.av + v;
        if dx > 0 && den > 0 {
            let dt = div(self.k_time * dx * (1u128 << V_FRAC), den);
            self.at = self.at.wrapping_add(dt as u64);
        }
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

    #[test]
    fn cruise_times_are_exact_over_long_runs() {
        // 123.4 steps/s from the start (w0 = wc): every step 1/123.4 s.
        let w = w_of(1234);
        let mut p = Profile::new_run(true, w, w, slope_of(1), slope_of(1), 0, F);
        let mut t = 0;
        // 300 × 100 steps = 243 s, inside the 2^32-tick wrap of Q32.32 times
        for _ in 0..300 {
            let n = p.segment_len(100);
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
        while p.remaining() > 0 {
            let n = p.segment_len(1000);
            p.advance(n);
        }
        assert_eq!(p.w(), 0);
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
        let mut x: u128 = 0x9E37_79B9_7F4A_7C15_F39C_C060_5CED_C834;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
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
        assert_eq!(p.segment_len(1 << 20), 1);
    }
}
