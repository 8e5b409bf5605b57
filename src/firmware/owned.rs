//! State with exactly one owner at a time, handed over without a lock.
//!
//! An [`IrqOwned`] has one owner at a time, one of two kinds, and each
//! `static` of it says which in its `SAFETY` comments:
//! - by the interrupt's enable: it belongs to one interrupt handler while
//!   that interrupt is enabled, and to thread code while it is disabled in
//!   the NVIC (before it is first enabled, or around a change:
//!   [`IrqOwned::with_irq_disabled`], rs485.rs's link, switches.rs's
//!   inputs);
//! - by an atomic state that the two sides hand it over with: the side the
//!   state names owns it, and only the owner moves the state on (with
//!   Release, the other side reads it with Acquire): rx_slots.rs's slots
//!   (free: the USART interrupt's; full: the dispatcher's), rs485.rs's
//!   reply buffer (idle: `send`'s; any other state: the interrupts').
//!
//! Either way nothing else touches the value meanwhile, so no critical
//! section is needed, and none masks anything.

use core::cell::UnsafeCell;

use embassy_stm32::interrupt::typelevel::Interrupt;

pub struct IrqOwned<T>(UnsafeCell<T>);

// SAFETY: one owner at a time uses the value (see `get`).
unsafe impl<T: Send> Sync for IrqOwned<T> {}

impl<T> IrqOwned<T> {
    pub const fn new(value: T) -> Self {
        Self(UnsafeCell::new(value))
    }

    /// # Safety
    /// The caller is the value's owner as the module docs define it (its
    /// interrupt handler, or thread code while that interrupt cannot run;
    /// or the side the value's atomic state names), and no other reference
    /// from this call is alive.
    #[allow(clippy::mut_from_ref)]
    pub unsafe fn get(&self) -> &mut T {
        // SAFETY: exclusive by the caller's contract.
        unsafe { &mut *self.0.get() }
    }

    /// `f` on the value from thread code, with interrupt `I`, whose
    /// handler owns it while enabled, disabled in the NVIC meanwhile
    /// (nothing else is masked) and enabled again after.
    ///
    /// # Safety
    /// The value belongs to `I`'s handler while `I` is enabled (the first
    /// kind of owner above), that handler is bound, and what `f` leaves
    /// is what the handler may find; no reference from [`IrqOwned::get`]
    /// is alive.
    pub unsafe fn with_irq_disabled<I: Interrupt, R>(&self, f: impl FnOnce(&mut T) -> R) -> R {
        I::disable();
        cortex_m::asm::dsb();
        cortex_m::asm::isb();
        // SAFETY: `I` cannot run now: thread code owns the value (the
        // caller's contract)
        let r = f(unsafe { self.get() });
        // SAFETY: the handler is bound (the caller's contract)
        unsafe { I::enable() };
        r
    }
}
