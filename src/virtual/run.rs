//! The event loop: one thread owns every drive and every line; `poll(2)`
//! waits for bytes, new connections or the next deadline (a frame's t3.5,
//! a reply's due time, the control loop).
//!
//! Frame path per line (SPEC §1):
//! - bytes are stamped with the time they were read (end of character = read
//!   time; a master writes a whole frame at once, so gaps inside it are ~0);
//! - each drive frames the stream with its own [`FrameAssembler`] at its own
//!   line timing (PA52/PA53), as each drive on a real bus has its own UART;
//! - a frame closes after the drive's t3.5 of silence (`poll`), goes to
//!   [`Device::handle_rx`], and a reply leaves in one write at
//!   `last byte + Device::reply_delay_us()` at the earliest;
//! - [`Device::reply_sent`] follows every handled frame, after the write.

use std::collections::VecDeque;
use std::io;
use std::os::fd::BorrowedFd;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use modbus_drive::boards::Board;
use modbus_drive::device::{Identity, Response};
use modbus_drive::dictionary::DriveLayer;
use modbus_drive::drive::DriveEvent;
use modbus_drive::event::{Event, FrameError};
use modbus_drive::motion::sim::{RunStop, SimAxis};
use modbus_drive::motion::{PlannerConfig, StepSchedule};
use modbus_drive::params::{BootOutcome, ParamStore};
use modbus_drive::rtu::{FrameAssembler, RxEvent, RxFlags, MAX_FRAME};
use modbus_drive::Device;
use nix::poll::{poll, PollFd, PollFlags, PollTimeout};

use super::cli::{AxisLayout, Options};
use super::console::Console;
use super::flash::{FileFlash, REGION_BYTES};
use super::trace::{Sample, Trace};
use super::transport::{listen_error, Listener, Pty, ReadOutcome, Stream};
use super::web::{self, ExceptionLog, Forced, WebPort};

mod modbus_tcp;

/// Longest sleep of the loop: the status line and trace keep ticking.
const IDLE_WAKE_US: u64 = 20_000;
/// Control loop period, as on the firmware (SPEC §8; within the planner's
/// 3 ms horizon).
const CONTROL_PERIOD_US: u64 = 1_000;
/// Control periods made up at once after the process was held up longer
/// (suspended, debugger); beyond that simulated time skips ahead.
const CATCH_UP_PERIODS_MAX: u64 = 5_000;
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

/// One simulated drive.
struct DriveSlot {
    device: Device,
    /// Its parameter flash: region of the `--state` file, or memory only.
    store: ParamStore<FileFlash>,
    /// The steps the core plans; the simulated step interrupt consumes them.
    schedule: Box<StepSchedule>,
    /// Step interrupt, motor and switches.
    axis: SimAxis,
    /// Time of the next periodic control call, µs.
    next_control_us: u64,
    last_statusword: u16,
    last_mode: i16,
    /// Switches forced from the page (`--web`).
    forced: Forced,
    /// The last exceptions answered, for the page.
    exceptions: ExceptionLog,
}

impl DriveSlot {
    /// Drive number `index` of `--drives`, at `address`, with its flash.
    /// At power-up it loads what its flash holds (SPEC §9). A saved set wins
    /// over `--drives`, PA51 included — it is what the drive's flash says;
    /// a blank or unreadable flash keeps the `--drives` address.
    fn new(
        address: u8,
        index: usize,
        state: Option<&Path>,
        layout: AxisLayout,
        board: Board,
    ) -> Result<Self, String> {
        let flash = match state {
            Some(path) => FileFlash::open(path, index)
                .map_err(|e| format!("--state {}: {e}", path.display()))?,
            None => FileFlash::in_memory(),
        };
        let mut store = ParamStore::new(flash, 0..REGION_BYTES as u32)
            .map_err(|e| format!("parameter store: {e:?}"))?;
        let mut device = Device::new(Identity::new("virtual"));
        // steps timed in the chosen board's timer ticks, as its firmware
        // does: the same limits (`--board`)
        let planner = PlannerConfig {
            tick_hz: board.step_tick_hz(),
            ..PlannerConfig::default()
        };
        device.set_planner_config(planner);
        let boot = store.boot();
        device.apply_boot(&boot);
        if !matches!(boot.outcome, BootOutcome::Loaded { .. }) {
            // `--drives` gives each drive its address (PA51, SPEC §7), in
            // force at once: no change worth logging
            device.configure(|pa, _| pa.set_address(address));
        }
        let last_statusword = device.drive().statusword();
        let last_mode = device.drive().mode_display();
        Ok(Self {
            device,
            store,
            schedule: Box::new(StepSchedule::new()),
            axis: sim_axis(layout, planner.tick_hz),
            next_control_us: 0,
            last_statusword,
            last_mode,
            forced: Forced::default(),
            exceptions: ExceptionLog::new(),
        })
    }

