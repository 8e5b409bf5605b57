//! The dispatcher task: closed frames → `Device::handle_rx` → (EE operation
//! on the parameter store) → reply after `Device::reply_delay_us` →
//! `Device::reply_sent` (SPEC §1, §3, §7, §9). It also logs what the core
//! reports (`Device::take_event`).
//!
//! The device lives in `DEVICE`, a thread-mode mutex: only tasks of the
//! thread-mode executor (this one and the control loop) touch it, never an
//! interrupt, so locking it costs no interrupt latency.

use core::cell::RefCell;
use core::sync::atomic::Ordering;

use embassy_stm32::flash::{Blocking as FlashBlocking, Flash};
use embassy_stm32::mode::Blocking;
use embassy_stm32::usart::Uart;
use embassy_sync::blocking_mutex::raw::ThreadModeRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::once_lock::OnceLock;
use modbus_drive::device::Response;
use modbus_drive::event::Event;
use modbus_drive::params::ParamStore;
use modbus_drive::rtu::MAX_FRAME;
use modbus_drive::Device;

use super::calc::{reply_wait_us, RateLimit};
use super::flash::FlashRegion;
use super::rs485::{self, FRAMES_DROPPED};
use super::steps;

/// The drive core, shared by the dispatcher and the control loop.
/// Installed once by `main` ([`install`]). A `OnceLock` is zero-initialised
/// (.bss): an `Option<Device>` initialiser is not (`None` is a niche value),
/// and its 2 KiB image would sit in flash as .data (README "Sizes").
static DEVICE: OnceLock<Mutex<ThreadModeRawMutex, RefCell<Device>>> = OnceLock::new();

/// The parameter store (SPEC §9) on the board's parameter pages.
pub type Store = ParamStore<FlashRegion<Flash<'static, FlashBlocking>>>;

/// Installs the device (`main`, once, before any task starts).
pub fn install(device: Device) {
    if DEVICE.init(Mutex::new(RefCell::new(device))).is_err() {
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
            let now_ms = embassy_time::Instant::now().as_millis() as u32;
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

#[embassy_executor::task]
pub async fn dispatcher_task(mut uart: Uart<'static, Blocking>, mut store: Store) {
    let mut reply = [0u8; MAX_FRAME];
    let mut log = EventLog::new();
    loop {
        let rx = rs485::receive().await;
        #[cfg(feature = "fault-test")]
        super::fault::test_trigger(rx.event());
        let Some((mut response, delay_us)) =
            with_device(|d| (d.handle_rx(rx.event(), &mut reply), d.reply_delay_us()))
        else {
            continue;
        };
        // An accepted EE request (SPEC §9) runs now; its reply is deferred
        // until it is done. Erasing or programming stalls every fetch from
        // the single flash bank, interrupts included, so it starts only
        // with the step output idle (the core refuses it while statusword
        // bit 9 is set; this is the glue's own check of the step schedule),
        // and nothing can queue a step until it is done: the control loop
        // shares this thread.
        if let Some(Some(deferred)) = with_device(|d| {
            d.pending_ee()?;
            if steps::idle() {
                d.poll_storage(&mut store, &mut reply)
            } else {
                d.refuse_storage(&mut reply)
            }
        }) {
            response = deferred;
        }
        log.drain();
        if let Response::Reply(n) = response {
            let wait = reply_wait_us(rs485::now_us(), rx.last_byte_at_us(), delay_us);
            rs485::send(&reply[..n.min(MAX_FRAME)], wait).await;
        }
        // a new address, line format or DE lead / tail takes effect after
        // the reply (SPEC §7)
        if let Some(Some((line, de))) =
            with_device(|d| d.reply_sent().map(|line| (line, d.driver_enable())))
        {
            if let Err(e) = rs485::apply_line(&mut uart, line, de) {
                defmt::error!(
                    "line {} refused by the USART: {}",
                    line,
                    rs485::config_error(e)
                );
            }
        }
        log.drain();
    }
}
