//! The event loop: one thread owns every drive and every line; `poll(2)`
//! waits for bytes, new connections or the next deadline (a frame's t3.5,
//! a reply's due time, the control loop).
//!
//! Frame path per line (SPEC §1):
//! - bytes are stamped with the time they were read (end of character = read
//!   time; a master writes a whole frame at once, so gaps inside it are ~0);
//! - each drive frames the stream with its own [`FrameAssembler`] at its own
//!   line timing (PA52/PA53), as each drive on a real bus has its own UART;
//! - a frame closes after the drive's t3.5 of silence (`poll`) and goes to
//!   [`Device::poll`] (`run/serve.rs`), which queues the reply with the time
//!   it may leave and a new line format behind it; the loop writes it in one
//!   go when it is due.

use std::collections::VecDeque;
use std::io;
use std::os::fd::BorrowedFd;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use modbus_drive::dictionary::DriveLayer;
use modbus_drive::rtu::{FrameAssembler, LineConfig, RxFlags};
use nix::poll::{poll, PollFd, PollFlags, PollTimeout};

use super::cli::Options;
use super::console::Console;
use super::trace::{Sample, Trace};
use super::transport::{listen_error, Listener, Pty, ReadOutcome, Stream};
use super::web::WebPort;

mod drive_slot;
mod encoder;
mod modbus_tcp;
mod serve;

use drive_slot::{log_events, DriveSlot};

use serve::{serve, PendingReply, Served};

/// Longest sleep of the loop: the status line and trace keep ticking.
const IDLE_WAKE_US: u64 = 20_000;
/// Output a peer does not read is dropped beyond this (a master that went
/// away from the pty without reading its last reply).
const OUT_LIMIT: usize = 64 * 1024;

/// Microseconds since start, monotonic.
struct Clock(Instant);

impl Clock {
    fn now_us(&self) -> u64 {
        self.0.elapsed().as_micros() as u64
    }
}

/// One line: a byte stream and, per drive, that drive's receiver.
struct Line {
    label: String,
    stream: Stream,
    framers: Vec<FrameAssembler>,
    last_rx_us: u64,
    inbuf: Vec<u8>,
    out: Vec<u8>,
    pending: VecDeque<PendingReply>,
}

impl Line {
    fn new(label: String, stream: Stream, drives: &[DriveSlot]) -> Self {
        Self {
            label,
            stream,
            framers: drives
                .iter()
                .map(|d| FrameAssembler::new(d.device.line().timing()))
                .collect(),
            last_rx_us: 0,
            inbuf: Vec::new(),
            out: Vec::new(),
            pending: VecDeque::new(),
        }
    }
}

pub struct VirtualDrive {
    clock: Clock,
    drives: Vec<DriveSlot>,
    lines: Vec<Line>,
    listeners: Vec<Listener>,
    console: Console,
    trace: Trace,
    /// `--modbus-tcp` (`run/modbus_tcp.rs`).
    mbap: modbus_tcp::ModbusTcp,
    web: Option<WebPort>,
}

/// Startup failure, reported with exit status 1.
pub struct StartError(pub String);

impl VirtualDrive {
    /// Opens every transport; when this returns, frames are accepted.
    pub fn start(opts: &Options) -> Result<Self, StartError> {
        let mut console = Console::new(opts.status_line);
        let mut drives = Vec::new();
        for (i, &address) in opts.drives.iter().enumerate() {
            drives.push(
                DriveSlot::new(address, i, opts.state.as_deref(), opts.axis, opts.board)
                    .map_err(StartError)?,
            );
        }
        let mut lines = Vec::new();
        if opts.pty {
            let pty = Pty::open(opts.pty_link.as_deref()).map_err(StartError)?;
            let mut label = format!("pty {}", pty.path.display());
            if let Some(l) = &opts.pty_link {
                label.push_str(&format!(" (link {})", l.display()));
            }
            console.log(&format!("serial: {label}"));
            lines.push(Line::new("pty".into(), Stream::Pty(pty), &drives));
        }
        let mut listeners = Vec::new();
        for &addr in &opts.tcp {
            let l =
                Listener::bind(addr).map_err(|e| StartError(listen_error("--tcp", addr, &e)))?;
            console.log(&format!("tcp: listening on {} (RTU framing)", l.addr));
            listeners.push(l);
        }
        let mut mbap = modbus_tcp::ModbusTcp::default();
        mbap.idle_timeout_us = opts.tcp_idle_timeout_s.map(|s| s * 1_000_000);
        for &addr in &opts.modbus_tcp {
            let l = Listener::bind(addr)
                .map_err(|e| StartError(listen_error("--modbus-tcp", addr, &e)))?;
            console.log(&format!(
                "modbus-tcp: listening on {} (MBAP framing)",
                l.addr
            ));
            mbap.listeners.push(l);
        }
        let web = match opts.web {
            Some(addr) => {
                let w = WebPort::start(addr, opts.web_token.clone(), drives.len())
                    .map_err(|e| StartError(format!("cannot serve the page on {addr}: {e}")))?;
                console.log(&format!("web: page on {}", w.url()));
                Some(w)
            }
            None => None,
        };
        for d in &mut drives {
            if opts.standard_exceptions {
                d.device.configure(|pa, _| pa.set_standard_exceptions(true));
            }
            // The first control call: a fault the drive starts in (both
            // limits active) is reported now, not with the first frame.
            d.advance(0);
            log_events(&mut console, d, None);
        }
        let trace = Trace::new(opts.trace.as_deref(), opts.plot.as_deref(), drives.len())
            .map_err(StartError)?;
        for d in &drives {
            let line = d.device.line();
            console.log(&format!(
                "{}: {} baud, t3.5 = {} µs, reply delay {} µs",
                d.label(),
                line.baud(),
                line.timing().t35_us(),
                d.device.reply_delay_us()
            ));
        }
        Ok(Self {
            clock: Clock(Instant::now()),
            drives,
            lines,
            listeners,
            console,
            trace,
            mbap,
            web,
        })
    }

