//! `--modbus-tcp`: a Modbus TCP server in front of the simulated bus, as a
//! Modbus TCP / RTU gateway would be (MBAP framing: the core's [`mbap`]).
//!
//! A request's PDU is wrapped into the RTU frame a gateway would put on the
//! serial line (unit id as address, CRC) and offered to every drive
//! through the same path as a frame from the pty ([`super::handle`]), so the
//! drives validate, count (§6) and answer exactly as on the bus; the reply
//! frame's PDU goes back in an MBAP response. No t3.5 and no PA56 response
//! delay on this side: they are serial-line timing, and TCP has none.
//!
//! Unit identifier (guide §3.1.3 / §4.4):
//! - 1..=247: the drive with that address (PA51 in force);
//! - 0 and 255 with one drive: that drive (the guide's "server itself",
//!   0 being accepted for it too);
//! - 0 with several drives: a serial-line broadcast, executed by every
//!   drive (0x06 / 0x10 only, SPEC §2), no response;
//! - 248..=255 with several drives: exception 0x0A (gateway path
//!   unavailable);
//! - a unit nobody answers (no such drive, listen-only mode): exception
//!   0x0B (gateway target device failed to respond), at once.
//!
//! Bad ADUs: a protocol id other than 0 is discarded without a reply and
//! the connection goes on; a length outside 2..=254 closes the connection
//! (the stream cannot be delimited any more); a request cut short by the
//! peer closing is dropped, and so is one whose rest does not come within
//! [`ADU_TIMEOUT_US`] (a length field larger than what the client sent):
//! the connection is closed, since whatever comes next would be read as
//! the missing bytes. Each is logged and counted ([`Stats`], on the status
//! line).
//!
//! Bounded: [`MAX_CLIENTS`] connections; per connection one ADU of
//! reassembly (the decoder's fixed buffer), and reading stops while
//! [`MAX_QUEUED`] replies or [`OUT_MAX`] bytes wait for a peer that does
//! not read (TCP flow control holds the client back).
//!
//! Connection management (Modbus TCP implementation guide §4.2.1): a
//! connection without a request in flight (nothing half-received, no
//! reply waiting or unsent) for the idle timeout (`--tcp-idle-timeout`)
//! is closed, and with [`MAX_CLIENTS`] connected a new one closes the
//! connection idle the longest to be admitted, so that sockets a client
//! forgot (or a squatter holds) cannot lock real clients out. Connections
//! with a request in flight are never closed for it; when every one has
//! one, the new connection is refused. Each case is counted.

use std::collections::VecDeque;
use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::os::fd::AsFd;

use modbus_drive::mbap::{self, Decoder, Frame, Header, MAX_ADU, MAX_PDU};
use modbus_drive::rtu::{with_crc, LineConfig, RxEvent, MAX_FRAME};
use nix::poll::{PollFd, PollFlags};

use super::{log_events, serve, Listener, VirtualDrive};

/// Connections served at once; more are accepted and closed at once.
pub(super) const MAX_CLIENTS: usize = 32;
/// Replies waiting per connection before its requests are left unread.
const MAX_QUEUED: usize = 16;
/// Response bytes waiting per connection before its requests are left
/// unread.
const OUT_MAX: usize = 16 * MAX_ADU;
/// Longest wait for the rest of a begun ADU. A client writes a request at
/// once, so its bytes arrive within milliseconds even over a slow network;
/// libmodbus waits half a second between bytes, this a little longer.
pub(super) const ADU_TIMEOUT_US: u64 = 1_000_000;

/// What the server saw, for the status line and the log.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Stats {
    pub requests: u32,
    /// Protocol id not 0: discarded.
    pub foreign_protocol: u32,
    /// Length field outside 2..=254: connection closed.
    pub bad_length: u32,
    /// Connection closed inside an ADU, by the peer or after
    /// [`ADU_TIMEOUT_US`] without the rest.
    pub truncated: u32,
    /// Gateway exceptions 0x0A / 0x0B sent.
    pub gateway_exceptions: u32,
    /// Connections refused beyond [`MAX_CLIENTS`] (every one in flight).
    pub refused: u32,
    /// Connections closed after the idle timeout.
    pub idle_closed: u32,
    /// Idle connections closed to admit a new one at the cap.
    pub evicted: u32,
}

