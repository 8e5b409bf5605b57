//! The ring of per-step delays shared by thread mode and the step
//! interrupt: the producer's side, the flags and the derived position
//! (module docs of the schedule).

use core::sync::atomic::{compiler_fence, AtomicBool, AtomicI32, AtomicU32, AtomicU8, Ordering};

use super::brake::{
    LimitBrake, BLOCK_BACKWARD, BLOCK_FORWARD, BRAKE_DONE, BRAKE_FORWARD, BRAKE_NONE,
};
use super::segment::{time_made, Expansion, Segment};
use super::sink::{PushedSteps, StepSink};
use super::{dir, END, HALF_TICK, MARK_BACKWARD, MARK_FORWARD, SCHEDULE_STEPS};

/// Entries a known run may lie behind the queue's end before a push of
/// other delays forgets it: far less than the 2^32 after which its
/// wrapping indices would name new entries, and a push moves the end by
/// less than a ring.
const STALE_RUN: u32 = 1 << 30;

/// The shared ring of per-step delays plus what the interrupt reports back
/// (see the module docs for who may call what). `repr(C)`: the ring at the
/// start and `next`/`quiet` right behind it, so that the interrupt's
/// fast path addresses all three from the schedule's own address.
#[repr(C)]
pub struct StepSchedule {
    pub(super) ring: [AtomicU32; SCHEDULE_STEPS],
    /// Index (wrapping) of the entry after the pending one, or after the
    /// last one taken while idle (the consumer's one store per step).
    pub(super) next: AtomicU32,
    /// Cleared ("attention raised") by whoever changes `flush`, `limits` or
    /// `brake_rate`, and by the consumer while it is idle or braking; set
    /// by the consumer when it has looked: its only per-step look at
    /// anything but the ring (module docs).
    pub(super) quiet: AtomicBool,
    /// Index (wrapping) of the sentinel, where the next push starts
    /// (producer only).
    pub(super) head: AtomicU32,
    /// Direction of the last push is negative (producer only; stored
    /// before `head`).
    pub(super) head_backward: AtomicBool,
    /// Fraction of the last pushed step's exact time plus half a tick,
    /// Q0.32, which the next push carries on (producer only).
    pub(super) frac: AtomicU32,
    /// Position base (consumer only, under `seq`): the position is
    /// `base_pos + base_dir · (next − base_idx)` (`base_dir` ±1, 0 before
    /// the first step).
    pub(super) base_pos: AtomicI32,
    pub(super) base_idx: AtomicU32,
    pub(super) base_dir: AtomicI32,
    /// Sequence count around changes of the base and of `next` outside the
    /// per-step path (odd while they change).
    pub(super) seq: AtomicU32,
    /// Set by thread mode: drop everything at the next step.
    pub(super) flush: AtomicBool,
    /// The consumer has a step pending (steps are being generated).
    pub(super) running: AtomicBool,
    /// Directions blocked by active limits (the limit-switch interrupt).
    pub(super) limits: AtomicU8,
    /// Armed limit brake ([`brake_rate`]; 0 = disarmed), from the drive.
    pub(super) brake_rate: AtomicU32,
    /// The limit brake's state (`BRAKE_*`).
    pub(super) brake: AtomicU8,
    /// Steps counted in the position that the step output has not made
    /// yet ([`StepSchedule::set_pin_lag`]), the position it was measured
    /// at, and whether an output has told it at all.
    pub(super) pin_lag: AtomicI32,
    pub(super) pin_lag_at: AtomicI32,
    pub(super) pin_lag_told: AtomicBool,
    /// A run of equal delays the producer has pushed, for the consumer to
    /// take without comparing them ([`StepSchedule::run_ahead`]): the
    /// entries from `run_from` up to `run_to` (excluded, wrapping) all
    /// hold `run_delay`; 0 there (the sentinel's value, never a delay):
    /// none known. Producer only.
    pub(super) run_from: AtomicU32,
    pub(super) run_to: AtomicU32,
    pub(super) run_delay: AtomicU32,
}

