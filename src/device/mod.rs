//! The whole drive as the glue sees it: frames in, replies out; time and
//! switch states in, steps out; events out for the glue to log.
//!
//! Frame path: the host feeds bytes to an [`crate::rtu::FrameAssembler`]
//! and calls [`Device::poll`] with its [`Line`] and [`Storage`]; `poll`
//! runs the rest (dispatch, EE operation, reply timing, address and line
//! changes, `poll.rs`). The steps it is made of ([`Device::handle_rx`],
//! [`Device::poll_storage`], [`Device::reply_delay_us`],
//! [`Device::reply_sent`]) stay public for tests and tools.
//!
//! Parameter storage (SPEC §9, `params/storage.rs`):
//! - at power-up, `device.apply_boot(&store.boot())` before the first frame;
//! - an accepted EE request (`10 00 3A 00 01 02 00 0k`, or the old
//!   `06 00 00 00 0k`) is answered [`Response::Silent`] for now and makes the
//!   device busy: every register request that passes validation meanwhile
//!   gets exception 6 (§5.2 step 9); the UART keeps receiving;
//! - [`Device::poll`] then calls [`Device::poll_storage`] with the store.
//!   It runs the operation and returns the deferred reply:
//!   the 0x10 reply / the echo of the old frame once done, exception 4 if
//!   the flash failed, nothing for a broadcast. Send it like any reply
//!   (step 3, no earlier than `reply_delay_us` after the request) and call
//!   [`Device::reply_sent`] after it: an address or line changed by EE-rd /
//!   EE-rS / EE-dEF takes effect then, as after a PA51..53 write;
//! - under a moving axis (statusword bit 9) an EE request is refused with
//!   exception 6 and changes nothing, at the request and again when it is
//!   to run; glue that sees its step output busy by its own means refuses
//!   it with [`Device::refuse_storage`] instead of running it.

mod poll;
#[cfg(feature = "sim")]
pub mod sim;

use heapless::Deque;

pub use poll::{Line, Polled, Request, Storage};

pub use crate::dictionary::Identity;
use embedded_storage::nor_flash::NorFlash;

use crate::dictionary::{Config, DriveLayer, OdValues, Registers};
use crate::drive::Drive;
use crate::event::Event;
use crate::motion::{PlannerConfig, StepSchedule, StepSink, SwitchEdges, Switches};
use crate::params::{
    execute, Boot, BootOutcome, EeError, EeOp, ParamStore, Params, PendingEe, StoreStatus,
};
use crate::rtu::{with_crc, DriverEnable, LineConfig, RxEvent, MAX_FRAME};
pub use crate::slave::Response;
use crate::slave::Slave;

/// Events kept until the glue takes them; older ones are kept, newer ones
/// dropped (and counted) when it falls behind.
pub const EVENT_QUEUE_LEN: usize = 16;

/// One drive on the bus.
pub struct Device {
    identity: Identity,
    od: OdValues,
    pa: Params,
    drive: Drive,
    /// Dispatcher state: §6 counters and listen-only mode.
    slave: Slave,
    /// Busy for a reason of the glue's own (or a test's): register requests
    /// get exception 6 (§5.2 step 9). The device is also busy on its own
    /// while an EE operation waits for [`Device::poll_storage`].
    storage_busy: bool,
    /// The EE operation accepted and not yet run (§5.2 step 9: busy).
    ee_pending: Option<PendingEe>,
    /// An EE operation ran in [`Device::poll`] and its reply is due then
    /// (host µs): busy until that time.
    ee_busy_until_us: Option<u64>,
    /// What DP-Err says about the store.
    store_status: StoreStatus,
    /// Address, line and RS-485 DE lead / tail in force: PA51/52/53 and
    /// PA57/58 as they were when the last reply left (SPEC §7).
    address: u8,
    line: LineConfig,
    driver_enable: DriverEnable,
    events: Deque<Event, EVENT_QUEUE_LEN>,
    events_dropped: u32,
    /// Time of the last control call (none yet: due at once).
    last_control_us: Option<u64>,
}

/// The longest a host may leave between two [`Device::control`] calls, µs:
/// the planner keeps its horizon of steps ahead of the step interrupt
/// with this period ([`crate::motion::PlannerConfig`]).
pub const CONTROL_PERIOD_US: u64 = 1_000;

