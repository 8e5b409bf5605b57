//! Compression: each segment's quintic fit, its push (whole or in parts)
//! and its cut when a new goal comes (module docs of the planner).

use super::slots::SlotInfo;
use super::{Planner, CONSTANT_STEPS_PER_BUDGET, PUSH_STEPS, SCHEDULE_SLOTS};
use crate::arith::div_i64;
use crate::motion::profile::w_along;
use crate::motion::schedule::{Segment, StepSchedule, StepSink, MAX_FINE_BITS};

/// The segment being handed to the interrupt: fitted and pushed whole
/// (in parts when the ring lacks room), and cut at the horizon by a new
/// goal, so that its length (the fit's cost is per segment) does not delay
/// a change of goal (module docs).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Pending {
    /// Its steps not yet pushed, and their terms (`count` = 0: none).
    pub(super) rest: Segment,
    /// Steps it holds.
    pub(super) n: u64,
    /// The planner's state before it (position, v², exact time), and the
    /// v² slope of its piece: enough to find the state after any of its
    /// steps when a new goal cuts it.
    pub(super) pos: i64,
    pub(super) w: u128,
    pub(super) t_ideal: u64,
    pub(super) slope: i128,
    /// For the drive's 0x606C: the velocities at its ends.
    pub(super) info: SlotInfo,
    /// Where it went, for a cut (`drop_pending`): its terms at its first
    /// step (`count` 0: its times are no longer those, as after the ring
    /// ran dry inside it, so no cut), the fraction carried into that
    /// step, the time before it as the interrupt will reach it, the ring
    /// index of its first step, and the steps pushed (0: none).
    pub(super) start: Segment,
    pub(super) start_frac: u32,
    pub(super) t_start: u64,
    pub(super) first: u32,
    pub(super) pushed: u32,
}

/// What [`Planner::push_pending`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Pushed {
    /// The pending segment is pushed whole.
    Ended,
    /// Its budget or [`PUSH_STEPS`] ended the push, steps are left.
    Stopped,
    /// The ring or the segment bookkeeping is full.
    Full,
}

impl Planner {
    /// Times the next run of steps of the current profile and fits it
    /// ([`fit_segment`]) into the pending segment, which
    /// [`Planner::push_pending`] hands to the interrupt. Out of line:
    /// inlined into the firmware's control loop it cost the F103 flash.
    #[inline(never)]
    pub(super) fn emit(&mut self) {
        let Some(profile) = self.profile.as_mut() else {
            return;
        };
        let (s0, c0) = if self.s_end_w == self.w && self.s_end != 0 {
            // the end slope and curvature of the previous segment, same
            // profile (start() clears them): a division and a curvature
            // saved
            (Some(self.s_end), self.c_end)
        } else {
            // after a cut (drop_pending), the slope of the steps made
            let s0 = match core::mem::take(&mut self.s_join) {
                0 => profile.step_ticks(),
                s => Some(s),
            };
            (s0, s0.map_or(0, |s0| profile.curvature(s0)))
        };
        let n = profile.segment_len(s0, c0, &self.budget);
        let (pos, w, t_ideal) = (self.pos, self.w, self.t_ideal);
        let slope = profile.piece_slope();
        let v_start = profile.velocity();
        let t_last = profile.advance(n);
        let s1 = profile.step_ticks();
        let c1 = s1.map_or(0, |s1| profile.curvature(s1));
        // the span the interrupt must make, from where it will be
        let span = t_last.wrapping_sub(self.t_isr);
        // a cruise (its piece level, no curvature carried in from a ramp)
        // is a constant speed: its fit would only spread the last
        // segment's time error as fine terms, which cost the expansion and
        // the refill a step each
        let cruise = slope == 0 && c0 == 0;
        let ([interval, add, add2, add3, add4], fine) = match (n, s0, s1) {
            (2.., Some(s0), Some(s1)) if !cruise => {
                let ends = [(s0, c0), (s1, c1)];
                fit_segment(n, ends, span)
            }
            // single steps, a cruise or no slope at the end: evenly, the
            // rest of the span is carried to the next segment through t_isr
            _ => ([span >> n.trailing_zeros(), 0, 0, 0, 0], 0),
        };
        self.t_ideal = t_last;
        self.planned_steps = self.planned_steps.wrapping_add(n);
        self.segments_fitted = self.segments_fitted.wrapping_add(1);
        self.pos += signed(profile.forward(), n);
        self.w = profile.w();
        self.forward = profile.forward();
        (self.s_end, self.c_end, self.s_end_w) = (s1.unwrap_or(0), c1, self.w);
        let seg = Segment::new(
            interval,
            add as i64,
            add2 as i64,
            add3 as i64,
            add4 as i64,
            n as u32,
            profile.forward(),
        )
        .with_fine_bits(fine);
        self.pending = Pending {
            rest: seg,
            start: seg,
            start_frac: 0,
            t_start: 0,
            first: 0,
            pushed: 0,
            n,
            pos,
            w,
            t_ideal,
            slope,
            info: SlotInfo {
                last_index: 0,
                to_end: 0,
                count: n as u32,
                v_start: signed(profile.forward(), v_start) as i32,
                v_end: signed(profile.forward(), profile.velocity()) as i32,
                ramping: profile.ramping() || profile.remaining() == 0,
            },
        };
    }

