//! The limit brake's deceleration: the rate the drive arms it with and
//! the interval of each braking step (module docs of the schedule).

use super::TICK_FRAC_BITS;
use crate::motion::profile::ratio;

/// [`StepSchedule::limits`] bits: the direction an active limit blocks.
pub(super) const BLOCK_BACKWARD: u8 = 1; // CW limit: the negative end (SPEC §8.6)
pub(super) const BLOCK_FORWARD: u8 = 2; // CCW limit: the positive end

/// [`StepSchedule::brake`] states (written by the interrupt, except
/// `DONE` → `NONE` by [`StepSchedule::release_brake`]).
pub(super) const BRAKE_NONE: u8 = 0;
pub(super) const BRAKE_ACTIVE: u8 = 1;
pub(super) const BRAKE_DONE: u8 = 2;
pub(super) const BRAKE_FORWARD: u8 = 4;

/// Mantissa bits of a brake rate ([`brake_rate`]); the shift sits above.
pub(super) const RATE_MANTISSA_BITS: u32 = 24;
pub(super) const RATE_MANTISSA: u32 = (1 << RATE_MANTISSA_BITS) - 1;
/// "At once": the first braking step already has `q ≥ 1/4`.
pub(super) const RATE_AT_ONCE: u32 = RATE_MANTISSA;

/// Brake rate for the step interrupt: the deceleration `decel` (0.1
/// steps/s², the drive's unit, e.g. 0x6085 × PA10) in steps/tick² at
/// `tick_hz`, as a 24-bit mantissa and a shift (`a = mantissa / 2^shift`)
/// packed in one word so that it can be an atomic on every Cortex-M.
/// `decel == 0` means "stop at once" (SPEC §8.3); 0 is never returned
/// (it means "disarmed"). Thread mode; two divisions.
pub fn brake_rate(decel: u64, tick_hz: u32) -> u32 {
    // a = decel / (10 · tick_hz²) steps/tick²
    let den = 10 * u128::from(tick_hz.max(1)).pow(2);
    let num = u128::from(decel);
    if num == 0 {
        return RATE_AT_ONCE;
    }
    if RATE_MANTISSA_BITS as i32 - 1 + den.ilog2() as i32 - (num.ilog2() as i32) < 0 {
        return RATE_AT_ONCE; // more than 2^23 steps/tick²: no step fits
    }
    // the ratio as a 31/32-bit mantissa and a shift (profile::ratio, one
    // 128-by-64 division), cut to 24 bits: the same floor(num·2^s/den)
    let (m, sh) = ratio(num, den);
    let r = (64 - m.leading_zeros()) - RATE_MANTISSA_BITS;
    let (m, s) = (m >> r, sh - r);
    if s > 111 {
        // below 2^-88 steps/tick²: slower than anything the planner runs
        return 1 | (111 << RATE_MANTISSA_BITS);
    }
    (m as u32 & RATE_MANTISSA) | (s << RATE_MANTISSA_BITS)
}

/// The interval after `p` (Q32.32 ticks) when braking at `rate`
/// ([`brake_rate`]), or `None` if the motor is less than two steps from
/// rest (`q ≥ 1/4`) or slower than 2^24 ticks per step: [`grown`] by
/// [`brake_q`].
#[cfg(test)]
pub(super) fn brake_interval(p: u64, rate: u32) -> Option<u64> {
    brake_q(p, rate).map(|q| grown(p, q))
}

