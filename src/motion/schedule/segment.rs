//! A run of steps and its expansion into per-step delays, which carries
//! the fraction of every exact time into the next (module docs of the
//! schedule).

use core::sync::atomic::{AtomicU32, Ordering};

use super::{MAX_DELAY_TICKS, SCHEDULE_STEPS, TICK_FRAC_BITS};

/// Most steps one pass of [`Expansion::run`]'s narrow loop takes: its
/// 32-bit bounds ([`Expansion::narrow`]) hold up to here.
pub(super) const NARROW_STEPS: usize = 512;

/// Most fraction bits of a segment's `add2`, `add3` and `add4` beyond the
/// interval's 32 ([`Segment::with_fine_bits`]).
pub const MAX_FINE_BITS: u32 = 16;

/// A run of steps with linearly changing interval (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Segment {
    /// Ticks (Q32.32) from the previous step to the first step of this one.
    interval: u64,
    /// Ticks (Q32.32) added to the interval after every step.
    add: i64,
    /// Added to `add` after every step, in units of 2^-(32 + `fine`) tick
    /// (its whole 2^-32 units: the sum's fraction is dropped).
    add2: i64,
    /// Added to `add2` after every step, and `add4` to it (same units):
    /// the intervals are a quartic in the step number (the planner's
    /// quintic fit of the step times, planner/segment.rs `fit_segment`).
    add3: i64,
    add4: i64,
    /// Fraction bits of `add2`, `add3` and `add4` beyond the interval's 32
    /// (at most [`MAX_FINE_BITS`]): the highest terms' rounding reaches the
    /// last interval of a segment C(n, 4) times, so finer terms let a
    /// ramp's segments stay long at high speed, where the interval hardly
    /// changes from step to step.
    fine: u8,
    /// Steps, at least 1 and at most what [`StepSchedule::free`](super::StepSchedule::free) allows.
    count: u32,
    /// Positive direction (position counts up).
    forward: bool,
}

impl Segment {
    /// The terms as their getters describe them.
    #[inline]
    pub const fn new(
        interval: u64,
        add: i64,
        add2: i64,
        add3: i64,
        add4: i64,
        count: u32,
        forward: bool,
    ) -> Self {
        Self {
            interval,
            add,
            add2,
            add3,
            add4,
            fine: 0,
            count,
            forward,
        }
    }

    /// The same segment with `add2`, `add3` and `add4` read in units of
    /// 2^-(32 + `bits`) tick (`bits` at most [`MAX_FINE_BITS`]: more are
    /// taken as that many).
    #[inline]
    pub const fn with_fine_bits(mut self, bits: u32) -> Self {
        self.fine = if bits < MAX_FINE_BITS {
            bits
        } else {
            MAX_FINE_BITS
        } as u8;
        self
    }

    /// Ticks (Q32.32) from the previous step to the first step of this one.
    #[inline]
    pub const fn interval(&self) -> u64 {
        self.interval
    }

    /// Ticks (Q32.32) added to the interval after every step.
    #[inline]
    pub const fn add(&self) -> i64 {
        self.add
    }

    /// Added to `add` after every step, in units of 2^-(32 +
    /// [`Segment::fine_bits`]) tick.
    #[inline]
    pub const fn add2(&self) -> i64 {
        self.add2
    }

    /// Added to `add2` after every step, and `add4` to it (the units of
    /// `add2`): the intervals are a quartic in the step number (the
    /// planner's quintic fit of the step times, planner/segment.rs
    /// `fit_segment`).
    #[inline]
    pub const fn add3(&self) -> i64 {
        self.add3
    }

    #[inline]
    pub const fn add4(&self) -> i64 {
        self.add4
    }

    /// Fraction bits of `add2`, `add3` and `add4` beyond the interval's 32.
    #[inline]
    pub const fn fine_bits(&self) -> u32 {
        self.fine as u32
    }

    /// Steps, at least 1 and at most what [`StepSchedule::free`](super::StepSchedule::free) allows.
    #[inline]
    pub const fn count(&self) -> u32 {
        self.count
    }

