//! The one entry a host calls on the frame path: [`Device::poll`].
//!
//! A host (the firmware, the virtual drive, a Modbus TCP front end, a web
//! page) moves bytes and time only: its [`Line`] hands over the frames its
//! assembler closed and takes the replies with the time they may leave;
//! its [`Storage`] holds the parameter store. `poll` owns the sequence in
//! between, the same for every host (SPEC §1, §3, §7, §9):
//!
//! 1. the closed frame (or frame error) goes through the dispatcher;
//! 2. an EE operation it accepted runs on the storage at once, and its
//!    deferred reply takes the request's place (exception 6 to other
//!    requests until that reply is due);
//! 3. the reply is queued on the line to leave no earlier than
//!    [`Device::reply_delay_us`] after the request's last byte (and after
//!    the flash's own time on a simulated flash);
//! 4. a new address takes effect, and a new line format is queued behind
//!    the reply (SPEC §7: the reply goes out from the old address on the
//!    old line).

use embedded_storage::nor_flash::NorFlash;

use super::Device;
use crate::params::ParamStore;
use crate::rtu::{LineConfig, RxEvent, MAX_FRAME};
use crate::slave::Response;

/// A frame (or frame error) the host's assembler closed.
#[derive(Debug)]
pub struct Request<'a> {
    event: RxEvent<'a>,
    /// When its last byte ended (µs, the host's clock); `None` on a
    /// transport without the serial line's reply delay (Modbus TCP, a web
    /// page): the reply may leave at once.
    last_byte_us: Option<u64>,
}

impl<'a> Request<'a> {
    /// `event` closed by the host's assembler, its last byte ended at
    /// `last_byte_us` (see [`Self::last_byte_us`]).
    #[inline]
    pub const fn new(event: RxEvent<'a>, last_byte_us: Option<u64>) -> Self {
        Self {
            event,
            last_byte_us,
        }
    }

    /// The frame or frame error.
    #[inline]
    pub const fn event(&self) -> &RxEvent<'a> {
        &self.event
    }

    /// When its last byte ended (µs, the host's clock); `None` on a
    /// transport without the serial line's reply delay.
    #[inline]
    pub const fn last_byte_us(&self) -> Option<u64> {
        self.last_byte_us
    }
}

/// The host's side of one line (or connection) to this drive.
pub trait Line {
    /// The next closed frame for this drive, if one waits.
    fn receive(&mut self) -> Option<Request<'_>>;
    /// Queues `bytes` to leave in one burst at `at_us` (the host's clock),
    /// not earlier. `bytes` may be empty (a broadcast EE operation): then
    /// nothing leaves, but what is queued after it waits until `at_us`.
    fn send(&mut self, bytes: &[u8], at_us: u64);
    /// Puts `line` in force once everything queued before has left.
    fn reconfigure(&mut self, line: LineConfig);
}

/// Where EE operations run: the parameter store (SPEC §9).
pub trait Storage {
    type Flash: NorFlash;
    fn store(&mut self) -> &mut ParamStore<Self::Flash>;
    /// Whether the operation may run now, by the host's own view (the
    /// firmware checks that its step output is idle); `false` refuses it
    /// with exception 6 and changes nothing ([`Device::refuse_storage`]).
    fn ready(&mut self) -> bool {
        true
    }

    /// Time (µs) the last operation keeps the flash busy after it returned:
    /// a simulated flash's chip time. 0 on hardware, where the operation
    /// itself took that long.
    fn take_busy_us(&mut self) -> u64 {
        0
    }
}

impl<F: NorFlash> Storage for ParamStore<F> {
    type Flash = F;
    fn store(&mut self) -> &mut ParamStore<F> {
        self
    }
}

/// What [`Device::poll`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Polled {
    /// No frame was waiting.
    Idle,
    /// One frame went through (its reply, if any, is queued on the line):
    /// the host runs its control call after it (SPEC §8) and polls again.
    Served,
}

impl Device {
    /// The frame path, sans I/O (module docs): takes at most one frame
    /// from `line`, at the host's time `now_us`.
    pub fn poll(
        &mut self,
        now_us: u64,
        line: &mut impl Line,
        storage: &mut impl Storage,
    ) -> Polled {
        self.poll_with(now_us, line, storage, &mut [0u8; MAX_FRAME])
    }

