//! The hook beside a fill: each push reports its steps' exact times to
//! it, and the planner asks it between pushes whether the caller wants
//! its thread back. `()` records nothing, never asks and compiles to
//! nothing; the simulation (`motion::sim::SimAxis`, feature `sim`) keeps
//! the exact time of every step in its own storage, so that the schedule
//! has one layout on every target (module docs of the schedule); the
//! firmware's control loop asks for a pause while a frame waits.

use super::segment::{Expansion, Segment};

/// Told of every push ([`super::StepSchedule::push_steps`]) before its
/// entries are written.
pub trait StepSink {
    fn pushed(&mut self, steps: &PushedSteps);

    /// Asked by the planner's fill between two pushes and before a fit,
    /// once the fill has made progress: true pauses the fill there
    /// ([`crate::motion::Fill::Paused`], as at the end of its budget) if
    /// the queue already reaches a quarter of the planner's horizon past
    /// the fill's `now` (half of what a budget's pause needs: a pause is
    /// asked for only while something short waits). A fill asked at
    /// every question still pushes what it would have pushed, a push
    /// ([`crate::motion::PUSH_STEPS`] at most) a part.
    #[inline(always)]
    fn pause_wanted(&mut self) -> bool {
        false
    }
}

/// The no-op sink: the firmware's and every caller's that needs no exact
/// times.
impl StepSink for () {
    #[inline(always)]
    fn pushed(&mut self, _: &PushedSteps) {}
}

/// The steps of one push, as the push expands them.
#[derive(Clone, Copy, Debug)]
pub struct PushedSteps {
    /// The segment's terms at the first pushed step.
    pub(super) seg: Segment,
    /// The fraction carried in (module docs).
    pub(super) frac: u32,
    /// Ring indices (wrapping) of the first step and after the last.
    pub(super) from: u32,
    pub(super) to: u32,
}

impl PushedSteps {
    /// Each pushed step's ring index (wrapping) and the fraction its time
    /// carries on (Q0.32, the exact time's fraction plus half a tick: as
    /// the delays are rounded, module docs), in push order.
    pub fn fractions(&self) -> impl Iterator<Item = (u32, u32)> {
        let mut x = Expansion::of(&self.seg, (self.frac, 0));
        let from = self.from;
        (0..self.to.wrapping_sub(from)).map(move |i| {
            x.step();
            (from.wrapping_add(i), x.frac)
        })
    }
}