impl Stats {
    pub fn bad_adus(&self) -> u32 {
        self.foreign_protocol + self.bad_length + self.truncated
    }
}

/// A response waiting for its time (an EE operation's, SPEC §9) or for the
/// responses before it.
struct Queued {
    due_us: u64,
    /// The MBAP response; empty: nothing to send (a broadcast).
    adu: Vec<u8>,
    /// The drive whose reply this is, and its new line format (in force
    /// once the reply is out).
    drive: Option<(usize, Option<LineConfig>)>,
}

struct Conn {
    label: String,
    stream: TcpStream,
    decoder: Decoder,
    out: Vec<u8>,
    queued: VecDeque<Queued>,
    /// The peer shut its sending side: close once every response is out.
    eof: bool,
    /// When the unfinished ADU in the decoder began.
    partial_since_us: Option<u64>,
    /// When the peer last sent bytes or was last sent a reply.
    last_activity_us: u64,
}

impl Conn {
    fn wants_input(&self) -> bool {
        !self.eof && self.queued.len() < MAX_QUEUED && self.out.len() < OUT_MAX
    }

    /// A request half-received, being answered, or its reply unsent.
    fn in_flight(&self) -> bool {
        self.decoder.pending() > 0 || !self.queued.is_empty() || !self.out.is_empty()
    }
}

/// The listeners and connections of `--modbus-tcp`.
#[derive(Default)]
pub(super) struct ModbusTcp {
    pub listeners: Vec<Listener>,
    conns: Vec<Conn>,
    pub stats: Stats,
    /// Idle connections close after this; `None`: never.
    pub idle_timeout_us: Option<u64>,
}

impl ModbusTcp {
    pub fn connections(&self) -> usize {
        self.conns.len()
    }

    /// The earliest time a queued response is due, an unfinished ADU
    /// times out, or a connection has been idle for the idle timeout.
    pub fn next_due(&self) -> Option<u64> {
        self.conns
            .iter()
            .flat_map(|c| {
                let expiry = c.partial_since_us.map(|t| t + ADU_TIMEOUT_US);
                let idle = self.idle_timeout_us.map(|t| c.last_activity_us + t);
                c.queued
                    .front()
                    .map(|q| q.due_us)
                    .into_iter()
                    .chain(expiry)
                    .chain(idle)
            })
            .min()
    }

    /// The counters as JSON, for the page.
    pub fn stats_json(&self) -> String {
        let s = &self.stats;
        format!(
            "{{\"connections\":{},\"requests\":{},\"bad_adus\":{},\"refused\":{},\
             \"idle_closed\":{},\"evicted\":{},\"idle_timeout_s\":{}}}",
            self.conns.len(),
            s.requests,
            s.bad_adus(),
            s.refused,
            s.idle_closed,
            s.evicted,
            self.idle_timeout_us
                .map_or("null".into(), |t| (t / 1_000_000).to_string())
        )
    }

    /// Poll entries: every listener, then every connection.
    pub fn poll_fds(&self) -> Vec<PollFd<'_>> {
        let mut fds: Vec<PollFd<'_>> = self
            .listeners
            .iter()
            .map(|l| PollFd::new(l.socket.as_fd(), PollFlags::POLLIN))
            .collect();
        for c in &self.conns {
            let mut ev = PollFlags::empty();
            if c.wants_input() {
                ev |= PollFlags::POLLIN;
            }
            if !c.out.is_empty() {
                ev |= PollFlags::POLLOUT;
            }
            fds.push(PollFd::new(c.stream.as_fd(), ev));
        }
        fds
    }
}

