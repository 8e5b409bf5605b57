//! The whole drive as the glue sees it: frames in, replies out; time and
//! switch states in, steps out; events out for the glue to log.
//!
//! Frame path (firmware UART interrupt or virtual-drive transport):
//! 1. feed bytes to an [`crate::rtu::FrameAssembler`];
//! 2. hand each [`RxEvent`] to [`Device::handle_rx`] with a reply buffer;
//! 3. on [`Response::Reply`], send those bytes no earlier than
//!    [`Device::reply_delay_us`] after the request's last byte, in one burst;
//! 4. then call [`Device::reply_sent`] (also after [`Response::Silent`]) so
//!    that a new address or line format takes effect (SPEC §7) — it returns
//!    the new line settings when they changed.

use heapless::Deque;

pub use crate::dictionary::Identity;
use crate::dictionary::{OdValues, Registers};
use crate::drive::Drive;
use crate::event::Event;
use crate::params::Params;
use crate::rtu::{LineConfig, RxEvent, MAX_FRAME};
pub use crate::slave::Response;
use crate::slave::Slave;

/// Events kept until the glue takes them; older ones are kept, newer ones
/// dropped (and counted) when it falls behind.
pub const EVENT_QUEUE_LEN: usize = 16;

/// One drive on the bus.
pub struct Device {
    pub identity: Identity,
    pub od: OdValues,
    pub pa: Params,
    pub drive: Drive,
    /// Dispatcher state: §6 counters and listen-only mode.
    pub slave: Slave,
    /// A parameter-storage operation is running (§5.2 step 9); set by the
    /// parameter store (issue 5).
    pub storage_busy: bool,
    /// Address and line in force: PA51/52/53 as they were when the last
    /// reply left (SPEC §7).
    address: u8,
    line: LineConfig,
    events: Deque<Event, EVENT_QUEUE_LEN>,
    events_dropped: u32,
}

impl Device {
    pub fn new(identity: Identity) -> Self {
        let pa = Params::defaults();
        Self {
            identity,
            od: OdValues::default(),
            address: pa.address(),
            line: pa.line(),
            pa,
            drive: Drive::new(),
            slave: Slave::new(),
            storage_busy: false,
            events: Deque::new(),
            events_dropped: 0,
        }
    }

    /// A closed frame (or frame error) from the assembler. Writes any reply
    /// into `reply` and says how much of it to send. Bus errors are counted
    /// (§6) and reported as events.
    pub fn handle_rx(&mut self, rx: RxEvent<'_>, reply: &mut [u8; MAX_FRAME]) -> Response {
        let mut regs = Registers {
            od: &mut self.od,
            pa: &mut self.pa,
            drive: &mut self.drive,
            identity: &self.identity,
            busy: self.storage_busy,
        };
        let outcome = self.slave.handle(rx, self.address, &mut regs, reply);
        if let Some(event) = outcome.event {
            self.push_event(event);
        }
        outcome.response
    }

    /// The reply (if any) has left the wire: apply a deferred change of
    /// address or line format (SPEC §7) — the reply to the write that made
    /// it went out from the old address on the old line. Returns the new
    /// line settings if they changed. Call it after [`Response::Silent`] too.
    pub fn reply_sent(&mut self) -> Option<LineConfig> {
        let address = self.pa.address();
        if address != self.address {
            self.address = address;
            self.push_event(Event::AddressChanged { address });
        }
        let line = self.pa.line();
        if line == self.line {
            return None;
        }
        self.line = line;
        self.push_event(Event::LineChanged(line));
        Some(line)
    }

    /// Earliest start of a reply after the request's last byte: t3.5 of the
    /// line in force plus the response delay PA56 (SPEC §1).
    pub fn reply_delay_us(&self) -> u32 {
        self.line.timing().t35_us + u32::from(self.pa.response_delay_ms()) * 1000
    }

    /// Our unicast address in force (PA51 once the reply that changed it
    /// has been sent).
    pub fn address(&self) -> u8 {
        self.address
    }

    /// The line settings in force (PA52/PA53, same rule as the address).
    pub fn line(&self) -> LineConfig {
        self.line
    }

    /// Queues an event for the glue. Parts of the core outside the frame
    /// path (drive, parameter store) report through here too.
    pub fn push_event(&mut self, event: Event) {
        if self.events.push_back(event).is_err() {
            self.events_dropped = self.events_dropped.wrapping_add(1);
        }
    }

    /// The oldest event not yet taken.
    pub fn take_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }

    /// Events lost because the queue was full.
    pub fn events_dropped(&self) -> u32 {
        self.events_dropped
    }
}
