//! Step output: a 16-bit timer whose channel 1 makes the STEP pulses in
//! hardware; its update interrupt does the constant-time step work.
//!
//! The channel runs in PWM mode 2 with ARR and CCR1 preloaded: each period
//! ends with a pulse of the STEP width (rising at CCR1, falling at the update
//! event) or has none (CCR1 > ARR). At every update event the interrupt
//! (1) writes DIR for the pulse that ends the period just started — so DIR
//! leads the edge by at least the set-up time, [`StepShaper`] stretches a
//! period after a reversal — and (2) preloads the next period from the next
//! step of the schedule. Widths and set-up come from PA15/PA16 with safe
//! minimums (calc.rs).
//!
//! SEAM — the core's step schedule: [`StepFeed`] is where the step source of
//! `src/motion` (issue 3, not on main yet) plugs in. Until it does, the feed
//! never yields a step: the timer runs idle periods and STEP stays low.
//!
//! Shared state: [`STEPPER`] behind a critical section (this interrupt, the
//! limit-switch interrupt, the control loop).

use core::cell::RefCell;

use critical_section::Mutex;
use embassy_stm32::gpio::Output;
use embassy_stm32::interrupt::typelevel::Handler;
use embassy_stm32::pac::timer::vals::Ocm;

use super::board;
use super::calc::{Period, Step, StepShape, StepShaper};

/// SEAM: the core's step schedule (src/motion, issue 3). Constant-time.
pub struct StepFeed {
    /// Set by a limit stop; the core clears it by replacing the feed.
    stopped: bool,
}

impl StepFeed {
    const fn new() -> Self {
        Self { stopped: false }
    }

    /// The next step, if one is due. No motion source is wired yet (see the
    /// module docs), so there is none.
    fn next_step(&mut self) -> Option<Step> {
        if self.stopped {
            return None;
        }
        None
    }

    /// A limit switch stopped the motion (switches.rs).
    fn stop(&mut self) {
        self.stopped = true;
    }
}

struct Stepper {
    shaper: StepShaper,
    feed: StepFeed,
    dir: Option<Output<'static>>,
    /// Direction of the pulse at the end of the period now running.
    pulse_now: Option<bool>,
    /// Direction of the pulse preloaded for the next period.
    pulse_next: Option<bool>,
    /// Compare value of the period now running (CCR1 reads back the preload).
    ccr_now: u16,
    /// Steps issued, positive = forward. The core keeps the drive's position;
    /// this one is what the hardware really did, for the logs.
    position: i32,
}

static STEPPER: Mutex<RefCell<Stepper>> = Mutex::new(RefCell::new(Stepper {
    shaper: StepShaper::new(StepShape::safe(board::STEP_TICK_HZ)),
    feed: StepFeed::new(),
    dir: None,
    pulse_now: None,
    pulse_next: None,
    ccr_now: u16::MAX,
    position: 0,
}));

/// Sets the timer up (tick `board::STEP_TICK_HZ`, PWM mode 2 on channel 1,
/// preloads, update interrupt) and starts it idle. The STEP pin is already
/// in its alternate function (`board::split`).
pub fn start(dir: Output<'static>, timer_clock_hz: u32) {
    let t = board::STEP_TIMER;
    let idle = StepShape::safe(board::STEP_TICK_HZ).idle_ticks;
    critical_section::with(|cs| {
        STEPPER.borrow_ref_mut(cs).dir = Some(dir);
        t.cr1().modify(|w| {
            w.set_cen(false);
            w.set_arpe(true);
        });
        t.psc()
            .write_value((timer_clock_hz / board::STEP_TICK_HZ - 1) as u16);
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
}

/// New STEP width / DIR set-up (PA15/PA16); applies from the next step.
pub fn set_shape(shape: StepShape) {
    critical_section::with(|cs| STEPPER.borrow_ref_mut(cs).shaper.set_shape(shape));
}

/// Steps issued so far (hardware count).
pub fn position() -> i32 {
    critical_section::with(|cs| STEPPER.borrow_ref(cs).position)
}

/// Direction of the step under way, if any (for the limit interrupt).
pub fn moving_forward() -> Option<bool> {
    critical_section::with(|cs| {
        let s = STEPPER.borrow_ref(cs);
        s.pulse_now.or(s.pulse_next)
    })
}

/// Stops step output now, from the limit-switch interrupt (issue 6: without
/// waiting for the control loop). A pulse that has already started is let
/// finish (cutting it would make a runt the driver may or may not count);
/// one not yet started is suppressed by forcing the output low.
pub fn limit_stop() {
    let t = board::STEP_TIMER;
    critical_section::with(|cs| {
        let mut s = STEPPER.borrow_ref_mut(cs);
        s.feed.stop();
        s.shaper.cancel();
        if s.pulse_now.is_some() && t.cnt().read().cnt() < s.ccr_now {
            t.ccmr_output(0)
                .modify(|w| w.set_ocm(0, Ocm::FORCE_INACTIVE));
            s.pulse_now = None;
        }
        s.pulse_next = None;
        t.ccr(0).write(|w| w.set_ccr(u16::MAX)); // next period: no pulse
    });
}

/// The step timer's update interrupt (priority: `board::PRIO_STEP`).
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

/// Constant time: one shaper step, a few register writes.
fn on_update(s: &mut Stepper) {
    let t = board::STEP_TIMER;
    // the pulse of the period that just ended has fallen: count it
    if let Some(forward) = s.pulse_now.take() {
        s.position = s.position.wrapping_add(if forward { 1 } else { -1 });
    }
    // the period now starting was preloaded last time
    s.pulse_now = s.pulse_next.take();
    s.ccr_now = t.ccr(0).read().ccr();
    if let Some(forward) = s.pulse_now {
        if let Some(dir) = s.dir.as_mut() {
            dir.set_level(forward.into());
        }
    }
    if t.ccmr_output(0).read().ocm(0) == Ocm::FORCE_INACTIVE {
        // after a limit stop: this period carries no pulse, PWM can resume
        t.ccmr_output(0).modify(|w| w.set_ocm(0, Ocm::PWM_MODE2));
    }
    let Stepper { shaper, feed, .. } = s;
    let Period { arr, ccr, dir } = shaper.next_period(|| feed.next_step());
    t.arr().write(|w| w.set_arr(arr));
    t.ccr(0).write(|w| w.set_ccr(ccr));
    s.pulse_next = dir;
}
