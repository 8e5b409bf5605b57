//! The RS-485 link: the USART interrupt and the line settings (SPEC §1).
//!
//! Receive: every byte is time-stamped in the interrupt (µs from the
//! embassy-time driver, a free-running timer) and pushed into the core's
//! [`FrameAssembler`] with its parity / framing / overrun flags. A closed
//! frame is copied into [`FRAMES`] for the dispatcher task (dispatch.rs).
//! The frame closes after t3.5 of silence:
//! - STM32G431: the USART receiver timeout (RTOF) fires t3.5 after the last
//!   stop bit → [`FrameAssembler::end_of_frame`];
//! - STM32F103 (no receiver timeout): [`frame_gap_task`] sleeps on an
//!   embassy-time alarm until t3.5 after the last byte and calls
//!   [`FrameAssembler::poll`]; t1.5 is judged by the assembler from the
//!   timestamps.
//!
//! Transmit: [`send`] hands the reply to the interrupt, which feeds the data
//! register on TXE (one burst, no gaps) and finishes at TC. DE leads the
//! first start bit and trails the last stop bit by PA57 / PA58
//! ([`apply_line`], `calc::DeDrive`): on the G431 the USART's
//! hardware driver-enable does it (DEAT / DEDT) while they fit; beyond
//! that, and always on the F103, DE is a GPIO that [`send`] raises the
//! lead before the first byte and the interrupt drops the tail after TC.
//!
//! Shared state: [`LINK`] (assembler + transmit buffer) behind a critical
//! section; [`FRAMES`], [`TX_DONE`] are embassy-sync primitives on a
//! critical-section mutex.

use core::cell::RefCell;
use core::sync::atomic::{AtomicU32, Ordering};

use critical_section::Mutex;
use embassy_stm32::interrupt::typelevel::Handler;
use embassy_stm32::mode::Blocking;
use embassy_stm32::usart::{self, Uart};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_sync::once_lock::OnceLock;
use embassy_sync::signal::Signal;
use heapless::Vec;
use modbus_drive::rtu::{
    CharFormat, DriverEnable, FrameAssembler, FrameTiming, LineConfig, RxEvent, RxFlags, MAX_FRAME,
};

use super::board;
use super::calc::DeDrive;

/// A closed frame (or frame error), owned, on its way to the dispatcher.
pub struct Received {
    pub outcome: Outcome,
    /// End of the request's last byte (the reply waits from here, SPEC §1).
    pub last_byte_at_us: u32,
}

// No heap to box into: the frame lives in its channel slot either way.
#[allow(clippy::large_enum_variant)]
pub enum Outcome {
    Frame {
        bytes: Vec<u8, MAX_FRAME>,
        parity_error: bool,
    },
    Broken,
    TooShort,
    Overrun,
}

impl Received {
    fn new(ev: RxEvent<'_>, last_byte_at_us: u32) -> Self {
        let outcome = match ev {
            RxEvent::Frame {
                bytes,
                parity_error,
            } => Outcome::Frame {
                // a frame is at most MAX_FRAME bytes (the assembler's buffer)
                bytes: Vec::from_slice(bytes).unwrap_or_default(),
                parity_error,
            },
            RxEvent::Broken => Outcome::Broken,
            RxEvent::TooShort => Outcome::TooShort,
            RxEvent::Overrun => Outcome::Overrun,
        };
        Self {
            outcome,
            last_byte_at_us,
        }
    }

    /// The core's view of it, for `Device::handle_rx`.
    pub fn event(&self) -> RxEvent<'_> {
        match &self.outcome {
            Outcome::Frame {
                bytes,
                parity_error,
            } => RxEvent::Frame {
                bytes,
                parity_error: *parity_error,
            },
            Outcome::Broken => RxEvent::Broken,
            Outcome::TooShort => RxEvent::TooShort,
            Outcome::Overrun => RxEvent::Overrun,
        }
    }
}

