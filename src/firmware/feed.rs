//! The step engine's step feed: the core's `StepSource` on the schedule,
//! each step's DIR level under PA11, and every step given to the timer
//! kept in the refill's `StepLedger`; and the refill's writing of a buffer
//! half through it (`fill_half`). HAL-free, so `tests/firmware_calc.rs`
//! includes it by path and runs the refill's own feed on the host.

use modbus_drive::motion::burst::{Burst, BurstWriter, StepFeed};
use modbus_drive::motion::{StepSchedule, StepSource};

use super::calc::StepLedger;

/// One refill's [`StepFeed`]. Its plain steps skip the ledger's per-step
/// work (they are in the direction of the step before them): they are
/// counted, and the count goes to the ledger before the next other step
/// and when the feed is dropped, which also has the ledger look at the
/// newest run's length (`StepLedger::check_long`).
pub struct EngineFeed<'a> {
    source: &'a mut StepSource,
    sched: &'a StepSchedule,
    ledger: &'a mut StepLedger,
    inverted: bool,
    /// Plain steps may be given: the writer's DIR level is this feed's
    /// for the pending step (PA11 as at the refill before, or a step has
    /// gone through [`StepFeed::next_step`] since).
    plain: bool,
    plain_steps: u16,
}

impl<'a> EngineFeed<'a> {
    /// DIR is `forward != inverted` (PA11); `inverted_before` is PA11 as
    /// the refill before this one applied it.
    pub fn new(
        source: &'a mut StepSource,
        sched: &'a StepSchedule,
        ledger: &'a mut StepLedger,
        inverted: bool,
        inverted_before: bool,
    ) -> Self {
        Self {
            source,
            sched,
            ledger,
            inverted,
            plain: inverted == inverted_before,
            plain_steps: 0,
        }
    }

    fn settle(&mut self) {
        self.ledger.advanced_plain(self.plain_steps);
        self.plain_steps = 0;
    }
}

impl StepFeed for EngineFeed<'_> {
    fn next_step(&mut self) -> Option<(u32, bool)> {
        self.settle();
        self.plain = true;
        let step = self.source.advance(self.sched);
        self.ledger.advanced(step.map(|n| n.forward()));
        step.map(|n| (n.delay_ticks(), n.forward() != self.inverted))
    }

    #[inline(always)]
    fn plain_step(&mut self) -> Option<u32> {
        if !self.plain {
            return None;
        }
        let delay = self.source.advance_plain(self.sched)?;
        self.plain_steps = self.plain_steps.wrapping_add(1);
        Some(delay)
    }

    #[inline(always)]
    fn run(&mut self, delay: u32, max: impl FnOnce() -> u32) -> u32 {
        let taken = self.source.advance_run(self.sched, delay, max);
        self.plain_steps = self.plain_steps.wrapping_add(taken as u16);
        taken
    }
}

impl Drop for EngineFeed<'_> {
    fn drop(&mut self) {
        self.settle();
        self.ledger.check_long();
    }
}

/// Writes one buffer half for the refill: the whole runs of a cruise that
/// goes on, copied (`BurstWriter::fill_runs`, the noted run of the
/// schedule: `StepSource::advance_whole_runs`), while PA11 is as the
/// refill before applied it; then the rest through an [`EngineFeed`]. The
/// pulses written.
#[inline(always)]
pub fn fill_half(
    writer: &mut BurstWriter,
    half: &mut [Burst],
    source: &mut StepSource,
    sched: &StepSchedule,
    ledger: &mut StepLedger,
    inverted: bool,
    inverted_before: bool,
) -> u32 {
    let (copied, runs_pulses) = if inverted == inverted_before {
        writer.fill_runs(half, |delay, per, entries| {
            source.advance_whole_runs(sched, delay, per, entries)
        })
    } else {
        (0, 0)
    };
    // the runs' steps are plain steps of the pending run (at most a half
    // of entries of 256 periods each: no wrap of the ledger's count)
    ledger.advanced_plain(runs_pulses as u16);
    let mut feed = EngineFeed::new(source, sched, ledger, inverted, inverted_before);
    runs_pulses + writer.fill(&mut half[copied..], &mut feed)
}
