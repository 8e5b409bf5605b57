//! One closed frame through a drive: the line side of [`Device::poll`] for
//! the virtual drive's lines and connections. The reply `poll` queues waits
//! in the line's (or connection's) queue until it is due; a new line format
//! rides with it and takes effect when it has left.
//!
//! [`Device::poll`]: modbus_drive::Device::poll

use std::collections::VecDeque;

use modbus_drive::device::{Line, Request, Storage};
use modbus_drive::params::ParamStore;
use modbus_drive::rtu::{LineConfig, RxEvent};

use super::super::flash::FileFlash;
use super::DriveSlot;

/// A reply waiting for its time.
pub(super) struct PendingReply {
    pub due_us: u64,
    pub drive: usize,
    /// Empty: nothing to send (a broadcast EE operation).
    pub bytes: Vec<u8>,
    /// The drive's new line format, in force once this reply has left.
    pub line: Option<LineConfig>,
}

/// What [`serve`] left to the caller.
pub(super) struct Served {
    /// A reply was queued; its line change (if any) rides with it.
    pub queued: bool,
    /// Nothing was queued: a line change to apply now.
    pub line: Option<LineConfig>,
}

/// The one frame of a [`serve`] call and the queue its reply goes to.
struct Queue<'q, 'f> {
    request: Option<Request<'f>>,
    drive: usize,
    pending: &'q mut VecDeque<PendingReply>,
    queued: bool,
    line: Option<LineConfig>,
}

impl Line for Queue<'_, '_> {
    fn receive(&mut self) -> Option<Request<'_>> {
        self.request.take()
    }

    fn send(&mut self, bytes: &[u8], at_us: u64) {
        self.pending.push_back(PendingReply {
            due_us: at_us,
            drive: self.drive,
            bytes: bytes.to_vec(),
            line: None,
        });
        self.queued = true;
    }

    fn reconfigure(&mut self, line: LineConfig) {
        match self.pending.back_mut() {
            Some(reply) if self.queued => reply.line = Some(line),
            _ => self.line = Some(line),
        }
    }
}

/// A drive's flash for [`Device::poll`]: `timed`, an EE reply leaves no
/// earlier than the chip would have finished (the bus); else it waits for
/// nothing (the page), and the flash's tally of chip time starts afresh
/// either way.
///
/// [`Device::poll`]: modbus_drive::Device::poll
pub(super) struct SimStorage<'s> {
    pub store: &'s mut ParamStore<FileFlash>,
    pub timed: bool,
}

impl Storage for SimStorage<'_> {
    type Flash = FileFlash;
    fn store(&mut self) -> &mut ParamStore<FileFlash> {
        self.store
    }
    fn take_busy_us(&mut self) -> u64 {
        let busy = self.store.flash().take_busy_us();
        if self.timed {
            busy
        } else {
            0
        }
    }
}

/// Hands a closed frame to drive `di` at `now_us` and queues what it
/// answers on `pending`. `last_byte_us`: the request's last byte on a
/// serial line, `None` on Modbus TCP (no serial-line reply delay).
///
/// The drive acts on a frame at the time it closed (SPEC §8: a control
/// call after each handled frame), with its axis up to date.
pub(super) fn serve(
    slot: &mut DriveSlot,
    di: usize,
    event: RxEvent<'_>,
    last_byte_us: Option<u64>,
    now_us: u64,
    pending: &mut VecDeque<PendingReply>,
) -> Served {
    slot.advance(now_us);
    let mut queue = Queue {
        request: Some(Request::new(event, last_byte_us)),
        drive: di,
        pending,
        queued: false,
        line: None,
    };
    let mut storage = SimStorage {
        store: &mut slot.store,
        timed: true,
    };
    slot.device.poll(now_us, &mut queue, &mut storage);
    slot.control_at(now_us);
    Served {
        queued: queue.queued,
        line: queue.line,
    }
}