impl Device {
    pub fn new(identity: Identity) -> Self {
        Self::with_planner_config(identity, PlannerConfig::default())
    }

    /// [`Device::new`] with the planner's timing and the board's limits
    /// from the start (what [`Device::set_planner_config`] sets later): no
    /// second planner is built, which the firmware's boot stack notices.
    pub fn with_planner_config(identity: Identity, cfg: PlannerConfig) -> Self {
        let pa = Params::defaults();
        Self {
            identity,
            od: OdValues::default(),
            address: pa.address(),
            line: pa.line(),
            driver_enable: pa.driver_enable(),
            pa,
            drive: Drive::with_config(cfg),
            slave: Slave::new(),
            storage_busy: false,
            ee_pending: None,
            ee_busy_until_us: None,
            store_status: StoreStatus::default(),
            events: Deque::new(),
            events_dropped: 0,
            last_control_us: None,
        }
    }

    /// What the drive answers to Read Device Identification.
    pub fn identity(&self) -> &Identity {
        &self.identity
    }

    /// The working parameter set (PA01..PA56), read through its named
    /// accessors ([`Params::steps_per_rev`], …).
    pub fn params(&self) -> &Params {
        &self.pa
    }

    /// The object dictionary's values as the master wrote them.
    pub fn od(&self) -> &OdValues {
        &self.od
    }

    /// The drive layer: power state, outputs, planner.
    pub fn drive(&self) -> &Drive {
        &self.drive
    }

    /// The dispatcher: §6 counters and listen-only mode.
    pub fn slave(&self) -> &Slave {
        &self.slave
    }

    /// Swaps the dispatcher state (§6 counters, listen-only mode) with
    /// `other`: a second port to the same drive (a web page, a TCP front
    /// end) keeps its own by swapping it in for its request and back.
    pub fn swap_slave(&mut self, other: &mut Slave) {
        core::mem::swap(&mut self.slave, other);
    }

    /// The planner's timing (step timer frequency, horizon): at start-up,
    /// before the first control call ([`Drive::set_planner_config`]).
    pub fn set_planner_config(&mut self, cfg: PlannerConfig) {
        self.drive.set_planner_config(cfg);
    }

    /// Changes parameters before the first frame, from the glue's own
    /// configuration (a command line, a board's wiring, a test's setup):
    /// `set` edits the working set (parameters and OD values), then its
    /// address and line are put in force at once and the drive layer
    /// re-reads it, as after a boot. Values are not checked against the
    /// table's ranges: the glue's settings are its own.
    pub fn configure(&mut self, set: impl FnOnce(&mut Params, &mut OdValues)) {
        set(&mut self.pa, &mut self.od);
        self.address = self.pa.address();
        self.line = self.pa.line();
        self.configuration_changed();
    }

    /// Register requests get exception 6 while `busy` (§5.2 step 9), for a
    /// reason of the glue's own (or a test's); see [`Self::busy`].
    pub fn set_storage_busy(&mut self, busy: bool) {
        self.storage_busy = busy;
    }

    /// Whether [`Device::handle_rx`] will answer `rx` with a reply due at
    /// once, t3.5 after its last byte (PA56 = 0), told before it runs
    /// ([`crate::slave::Slave::will_answer`]); an EE request's reply,
    /// deferred until the flash is done, counts as answered. The firmware raises
    /// the transceiver's DE on it, so that the lead runs while the reply
    /// is made.
    pub fn will_answer_at_once(&self, rx: &RxEvent<'_>) -> bool {
        self.pa.response_delay_ms() == 0
            && self.slave.will_answer(
                rx,
                self.address,
                self.pa.standard_exceptions(),
                self.pa.answer_frame_errors(),
            )
    }

