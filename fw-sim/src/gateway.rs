//! Modbus TCP in front of the emulated RS-485 line (`--modbus-tcp`): the
//! runner is a Modbus TCP to RTU gateway, as a field engineer would put one
//! in front of the board (MODBUS Messaging on TCP/IP Implementation Guide
//! V1.0b §3.1.3; the serial side per Modbus over Serial Line V1.02).
//!
//! - Each connection's byte stream is cut into requests by the drive crate's
//!   own MBAP codec (`modbus_drive::mbap`); a foreign protocol identifier
//!   is skipped without a reply, a bad length closes the connection.
//! - A request becomes an RTU frame: the unit identifier as the slave
//!   address, the PDU, the CRC (`modbus_drive::rtu::crc16`). It goes onto
//!   the RX wire like a raw master's bytes, at the USART's baud.
//! - The line is half duplex: one request is on it at a time, the others
//!   wait in arrival order.
//! - The firmware's reply is taken from the TX wire (only what left while
//!   its driver was enabled) and is complete once the line has been silent
//!   for t3.5 after a frame with a correct CRC; its address must be the
//!   unit's. The PDU goes back with the request's transaction and unit.
//! - No reply (a wrong unit, a frame the firmware drops) within
//!   [`RESPONSE_TIMEOUT_PS`] of emulated time, or a garbled one: exception
//!   0x0B, "gateway target device failed to respond" (Application Protocol
//!   V1.1b3 §7). A broadcast (unit 0) is sent and never answered, as on the
//!   line; the next request follows after t3.5.

use std::collections::VecDeque;
use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::os::fd::{AsFd, BorrowedFd};

use modbus_drive::mbap::{
    encode_response, exception_pdu, Decoder, Frame, Header, EXCEPTION_GATEWAY_TARGET_FAILED,
    MAX_ADU,
};
use modbus_drive::rtu::crc16;

/// How long the gateway waits for the firmware's reply, in emulated time
/// (ps). Long enough for an EE operation, whose reply waits for the flash.
pub const RESPONSE_TIMEOUT_PS: u64 = 1_000_000_000_000;

struct Conn {
    id: u64,
    stream: TcpStream,
    decoder: Decoder,
}

struct Request {
    conn: u64,
    header: Header,
    rtu: Vec<u8>,
}

/// The request on the line and what has come back for it.
struct OnLine {
    req: Request,
    /// Emulated time (ps) the request's last character ends.
    sent_end: u64,
    reply: Vec<u8>,
    /// End of the reply's last character so far.
    reply_end: u64,
}

#[derive(Default)]
pub struct Gateway {
    listeners: Vec<TcpListener>,
    conns: Vec<Conn>,
    next_id: u64,
    waiting: VecDeque<Request>,
    on_line: Option<OnLine>,
}

impl Gateway {
    pub fn new(addrs: &[SocketAddr]) -> std::io::Result<Self> {
        let mut g = Gateway::default();
        for a in addrs {
            let l = TcpListener::bind(a)?;
            l.set_nonblocking(true)?;
            eprintln!("modbus-tcp: listening on {}", l.local_addr()?);
            g.listeners.push(l);
        }
        Ok(g)
    }