    /// Pushes the pending segment whole, or as much of it as the ring
    /// takes, `limit` (budget steps) allows and [`PUSH_STEPS`] (a new goal
    /// cuts it at the horizon, `drop_pending`); the steps pushed come off
    /// the fill's budget.
    pub(super) fn push_pending<S: StepSink>(
        &mut self,
        sched: &StepSchedule,
        sink: &mut S,
        limit: u32,
    ) -> Pushed {
        let tracked = self.segments.wrapping_sub(self.oldest) as usize;
        if tracked >= SCHEDULE_SLOTS {
            return Pushed::Full;
        }
        let pending = &mut self.pending;
        let seg = &mut pending.rest;
        // `limit` in budget steps (a constant speed's are cheaper)
        let shift = if seg.is_constant() {
            CONSTANT_STEPS_PER_BUDGET.trailing_zeros()
        } else {
            0
        };
        let k = seg
            .count()
            .min(sched.free() as u32)
            .min(limit.saturating_mul(1 << shift))
            .min(PUSH_STEPS);
        if (self
            .t_isr
            .wrapping_add(seg.interval())
            .wrapping_sub(self.now) as i64)
            < 0
        {
            self.late_segments = self.late_segments.wrapping_add(1);
        }
        let first_part = pending.pushed == 0;
        if first_part {
            pending.start_frac = sched.carry_in();
            pending.t_start = self.t_isr;
        }
        let Some(made) = sched.push_steps(seg, k, sink) else {
            return Pushed::Full;
        };
        pending.pushed += k;
        self.step_budget = self
            .step_budget
            .saturating_sub((k + (1 << shift) - 1) >> shift);
        self.t_isr = self.t_isr.wrapping_add(made);
        let last = sched.last_pushed_index();
        // one slot per segment, its end moved on with each part
        if first_part {
            pending.first = last.wrapping_sub(k - 1);
            self.slots[self.segments as usize % SCHEDULE_SLOTS] = pending.info;
            self.segments = self.segments.wrapping_add(1);
        }
        let to_end = pending.rest.count();
        let slot = self.last_slot();
        slot.last_index = last;
        slot.to_end = to_end;
        if to_end == 0 {
            Pushed::Ended
        } else if sched.free() == 0 {
            Pushed::Full
        } else {
            Pushed::Stopped
        }
    }

