//! State with exactly one owner at a time, handed over without a lock.
//!
//! An [`IrqOwned`] belongs to one interrupt handler once that interrupt is
//! enabled; before that (and while the interrupt is disabled in the NVIC)
//! thread code may set it up. Nothing else can run the handler meanwhile,
//! so no critical section is needed, and none masks anything.

use core::cell::UnsafeCell;

pub struct IrqOwned<T>(UnsafeCell<T>);

// SAFETY: one context at a time uses the value (see `get`).
unsafe impl<T: Send> Sync for IrqOwned<T> {}

impl<T> IrqOwned<T> {
    pub const fn new(value: T) -> Self {
        Self(UnsafeCell::new(value))
    }

    /// # Safety
    /// The caller is the value's owner: its interrupt handler, or thread
    /// code while that interrupt cannot run (not yet enabled, or disabled
    /// in the NVIC); and no other reference from this call is alive.
    #[allow(clippy::mut_from_ref)]
    pub unsafe fn get(&self) -> &mut T {
        // SAFETY: exclusive by the caller's contract.
        unsafe { &mut *self.0.get() }
    }
}