    /// Runs the axis and the control loop up to `now_us`: every control
    /// period in turn, in simulated time, so a late wake-up of the process
    /// never starves the step schedule. A step that changes a switch stops
    /// the axis there and the drive sees the new states at that instant
    /// (SPEC §8.6: the origin is the step where the edge was seen).
    fn advance(&mut self, now_us: u64) {
        if now_us.saturating_sub(self.next_control_us) > CATCH_UP_PERIODS_MAX * CONTROL_PERIOD_US {
            // Held up for seconds: time jumps (the axis idles through it).
            self.next_control_us = now_us;
        }
        while self.next_control_us <= now_us {
            let t = self.next_control_us;
            self.control_at(t);
            self.next_control_us = t + CONTROL_PERIOD_US;
        }
    }

    /// One control call at `t_us` (not earlier than the last one), after
    /// the axis made every step up to then.
    fn control_at(&mut self, t_us: u64) {
        let until = self.axis.us_to_ticks(t_us);
        // the simulated limit-switch interrupt applies PA14 as the board's
        self.axis
            .set_limit_enable(self.device.params().limit_enable());
        while self.axis.run_until(&self.schedule, until, |_| {}) == RunStop::SwitchChanged {
            let at = self.axis.now_us();
            let switches = self.forced.apply(self.axis.switches());
            self.device.control(at, switches, &self.schedule);
            self.axis.kick(&self.schedule);
        }
        let switches = self.forced.apply(self.axis.switches());
        self.device.control(t_us, switches, &self.schedule);
        self.axis.kick(&self.schedule);
    }

    fn label(&self) -> String {
        format!("drive {}", self.device.address())
    }
}

/// The simulated axis with the `--cw-limit` / `--ccw-limit` /
/// `--home-switch` switches, at the step timer frequency the planner uses.
fn sim_axis(layout: AxisLayout, tick_hz: u32) -> SimAxis {
    // with the limit-switch interrupt: the step interrupt brakes at the
    // edge step, as on the board (SPEC §8.7)
    let mut axis = SimAxis::new(tick_hz).with_limit_interrupt();
    if let Some(edge) = layout.cw_limit_steps {
        axis = axis.with_cw_limit(i64::from(edge));
    }
    if let Some(edge) = layout.ccw_limit_steps {
        axis = axis.with_ccw_limit(i64::from(edge));
    }
    if let Some(w) = layout.home_switch {
        axis = axis.with_home(i64::from(w.from_steps), i64::from(w.to_steps));
    }
    axis
}