    /// Runs until `stop` is set (SIGINT / SIGTERM), then writes trace and plot.
    pub fn run(mut self, stop: &Arc<AtomicBool>) -> Result<(), String> {
        while !stop.load(Ordering::SeqCst) {
            let now = self.clock.now_us();
            for di in 0..self.drives.len() {
                self.drives[di].advance(now);
                // what the control loop reports belongs to no line
                self.log_events(di, None);
            }
            self.serve_web(now);
            self.close_frames(now);
            self.send_due_replies(now);
            self.modbus_tcp_send_due(now);
            self.observe(now);
            let timeout = self.next_deadline(now).saturating_sub(self.clock.now_us());
            self.wait_and_read(timeout)?;
        }
        self.console.finish();
        match self.trace.finish() {
            Ok(files) => {
                for f in files {
                    self.console.log(&format!("wrote {}", f.display()));
                }
                Ok(())
            }
            Err(e) => Err(e),
        }
    }

    /// The page's commands, between two frames of any line (`web/`).
    fn serve_web(&mut self, now: u64) {
        let Some(web) = &mut self.web else {
            return;
        };
        if !self.mbap.listeners.is_empty() {
            web.set_modbus_tcp(self.mbap.stats_json());
        }
        for (di, line) in web.serve(now, &mut self.drives) {
            log_events(&mut self.console, &mut self.drives[di], Some("web"));
            // A bus reply still queued for this drive puts a new line
            // format in force when it leaves; else it takes effect now.
            let next_out = self
                .lines
                .iter_mut()
                .flat_map(|l| l.pending.iter_mut())
                .filter(|p| p.drive == di)
                .min_by_key(|p| p.due_us);
            match next_out {
                Some(reply) => reply.line = line.or(reply.line),
                None => self.reply_done(di, line),
            }
        }
    }

    /// Closes frames whose t3.5 has passed and hands them to their drive.
    fn close_frames(&mut self, now: u64) {
        for li in 0..self.lines.len() {
            for di in 0..self.drives.len() {
                let line = &mut self.lines[li];
                let last_rx_us = line.last_rx_us;
                if let Some(ev) = line.framers[di].poll(now as u32) {
                    let served = serve(
                        &mut self.drives[di],
                        di,
                        ev,
                        Some(last_rx_us),
                        now,
                        &mut line.pending,
                    );
                    self.after_frame(li, di, served);
                }
            }
        }
    }

    /// Logs what the core reported, and finishes a silent frame at once.
    fn after_frame(&mut self, li: usize, di: usize, served: Served) {
        self.log_events(di, Some(li));
        if !served.queued {
            self.reply_done(di, served.line);
        }
    }

    /// The reply (or silence) is out: a new line format of drive `di`
    /// takes effect on every line's receiver for it.
    fn reply_done(&mut self, di: usize, line: Option<LineConfig>) {
        if let Some(cfg) = line {
            for line in &mut self.lines {
                line.framers[di].set_timing(cfg.timing());
            }
        }
        self.log_events(di, None);
    }

    /// Drains drive `di`'s core events to the log.
    fn log_events(&mut self, di: usize, line: Option<usize>) {
        let on = line.map(|li| self.lines[li].label.as_str());
        log_events(&mut self.console, &mut self.drives[di], on);
    }

