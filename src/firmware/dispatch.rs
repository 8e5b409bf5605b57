//! The dispatcher task: hands each closed frame to `Device::poll` (SPEC §1,
//! §3, §7, §9), then sends the reply `poll` queued at its time and puts a
//! new line format and DE lead / tail in force. It also logs what the core
//! reports (`Device::take_event`).
//!
//! The device lives in `DEVICE`, a thread-mode mutex: only tasks of the
//! thread-mode executor (this one and the control loop) touch it, never an
//! interrupt, so locking it costs no interrupt latency.

use core::cell::RefCell;
use core::sync::atomic::Ordering;
use modbus_drive::arith::div_u64;

use embassy_stm32::flash::{Blocking as FlashBlocking, Flash};
use embassy_stm32::mode::Blocking;
use embassy_stm32::usart::Uart;
use embassy_sync::blocking_mutex::raw::ThreadModeRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::once_lock::OnceLock;
use modbus_drive::device::{Line, Request, Storage};
use modbus_drive::event::Event;
use modbus_drive::params::ParamStore;
use modbus_drive::rtu::{DriverEnable, LineConfig, MAX_FRAME};
use modbus_drive::Device;

use super::calc::RateLimit;
use super::fault;
use super::flash::FlashRegion;
use super::rs485;
use super::rx_slots::{self, RxFrame, FRAMES_DROPPED};
use super::steps;

/// The drive core, shared by the dispatcher and the control loop.
/// Installed once by `main` ([`install`]). A `OnceLock` is zero-initialised
/// (.bss): an `Option<Device>` initialiser is not (`None` is a niche value),
/// and its image would sit in flash as .data.
static DEVICE: OnceLock<Mutex<ThreadModeRawMutex, RefCell<Device>>> = OnceLock::new();

/// The parameter store (SPEC §9) on the board's parameter pages.
pub type Store = ParamStore<FlashRegion<Flash<'static, FlashBlocking>>>;

/// Installs the device `build` makes (`main`, once, before any task
/// starts). Built inside the lock's initialiser, not passed in: a value
/// passed to `init` is copied on the way, and comes back in its `Err`.
pub fn install(build: impl FnOnce() -> Device) {
    let mut built = false;
    DEVICE.get_or_init(|| {
        built = true;
        Mutex::new(RefCell::new(build()))
    });
    if !built {
        defmt::panic!("device installed twice");
    }
}

/// Runs `f` on the device (`None` before [`install`]).
pub fn with_device<R>(f: impl FnOnce(&mut Device) -> R) -> Option<R> {
    DEVICE.try_get().map(|d| d.lock(|d| f(&mut d.borrow_mut())))
}

/// Logs the core's events; frame errors and exceptions at most once a
/// second each, so a noisy bus or a misbehaving master cannot flood RTT.
pub struct EventLog {
    frame_errors: RateLimit,
    exceptions: RateLimit,
}

impl EventLog {
    pub const fn new() -> Self {
        Self {
            frame_errors: RateLimit::new(1000),
            exceptions: RateLimit::new(1000),
        }
    }

    pub fn drain(&mut self) {
        while let Some(Some(event)) = with_device(|d| d.take_event()) {
            let now_ms = div_u64(embassy_time::Instant::now().as_micros(), 1000) as u32;
            match event {
                Event::FrameError { .. } => {
                    if let Some(suppressed) = self.frame_errors.allow(now_ms) {
                        defmt::warn!(
                            "{} ({} similar suppressed, {} frames dropped by the glue)",
                            event,
                            suppressed,
                            FRAMES_DROPPED.load(Ordering::Relaxed)
                        );
                    }
                }
                Event::Exception { .. } => {
                    if let Some(suppressed) = self.exceptions.allow(now_ms) {
                        defmt::info!("{} ({} similar suppressed)", event, suppressed);
                    }
                }
                _ => defmt::info!("{}", event),
            }
        }
        if let Some(dropped) = with_device(|d| d.events_dropped()).filter(|&n| n > 0) {
            defmt::trace!("{} events dropped by the core so far", dropped);
        }
    }
}

/// What `poll` queued on the line: a reply loaded into the link
/// (`rs485::load`), when it may leave and whether it has started; or an
/// empty one, which only delays what follows it.
#[derive(Clone, Copy)]
enum Queued {
    Reply { at_us: u64, started: bool },
    Nothing { at_us: u64 },
}