    /// Positive direction (position counts up).
    #[inline]
    pub const fn forward(&self) -> bool {
        self.forward
    }

    /// A constant speed: the interval does not change from step to step
    /// (the expansion then writes each step with one store).
    #[inline]
    pub const fn is_constant(&self) -> bool {
        self.add | self.add2 | self.add3 | self.add4 == 0
    }

    /// The one delay every step of it gets, if it has one: a constant
    /// speed of whole ticks (no fraction to carry), a plain delay.
    #[inline]
    pub(super) fn uniform_delay(&self) -> Option<u32> {
        let whole = (self.interval >> TICK_FRAC_BITS) as u32;
        (self.is_constant() && self.interval as u32 == 0 && whole as i32 > 0).then_some(whole)
    }
}

impl Segment {
    /// Drops the steps left: the segment is done.
    #[inline]
    pub(crate) fn clear_steps(&mut self) {
        self.count = 0;
    }

    /// `steps` (≤ `count`) of it were pushed.
    #[inline]
    pub(super) fn consume(&mut self, steps: u32) {
        self.count -= steps;
    }

    /// Moves the terms on, as a push of the same steps would, by the
    /// fewest steps (at least one, at most `max`, and at most `count`)
    /// whose exact time reaches `until` (Q32.32 ticks, from the previous
    /// step); `frac` is the fraction carried in and comes out carried on.
    /// Returns the steps and their exact time, the same numbers a push
    /// gives (planner/segment.rs `drop_pending` finds with it where to cut a
    /// segment pushed whole). Writes no entry.
    pub fn advance_until(&mut self, frac: &mut u32, until: u64, max: u32) -> (u32, u64) {
        let mut x = Expansion::of(self, (*frac, 0));
        let max = max.min(self.count);
        let (mut steps, mut time) = (0, 0);
        while steps < max && (steps == 0 || (time as i64) < until as i64) {
            x.step();
            steps += 1;
            time = time_made(*frac, (x.frac, x.sum));
        }
        x.store_terms(self);
        self.count -= steps;
        *frac = x.frac;
        (steps, time)
    }
}

/// The delay of a step `interval` (Q32.32 ticks) after the previous one:
/// its integer part plus the carry of its fraction into `frac`, the
/// fraction the exact times carry (module docs). The expansion's and the
/// limit brake's.
#[inline(always)]
pub(super) fn carried(frac: &mut u32, interval: u64) -> u32 {
    let (f, carry) = frac.overflowing_add(interval as u32);
    *frac = f;
    ((interval >> TICK_FRAC_BITS) as u32).wrapping_add(u32::from(carry))
}

/// `delay` as a ring entry: 0 (from an interval below half a tick, never
/// planned: the sentinel's value) becomes 1 and a delay past the longest
/// (or a negative `interval`) [`MAX_DELAY_TICKS`].
#[inline(always)]
pub(super) fn clamped(delay: u32, interval: u64) -> u32 {
    if delay.wrapping_sub(1) < MAX_DELAY_TICKS {
        delay
    } else if interval >> 63 != 0 {
        MAX_DELAY_TICKS
    } else {
        1
    }
}

/// The exact time (Q32.32 ticks, wrapping) of steps expanded from the
/// carried fraction `frac` to `carry` (fraction, delay sum): the sum of
/// their intervals, which is the delays' sum plus the fraction's change
/// (signed: a carry made it smaller).
pub(super) fn time_made(frac: u32, carry: (u32, u32)) -> u64 {
    let dfrac = i64::from(carry.0) - i64::from(frac);
    (u64::from(carry.1) << TICK_FRAC_BITS).wrapping_add(dfrac as u64)
}

/// The producer's exact-time accumulator over one segment (module docs).
#[derive(Clone, Copy)]
pub(super) struct Expansion {
    pub(super) interval: u64,
    pub(super) add: u64,
    pub(super) add2: u64,
    pub(super) add3: u64,
    pub(super) add4: u64,
    /// [`Segment::fine_bits`].
    pub(super) fine: u32,
    pub(super) frac: u32,
    /// The delays written, summed (wrapping): with `frac`'s change, the
    /// exact time they make (`StepSchedule::push_steps`).
    pub(super) sum: u32,
}