    /// A new goal: the state goes back to the last step of the pending
    /// segment that stays, so that the new goal continues from that step
    /// and takes effect within the horizon. The segment was pushed whole
    /// (or as far as the ring took it); with `cut` (a motion being
    /// replaced, not one planned to its end) its steps due after the
    /// horizon are taken back from the ring ([`StepSchedule::truncate`],
    /// in the next [`Planner::fill`]: returned here, kept in `cut`), and
    /// the steps not pushed are dropped. What the state goes back to:
    /// the position and v² (linear along its piece), and the time and
    /// slope of the steps made — where the interrupt will be, not the
    /// profile's exact time and `1/v` there: inside a segment the fit
    /// differs from those by up to its error bound, and the next segment
    /// must continue the steps made without a jump in time or velocity
    /// (a jump of 0.3 µs in one step would be a spike of 60 000 steps/s²
    /// at 6000 steps/s). The new profile starts from that time.
    pub(super) fn drop_pending(&mut self, cut: bool) -> Option<(u32, u32)> {
        let p = self.pending;
        self.pending.rest.clear_steps();
        self.pending.pushed = 0;
        // the steps dropped, the terms at the last step that stays, and
        // the cut to make in the ring (its first ring index, the fraction
        // carried there)
        let (mut left, mut r, mut taken) = (p.rest.count(), p.rest, None);
        if cut && p.pushed > 1 && p.start.count() > 0 {
            // the steps due before the horizon (at least one), found by
            // expanding the segment again from its start
            let (mut seg, mut frac) = (p.start, p.start_frac);
            let until = self
                .now
                .wrapping_add(self.horizon_q)
                .wrapping_sub(p.t_start);
            let (steps, time) = seg.advance_until(&mut frac, until, p.pushed);
            if steps < p.pushed {
                // taken back from the ring in the next fill (set_goal may
                // run where the schedule is not at hand)
                taken = Some((p.first.wrapping_add(steps), frac));
                (left, r) = (left + p.pushed - steps, seg);
                self.t_isr = p.t_start.wrapping_add(time);
                let slot = self.last_slot();
                slot.last_index = p.first.wrapping_add(steps - 1);
                slot.to_end = p.n as u32 - steps;
            }
        }
        if left == 0 {
            return None;
        }
        let (left, j) = (u64::from(left), p.n - u64::from(left));
        self.planned_steps = self.planned_steps.wrapping_sub(left);
        self.pos = p.pos + signed(p.rest.forward(), j);
        self.w = w_along(p.w, p.slope, u128::from(j) << 32);
        self.t_ideal = self.t_isr;
        // T'(j) from the forward differences at j (D = ln(1 + Δ)):
        // Δ − Δ²/2 + Δ³/3 − Δ⁴/4 + Δ⁵/5, exact for the quintic
        // the fine terms' part, in their units
        let fine_part = (r.add2().wrapping_mul(20))
            .wrapping_add(r.add3().wrapping_mul(-15))
            .wrapping_add(r.add4().wrapping_mul(12));
        let higher = (r.add().wrapping_mul(-30)).wrapping_add(fine_part >> r.fine_bits());
        self.s_join = r.interval().wrapping_add(div_i64(higher, 60) as u64);
        self.s_end = 0;
        taken
    }
}

/// `n` steps (or 0.1 steps/s) as a signed count in the direction
/// `forward`.
pub(super) fn signed(forward: bool, n: u64) -> i64 {
    if forward {
        n as i64
    } else {
        -(n as i64)
    }
}

/// The forward differences at 0 of `j³`, `j⁴` and `j⁵` (`Δ^i j^m = i!·S(m, i)`),
/// by difference order 1 to 5: the coefficients of `a3`, `a4`, `a5` in
/// each of [`fit_segment`]'s terms.
const FORWARD_DIFFS: [[i16; 3]; 5] = [
    [1, 1, 1],
    [6, 14, 30],
    [6, 36, 150],
    [0, 24, 240],
    [0, 0, 120],
];