    /// A closed frame (or frame error) from the assembler. Writes any reply
    /// into `reply` and says how much of it to send. Bus errors are counted
    /// (§6) and reported as events.
    pub fn handle_rx(&mut self, rx: RxEvent<'_>, reply: &mut [u8; MAX_FRAME]) -> Response {
        let busy = self.busy();
        let mut regs = Registers::new(&mut self.od, &mut self.pa, &mut self.drive, &self.identity)
            .with_store(busy, self.store_status);
        let messages = self.slave.counters().slave_messages();
        let outcome = self.slave.handle(rx, self.address, &mut regs, reply);
        let ee_request = regs.ee_request();
        if self.slave.counters().slave_messages() != messages {
            // a valid frame for us (or a broadcast): PA20 timer (SPEC §8.7)
            self.drive.frame_received();
        }
        if let Some(event) = outcome.event() {
            self.push_event(event);
        }
        match (ee_request, outcome.response()) {
            // SPEC §9: the reply comes once the operation is done.
            (Some(op), Response::Reply(n)) => {
                self.ee_pending = Some(PendingEe::new(op, Some(&reply[..n])));
                Response::Silent
            }
            (Some(op), Response::Silent) => {
                self.ee_pending = Some(PendingEe::new(op, None)); // broadcast
                Response::Silent
            }
            (None, response) => response,
        }
    }

    /// Register requests get exception 6 (§5.2 step 9): an EE operation is
    /// waiting for [`Self::poll_storage`] or its reply is not yet due
    /// ([`Self::poll`]), or the glue set `storage_busy`.
    pub fn busy(&self) -> bool {
        self.storage_busy || self.ee_pending.is_some() || self.ee_busy_until_us.is_some()
    }

    /// The EE operation waiting, if any (the glue may log it or decide when
    /// to run it).
    pub fn pending_ee(&self) -> Option<EeOp> {
        self.ee_pending.map(|p| p.op())
    }

    /// At power-up, before the first frame: takes the set the store found
    /// (SPEC §9) as the working set, with its address and line in force at
    /// once, reports how it was obtained (event, DP-Err) and tells the
    /// drive layer.
    pub fn apply_boot(&mut self, boot: &Boot) {
        boot.set().apply_to(&mut self.pa, &mut self.od);
        self.address = self.pa.address();
        self.line = self.pa.line();
        self.driver_enable = self.pa.driver_enable();
        self.store_status = StoreStatus::booted(
            boot.outcome() == BootOutcome::Blank,
            matches!(boot.outcome(), BootOutcome::Unreadable(_)),
            self.store_status.reset_cause(),
        );
        self.push_event(Event::ParamsLoaded(boot.outcome()));
        self.configuration_changed();
    }

    /// Why the chip last reset, as DP-rES (0x0017) shows it: the glue's
    /// code (docs/parameters.md), read from the chip at boot.
    pub fn set_reset_cause(&mut self, code: u16) {
        self.store_status.set_reset_cause(code);
    }

    /// Runs the waiting EE operation (if any) on `store` and returns its
    /// deferred reply: `None` when nothing was waiting, `Some(Silent)` after
    /// a broadcast, else `Some(Reply(n))` with the reply in `reply` — the
    /// request's own success reply, exception 4 when the flash failed or
    /// EE-rS found no backup (§5.2 step 10), or exception 6 with nothing
    /// changed when steps are being generated now (statusword bit 9, SPEC
    /// §9: flash work stalls the processor, and with it the step
    /// interrupt). Call [`Self::reply_sent`] after sending it.
    pub fn poll_storage<F: NorFlash>(
        &mut self,
        store: &mut ParamStore<F>,
        reply: &mut [u8; MAX_FRAME],
    ) -> Option<Response> {
        if self.drive.generating_steps() {
            return self.refuse_storage(reply);
        }
        let pending = self.ee_pending.take()?;
        let result = execute(pending.op(), &mut self.pa, &mut self.od, store);
        Some(self.finish_ee(pending, result, reply))
    }

    /// Refuses the waiting EE operation (if any) with exception 6 and
    /// changes nothing, as [`Self::poll_storage`] does under a moving axis:
    /// for glue that sees steps queued or the step output busy by its own
    /// means (the firmware checks its step schedule before any flash work).
    pub fn refuse_storage(&mut self, reply: &mut [u8; MAX_FRAME]) -> Option<Response> {
        let pending = self.ee_pending.take()?;
        Some(self.finish_ee(pending, Err(EeError::StepsRunning), reply))
    }