impl Default for StepSchedule {
    fn default() -> Self {
        Self::new()
    }
}
impl StepSchedule {
    /// All zeros (the sentinel is 0, the flags are chosen so), so that a
    /// `static` of it is zero-initialised memory (.bss), no flash image.
    pub const fn new() -> Self {
        Self {
            ring: [const { AtomicU32::new(END) }; SCHEDULE_STEPS],
            next: AtomicU32::new(0),
            quiet: AtomicBool::new(false),
            head: AtomicU32::new(0),
            head_backward: AtomicBool::new(false),
            frac: AtomicU32::new(0),
            base_pos: AtomicI32::new(0),
            base_idx: AtomicU32::new(0),
            base_dir: AtomicI32::new(0),
            seq: AtomicU32::new(0),
            flush: AtomicBool::new(false),
            running: AtomicBool::new(false),
            limits: AtomicU8::new(0),
            brake_rate: AtomicU32::new(0),
            brake: AtomicU8::new(BRAKE_NONE),
            pin_lag: AtomicI32::new(0),
            pin_lag_at: AtomicI32::new(0),
            pin_lag_told: AtomicBool::new(false),
            run_from: AtomicU32::new(0),
            run_to: AtomicU32::new(0),
            run_delay: AtomicU32::new(END),
        }
    }

    /// The whole ring, in index order from 0.
    pub(super) fn ring(&self) -> &[AtomicU32; SCHEDULE_STEPS] {
        &self.ring
    }

    pub(super) fn entry(&self, index: u32) -> &AtomicU32 {
        &self.ring[index as usize % SCHEDULE_STEPS]
    }

    // ---- producer side (thread mode) ----

    /// Entries a push may write now: every slot from the sentinel's up to
    /// the one before the pending entry's (`next − 1`), less one for the
    /// new sentinel.
    fn room(&self) -> u32 {
        let pending = self.next.load(Ordering::Relaxed).wrapping_sub(1);
        let used = self.head.load(Ordering::Relaxed).wrapping_sub(pending);
        (SCHEDULE_STEPS as u32 - 1).saturating_sub(used)
    }

    /// Steps a push can take now, whatever its direction (one entry is
    /// kept for a direction marker). `SCHEDULE_STEPS - 3` when empty.
    pub fn free(&self) -> usize {
        self.room().saturating_sub(1) as usize
    }

    /// Appends a segment, expanded into its steps' delays (module docs);
    /// gives it back when it has no step or the ring lacks room for all of
    /// them (plus a direction marker if the direction changes).
    pub fn push(&self, seg: Segment) -> Result<(), Segment> {
        let mut rest = seg;
        match self.push_steps(&mut rest, seg.count(), &mut ()) {
            Some(_) => Ok(()),
            None => Err(seg),
        }
    }

    /// Appends the first `count` steps of `seg` (all of them at most) and
    /// leaves in `seg` the rest: its terms moved on by those steps, its
    /// count reduced (the planner hands a segment over in parts when the
    /// ring lacks room for all of it). Returns the time the appended
    /// steps take, exactly ([`time_made`]). `None`, and
    /// nothing done, when `count` is 0 or the ring lacks room for them.
    /// `sink` is told of the steps first ([`StepSink`]; `()` for none).
    #[inline(never)]
    pub fn push_steps<S: StepSink>(
        &self,
        seg: &mut Segment,
        count: u32,
        sink: &mut S,
    ) -> Option<u64> {
        let count = count.min(seg.count());
        let head = self.head.load(Ordering::Relaxed);
        let turn = seg.forward() == self.head_backward.load(Ordering::Relaxed);
        let entries = count.saturating_add(u32::from(turn));
        if count == 0 || entries > self.room() {
            return None;
        }
        let uniform = seg.uniform_delay();
        let frac = self.carry_in();
        let mut carry = (frac, 0);
        // ring[head], the old sentinel, is written last (module docs)
        let end = head.wrapping_add(entries);
        let from = head.wrapping_add(u32::from(turn));
        sink.pushed(&PushedSteps {
            seg: *seg,
            frac,
            from,
            to: end,
        });
        let first_step = self.expand(seg, &mut carry, from, end);
        let first = match (turn, seg.forward()) {
            (false, _) => first_step,
            (true, forward) => {
                self.entry(head.wrapping_add(1))
                    .store(first_step, Ordering::Relaxed);
                if forward {
                    MARK_FORWARD
                } else {
                    MARK_BACKWARD
                }
            }
        };
        self.entry(end).store(END, Ordering::Relaxed);
        // one core: program order is all the interrupt needs (module docs)
        compiler_fence(Ordering::SeqCst);
        self.entry(head).store(first, Ordering::Relaxed);
        self.frac.store(carry.0, Ordering::Relaxed);
        compiler_fence(Ordering::SeqCst);
        self.head_backward.store(!seg.forward(), Ordering::Relaxed);
        compiler_fence(Ordering::SeqCst);
        self.head.store(end, Ordering::Relaxed);
        compiler_fence(Ordering::SeqCst);
        self.note_run(uniform, from, end);
        seg.consume(count);
        Some(time_made(frac, carry))
    }

