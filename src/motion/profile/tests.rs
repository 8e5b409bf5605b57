//! The profile's unit tests.

use super::fixed::*;
use super::length::MAX_RAMP_SEGMENT_LOG2;
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
        let s = p.step_ticks();
        let n = p.segment_len(s, s.map_or(0, |s| p.curvature(s)), &budget);
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
    assert_eq!(p.steps(), Some(125));
    let budget = SegmentBudget::new(F, 100_000);
    let mut segments = 0;
    while p.remaining() > 0 {
        let s = p.step_ticks();
        let n = p.segment_len(s, s.map_or(0, |s| p.curvature(s)), &budget);
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
    let mut p = Profile::new_move(true, 0, w_of(100_000), 0, su, su, 1_000_000, 0, F);
    // at rest: single steps
    let budget = SegmentBudget::new(F, 2000);
    let s = p.step_ticks();
    assert_eq!(
        p.segment_len(s, s.map_or(0, |s| p.curvature(s)), &budget),
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

/// A ramp's segments stay 2^7 steps long up to a high step rate: the fit's
/// fine bits keep the rounding of its highest terms inside the precision
/// bound where the interval hardly changes from step to step (with terms
/// at 2^-32 tick only, they shrank to 8 steps towards 1 000 000 steps/s).
#[test]
fn ramp_segments_stay_long_at_high_step_rates() {
    const TICK: u32 = 170_000_000;
    // to 1 000 000 steps/s at 2 000 000 steps/s²
    let slope = slope_of(20_000_000);
    let mut p = Profile::new_run(true, 0, w_of(10_000_000), slope, slope, 0, TICK);
    let budget = SegmentBudget::new(TICK, 100_000);
    let rate = |s: u64| f64::from(TICK) * 4294967296.0 / s as f64;
    let mut fast = 0;
    loop {
        let s = p.step_ticks();
        let v = s.map_or(0.0, rate);
        if v > 990_000.0 {
            break;
        }
        let n = p.segment_len(s, s.map_or(0, |s| p.curvature(s)), &budget);
        if v > 200_000.0 {
            assert_eq!(n, 1 << MAX_RAMP_SEGMENT_LOG2, "at {v} steps/s");
            fast += 1;
        }
        p.advance(n);
    }
    assert!(fast > 1_000, "{fast} segments");
}

/// The remembered quotients (a cruise's travel time and step time) are
/// the ones the divisions give: a profile planned segment by segment
/// through ramps and a cruise times every step and gives every slope as
/// the same profile with both forgotten before each segment, and the
/// cruise's segments do take them from memory. The slow ramps' steps are
/// timed by the same division as a cruise, at a speed that changes.
#[test]
fn remembered_quotients_are_the_divisions() {
    for (accel, steps) in [(2_000_000, 400_000), (100, 3_000)] {
        let su = slope_of(accel);
        let mut p = Profile::new_move(true, 0, w_of(300_000), 0, su, su, steps, 0, F);
        let budget = SegmentBudget::new(F, 2000);
        let mut remembered = 0;
        while p.remaining() != 0 {
            let mut fresh = p.clone();
            let cruise = p.piece_slope() == 0;
            let s = p.step_ticks();
            fresh.step_memo = (u128::MAX, None);
            assert_eq!(fresh.step_ticks(), s);
            let n = p.segment_len(s, s.map_or(0, |s| p.curvature(s)), &budget);
            let known = p.travel_memo;
            fresh.travel_memo = (0, 0, 0);
            assert_eq!(
                p.advance(n),
                fresh.advance(n),
                "{accel}: at step {}",
                p.done
            );
            remembered += usize::from(cruise && p.travel_memo == known);
        }
        assert!(
            remembered > 100 || accel < 1000,
            "{remembered} segments from memory"
        );
    }
}