/// Closed frames for the dispatcher. Two slots: one being answered, one
/// arriving (a master does not send more before our reply).
pub static FRAMES: Channel<CriticalSectionRawMutex, Received, 2> = Channel::new();
/// Frames lost because the dispatcher was behind (logged by the dispatcher).
pub static FRAMES_DROPPED: AtomicU32 = AtomicU32::new(0);
/// The interrupt has sent the last stop bit of the reply.
static TX_DONE: Signal<CriticalSectionRawMutex, ()> = Signal::new();
/// A byte arrived (wakes the F103 frame-gap task).
#[cfg(feature = "board-f103")]
static RX_ACTIVITY: Signal<CriticalSectionRawMutex, ()> = Signal::new();

/// `repr(C)`, the fields that start at zero together: one fill sets them
/// up (flash is short on the F103).
#[repr(C)]
struct Link {
    assembler: FrameAssembler,
    t35_us: u32,
    tx_len: usize,
    tx_pos: usize,
    /// PA57 / PA58 as this board makes them.
    de_drive: DeDrive,
    transmitting: bool,
    tx: [u8; MAX_FRAME],
}

/// Set up at first use. A `OnceLock` is zero-initialised (.bss); a `Link`
/// initialiser is not, and would cost its size again in flash as a .data
/// image (README "Sizes").
static LINK: OnceLock<Mutex<RefCell<Link>>> = OnceLock::new();

/// `f` on the link, inside a critical section (the USART interrupt shares it).
fn with_link<R>(f: impl FnOnce(&mut Link) -> R) -> R {
    critical_section::with(|cs| f(&mut link().borrow_ref_mut(cs)))
}

/// The link, set up at the first call. Not inlined: one copy of the set-up
/// for all callers.
#[inline(never)]
fn link() -> &'static Mutex<RefCell<Link>> {
    LINK.get_or_init(|| {
        Mutex::new(RefCell::new(Link {
            assembler: FrameAssembler::new(FrameTiming::new(LineConfig::DEFAULT)),
            t35_us: FrameTiming::new(LineConfig::DEFAULT).t35_us,
            tx: [0; MAX_FRAME],
            tx_len: 0,
            tx_pos: 0,
            transmitting: false,
            // replaced by `apply_line` before the first reply
            de_drive: DeDrive::default(),
        }))
    })
}

/// Microseconds from the embassy-time driver (tick 1 MHz), wrapping.
pub fn now_us() -> u32 {
    embassy_time::Instant::now().as_micros() as u32
}

/// embassy-stm32 USART settings for a line (SPEC §7 PA52/PA53).
pub fn usart_config(line: LineConfig) -> usart::Config {
    let mut c = usart::Config::default();
    c.baudrate = line.baud;
    c.data_bits = usart::DataBits::DataBits8;
    (c.parity, c.stop_bits) = match line.format {
        CharFormat::N1 => (usart::Parity::ParityNone, usart::StopBits::STOP1),
        CharFormat::E1 => (usart::Parity::ParityEven, usart::StopBits::STOP1),
        CharFormat::O1 => (usart::Parity::ParityOdd, usart::StopBits::STOP1),
        CharFormat::N2 => (usart::Parity::ParityNone, usart::StopBits::STOP2),
    };
    // RX idles high through the transceiver; a pull-up keeps it there when
    // the transceiver's receiver is disabled while we transmit.
    c.rx_pull = embassy_stm32::gpio::Pull::Up;
    c
}

/// What the USART refused in a line configuration, for the log. embassy's
/// own `defmt::Format` impls are left off (their `defmt` features cost flash,
/// see docs/firmware-size.md); the names are interned, so they cost no flash.
pub fn config_error(e: usart::ConfigError) -> defmt::Str {
    match e {
        usart::ConfigError::BaudrateTooLow => {
            defmt::intern!("baud rate too low for the USART clock")
        }
        usart::ConfigError::BaudrateTooHigh => {
            defmt::intern!("baud rate too high for the USART clock")
        }
        usart::ConfigError::RxOrTxNotEnabled => {
            defmt::intern!("receiver or transmitter not enabled")
        }
        usart::ConfigError::DataParityNotSupported => {
            defmt::intern!("data bits and parity not supported")
        }
        #[cfg(feature = "board-g431")]
        usart::ConfigError::DeAssertionTimeTooHigh => defmt::intern!("DE assertion time too high"),
        #[cfg(feature = "board-g431")]
        usart::ConfigError::DeDeassertionTimeTooHigh => {
            defmt::intern!("DE deassertion time too high")
        }
        _ => defmt::intern!("configuration refused"),
    }
}

