//! CW limit, CCW limit and home inputs (SPEC §7 PA13/PA14, §8.6, §8.7).
//!
//! The pins are read through the core's `drive::io::SwitchInputs` (embedded-
//! hal `InputPin`, PA13 polarity: a normally open switch is active when its
//! pin is high), the same code the host doubles run.
//!
//! Every edge raises the EXTI interrupt. It clears the pending bits of all
//! its lines first, whatever their state (an edge it cannot attribute would
//! otherwise re-enter the handler for ever), reads the three pins at once
//! and hands the enabled limits (PA14) to the step schedule
//! (`StepSchedule::set_limits`): the step engine's next refill then brakes
//! any motion towards an active limit with 0x6085 (behind the entries
//! already written), without waiting for the control loop
//! (motion/schedule/mod.rs "Limit brake"; disarmed in homing, where the
//! core's sequencer decides). The control loop reads the pins
//! every millisecond too ([`sample`], which also re-sends the limits, so a
//! change of PA13/PA14 or a missed edge is caught within 1 ms) and
//! debounces them for the core ([`sample`], calc.rs `LatchedSwitch`).
//!
//! Homing origin (SPEC §8.6): at every reading that finds a switch away
//! from its debounced state, the first such reading latches the STEP pin's
//! position (`steps::read_at_pin_position`: the schedule's position less
//! the steps not yet made, which TIM3 counts); the control loop hands it
//! to the core with the debounced change (`Device::control_latched`),
//! which takes it as the origin if it lies on the current search leg. The
//! refill outranks the read (priority.rs) and may run during
//! the read; the pulse count is read before and after the pins and the
//! pins again if it changed, so position and levels belong together.
//!
//! The position is taken with the first read, never after the
//! confirmation below, during which the next pulse may rise.
//!
//! A limit brakes only when a second read of its pin [`CONFIRM_US`] after
//! the first agrees: a spike shorter than that (motor cables next to the
//! switch wiring) no longer latches a quick stop. A release needs no
//! confirmation (a brake already under way is the schedule's business).
//! The homing latch is not confirmed: a spike latches nothing lasting,
//! the control loop forgets a latch whose switch reads stable again.
//!
//! Shared state: the inputs and latches ([`INPUTS`]) belong to the EXTI
//! interrupt, and to the control loop while it has that one interrupt
//! disabled in the NVIC ([`with_inputs`]), during which it also sends the
//! limits, so the two never overwrite a newer reading with an older one.
//! No critical section: a reading at a limit (two reads and the
//! confirmation between them) would hold off every interrupt below the
//! refill, the USART's too, and while the step engine is at its busiest
//! (a limit brake at the top rate) that time stretches several times over.
//! PA13 polarity and PA14 enable bits in atomics written by the control
//! loop.

use core::sync::atomic::{AtomicU16, Ordering};

use embassy_stm32::exti::ExtiInput;
use embassy_stm32::interrupt::typelevel::Handler;
use embassy_stm32::mode::Blocking;
use embassy_stm32::pac;
use modbus_drive::drive::io;
use modbus_drive::motion::{SwitchEdges, Switches};

use super::board;
use super::calc::LatchedSwitch;
use super::owned::IrqOwned;
use super::steps;

type Exti = ExtiInput<'static, Blocking>;
/// The three switch inputs (board files).
pub type SwitchInputs = io::SwitchInputs<Exti, Exti, Exti>;

struct Inputs {
    pins: SwitchInputs,
    cw: LatchedSwitch,
    ccw: LatchedSwitch,
    home: LatchedSwitch,
}

/// Owned by the EXTI interrupt while it is enabled, by [`with_inputs`]
/// while it is disabled.
static INPUTS: IrqOwned<Option<Inputs>> = IrqOwned::new(None);
/// PA13: bit 0 CW, bit 1 CCW, bit 2 home; 1 = normally closed.
static POLARITY: AtomicU16 = AtomicU16::new(0);
/// PA14: bit 0 CW, bit 1 CCW limit enabled (default both).
static LIMIT_ENABLE: AtomicU16 = AtomicU16::new(3);
/// Time between the two reads of an active limit.
pub const CONFIRM_US: u32 = 2;
/// EXTI lines of the EXTI15_10 vector: pending bits cleared at every entry.
const EXTI_LINES_10_15: u32 = 0xFC00;