    /// The deferred reply of an EE operation that ran (or was refused).
    fn finish_ee(
        &mut self,
        pending: PendingEe,
        result: Result<(), EeError>,
        reply: &mut [u8; MAX_FRAME],
    ) -> Response {
        let refused = result == Err(EeError::StepsRunning);
        if !refused {
            let saved = result.is_ok()
                && matches!(
                    pending.op(),
                    EeOp::Save | EeOp::RestoreBackup | EeOp::RestoreDefaults
                );
            self.store_status
                .ee_done(matches!(result, Err(EeError::Storage(_))), saved);
        }
        self.push_event(Event::EeDone {
            op: pending.op(),
            error: result.err(),
        });
        if result.is_ok() && pending.op() != EeOp::Save && pending.op() != EeOp::Backup {
            self.configuration_changed();
        }
        let Some(ok_reply) = pending.reply() else {
            return Response::Silent;
        };
        let n = match result {
            Ok(()) => {
                reply[..ok_reply.len()].copy_from_slice(ok_reply);
                ok_reply.len()
            }
            Err(_) => {
                // Codes 4 and 6 are the same in both PA55 profiles.
                let exception = if refused {
                    crate::rtu::Exception::Busy
                } else {
                    crate::rtu::Exception::DeviceFailure
                };
                self.slave.count_deferred_exception(exception);
                reply[0] = ok_reply[0];
                reply[1] = ok_reply[1] | 0x80;
                reply[2] = exception as u8;
                with_crc(reply, 3)
            }
        };
        Response::Reply(n)
    }

    /// The working set was replaced (boot, EE-rd / EE-rS / EE-dEF): the
    /// drive layer re-reads PA10..14, PA20 and the profile values.
    fn configuration_changed(&mut self) {
        let cfg = Config::new(&self.od, &self.pa);
        self.drive.values_written(cfg);
    }

    /// The reply (if any) has left the wire: apply a deferred change of
    /// address, line format or DE lead / tail (SPEC §7) — the reply to the
    /// write that made it went out from the old address on the old line.
    /// Returns the line settings if they or the DE lead / tail
    /// ([`Self::driver_enable`]) changed: the glue applies both. Call it
    /// after [`Response::Silent`] too.
    pub fn reply_sent(&mut self) -> Option<LineConfig> {
        let address = self.pa.address();
        if address != self.address {
            self.address = address;
            self.push_event(Event::AddressChanged { address });
        }
        let line = self.pa.line();
        let driver_enable = self.pa.driver_enable();
        let de_changed = driver_enable != self.driver_enable;
        self.driver_enable = driver_enable;
        if line == self.line {
            return de_changed.then_some(line);
        }
        self.line = line;
        self.push_event(Event::LineChanged(line));
        Some(line)
    }