    /// [`Device::poll`] making the reply in `reply`, a buffer the host
    /// keeps (its contents do not matter): a firmware spares itself
    /// clearing one on the stack for each frame.
    pub fn poll_with(
        &mut self,
        now_us: u64,
        line: &mut impl Line,
        storage: &mut impl Storage,
        reply: &mut [u8; MAX_FRAME],
    ) -> Polled {
        if self.ee_busy_until_us.is_some_and(|t| now_us >= t) {
            self.ee_busy_until_us = None;
        }
        let (mut response, mut due_us) = {
            let Some(request) = line.receive() else {
                return Polled::Idle;
            };
            let due_us = request
                .last_byte_us
                .map_or(now_us, |t| t + u64::from(self.reply_delay_us()));
            (self.handle_rx(request.event, reply), due_us)
        };
        let mut ee = false;
        if self.pending_ee().is_some() {
            let deferred = if storage.ready() {
                self.poll_storage(storage.store(), reply)
            } else {
                self.refuse_storage(reply)
            };
            if let Some(deferred) = deferred {
                response = deferred;
                ee = true;
                due_us = due_us.max(now_us + storage.take_busy_us());
                // busy to other requests until its reply is due
                self.ee_busy_until_us = (due_us > now_us).then_some(due_us);
            }
        }
        match response {
            Response::Reply(n) => line.send(&reply[..n.min(MAX_FRAME)], due_us),
            Response::Silent if ee => line.send(&[], due_us),
            Response::Silent => {}
        }
        if let Some(config) = self.reply_sent() {
            line.reconfigure(config);
        }
        Polled::Served
    }
}

#[cfg(all(test, feature = "sim"))]
mod tests {
    extern crate std;
    use std::vec::Vec;

    use super::*;
    use crate::dictionary::Identity;
    use crate::params::SimFlash;
    use crate::rtu::with_crc;

    /// A line that holds one frame and records what the device queued.
    #[derive(Default)]
    struct Wire {
        frame: Option<(Vec<u8>, Option<u64>)>,
        sent: Vec<(Vec<u8>, u64)>,
        configs: Vec<LineConfig>,
    }

    impl Wire {
        fn with(pdu: &[u8], last_byte_us: Option<u64>) -> Self {
            let mut f = [0u8; MAX_FRAME];
            f[0] = 1;
            f[1..=pdu.len()].copy_from_slice(pdu);
            let n = with_crc(&mut f, pdu.len() + 1);
            Self {
                frame: Some((f[..n].to_vec(), last_byte_us)),
                ..Self::default()
            }
        }
    }

