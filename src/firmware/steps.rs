//! Step output: a 16-bit timer whose channel 1 makes the STEP pulses in
//! hardware; its update interrupt consumes the core's step schedule.
//!
//! [`SCHEDULE`] is the core's lock-free `StepSchedule`
//! (src/motion/schedule/mod.rs): the control loop fills it through `Device::control`, this
//! interrupt owns the `StepSource` that empties it, and the limit-switch
//! interrupt writes the active limits into it (`set_limits`), so a limit
//! brakes the motion here, at the next step, with 0x6085 (SPEC §8.7; the
//! "Limit brake" docs in motion/schedule/mod.rs).
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
//! starts when the control loop has queued segments (≤ 100 µs later). A
//! step found at such an update event is due its interval from there; the
//! idle period already preloaded runs first and counts towards it
//! (`StepShaper`), so a queue that runs dry for a moment — the control loop
//! has not queued the next step yet when the interrupt asks for it, one
//! period ahead — costs no time.
//!
//! `advance` counts the step announced at the previous update event: that
//! step is already loaded into the timer and goes out at the end of the
//! period starting now, so the core's position leads the STEP pin by at
//! most one period.
//!
//! Shared state, none of it behind a lock (priority.rs: nothing masks this
//! interrupt): [`SCHEDULE`] lock-free (atomics only), [`STEPPER`] owned by
//! this interrupt alone (set up before it is enabled), the STEP width / DIR
//! set-up and PA11 handed over in atomics ([`set_shape`],
//! [`set_dir_inverted`]) and taken at the next update event.
//!
//! DIR: [`start`] writes it for the positive direction, which is what the
//! shaper assumes of the first step; a PA11 change flips the pin's meaning,
//! so the interrupt then tells the shaper the pin now stands for the other
//! direction, and the next step gets the set-up stretch of a reversal.

use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use embassy_stm32::gpio::Output;
use embassy_stm32::interrupt::typelevel::Handler;
use embassy_stm32::pac::timer::vals::Ocm;
use modbus_drive::drive::io::DirectionOutput;
use modbus_drive::motion::{StepSchedule, StepSource};

use super::board;
use super::calc::{Period, Step, StepShape, StepShaper};
use super::owned::IrqOwned;

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
/// STEP width and DIR set-up in ticks, packed (`StepShape::packed`).
static SHAPE: AtomicU32 = AtomicU32::new(0);

struct Stepper {
    shaper: StepShaper,
    source: StepSource,
    dir: Option<DirectionOutput<Output<'static>>>,
    /// PA11 as the pin levels in the timer were computed with.
    inverted: bool,
    /// Shape last taken from [`SHAPE`].
    shape: u32,
    /// DIR level for the pulse preloaded for the next period.
    pulse_next: Option<bool>,
}

/// Owned by the step interrupt once it is enabled (`start` fills it before).
static STEPPER: IrqOwned<Stepper> = IrqOwned::new(Stepper {
    shaper: StepShaper::new(StepShape::safe(board::STEP_TICK_HZ)),
    source: StepSource::new(),
    dir: None,
    inverted: false,
    shape: 0,
    pulse_next: None,
});

