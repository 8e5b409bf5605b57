//! A simulated axis: the step interrupt, the motor and three switches, for
//! the host tests and the virtual drive (no_std, no heap, no clock).
//!
//! # API
//!
//! - [`SimAxis::new`]`(tick_hz)` then the builders
//!   [`SimAxis::with_cw_limit`]`(edge)` (active at and below `edge`: "left",
//!   negative), [`SimAxis::with_ccw_limit`]`(edge)` (active at and above),
//!   [`SimAxis::with_home`]`(from, to)` (active on `from..=to`),
//!   [`SimAxis::at`]`(position)` (physical start position, steps).
//! - [`SimAxis::run_until`]`(sched, tick, on_step)`: plays the
//!   [`StepSource`] as the step-timer interrupt would, making every step
//!   whose time is `≤ tick` and calling `on_step` with each
//!   [`StepRecord`]. It returns early, right after the step, when that step
//!   changed a switch state ([`RunStop::SwitchChanged`]) so that the caller
//!   can hand the new states to the drive at the exact step (SPEC §8.6: the
//!   origin is the step where the edge was seen).
//! - [`SimAxis::kick`]`(sched)`: what the glue does after each control call:
//!   start the idle interrupt when the schedule holds segments.
//! - [`SimAxis::with_limit_interrupt`], [`SimAxis::set_limit_enable`]`(pa14)`:
//!   the limit-switch interrupt too (the firmware's EXTI handler): the
//!   enabled limits go to [`StepSchedule::set_limits`] right after the step
//!   that changed them and at every [`SimAxis::run_until`], so the step
//!   interrupt's limit brake (SPEC §8.7) begins at the edge step, as on
//!   the board. Without it the caller plays that interrupt.
//! - The exact-time record: [`SimAxis`] is a [`StepSink`]; hand it to the
//!   push path ([`crate::Device::control_with`],
//!   [`crate::motion::Planner::fill_with`],
//!   [`StepSchedule::push_steps`]) and it keeps the exact time of every
//!   step pushed, which [`StepRecord::exact`] reports. The schedule keeps
//!   none (one layout on every target): a step whose push the axis was not
//!   told of has no exact time, and `run_until` panics on it rather than
//!   report a wrong one.
//! - [`SimAxis::switches`]: the logical switch states at the current
//!   position; [`SimAxis::position`], [`SimAxis::now_ticks`],
//!   [`SimAxis::now_us`], [`SimAxis::us_to_ticks`].
//!
//! A typical loop (see `tests/common`):
//! ```ignore
//! loop {
//!     let stop = axis.run_until(&sched, axis.us_to_ticks(next_us), |s| ...);
//!     let now = if stop == RunStop::SwitchChanged { axis.now_us() } else { next_us };
//!     device.control(now, axis.switches(), &sched);
//!     axis.kick(&sched);
//! }
//! ```

use super::schedule::{PushedSteps, StepSchedule, StepSink, StepSource, SCHEDULE_STEPS};
use super::Switches;

/// One step the simulated motor made.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StepRecord {
    /// Timer tick at which the step was made.
    tick: u64,
    /// The exact time the schedule asked for, Q32.32 ticks (wrapping).
    exact: u64,
    /// Physical position after the step.
    position: i64,
    forward: bool,
}

impl StepRecord {
    #[inline]
    pub const fn new(tick: u64, exact: u64, position: i64, forward: bool) -> Self {
        Self {
            tick,
            exact,
            position,
            forward,
        }
    }

    /// Timer tick at which the step was made.
    #[inline]
    pub const fn tick(&self) -> u64 {
        self.tick
    }

    /// The exact time the schedule asked for, Q32.32 ticks (wrapping).
    #[inline]
    pub const fn exact(&self) -> u64 {
        self.exact
    }

    /// Physical position after the step.
    #[inline]
    pub const fn position(&self) -> i64 {
        self.position
    }

    #[inline]
    pub const fn forward(&self) -> bool {
        self.forward
    }
}

/// Why [`SimAxis::run_until`] returned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunStop {
    /// Time reached `until`.
    Reached,
    /// The last step changed a switch state; time is that step's.
    SwitchChanged,
}

/// See the module docs.
#[derive(Clone, Debug)]
pub struct SimAxis {
    source: StepSource,
    tick_hz: u32,
    now: u64,
    /// Tick and direction of the step the interrupt has announced.
    next: Option<(u64, bool)>,
    position: i64,
    cw_limit: Option<i64>,
    ccw_limit: Option<i64>,
    home: Option<(i64, i64)>,
    /// The limit-switch interrupt with PA14's enable bits, if simulated.
    limit_interrupt: Option<u16>,
    /// Steps made.
    steps: u64,
    /// The exact-time record: per ring slot, the ring index (wrapping) of
    /// the step last pushed there and the fraction its time carries on
    /// ([`PushedSteps::fractions`]).
    exact: [(u32, u32); SCHEDULE_STEPS],
}

