//! The closed loop in the drive (SPEC §8.8): the measured position from the
//! encoder count the glue passes in, the following-error check and the
//! fault it raises.
//!
//! Positions here are in the planner's raw step frame (what
//! [`Drive::raw_position`] counts); the user frame is `raw − offset` as for
//! the commanded position. The encoder's running count, scaled with PA17 /
//! PA10, plus a base is the measured raw position. The base is chosen when
//! the encoder is taken into use (measured = commanded then) and moved when
//! operation is enabled again, so that the drive takes the measured
//! position as its actual position and the error starts from 0.

use super::{Drive, FaultCause, PowerState};
use crate::closed_loop::{CountsToSteps, Encoder, FollowingErrorMonitor, FollowingState};
use crate::dictionary::Config;

/// The closed loop's state in the drive; open loop until the glue passes an
/// encoder count in and PA17 names a resolution.
#[derive(Clone, Debug, Default)]
pub(super) struct Feedback {
    /// The glue's latest reading of the encoder counter.
    raw: Option<u16>,
    /// The encoder in use, if any.
    active: Option<Active>,
    monitor: FollowingErrorMonitor,
    /// Time of the last control call, for the time above the window.
    last_us: Option<u64>,
}

#[derive(Clone, Debug)]
struct Active {
    /// PA17, PA10 and PA18 it was set up with: a change sets it up again.
    key: (u16, u16, bool),
    encoder: Encoder,
    scale: CountsToSteps,
    /// Measured raw position = scaled count + base.
    base: i64,
    /// Measured raw position at the last control call.
    measured: i64,
}

impl Drive {
    /// The encoder timer's counter as the glue read it now (SPEC §8.8);
    /// used from the next control call on. Glue without an encoder never
    /// calls this, and the drive stays open loop whatever PA17 says.
    pub fn set_encoder_count(&mut self, raw: u16) {
        self.feedback.raw = Some(raw);
    }

    /// Whether an encoder is in use (a count was passed in and PA17 ≥ 100).
    pub fn closed_loop(&self) -> bool {
        self.feedback.active.is_some()
    }

    /// One control period of the closed loop: the measured position, the
    /// error, and the fault when the error stayed above the window for
    /// longer than the time out while operation was enabled.
    pub(super) fn update_feedback(&mut self, now_us: u64, cfg: Config<'_>) {
        let commanded = self.raw_position;
        let fb = &mut self.feedback;
        let dt_us = fb
            .last_us
            .map_or(0, |t| now_us.saturating_sub(t))
            .min(u64::from(u32::MAX)) as u32;
        fb.last_us = Some(now_us);
        fb.monitor.configure(
            cfg.od().following_error_window(),
            cfg.od().following_error_timeout(),
        );
        let Some(raw) = fb.raw else {
            return;
        };
        let pa = cfg.pa();
        let key = (
            pa.encoder_counts_per_rev(),
            pa.steps_per_rev(),
            pa.encoder_inverted(),
        );
        if fb.active.as_ref().map(|a| a.key) != Some(key) {
            // Taken into use (or its scaling changed): measured = commanded
            // from here on, as after a re-enable.
            fb.active = CountsToSteps::new(key.0, key.1).map(|scale| Active {
                key,
                encoder: Encoder::new(raw, key.2),
                scale,
                base: commanded,
                measured: commanded,
            });
        }
        let Some(a) = fb.active.as_mut() else {
            return;
        };
        let counts = a.encoder.update(raw);
        a.measured = a.scale.steps(counts).saturating_add(a.base);
        let enabled = self.state == PowerState::OperationEnabled;
        let verdict = fb.monitor.update(commanded, a.measured, dt_us, enabled);
        if verdict == FollowingState::Fault && self.fault.is_none() {
            self.enter_fault(FaultCause::FollowingError, cfg.od());
        }
    }

    /// Operation is enabled again: the measured position becomes the
    /// actual (and commanded) position, so the error starts from 0 (SPEC
    /// §8.8). The user position stays where the encoder says the motor is.
    pub(super) fn take_measured_position(&mut self) {
        if let Some(a) = self.feedback.active.as_mut() {
            let shift = self.raw_position - a.measured;
            a.base += shift;
            a.measured = self.raw_position;
            self.offset += shift;
        }
    }

    /// Fault reset: the following-error latch goes.
    pub(super) fn reset_following_error(&mut self) {
        self.feedback.monitor.reset();
    }

    /// Statusword bit 13 in every mode while a following-error fault is
    /// latched (SPEC §8.8).
    pub(super) fn following_error_latched(&self) -> bool {
        self.feedback.monitor.is_fault()
    }

    /// 0x6064 in the user frame: measured with an encoder, else commanded.
    pub(super) fn reported_position(&self) -> i64 {
        match &self.feedback.active {
            Some(a) => a.measured - self.offset,
            None => self.user_position(),
        }
    }

    /// 0x60F4, DP-EPo / DP-EPo.: commanded − measured, 0 open loop.
    pub(super) fn following_error_steps(&self) -> i32 {
        if self.feedback.active.is_some() {
            self.feedback.monitor.error_i32()
        } else {
            0
        }
    }
}