/// Applies a line and the DE lead / tail PA57 / PA58 (at boot, and after
/// a reply when `Device::reply_sent` changed the line or the parameters
/// changed) and (re)arms the receive interrupts. Call it between frames.
pub fn apply_line(
    uart: &mut Uart<'static, Blocking>,
    line: LineConfig,
    de: DriverEnable,
) -> Result<(), usart::ConfigError> {
    // embassy rewrites CR1/CR2 here (for the whole USART, whichever half is
    // asked), clearing our interrupt enables
    uart.split_ref().1.set_config(&usart_config(line))?;
    let timing = line.timing();
    with_link(|link| {
        link.assembler.set_timing(timing);
        link.t35_us = timing.t35_us;
        link.de_drive = DeDrive::new(de, line, de_samples_per_bit());
        arm_receiver(line, link.de_drive);
    });
    Ok(())
}

/// USART samples per bit for its hardware DE timing (DEAT / DEDT count
/// them): 16, or 8 when embassy chose 8× oversampling for the baud.
#[cfg(feature = "board-g431")]
fn de_samples_per_bit() -> u32 {
    use embassy_stm32::pac::usart::vals::Over8;
    if board::UART.cr1().read().over8() == Over8::OVERSAMPLING8 {
        8
    } else {
        16
    }
}

/// The F103's USART has no hardware DE.
#[cfg(feature = "board-f103")]
fn de_samples_per_bit() -> u32 {
    0
}

/// STM32G4 (RM0440 USART chapter): FIFO off so that each byte gets its own
/// interrupt and timestamp; DE assertion/deassertion times from PA57 /
/// PA58 (DEAT / DEDT in sample times; embassy-stm32 0.6.0 writes DEAT into
/// both, so set them here); receiver timeout = t3.5 in bit times. FIFOEN,
/// DEAT and DEDT may only be written with UE = 0.
#[cfg(feature = "board-g431")]
fn arm_receiver(line: LineConfig, de: DeDrive) {
    let r = board::UART;
    r.cr1().modify(|w| w.set_ue(false));
    r.cr1().modify(|w| {
        w.set_fifoen(false);
        w.set_deat(de.deat);
        w.set_dedt(de.dedt);
    });
    r.rtor()
        .write(|w| w.set_rto(super::calc::t35_rto_bits(line)));
    r.cr2().modify(|w| w.set_rtoen(true));
    r.icr().write(|w| {
        w.set_pe(true);
        w.set_fe(true);
        w.set_ne(true);
        w.set_ore(true);
        w.set_rtof(true);
        w.set_tc(true);
    });
    r.cr1().modify(|w| {
        w.set_ue(true);
        w.set_rxneie(true);
        w.set_rtoie(true);
    });
}

/// STM32F103 (RM0008 USART chapter): RXNE interrupt only; t3.5 is timed by
/// [`frame_gap_task`]. Error flags are read with RXNE (SR then DR clears them).
#[cfg(feature = "board-f103")]
fn arm_receiver(_line: LineConfig, _de: DeDrive) {
    board::UART.cr1().modify(|w| w.set_rxneie(true));
}

/// The USART interrupt (priority: `board::PRIO_UART`).
pub struct UartHandler;

impl Handler<board::UartIrq> for UartHandler {
    unsafe fn on_interrupt() {
        let at_us = now_us();
        if let Some(tail_us) = with_link(|link| on_uart(link, at_us)) {
            // The software DE tail, here rather than in `send`: the
            // dispatcher task may wake much later (thread mode shares the
            // CPU with the control loop), and a master may send its next
            // request soon after our last stop bit. Outside the critical
            // section, so the step interrupt runs meanwhile. Core cycles
            // (at least that many, more if preempted) rather than reads of
            // the time driver: the wait touches no peripheral.
            cortex_m::asm::delay(tail_us.saturating_mul(board::CPU_HZ / 1_000_000));
            set_de(false);
        }
    }
}