impl SimAxis {
    /// Steps made.
    #[inline]
    pub const fn steps(&self) -> u64 {
        self.steps
    }
}

/// Half a tick, Q0.32: the carried fraction of a time that falls on a tick.
const HALF_TICK: u32 = 1 << 31;

impl SimAxis {
    pub fn new(tick_hz: u32) -> Self {
        Self {
            source: StepSource::new(),
            tick_hz,
            now: 0,
            next: None,
            position: 0,
            cw_limit: None,
            ccw_limit: None,
            home: None,
            limit_interrupt: None,
            steps: 0,
            // index 1 in slot 0 and so on: no step is recorded yet
            exact: core::array::from_fn(|i| (i as u32 ^ 1, 0)),
        }
    }

    pub fn with_cw_limit(mut self, edge: i64) -> Self {
        self.cw_limit = Some(edge);
        self
    }

    pub fn with_ccw_limit(mut self, edge: i64) -> Self {
        self.ccw_limit = Some(edge);
        self
    }

    pub fn with_home(mut self, from: i64, to: i64) -> Self {
        self.home = Some((from, to));
        self
    }

    /// Simulates the limit-switch interrupt (module docs), both limits
    /// enabled (PA14's default) until [`Self::set_limit_enable`].
    pub fn with_limit_interrupt(mut self) -> Self {
        self.limit_interrupt = Some(0b11);
        self
    }

    /// PA14 (bit 0 CW, bit 1 CCW) as the limit-switch interrupt applies it;
    /// the glue passes the drive's value before each run.
    pub fn set_limit_enable(&mut self, pa14: u16) {
        if self.limit_interrupt.is_some() {
            self.limit_interrupt = Some(pa14);
        }
    }

    /// The limit-switch interrupt: the enabled limits active now.
    fn limit_interrupt(&self, sched: &StepSchedule) {
        if let Some(enable) = self.limit_interrupt {
            let s = self.switches();
            sched.set_limits(
                s.cw_limit && enable & 1 != 0,
                s.ccw_limit && enable & 2 != 0,
            );
        }
    }

    pub fn at(mut self, position: i64) -> Self {
        self.position = position;
        self
    }

    /// Physical position, steps.
    pub fn position(&self) -> i64 {
        self.position
    }

    pub fn now_ticks(&self) -> u64 {
        self.now
    }

    /// Current time in µs, rounded up (never before the last step).
    pub fn now_us(&self) -> u64 {
        (u128::from(self.now) * 1_000_000).div_ceil(u128::from(self.tick_hz)) as u64
    }

    /// The planner's conversion (rounded down).
    pub fn us_to_ticks(&self, us: u64) -> u64 {
        (u128::from(us) * u128::from(self.tick_hz) / 1_000_000) as u64
    }

    /// A step is announced on the timer.
    pub fn is_running(&self) -> bool {
        self.next.is_some()
    }

    pub fn switches(&self) -> Switches {
        let p = self.position;
        Switches::new(
            self.cw_limit.is_some_and(|e| p <= e),
            self.ccw_limit.is_some_and(|e| p >= e),
            self.home.is_some_and(|(a, b)| a <= p && p <= b),
        )
    }

    /// Starts the idle interrupt if the schedule has work (see module docs).
    pub fn kick(&mut self, sched: &StepSchedule) {
        if self.next.is_none() && !sched.is_empty() {
            let now = self.now;
            self.next = self
                .source
                .advance(sched)
                .map(|s| (now + u64::from(s.delay_ticks()), s.forward()));
        }
    }

    /// See the module docs.
    pub fn run_until(
        &mut self,
        sched: &StepSchedule,
        until: u64,
        mut on_step: impl FnMut(StepRecord),
    ) -> RunStop {
        self.limit_interrupt(sched);
        loop {
            let Some((tick, forward)) = self.next else {
                self.now = self.now.max(until);
                return RunStop::Reached;
            };
            if tick > until {
                self.now = self.now.max(until);
                return RunStop::Reached;
            }
            self.now = tick;
            let before = self.switches();
            self.position += if forward { 1 } else { -1 };
            self.steps += 1;
            on_step(StepRecord {
                tick,
                exact: (tick << 32).wrapping_add(self.rounding_q32(sched) as u64),
                position: self.position,
                forward,
            });
            self.next = self
                .source
                .advance(sched)
                .map(|s| (tick + u64::from(s.delay_ticks()), s.forward()));
            if self.switches() != before {
                self.limit_interrupt(sched);
                return RunStop::SwitchChanged;
            }
        }
    }
}

