//! Fixed-point arithmetic of the profile: v² along a piece, travel times,
//! ratios, base-2 logarithms, and the 128-bit division and square root
//! through 64-bit routines (a generic u128 division is a long software
//! loop on a 32-bit core).

use super::V_FRAC;

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
pub(super) const LOG2_FRAC_Q8: [u8; 32] = [
    0, 11, 22, 33, 43, 53, 63, 73, 82, 91, 100, 109, 117, 125, 134, 141, 149, 157, 164, 172, 179,
    186, 193, 200, 206, 213, 219, 225, 232, 238, 244, 250,
];

/// How far below `256·log2 x` [`log2_q8`] may be (1/256 bits): adding it
/// gives an upper bound.
pub(super) const LOG2_Q8_SLACK: i32 = 12;

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
pub(super) fn log2_q8_64(x: u64) -> i32 {
    let e = 63 - x.leading_zeros();
    let top = (if e >= 5 { x >> (e - 5) } else { x << (5 - e) }) as usize & 31;
    e as i32 * 256 + i32::from(LOG2_FRAC_Q8[top])
}

/// An upper bound of `256·log2 x` (`x > 0`).
pub(super) fn log2_q8_up(x: u64) -> i32 {
    log2_q8_64(x) + LOG2_Q8_SLACK
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
pub(super) fn div_u128_by_u64(n: u128, d: u64) -> u64 {
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
pub(super) fn div_u64_by_u32(u: u64, v: u32) -> u32 {
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
/// root of the crate, so that core's generic `u128::isqrt` (a large
/// routine on a Cortex-M) is not linked into the firmware.
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