struct PendingReply {
    due_us: u64,
    drive: usize,
    /// Empty: nothing to send (a broadcast EE operation).
    bytes: Vec<u8>,
    /// The deferred reply of an EE operation: the drive is busy until it is out.
    ee: bool,
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
                let w = WebPort::start(addr, drives.len())
                    .map_err(|e| StartError(format!("cannot serve the page on {addr}: {e}")))?;
                console.log(&format!("web: page on http://{}/", w.addr));
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
                line.baud,
                line.timing().t35_us,
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
        for di in web.serve(now, &mut self.drives) {
            log_events(&mut self.console, &mut self.drives[di], Some("web"));
            // A bus reply still queued for this drive applies a deferred
            // address or line change when it leaves; else it applies now.
            let queued = self
                .lines
                .iter()
                .any(|l| l.pending.iter().any(|p| p.drive == di));
            if !queued {
                self.reply_done(di);
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
                    let replied = handle(
                        &mut self.drives[di],
                        di,
                        ev,
                        last_rx_us,
                        now,
                        &mut line.pending,
                    );
                    self.after_frame(li, di, replied);
                }
            }
        }
    }

    /// Logs what the core reported, and finishes a silent frame at once.
    fn after_frame(&mut self, li: usize, di: usize, replied: bool) {
        self.log_events(di, Some(li));
        if !replied {
            self.reply_done(di);
        }
    }

    /// The reply (or silence) is out: deferred address / line changes apply.
    fn reply_done(&mut self, di: usize) {
        if let Some(cfg) = self.drives[di].device.reply_sent() {
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
                done.push((p.drive, p.ee));
            }
            if let Err(e) = line.stream.flush(&mut line.out) {
                let msg = format!("{}: write failed: {e}", line.label);
                line.out.clear();
                self.console.log(&msg);
            }
        }
        for (di, ee) in done {
            if ee {
                self.drives[di].device.set_storage_busy(false);
            }
            self.reply_done(di);
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
            status.push(format!(
                "@{} {:?} sw 0x{:04X} mode {} pos {} vel {} r/min frames {} errors {}",
                sample.address,
                drive.state(),
                sample.statusword,
                sample.mode,
                sample.position_steps,
                sample.velocity_rpm,
                counters.bus_messages,
                u32::from(counters.bus_errors) + u32::from(counters.overruns),
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
                " | modbus-tcp conns {} requests {} bad ADUs {}",
                mb.connections(),
                mb.stats.requests,
                mb.stats.bad_adus()
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
            at = at.min(d.next_control_us);
        }
        for line in &self.lines {
            if let Some(p) = line.pending.front() {
                at = at.min(p.due_us);
            }
            for (di, f) in line.framers.iter().enumerate() {
                if f.is_receiving() {
                    let t35 = u64::from(self.drives[di].device.line().timing().t35_us);
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
                        let replied = handle(
                            &mut self.drives[di],
                            di,
                            ev,
                            last_rx_us,
                            now,
                            &mut line.pending,
                        );
                        self.after_frame(li, di, replied);
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

/// Hands a closed frame to its drive and queues what it answers. Returns
/// whether something was queued (then `reply_sent` waits until it is out).
///
/// An accepted EE operation (SPEC §9) runs on the flash at once; its reply
/// leaves no earlier than the chip would have finished (the flash's time
/// tally) and the drive answers exception 6 to other requests until then.
fn handle(
    slot: &mut DriveSlot,
    di: usize,
    ev: RxEvent<'_>,
    last_rx_us: u64,
    now_us: u64,
    pending: &mut VecDeque<PendingReply>,
) -> bool {
    let due_us = last_rx_us + u64::from(slot.device.reply_delay_us());
    handle_due(slot, di, ev, due_us, now_us, pending)
}

/// [`handle`] with the reply's earliest time given (Modbus TCP has no
/// serial-line reply delay).
fn handle_due(
    slot: &mut DriveSlot,
    di: usize,
    ev: RxEvent<'_>,
    mut due_us: u64,
    now_us: u64,
    pending: &mut VecDeque<PendingReply>,
) -> bool {
    // The drive acts on a frame at the time it closed (SPEC §8: control
    // after each handled frame), with its axis up to date.
    slot.advance(now_us);
    let mut reply = [0u8; MAX_FRAME];
    let mut response = slot.device.handle_rx(ev, &mut reply);
    let mut ee = false;
    if let Some(r) = slot.device.poll_storage(&mut slot.store, &mut reply) {
        response = r;
        ee = true;
        due_us = due_us.max(now_us + slot.store.flash().take_busy_us());
        slot.device.set_storage_busy(true);
    }
    let bytes = match response {
        Response::Reply(n) => reply[..n.min(MAX_FRAME)].to_vec(),
        Response::Silent if ee => Vec::new(),
        Response::Silent => {
            slot.control_at(now_us);
            return false;
        }
    };
    slot.control_at(now_us);
    pending.push_back(PendingReply {
        due_us,
        drive: di,
        bytes,
        ee,
    });
    true
}

/// Logs the core events of `slot` (and the file error behind a failed
/// flash operation, which the core only knows as "flash failed").
fn log_events(console: &mut Console, slot: &mut DriveSlot, line: Option<&str>) {
    while let Some(ev) = slot.device.take_event() {
        // the vendor code names the cause; say what went on the wire
        let mut sent_as = String::new();
        if let Event::Exception {
            function,
            exception,
            answered,
        } = ev
        {
            let standard = slot.device.params().standard_exceptions();
            let code = exception.code(standard).unwrap_or(exception.vendor_code());
            let port = line.unwrap_or("-");
            slot.exceptions.record(port, function, code, answered);
            if answered && code != exception.vendor_code() {
                sent_as = format!(", sent as {code} (PA55 = 1)");
            }
        }
        let on = line.map_or(String::new(), |l| format!(" on {l}"));
        let failed = matches!(
            ev,
            Event::EeDone { error: Some(_), .. } | Event::ParamsLoaded(BootOutcome::Unreadable(_))
        );
        let cause = match slot.store.flash().take_io_error() {
            Some(e) if failed => format!(": {e}"),
            _ => String::new(),
        };
        console.log(&format!(
            "{}{on}: {}{sent_as}{cause}",
            slot.label(),
            describe(&ev)
        ));
    }
}

/// A core event in words.
fn describe(ev: &Event) -> String {
    match *ev {
        Event::FrameError {
            kind,
            address,
            answered,
        } => {
            let what = match kind {
                FrameError::Crc => "CRC error",
                FrameError::Parity => "parity error",
                FrameError::Broken => "broken frame (silence > t1.5 inside it)",
                FrameError::TooShort => "frame shorter than 4 bytes",
                FrameError::Overrun => "frame longer than 256 bytes",
            };
            let from = address.map_or(String::new(), |a| format!(" (address byte {a})"));
            let answer = if answered { ", answered" } else { "" };
            format!("{what}{from}{answer}")
        }
        Event::Exception {
            function,
            exception,
            answered,
        } => format!(
            "function 0x{function:02X} refused: exception {} ({exception:?}){}",
            exception.vendor_code(),
            if answered { "" } else { ", not answered" }
        ),
        Event::AddressChanged { address } => format!("address is now {address} (PA51)"),
        Event::LineChanged(line) => format!(
            "line is now {} baud {:?}, t3.5 = {} µs",
            line.baud,
            line.format,
            line.timing().t35_us
        ),
        Event::ListenOnly(true) => "listen-only mode (diagnostics 0x04)".into(),
        Event::ListenOnly(false) => "listen-only mode ended".into(),
        Event::CountersCleared => "diagnostic counters cleared".into(),
        Event::ParamsLoaded(BootOutcome::Loaded { fixed: 0 }) => "saved parameters loaded".into(),
        Event::ParamsLoaded(BootOutcome::Loaded { fixed }) => {
            format!("saved parameters loaded, {fixed} out of range set to default")
        }
        Event::ParamsLoaded(BootOutcome::Blank) => "no saved parameters: defaults".into(),
        Event::ParamsLoaded(BootOutcome::Unreadable(e)) => {
            format!("saved parameters unreadable ({e:?}): defaults")
        }
        Event::Drive(d) => match d {
            DriveEvent::State(state) => format!("state {state:?}"),
            DriveEvent::Fault(cause) => format!("fault: {cause:?}"),
            DriveEvent::LimitStop { cw: true } => "CW limit: motion stopped".into(),
            DriveEvent::LimitStop { cw: false } => "CCW limit: motion stopped".into(),
            DriveEvent::MotionRefused => "motion refused (statusword bit 7)".into(),
            DriveEvent::HomingAttained { origin } => format!("homing: origin at raw step {origin}"),
            DriveEvent::HomingDone => "homing done".into(),
            DriveEvent::HomingFailed(e) => format!("homing failed: {e:?}"),
            DriveEvent::ScheduleUnderrun => "step schedule ran dry (control loop late)".into(),
        },
        Event::EeDone { op, error: None } => format!("EE operation {op:?} done"),
        Event::EeDone { op, error: Some(e) } => format!("EE operation {op:?} failed ({e:?})"),
        other => format!("{other:?}"),
    }
}

/// The page reaches a drive through its dispatcher only (`web/modbus.rs`).
impl web::Dispatch for DriveSlot {
    fn device(&mut self) -> &mut Device {
        &mut self.device
    }

    fn run_storage(&mut self, reply: &mut [u8; MAX_FRAME]) -> Option<Response> {
        let r = self.device.poll_storage(&mut self.store, reply);
        // The page's answer waits for nothing: the flash's time is not
        // simulated for it, so its tally starts afresh.
        self.store.flash().take_busy_us();
        r
    }

    fn advance(&mut self, now_us: u64) {
        DriveSlot::advance(self, now_us);
    }

    fn control_at(&mut self, now_us: u64) {
        DriveSlot::control_at(self, now_us);
    }
}

impl web::Target for DriveSlot {
    fn view<'a>(&'a self, port: &'a modbus_drive::slave::Slave) -> web::View<'a> {
        web::View {
            device: &self.device,
            port,
            axis_switches: self.axis.switches(),
            forced: self.forced,
            exceptions: &self.exceptions,
        }
    }

    fn force(&mut self, switch: web::Switch, state: Option<bool>) {
        self.forced.set(switch, state);
    }
}

impl From<io::Error> for StartError {
    fn from(e: io::Error) -> Self {
        Self(e.to_string())
    }
}