    /// The fraction the next push carries on (module docs): the last
    /// pushed step's, or half a tick for a run from rest (the interrupt
    /// idle, nothing queued: only the producer can change that), so that
    /// the delays round every exact time to the nearest tick.
    pub fn carry_in(&self) -> u32 {
        if !self.is_running() && self.is_empty() {
            HALF_TICK
        } else {
            self.frac.load(Ordering::Relaxed)
        }
    }

    /// Takes back the queued entries from ring index `at` on (producer
    /// only): the queue then ends before `at`, and the next push starts
    /// there, carrying the fraction `frac` (that of the step before `at`,
    /// [`Segment::advance_until`]). The planner cuts a segment pushed
    /// whole this way when a new goal arrives (planner/segment.rs `drop_pending`).
    ///
    /// False, and nothing taken back, unless `at` is inside the queue and
    /// not behind the interrupt's next read.
    /// The interrupt reads `ring[next]` and never looks at `head` but to
    /// drop the queue (flush, the limit brake's end, `cancel`), which
    /// moves `next` to `head`. So: `head` first, then the sentinel at
    /// `at`, then a second look at `next`. At or before `at`: the
    /// interrupt has not read the entry there and will find the sentinel
    /// (or has dropped the queue to the new `head`: empty, consistent).
    /// Past it (it read the entry at `at` in between, or dropped the
    /// queue to the old `head`): `head` goes back, and what was written at
    /// `at` lies behind the interrupt, where nobody reads it.
    pub fn truncate(&self, at: u32, frac: u32) -> bool {
        let head = self.head.load(Ordering::Relaxed);
        let next = self.next.load(Ordering::Relaxed);
        if (at.wrapping_sub(next) as i32) < 0 || head.wrapping_sub(at) as i32 <= 0 {
            return false;
        }
        self.cut_run(at);
        self.head.store(at, Ordering::Relaxed);
        compiler_fence(Ordering::SeqCst);
        self.entry(at).store(END, Ordering::Relaxed);
        compiler_fence(Ordering::SeqCst);
        if (at.wrapping_sub(self.next.load(Ordering::Relaxed)) as i32) < 0 {
            self.head.store(head, Ordering::Relaxed);
            return false;
        }
        self.frac.store(frac, Ordering::Relaxed);
        true
    }

    /// The known run after a push of the entries `from` up to `end`, all
    /// `uniform` if that is `Some` (a constant speed of whole ticks): it
    /// grows by them if they continue it, else they are the run. A push
    /// of other delays keeps it, unless it lies so far behind the queue
    /// that its indices could come round again. The consumer may come in
    /// between any two stores: a run it could then see is either the old
    /// one or the new one (`run_delay` is 0 while the ends change).
    fn note_run(&self, uniform: Option<u32>, from: u32, end: u32) {
        let to = self.run_to.load(Ordering::Relaxed);
        match uniform {
            Some(delay) if delay == self.run_delay.load(Ordering::Relaxed) && to == from => {
                self.run_to.store(end, Ordering::Relaxed);
            }
            Some(delay) => {
                self.run_delay.store(END, Ordering::Relaxed);
                compiler_fence(Ordering::SeqCst);
                self.run_from.store(from, Ordering::Relaxed);
                self.run_to.store(end, Ordering::Relaxed);
                compiler_fence(Ordering::SeqCst);
                self.run_delay.store(delay, Ordering::Relaxed);
            }
            None if from.wrapping_sub(to) > STALE_RUN => {
                self.run_delay.store(END, Ordering::Relaxed);
            }
            None => {}
        }
    }

    /// Before the entries from `at` on are taken back (and written again
    /// by later pushes): the known run ends before `at`.
    fn cut_run(&self, at: u32) {
        let from = self.run_from.load(Ordering::Relaxed);
        if self.run_to.load(Ordering::Relaxed).wrapping_sub(at) as i32 > 0 {
            if at.wrapping_sub(from) as i32 > 0 {
                self.run_to.store(at, Ordering::Relaxed);
            } else {
                self.run_delay.store(END, Ordering::Relaxed);
            }
        }
        compiler_fence(Ordering::SeqCst);
    }

    /// Consumer side: how many entries from `start` on are known to hold
    /// `delay` (a delay, not 0) without reading them: those of the run
    /// the producer noted, if `start` lies in it.
    #[inline(always)]
    pub(super) fn run_ahead(&self, start: u32, delay: u32) -> usize {
        let from = self.run_from.load(Ordering::Relaxed);
        let to = self.run_to.load(Ordering::Relaxed);
        if self.run_delay.load(Ordering::Relaxed) != delay
            || start.wrapping_sub(from) >= to.wrapping_sub(from)
        {
            return 0;
        }
        to.wrapping_sub(start) as usize
    }

