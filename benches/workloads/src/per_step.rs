//! A design experiment, not the drive's planner (docs/benchmarks.md): the bench
//! triangle's step times computed one by one, exactly, instead of fitted
//! per segment and expanded — how much a per-step planner would cost on
//! the Cortex-M4 in the same rhythm (a call every 1 ms that fills 3 ms
//! ahead).
//!
//! On a ramp from rest the time of step `n` is `U(n) = √(n·q)` with
//! `q = 2f²/a` ticks² per step (`a` in steps/s², `f` the timer): the root
//! `U` is kept in Q10 ticks (< 2^32 on this move) and `U²` exactly in
//! 64 bits, and each step's root comes from the previous two by a
//! second-order prediction and one Newton correction — a 32×32 → 64
//! multiplication and one 32-bit division (`sdiv`, one instruction), no
//! software division. The fall is the rise mirrored about the peak. The
//! steps less than 16 from rest take the exact root (`u64::isqrt`), where
//! the prediction is far off. Delays are rounded like the drive's ring:
//! every step at its exact time to the nearest tick.
//!
//! It is deliberately the cheapest case: one move, no cruise, no change
//! of goal, no direction, no velocity shown, and a 2^-10-tick root that
//! only fits this move (the planner's acceleration bound needs about
//! 2^-16 tick at 200 000 steps/s, and 64-bit roots there). Its cost is
//! therefore a floor for a per-step design written like the rest of the
//! core (safe Rust: no assembly), not an estimate of one.

use modbus_drive::motion::SCHEDULE_STEPS as RING;

use crate::{CONTROL_PERIOD_US, RAMP_ACCEL_STEPS_PER_S2, RAMP_MOVE_STEPS};

/// Steps from rest that take the exact root.
const EXACT_NEAR_REST: u32 = 16;

/// The experiment's state: the ring it fills and where the move is.
pub struct PerStep {
    pub ring: [u32; RING],
    head: usize,
    /// `U` (Q10 ticks) at the last step and its last two differences.
    u: u32,
    d: i32,
    dp: i32,
    /// `U²` (Q20 ticks², exact) at the last step; `q` per step.
    w: u64,
    q: u64,
    /// Steps made, in the move, at the peak; `U` at the peak.
    pub n: u32,
    total: u32,
    peak: u32,
    u_peak: u32,
    /// Tick (rounded, wrapping) of the last step.
    last: u32,
}

impl Default for PerStep {
    fn default() -> Self {
        let f = crate::BENCH_TICK_HZ;
        Self::new(RAMP_MOVE_STEPS, RAMP_ACCEL_STEPS_PER_S2.into(), f.into())
    }
}

impl PerStep {
    /// A symmetric triangle of `total` steps at `a` steps/s² on an
    /// `f` Hz timer (the peak's root must stay below 2^32 in Q10).
    pub fn new(total: u32, a: u64, f: u64) -> Self {
        let q = (2 * f * f / a) << 20;
        let peak = total / 2;
        Self {
            ring: [0; RING],
            head: 0,
            u: 0,
            d: 0,
            dp: 0,
            w: 0,
            q,
            n: 0,
            total,
            peak,
            u_peak: (q * u64::from(peak)).isqrt() as u32,
            last: 0,
        }
    }

    /// `U` at the last step (Q10 ticks) and `U²` there: for the test.
    pub fn root(&self) -> (u32, u64) {
        (self.u, self.w)
    }