/// The RS-485 line as [`Device::poll`] sees it: the frame the link
/// received, and the reply and line format `poll` queues, which the task
/// carries out after it, in that order ([`Rs485Line::carry_out`]).
struct Rs485Line<'a> {
    received: Option<&'a RxFrame>,
    /// The time driver's µs now, and the frame's last byte on that scale
    /// (the link stamps bytes with its wrapping 32-bit µs).
    now_us: u64,
    last_byte_us: u64,
    queued: Option<Queued>,
    line: Option<LineConfig>,
}

impl<'a> Rs485Line<'a> {
    fn new(received: &'a RxFrame) -> Self {
        let now_us = embassy_time::Instant::now().as_micros();
        let ago = (now_us as u32).wrapping_sub(received.last_byte_at_us());
        Self {
            received: Some(received),
            now_us,
            last_byte_us: now_us.saturating_sub(u64::from(ago)),
            queued: None,
            line: None,
        }
    }

    /// Sends the queued reply at its time, then puts a new line format and
    /// the DE lead / tail `de` in force (SPEC §7: after the reply).
    async fn carry_out(&mut self, uart: &mut Uart<'static, Blocking>, de: DriverEnable) {
        match self.queued.take() {
            // `finish` waits itself: DE rises its lead before `at_us`
            Some(Queued::Reply { at_us, started }) => {
                rs485::finish(started, wait_until(at_us)).await;
            }
            Some(Queued::Nothing { at_us }) => {
                embassy_time::Timer::at(embassy_time::Instant::from_micros(at_us)).await;
            }
            None => {}
        }
        if let Some(line) = self.line.take() {
            if let Err(e) = rs485::apply_line(uart, line, de) {
                defmt::error!(
                    "line {} refused by the USART: {}",
                    line,
                    rs485::config_error(e)
                );
            }
        }
    }
}

/// µs from now until `at_us` on the time driver's scale (0 if past).
fn wait_until(at_us: u64) -> u32 {
    let wait = at_us.saturating_sub(embassy_time::Instant::now().as_micros());
    u32::try_from(wait).unwrap_or(u32::MAX)
}

impl Line for Rs485Line<'_> {
    fn receive(&mut self) -> Option<Request<'_>> {
        let received = self.received.take()?;
        Some(Request::new(received.event(), Some(self.last_byte_us)))
    }

    /// Loads a reply into the link at once, and starts it if it is due
    /// within the DE lead: the lead then runs while the core finishes
    /// `poll`.
    fn send(&mut self, bytes: &[u8], at_us: u64) {
        self.queued = Some(if bytes.is_empty() {
            Queued::Nothing { at_us }
        } else {
            Queued::Reply {
                at_us,
                started: rs485::load(bytes, wait_until(at_us)),
            }
        });
    }

    fn reconfigure(&mut self, line: LineConfig) {
        self.line = Some(line);
    }
}

/// The parameter store as [`Device::poll`] sees it. An accepted EE request
/// (SPEC §9) runs inside `poll`, its reply deferred until it is done.
/// Erasing or programming stalls every fetch from the single flash bank,
/// interrupts included, so it starts only with the step output idle (the
/// core refuses it while statusword bit 9 is set; this is the glue's own
/// check of the step schedule), and nothing can queue a step until it is
/// done: the control loop shares this thread.
struct FlashStorage<'s>(&'s mut Store);

impl Storage for FlashStorage<'_> {
    type Flash = FlashRegion<Flash<'static, FlashBlocking>>;
    fn store(&mut self) -> &mut Store {
        self.0
    }
    fn ready(&mut self) -> bool {
        steps::idle()
    }
}

#[embassy_executor::task]
pub async fn dispatcher_task(mut uart: Uart<'static, Blocking>, mut store: Store) {
    let mut log = EventLog::new();
    // the core makes each reply here (kept across frames: never cleared)
    let mut reply = [0; MAX_FRAME];
    loop {
        fault::DISPATCHER.idle();
        let rx = rx_slots::receive().await;
        fault::DISPATCHER.busy();
        #[cfg(feature = "fault-test")]
        if fault::test_trigger(rx.event()) {
            core::future::pending::<()>().await; // stuck on purpose
        }
        let mut line = Rs485Line::new(&rx);
        let mut storage = FlashStorage(&mut store);
        // PA57 / PA58 as the request left them, for a reconfigured line
        let Some(de) = with_device(|d| {
            if d.will_answer_at_once(&rx.event()) {
                // the DE lead runs while the reply is made
                rs485::raise_early();
            }
            d.poll_with(line.now_us, &mut line, &mut storage, &mut reply);
            d.driver_enable()
        }) else {
            continue;
        };
        if line.queued.is_none() {
            rs485::drop_early();
        }
        // the reply first: what the core reported is logged after it
        line.carry_out(&mut uart, de).await;
        log.drain();
    }
}
