//! The dispatcher task: closed frames → `Device::handle_rx` → reply after
//! `Device::reply_delay_us` → `Device::reply_sent` (SPEC §1, §3, §7).
//!
//! The device lives in [`DEVICE`], a thread-mode mutex: only tasks of the
//! thread-mode executor (this one and the control loop) touch it, never an
//! interrupt, so locking it costs no interrupt latency.

use core::cell::RefCell;
use core::sync::atomic::Ordering;

use embassy_stm32::mode::Blocking;
use embassy_stm32::usart::Uart;
use embassy_sync::blocking_mutex::raw::ThreadModeRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use modbus_drive::device::Response;
use modbus_drive::rtu::{RxEvent, MAX_FRAME};
use modbus_drive::Device;

use super::calc::{reply_wait_us, RateLimit};
use super::rs485::{self, FRAMES, FRAMES_DROPPED};

/// The drive core, shared by the dispatcher and the control loop.
pub static DEVICE: Mutex<ThreadModeRawMutex, RefCell<Option<Device>>> =
    Mutex::new(RefCell::new(None));

/// Runs `f` on the device (installed by `main` before any task starts).
pub fn with_device<R>(f: impl FnOnce(&mut Device) -> R) -> Option<R> {
    DEVICE.lock(|d| d.borrow_mut().as_mut().map(f))
}

#[embassy_executor::task]
pub async fn dispatcher_task(mut uart: Uart<'static, Blocking>) {
    let mut reply = [0u8; MAX_FRAME];
    let mut frame_errors = RateLimit::new(1000);
    loop {
        let rx = FRAMES.receive().await;
        let event = rx.event();
        if !matches!(event, RxEvent::Frame { .. }) {
            let now_ms = embassy_time::Instant::now().as_millis() as u32;
            if let Some(suppressed) = frame_errors.allow(now_ms) {
                defmt::warn!(
                    "frame error: {} ({} more suppressed, {} frames dropped)",
                    event,
                    suppressed,
                    FRAMES_DROPPED.load(Ordering::Relaxed)
                );
            }
        }
        let Some((response, delay_us)) =
            with_device(|d| (d.handle_rx(event, &mut reply), d.reply_delay_us()))
        else {
            continue;
        };
        if let Response::Reply(n) = response {
            let wait = reply_wait_us(rs485::now_us(), rx.last_byte_at_us, delay_us);
            embassy_time::Timer::after_micros(u64::from(wait)).await;
            rs485::send(&reply[..n.min(MAX_FRAME)]).await;
        }
        // a new address or line format takes effect after the reply (SPEC §7)
        if let Some(Some(line)) = with_device(|d| d.reply_sent()) {
            match rs485::apply_line(&mut uart, line) {
                Ok(()) => defmt::info!("line changed: {}", line),
                Err(e) => defmt::error!("line {} refused by the USART: {}", line, e),
            }
        }
    }
}