    /// Makes every step due by `until` (ticks); returns how many.
    #[inline(never)]
    pub fn fill(&mut self, until: u64) -> u32 {
        let until_q = until << 10;
        let (mut u, mut d, mut dp, mut w) = (self.u, self.d, self.dp, self.w);
        let (mut n, mut head, mut last) = (self.n, self.head, self.last);
        let (q, peak, total) = (self.q, self.peak, self.total);
        let start = n;
        let ring = &mut self.ring;
        // the rise: time = U (the rise and the fall are two loops: one
        // loop for both, generic over the direction, measured 83.2 per
        // step against 71.2)
        if n < peak {
            let lim = until_q.min(u64::from(u32::MAX)) as u32;
            while n < peak && u <= lim {
                w += q;
                n += 1;
                let nu = if n < EXACT_NEAR_REST {
                    exact_root(w)
                } else {
                    newton(u, d, dp, w)
                };
                (dp, d, u) = (d, nu.wrapping_sub(u) as i32, nu);
                let tick = (u + 512) >> 10;
                ring[head & (RING - 1)] = tick.wrapping_sub(last);
                (head, last) = (head + 1, tick);
            }
            if n == peak {
                // the fall retraces the rise's roots backwards
                d = -d;
                dp = d;
            }
        }
        // the fall: time = 2·U_peak − U, with U_peak − U < 2^32
        let upk = self.u_peak;
        if n >= peak && until_q >= u64::from(upk) {
            let lim = (until_q - u64::from(upk)).min(u64::from(u32::MAX)) as u32;
            while n < total && upk - u <= lim {
                w -= q;
                n += 1;
                let nu = if total - n < EXACT_NEAR_REST {
                    exact_root(w)
                } else {
                    newton(u, d, dp, w)
                };
                (dp, d, u) = (d, nu.wrapping_sub(u) as i32, nu);
                let tick = ((u64::from(upk) * 2 - u64::from(u) + 512) >> 10) as u32;
                ring[head & (RING - 1)] = tick.wrapping_sub(last);
                (head, last) = (head + 1, tick);
            }
        }
        (self.u, self.d, self.dp, self.w) = (u, d, dp, w);
        (self.n, self.head, self.last) = (n, head & (RING - 1), last);
        n - start
    }
}

/// `√w` from the previous root `u` and its last two differences: the
/// second-order prediction, then one Newton step `(w − p²)/(2p)` through
/// one 32-bit division (the remainder and the root scaled to fit).
#[inline(always)]
fn newton(u: u32, d: i32, dp: i32, w: u64) -> u32 {
    let p = u
        .wrapping_add(d as u32)
        .wrapping_add(d.wrapping_sub(dp) as u32);
    let r = w.wrapping_sub(u64::from(p) * u64::from(p)) as i64;
    p.wrapping_add((((r >> 16) as i32) / ((p >> 15) as i32)) as u32)
}

#[inline(never)]
#[cold]
fn exact_root(w: u64) -> u32 {
    w.isqrt() as u32
}

/// The whole move in the drive's rhythm — a call every control period
/// ([`CONTROL_PERIOD_US`]) filling the planner's default horizon ahead, on
/// its default timer: the workload the QEMU runner times. Returns the
/// steps made.
#[inline(never)]
pub fn per_step_move(s: &mut PerStep) -> u32 {
    *s = PerStep::default();
    let cfg = crate::bench_config();
    let per_us = u64::from(cfg.tick_hz() / 1_000_000);
    let (period, horizon) = (
        CONTROL_PERIOD_US * per_us,
        u64::from(cfg.horizon_us()) * per_us,
    );
    let (mut steps, mut now) = (0, 0u64);
    while s.n < s.total {
        steps += s.fill(now + horizon);
        now += period;
    }
    steps
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;

    /// Every step lands on its exact time rounded to the nearest tick,
    /// and every root is within a few units of `⌊√U²⌋` (calls short
    /// enough to make one step each: the state carries over, so the
    /// roots are those of any rhythm).
    #[test]
    fn every_step_at_its_exact_time() {
        let mut s = PerStep::default();
        let f = f64::from(crate::BENCH_TICK_HZ);
        let a = f64::from(RAMP_ACCEL_STEPS_PER_S2);
        let (total, peak) = (f64::from(RAMP_MOVE_STEPS), f64::from(RAMP_MOVE_STEPS / 2));
        let time = |n: u32| {
            let x = f64::from(n);
            f * if x <= peak {
                (2.0 * x / a).sqrt()
            } else {
                2.0 * (2.0 * peak / a).sqrt() - (2.0 * (total - x) / a).sqrt()
            }
        };
        let (mut until, mut tick, mut worst_root) = (0u64, 0u64, 0i64);
        while s.n < s.total {
            let before = s.n;
            assert!(s.fill(until) <= 1);
            if s.n > before {
                tick += u64::from(s.ring[before as usize % RING]);
                let err = (tick as f64 - time(s.n)).abs();
                assert!(err <= 0.5 + 1e-3, "step {}: {err} ticks off", s.n);
                let (u, w) = s.root();
                worst_root = worst_root.max((i64::from(u) - w.isqrt() as i64).abs());
            }
            until += 1_000;
        }
        assert_eq!(s.n, RAMP_MOVE_STEPS);
        assert!(
            worst_root <= 8,
            "root off by {worst_root} units of 2^-10 tick"
        );
        std::println!("worst root error {worst_root} units of 2^-10 tick");
    }
}
