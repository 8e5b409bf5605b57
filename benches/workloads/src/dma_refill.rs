//! The refill side of the timer + DMA step engine (docs/firmware.md, "Step
//! engine by timer and DMA"), simulated in the glue's rhythm: the planner
//! fills the schedule every control period, and each time the DMA has
//! read one half of a circular buffer of timer entries, the half-transfer
//! (or transfer-complete) interrupt writes that half again with
//! `BurstWriter::fill` from `StepSource::advance`. What the bench times is
//! that refill: the CPU's whole share of the pulses once the hardware
//! makes them, per step.

use modbus_drive::motion::burst::{Burst, BurstWriter, PulseShape, StepFeed};
use modbus_drive::motion::{Fill, Goal, Planner, Ramp, StepSchedule, StepSource};

use crate::{dither, CONTROL_PERIOD_US};

/// Entries in one half of the circular buffer.
pub const HALF_ENTRIES: usize = 16;
/// STEP width, DIR set-up and idle entry at the planner's 10 MHz tick:
/// 2.5 µs, 5 µs, 100 µs (the firmware's safe minimums and idle period).
const SHAPE: (u32, u32, u32) = (25, 50, 1_000);

/// Counts of one simulated move by the refill side.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RefillCost {
    /// Pulses written into the entries.
    pub pulses: u32,
    /// Position the step source ended at.
    pub final_position: i32,
    /// Steps whose pulse could not keep its delay (the writer's count).
    pub late: u32,
    pub refill_calls: u32,
    pub refill_clock: u32,
}

/// The refill's steps as the firmware's feed (src/firmware/feed.rs) gives
/// them, less its pin-position ledger: plain steps straight from the ring
/// (`StepSource::advance_plain`) with their runs of equal delays
/// (`StepSource::advance_run`), the rest through `advance`.
struct Feed<'a> {
    src: &'a mut StepSource,
    sched: &'a StepSchedule,
}

impl StepFeed for Feed<'_> {
    fn next_step(&mut self) -> Option<(u32, bool)> {
        self.src
            .advance(self.sched)
            .map(|n| (n.delay_ticks(), n.forward()))
    }

    fn plain_step(&mut self) -> Option<u32> {
        self.src.advance_plain(self.sched)
    }

    fn run(&mut self, delay: u32, max: impl FnOnce() -> u32) -> u32 {
        self.src.advance_run(self.sched, delay, max)
    }
}

/// One half-buffer refill (out of line, so the M4 bench can time it).
#[inline(never)]
pub fn timed_refill(
    w: &mut BurstWriter,
    half: &mut [Burst],
    src: &mut StepSource,
    sched: &StepSchedule,
) -> u32 {
    w.fill(half, &mut Feed { src, sched })
}

fn duration(half: &[Burst]) -> u64 {
    half.iter().map(|b| u64::from(b.ticks())).sum()
}

/// A move to `target` at `ramp` from rest: every control period the
/// planner fills the schedule; every time the DMA finishes a half (the
/// entries' own lengths decide when) that half is refilled. `clock` is
/// read around every refill (a down-counter, as in `simulate_move`).
pub fn simulate_dma_move(target: i64, ramp: Ramp, clock: fn() -> u32) -> RefillCost {
    let cfg = crate::bench_config();
    let ticks_per_us = u64::from(cfg.tick_hz() / 1_000_000);
    let mut planner = Planner::new(cfg);
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    let mut writer = BurstWriter::new(PulseShape::new(SHAPE.0, SHAPE.1, SHAPE.2), true);
    let mut buf = [[Burst::default(); HALF_ENTRIES]; 2];
    let mut cost = RefillCost::default();
    planner.set_goal(Goal::Move {
        target,
        ramp,
        end_velocity: 0,
    });
    // both halves written before the DMA starts (from rest: idle entries)
    for half in buf.iter_mut() {
        writer.fill(half, &mut || None);
    }
    let mut dur = [duration(&buf[0]), duration(&buf[1])];
    // the DMA reads half 0 from tick 0; its end is the first refill
    let mut refill_at = dur[0];
    let mut next_half = 0;
    let mut now_us: u64 = 0;
    for _ in 0..100_000 {
        let fill = planner.fill(now_us, &sched);
        let period_end = (now_us + CONTROL_PERIOD_US) * ticks_per_us;
        while refill_at < period_end {
            let t0 = clock();
            cost.pulses += timed_refill(&mut writer, &mut buf[next_half], &mut src, &sched);
            cost.refill_clock = cost
                .refill_clock
                .wrapping_add(t0.wrapping_sub(clock()) & 0x00FF_FFFF);
            cost.refill_calls += 1;
            dither(cost.refill_calls);
            dur[next_half] = duration(&buf[next_half]);
            // the DMA now reads the other half, written earlier
            next_half ^= 1;
            refill_at += dur[next_half];
        }
        now_us += CONTROL_PERIOD_US;
        if matches!(fill, Fill::Idle) && sched.is_empty() && !writer.busy() {
            break;
        }
    }
    cost.final_position = sched.position();
    cost.late = writer.late();
    cost
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{MOVE_RAMP, RAMP_MOVE_STEPS, SEED_MOVE_STEPS, SEED_RAMP};

    #[test]
    fn the_refills_write_one_pulse_per_step_of_the_move_and_none_late() {
        for (steps, ramp) in [(RAMP_MOVE_STEPS, MOVE_RAMP), (SEED_MOVE_STEPS, SEED_RAMP)] {
            let c = simulate_dma_move(i64::from(steps), ramp, || 0);
            assert_eq!(c.final_position, steps as i32);
            assert_eq!(c.pulses, steps);
            assert_eq!(c.late, 0, "the buffer keeps ahead of the pulses");
        }
    }
}