impl Expansion {
    /// The next step's delay: the interval's integer part plus the carry
    /// of its fraction into the pending time's; then the interval one step
    /// on.
    #[inline(always)]
    pub(super) fn step(&mut self) -> u32 {
        let delay = clamped(carried(&mut self.frac, self.interval), self.interval);
        self.interval = self.interval.wrapping_add(self.add);
        self.add = self
            .add
            .wrapping_add(((self.add2 as i64) >> self.fine) as u64);
        self.add2 = self.add2.wrapping_add(self.add3);
        self.add3 = self.add3.wrapping_add(self.add4);
        self.sum = self.sum.wrapping_add(delay);
        delay
    }

    /// `seg`'s terms with the carried fraction and delay sum `carry`.
    pub(super) fn of(seg: &Segment, carry: (u32, u32)) -> Self {
        Self {
            interval: seg.interval,
            add: seg.add as u64,
            add2: seg.add2 as u64,
            add3: seg.add3 as u64,
            add4: seg.add4 as u64,
            fine: seg.fine.into(),
            frac: carry.0,
            sum: carry.1,
        }
    }

    /// Back into `seg`: its terms, moved on.
    pub(super) fn store_terms(&self, seg: &mut Segment) {
        seg.interval = self.interval;
        seg.add = self.add as i64;
        seg.add2 = self.add2 as i64;
        seg.add3 = self.add3 as i64;
        seg.add4 = self.add4 as i64;
    }

    /// The next `steps` steps can take the narrow loop of
    /// [`Expansion::run`]: the terms from `add2` on stay inside `i32`
    /// (`add2 + j·add3 + C(j,2)·add4` and `add3 + j·add4` for every
    /// `j ≤ steps`, the terms after the last step included), so 32-bit
    /// sums give them exactly; and every interval stays between 1 and
    /// 2^31 ticks (`|interval_j − interval| ≤ Σ C(steps, k)·|term k|`,
    /// the fine terms over 2^`fine`, plus one unit for each fraction that
    /// `add`'s steps drop), so no delay needs [`clamped`].
    pub(super) fn narrow(&self, steps: usize) -> bool {
        const LIM: u64 = 1 << 31;
        let m = |t: u64| (t as i64).unsigned_abs();
        let (a1, a2, a3, a4) = (m(self.add), m(self.add2), m(self.add3), m(self.add4));
        if steps > NARROW_STEPS || a1 >= 1 << 48 || (a2 | a3 | a4) >= LIM {
            return false;
        }
        // 32-bit factors from here (one `umull` per product): l ≤ 2^9,
        // C(l, 2) < 2^17, C(l, 3) < 2^25, C(l, 4) < 2^32
        let (l, a2, a3, a4) = (steps as u32, a2 as u32, a3 as u32, a4 as u32);
        let wide = |x: u32, y: u32| u64::from(x) * u64::from(y);
        let c2 = l * l.saturating_sub(1) / 2;
        let c3 = c2 * l.saturating_sub(2) / 3;
        let c4 = (wide(c3, l.saturating_sub(3)) / 4) as u32;
        // each product below 2^57, 2^48, 2^56, 2^63: no overflow
        // `add`'s steps drop the fractions of fine terms (at most one
        // unit each): C(l, 2) more at most
        let higher = (wide(c2, a2) + wide(c3, a3) + wide(c4, a4)) >> self.fine;
        let dropped = if self.fine == 0 { 0 } else { u64::from(c2) };
        let drift = a1 * u64::from(l) + higher + dropped;
        u64::from(a3) + wide(l, a4) < LIM
            && u64::from(a2) + wide(l, a3) + wide(c2, a4) < LIM
            && self.interval.saturating_sub(drift) >= 1 << TICK_FRAC_BITS
            && self.interval.saturating_add(drift) < 1 << 63
    }

