//! The control loop: a 1 kHz task that reads and debounces the switches,
//! runs the core's control step (`Device::control`: goals to the planner,
//! the step schedule refilled, homing, limits, the communication-loss timer,
//! SPEC §8), drives ENABLE / BRAKE from the power state (§8.1) through the
//! core's `drive::io::PowerOutputs`, passes PA11/PA13/PA14/PA15/PA16 on to
//! the interrupts and logs what the core reports (state transitions,
//! faults, limit stops, homing).
//!
//! `Device::control` wants to be called at least every millisecond, after
//! each frame and at switch edges; here it runs every millisecond only, so a
//! frame's set-point reaches the planner ≤ 1 ms after its reply, and the
//! debounced switch states come 2–3 ms after their edges — with the step
//! count latched at each edge (switches.rs), which the core takes as the
//! homing origin (`Device::control_latched`, SPEC §8.6; docs/firmware.md).
//! Limits do not wait for this loop (switches.rs).
//!
//! Each tick feeds the independent watchdog if the other long-lived tasks
//! have checked in: the loop, not an interrupt, so that a thread that hangs
//! (or an executor that no longer runs this task) resets the chip
//! (fault.rs). It passes PA23 to the fault path, which holds ENABLE that
//! long while the brake engages.

use core::task::Poll;

use embassy_stm32::gpio::Output;
use embassy_time::{Duration, Instant, Ticker};
use modbus_drive::drive::io::PowerOutputs;
use modbus_drive::motion::{PushedSteps, StepSchedule, StepSink};

use super::board;
use super::calc::StepShape;
use super::dispatch::{with_device, EventLog};
use super::encoder::EncoderInput;
use super::fault::{self, Watchdog};
use super::rx_slots;
use super::steps;
use super::switches;

/// Control loop period: the core's (`Device::poll_at` comes one period
/// after each call, so a ticker at this period is never late).
pub const CONTROL_PERIOD: Duration = Duration::from_micros(modbus_drive::device::CONTROL_PERIOD_US);

/// Steps one part of the control call may push into the schedule
/// (`PlannerConfig::with_fill_budget`): the longest a frame that closes
/// during the control call waits for the thread is one part, not the call
/// (docs/firmware.md, "Reply latency while stepping"). As much as a fit
/// counts (`motion::FIT_COST`): a part of steps then takes about as long
/// as a part that fits a segment, and smaller parts would not shorten the
/// longest one, only repeat the fill's set-up more often.
pub const FILL_BUDGET: u32 = modbus_drive::motion::FIT_COST;

/// The fill's sink here: no exact times kept; a pause wanted while a
/// closed frame waits for the dispatcher, so that the part running when a
/// frame closes ends after the push it is in (once the queue reaches the
/// planner's lead), not at its budget.
struct FrameWaits;

impl StepSink for FrameWaits {
    #[inline(always)]
    fn pushed(&mut self, _: &PushedSteps) {}

    #[inline(always)]
    fn pause_wanted(&mut self) -> bool {
        rx_slots::frame_waiting()
    }
}

/// ENABLE (high = power stage on) and BRAKE (high = brake released).
pub type PowerPins = PowerOutputs<Output<'static>, Output<'static>>;

pub async fn run(
    mut pins: PowerPins,
    schedule: &'static StepSchedule,
    watchdog: Watchdog,
    mut encoder: EncoderInput,
) -> ! {
    let mut ticker = Ticker::every(CONTROL_PERIOD);
    let mut log = EventLog::new();
    // PA15 / PA16 as last applied: the shape (a few divisions) is computed
    // only when they change
    let mut last_shape = None;
    let mut pins_ok = true;
    let mut late_refills = 0;
    // PA17 > 0 as last seen: the encoder timer starts the period after
    let mut encoder_wanted = false;
    loop {
        ticker.next().await;
        // a frame that closed with this tick's wake-up goes first: the
        // executor polls this task before the dispatcher in that batch
        in_parts(&mut || false).await;
        #[cfg(feature = "fault-test")]
        if super::fault::control_stuck() {
            core::future::pending::<()>().await; // stuck on purpose
        }
        watchdog.feed();
        let now_us = Instant::now().as_micros();
        let (switch_states, edges, switches_changed) = switches::sample();
        if switches_changed {
            defmt::info!("switches: {}", switch_states);
        }
        let count = encoder.read(encoder_wanted);
        steps::publish_pin_lag();
        // The control call in parts (the planner's fill budget, main.rs):
        // a frame that closes meanwhile waits for one part, not the call.
        let mut call = Some((count, switch_states, edges));
        in_parts(&mut || {
            with_device(|d| {
                match call.take() {
                    Some((count, switch_states, edges)) => {
                        if let Some(c) = count {
                            d.set_encoder_count(c);
                        }
                        encoder_wanted = d.params().encoder_counts_per_rev() > 0;
                        d.begin_control_latched(now_us, switch_states, edges, schedule);
                    }
                    None => d.top_up_with(schedule, &mut FrameWaits),
                }
                d.fill_paused()
            })
            .unwrap_or(false)
        })
        .await;
        let Some((outputs, params, shape, engage_ms)) = with_device(|d| {
            (
                d.drive().outputs(),
                (
                    d.params().direction_inverted(),
                    d.params().switch_polarity(),
                    d.params().limit_enable(),
                ),
                (d.params().step_pulse_ns(), d.params().dir_setup()),
                d.params().brake_engage_ms(),
            )
        }) else {
            continue;
        };
        fault::set_brake_engage_ms(engage_ms);
        if pins.apply(outputs) != pins_ok {
            pins_ok = !pins_ok;
            if !pins_ok {
                defmt::error!("ENABLE / BRAKE pin refused a level");
            }
        }
        let (dir_inverted, polarity, limit_enable) = params;
        steps::set_dir_inverted(dir_inverted);
        switches::set_params(polarity, limit_enable);
        if last_shape != Some(shape) {
            let (pulse, dir_setup) = shape;
            steps::set_shape(StepShape::from_params(
                pulse,
                dir_setup,
                board::STEP_TICK_HZ,
            ));
            last_shape = Some(shape);
        }
        log.drain(); // state transitions, faults, limit stops, homing
        let late = steps::late_refills();
        if late > late_refills {
            late_refills = late;
            defmt::warn!(
                "step engine: {=u32} refill(s) came a buffer half late",
                late
            );
        }
    }
}

/// Makes the control call's parts (`f` makes one and says whether another
/// is due), back to back within one poll of this task while no closed
/// frame waits for the dispatcher (`rx_slots::frame_waiting`). With one
/// waiting, at the start or at the end of a part, this task passes its
/// turn until the dispatcher has taken the frame up: embassy's executor
/// runs each batch of woken tasks in the reverse order of their wake-ups,
/// so this task, queued after the dispatcher, comes first in the next
/// batch and passes once more, and the dispatcher runs in that batch. Two
/// passes a part at most: the dispatcher may still be busy with the reply
/// before (a master that does not wait for it). A frame thus waits for one
/// part at most, and an idle bus costs no executor round. Not generic,
/// one copy: `f` is called through a pointer.
async fn in_parts(f: &mut dyn FnMut() -> bool) {
    let mut passes = 0;
    core::future::poll_fn(|cx| loop {
        if passes < 2 && rx_slots::frame_waiting() {
            passes += 1;
            cx.waker().wake_by_ref();
            return Poll::Pending;
        }
        passes = 0;
        if !f() {
            return Poll::Ready(());
        }
    })
    .await
}