    /// Expands the next steps of `seg` for the entries `from` up to `to`
    /// (excluded, at least one): writes all but the first, which it
    /// returns, so that the caller can write it last.
    fn expand(&self, seg: &mut Segment, carry: &mut (u32, u32), from: u32, to: u32) -> u32 {
        // the first into a local, the rest to the ring in at most two
        // contiguous pieces (the `min`s never cut: fewer than
        // SCHEDULE_STEPS entries)
        let mut first = END;
        let start = from.wrapping_add(1) as usize % SCHEDULE_STEPS;
        let n = to.wrapping_sub(from).wrapping_sub(1) as usize;
        let (before, after) = self.ring.split_at(start);
        let k = n.min(after.len());
        Expansion::fill(seg, carry, Some(&mut first), &after[..k]);
        if k < n {
            Expansion::fill(seg, carry, None, &before[..(n - k).min(before.len())]);
        }
        first
    }

    /// Ring index (wrapping) of the last entry pushed: after a push, its
    /// last step's. The planner keeps it per segment to tell which one
    /// the interrupt is executing ([`StepSchedule::step_index`]).
    pub fn last_pushed_index(&self) -> u32 {
        self.head.load(Ordering::Relaxed).wrapping_sub(1)
    }

    /// Ring index (wrapping) of the step the interrupt has announced and
    /// not yet made, while [`StepSchedule::is_running`] (during a limit
    /// brake: of the last step it took from the ring).
    pub fn step_index(&self) -> u32 {
        self.next.load(Ordering::Relaxed).wrapping_sub(1)
    }

    /// Asks the consumer to drop the pending step and every queued entry
    /// ("stop step output at once", SPEC §8.1/§8.3).
    pub fn request_flush(&self) {
        self.flush.store(true, Ordering::Relaxed);
        self.raise_attention();
    }

    /// Tells the consumer to look at `flush`, `limits` and `brake_rate`
    /// at its next step: the flag after the value (module docs).
    fn raise_attention(&self) {
        self.quiet.store(false, Ordering::Relaxed);
    }

    /// A flush was requested and the consumer has not yet carried it out.
    pub fn flush_pending(&self) -> bool {
        self.flush.load(Ordering::Relaxed)
    }

    /// Clears a flush request nobody will carry out because the interrupt
    /// is idle and the ring empty (the interrupt starts only on a non-empty
    /// ring, and only the producer fills it, so this cannot race).
    pub fn clear_flush_if_idle(&self) {
        if !self.is_running() && self.is_empty() {
            self.flush.store(false, Ordering::Relaxed);
        }
    }

    /// Arms the limit brake with a [`brake_rate`](super::brake::brake_rate), or disarms it (`None`:
    /// homing, where the sequencer decides at the limits, SPEC §8.6).
    pub fn set_brake_rate(&self, rate: Option<u32>) {
        let rate = rate.unwrap_or(0);
        // thread mode is the only writer: compare, so that the drive may
        // call it every period without sending the interrupt the slow way
        if self.brake_rate.load(Ordering::Relaxed) != rate {
            self.brake_rate.store(rate, Ordering::Relaxed);
            self.raise_attention();
        }
    }

    /// The interrupt's limit brake, if it has engaged and not been
    /// released.
    pub fn limit_brake(&self) -> Option<LimitBrake> {
        let b = self.brake.load(Ordering::Relaxed);
        (b != BRAKE_NONE).then_some(LimitBrake::new(b & BRAKE_FORWARD != 0, b & BRAKE_DONE != 0))
    }

    /// Lets the interrupt take entries again after a finished brake (the
    /// planner calls it once it has the position back). No effect while
    /// the brake is still running.
    pub fn release_brake(&self) {
        if self.brake.load(Ordering::Relaxed) & BRAKE_DONE != 0 {
            self.brake.store(BRAKE_NONE, Ordering::Relaxed);
        }
    }

    // ---- the limit-switch interrupt (or whoever reads the switches) ----

    /// The enabled limits active now (logical, after PA13/PA14). Call it
    /// on every switch edge, from one context at a time. Returns whether
    /// they changed.
    pub fn set_limits(&self, cw_limit: bool, ccw_limit: bool) -> bool {
        let bits =
            if cw_limit { BLOCK_BACKWARD } else { 0 } | if ccw_limit { BLOCK_FORWARD } else { 0 };
        let changed = self.limits.load(Ordering::Relaxed) != bits;
        if changed {
            self.limits.store(bits, Ordering::Relaxed);
            self.raise_attention();
        }
        changed
    }