/// The debounced states start inactive: a switch active at power-up is
/// reported 3 ms later, like any change.
pub fn install(pins: SwitchInputs) {
    with_inputs(|inputs| {
        *inputs = Some(Inputs {
            pins,
            cw: LatchedSwitch::new(false),
            ccw: LatchedSwitch::new(false),
            home: LatchedSwitch::new(false),
        })
    });
}

/// `f` on the inputs from thread code, with the EXTI interrupt disabled
/// in the NVIC meanwhile (nothing else is masked).
fn with_inputs<R>(f: impl FnOnce(&mut Option<Inputs>) -> R) -> R {
    // SAFETY: the inputs belong to the EXTI interrupt while it is enabled;
    // its handler is bound (board::Irqs) and finds them whole.
    unsafe { INPUTS.with_irq_disabled::<board::SwitchIrq, _>(f) }
}

/// PA13 / PA14 as they are now (called by the control loop).
pub fn set_params(polarity: u16, limit_enable: u16) {
    POLARITY.store(polarity, Ordering::Relaxed);
    LIMIT_ENABLE.store(limit_enable, Ordering::Relaxed);
}

/// Reads the three pins now, sends the enabled limits to the step schedule
/// and latches the step count for a switch that has left its debounced
/// state; returns the logical states (after PA13, before PA14: the core
/// applies PA14 itself).
fn read(i: &mut Inputs) -> Switches {
    let polarity = POLARITY.load(Ordering::Relaxed);
    let schedule = steps::schedule();
    // The STEP pin's position that goes with this reading (the pulses the
    // timer had made when the pins were read), taken now and not after the
    // confirmation below, by when the next pulse may have gone out.
    let (s, position) = steps::read_at_pin_position(|| i.pins.read(polarity));
    let (mut cw, mut ccw) = (s.cw_limit(), s.ccw_limit());
    if cw || ccw {
        cortex_m::asm::delay(board::SYSCLK_HZ / 1_000_000 * CONFIRM_US);
        let again = i.pins.read(polarity);
        cw &= again.cw_limit();
        ccw &= again.ccw_limit();
    }
    let enabled = LIMIT_ENABLE.load(Ordering::Relaxed);
    if schedule.set_limits(cw && enabled & 1 != 0, ccw && enabled & 2 != 0) {
        steps::limits_changed();
    }
    i.cw.edge(s.cw_limit(), position);
    i.ccw.edge(s.ccw_limit(), position);
    i.home.edge(s.home(), position);
    s
}

/// The control loop's sample: the debounced states, the latched edges of
/// the switches whose debounced state changed now, and whether any did.
pub fn sample() -> (Switches, SwitchEdges, bool) {
    with_inputs(|inputs| {
        // Not installed yet: nothing is blocked, nothing moves either.
        let Some(i) = inputs.as_mut() else {
            return Default::default();
        };
        let raw = read(i);
        let (cw, ccw, home) = (
            i.cw.sample(raw.cw_limit()),
            i.ccw.sample(raw.ccw_limit()),
            i.home.sample(raw.home()),
        );
        let states = Switches::new(i.cw.state(), i.ccw.state(), i.home.state());
        let edges = SwitchEdges::new(cw.flatten(), ccw.flatten(), home.flatten());
        (states, edges, cw.or(ccw).or(home).is_some())
    })
}

/// EXTI lines 10..15 (priority: `PRIO_SWITCH`).
pub struct SwitchHandler;

impl Handler<board::SwitchIrq> for SwitchHandler {
    unsafe fn on_interrupt() {
        // before the pins are read: an edge after the read raises it again
        pac::EXTI
            .pr(0)
            .write_value(pac::exti::regs::Lines(EXTI_LINES_10_15));
        // SAFETY: this interrupt owns the inputs while it is enabled.
        if let Some(i) = unsafe { INPUTS.get() }.as_mut() {
            read(i);
        }
    }
}
