//! Integer division and square root with the core's 32-bit hardware divide
//! only. Rust's 64-bit `/`, `%` and `isqrt` are software routines on a
//! 32-bit Cortex-M, linked once each into the firmware; everything here
//! reuses the two long-division steps the motion planner needs anyway, so
//! the firmware carries one set of division code instead of two.

/// `n / d` (`d > 0`), as `u64` division.
pub fn div_u64(n: u64, d: u64) -> u64 {
    assert!(d != 0, "attempt to divide by zero");
    if d >> 32 != 0 {
        return div_u128_by_u64(u128::from(n), d);
    }
    let d = d as u32;
    let hi = (n >> 32) as u32;
    if hi == 0 {
        return u64::from(n as u32 / d);
    }
    // a 32-bit divisor: the high word by the hardware divide, then the
    // remainder and the low word (a quotient below 2^32) by the 64-by-32
    // step, the divisor normalised (top bit set) as that step wants it
    let (q_hi, r_hi) = (hi / d, hi % d);
    let s = d.leading_zeros();
    let low = ((u64::from(r_hi) << 32) | (n & 0xFFFF_FFFF)) << s;
    (u64::from(q_hi) << 32) | u64::from(div_u64_by_u32(low, d << s))
}

/// `n.div_ceil(d)` (`d > 0`), one quotient bit at a time: `const` (the
/// firmware computes step timings in a static initialiser) and short, for
/// configuration rather than a hot path.
pub const fn div_ceil_u64(n: u64, d: u64) -> u64 {
    assert!(d != 0, "attempt to divide by zero");
    // the dividend shifts out of `q` into the remainder as the quotient
    // bits shift in
    let (mut q, mut r, mut i) = (n, 0u64, 0);
    while i < 64 {
        // a remainder shifted past 64 bits is above any divisor
        let over = r >> 63 != 0;
        r = (r << 1) | (q >> 63);
        q <<= 1;
        if over || r >= d {
            r = r.wrapping_sub(d);
            q |= 1;
        }
        i += 1;
    }
    if r != 0 {
        q + 1
    } else {
        q
    }
}

/// `n / d` (`d ≠ 0`), rounded toward zero as `i64` division (`i64::MIN / -1`,
/// which overflows, wraps instead of panicking).
pub fn div_i64(n: i64, d: i64) -> i64 {
    let q = div_u64(n.unsigned_abs(), d.unsigned_abs()) as i64;
    if (n < 0) != (d < 0) {
        q.wrapping_neg()
    } else {
        q
    }
}

/// `⌊√x⌋` by Newton's iteration with the hardware divide, from a power
/// of two at or above the root: core's `u32::isqrt` starts from a
/// 256-entry table (half a kilobyte of flash besides its code).
pub fn isqrt_u32(x: u32) -> u32 {
    if x == 0 {
        return 0;
    }
    // 2^⌈bits/2⌉ > √x; below 2^17, so y + x / y cannot overflow
    let mut y = 1u32 << (32 - x.leading_zeros()).div_ceil(2);
    loop {
        // from above, a floor Newton step decreases until ⌊√x⌋
        let z = (y + x / y) / 2;
        if z >= y {
            return y;
        }
        y = z;
    }
}

/// `⌊√x⌋`: the 32-bit root of the top bits, one Newton step with a
/// 64-by-64 division, then corrected down to the exact floor.
pub fn isqrt_u64(x: u64) -> u64 {
    if x >> 32 == 0 {
        return u64::from(isqrt_u32(x as u32));
    }
    let k = (64 - x.leading_zeros() - 31) / 2; // x >> 2k keeps 31 or 32 bits
    let y0 = u64::from(isqrt_u32((x >> (2 * k)) as u32)) << k;
    // a Newton step in floor arithmetic never lands below ⌊√x⌋ (AM-GM:
    // ⌊(y0 + ⌊x/y0⌋)/2⌋ = ⌊(y0 + x/y0)/2⌋ ≥ ⌊√x⌋), and from this
    // close a start only a little above it
    let mut y = (y0 + div_u64(x, y0)) / 2;
    while y.checked_mul(y).is_none_or(|square| square > x) {
        y -= 1;
    }
    y
}