    /// What `poll` should watch.
    pub fn fds(&self) -> impl Iterator<Item = BorrowedFd<'_>> {
        let l = self.listeners.iter().map(|l| l.as_fd());
        l.chain(self.conns.iter().map(|c| c.stream.as_fd()))
    }

    /// Accepts connections and decodes what they sent into requests.
    pub fn read(&mut self) {
        for l in &self.listeners {
            while let Ok((s, _)) = l.accept() {
                let _ = s.set_nonblocking(true);
                let _ = s.set_nodelay(true);
                self.next_id += 1;
                self.conns.push(Conn {
                    id: self.next_id,
                    stream: s,
                    decoder: Decoder::new(),
                });
            }
        }
        let waiting = &mut self.waiting;
        let mut buf = [0u8; 1024];
        self.conns.retain_mut(|c| loop {
            let n = match c.stream.read(&mut buf) {
                Ok(0) => return false,
                Ok(n) => n,
                Err(e) if e.kind() == ErrorKind::WouldBlock => return true,
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(_) => return false,
            };
            let mut input = &buf[..n];
            while !input.is_empty() {
                let (used, frame) = c.decoder.feed(input);
                input = &input[used..];
                match frame {
                    Some(Frame::Request { header, pdu }) => {
                        let mut adu = Vec::with_capacity(pdu.len() + 3);
                        adu.push(header.unit());
                        adu.extend_from_slice(pdu);
                        waiting.push_back(Request {
                            conn: c.id,
                            header,
                            rtu: with_crc_vec(&adu),
                        });
                    }
                    Some(Frame::ForeignProtocol(_)) => {}
                    Some(Frame::BadLength(_)) => return false,
                    None if used == 0 => break,
                    None => {}
                }
            }
        });
    }

    /// The next request to put on the line, if the line is free.
    pub fn next_frame(&mut self) -> Option<Vec<u8>> {
        if self.on_line.is_some() {
            return None;
        }
        let req = self.waiting.pop_front()?;
        let rtu = req.rtu.clone();
        self.on_line = Some(OnLine {
            req,
            sent_end: u64::MAX,
            reply: Vec::new(),
            reply_end: 0,
        });
        Some(rtu)
    }

    /// The frame from `next_frame` is queued on the RX wire up to `end`.
    pub fn sent(&mut self, end: u64) {
        if let Some(o) = self.on_line.as_mut() {
            o.sent_end = end;
        }
    }

    /// A character the firmware drove onto the line, ending at `end`.
    pub fn tx(&mut self, byte: u8, end: u64) {
        if let Some(o) = self.on_line.as_mut().filter(|o| end > o.sent_end) {
            o.reply.push(byte);
            o.reply_end = end;
        }
    }

    /// At emulated time `now` with the line's t3.5 `t35` (ps): finishes the
    /// request on the line when its reply is complete or overdue.
    pub fn tick(&mut self, now: u64, t35: u64) {
        let Some(o) = &self.on_line else { return };
        if o.sent_end == u64::MAX {
            return;
        }
        let unit = o.req.header.unit();
        let pdu: Option<Vec<u8>> = if unit == 0 {
            // a broadcast: never answered
            if now < o.sent_end + t35 {
                return;
            }
            None
        } else if !o.reply.is_empty() {
            if now < o.reply_end + t35 {
                return;
            }
            let r = &o.reply;
            let ok = r.len() >= 4 && r[0] == unit && with_crc_vec(&r[..r.len() - 2]) == *r;
            Some(if ok {
                r[1..r.len() - 2].to_vec()
            } else {
                gateway_failed(&o.req)
            })
        } else if now >= o.sent_end + RESPONSE_TIMEOUT_PS {
            Some(gateway_failed(&o.req))
        } else {
            return;
        };
        let o = self.on_line.take().expect("checked above");
        if let Some(pdu) = pdu {
            let mut out = [0u8; MAX_ADU];
            let n = encode_response(&o.req.header, &pdu, &mut out);
            if let Some(c) = self.conns.iter_mut().find(|c| c.id == o.req.conn) {
                // a peer that stopped reading is dropped at its next read
                let _ = c.stream.write_all(&out[..n]);
            }
        }
    }
}

fn gateway_failed(req: &Request) -> Vec<u8> {
    // the function code is the RTU frame's second byte
    exception_pdu(req.rtu[1], EXCEPTION_GATEWAY_TARGET_FAILED).to_vec()
}

/// `frame` with its CRC appended (low byte first).
fn with_crc_vec(frame: &[u8]) -> Vec<u8> {
    let mut out = frame.to_vec();
    out.extend_from_slice(&crc16(frame).to_le_bytes());
    out
}