    impl Line for Wire {
        fn receive(&mut self) -> Option<Request<'_>> {
            let (bytes, last_byte_us) = self.frame.as_ref()?;
            let request = Request {
                event: RxEvent::Frame {
                    bytes,
                    parity_error: false,
                },
                last_byte_us: *last_byte_us,
            };
            Some(request)
        }
        fn send(&mut self, bytes: &[u8], at_us: u64) {
            self.sent.push((bytes.to_vec(), at_us));
        }
        fn reconfigure(&mut self, line: LineConfig) {
            self.configs.push(line);
        }
    }

    fn poll_once(d: &mut Device, wire: &mut Wire, now_us: u64) -> Polled {
        let mut store = ParamStore::new(SimFlash::<2>::new(), 0..4096).unwrap();
        let polled = d.poll(now_us, wire, &mut store);
        wire.frame = None;
        polled
    }

    #[test]
    fn a_reply_is_queued_at_the_reply_delay_after_the_last_byte() {
        let mut d = Device::new(Identity::new("t"));
        let mut wire = Wire::with(&[0x03, 0x60, 0x41, 0x00, 0x01], Some(10_000));
        assert_eq!(poll_once(&mut d, &mut wire, 12_000), Polled::Served);
        let delay = u64::from(d.reply_delay_us());
        assert_eq!(wire.sent.len(), 1);
        assert_eq!(wire.sent[0].1, 10_000 + delay);
        assert_eq!(wire.sent[0].0[..3], [0x01, 0x03, 0x02]);
        assert_eq!(poll_once(&mut d, &mut wire, 13_000), Polled::Idle);
    }

    #[test]
    fn without_a_serial_line_the_reply_may_leave_at_once() {
        let mut d = Device::new(Identity::new("t"));
        let mut wire = Wire::with(&[0x03, 0x60, 0x41, 0x00, 0x01], None);
        poll_once(&mut d, &mut wire, 5_000);
        assert_eq!(wire.sent[0].1, 5_000);
    }

    #[test]
    fn a_new_line_format_is_queued_behind_the_reply_that_set_it() {
        let mut d = Device::new(Identity::new("t"));
        // PA52 = 0 (9600 baud): legacy address 0x0064 + 52
        let mut wire = Wire::with(&[0x06, 0x00, 0x98, 0x00, 0x00], Some(0));
        poll_once(&mut d, &mut wire, 0);
        assert_eq!(wire.sent.len(), 1, "the echo leaves first");
        assert_eq!(wire.configs.len(), 1);
        assert_eq!(d.line(), wire.configs[0]);
    }

    #[test]
    fn an_ee_request_is_answered_after_its_operation_and_blocks_until_then() {
        let mut d = Device::new(Identity::new("t"));
        // EE-Save: 0x10 to 0x003A, one register, value 1
        let save = [0x10, 0x00, 0x3A, 0x00, 0x01, 0x02, 0x00, 0x01];
        let mut wire = Wire::with(&save, Some(1_000));
        poll_once(&mut d, &mut wire, 1_000);
        assert_eq!(wire.sent.len(), 1);
        assert_eq!(wire.sent[0].0[..6], [0x01, 0x10, 0x00, 0x3A, 0x00, 0x01]);
        assert!(d.pending_ee().is_none());
        // a request before that reply is due gets exception 6, one after
        // it a plain answer
        let due = wire.sent[0].1;
        let mut wire = Wire::with(&[0x03, 0x60, 0x41, 0x00, 0x01], Some(due - 1));
        poll_once(&mut d, &mut wire, due - 1);
        assert_eq!(wire.sent[0].0[1..3], [0x83, 0x06]);
        let mut wire = Wire::with(&[0x03, 0x60, 0x41, 0x00, 0x01], Some(due));
        poll_once(&mut d, &mut wire, due);
        assert_eq!(wire.sent[0].0[1], 0x03);
    }

    /// A store that is never ready: the host sees its step output busy.
    struct Busy(ParamStore<SimFlash<2>>);

    impl Storage for Busy {
        type Flash = SimFlash<2>;
        fn store(&mut self) -> &mut ParamStore<SimFlash<2>> {
            &mut self.0
        }
        fn ready(&mut self) -> bool {
            false
        }
    }

    #[test]
    fn an_ee_request_the_host_is_not_ready_for_gets_exception_6() {
        let mut d = Device::new(Identity::new("t"));
        let save = [0x10, 0x00, 0x3A, 0x00, 0x01, 0x02, 0x00, 0x01];
        let mut wire = Wire::with(&save, Some(0));
        let mut busy = Busy(ParamStore::new(SimFlash::<2>::new(), 0..4096).unwrap());
        assert_eq!(d.poll(0, &mut wire, &mut busy), Polled::Served);
        assert_eq!(wire.sent.len(), 1);
        assert_eq!(wire.sent[0].0[1..3], [0x90, 0x06]);
        assert!(d.pending_ee().is_none());
        // nothing was written: the store holds no saved set
        assert!(busy.0.boot().outcome() == crate::params::BootOutcome::Blank);
    }

    #[test]
    fn a_foreign_frame_queues_nothing() {
        let mut d = Device::new(Identity::new("t"));
        let mut wire = Wire::with(&[0x03, 0x60, 0x41, 0x00, 0x01], Some(0));
        if let Some((bytes, _)) = wire.frame.as_mut() {
            bytes[0] = 9;
            let n = bytes.len() - 2;
            let mut f = [0u8; MAX_FRAME];
            f[..n].copy_from_slice(&bytes[..n]);
            let len = with_crc(&mut f, n);
            *bytes = f[..len].to_vec();
        }
        assert_eq!(poll_once(&mut d, &mut wire, 0), Polled::Served);
        assert!(wire.sent.is_empty() && wire.configs.is_empty());
    }
}
