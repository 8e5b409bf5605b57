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
/// rest (`q ≥ 1/4`) or slower than 2^24 ticks per step. Constant time: six
/// 64×64 multiplies, no division (module docs).
pub(super) fn brake_interval(p: u64, rate: u32) -> Option<u64> {
    if p >> (TICK_FRAC_BITS + 24) != 0 {
        return None;
    }
    // Rounded, not truncated: near the end v² is a small difference of
    // large numbers, so a bias per step would show there.
    let p8 = p >> 8; // Q32.24, < 2^48
    let p2 = u128::from(p8) * u128::from(p8); // p², Q.48, < 2^96
    let shift = (rate >> RATE_MANTISSA_BITS) + 16;
    let half = 1u128 << (shift - 1);
    let q = (u128::from(rate & RATE_MANTISSA) * p2 + half) >> shift; // q, Q0.32
    if q >= 1 << 30 {
        return None;
    }
    let q = q as u64;
    let mul = |x: u64, y: u64| (x * y + (1 << 31)) >> 32;
    let (q2, q3) = (mul(q, q), mul(mul(q, q), q));
    let q4 = mul(q2, q2);
    // (1-2q)^-1/2 - 1 = q + 3/2 q² + 5/2 q³ + 35/8 q⁴ + …, Q0.32; the rest
    // is below 0.6 % at q = 1/4
    let f = q + q2 + (q2 >> 1) + 2 * q3 + (q3 >> 1) + 4 * q4 + (q4 >> 2) + (q4 >> 3);
    let grow = (u128::from(p) * u128::from(f) + (1 << 31)) >> 32;
    Some(p + grow as u64)
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