/// Sets the timer up (tick `board::STEP_TICK_HZ`, PWM mode 2 on channel 1,
/// preloads, update interrupt) and starts it idle, DIR set for the positive
/// direction under PA11 = `dir_inverted`. The STEP pin is already in its
/// alternate function (`board::split`). `prescaler` is
/// `calc::step_prescaler` of the timer's clock. Returns the step schedule
/// for the control loop. Call it before the step interrupt is enabled.
pub fn start(dir: Output<'static>, prescaler: u16, dir_inverted: bool) -> &'static StepSchedule {
    let t = board::STEP_TIMER;
    let shape = StepShape::safe(board::STEP_TICK_HZ);
    DIR_INVERTED.store(dir_inverted, Ordering::Relaxed);
    SHAPE.store(shape.packed(), Ordering::Relaxed);
    // SAFETY: the step interrupt is not enabled yet: nothing else runs on it.
    let s = unsafe { STEPPER.get() };
    let mut dir = DirectionOutput::new(dir);
    // the shaper starts out assuming the last step went forward
    dir.set(true, dir_inverted);
    s.dir = Some(dir);
    s.inverted = dir_inverted;
    s.shape = shape.packed();
    t.cr1().modify(|w| {
        w.set_cen(false);
        w.set_arpe(true);
    });
    t.psc().write_value(prescaler);
    t.arr().write(|w| w.set_arr((shape.idle_ticks - 1) as u16));
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
    &SCHEDULE
}

/// New STEP width / DIR set-up (PA15/PA16); applies from the next step.
pub fn set_shape(shape: StepShape) {
    SHAPE.store(shape.packed(), Ordering::Relaxed);
}

/// PA11 (DIR inverted); applies from the next step.
pub fn set_dir_inverted(inverted: bool) {
    DIR_INVERTED.store(inverted, Ordering::Relaxed);
}

/// Nothing is queued and no step is under way: flash work may start
/// (SPEC §9). Only the control loop fills the schedule, and it cannot run
/// while the dispatcher does flash work, so this stays true through it.
pub fn idle() -> bool {
    SCHEDULE.is_empty() && !SCHEDULE.is_running()
}

/// The latest this interrupt has started after its update event, in timer
/// ticks (the counter at entry): its measured worst-case latency, which the
/// DIR set-up stretch assumes below `calc::ISR_LATENCY_NS`.
static WORST_ENTRY_TICKS: AtomicU32 = AtomicU32::new(0);

/// [`WORST_ENTRY_TICKS`] (for the control loop's log).
pub fn worst_entry_ticks() -> u32 {
    WORST_ENTRY_TICKS.load(Ordering::Relaxed)
}

/// The step timer's update interrupt (priority: `PRIO_STEP`).
pub struct StepHandler;

impl Handler<board::StepIrq> for StepHandler {
    unsafe fn on_interrupt() {
        let t = board::STEP_TIMER;
        // the counter restarted at the update event: it is how late we are
        let late = u32::from(t.cnt().read().cnt());
        if !t.sr().read().uif() {
            return;
        }
        t.sr().modify(|w| w.set_uif(false));
        WORST_ENTRY_TICKS.fetch_max(late, Ordering::Relaxed);
        // SAFETY: this interrupt is the stepper's only user once enabled.
        on_update(unsafe { STEPPER.get() });
    }
}

/// Constant time: one `StepSource::advance` (or none, in a long period),
/// one shaper step, a few register writes.
fn on_update(s: &mut Stepper) {
    let t = board::STEP_TIMER;
    // the period now starting was preloaded last time: DIR for its pulse
    if let (Some(level), Some(dir)) = (s.pulse_next.take(), s.dir.as_mut()) {
        // Output is infallible; the level has PA11 applied already
        dir.set(level, false);
    }
    let inverted = DIR_INVERTED.load(Ordering::Relaxed);
    if inverted != s.inverted {
        s.inverted = inverted;
        s.shaper.dir_pin_flipped();
    }
    let shape = SHAPE.load(Ordering::Relaxed);
    if shape != s.shape {
        s.shape = shape;
        s.shaper.set_packed_shape(shape);
    }
    let Stepper { shaper, source, .. } = s;
    let Period { arr, ccr, dir } = shaper.next_period(|| {
        source.advance(&SCHEDULE).map(|n| Step {
            forward: n.forward(),
            interval_ticks: n.delay_ticks(),
        })
    });
    t.arr().write(|w| w.set_arr(arr));
    t.ccr(0).write(|w| w.set_ccr(ccr));
    s.pulse_next = dir.map(|forward| forward != s.inverted);
}
