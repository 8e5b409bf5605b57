//! Brake sequencing (PA22 / PA23): when the holding brake may be released
//! and when the power stage may drop, around the outputs SPEC §8.1 gives
//! each power state.
//!
//! With PA22 = PA23 = 0 (the defaults) the outputs are §8.1's at once. With
//! either set the drive sequences them as a servo drive does, so a vertical
//! axis never hangs on neither the brake nor the motor:
//! - the brake is released only while the power stage is on, and only
//!   PA22 ms after it came on (the power stage has built up torque); motion
//!   waits for it ([`super::Drive::control`]);
//! - when the power stage is to go off (disable, quick stop left for a
//!   state without power, fault reaction over), the brake engages at once
//!   and the power stage holds the axis PA23 ms longer (the brake's engage
//!   time), then drops.
//!
//! The tracker changes only in the control step, which has the time; a
//! read between two control calls (right after a controlword write) sees
//! the power stage as the new state wants it on (or still on, when it is to
//! go off) and the brake applied; the timing starts at the next control
//! call.

use super::Outputs;

#[derive(Clone, Copy, Debug, Default)]
pub(super) struct BrakeSequence {
    /// The power stage has been wanted on since (µs, as seen by control).
    on_since: Option<u64>,
    /// The power stage is held on until (µs): the brake engages meanwhile.
    hold_until: Option<u64>,
}

/// PA22 / PA23 as the sequence uses them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct BrakeTimes {
    /// PA22: brake release delay after the power stage is on, ms.
    pub(super) release_delay_ms: u16,
    /// PA23: brake engage time, ms: how long the power stage holds the axis
    /// after the brake was told to engage.
    pub(super) engage_ms: u16,
}

impl BrakeTimes {
    fn sequenced(self) -> bool {
        self.release_delay_ms > 0 || self.engage_ms > 0
    }
}

impl BrakeSequence {
    /// The control step at `now_us`: `power_wanted` is §8.1's power stage
    /// for the state now.
    pub(super) fn update(&mut self, power_wanted: bool, now_us: u64, t: BrakeTimes) {
        if power_wanted {
            if self.on_since.is_none() {
                self.on_since = Some(now_us);
                self.hold_until = None;
            }
        } else {
            if self.on_since.take().is_some() {
                self.hold_until = Some(now_us + u64::from(t.engage_ms) * 1000);
            }
            if self.hold_until.is_some_and(|end| now_us >= end) {
                self.hold_until = None;
            }
        }
    }

    /// The outputs at `now_us` (the last control step's time) for the §8.1
    /// outputs `spec` of the state now.
    pub(super) fn outputs(&self, spec: Outputs, now_us: u64, t: BrakeTimes) -> Outputs {
        if !t.sequenced() {
            return spec;
        }
        if spec.power_stage {
            let delay = u64::from(t.release_delay_ms) * 1000;
            Outputs {
                // on and in the hold window: it stays on
                power_stage: true,
                brake_released: self
                    .on_since
                    .is_some_and(|since| now_us.saturating_sub(since) >= delay),
            }
        } else {
            Outputs {
                // not yet seen off by control, or holding the axis
                power_stage: self.on_since.is_some()
                    || self.hold_until.is_some_and(|end| now_us < end),
                brake_released: false,
            }
        }
    }

    /// The power stage is on but the brake not yet released: no motion may
    /// start.
    pub(super) fn holding(&self, spec: Outputs, now_us: u64, t: BrakeTimes) -> bool {
        spec.power_stage && !self.outputs(spec, now_us, t).brake_released
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ON: Outputs = Outputs {
        power_stage: true,
        brake_released: true,
    };
    const OFF: Outputs = Outputs {
        power_stage: false,
        brake_released: false,
    };
    const SWITCHED_ON: Outputs = Outputs {
        power_stage: false,
        brake_released: true,
    };

    #[test]
    fn zero_times_are_the_spec_outputs() {
        let mut b = BrakeSequence::default();
        let t = BrakeTimes::default();
        for (i, spec) in [OFF, SWITCHED_ON, ON, SWITCHED_ON, OFF]
            .into_iter()
            .enumerate()
        {
            let now = i as u64 * 1000;
            b.update(spec.power_stage, now, t);
            assert_eq!(b.outputs(spec, now, t), spec);
            assert!(!b.holding(spec, now, t));
        }
    }

    #[test]
    fn release_waits_and_power_holds_for_the_engage_time() {
        let mut b = BrakeSequence::default();
        let t = BrakeTimes {
            release_delay_ms: 5,
            engage_ms: 3,
        };
        // switched on: the brake stays applied without the power stage
        b.update(false, 0, t);
        assert_eq!(b.outputs(SWITCHED_ON, 0, t), OFF);
        // not yet timed: the brake stays applied
        assert_eq!(
            b.outputs(ON, 0, t),
            Outputs {
                power_stage: true,
                brake_released: false
            }
        );
        b.update(true, 1_000, t);
        for now in [1_000, 5_999] {
            assert!(b.holding(ON, now, t), "{now}");
            assert!(!b.outputs(ON, now, t).brake_released);
        }
        assert_eq!(b.outputs(ON, 6_000, t), ON);
        assert!(!b.holding(ON, 6_000, t));
        // disable at 10 ms: brake at once, power until 13 ms
        assert_eq!(
            b.outputs(OFF, 10_000, t),
            Outputs {
                power_stage: true,
                brake_released: false
            }
        );
        b.update(false, 10_000, t);
        assert_eq!(
            b.outputs(OFF, 12_999, t),
            Outputs {
                power_stage: true,
                brake_released: false
            }
        );
        assert_eq!(b.outputs(OFF, 13_000, t), OFF);
        b.update(false, 13_000, t);
        assert_eq!(b.outputs(OFF, 20_000, t), OFF);
    }

    #[test]
    fn enable_again_while_holding_restarts_the_release_delay() {
        let mut b = BrakeSequence::default();
        let t = BrakeTimes {
            release_delay_ms: 2,
            engage_ms: 10,
        };
        b.update(true, 0, t);
        b.update(false, 5_000, t);
        b.update(true, 7_000, t);
        assert_eq!(
            b.outputs(ON, 8_000, t),
            Outputs {
                power_stage: true,
                brake_released: false
            }
        );
        assert_eq!(b.outputs(ON, 9_000, t), ON);
    }
}