    /// [`Expansion::step`] for every entry; with `add2`, `add3` and `add4`
    /// in 32-bit registers and no clamp when [`Expansion::narrow`] allows
    /// (the common push: the higher terms are small): the same delays
    /// and terms from a loop whose state fits the Cortex-M's registers.
    #[inline(always)]
    pub(super) fn run(&mut self, entries: &[AtomicU32]) {
        if SCHEDULE_STEPS <= NARROW_STEPS {
            // a push is shorter than the ring: one pass (no loop in the image)
            self.run_chunk(entries);
        } else {
            for chunk in entries.chunks(NARROW_STEPS) {
                self.run_chunk(chunk);
            }
        }
    }

    #[inline(always)]
    fn run_chunk(&mut self, entries: &[AtomicU32]) {
        let whole = (self.interval >> TICK_FRAC_BITS) as u32;
        if self.add | self.add2 | self.add3 | self.add4 == 0
            && (1..MAX_DELAY_TICKS).contains(&whole)
        {
            // a constant speed: only the fraction moves, and no delay
            // (the interval's whole ticks, or one more) needs a clamp; the
            // delays sum to the whole ticks and the fraction's carries
            let part = self.interval as u32;
            let n = entries.len() as u64;
            let reach = u64::from(self.frac) + n * u64::from(part);
            if part == 0 {
                // four stores a loop round (written out: the images'
                // size-optimised builds do not unroll), the cruise's whole
                // cost here
                let mut rest = entries;
                while let [a, b, c, d, tail @ ..] = rest {
                    a.store(whole, Ordering::Relaxed);
                    b.store(whole, Ordering::Relaxed);
                    c.store(whole, Ordering::Relaxed);
                    d.store(whole, Ordering::Relaxed);
                    rest = tail;
                }
                for entry in rest {
                    entry.store(whole, Ordering::Relaxed);
                }
            } else {
                let mut frac = self.frac;
                for entry in entries {
                    let (f, carry) = frac.overflowing_add(part);
                    frac = f;
                    entry.store(whole + u32::from(carry), Ordering::Relaxed);
                }
            }
            let carries = (reach >> 32) as u32;
            self.sum = self
                .sum
                .wrapping_add((n as u32).wrapping_mul(whole))
                .wrapping_add(carries);
            self.frac = reach as u32;
            return;
        }
        if !self.narrow(entries.len()) {
            for entry in entries {
                entry.store(self.step(), Ordering::Relaxed);
            }
            return;
        }
        let (mut interval, mut add) = (self.interval, self.add);
        let (mut add2, mut add3, add4) = (self.add2 as i32, self.add3 as i32, self.add4 as i32);
        let (mut frac, mut sum, fine) = (self.frac, self.sum, self.fine);
        for entry in entries {
            let delay = carried(&mut frac, interval);
            entry.store(delay, Ordering::Relaxed);
            sum = sum.wrapping_add(delay);
            let next_add3 = add3.wrapping_add(add4);
            let next_add2 = add2.wrapping_add(add3);
            let next_add = add.wrapping_add((add2 >> fine) as i64 as u64);
            interval = interval.wrapping_add(add);
            (add, add2, add3) = (next_add, next_add2, next_add3);
        }
        (self.interval, self.add) = (interval, add);
        (self.add2, self.add3) = (add2 as i64 as u64, add3 as i64 as u64);
        (self.frac, self.sum) = (frac, sum);
    }

    /// Writes the next steps' delays of `seg` to `first` (if given) and
    /// `entries`, in order, and moves `seg`'s terms and `carry` (fraction,
    /// delay sum) on: one call per push, straight from and to the segment.
    #[inline(never)]
    pub(super) fn fill(
        seg: &mut Segment,
        carry: &mut (u32, u32),
        first: Option<&mut u32>,
        entries: &[AtomicU32],
    ) {
        let mut x = Self::of(seg, *carry);
        if let Some(first) = first {
            *first = x.step();
        }
        x.run(entries);
        x.store_terms(seg);
        *carry = (x.frac, x.sum);
    }
}