impl SimAxis {
    /// Exact time of the pending step minus the tick it is announced at
    /// (Q32.32, signed, within ±½ tick): the rounding its delay carries,
    /// from the record (or the limit brake's own fraction: its steps are
    /// no ring entries).
    fn rounding_q32(&self, sched: &StepSchedule) -> i64 {
        let frac = self.source.braking_frac().unwrap_or_else(|| {
            let index = sched.step_index();
            let (recorded, frac) = self.exact[index as usize % SCHEDULE_STEPS];
            assert_eq!(
                recorded, index,
                "step at ring index {index} pushed without the axis as sink"
            );
            frac
        });
        i64::from(frac) - i64::from(HALF_TICK)
    }
}

impl StepSink for SimAxis {
    fn pushed(&mut self, steps: &PushedSteps) {
        for (index, frac) in steps.fractions() {
            self.exact[index as usize % SCHEDULE_STEPS] = (index, frac);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::Segment;

    const ONE_TICK: u64 = 1 << 32;

    fn steps(interval: u64, count: u32) -> Segment {
        Segment::new(interval, 0, 0, 0, 0, count, true)
    }

    #[test]
    fn steps_and_switch_windows() {
        let sched = StepSchedule::new();
        let mut axis = SimAxis::new(1_000_000)
            .with_home(3, 5)
            .with_ccw_limit(8)
            .at(0);
        sched
            .push_steps(&mut steps(10 << 32, 10), 10, &mut axis)
            .unwrap();
        axis.kick(&sched);
        let mut seen = 0;
        assert_eq!(
            axis.run_until(&sched, 1000, |s| {
                seen += 1;
                assert_eq!(s.exact, s.tick << 32);
            }),
            RunStop::SwitchChanged
        );
        assert_eq!((axis.position(), axis.now_ticks()), (3, 30));
        assert!(axis.switches().home);
        assert_eq!(
            axis.run_until(&sched, 1000, |_| seen += 1),
            RunStop::SwitchChanged
        );
        assert_eq!(axis.position(), 6);
        assert!(!axis.switches().home);
        assert_eq!(
            axis.run_until(&sched, 1000, |_| seen += 1),
            RunStop::SwitchChanged
        );
        assert!(axis.switches().ccw_limit);
        assert_eq!(
            axis.run_until(&sched, 1000, |_| seen += 1),
            RunStop::Reached
        );
        assert_eq!((axis.position(), seen, sched.position()), (10, 10, 10));
        assert_eq!(axis.now_ticks(), 1000);
    }

    /// The record gives each step the exact time of its own push, across
    /// the ring's wrap.
    #[test]
    fn exact_times_come_from_the_record() {
        let sched = StepSchedule::new();
        let mut axis = SimAxis::new(1_000_000);
        let (mut made, mut starts) = (Vec::new(), Vec::new());
        // 2.25 ticks a step: the exact times fall between ticks
        let quarter = (9u64 << 32) / 4;
        for _ in 0..3 {
            starts.push(axis.now_ticks() << 32);
            sched
                .push_steps(&mut steps(quarter, 300), 300, &mut axis)
                .unwrap();
            axis.kick(&sched);
            let until = axis.now_ticks() + 1000;
            axis.run_until(&sched, until, |s| made.push(s));
        }
        assert_eq!(made.len(), 900);
        // each run from rest is timed from the kick
        for (run, t0) in made.chunks(300).zip(starts) {
            for (i, s) in run.iter().enumerate() {
                assert_eq!(s.exact - t0, (i as u64 + 1) * quarter);
                assert!(s.exact.abs_diff(s.tick << 32) <= 1 << 31);
            }
        }
    }

    /// A step whose push the axis was not told of stops the run instead of
    /// reporting a wrong time, also where the slot holds an older step's.
    #[test]
    #[should_panic(expected = "ring index 512 pushed without the axis as sink")]
    fn a_push_the_axis_was_not_told_of_has_no_exact_time() {
        let sched = StepSchedule::new();
        let mut axis = SimAxis::new(1_000_000);
        for _ in 0..2 {
            sched
                .push_steps(&mut steps(ONE_TICK, 256), 256, &mut axis)
                .unwrap();
            axis.kick(&sched);
            axis.run_until(&sched, axis.now_ticks() + 1000, |_| {});
        }
        assert_eq!(axis.position(), 512);
        sched.push(steps(ONE_TICK, 1)).unwrap();
        axis.kick(&sched);
        axis.run_until(&sched, axis.now_ticks() + 10, |_| {});
    }
}
