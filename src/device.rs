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

use crate::dictionary::OdValues;
use crate::drive::Drive;
use crate::params::Params;
use crate::rtu::{LineConfig, RxEvent, MAX_FRAME};

/// Strings of 0x1008 / 0x1009 / 0x100A (SPEC §5), 16 ASCII bytes at most.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Identity {
    /// Device name (0x1008).
    pub product: &'static str,
    /// Hardware version (0x1009): the board, e.g. "STM32G431CB" or "virtual".
    pub hardware: &'static str,
    /// Software version (0x100A).
    pub software: &'static str,
}

impl Identity {
    pub const fn new(hardware: &'static str) -> Self {
        Self {
            product: "modbus-drive",
            hardware,
            software: env!("CARGO_PKG_VERSION"),
        }
    }
}

/// What to do after a frame was handled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Response {
    /// Send nothing (foreign address, broadcast, strict frame error, …).
    Silent,
    /// Send the first `n` bytes of the reply buffer (CRC included).
    Reply(usize),
}

/// One drive on the bus.
pub struct Device {
    pub identity: Identity,
    pub od: OdValues,
    pub pa: Params,
    pub drive: Drive,
}

impl Device {
    pub fn new(identity: Identity) -> Self {
        Self {
            identity,
            od: OdValues::default(),
            pa: Params::defaults(),
            drive: Drive::new(),
        }
    }

    /// A closed frame (or frame error) from the assembler. Writes any reply
    /// into `reply` and says how much of it to send.
    pub fn handle_rx(&mut self, _ev: RxEvent<'_>, _reply: &mut [u8; MAX_FRAME]) -> Response {
        Response::Silent // issue 2
    }

    /// The reply (if any) has left the wire: apply a deferred change of
    /// address or line format. Returns the new line settings if they changed.
    pub fn reply_sent(&mut self) -> Option<LineConfig> {
        None // issue 2 / issue 5
    }

    /// Earliest start of a reply after the request's last byte: t3.5 of the
    /// current line plus the response delay PA56 (SPEC §1).
    pub fn reply_delay_us(&self) -> u32 {
        self.line().timing().t35_us + u32::from(self.pa.response_delay_ms()) * 1000
    }

    /// Our unicast address (PA51).
    pub fn address(&self) -> u8 {
        self.pa.address()
    }

    /// The line settings in force (PA52/PA53).
    pub fn line(&self) -> LineConfig {
        self.pa.line()
    }
}
