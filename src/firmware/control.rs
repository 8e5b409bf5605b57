//! The control loop: a 1 kHz task that samples the switches, runs the core's
//! control step and drives ENABLE / BRAKE from the power state (SPEC §8.1);
//! it also logs state transitions, faults and limit stops.
//!
//! SEAM — the core's control entry (issue 3: planner refill, homing,
//! communication-loss timer) is not on main yet; once it is, it is called
//! where marked below with `now_us` and the debounced switch states.

use core::sync::atomic::Ordering;

use embassy_stm32::gpio::Output;
use embassy_time::{Duration, Instant, Ticker};
use modbus_drive::dictionary::DriveLayer;

use super::board;
use super::calc::{power_outputs, power_state_name, Debounce, StepShape};
use super::dispatch::with_device;
use super::steps;
use super::switches::{self, SwitchStates, LIMIT_STOPS};

/// Control loop period: 1 kHz.
pub const CONTROL_PERIOD: Duration = Duration::from_micros(1000);

/// ENABLE (high = power stage on) and BRAKE (high = brake released).
pub struct PowerPins {
    pub enable: Output<'static>,
    pub brake: Output<'static>,
}

struct Debounced {
    cw: Debounce,
    ccw: Debounce,
    home: Debounce,
}

impl Debounced {
    fn new(s: SwitchStates) -> Self {
        Self {
            cw: Debounce::new(s.cw_limit),
            ccw: Debounce::new(s.ccw_limit),
            home: Debounce::new(s.home),
        }
    }

    /// One sample of all three; the stable states and whether any changed.
    fn sample(&mut self, raw: SwitchStates) -> (SwitchStates, bool) {
        let changed = self.cw.sample(raw.cw_limit).is_some()
            | self.ccw.sample(raw.ccw_limit).is_some()
            | self.home.sample(raw.home).is_some();
        let stable = SwitchStates {
            cw_limit: self.cw.state(),
            ccw_limit: self.ccw.state(),
            home: self.home.state(),
        };
        (stable, changed)
    }
}

pub async fn run(mut pins: PowerPins) -> ! {
    let mut ticker = Ticker::every(CONTROL_PERIOD);
    let mut debounced = Debounced::new(switches::read());
    let mut last_statusword = None;
    let mut last_error_register = 0;
    let mut last_shape = None;
    let mut limit_stops_logged = 0;
    loop {
        ticker.next().await;
        let _now_us = Instant::now().as_micros();
        let (switch_states, switches_changed) = debounced.sample(switches::read());
        if switches_changed {
            defmt::info!("switches: {}", switch_states);
        }
        let Some((statusword, error_register, polarity, limit_enable, shape)) = with_device(|d| {
            // SEAM: the core's control step, e.g.
            // d.control(_now_us, switch_states) — issue 3, not on main yet.
            (
                d.drive.statusword(),
                d.drive.error_register(),
                d.pa.switch_polarity(),
                d.pa.limit_enable(),
                StepShape::from_params(d.pa.get(15), d.pa.get(16), board::STEP_TICK_HZ),
            )
        }) else {
            continue;
        };
        switches::set_params(polarity, limit_enable);
        if last_shape != Some(shape) {
            steps::set_shape(shape);
            last_shape = Some(shape);
        }
        let out = power_outputs(statusword);
        pins.enable.set_level(out.enable.into());
        pins.brake.set_level(out.brake_released.into());

        let state = statusword & 0x6F;
        if last_statusword.map(|s| s & 0x6F) != Some(state) {
            defmt::info!(
                "state: {} (statusword {=u16:#06x}, enable {}, brake released {})",
                power_state_name(statusword),
                statusword,
                out.enable,
                out.brake_released
            );
        }
        last_statusword = Some(statusword);
        if error_register != last_error_register {
            defmt::warn!("error register 0x1001 = {=u16:#06x}", error_register);
            last_error_register = error_register;
        }
        let stops = LIMIT_STOPS.load(Ordering::Relaxed);
        if stops != limit_stops_logged {
            defmt::warn!(
                "limit stop by the switch interrupt ({} so far) at step {}",
                stops,
                steps::position()
            );
            limit_stops_logged = stops;
        }
    }
}
