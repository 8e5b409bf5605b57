//! The dispatcher: a closed frame in → reply bytes or silence, plus the §6
//! counters and an [`Event`] for the glue to log.
//!
//! Order of a frame's journey (SPEC §2, §3, §5.2):
//! 1. frame errors (parity, CRC) are counted; our own unicast address gets
//!    exception 9/10 if PA54 = 1 and PA55 = 0;
//! 2. foreign addresses (including 248..=255) are dropped without a word;
//! 3. listen-only mode (diagnostics 0x04) swallows everything but 0x08/0x01;
//! 4. broadcasts execute 0x06 / 0x10 and never answer;
//! 5. unicast requests are validated in the §5.2 order and answered.
//!
//! The dispatcher is generic over [`DriveLayer`] so that tests can use a
//! double; [`crate::device::Device`] runs it with the real drive.

mod diagnostics;
mod identification;

pub use diagnostics::Counters;

use crate::dictionary::{DriveLayer, Registers};
use crate::event::{Event, FrameError};
use crate::rtu::{crc16, with_crc, RxEvent, MAX_FRAME, MIN_FRAME};

/// Broadcast address (§2).
pub const BROADCAST: u8 = 0;

pub use crate::rtu::pdu::{function, MAX_READ_QUANTITY, MAX_WRITE_QUANTITY};
use crate::rtu::pdu::{ReadRequest, WriteMultipleRequest, WriteSingleRequest};
pub use crate::rtu::Exception;

/// What to do after a frame was handled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Response {
    /// Send nothing (foreign address, broadcast, strict frame error, …).
    Silent,
    /// Send the first `n` bytes of the reply buffer (CRC included).
    Reply(usize),
}

/// What [`Slave::handle`] produced.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Outcome {
    response: Response,
    event: Option<Event>,
}

impl Outcome {
    #[inline]
    pub const fn response(&self) -> Response {
        self.response
    }

    #[inline]
    pub const fn event(&self) -> Option<Event> {
        self.event
    }
}

impl Outcome {
    const SILENT: Self = Self {
        response: Response::Silent,
        event: None,
    };
}

/// The slave side of the serial line: counters and listen-only mode.
#[derive(Clone, Debug, Default)]
pub struct Slave {
    counters: Counters,
    listen_only: bool,
}

/// What a valid request is answered with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Reply {
    /// The first `n` bytes written to the reply PDU buffer.
    Pdu(usize),
    /// The request frame itself, CRC included (0x06, most of 0x08): no
    /// second CRC computation.
    Echo,
    /// Nothing (0x08/0x04 enters listen-only mode).
    None,
}

/// A PDU's result.
type Handled = Result<Reply, Exception>;

impl Slave {
    pub fn new() -> Self {
        Self::default()
    }

    /// The §6 counters.
    pub fn counters(&self) -> &Counters {
        &self.counters
    }

    /// An exception reply produced after the request (a failed EE
    /// operation's exception 4, or 6 for one refused under a moving axis,
    /// `Device::poll_storage`) is counted (§6).
    pub fn count_deferred_exception(&mut self, exception: Exception) {
        let c = &mut self.counters;
        c.count_exception();
        if exception == Exception::Busy {
            c.count_busy();
        }
    }

    /// Listen-only mode (diagnostics 0x04) is on.
    pub fn listen_only(&self) -> bool {
        self.listen_only
    }

    /// Whether [`Slave::handle`] will answer `rx` at all, told before it
    /// runs, with the same `own_address` and PA (`standard`: PA55's
    /// standard exception profile, `answer_frame_errors`: PA54): a frame
    /// for us outside listen-only mode, good or with its frame errors
    /// answered. A request to enter listen-only mode (0x08 / 0x04) is
    /// told unanswered, though a malformed one gets an exception. For a
    /// glue that gets the line ready before the reply is made.
    pub fn will_answer(
        &self,
        rx: &RxEvent<'_>,
        own_address: u8,
        standard: bool,
        answer_frame_errors: bool,
    ) -> bool {
        let RxEvent::Frame {
            bytes,
            parity_error,
        } = *rx
        else {
            return false;
        };
        if bytes.len() < MIN_FRAME
            || bytes[0] != own_address
            || own_address == BROADCAST
            || self.listen_only
        {
            return false;
        }
        if parity_error || crc16(bytes) != 0 {
            // both frame errors have the same code, if any
            return answer_frame_errors && Exception::Crc.code(standard).is_some();
        }
        !matches!(bytes[1..], [0x08, 0x00, 0x04, ..])
    }

