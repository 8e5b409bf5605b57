//! One simulated drive: the core, its parameter flash, the step schedule
//! and the simulated axis that consumes it, on the loop's clock; what it
//! logs; and the page's way to it (`web/`).

use std::path::Path;

use modbus_drive::boards::Board;
use modbus_drive::closed_loop::sim::SimEncoder;
use modbus_drive::device::sim::SimHost;
use modbus_drive::device::{Identity, Line, Polled, CONTROL_PERIOD_US};
use modbus_drive::dictionary::DriveLayer;
use modbus_drive::drive::DriveEvent;
use modbus_drive::event::{Event, FrameError};
use modbus_drive::motion::sim::SimAxis;
use modbus_drive::motion::{PlannerConfig, StepSchedule};
use modbus_drive::params::{BootOutcome, ParamStore};
use modbus_drive::Device;

use super::super::cli::AxisLayout;
use super::super::console::Console;
use super::super::flash::{FileFlash, REGION_BYTES};
use super::super::web::{self, ExceptionLog, Forced};
use super::encoder;
use super::serve::SimStorage;

/// Control periods made up at once after the process was held up longer
/// (suspended, debugger); beyond that simulated time skips ahead.
const CATCH_UP_PERIODS_MAX: u64 = 5_000;

/// One simulated drive.
pub(super) struct DriveSlot {
    pub(super) device: Device,
    /// Its parameter flash: region of the `--state` file, or memory only.
    pub(super) store: ParamStore<FileFlash>,
    /// The steps the core plans; the simulated step interrupt consumes them.
    pub(super) schedule: Box<StepSchedule>,
    /// Step interrupt, motor and switches.
    pub(super) axis: SimAxis,
    /// The encoder on the motor (`--encoder`, or PA17 > 0).
    pub(super) encoder: SimEncoder,
    pub(super) encoder_wired: bool,
    pub(super) last_statusword: u16,
    pub(super) last_mode: i16,
    /// Switches forced from the page (`--web`).
    pub(super) forced: Forced,
    /// The last exceptions answered, for the page.
    pub(super) exceptions: ExceptionLog,
}

impl DriveSlot {
    /// Drive number `index` of `--drives`, at `address`, with its flash.
    /// At power-up it loads what its flash holds (SPEC §9). A saved set wins
    /// over `--drives`, PA51 included — it is what the drive's flash says;
    /// a blank or unreadable flash keeps the `--drives` address.
    pub(super) fn new(
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
        device.set_planner_config(PlannerConfig::for_board(board));
        let boot = store.boot();
        device.apply_boot(&boot);
        if !matches!(boot.outcome(), BootOutcome::Loaded { .. }) {
            // `--drives` gives each drive its address (PA51, SPEC §7), in
            // force at once: no change worth logging
            device.configure(|pa, _| pa.set_address(address));
        }
        encoder::wire(&mut device, layout.encoder);
        let last_statusword = device.drive().statusword();
        let last_mode = device.drive().mode_display();
        Ok(Self {
            device,
            store,
            schedule: Box::new(StepSchedule::new()),
            axis: sim_axis(layout, board.step_tick_hz()),
            encoder: encoder::sim_encoder(layout.encoder),
            encoder_wired: layout.encoder.on,
            last_statusword,
            last_mode,
            forced: Forced::default(),
            exceptions: ExceptionLog::new(),
        })
    }

    /// The simulation host over this drive's axis, encoder and forced
    /// switches.
    fn host(&mut self) -> SimHost<'_> {
        SimHost::new(&mut self.device, &mut self.axis, &self.schedule)
            .with_encoder(&mut self.encoder, self.encoder_wired)
            .with_switches(&self.forced)
    }

    /// Runs the axis and the control loop up to `now_us`: every control
    /// call the drive asks for in turn (`Device::poll_at`), in simulated
    /// time, so a late wake-up of the process never starves the step
    /// schedule. A step that changes a switch stops the axis there and the
    /// drive sees the new states at that instant (SPEC §8.6: the origin is
    /// the step where the edge was seen).
    pub(super) fn advance(&mut self, now_us: u64) {
        let late = now_us.saturating_sub(self.device.poll_at());
        if late > CATCH_UP_PERIODS_MAX * CONTROL_PERIOD_US {
            // Held up for seconds: time jumps (the axis idles through it).
            self.host().resume_at(now_us, |_| {});
        } else {
            self.host().run_to(now_us, |_| {});
        }
    }

    /// The axis and control loop up to `t_us`, then a control call at
    /// `t_us` (after a handled frame).
    pub(super) fn control_at(&mut self, t_us: u64) {
        self.host().control_at(t_us, |_| {});
    }

    pub(super) fn label(&self) -> String {
        format!("drive {}", self.device.address())
    }
}

/// The simulated axis with the `--cw-limit` / `--ccw-limit` /
/// `--home-switch` switches, at the step timer frequency the planner uses.
pub(super) fn sim_axis(layout: AxisLayout, tick_hz: u32) -> SimAxis {
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

/// Logs the core events of `slot` (and the file error behind a failed
/// flash operation, which the core only knows as "flash failed").
pub(super) fn log_events(console: &mut Console, slot: &mut DriveSlot, line: Option<&str>) {
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
pub(super) fn describe(ev: &Event) -> String {
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
            line.baud(),
            line.format(),
            line.timing().t35_us()
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

    fn poll(&mut self, now_us: u64, line: &mut impl Line) -> Polled {
        // the page's answer waits for no flash time
        let mut storage = SimStorage {
            store: &mut self.store,
            timed: false,
        };
        self.device.poll(now_us, line, &mut storage)
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