impl VirtualDrive {
    /// After `poll`: `revents` in the order of [`ModbusTcp::poll_fds`].
    pub(super) fn modbus_tcp_ready(&mut self, revents: &[Option<PollFlags>]) {
        let nl = self.mbap.listeners.len();
        let ready = |i: usize, f: PollFlags| {
            revents
                .get(i)
                .copied()
                .flatten()
                .is_some_and(|r| r.intersects(f))
        };
        let nc = self.mbap.conns.len().min(revents.len().saturating_sub(nl));
        let mut closed = Vec::new();
        for ci in 0..nc {
            let i = nl + ci;
            if ready(i, PollFlags::POLLOUT) {
                self.flush_conn(ci);
            }
            let hangup = PollFlags::POLLIN | PollFlags::POLLHUP | PollFlags::POLLERR;
            if ready(i, hangup) && !self.read_conn(ci) {
                closed.push(ci);
            }
        }
        for ci in 0..self.mbap.conns.len() {
            let c = &self.mbap.conns[ci];
            if c.eof && c.queued.is_empty() && c.out.is_empty() && !closed.contains(&ci) {
                closed.push(ci);
            }
        }
        closed.sort_unstable();
        for ci in closed.into_iter().rev() {
            self.close_conn(ci, "");
        }
        for li in 0..nl {
            if ready(li, PollFlags::POLLIN) {
                self.accept_modbus_tcp(li);
            }
        }
    }

    fn accept_modbus_tcp(&mut self, li: usize) {
        loop {
            match self.mbap.listeners[li].accept() {
                Ok(Some((stream, peer))) => {
                    let label = format!("modbus-tcp {peer}");
                    if self.mbap.conns.len() >= MAX_CLIENTS {
                        let idlest = (0..self.mbap.conns.len())
                            .filter(|&ci| !self.mbap.conns[ci].in_flight())
                            .min_by_key(|&ci| self.mbap.conns[ci].last_activity_us);
                        let Some(ci) = idlest else {
                            self.mbap.stats.refused += 1;
                            self.console.log(&format!(
                                "{label}: refused, {MAX_CLIENTS} clients connected, \
                                 each with a request in flight"
                            ));
                            continue; // dropping the stream closes it
                        };
                        self.mbap.stats.evicted += 1;
                        let why = format!(" (idle the longest, to admit {peer})");
                        self.close_conn(ci, &why);
                    }
                    self.console.log(&format!("{label}: connected"));
                    self.mbap.conns.push(Conn {
                        label,
                        stream,
                        decoder: Decoder::new(),
                        out: Vec::new(),
                        queued: VecDeque::new(),
                        eof: false,
                        partial_since_us: None,
                        last_activity_us: self.clock.now_us(),
                    });
                }
                Ok(None) => return,
                Err(e) => {
                    let addr: SocketAddr = self.mbap.listeners[li].addr;
                    self.console
                        .log(&format!("modbus-tcp {addr}: accept failed: {e}"));
                    return;
                }
            }
        }
    }

    /// Reads what connection `ci` sent and serves each complete request.
    /// Returns false when the connection is to be closed now.
    fn read_conn(&mut self, ci: usize) -> bool {
        let mut chunk = [0u8; 1024];
        while self.mbap.conns[ci].wants_input() {
            let n = match self.mbap.conns[ci].stream.read(&mut chunk) {
                Ok(0) => {
                    self.mbap.conns[ci].eof = true;
                    if self.mbap.conns[ci].decoder.pending() > 0 {
                        return false; // a request cut short: nothing to answer
                    }
                    return true;
                }
                Ok(n) => n,
                Err(e) if e.kind() == ErrorKind::WouldBlock => return true,
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(e) => {
                    let msg = format!("{}: read failed: {e}", self.mbap.conns[ci].label);
                    self.console.log(&msg);
                    return false;
                }
            };
            if !self.serve_bytes(ci, &chunk[..n]) {
                return false;
            }
            let now = self.clock.now_us();
            let conn = &mut self.mbap.conns[ci];
            conn.last_activity_us = now;
            conn.partial_since_us = match conn.decoder.pending() {
                0 => None,
                _ => Some(conn.partial_since_us.unwrap_or(now)),
            };
        }
        true
    }