    /// One event of the frame assembler. `own_address` is the unicast
    /// address in force (a new PA51 waits for the reply, §7); PA54 and PA55
    /// are read from `regs.pa`. A reply is written into `reply`.
    pub fn handle<D: DriveLayer>(
        &mut self,
        rx: RxEvent<'_>,
        own_address: u8,
        regs: &mut Registers<'_, D>,
        reply: &mut [u8; MAX_FRAME],
    ) -> Outcome {
        let (bytes, parity_error) = match rx {
            RxEvent::Frame {
                bytes,
                parity_error,
            } => (bytes, parity_error),
            RxEvent::Broken => return self.lost(FrameError::Broken),
            RxEvent::TooShort => return self.lost(FrameError::TooShort),
            RxEvent::Overrun => return self.lost(FrameError::Overrun),
        };
        if bytes.len() < MIN_FRAME {
            return self.lost(FrameError::TooShort);
        }
        let address = bytes[0];
        let ours = address == own_address && address != BROADCAST;
        let standard = regs.pa.standard_exceptions();

        // §3: frame errors. A parity error names the cause better than the
        // CRC mismatch it usually also causes, so it wins.
        let frame_error = if parity_error {
            Some(Exception::Parity)
        } else if crc16(bytes) != 0 {
            Some(Exception::Crc)
        } else {
            None
        };
        if let Some(e) = frame_error {
            self.counters.count_bus_error();
            let code = e
                .code(standard)
                .filter(|_| ours && !self.listen_only && regs.pa.answer_frame_errors());
            let kind = if e == Exception::Parity {
                FrameError::Parity
            } else {
                FrameError::Crc
            };
            let response = match code {
                Some(code) => {
                    self.counters.count_exception();
                    Response::Reply(exception_reply(reply, address, bytes[1], code))
                }
                None => Response::Silent,
            };
            return Outcome {
                response,
                event: Some(Event::FrameError {
                    kind,
                    address: Some(address),
                    answered: code.is_some(),
                }),
            };
        }

        self.counters.count_bus_message();
        if !ours && address != BROADCAST {
            return Outcome::SILENT; // §2: not even counted as ours
        }
        self.counters.count_slave_message();
        let pdu = &bytes[1..bytes.len() - 2];
        let function = pdu[0];

        if self.listen_only {
            self.counters.count_no_response();
            // §2: a broadcast never acts outside 0x06/0x10, not even here.
            let event = if ours {
                self.listen_only_request(pdu)
            } else {
                None
            };
            return Outcome {
                response: Response::Silent,
                event,
            };
        }

        if address == BROADCAST {
            self.counters.count_no_response();
            if !matches!(
                function,
                function::WRITE_SINGLE_REGISTER | function::WRITE_MULTIPLE_REGISTERS
            ) {
                return Outcome::SILENT; // §2: ignored, counted
            }
            let mut scratch = [0u8; MAX_FRAME];
            return match self.execute(pdu, regs, &mut scratch[1..MAX_FRAME - 2]) {
                Ok(_) => Outcome::SILENT,
                Err(exception) => Outcome {
                    response: Response::Silent,
                    event: Some(self.refused(function, exception, false)),
                },
            };
        }

        // Unicast: the reply PDU goes after the address byte, CRC after it.
        let outcome = self.execute(pdu, regs, &mut reply[1..MAX_FRAME - 2]);
        match outcome {
            Ok(Reply::Pdu(len)) => {
                reply[0] = address;
                Outcome {
                    response: Response::Reply(with_crc(reply, 1 + len)),
                    event: self.after_reply(pdu),
                }
            }
            Ok(Reply::Echo) => {
                match <&[u8; 8]>::try_from(bytes) {
                    // 0x06 and most 0x08 requests: a fixed-size copy, no
                    // memcpy call.
                    Ok(frame8) => reply[..8].copy_from_slice(frame8),
                    Err(_) => reply[..bytes.len()].copy_from_slice(bytes),
                }
                Outcome {
                    response: Response::Reply(bytes.len()),
                    event: self.after_reply(pdu),
                }
            }
            Ok(Reply::None) => {
                self.counters.count_no_response();
                Outcome {
                    response: Response::Silent,
                    event: Some(Event::ListenOnly(true)),
                }
            }
            Err(exception) => {
                let event = Some(self.refused(function, exception, true));
                // Every unicast exception has a code in both profiles (only
                // 9/10 lose theirs, and they never come from a PDU).
                let code = exception.code(standard).unwrap_or(exception as u8);
                Outcome {
                    response: Response::Reply(exception_reply(reply, address, function, code)),
                    event,
                }
            }
        }
    }