    // ---- either side ----

    /// The step output tells how far the STEP pin is behind
    /// [`StepSchedule::position`]: the steps the position counts that are
    /// not on the pin yet (signed, in the position's sense). An output
    /// that makes each step as it is counted leaves it 0 (the host
    /// simulation); the firmware's timer + DMA engine, which is handed
    /// steps ahead of its timer, sets it from its pulse counter every
    /// control period, with `at`, the [`StepSchedule::position`] it was
    /// measured against. The drive reports the pin's position and is at
    /// rest only once the pin is settled ([`StepSchedule::pin_settled`]).
    pub fn set_pin_lag(&self, lag: i32, at: i32) {
        self.pin_lag.store(lag, Ordering::Relaxed);
        self.pin_lag_at.store(at, Ordering::Relaxed);
        self.pin_lag_told.store(true, Ordering::Relaxed);
    }

    /// [`StepSchedule::set_pin_lag`]'s value.
    pub fn pin_lag(&self) -> i32 {
        self.pin_lag.load(Ordering::Relaxed)
    }

    /// The STEP pin has made every step the position counts: the lag last
    /// told is 0 and the position has not moved since it was measured
    /// (steps handed to the output after that, the last of a move among
    /// them, may not be on the pin yet), or no output tells a lag.
    pub fn pin_settled(&self) -> bool {
        !self.pin_lag_told.load(Ordering::Relaxed)
            || (self.pin_lag() == 0 && self.pin_lag_at.load(Ordering::Relaxed) == self.position())
    }

    /// Raw step count: steps made forward minus steps made backward.
    /// Derived from the position base and the index of the pending step
    /// (module docs: the interrupt stores no position per step). Call it
    /// from a context the interrupt may preempt, not from one that may
    /// preempt the interrupt.
    pub fn position(&self) -> i32 {
        loop {
            let seq = self.seq.load(Ordering::Relaxed);
            compiler_fence(Ordering::SeqCst);
            let pos = self.base_position(self.next.load(Ordering::Relaxed));
            compiler_fence(Ordering::SeqCst);
            if seq & 1 == 0 && self.seq.load(Ordering::Relaxed) == seq {
                return pos;
            }
        }
    }

    /// The position formula on the current base at `next` (the consumer,
    /// which writes the base, reads it without the sequence count).
    pub(super) fn base_position(&self, next: u32) -> i32 {
        let pos = self.base_pos.load(Ordering::Relaxed);
        let idx = self.base_idx.load(Ordering::Relaxed);
        let dir = self.base_dir.load(Ordering::Relaxed);
        pos.wrapping_add(dir.wrapping_mul(next.wrapping_sub(idx) as i32))
    }

    /// Consumer only: `next` and a new base at it (position `pos`,
    /// direction `forward`), under the sequence count that
    /// [`StepSchedule::position`] reads them with.
    pub(super) fn set_base(&self, pos: i32, next: u32, forward: bool) {
        let seq = self.seq.load(Ordering::Relaxed);
        self.seq.store(seq.wrapping_add(1), Ordering::Relaxed);
        compiler_fence(Ordering::SeqCst);
        self.base_pos.store(pos, Ordering::Relaxed);
        self.base_idx.store(next, Ordering::Relaxed);
        self.base_dir.store(dir(forward), Ordering::Relaxed);
        self.next.store(next, Ordering::Relaxed);
        compiler_fence(Ordering::SeqCst);
        self.seq.store(seq.wrapping_add(2), Ordering::Relaxed);
    }

    /// Consumer only: the base's position moved on by `by`, `next` at the
    /// base's index (the limit brake's steps, which are no ring entries):
    /// one store, which [`StepSchedule::position`] sees whole, old or new.
    pub(super) fn move_base(&self, by: i32) {
        let pos = self.base_pos.load(Ordering::Relaxed);
        self.base_pos.store(pos.wrapping_add(by), Ordering::Relaxed);
    }

    /// Steps are being generated (a step is scheduled on the timer).
    pub fn is_running(&self) -> bool {
        self.running.load(Ordering::Relaxed)
    }

    /// Nothing is queued behind the pending step (or behind the last step
    /// made, when idle).
    pub fn is_empty(&self) -> bool {
        self.head.load(Ordering::Relaxed) == self.next.load(Ordering::Relaxed)
    }
}