    /// Cuts `bytes` into ADUs and serves them; false on a bad length.
    fn serve_bytes(&mut self, ci: usize, bytes: &[u8]) -> bool {
        let mut off = 0;
        while off < bytes.len() {
            let conn = &mut self.mbap.conns[ci];
            let (used, frame) = conn.decoder.feed(&bytes[off..]);
            off += used;
            let mut pdu = [0u8; MAX_PDU];
            let request = match frame {
                None => {
                    if used == 0 {
                        return false; // the decoder refuses input: broken
                    }
                    continue;
                }
                Some(Frame::Request { header, pdu: p }) => {
                    pdu[..p.len()].copy_from_slice(p);
                    (header, p.len())
                }
                Some(Frame::ForeignProtocol(h)) => {
                    self.mbap.stats.foreign_protocol += 1;
                    let msg = format!(
                        "{}: protocol id {} is not Modbus (0): ADU of transaction {} discarded \
                         ({} bad ADUs)",
                        conn.label,
                        h.protocol(),
                        h.transaction(),
                        self.mbap.stats.bad_adus()
                    );
                    self.console.log(&msg);
                    continue;
                }
                Some(Frame::BadLength(h)) => {
                    self.mbap.stats.bad_length += 1;
                    let msg = format!(
                        "{}: MBAP length {} outside 2..=254: connection closed ({} bad ADUs)",
                        conn.label,
                        h.length(),
                        self.mbap.stats.bad_adus()
                    );
                    self.console.log(&msg);
                    return false;
                }
            };
            let now = self.clock.now_us();
            self.serve_request(ci, request.0, &pdu[..request.1], now);
        }
        true
    }

    /// One request: to the drive(s) its unit id names, as an RTU frame.
    fn serve_request(&mut self, ci: usize, header: Header, pdu: &[u8], now: u64) {
        self.mbap.stats.requests = self.mbap.stats.requests.wrapping_add(1);
        let unit = header.unit();
        let address = match unit {
            0 | mbap::UNIT_SERVER if self.drives.len() == 1 => self.drives[0].device.address(),
            0..=247 => unit,
            _ => {
                self.gateway_exception(ci, &header, pdu, mbap::EXCEPTION_GATEWAY_PATH_UNAVAILABLE);
                return;
            }
        };
        let mut frame = [0u8; MAX_FRAME];
        frame[0] = address;
        frame[1..=pdu.len()].copy_from_slice(pdu);
        let n = with_crc(&mut frame, 1 + pdu.len());
        let label = self.mbap.conns[ci].label.clone();
        let mut answered = false;
        for di in 0..self.drives.len() {
            let mut replies = VecDeque::new();
            let rx = RxEvent::Frame {
                bytes: &frame[..n],
                parity_error: false,
            };
            let served = serve(&mut self.drives[di], di, rx, None, now, &mut replies);
            log_events(&mut self.console, &mut self.drives[di], Some(&label));
            if !served.queued {
                self.reply_done(di, served.line);
                continue;
            }
            for r in replies {
                let mut adu = Vec::new();
                // address, PDU, CRC: the PDU goes back; a second answer
                // (two drives at one address) is a collision and dropped
                if r.bytes.len() >= 4 && !answered {
                    answered = true;
                    let mut buf = [0u8; MAX_ADU];
                    let m =
                        mbap::encode_response(&header, &r.bytes[1..r.bytes.len() - 2], &mut buf);
                    adu.extend_from_slice(&buf[..m]);
                }
                self.mbap.conns[ci].queued.push_back(Queued {
                    due_us: r.due_us,
                    adu,
                    drive: Some((r.drive, r.line)),
                });
            }
        }
        if !answered && address != modbus_drive::slave::BROADCAST {
            self.gateway_exception(ci, &header, pdu, mbap::EXCEPTION_GATEWAY_TARGET_FAILED);
        }
    }

    /// A gateway's own exception response (0x0A / 0x0B), logged and counted.
    fn gateway_exception(&mut self, ci: usize, header: &Header, pdu: &[u8], code: u8) {
        self.mbap.stats.gateway_exceptions += 1;
        let function = pdu.first().copied().unwrap_or(0);
        let mut buf = [0u8; MAX_ADU];
        let n = mbap::encode_response(header, &mbap::exception_pdu(function, code), &mut buf);
        let conn = &mut self.mbap.conns[ci];
        let why = if code == mbap::EXCEPTION_GATEWAY_PATH_UNAVAILABLE {
            "is no drive address (several drives: 0 broadcasts, 1..=247 select)"
        } else {
            "has no drive that answers"
        };
        let msg = format!(
            "{}: unit {} {why}: exception 0x{code:02X}",
            conn.label,
            header.unit()
        );
        let due_us = conn.queued.back().map_or(0, |q| q.due_us);
        conn.queued.push_back(Queued {
            due_us,
            adu: buf[..n].to_vec(),
            drive: None,
        });
        self.console.log(&msg);
    }

