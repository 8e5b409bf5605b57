//! The two receive slots between the USART interrupt and the dispatcher
//! task: a closed frame is copied into a free slot by the interrupt
//! ([`deliver`]) and read in place by the dispatcher ([`receive`],
//! [`RxFrame`]) until it drops it. Ownership passes with an atomic state
//! per slot, so no lock is held while bytes are copied and the step
//! interrupt is never masked (priority.rs).

use core::sync::atomic::{AtomicU32, AtomicU8, AtomicUsize, Ordering};

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use modbus_drive::rtu::{RxEvent, MAX_FRAME};

use super::owned::IrqOwned;

/// A closed frame (or frame error), as the interrupt left it in its slot.
pub struct FrameSlot {
    bytes: [u8; MAX_FRAME],
    len: u16,
    kind: u8,
    parity_error: bool,
    /// End of the request's last byte (the reply waits from here, SPEC §1).
    last_byte_at_us: u32,
}

const KIND_FRAME: u8 = 0;
const KIND_BROKEN: u8 = 1;
const KIND_TOO_SHORT: u8 = 2;
const KIND_OVERRUN: u8 = 3;

impl FrameSlot {
    /// All zeros: the slots live in .bss, no flash image.
    const EMPTY: Self = Self {
        bytes: [0; MAX_FRAME],
        len: 0,
        kind: KIND_FRAME,
        parity_error: false,
        last_byte_at_us: 0,
    };

    fn fill(&mut self, ev: RxEvent<'_>, last_byte_at_us: u32) {
        self.last_byte_at_us = last_byte_at_us;
        (self.kind, self.len) = match ev {
            RxEvent::Frame {
                bytes,
                parity_error,
            } => {
                // a frame is at most MAX_FRAME bytes (the assembler's buffer)
                let n = bytes.len().min(MAX_FRAME);
                self.bytes[..n].copy_from_slice(&bytes[..n]);
                self.parity_error = parity_error;
                (KIND_FRAME, n as u16)
            }
            RxEvent::Broken => (KIND_BROKEN, 0),
            RxEvent::TooShort => (KIND_TOO_SHORT, 0),
            RxEvent::Overrun => (KIND_OVERRUN, 0),
        };
    }
}

const SLOT_FREE: u8 = 0;
const SLOT_FULL: u8 = 1;

/// Two slots: one being answered, one arriving (a master does not send
/// more before our reply).
static SLOTS: [IrqOwned<FrameSlot>; 2] = [
    IrqOwned::new(FrameSlot::EMPTY),
    IrqOwned::new(FrameSlot::EMPTY),
];
static SLOT_STATE: [AtomicU8; 2] = [AtomicU8::new(SLOT_FREE), AtomicU8::new(SLOT_FREE)];
/// The next slot the dispatcher reads (thread only).
static READ_SLOT: AtomicUsize = AtomicUsize::new(0);
/// A slot became full.
static FRAME_READY: Signal<CriticalSectionRawMutex, ()> = Signal::new();
/// Frames lost because the dispatcher was behind (logged by the dispatcher).
pub static FRAMES_DROPPED: AtomicU32 = AtomicU32::new(0);

/// A full slot, the dispatcher's until dropped.
pub struct RxFrame {
    index: usize,
}

impl RxFrame {
    fn slot(&self) -> &FrameSlot {
        // SAFETY: the slot is full: the interrupt does not touch it until
        // `drop` marks it free; only shared references are made here.
        unsafe { SLOTS[self.index].get() }
    }

    /// The core's view of it, for `Device::poll`.
    pub fn event(&self) -> RxEvent<'_> {
        let s = self.slot();
        match s.kind {
            KIND_FRAME => RxEvent::Frame {
                bytes: &s.bytes[..usize::from(s.len)],
                parity_error: s.parity_error,
            },
            KIND_BROKEN => RxEvent::Broken,
            KIND_TOO_SHORT => RxEvent::TooShort,
            _ => RxEvent::Overrun,
        }
    }

    pub fn last_byte_at_us(&self) -> u32 {
        self.slot().last_byte_at_us
    }
}

impl Drop for RxFrame {
    fn drop(&mut self) {
        SLOT_STATE[self.index].store(SLOT_FREE, Ordering::Release);
    }
}

/// A closed frame waits for the dispatcher to take it up ([`receive`]).
pub fn frame_waiting() -> bool {
    SLOT_STATE[READ_SLOT.load(Ordering::Relaxed)].load(Ordering::Acquire) == SLOT_FULL
}

/// The next closed frame, in arrival order.
pub async fn receive() -> RxFrame {
    let index = READ_SLOT.load(Ordering::Relaxed);
    loop {
        if SLOT_STATE[index].load(Ordering::Acquire) == SLOT_FULL {
            READ_SLOT.store(index ^ 1, Ordering::Relaxed);
            return RxFrame { index };
        }
        FRAME_READY.wait().await;
    }
}

/// Into the next slot if it is free (else the frame is dropped and
/// counted), then handed to the dispatcher.
pub fn deliver(write_slot: &mut usize, ev: RxEvent<'_>, last_byte_at_us: u32) {
    let i = *write_slot;
    if SLOT_STATE[i].load(Ordering::Acquire) != SLOT_FREE {
        FRAMES_DROPPED.fetch_add(1, Ordering::Relaxed);
        return;
    }
    // SAFETY: a free slot is the interrupt's until marked full.
    unsafe { SLOTS[i].get() }.fill(ev, last_byte_at_us);
    SLOT_STATE[i].store(SLOT_FULL, Ordering::Release);
    *write_slot = i ^ 1;
    FRAME_READY.signal(());
}
