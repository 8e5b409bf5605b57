//! CW limit, CCW limit and home inputs (SPEC §7 PA13/PA14, §8.6, §8.7).
//!
//! Every edge raises the EXTI interrupt. It reads the levels at once and, if
//! an enabled limit has become active while the motor steps towards it
//! (CW = negative direction, CCW = positive, SPEC §8.6), stops step output
//! from the interrupt (`steps::limit_stop`) — without waiting for the
//! control loop. The control loop samples the same pins every millisecond
//! through a debounce (calc.rs) for everything else.
//!
//! Shared state: the inputs behind a critical section ([`INPUTS`]); PA13
//! polarity and PA14 enable bits in atomics written by the control loop.

use core::cell::RefCell;
use core::sync::atomic::{AtomicU16, AtomicU32, Ordering};

use critical_section::Mutex;
use embassy_stm32::exti::ExtiInput;
use embassy_stm32::interrupt::typelevel::Handler;
use embassy_stm32::mode::Blocking;

use super::board;
use super::calc::switch_active;
use super::steps;

/// The three switch inputs (pull-ups, contact to ground; board files).
pub struct SwitchInputs {
    pub cw: ExtiInput<'static, Blocking>,
    pub ccw: ExtiInput<'static, Blocking>,
    pub home: ExtiInput<'static, Blocking>,
}

/// Raw switch states, already corrected for polarity.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, defmt::Format)]
pub struct SwitchStates {
    pub cw_limit: bool,
    pub ccw_limit: bool,
    pub home: bool,
}

static INPUTS: Mutex<RefCell<Option<SwitchInputs>>> = Mutex::new(RefCell::new(None));
/// PA13: bit 0 CW, bit 1 CCW, bit 2 home; 1 = normally closed.
static POLARITY: AtomicU16 = AtomicU16::new(0);
/// PA14: bit 0 CW, bit 1 CCW limit enabled (default both).
static LIMIT_ENABLE: AtomicU16 = AtomicU16::new(3);
/// Limit stops made by the interrupt (logged by the control loop).
pub static LIMIT_STOPS: AtomicU32 = AtomicU32::new(0);

pub fn install(inputs: SwitchInputs) {
    critical_section::with(|cs| *INPUTS.borrow_ref_mut(cs) = Some(inputs));
}

/// PA13 / PA14 as they are now (called by the control loop).
pub fn set_params(polarity: u16, limit_enable: u16) {
    POLARITY.store(polarity, Ordering::Relaxed);
    LIMIT_ENABLE.store(limit_enable, Ordering::Relaxed);
}

/// Reads the three pins now.
pub fn read() -> SwitchStates {
    let nc = POLARITY.load(Ordering::Relaxed);
    critical_section::with(|cs| match INPUTS.borrow_ref(cs).as_ref() {
        Some(i) => SwitchStates {
            cw_limit: switch_active(i.cw.is_high(), nc & 1 != 0),
            ccw_limit: switch_active(i.ccw.is_high(), nc & 2 != 0),
            home: switch_active(i.home.is_high(), nc & 4 != 0),
        },
        None => SwitchStates::default(),
    })
}

/// EXTI lines 10..15 (priority: `board::PRIO_SWITCH`).
pub struct SwitchHandler;

impl Handler<board::SwitchIrq> for SwitchHandler {
    unsafe fn on_interrupt() {
        critical_section::with(|cs| {
            if let Some(i) = INPUTS.borrow_ref_mut(cs).as_mut() {
                i.cw.clear_pending();
                i.ccw.clear_pending();
                i.home.clear_pending();
            }
        });
        let s = read();
        let enabled = LIMIT_ENABLE.load(Ordering::Relaxed);
        let towards = steps::moving_forward();
        let stop = match towards {
            Some(false) => s.cw_limit && enabled & 1 != 0,
            Some(true) => s.ccw_limit && enabled & 2 != 0,
            None => false,
        };
        if stop {
            steps::limit_stop();
            LIMIT_STOPS.fetch_add(1, Ordering::Relaxed);
        }
    }
}