    /// Earliest start of a reply after the request's last byte: t3.5 of the
    /// line in force plus the response delay PA56 (SPEC §1).
    pub fn reply_delay_us(&self) -> u32 {
        self.line.timing().t35_us() + u32::from(self.pa.response_delay_ms()) * 1000
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

    /// The RS-485 DE lead and tail in force (PA57/PA58, same rule).
    pub fn driver_enable(&self) -> DriverEnable {
        self.driver_enable
    }

    /// The control loop (SPEC §8): call it by [`Self::poll_at`] (at least
    /// every [`CONTROL_PERIOD_US`], within the planner's horizon,
    /// [`crate::motion::PlannerConfig`]), after each handled frame, and
    /// when a switch input changes (so that a homing origin is latched at
    /// that step; glue that cannot, calls [`Self::control_latched`]). `switches` are the logical
    /// states after PA13 ([`crate::drive::io::SwitchInputs::read`]);
    /// `schedule` is the one the step interrupt's
    /// [`crate::motion::StepSource`] consumes (see [`crate::motion::schedule`]
    /// for how the firmware shares it). Afterwards apply
    /// [`Drive::outputs`](crate::drive::Drive::outputs) to ENABLE/BRAKE and
    /// start the step interrupt if it is idle and the schedule is not empty.
    pub fn control(&mut self, now_us: u64, switches: Switches, schedule: &StepSchedule) {
        self.control_latched(now_us, switches, SwitchEdges::default(), schedule);
    }

    /// [`Self::control`], telling `sink` of every step it pushes to
    /// `schedule` ([`StepSink`]: the simulation keeps their exact times).
    pub fn control_with<S: StepSink>(
        &mut self,
        now_us: u64,
        switches: Switches,
        schedule: &StepSchedule,
        sink: &mut S,
    ) {
        let edges = SwitchEdges::default();
        self.control_latched_with(now_us, switches, edges, schedule, sink);
    }

    /// When the host must call [`Self::control`] next, host µs: one
    /// [`CONTROL_PERIOD_US`] after the last call (at once before the
    /// first). Earlier calls are welcome: after a handled frame and at a
    /// switch edge.
    pub fn poll_at(&self) -> u64 {
        self.last_control_us.map_or(0, |t| t + CONTROL_PERIOD_US)
    }

    /// The encoder timer's 16-bit counter, read by glue that has an encoder
    /// just before its control call (SPEC §8.8). The drive is closed loop
    /// once this has been called and PA17 names a resolution; glue without
    /// an encoder never calls it. The counter may wrap; it must be read
    /// before it has moved half its range since the last reading.
    pub fn set_encoder_count(&mut self, raw: u16) {
        self.drive.set_encoder_count(raw);
    }

    /// [`Self::control`] for glue that samples the switches later than
    /// their edges (the firmware's debounced 1 kHz loop): `edges` are the
    /// step counts ([`StepSchedule::position`]) latched at the edges that
    /// led to `switches`; a homing origin is taken there (SPEC §8.6) when
    /// the edge lies on the current search leg.
    pub fn control_latched(
        &mut self,
        now_us: u64,
        switches: Switches,
        edges: SwitchEdges,
        schedule: &StepSchedule,
    ) {
        self.control_latched_with(now_us, switches, edges, schedule, &mut ());
    }

    /// [`Self::control_latched`], telling `sink` of every step it pushes
    /// ([`Self::control_with`]).
    pub fn control_latched_with<S: StepSink>(
        &mut self,
        now_us: u64,
        switches: Switches,
        edges: SwitchEdges,
        schedule: &StepSchedule,
        sink: &mut S,
    ) {
        let cfg = Config::new(&self.od, &self.pa);
        self.drive
            .control(now_us, switches, edges, schedule, sink, cfg);
        self.last_control_us = Some(now_us);
        self.drive_events();
    }

    /// [`Self::control_latched`] in parts, for glue that bounds how long
    /// one call holds its thread: this call is everything before the fill
    /// (the schedule is not pushed to); then call [`Self::top_up`] while
    /// [`Self::fill_paused`], letting other work (a frame) run in between.
    /// With the planner's fill budget
    /// ([`crate::motion::PlannerConfig::with_fill_budget`]) each part
    /// pushes a bounded number of steps; the parts together do what one
    /// [`Self::control_latched`] does.
    pub fn begin_control_latched(
        &mut self,
        now_us: u64,
        switches: Switches,
        edges: SwitchEdges,
        schedule: &StepSchedule,
    ) {
        let cfg = Config::new(&self.od, &self.pa);
        self.drive
            .begin_control(now_us, switches, edges, schedule, cfg);
        self.last_control_us = Some(now_us);
        self.drive_events();
    }

    /// The control call begun by [`Self::begin_control_latched`] has parts
    /// left: call [`Self::top_up`].
    pub fn fill_paused(&self) -> bool {
        self.drive.fill_paused()
    }

    /// The next part of the control call begun by
    /// [`Self::begin_control_latched`] (at its time); nothing when
    /// [`Self::fill_paused`] is false.
    pub fn top_up(&mut self, schedule: &StepSchedule) {
        self.top_up_with(schedule, &mut ());
    }

    /// [`Self::top_up`], telling `sink` of every step it pushes
    /// ([`Self::control_with`]).
    pub fn top_up_with<S: StepSink>(&mut self, schedule: &StepSchedule, sink: &mut S) {
        self.drive.top_up(schedule, sink);
        self.drive_events();
    }

    fn drive_events(&mut self) {
        while let Some(e) = self.drive.take_event() {
            self.push_event(Event::Drive(e));
        }
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