/// `n / d` for `n >> 64 < d` (the quotient fits 64 bits): Knuth's
/// algorithm D with two 32-bit digits (Hacker's Delight `divlu`), two
/// 64-by-32 divisions.
pub(crate) fn div_u128_by_u64(n: u128, d: u64) -> u64 {
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
pub(crate) fn div_u64_by_u32(u: u64, v: u32) -> u32 {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// xorshift on 64 bits: the tests' random numbers
    fn next(x: &mut u64) -> u64 {
        *x ^= *x << 13;
        *x ^= *x >> 7;
        *x ^= *x << 17;
        *x
    }

    #[test]
    fn division_matches_the_operators() {
        let mut x = 0x9E37_79B9_7F4A_7C15;
        for i in 0..50_000u32 {
            let n = next(&mut x) >> (i % 64);
            let d = (next(&mut x) >> ((i / 64) % 64)).max(1);
            assert_eq!(div_u64(n, d), n / d, "{n} / {d}");
            assert_eq!(div_ceil_u64(n, d), n.div_ceil(d), "{n} / {d}");
            let (sn, sd) = (n as i64, d as i64);
            if sd != 0 && !(sn == i64::MIN && sd == -1) {
                assert_eq!(div_i64(sn, sd), sn / sd, "{sn} / {sd}");
            }
        }
        for (n, d) in [
            (0, 1),
            (u64::MAX, 1),
            (u64::MAX, u64::MAX),
            (1 << 32, 1 << 32),
            (u64::MAX, 3),
        ] {
            assert_eq!(div_u64(n, d), n / d);
            assert_eq!(div_ceil_u64(n, d), n.div_ceil(d));
        }
        assert_eq!(div_i64(-7, 2), -3);
        assert_eq!(div_i64(7, -2), -3);
        assert_eq!(div_i64(-7, -2), 3);
        assert_eq!(div_i64(i64::MIN, 1), i64::MIN);
    }

    #[test]
    #[should_panic(expected = "divide by zero")]
    fn division_by_zero_panics_like_the_operator() {
        div_u64(1, 0);
    }

    #[test]
    fn root_matches_core() {
        let mut x = 0x2545_F491_4F6C_DD1D;
        for i in 0..50_000u32 {
            let w = next(&mut x) >> (i % 64);
            assert_eq!(isqrt_u64(w), w.isqrt(), "isqrt {w}");
        }
        for w in [
            0,
            1,
            2,
            3,
            4,
            u64::from(u32::MAX),
            1 << 32,
            (1 << 32) + 1,
            u64::MAX - 1,
            u64::MAX,
        ] {
            assert_eq!(isqrt_u64(w), w.isqrt(), "isqrt {w}");
        }
        for r in [1u64 << 31, (1 << 32) - 1, 3_037_000_499, 4_294_967_295] {
            for w in [r * r - 1, r * r, r * r + 1] {
                assert_eq!(isqrt_u64(w), w.isqrt(), "isqrt {w}");
            }
        }
    }

    #[test]
    fn root_u32_matches_core() {
        // every x up to 2^20, then every square's neighbours and a
        // pseudo-random sample over the whole range
        for w in 0..=1u32 << 20 {
            assert_eq!(isqrt_u32(w), w.isqrt(), "isqrt {w}");
        }
        for r in 1u32..=65_535 {
            for w in [r * r - 1, r * r, (r * r).saturating_add(1), r * r + 2 * r] {
                assert_eq!(isqrt_u32(w), w.isqrt(), "isqrt {w}");
            }
        }
        let mut x = 0x9E37_79B9_7F4A_7C15;
        for i in 0..200_000u32 {
            let w = (next(&mut x) >> 32) as u32 >> (i % 32);
            assert_eq!(isqrt_u32(w), w.isqrt(), "isqrt {w}");
        }
        assert_eq!(isqrt_u32(u32::MAX), u32::MAX.isqrt());
    }
}