/// `[interval, add, add2, add3, add4]` (Q32.32, two's complement; `add2`
/// on with the fraction bits returned beside them) of a segment of
/// `n = 2^k ≥ 2` steps whose step times follow the quintic `T(j)` with
/// `T(0) = 0`, `T(n) = span` and the slopes and curvatures
/// `ends = [(T'(0), T''(0)), (T'(n), T''(n))]` (quintic Hermite: the
/// profile's `dt/dx = 1/v` and `d²t/dx² = −a/v³` at both ends, so that
/// consecutive segments join with continuous velocity *and*
/// acceleration). With `T(j) = s0·j + c0/2·j² + (N3·j³ + N4·j⁴/n +
/// N5·j⁵/n²)/n³` the terms are the forward differences of `T` at 0, each
/// rounded once from exact numerators over `n⁵` (a shift): the rounding
/// of the highest term, summed over the segment, stays below 1/100 tick.
/// The caller accounts the rest: it tracks the time the interrupt will
/// really reach.
///
/// `add2`, `add3` and `add4` get up to [`MAX_FINE_BITS`] more fraction
/// bits (`3k − 1` at most: each numerator is still shifted right), as
/// many as keep `|add2|`, `n·|add3|` and `n²/2·|add4|` below 2^29, so that the
/// expansion's 32-bit loop still takes them (schedule's `Expansion::narrow`).
pub(super) fn fit_segment(n: u64, ends: [(u64, i64); 2], span: u64) -> ([u64; 5], u32) {
    let [(s0, c0), (s1, c1)] = ends;
    let k = n.trailing_zeros();
    // R, R1 are small remainders of large numbers: wrapping arithmetic
    // gives them exactly. Sizes: R ≈ t‴·n³/6 ≤ span·2^27 (n ≤ m/2), and
    // spans ≤ 2^22 ticks (SegmentBudget): every number below < 2^62.
    let h = n as i64;
    let r = span
        .wrapping_sub(s0.wrapping_mul(n))
        .wrapping_sub((c0.wrapping_mul(h * h) >> 1) as u64) as i64;
    let r1 = s1.wrapping_sub(s0).wrapping_sub(c0.wrapping_mul(h) as u64) as i64;
    let r2h2 = (c1.wrapping_sub(c0) << (2 * k)) >> 1;
    let r1h = r1 << k;
    let n3 = 10 * r - 4 * r1h + r2h2;
    let n4 = -15 * r + 7 * r1h - 2 * r2h2;
    let n5 = 6 * r - 3 * r1h + r2h2;
    // a3 = N3/n³, a4 = N4/n⁴, a5 = N5/n⁵ (FORWARD_DIFFS). Each term
    // rounded separately (≤ 1.5 units of its last bit), the highest once.
    let nums = [n3, n4, n5];
    let mut fine = MAX_FINE_BITS.min(3 * k - 1);
    let [t1, t2, add2, add3, add4] = loop {
        let t = fit_terms(nums, k, fine);
        // bits of |add2|, n·|add3| and n²/2·|add4|, at most
        let bits = |x: u64, scale: u32| 64 - (x as i64).unsigned_abs().leading_zeros() + scale;
        let size = bits(t[2], 0).max(bits(t[3], k)).max(bits(t[4], 2 * k - 1));
        if size <= 29 || fine == 0 {
            break t;
        }
        // fewer bits: the slow start of a ramp, where the terms are large
        // and the segments short
        fine = fine.saturating_sub(size - 29);
    };
    (
        [
            s0.wrapping_add((c0 >> 1) as u64).wrapping_add(t1),
            (c0 as u64).wrapping_add(t2),
            add2,
            add3,
            add4,
        ],
        fine,
    )
}

/// [`fit_segment`]'s five terms from its numerators `N3`, `N4`, `N5` over
/// `n = 2^k`, `add2` on with `fine` more fraction bits. Out of line, and a
/// loop: it runs once or twice a segment.
#[inline(never)]
fn fit_terms(nums: [i64; 3], k: u32, fine: u32) -> [u64; 5] {
    let mut out = [0u64; 5];
    for (i, (term, diffs)) in out.iter_mut().zip(FORWARD_DIFFS).enumerate() {
        let f = if i < 2 { 0 } else { fine };
        let mut sum = 0i64;
        for (p, (c, x)) in diffs.iter().zip(nums).enumerate() {
            // rounded to the nearest unit of the term's last bit
            let sh = (3 + p as u32) * k - f;
            sum += (((i64::from(*c) * x) >> (sh - 1)) + 1) >> 1;
        }
        *term = sum as u64;
    }
    out
}