/// Serves the USART; returns the DE tail to hold (µs) when a reply that
/// software drives DE for has just left the wire.
#[cfg(feature = "board-g431")]
fn on_uart(link: &mut Link, at_us: u32) -> Option<u32> {
    let r = board::UART;
    let isr = r.isr().read();
    if isr.rxne() {
        let flags = RxFlags {
            parity: isr.pe(),
            framing: isr.fe() || isr.ne(),
            overrun: isr.ore(),
        };
        let byte = r.rdr().read().dr() as u8; // clears RXNE
        r.icr().write(|w| {
            w.set_pe(true);
            w.set_fe(true);
            w.set_ne(true);
            w.set_ore(true);
        });
        on_byte(link, byte, at_us, flags);
    } else if isr.ore() {
        r.icr().write(|w| w.set_ore(true));
    }
    if isr.rtof() {
        r.icr().write(|w| w.set_rtof(true));
        let last = link.assembler.last_byte_at_us();
        if let Some(ev) = link.assembler.end_of_frame() {
            deliver(Received::new(ev, last));
        }
    }
    let cr1 = r.cr1().read();
    if cr1.txeie() && isr.txe() {
        if link.tx_pos < link.tx_len {
            r.tdr().write(|w| w.set_dr(u16::from(link.tx[link.tx_pos])));
            link.tx_pos += 1;
        } else {
            r.cr1().modify(|w| {
                w.set_txeie(false);
                w.set_tcie(true);
            });
        }
    }
    if cr1.tcie() && isr.tc() {
        // last stop bit sent; the USART drops DE after DEDT by itself
        // unless software drives it
        r.cr1().modify(|w| w.set_tcie(false));
        r.icr().write(|w| w.set_tc(true));
        link.transmitting = false;
        TX_DONE.signal(());
        return link.de_drive.software.then_some(link.de_drive.tail_us);
    }
    None
}

/// Serves the USART; returns the DE tail to hold (µs) when a reply has
/// just left the wire (DE is always software's here).
#[cfg(feature = "board-f103")]
fn on_uart(link: &mut Link, at_us: u32) -> Option<u32> {
    let r = board::UART;
    let sr = r.sr().read();
    if sr.rxne() || sr.ore() {
        let flags = RxFlags {
            parity: sr.pe(),
            framing: sr.fe() || sr.ne(),
            overrun: sr.ore(),
        };
        // SR read then DR read clears RXNE, PE, FE, NE and ORE (RM0008)
        let byte = r.dr().read().dr() as u8;
        if sr.rxne() {
            on_byte(link, byte, at_us, flags);
            RX_ACTIVITY.signal(());
        }
    }
    let cr1 = r.cr1().read();
    if cr1.txeie() && sr.txe() {
        if link.tx_pos < link.tx_len {
            r.dr().write(|w| w.set_dr(u16::from(link.tx[link.tx_pos])));
            link.tx_pos += 1;
        } else {
            r.cr1().modify(|w| {
                w.set_txeie(false);
                w.set_tcie(true);
            });
        }
    }
    if cr1.tcie() && sr.tc() {
        // the last stop bit has left: the bus is released after the DE
        // tail (SPEC §1)
        r.cr1().modify(|w| w.set_tcie(false));
        link.transmitting = false;
        TX_DONE.signal(());
        return Some(link.de_drive.tail_us);
    }
    None
}

fn on_byte(link: &mut Link, byte: u8, at_us: u32, flags: RxFlags) {
    if link.transmitting {
        return; // our own echo if /RE is not tied to DE
    }
    let last = link.assembler.last_byte_at_us();
    if let Some(ev) = link.assembler.push(byte, at_us, flags) {
        deliver(Received::new(ev, last));
    }
}

fn deliver(rx: Received) {
    if FRAMES.try_send(rx).is_err() {
        FRAMES_DROPPED.fetch_add(1, Ordering::Relaxed);
    }
}