    /// Moves due responses to their connections' output and sends them;
    /// each drive's reply counts as sent then (SPEC §7: a new address or
    /// line takes effect after the reply).
    pub(super) fn modbus_tcp_send_due(&mut self, now: u64) {
        self.expire_partial_adus(now);
        self.expire_idle(now);
        let mut done = Vec::new();
        for ci in 0..self.mbap.conns.len() {
            let conn = &mut self.mbap.conns[ci];
            while conn.queued.front().is_some_and(|q| q.due_us <= now) {
                let Some(q) = conn.queued.pop_front() else {
                    break;
                };
                conn.last_activity_us = now;
                conn.out.extend_from_slice(&q.adu);
                done.extend(q.drive);
            }
            self.flush_conn(ci);
        }
        self.finish_replies(done);
    }

    /// Closes the connections whose unfinished ADU has waited
    /// [`ADU_TIMEOUT_US`] for its rest (module docs).
    fn expire_partial_adus(&mut self, now: u64) {
        for ci in (0..self.mbap.conns.len()).rev() {
            let conn = &self.mbap.conns[ci];
            // not while its input is left unread (replies pile up): the
            // rest may be waiting in the socket
            let expired = conn
                .partial_since_us
                .is_some_and(|t| now >= t + ADU_TIMEOUT_US);
            if expired && conn.wants_input() {
                let why = format!(
                    " (the rest of a request did not come within {} ms)",
                    ADU_TIMEOUT_US / 1000
                );
                self.close_conn(ci, &why);
            }
        }
    }

    /// Closes the connections idle for the idle timeout (module docs).
    fn expire_idle(&mut self, now: u64) {
        let Some(timeout) = self.mbap.idle_timeout_us else {
            return;
        };
        for ci in (0..self.mbap.conns.len()).rev() {
            let conn = &self.mbap.conns[ci];
            // a reply the peer has not taken for so long does not hold
            // the connection open: only one being received or made does
            let busy = conn.decoder.pending() > 0 || !conn.queued.is_empty();
            if !busy && now >= conn.last_activity_us + timeout {
                self.mbap.stats.idle_closed += 1;
                let why = format!(" (idle for {} s)", timeout / 1_000_000);
                self.close_conn(ci, &why);
            }
        }
    }

    fn finish_replies(&mut self, done: Vec<(usize, Option<LineConfig>)>) {
        for (di, line) in done {
            self.reply_done(di, line);
        }
    }

    fn flush_conn(&mut self, ci: usize) {
        let now_us = self.clock.now_us();
        let conn = &mut self.mbap.conns[ci];
        while !conn.out.is_empty() {
            match conn.stream.write(&conn.out) {
                Ok(n) => {
                    conn.out.drain(..n);
                    conn.last_activity_us = now_us;
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => return,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => {
                    let msg = format!("{}: write failed: {e}", conn.label);
                    conn.out.clear();
                    self.console.log(&msg);
                    return;
                }
            }
        }
    }

    /// Closes connection `ci` (`why` is appended to the log line). Replies
    /// it still waited for count as sent: a line change they carry takes
    /// effect now (a drive stays busy after an EE operation only until its
    /// reply was due, whoever waits for it).
    fn close_conn(&mut self, ci: usize, why: &str) {
        let conn = self.mbap.conns.remove(ci);
        let mut note = String::new();
        if conn.decoder.pending() > 0 {
            self.mbap.stats.truncated += 1;
            note = format!(
                ", {} bytes of an unfinished request dropped ({} bad ADUs)",
                conn.decoder.pending(),
                self.mbap.stats.bad_adus()
            );
        }
        self.console
            .log(&format!("{}: closed{why}{note}", conn.label));
        let done = conn.queued.into_iter().filter_map(|q| q.drive).collect();
        self.finish_replies(done);
    }
}