/// `q = a·p²` (Q0.32) of the brake at `rate` ([`brake_rate`]) after an
/// interval `p` (Q32.32 ticks), or `None` if the motor is less than two
/// steps from rest (`q ≥ 1/4`) or slower than 2^24 ticks per step.
/// Constant time and 32-bit products only (the step engine's refill makes
/// a braking step in the time of one at the top rate): `p` is taken as a
/// 32-bit mantissa and a shift, which leaves `q` a relative error below
/// 2^-29, far below what the series' truncation leaves (module docs).
pub(super) fn brake_q(p: u64, rate: u32) -> Option<u32> {
    if p >> (TICK_FRAC_BITS + 24) != 0 {
        return None;
    }
    let wide = |x: u32, y: u32| u64::from(x) * u64::from(y);
    // p ≈ pm · 2^k with pm's top bit set (k = 0 below 2^32: a step
    // shorter than a tick, where q is far below 1/4 anyway); shifts of
    // 32-bit words only (a 64-bit shift by a variable is a library call)
    let (hi, lo) = ((p >> 32) as u32, p as u32);
    let (pm, k) = match hi.leading_zeros() {
        32 => (lo, 0),
        z => ((hi << z) | (lo >> (32 - z)), 32 - z),
    };
    // p² ≈ t · 2^(2k + 32)
    let t = (wide(pm, pm) >> 32) as u32;
    // q = m · p² / 2^(s + 64) in Q0.32 = m · t · 2^(2k - s), from the top
    // 32 of m · t's 56 bits; rounded, not truncated: near the end v² is a
    // small difference of large numbers, so a bias per step would show
    // there
    let top = (wide(rate & RATE_MANTISSA, t) >> 24) as u32;
    let s = (rate >> RATE_MANTISSA_BITS) as i32 - 2 * k as i32 - 24;
    let q = match s {
        1..=31 => (top >> s) + ((top >> (s - 1)) & 1),
        0 => top,
        s if s > 0 => 0,
        // at least 2^30 unless `top` is small: q ≥ 1/4
        s if top.leading_zeros() as i32 + s <= 1 => return None,
        s => top << -s,
    };
    (q < 1 << 30).then_some(q)
}

/// `p · (1 - 2q)^-1/2` for `q < 1/4` (Q0.32), `p` in Q32.32 ticks: the
/// interval `n` braking steps after `p` where `q` is `n` times the one
/// step's [`brake_q`] (`v² ← v² - 2an`). 32 × 32-bit products only.
pub(super) fn grown(p: u64, q: u32) -> u64 {
    // 32 × 32 → 64-bit products (one `umull` each), rounded back to 32
    let wide = |x: u32, y: u32| u64::from(x) * u64::from(y);
    let mul = |x: u32, y: u32| ((wide(x, y) + (1 << 31)) >> 32) as u32;
    let (q2, q3) = (mul(q, q), mul(mul(q, q), q));
    let q4 = mul(q2, q2);
    // (1-2q)^-1/2 - 1 = q + 3/2 q² + 5/2 q³ + 35/8 q⁴ + …, Q0.32 (below
    // 0.4 at q = 1/4); the rest is below 0.6 % at q = 1/4
    let f = q + q2 + (q2 >> 1) + 2 * q3 + (q3 >> 1) + 4 * q4 + (q4 >> 2) + (q4 >> 3);
    // p · f / 2^32 from p's two halves
    let (hi, lo) = ((p >> 32) as u32, p as u32);
    let grow = u64::from(hi) * u64::from(f) + ((wide(lo, f) + (1 << 31)) >> 32);
    p + grow
}

/// What the step interrupt's limit brake is doing (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LimitBrake {
    /// The motion it stopped went in the positive direction (towards the
    /// CCW limit).
    forward: bool,
    /// The motor is at rest; the schedule stays latched (empty) until
    /// [`StepSchedule::release_brake`](super::StepSchedule::release_brake).
    done: bool,
}

impl LimitBrake {
    #[inline]
    pub const fn new(forward: bool, done: bool) -> Self {
        Self { forward, done }
    }

    /// The motion it stopped went in the positive direction (towards the
    /// CCW limit).
    #[inline]
    pub const fn forward(&self) -> bool {
        self.forward
    }

    /// The motor is at rest; the schedule stays latched (empty) until
    /// [`StepSchedule::release_brake`](super::StepSchedule::release_brake).
    #[inline]
    pub const fn done(&self) -> bool {
        self.done
    }
}
