//! Which pushed segment the interrupt is executing, and the velocity the
//! drive shows for it (0x606C).

use super::{Planner, SCHEDULE_SLOTS};
use crate::motion::StepSchedule;

/// What the drive shows for the segment the interrupt is executing.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct SlotInfo {
    /// Ring index of the segment's last step ([`StepSchedule::step_index`]).
    pub(super) last_index: u32,
    /// Steps of its segment after its last step (a segment is pushed in
    /// parts when the ring lacks room, and cut by a new goal), the
    /// segment's steps, and the signed
    /// velocities (0.1 steps/s) before the segment's first and at its last
    /// step: v² is linear in the steps within a segment (one profile
    /// piece), so the velocity of any of its steps follows without keeping
    /// v² per step.
    pub(super) to_end: u32,
    pub(super) count: u32,
    pub(super) v_start: i32,
    pub(super) v_end: i32,
    pub(super) ramping: bool,
}

impl SlotInfo {
    /// Signed velocity (0.1 steps/s) at the step with ring index `step`.
    pub(super) fn velocity_at(&self, step: u32) -> i64 {
        let left =
            u64::from(self.last_index.wrapping_sub(step).min(self.count)) + u64::from(self.to_end);
        let (a, b) = (i64::from(self.v_start), i64::from(self.v_end));
        if a == b || self.count == 0 {
            return b;
        }
        // v² = b² − (b² − a²)·left/count, in u64 (|v| < 2^22)
        let (a2, b2) = ((a * a) as u64, (b * b) as u64);
        let n = u64::from(self.count);
        // segments hold a power of two of steps: the division is a shift
        let (left, k) = (left.min(n), n.trailing_zeros());
        let w = if b2 >= a2 {
            b2 - (((b2 - a2) * left) >> k)
        } else {
            b2 + (((a2 - b2) * left) >> k)
        };
        let v = w.isqrt() as i64;
        if b < 0 || (b == 0 && a < 0) {
            -v
        } else {
            v
        }
    }
}

impl Planner {
    pub(super) fn current_slot(&self, sched: &StepSchedule) -> Option<SlotInfo> {
        if !sched.is_running() {
            return None;
        }
        let k = self.first_unfinished(sched.step_index());
        (k != self.segments).then(|| self.slots[k as usize % SCHEDULE_SLOTS])
    }

    /// The first segment from `oldest` on whose last step is at or after
    /// ring index `step` (wrapping): its number, `segments` if none.
    pub(super) fn first_unfinished(&self, step: u32) -> u32 {
        let mut k = self.oldest;
        while k != self.segments {
            let last = self.slots[k as usize % SCHEDULE_SLOTS].last_index;
            if last.wrapping_sub(step) as i32 >= 0 {
                break;
            }
            k = k.wrapping_add(1);
        }
        k
    }

    /// The slot of the last segment pushed.
    #[inline(always)]
    pub(super) fn last_slot(&mut self) -> &mut SlotInfo {
        &mut self.slots[self.segments.wrapping_sub(1) as usize % SCHEDULE_SLOTS]
    }
}