    fn send_due_replies(&mut self, now: u64) {
        let mut done = Vec::new();
        for li in 0..self.lines.len() {
            let line = &mut self.lines[li];
            while line.pending.front().is_some_and(|p| p.due_us <= now) {
                let Some(p) = line.pending.pop_front() else {
                    break;
                };
                if line.out.len() + p.bytes.len() > OUT_LIMIT {
                    line.out.clear();
                }
                line.out.extend_from_slice(&p.bytes);
                done.push((p.drive, p.line));
            }
            if let Err(e) = line.stream.flush(&mut line.out) {
                let msg = format!("{}: write failed: {e}", line.label);
                line.out.clear();
                self.console.log(&msg);
            }
        }
        for (di, line) in done {
            self.reply_done(di, line);
        }
    }

    /// Status line and trace: what the drives report now.
    fn observe(&mut self, now: u64) {
        let mut status = Vec::new();
        for (di, d) in self.drives.iter_mut().enumerate() {
            let drive = d.device.drive();
            let sample = Sample {
                time_us: now,
                drive: di,
                address: d.device.address(),
                position_steps: drive.actual_position(),
                velocity_rpm: drive.actual_velocity_rpm(),
                statusword: drive.statusword(),
                mode: drive.mode_display(),
            };
            let mut changes = Vec::new();
            if sample.statusword != d.last_statusword {
                changes.push(format!(
                    "statusword 0x{:04X} -> 0x{:04X}",
                    d.last_statusword, sample.statusword
                ));
                d.last_statusword = sample.statusword;
            }
            if sample.mode != d.last_mode {
                changes.push(format!("mode {} -> {}", d.last_mode, sample.mode));
                d.last_mode = sample.mode;
            }
            if !changes.is_empty() {
                let msg = format!("drive {}: {}", sample.address, changes.join(", "));
                self.console.log(&msg);
            }
            if let Err(e) = self.trace.offer(sample) {
                self.console.log(&format!("trace: {e}"));
            }
            let counters = d.device.slave().counters();
            // the following error beside the position once an encoder is in use
            let ferr = if drive.closed_loop() {
                format!(" ferr {}", drive.following_error())
            } else {
                String::new()
            };
            status.push(format!(
                "@{} {:?} sw 0x{:04X} mode {} pos {}{ferr} vel {} r/min frames {} errors {}",
                sample.address,
                drive.state(),
                sample.statusword,
                sample.mode,
                sample.position_steps,
                sample.velocity_rpm,
                counters.bus_messages(),
                u32::from(counters.bus_errors()) + u32::from(counters.overruns()),
            ));
        }
        let conns = self
            .lines
            .iter()
            .filter(|l| matches!(l.stream, Stream::Tcp(_)))
            .count();
        let mb = &self.mbap;
        let modbus_tcp = if mb.listeners.is_empty() {
            String::new()
        } else {
            format!(
                " | modbus-tcp conns {} requests {} bad ADUs {} idle-closed {} evicted {} \
                 refused {}",
                mb.connections(),
                mb.stats.requests,
                mb.stats.bad_adus(),
                mb.stats.idle_closed,
                mb.stats.evicted,
                mb.stats.refused
            )
        };
        self.console.status(format!(
            "{} | tcp conns {conns}{modbus_tcp}",
            status.join(" | ")
        ));
    }

    /// The next time the loop must run even without input.
    fn next_deadline(&self, now: u64) -> u64 {
        let mut at = now + IDLE_WAKE_US;
        for d in &self.drives {
            at = at.min(d.device.poll_at());
        }
        for line in &self.lines {
            if let Some(p) = line.pending.front() {
                at = at.min(p.due_us);
            }
            for (di, f) in line.framers.iter().enumerate() {
                if f.is_receiving() {
                    let t35 = u64::from(self.drives[di].device.line().timing().t35_us());
                    at = at.min(line.last_rx_us + t35);
                }
            }
        }
        if self.trace.is_active() {
            at = at.min(now + super::trace::SAMPLE_PERIOD_US);
        }
        if let Some(due) = self.mbap.next_due() {
            at = at.min(due);
        }
        if let Some(web) = &self.web {
            at = at.min(web.next_due_us());
        }
        at
    }