    /// A frame that never became a request (§1): counted, reported.
    fn lost(&mut self, kind: FrameError) -> Outcome {
        let c = &mut self.counters;
        match kind {
            FrameError::Overrun => c.count_overrun(),
            _ => c.count_bus_error(),
        }
        Outcome {
            response: Response::Silent,
            event: Some(Event::FrameError {
                kind,
                address: None,
                answered: false,
            }),
        }
    }

    /// Counts a refused request (§6: broadcast refusals count too).
    fn refused(&mut self, function: u8, exception: Exception, answered: bool) -> Event {
        let c = &mut self.counters;
        c.count_exception();
        if exception == Exception::Busy {
            c.count_busy();
        }
        Event::Exception {
            function,
            exception,
            answered,
        }
    }

    /// Validates and executes one request PDU (§4, §5.2), writing the reply
    /// PDU into `out` (room for 253 bytes).
    fn execute<D: DriveLayer>(
        &mut self,
        pdu: &[u8],
        regs: &mut Registers<'_, D>,
        out: &mut [u8],
    ) -> Handled {
        match pdu[0] {
            function::READ_HOLDING_REGISTERS => read_holding_registers(pdu, regs, out),
            function::WRITE_SINGLE_REGISTER => write_single_register(pdu, regs),
            function::WRITE_MULTIPLE_REGISTERS => write_multiple_registers(pdu, regs, out),
            function::DIAGNOSTICS => self.diagnostics(pdu, regs.busy, out),
            function::ENCAPSULATED_INTERFACE => identification::read_device_id(pdu, regs, out),
            _ => Err(Exception::IllegalFunction),
        }
    }
}

/// 0x03: `03 start quantity` → `03 bytecount words…`.
fn read_holding_registers<D: DriveLayer>(
    pdu: &[u8],
    regs: &Registers<'_, D>,
    out: &mut [u8],
) -> Handled {
    let request = ReadRequest::new_checked(pdu)?;
    let bytes = 2 * usize::from(request.quantity());
    regs.read(request, &mut out[2..])?;
    out[0] = function::READ_HOLDING_REGISTERS;
    out[1] = bytes as u8;
    Ok(Reply::Pdu(2 + bytes))
}

/// 0x06: `06 address value` → the same frame.
fn write_single_register<D: DriveLayer>(pdu: &[u8], regs: &mut Registers<'_, D>) -> Handled {
    let request = WriteSingleRequest::new_checked(pdu)?;
    regs.write_single(request.address(), request.value())?;
    Ok(Reply::Echo)
}

/// 0x10: `10 start quantity bytecount words…` → `10 start quantity`.
fn write_multiple_registers<D: DriveLayer>(
    pdu: &[u8],
    regs: &mut Registers<'_, D>,
    out: &mut [u8],
) -> Handled {
    let request = WriteMultipleRequest::new_checked(pdu)?;
    regs.write(request)?;
    // a checked request is at least six bytes long
    out[..5].copy_from_slice(&pdu[..5]);
    Ok(Reply::Pdu(5))
}

/// `address function|0x80 code CRC` into `reply`; returns its length.
fn exception_reply(reply: &mut [u8; MAX_FRAME], address: u8, function: u8, code: u8) -> usize {
    reply[0] = address;
    reply[1] = function | 0x80;
    reply[2] = code;
    with_crc(reply, 3)
}
