//! The following-error check (CiA 402 0x6065 window, 0x6066 time out).

/// 0x6065 value that switches the check off (the CiA 402 convention and the
/// default, so the drive stays open loop until a window is written).
pub const WINDOW_OFF: u32 = u32::MAX;

/// What the check says after a control period.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FollowingState {
    /// The error is within the window, the check is off, or the drive is
    /// not in operation enabled.
    Within,
    /// Above the window, for no longer than the time out so far.
    Above,
    /// Above the window for longer than the time out: the drive must stop
    /// with the quick stop deceleration and fault (statusword bit 13,
    /// 0x1001 bit 5). Stays until [`FollowingErrorMonitor::reset`].
    Fault,
}

/// Compares the commanded with the measured position every control period.
///
/// The time above the window adds up the control periods passed in (no
/// clock here); any period within the window starts it again. "Longer than
/// the time out" is strict: with a time out of 0 the first period above the
/// window faults, with 10 ms and a 1 ms period the eleventh in a row.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FollowingErrorMonitor {
    window: u32,
    timeout_ms: u16,
    above_us: u32,
    error: i64,
    fault: bool,
}

impl Default for FollowingErrorMonitor {
    /// Off (window [`WINDOW_OFF`], time out 0: SPEC §8.8's defaults).
    fn default() -> Self {
        Self::new(WINDOW_OFF, 0)
    }
}

impl FollowingErrorMonitor {
    /// `window` in steps (0x6065), `timeout_ms` (0x6066).
    pub const fn new(window: u32, timeout_ms: u16) -> Self {
        Self {
            window,
            timeout_ms,
            above_us: 0,
            error: 0,
            fault: false,
        }
    }

    /// Takes a new window and time out (a master's write), in force from
    /// the next [`update`](Self::update); the time already above the window
    /// counts against the new time out.
    pub fn configure(&mut self, window: u32, timeout_ms: u16) {
        self.window = window;
        self.timeout_ms = timeout_ms;
    }

    /// One control period: `commanded` and `measured` positions in steps,
    /// `dt_us` since the last call, `enabled` = operation enabled (the check
    /// only runs there; the error is computed always, for the monitor).
    pub fn update(
        &mut self,
        commanded: i64,
        measured: i64,
        dt_us: u32,
        enabled: bool,
    ) -> FollowingState {
        self.error = commanded.saturating_sub(measured);
        if self.fault {
            return FollowingState::Fault;
        }
        if !enabled
            || self.window == WINDOW_OFF
            || self.error.unsigned_abs() <= u64::from(self.window)
        {
            self.above_us = 0;
            return FollowingState::Within;
        }
        self.above_us = self.above_us.saturating_add(dt_us);
        if self.above_us > u32::from(self.timeout_ms) * 1000 {
            self.fault = true;
            FollowingState::Fault
        } else {
            FollowingState::Above
        }
    }

    /// Commanded − measured at the last update, in steps.
    pub const fn error(&self) -> i64 {
        self.error
    }

    /// The error as 0x60F4 and DP-EPo / DP-EPo. show it (I32, saturated).
    pub fn error_i32(&self) -> i32 {
        self.error.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32
    }

    /// Whether a following-error fault is latched.
    pub const fn is_fault(&self) -> bool {
        self.fault
    }

    /// Whether the check is off (window [`WINDOW_OFF`]).
    pub const fn is_off(&self) -> bool {
        self.window == WINDOW_OFF
    }

    /// Fault reset: clears the latch and the time above the window.
    pub fn reset(&mut self) {
        self.fault = false;
        self.above_us = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u32 = 1000;

    #[test]
    fn off_by_default_whatever_the_error() {
        let mut m = FollowingErrorMonitor::default();
        assert!(m.is_off());
        for _ in 0..10_000 {
            assert_eq!(m.update(1_000_000, 0, MS, true), FollowingState::Within);
        }
        assert_eq!(m.error(), 1_000_000);
        assert!(!m.is_fault());
    }

    #[test]
    fn faults_only_after_more_than_the_time_out() {
        let mut m = FollowingErrorMonitor::new(100, 10);
        for _ in 0..10 {
            assert_eq!(m.update(101, 0, MS, true), FollowingState::Above);
        }
        assert_eq!(m.update(101, 0, MS, true), FollowingState::Fault);
        assert!(m.is_fault());
        // latched, even with the error gone
        assert_eq!(m.update(0, 0, MS, true), FollowingState::Fault);
    }

    #[test]
    fn the_window_itself_is_within_in_both_directions() {
        let mut m = FollowingErrorMonitor::new(100, 0);
        assert_eq!(m.update(100, 0, MS, true), FollowingState::Within);
        assert_eq!(m.update(0, 100, MS, true), FollowingState::Within);
        assert_eq!(m.error(), -100);
        assert_eq!(m.update(0, 101, MS, true), FollowingState::Fault);
    }

    #[test]
    fn a_period_within_the_window_starts_the_time_again() {
        let mut m = FollowingErrorMonitor::new(50, 5);
        for _ in 0..3 {
            for _ in 0..5 {
                assert_eq!(m.update(60, 0, MS, true), FollowingState::Above);
            }
            assert_eq!(m.update(40, 0, MS, true), FollowingState::Within);
        }
        assert!(!m.is_fault());
    }

    #[test]
    fn only_checked_while_operation_is_enabled() {
        let mut m = FollowingErrorMonitor::new(10, 0);
        assert_eq!(m.update(500, 0, MS, false), FollowingState::Within);
        assert_eq!(m.error(), 500);
        // disabling in between starts the time again
        let mut m = FollowingErrorMonitor::new(10, 2);
        assert_eq!(m.update(500, 0, MS, true), FollowingState::Above);
        assert_eq!(m.update(500, 0, MS, true), FollowingState::Above);
        assert_eq!(m.update(500, 0, MS, false), FollowingState::Within);
        assert_eq!(m.update(500, 0, MS, true), FollowingState::Above);
    }

    #[test]
    fn reset_clears_the_fault_and_the_time() {
        let mut m = FollowingErrorMonitor::new(10, 1);
        m.update(20, 0, MS, true);
        assert_eq!(m.update(20, 0, MS, true), FollowingState::Fault);
        m.reset();
        assert!(!m.is_fault());
        assert_eq!(m.update(20, 0, MS, true), FollowingState::Above);
        assert_eq!(m.update(0, 0, MS, true), FollowingState::Within);
    }

    #[test]
    fn a_new_time_out_counts_the_time_already_above() {
        let mut m = FollowingErrorMonitor::new(10, 100);
        for _ in 0..5 {
            m.update(20, 0, MS, true);
        }
        m.configure(10, 4);
        assert_eq!(m.update(20, 0, MS, true), FollowingState::Fault);
        let mut m = FollowingErrorMonitor::new(10, 100);
        m.update(20, 0, MS, true);
        m.configure(WINDOW_OFF, 0);
        assert_eq!(m.update(20, 0, MS, true), FollowingState::Within);
    }

    #[test]
    fn the_shown_error_saturates() {
        let mut m = FollowingErrorMonitor::default();
        m.update(i64::MAX, i64::MIN, MS, true);
        assert_eq!(m.error(), i64::MAX);
        assert_eq!(m.error_i32(), i32::MAX);
        m.update(i64::from(i32::MIN) - 5, 0, MS, true);
        assert_eq!(m.error_i32(), i32::MIN);
    }
}