    /// Waits up to `timeout_us` for input, then reads and frames it.
    fn wait_and_read(&mut self, timeout_us: u64) -> Result<(), String> {
        let (readable, writable, accept, modbus_tcp) = {
            let mut fds: Vec<PollFd> = Vec::new();
            for line in &self.lines {
                let mut ev = PollFlags::POLLIN;
                if !line.out.is_empty() {
                    ev |= PollFlags::POLLOUT;
                }
                fds.push(PollFd::new(line.stream.fd(), ev));
            }
            for l in &self.listeners {
                let fd: BorrowedFd<'_> = std::os::fd::AsFd::as_fd(&l.socket);
                fds.push(PollFd::new(fd, PollFlags::POLLIN));
            }
            let m = fds.len();
            fds.extend(self.mbap.poll_fds());
            // Round up so a deadline is never missed by sleeping too little.
            let ms = timeout_us.div_ceil(1000).min(u64::from(u16::MAX)) as u16;
            match poll(&mut fds, PollTimeout::from(ms)) {
                Ok(_) => {}
                Err(nix::errno::Errno::EINTR) => return Ok(()),
                Err(e) => return Err(format!("poll: {e}")),
            }
            let ready = |fd: &PollFd, f: PollFlags| fd.revents().is_some_and(|r| r.intersects(f));
            let n = self.lines.len();
            let in_flags = PollFlags::POLLIN | PollFlags::POLLHUP | PollFlags::POLLERR;
            (
                fds[..n]
                    .iter()
                    .map(|f| ready(f, in_flags))
                    .collect::<Vec<_>>(),
                fds[..n]
                    .iter()
                    .map(|f| ready(f, PollFlags::POLLOUT))
                    .collect::<Vec<_>>(),
                fds[n..m]
                    .iter()
                    .map(|f| ready(f, PollFlags::POLLIN))
                    .collect::<Vec<_>>(),
                fds[m..].iter().map(|f| f.revents()).collect::<Vec<_>>(),
            )
        };

        let mut closed = Vec::new();
        for li in 0..self.lines.len() {
            if writable[li] {
                let line = &mut self.lines[li];
                if let Err(e) = line.stream.flush(&mut line.out) {
                    let msg = format!("{}: write failed: {e}", line.label);
                    line.out.clear();
                    self.console.log(&msg);
                }
            }
            if readable[li] && !self.read_line(li) {
                closed.push(li);
            }
        }
        for li in closed.into_iter().rev() {
            let line = self.lines.remove(li);
            self.console.log(&format!("{}: closed", line.label));
        }
        for (i, ready) in accept.into_iter().enumerate() {
            if ready {
                self.accept(i);
            }
        }
        self.modbus_tcp_ready(&modbus_tcp);
        Ok(())
    }

    /// Reads a ready line and feeds the bytes to every drive's receiver.
    /// Returns false when the line is gone.
    fn read_line(&mut self, li: usize) -> bool {
        let mut buf = std::mem::take(&mut self.lines[li].inbuf);
        buf.clear();
        let outcome = self.lines[li].stream.read_available(&mut buf);
        let alive = match outcome {
            Ok(ReadOutcome::Data) => true,
            Ok(ReadOutcome::Closed) => false,
            Err(e) => {
                let msg = format!("{}: read failed: {e}", self.lines[li].label);
                self.console.log(&msg);
                !matches!(self.lines[li].stream, Stream::Tcp(_))
            }
        };
        if !buf.is_empty() {
            let now = self.clock.now_us();
            // Frames whose t3.5 ran out before these bytes came close first.
            self.close_frames(now);
            for di in 0..self.drives.len() {
                for &b in &buf {
                    let line = &mut self.lines[li];
                    let last_rx_us = line.last_rx_us;
                    let ev = line.framers[di].push(b, now as u32, RxFlags::NONE);
                    if let Some(ev) = ev {
                        let served = serve(
                            &mut self.drives[di],
                            di,
                            ev,
                            Some(last_rx_us),
                            now,
                            &mut line.pending,
                        );
                        self.after_frame(li, di, served);
                    }
                }
            }
            self.lines[li].last_rx_us = now;
        }
        self.lines[li].inbuf = buf;
        alive
    }

    fn accept(&mut self, i: usize) {
        loop {
            match self.listeners[i].accept() {
                Ok(Some((stream, peer))) => {
                    let label = format!("tcp {peer}");
                    self.console.log(&format!("{label}: connected"));
                    self.lines
                        .push(Line::new(label, Stream::Tcp(stream), &self.drives));
                }
                Ok(None) => return,
                Err(e) => {
                    let msg = format!("tcp {}: accept failed: {e}", self.listeners[i].addr);
                    self.console.log(&msg);
                    return;
                }
            }
        }
    }
}

impl From<io::Error> for StartError {
    fn from(e: io::Error) -> Self {
        Self(e.to_string())
    }
}