/// Sends `bytes` (≤ 256) in one burst, its first start bit no earlier than
/// `not_before_us` from now, and returns once the last stop bit has left
/// the wire and DE is released.
pub async fn send(bytes: &[u8], not_before_us: u32) {
    let [lead, tail] = load_reply(bytes);
    // DE rises the lead before the earliest start (or now, and the start
    // waits for the lead); the tail follows transmission complete, and
    // whatever follows the reply (`apply_line` disables the USART) waits
    // for it. One await point for the three waits: each await of a timer
    // is a state of its own in the dispatcher's future, and flash is short
    // on the F103.
    let waits = [not_before_us.saturating_sub(lead), lead, tail];
    for (phase, us) in waits.into_iter().enumerate() {
        if phase == 1 {
            set_de(true);
        } else if phase == 2 {
            // inside the critical section: the interrupt modifies CR1 too
            with_link(|_| board::UART.cr1().modify(|w| w.set_txeie(true)));
            TX_DONE.wait().await;
        }
        // one time-driver tick more: a wait of n ticks may start late in
        // a tick
        if us > 0 {
            embassy_time::Timer::after_micros(u64::from(us) + 1).await;
        }
    }
}

/// Loads the reply for the interrupt. Returns the DE lead software times
/// (0 when the USART times it) and the tail, µs; whether the USART or the
/// interrupt drops DE after the tail, `send` waits for it.
fn load_reply(bytes: &[u8]) -> [u32; 2] {
    let n = bytes.len().min(MAX_FRAME);
    TX_DONE.reset();
    with_link(|link| {
        link.tx[..n].copy_from_slice(&bytes[..n]);
        link.tx_len = n;
        link.tx_pos = 0;
        link.transmitting = true;
        let de = link.de_drive;
        // (always software on the F103: it has no hardware DE)
        let software = de.software || cfg!(feature = "board-f103");
        [if software { de.lead_us } else { 0 }, de.tail_us]
    })
}

/// Raises or drops DE if software drives it (on the G431 while PA57 /
/// PA58 exceed DEAT / DEDT): the USART's DE pin taken over as a GPIO
/// (output data set first, so the switch from the alternate function, low
/// between frames, is glitch-free) and handed back to the USART low.
#[cfg(feature = "board-g431")]
#[inline(never)]
fn set_de(high: bool) {
    use embassy_stm32::pac::gpio::vals::Moder;
    with_link(|link| {
        if !link.de_drive.software {
            return;
        }
        let (port, pin) = (board::DE_PORT, board::DE_PIN);
        port.bsrr().write(|w| {
            w.set_bs(pin, high);
            w.set_br(pin, !high);
        });
        port.moder().modify(|w| {
            w.set_moder(
                pin,
                if high {
                    Moder::OUTPUT
                } else {
                    Moder::ALTERNATE
                },
            )
        });
    });
}

/// Raises or drops DE: always software on the F103 (a GPIO; one write to
/// its set/reset register, atomic, so no critical section).
#[cfg(feature = "board-f103")]
fn set_de(high: bool) {
    board::DE_PORT.bsrr().write(|w| {
        w.set_bs(board::DE_PIN, high);
        w.set_br(board::DE_PIN, !high);
    });
}

/// STM32F103: closes a frame t3.5 after its last byte (no receiver timeout
/// in this USART). The assembler itself rejects early polls, so a byte that
/// arrives while this task sleeps just makes it sleep again.
#[cfg(feature = "board-f103")]
#[embassy_executor::task]
pub async fn frame_gap_task() {
    loop {
        RX_ACTIVITY.wait().await;
        loop {
            let (receiving, last, t35) = with_link(|link| {
                (
                    link.assembler.is_receiving(),
                    link.assembler.last_byte_at_us(),
                    link.t35_us,
                )
            });
            if !receiving {
                break;
            }
            let wait = super::calc::reply_wait_us(now_us(), last, t35);
            embassy_time::Timer::after_micros(u64::from(wait)).await;
            with_link(|link| {
                let last = link.assembler.last_byte_at_us();
                if let Some(ev) = link.assembler.poll(now_us()) {
                    deliver(Received::new(ev, last));
                }
            });
        }
    }
}
