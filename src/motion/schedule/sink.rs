//! The hook through which a push reports its steps' exact times: the
//! firmware passes `()`, which records nothing and compiles to nothing;
//! the simulation (`motion::sim::SimAxis`, feature `sim`) keeps the exact time of
//! every step in its own storage, so that the schedule has one layout on
//! every target (module docs of the schedule).

use super::segment::{Expansion, Segment};

/// Told of every push ([`super::StepSchedule::push_steps`]) before its
/// entries are written.
pub trait StepSink {
    fn pushed(&mut self, steps: &PushedSteps);
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
