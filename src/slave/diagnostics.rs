//! Function 0x08, diagnostics (SPEC §4, §6; Modbus Application Protocol
//! V1.1b3 §6.8 and Modbus over Serial Line V1.02 Appendix A).

use super::{Exception, Handled, Reply, Slave};
use crate::event::Event;

/// Declares [`Counters`] from one list: each counter's field, its getter
/// (named after it, with its doc) and the slave's wrapping increment.
macro_rules! counters {
    ($($(#[$doc:meta])* $field:ident => $count:ident;)*) => {
        /// The serial-line counters of SPEC §6 (Modbus over Serial Line,
        /// Appendix A), 16 bits each, wrapping. Cleared by diagnostics 0x01
        /// and 0x0A.
        #[derive(Clone, Debug, Default, PartialEq, Eq)]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        pub struct Counters {
            $($(#[$doc])* $field: u16,)*
        }

        impl Counters {
            $(
                $(#[$doc])*
                #[inline]
                pub const fn $field(&self) -> u16 {
                    self.$field
                }

                /// Counts one more (wrapping); only the slave counts.
                #[inline]
                pub(super) fn $count(&mut self) {
                    self.$field = self.$field.wrapping_add(1);
                }
            )*
        }
    };
}

counters! {
    /// Frames with a good CRC and no parity error, for any address
    /// (sub-function 0x0B).
    bus_messages => count_bus_message;
    /// CRC and parity errors (any address), broken frames, frames shorter
    /// than 4 bytes (0x0C).
    bus_errors => count_bus_error;
    /// Exception replies sent, including 9/10 frame-error replies, plus
    /// broadcasts refused without a reply (0x0D).
    exceptions => count_exception;
    /// Good frames addressed to us or broadcast (0x0E).
    slave_messages => count_slave_message;
    /// Good frames addressed to us or broadcast that got no reply:
    /// broadcasts, listen-only mode, the 0x04 request itself (0x0F).
    no_response => count_no_response;
    /// Requests refused with exception 6 (0x11).
    busy => count_busy;
    /// Frames over 256 bytes or with bytes lost by the UART (0x12).
    overruns => count_overrun;
}

impl Counters {
    /// The counters as a master read them with sub-functions 0x0B..=0x0F,
    /// 0x11 and 0x12, in that order (the slave's own counters change only
    /// through [`crate::slave::Slave`]).
    pub const fn from_reads(reads: [u16; 7]) -> Self {
        Self {
            bus_messages: reads[0],
            bus_errors: reads[1],
            exceptions: reads[2],
            slave_messages: reads[3],
            no_response: reads[4],
            busy: reads[5],
            overruns: reads[6],
        }
    }
}

/// Sub-functions (SPEC §4: 0x00, 0x01, 0x04, 0x0A..=0x12).
mod sub {
    pub const RETURN_QUERY_DATA: u16 = 0x00;
    pub const RESTART_COMMUNICATIONS: u16 = 0x01;
    pub const FORCE_LISTEN_ONLY: u16 = 0x04;
    pub const CLEAR_COUNTERS: u16 = 0x0A;
    pub const BUS_MESSAGE_COUNT: u16 = 0x0B;
    pub const BUS_ERROR_COUNT: u16 = 0x0C;
    pub const EXCEPTION_COUNT: u16 = 0x0D;
    pub const SLAVE_MESSAGE_COUNT: u16 = 0x0E;
    pub const NO_RESPONSE_COUNT: u16 = 0x0F;
    pub const NAK_COUNT: u16 = 0x10;
    pub const BUSY_COUNT: u16 = 0x11;
    pub const OVERRUN_COUNT: u16 = 0x12;
}

/// Data of 0x01: keep (0x0000) or clear (0xFF00) the event log. There is
/// no event log here, so both only restart.
const CLEAR_LOG: u16 = 0xFF00;

impl Slave {
    /// `08 sub(2) data…`. The reply echoes the request except for the
    /// counter reads, whose data is the counter. 0x04 is never answered.
    /// While a parameter-storage operation runs (`busy`) a valid request
    /// gets exception 6 and does nothing (SPEC §9: "other requests during an
    /// operation get exception 6"; §5.2: after validation).
    pub(super) fn diagnostics(&mut self, pdu: &[u8], busy: bool, out: &mut [u8]) -> Handled {
        let (sub_function, data) = match pdu {
            [_, s0, s1, data @ ..] => (u16::from_be_bytes([*s0, *s1]), data),
            _ => return Err(Exception::ByteCountMismatch),
        };
        if sub_function == sub::RETURN_QUERY_DATA {
            return if busy {
                Err(Exception::Busy)
            } else {
                Ok(Reply::Echo)
            };
        }
        let counter = match sub_function {
            sub::RESTART_COMMUNICATIONS | sub::FORCE_LISTEN_ONLY | sub::CLEAR_COUNTERS => None,
            sub::BUS_MESSAGE_COUNT => Some(self.counters.bus_messages),
            sub::BUS_ERROR_COUNT => Some(self.counters.bus_errors),
            sub::EXCEPTION_COUNT => Some(self.counters.exceptions),
            sub::SLAVE_MESSAGE_COUNT => Some(self.counters.slave_messages),
            sub::NO_RESPONSE_COUNT => Some(self.counters.no_response),
            sub::NAK_COUNT => Some(0), // this slave never sends a NAK (code 7 of the standard)
            sub::BUSY_COUNT => Some(self.counters.busy),
            sub::OVERRUN_COUNT => Some(self.counters.overruns),
            _ => return Err(Exception::IllegalFunction),
        };
        let &[d0, d1] = data else {
            return Err(Exception::ByteCountMismatch);
        };
        let value = u16::from_be_bytes([d0, d1]);
        let value_ok = match sub_function {
            sub::RESTART_COMMUNICATIONS => value == 0 || value == CLEAR_LOG,
            _ => value == 0,
        };
        if !value_ok {
            return Err(Exception::IllegalDataValue);
        }
        if busy {
            return Err(Exception::Busy);
        }
        if sub_function == sub::FORCE_LISTEN_ONLY {
            self.listen_only = true;
            return Ok(Reply::None);
        }
        let Some(counter) = counter else {
            return Ok(Reply::Echo); // 0x01, 0x0A
        };
        out[..3].copy_from_slice(&pdu[..3]);
        out[3..5].copy_from_slice(&counter.to_be_bytes());
        Ok(Reply::Pdu(5))
    }

    /// After an answered request: 0x01 and 0x0A act once their echo is
    /// built ("the reply is sent before the restart is executed").
    pub(super) fn after_reply(&mut self, pdu: &[u8]) -> Option<Event> {
        match pdu {
            [0x08, 0x00, 0x01 | 0x0A, ..] => {
                self.counters = Counters::default();
                Some(Event::CountersCleared)
            }
            _ => None,
        }
    }

    /// A good frame for us while in listen-only mode: only a valid
    /// 0x08/0x01 acts — it leaves the mode and clears the counters, without
    /// a reply (Modbus Application Protocol §6.8.1).
    pub(super) fn listen_only_request(&mut self, pdu: &[u8]) -> Option<Event> {
        match pdu {
            [0x08, 0x00, 0x01, 0x00 | 0xFF, 0x00] => {
                self.listen_only = false;
                self.counters = Counters::default();
                Some(Event::ListenOnly(false))
            }
            _ => None,
        }
    }
}
