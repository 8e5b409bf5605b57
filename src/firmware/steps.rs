//! Step output: a 16-bit timer whose channel 1 makes the STEP pulses in
//! hardware; its update interrupt consumes the core's step schedule.
//!
//! [`SCHEDULE`] is the core's lock-free `StepSchedule` (src/motion/
//! schedule.rs): the control loop fills it through `Device::control`, this
//! interrupt owns the `StepSource` that empties it, and the limit-switch
//! interrupt writes the active limits into it (`set_limits`), so a limit
//! brakes the motion here, at the next step, with 0x6085 (SPEC §8.7; the
//! "Limit brake" docs in schedule.rs).
//!
//! The channel runs in PWM mode 2 with ARR and CCR1 preloaded: each period
//! ends with a pulse of the STEP width (rising at CCR1, falling at the update
//! event) or has none (CCR1 > ARR). At every update event the interrupt
//! (1) writes DIR for the pulse that ends the period just started — so DIR
//! leads the edge by at least the set-up time, [`StepShaper`] stretches a
//! period after a reversal — and (2) preloads the next period from
//! `StepSource::advance`. Widths and set-up come from PA15/PA16 with safe
//! minimums (calc.rs). While no step is due the timer runs idle periods of
//! 100 µs and asks the source again at each: that is how the interrupt
//! starts when the control loop has queued segments (≤ 100 µs later).
//!
//! `advance` counts the step announced at the previous update event: that
//! step is already loaded into the timer and goes out at the end of the
//! period starting now, so the core's position leads the STEP pin by at
//! most one period.
//!
//! Shared state: [`STEPPER`] behind a critical section (this interrupt; the
//! control loop sets the shape), [`SCHEDULE`] lock-free (atomics only),
//! [`DIR_INVERTED`] an atomic.

use core::cell::RefCell;
use core::sync::atomic::{AtomicBool, Ordering};

use critical_section::Mutex;
use embassy_stm32::gpio::Output;
use embassy_stm32::interrupt::typelevel::Handler;
use embassy_stm32::pac::timer::vals::Ocm;
use modbus_drive::drive::io::DirectionOutput;
use modbus_drive::motion::{StepSchedule, StepSource};

use super::board;
use super::calc::{Period, Step, StepShape, StepShaper};

/// The step schedule between the control loop and this interrupt. Its
/// `const` initialiser is all zeros, so it lives in .bss and costs no flash
/// image.
static SCHEDULE: StepSchedule = StepSchedule::new();

/// The step schedule.
pub fn schedule() -> &'static StepSchedule {
    &SCHEDULE
}

/// PA11: DIR inverted (written by the control loop).
static DIR_INVERTED: AtomicBool = AtomicBool::new(false);

struct Stepper {
    shaper: StepShaper,
    source: StepSource,
    dir: Option<DirectionOutput<Output<'static>>>,
    /// Direction of the pulse preloaded for the next period.
    pulse_next: Option<bool>,
}

static STEPPER: Mutex<RefCell<Stepper>> = Mutex::new(RefCell::new(Stepper {
    shaper: StepShaper::new(StepShape::safe(board::STEP_TICK_HZ)),
    source: StepSource::new(),
    dir: None,
    pulse_next: None,
}));

/// Sets the timer up (tick `board::STEP_TICK_HZ`, PWM mode 2 on channel 1,
/// preloads, update interrupt) and starts it idle. The STEP pin is already
/// in its alternate function (`board::split`). `prescaler` is
/// `calc::step_prescaler` of the timer's clock. Returns the step schedule
/// for the control loop.
pub fn start(dir: Output<'static>, prescaler: u16) -> &'static StepSchedule {
    let t = board::STEP_TIMER;
    let idle = StepShape::safe(board::STEP_TICK_HZ).idle_ticks;
    critical_section::with(|cs| {
        STEPPER.borrow_ref_mut(cs).dir = Some(DirectionOutput { dir });
        t.cr1().modify(|w| {
            w.set_cen(false);
            w.set_arpe(true);
        });
        t.psc().write_value(prescaler);
        t.arr().write(|w| w.set_arr((idle - 1) as u16));
        t.ccr(0).write(|w| w.set_ccr(u16::MAX));
        t.ccmr_output(0).modify(|w| {
            w.set_ocm(0, Ocm::PWM_MODE2);
            w.set_ocpe(0, true);
        });
        t.ccer().modify(|w| w.set_cce(0, true));
        t.egr().write(|w| w.set_ug(true)); // load PSC/ARR/CCR1 now
        t.sr().write_value(Default::default());
        t.dier().modify(|w| w.set_uie(true));
        t.cr1().modify(|w| w.set_cen(true));
    });
    &SCHEDULE
}

/// New STEP width / DIR set-up (PA15/PA16); applies from the next step.
pub fn set_shape(shape: StepShape) {
    critical_section::with(|cs| STEPPER.borrow_ref_mut(cs).shaper.set_shape(shape));
}

/// PA11 (DIR inverted); applies from the next step.
pub fn set_dir_inverted(inverted: bool) {
    DIR_INVERTED.store(inverted, Ordering::Relaxed);
}

/// The step timer's update interrupt (priority: `PRIO_STEP`).
pub struct StepHandler;

impl Handler<board::StepIrq> for StepHandler {
    unsafe fn on_interrupt() {
        let t = board::STEP_TIMER;
        if !t.sr().read().uif() {
            return;
        }
        t.sr().modify(|w| w.set_uif(false));
        critical_section::with(|cs| on_update(&mut STEPPER.borrow_ref_mut(cs)));
    }
}

/// Constant time: one `StepSource::advance` (or none, in a long period),
/// one shaper step, a few register writes.
fn on_update(s: &mut Stepper) {
    let t = board::STEP_TIMER;
    // the period now starting was preloaded last time: DIR for its pulse
    if let (Some(forward), Some(dir)) = (s.pulse_next.take(), s.dir.as_mut()) {
        // Output is infallible; DirectionOutput applies PA11
        dir.set(forward, DIR_INVERTED.load(Ordering::Relaxed));
    }
    let Stepper { shaper, source, .. } = s;
    let Period { arr, ccr, dir } = shaper.next_period(|| {
        source.advance(&SCHEDULE).map(|n| Step {
            forward: n.forward,
            interval_ticks: n.delay_ticks,
        })
    });
    t.arr().write(|w| w.set_arr(arr));
    t.ccr(0).write(|w| w.set_ccr(ccr));
    s.pulse_next = dir;
}
