//! Interrupt priorities and the one masking rule: nothing but a fault ever
//! masks the step engine's refill.
//!
//! | priority | interrupt | shares state with lower levels through |
//! |---|---|---|
//! | P0 | step engine's DMA channel (the refill) | atomics only (`StepSchedule`, the pin-position ledger, steps.rs) |
//! | P1 | switches (EXTI15_10); embassy-time driver (TIM2) | switches: ownership by the NVIC enable (switches.rs); the time driver: the critical section |
//! | P2 | RS-485 USART; SysTick (the software DE's lead / tail; on the F103 also the frame gap, rs485.rs) | atomics, buffer hand-over by index (rs485.rs) |
//! | thread | executor: control loop, dispatcher | — |
//!
//! The `critical-section` implementation of the whole image (embassy's
//! executor and time driver, embassy-sync, defmt-rtt if it used one, our
//! own) is [`BasepriCs`]: it raises BASEPRI to [`MASK`] (P1), which masks
//! P1 and everything below and leaves P0 running. That is sound because no
//! code at P0 takes the critical section or touches data behind one: the
//! refill runs the core's lock-free `StepSource` into its own DMA buffer
//! and reads the DMA channel's flags and count, nothing else. [`init`]
//! demotes every other interrupt of the chip to P1 or below, so no
//! embassy-enabled line (the EXTI lines it unmasks at init) can sit at P0
//! beside it.
//!
//! HardFault and NMI are above BASEPRI; their handlers (fault.rs) take no
//! critical section either.

use core::sync::atomic::{compiler_fence, Ordering};

use cortex_m::interrupt::InterruptNumber;
use cortex_m::peripheral::scb::SystemHandler;
use cortex_m::peripheral::{ICB, NVIC};
use embassy_stm32::interrupt::typelevel::{Interrupt, TIM2};
use embassy_stm32::interrupt::Priority;

use super::board;

pub const PRIO_STEP: Priority = Priority::P0;
pub const PRIO_SWITCH: Priority = Priority::P1;
pub const PRIO_UART: Priority = Priority::P2;
/// Above the USART: a flash erase stalls the core, TIM2's overflow and
/// half-period events can both fall due meanwhile, and the USART interrupt
/// that stamps the next byte must not run before the time driver has
/// counted them (it would read the time one or two half-periods early).
/// With TIM2 higher, the pending TIM2 interrupt always runs first.
pub const PRIO_TIME: Priority = Priority::P1;

/// BASEPRI inside a critical section: masks P1 and below.
pub const MASK: u8 = PRIO_SWITCH as u8;

/// Sets the priorities of the table above; every other interrupt goes to
/// P1 at most. Call it right after `embassy_stm32::init`, before any of
/// them can fire with a meaning.
pub fn init() {
    board::StepIrq::set_priority(PRIO_STEP);
    board::SwitchIrq::set_priority(PRIO_SWITCH);
    board::UartIrq::set_priority(PRIO_UART);
    TIM2::set_priority(PRIO_TIME);
    // SAFETY: a byte write of SHPR3 at boot; SysTick is not running.
    unsafe {
        cortex_m::Peripherals::steal()
            .SCB
            .set_priority(SystemHandler::SysTick, PRIO_UART as u8);
    }
    let step = board::StepIrq::IRQ.number();
    // SAFETY: reads of the ICB and byte writes of NVIC IPR registers; the
    // interrupts touched are not running (thread mode, boot).
    unsafe {
        let lines = (((*ICB::PTR).ictr.read() & 0xF) + 1) * 32;
        let nvic = &*NVIC::PTR;
        for n in 0..lines.min(nvic.ipr.len() as u32) {
            let ipr = &nvic.ipr[n as usize];
            if n != u32::from(step) && ipr.read() < MASK {
                ipr.write(MASK);
            }
        }
    }
}

/// The image's `critical-section` implementation (see the module docs).
struct BasepriCs;
critical_section::set_impl!(BasepriCs);

// SAFETY: BASEPRI_MAX only ever raises the mask, so nested sections work and
// `release` restores the level the outer one saw. The fences keep the
// compiler from moving memory accesses out of the section. Neither half is
// inlined: the image takes the section at a dozen sites and a call costs a
// few cycles there, never on the step engine's refill (which takes none).
unsafe impl critical_section::Impl for BasepriCs {
    #[inline(never)]
    unsafe fn acquire() -> u8 {
        let old = cortex_m::register::basepri::read();
        cortex_m::register::basepri_max::write(MASK); // followed by an ISB
        compiler_fence(Ordering::SeqCst);
        old
    }

    #[inline(never)]
    unsafe fn release(old: u8) {
        compiler_fence(Ordering::SeqCst);
        // SAFETY: restores the level saved by the matching `acquire`.
        unsafe { cortex_m::register::basepri::write(old) };
    }
}
