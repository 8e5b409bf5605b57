//! The RS-485 link: the USART interrupt and the line settings (SPEC §1).
//!
//! Receive: every byte is time-stamped in the interrupt (µs from the
//! embassy-time driver, a free-running timer) and pushed into the core's
//! [`FrameAssembler`] with its parity / framing / overrun flags. A closed
//! frame is copied into a slot of `rx_slots.rs` for the dispatcher task
//! (dispatch.rs).
//! The frame closes after t3.5 of silence:
//! - STM32G431: the USART receiver timeout (RTOF) fires t3.5 after the last
//!   stop bit → [`FrameAssembler::end_of_frame`];
//! - STM32F103 (no receiver timeout): each byte arms SysTick for t3.5
//!   (the one-shot DE uses too, idle while a frame arrives), whose
//!   interrupt has the USART interrupt call [`FrameAssembler::poll`];
//!   t1.5 is judged by the assembler from the timestamps.
//!
//! Transmit: [`load`] and [`finish`] hand the reply to the interrupt, which
//! feeds the data register on TXE (one burst, no gaps) and finishes at TC.
//! DE leads the first start bit and trails the last stop bit by PA57 / PA58
//! ([`apply_line`], `calc::DeDrive`): on the G431 the USART's hardware
//! driver-enable does it (DEAT / DEDT) while they fit; beyond that, and
//! always on the F103, DE is a GPIO timed by SysTick as a one-shot compare
//! (nothing outside this module uses it; embassy-time runs on TIM2): the
//! dispatcher raises DE and arms SysTick for the lead ([`raise_early`] once
//! the core foresees a reply, before it is made; else [`load`] or
//! [`finish`]), whose interrupt starts the transmission once the reply is
//! loaded; at TC the USART interrupt arms it for the tail, whose interrupt
//! drops DE and wakes [`finish`]. No busy wait: the dispatcher awaits, and
//! both interrupts return at once.
//!
//! Shared state, no lock held while bytes are copied (priority.rs):
//! - the link (assembler, line timing, DE lead / tail) belongs to the USART
//!   interrupt; thread code changes it only with that one interrupt
//!   disabled in the NVIC ([`with_link`]), which masks nothing else;
//! - a closed frame goes into one of two slots (`rx_slots.rs`), owned by
//!   the interrupt while free and by the dispatcher once marked full,
//!   handed over with an atomic state; a frame that finds no
//!   free slot is dropped and counted;
//! - a reply goes the same way: [`load`] fills the transmit buffer while no
//!   transmission runs ([`TX_STATE`] idle or early), marks it requested and
//!   pends the interrupt, which starts it (only the interrupt writes CR1
//!   while the link runs); with a software DE it marks the lead instead,
//!   and the SysTick interrupt marks it requested at the lead's end; at TC
//!   the USART interrupt marks the tail, and SysTick idle at its end; a
//!   software DE is raised by the dispatcher before it arms the lead (no
//!   interrupt touches the pin while no transmission runs) and dropped by
//!   the SysTick interrupt at the end of the tail;
//! - SysTick runs at the USART's priority, so neither interrupts the other:
//!   the lead's SysTick interrupt only moves [`TX_STATE`] on and pends the
//!   USART interrupt, which alone touches the link;
//! - F103: the frame gap's SysTick interrupt asks the USART interrupt to
//!   poll the assembler through an atomic flag and a pended interrupt; a
//!   byte arms the gap only while no reply is under way (SysTick times its
//!   lead or tail then), and the end of the tail, or of a DE raised for
//!   nothing, arms it for a frame that arrived meanwhile.
//!
//! `FRAME_READY` and [`TX_DONE`] only wake tasks (embassy-sync signals;
//! their critical section is short and leaves the step engine's refill alone).

use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, AtomicU32, AtomicU8, Ordering};

use embassy_stm32::interrupt::typelevel::{Handler, Interrupt};
use embassy_stm32::mode::Blocking;
use embassy_stm32::usart::{self, Uart};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use modbus_drive::rtu::{
    CharFormat, DriverEnable, FrameAssembler, FrameTiming, LineConfig, RxFlags, MAX_FRAME,
};

use super::board;
use super::calc::DeDrive;
use super::owned::IrqOwned;
use super::rx_slots;

const TX_IDLE: u8 = 0;
const TX_REQUESTED: u8 = 1;
const TX_SENDING: u8 = 2;
/// Software DE: raised, SysTick times the lead, then [`TX_REQUESTED`].
const TX_LEAD: u8 = 3;
/// Software DE: the last stop bit has left, SysTick times the tail, then
/// [`TX_IDLE`].
const TX_TAIL: u8 = 4;
/// Software DE raised for a reply not made yet ([`raise_early`]): SysTick
/// times the lead, then [`TX_EARLY_DONE`]; [`load`] makes it [`TX_LEAD`].
const TX_EARLY: u8 = 5;
/// The early lead is over; [`load`] requests the reply at once.
const TX_EARLY_DONE: u8 = 6;

struct TxBuf {
    bytes: [u8; MAX_FRAME],
    len: usize,
}

/// The reply: [`load`]'s while [`TX_STATE`] is idle or early, the
/// interrupt's once requested.
static TX: IrqOwned<TxBuf> = IrqOwned::new(TxBuf {
    bytes: [0; MAX_FRAME],
    len: 0,
});
static TX_STATE: AtomicU8 = AtomicU8::new(TX_IDLE);
/// The DE lead software times (0: the USART does, or none) and the tail
/// (µs), as [`apply_line`] left them for the dispatcher's calls.
static DE_LEAD_US: AtomicU32 = AtomicU32::new(0);
static DE_TAIL_US: AtomicU32 = AtomicU32::new(0);
static DE_SOFTWARE: AtomicBool = AtomicBool::new(false);
/// The interrupt has sent the last stop bit of the reply.
static TX_DONE: Signal<CriticalSectionRawMutex, ()> = Signal::new();

/// F103: the last byte's time and t3.5, for the frame gap's SysTick.
#[cfg(feature = "board-f103")]
static LAST_BYTE_AT_US: AtomicU32 = AtomicU32::new(0);
#[cfg(feature = "board-f103")]
static T35_US: AtomicU32 = AtomicU32::new(0);
/// F103: the frame gap's SysTick asks the USART interrupt to poll the
/// assembler.
#[cfg(feature = "board-f103")]
static POLL_REQUESTED: AtomicBool = AtomicBool::new(false);
/// F103: a frame is being received (the assembler's `is_receiving`).
#[cfg(feature = "board-f103")]
static RECEIVING: AtomicBool = AtomicBool::new(false);

struct Link {
    assembler: FrameAssembler,
    /// The slot the next frame goes to.
    write_slot: usize,
    tx_pos: usize,
    /// PA57 / PA58 as this board makes them.
    de_drive: DeDrive,
}

/// Owned by the USART interrupt once [`LINK_READY`] is set, which also
/// says it is initialised. Not an `Option`: its `None` is not all zeros and
/// would put the whole link into .data, a flash image of its size.
static LINK: IrqOwned<MaybeUninit<Link>> = IrqOwned::new(MaybeUninit::uninit());
static LINK_READY: AtomicBool = AtomicBool::new(false);

/// `f` on the link from thread code, with the USART interrupt disabled in
/// the NVIC meanwhile (nothing else is masked). The link is set up at the
/// first call.
fn with_link<R>(f: impl FnOnce(&mut Link) -> R) -> R {
    // SAFETY: the link belongs to the USART interrupt while it is enabled;
    // its handler is bound (board::Irqs) and finds the link set up (below,
    // at the first call) and marked so.
    unsafe {
        LINK.with_irq_disabled::<board::UartIrq, _>(|slot| {
            let link = if LINK_READY.load(Ordering::Relaxed) {
                // SAFETY: initialised by the first call (LINK_READY).
                slot.assume_init_mut()
            } else {
                slot.write(Link {
                    assembler: FrameAssembler::new(FrameTiming::new(LineConfig::DEFAULT)),
                    write_slot: 0,
                    tx_pos: 0,
                    // replaced by `apply_line` before the first reply
                    de_drive: DeDrive::default(),
                })
            };
            let r = f(link);
            LINK_READY.store(true, Ordering::Release);
            r
        })
    }
}

/// Microseconds from the embassy-time driver (tick 1 MHz), wrapping.
pub fn now_us() -> u32 {
    embassy_time::Instant::now().as_micros() as u32
}

/// embassy-stm32 USART settings for a line (SPEC §7 PA52/PA53).
pub fn usart_config(line: LineConfig) -> usart::Config {
    let mut c = usart::Config::default();
    c.baudrate = line.baud();
    c.data_bits = usart::DataBits::DataBits8;
    (c.parity, c.stop_bits) = match line.format() {
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

/// Applies a line and the DE lead / tail PA57 / PA58 (at boot and after a
/// reply that changed either) and (re)arms the receive interrupts. Call it
/// between frames.
pub fn apply_line(
    uart: &mut Uart<'static, Blocking>,
    line: LineConfig,
    de: DriverEnable,
) -> Result<(), usart::ConfigError> {
    // embassy rewrites CR1/CR2 here (for the whole USART, whichever half is
    // asked), clearing our interrupt enables
    uart.split_ref().1.set_config(&usart_config(line))?;
    let timing = line.timing();
    #[cfg(feature = "board-f103")]
    T35_US.store(timing.t35_us(), Ordering::Relaxed);
    let de_drive = DeDrive::new(de, line, de_samples_per_bit());
    // the dispatcher's copy: thread code only (the dispatcher, main before it)
    let lead = if de_drive.software {
        de_drive.lead_us
    } else {
        0
    };
    DE_LEAD_US.store(lead, Ordering::Relaxed);
    DE_TAIL_US.store(de_drive.tail_us, Ordering::Relaxed);
    DE_SOFTWARE.store(de_drive.software, Ordering::Relaxed);
    with_link(|link| {
        link.assembler.set_timing(timing);
        link.de_drive = de_drive;
        arm_receiver(line, de_drive);
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
/// SysTick ([`arm_gap_if_receiving`]). Error flags are read with RXNE (SR then DR clears
/// them).
#[cfg(feature = "board-f103")]
fn arm_receiver(_line: LineConfig, _de: DeDrive) {
    board::UART.cr1().modify(|w| w.set_rxneie(true));
}

/// The USART interrupt (priority: `priority::PRIO_UART`).
pub struct UartHandler;

impl Handler<board::UartIrq> for UartHandler {
    unsafe fn on_interrupt() {
        if !LINK_READY.load(Ordering::Acquire) {
            return;
        }
        let at_us = now_us();
        // SAFETY: this interrupt owns the link (thread code disables it
        // before touching the link), initialised (LINK_READY).
        let link = unsafe { LINK.get().assume_init_mut() };
        start_tx(link);
        if let Some(tail_us) = on_uart(link, at_us) {
            // The software DE tail, timed from here rather than from
            // `finish`: the dispatcher task may wake much later (thread mode
            // shares the CPU with the control loop), and a master may send
            // its next request soon after our last stop bit.
            TX_STATE.store(TX_TAIL, Ordering::Relaxed);
            de_timer_start(tail_us);
        }
    }
}

/// Arms SysTick to interrupt once, `us` from now (core clock; at most the
/// longest DE lead or tail, or the F103's t3.5 at the slowest line, well
/// inside its 24 bits).
fn de_timer_start(us: u32) {
    let cycles = us
        .saturating_mul(board::SYSCLK_HZ / 1_000_000)
        .clamp(2, 1 << 24);
    // SAFETY: SysTick is this module's alone (module docs); the register
    // writes are atomic and the exception is not running (it stops the
    // timer before it arms anything).
    unsafe {
        let st = &*cortex_m::peripheral::SYST::PTR;
        st.csr.write(0);
        st.rvr.write(cycles - 1);
        st.cvr.write(0); // clears the counter and COUNTFLAG
        st.csr.write(SYST_ENABLE | SYST_TICKINT | SYST_CORE_CLOCK);
    }
}

/// Stops SysTick; an interrupt it had already raised has run by the
/// return (it outranks thread code).
fn de_timer_stop() {
    // SAFETY: as in `de_timer_start`
    unsafe { (*cortex_m::peripheral::SYST::PTR).csr.write(0) };
    cortex_m::asm::dsb();
    cortex_m::asm::isb();
}

const SYST_ENABLE: u32 = 1 << 0;
const SYST_TICKINT: u32 = 1 << 1;
const SYST_CORE_CLOCK: u32 = 1 << 2;

/// SysTick at the USART's priority (`priority::init`): the end of a
/// software DE lead or tail ([`de_timer_start`]).
#[cortex_m_rt::exception]
fn SysTick() {
    // SAFETY: one-shot: stopped first; only `de_timer_start` rearms it.
    unsafe { (*cortex_m::peripheral::SYST::PTR).csr.write(0) };
    match TX_STATE.load(Ordering::Acquire) {
        // no reply under way: the frame gap ran out
        #[cfg(feature = "board-f103")]
        TX_IDLE => {
            POLL_REQUESTED.store(true, Ordering::Relaxed);
            board::UartIrq::pend();
        }
        TX_LEAD => {
            TX_STATE.store(TX_REQUESTED, Ordering::Release);
            board::UartIrq::pend(); // which starts the transmission
        }
        TX_TAIL => {
            set_de(false);
            TX_STATE.store(TX_IDLE, Ordering::Release);
            TX_DONE.signal(());
            #[cfg(feature = "board-f103")]
            arm_gap_if_receiving();
        }
        // thread code moves it on with a compare-and-swap (`load`)
        TX_EARLY => TX_STATE.store(TX_EARLY_DONE, Ordering::Release),
        _ => {}
    }
}

/// A reply the dispatcher requested: start feeding the data register.
fn start_tx(link: &mut Link) {
    if TX_STATE.load(Ordering::Acquire) != TX_REQUESTED {
        return;
    }
    TX_STATE.store(TX_SENDING, Ordering::Relaxed);
    link.tx_pos = 0;
    board::UART.cr1().modify(|w| w.set_txeie(true));
}

/// The next byte of the reply, or `None` at its end.
fn next_tx_byte(link: &mut Link) -> Option<u8> {
    // SAFETY: TX_STATE is TX_SENDING: the buffer is the interrupt's.
    let tx = unsafe { TX.get() };
    let b = tx.bytes[..tx.len].get(link.tx_pos).copied();
    link.tx_pos += 1;
    b
}

/// The reply has left the wire. Returns the DE tail to time (µs) when
/// software drives DE for it (the caller arms it); otherwise the
/// transmission is over.
fn tx_done(link: &Link) -> Option<u32> {
    if link.de_drive.software {
        return Some(link.de_drive.tail_us);
    }
    TX_STATE.store(TX_IDLE, Ordering::Release);
    TX_DONE.signal(());
    None
}

/// Serves the USART; returns the DE tail to hold (µs) when a reply that
/// software drives DE for has just left the wire.
#[cfg(feature = "board-g431")]
fn on_uart(link: &mut Link, at_us: u32) -> Option<u32> {
    let r = board::UART;
    let isr = r.isr().read();
    // RTOF before the byte: with both set, the timeout ended the frame
    // before this byte arrived (a byte waiting t3.5 for its interrupt
    // would have overrun long before), so the byte starts the next one.
    if isr.rtof() {
        r.icr().write(|w| w.set_rtof(true));
        let last = link.assembler.last_byte_at_us();
        if let Some(ev) = link.assembler.end_of_frame() {
            rx_slots::deliver(&mut link.write_slot, ev, last);
        }
    }
    if isr.rxne() {
        let flags = RxFlags::new(isr.pe(), isr.fe() || isr.ne(), isr.ore());
        let byte = r.rdr().read().dr() as u8; // clears RXNE
                                              // only the flags read with this byte: one raised by the next byte
                                              // meanwhile stays for its own interrupt
        r.icr().write(|w| {
            w.set_pe(isr.pe());
            w.set_fe(isr.fe());
            w.set_ne(isr.ne());
            w.set_ore(isr.ore());
        });
        on_byte(link, byte, at_us, flags);
    } else if isr.ore() {
        r.icr().write(|w| w.set_ore(true));
    }
    let cr1 = r.cr1().read();
    if cr1.txeie() && isr.txe() {
        match next_tx_byte(link) {
            Some(b) => r.tdr().write(|w| w.set_dr(u16::from(b))),
            None => r.cr1().modify(|w| {
                w.set_txeie(false);
                w.set_tcie(true);
            }),
        }
    }
    if cr1.tcie() && isr.tc() {
        // last stop bit sent; the USART drops DE after DEDT by itself
        // unless software drives it
        r.cr1().modify(|w| w.set_tcie(false));
        r.icr().write(|w| w.set_tc(true));
        return tx_done(link);
    }
    None
}

/// Serves the USART; returns the DE tail to hold (µs) when a reply has
/// just left the wire (DE is always software's here).
#[cfg(feature = "board-f103")]
fn on_uart(link: &mut Link, at_us: u32) -> Option<u32> {
    let r = board::UART;
    if POLL_REQUESTED.swap(false, Ordering::Relaxed) {
        let last = link.assembler.last_byte_at_us();
        if let Some(ev) = link.assembler.poll(now_us()) {
            rx_slots::deliver(&mut link.write_slot, ev, last);
        }
        RECEIVING.store(link.assembler.is_receiving(), Ordering::Relaxed);
        // a poll the assembler found early: the rest of the gap
        arm_gap_if_receiving();
    }
    let sr = r.sr().read();
    if sr.rxne() || sr.ore() {
        let flags = RxFlags::new(sr.pe(), sr.fe() || sr.ne(), sr.ore());
        // SR read then DR read clears RXNE, PE, FE, NE and ORE (RM0008)
        let byte = r.dr().read().dr() as u8;
        if sr.rxne() {
            on_byte(link, byte, at_us, flags);
            LAST_BYTE_AT_US.store(link.assembler.last_byte_at_us(), Ordering::Relaxed);
            RECEIVING.store(link.assembler.is_receiving(), Ordering::Relaxed);
            arm_gap_if_receiving();
        }
    }
    let cr1 = r.cr1().read();
    if cr1.txeie() && sr.txe() {
        match next_tx_byte(link) {
            Some(b) => r.dr().write(|w| w.set_dr(u16::from(b))),
            None => r.cr1().modify(|w| {
                w.set_txeie(false);
                w.set_tcie(true);
            }),
        }
    }
    if cr1.tcie() && sr.tc() {
        // the last stop bit has left: the bus is released after the DE
        // tail (SPEC §1)
        r.cr1().modify(|w| w.set_tcie(false));
        return tx_done(link);
    }
    None
}

fn on_byte(link: &mut Link, byte: u8, at_us: u32, flags: RxFlags) {
    // Our own echo (if /RE is not tied to DE) comes only while the USART
    // sends. A byte during a software DE's lead or tail is the master's
    // (one that does not keep t3.5 after our reply): taken, as it was when
    // the tail was a busy wait after TC.
    if matches!(TX_STATE.load(Ordering::Relaxed), TX_REQUESTED | TX_SENDING) {
        return;
    }
    let last = link.assembler.last_byte_at_us();
    if let Some(ev) = link.assembler.push(byte, at_us, flags) {
        rx_slots::deliver(&mut link.write_slot, ev, last);
    }
}

/// Raises a software DE for a reply the core has foreseen
/// (`Device::will_answer_at_once`) before it is made, and times its lead
/// from now: the lead then runs while the dispatcher makes the reply,
/// which [`load`] starts at its end, or at once if it is over. Nothing
/// with no software lead, or while a reply is under way. [`drop_early`]
/// takes it back if no reply comes after all.
pub fn raise_early() {
    let lead = DE_LEAD_US.load(Ordering::Relaxed);
    if lead == 0 || TX_STATE.load(Ordering::Acquire) != TX_IDLE {
        return;
    }
    begin_reply();
    raise_for_lead(TX_EARLY, lead);
}

/// After the core's `poll` loaded no reply: a DE [`raise_early`] raised
/// is dropped (the line was held at its idle level meanwhile, while the
/// master waited for an answer).
pub fn drop_early() {
    if !matches!(TX_STATE.load(Ordering::Acquire), TX_EARLY | TX_EARLY_DONE) {
        return;
    }
    de_timer_stop();
    TX_STATE.store(TX_IDLE, Ordering::Release);
    set_de(false);
    #[cfg(feature = "board-f103")]
    arm_gap_if_receiving();
}

/// Loads `bytes` (≤ 256) as the reply and starts it if its first start
/// bit may leave within the DE lead, `not_before_us` from now: DE rises
/// (unless [`raise_early`] raised it) and the lead runs while the caller
/// goes on (the dispatcher calls this from inside `Device::poll`, as the
/// core queues the reply). Returns whether it started; either way
/// [`finish`] sends the rest of it.
pub fn load(bytes: &[u8], not_before_us: u32) -> bool {
    let due = not_before_us <= DE_LEAD_US.load(Ordering::Relaxed);
    if !due {
        drop_early();
    }
    let state = TX_STATE.load(Ordering::Acquire);
    if !matches!(state, TX_IDLE | TX_EARLY | TX_EARLY_DONE) {
        return false; // never: the dispatcher sends one reply at a time
    }
    let n = bytes.len().min(MAX_FRAME);
    // SAFETY: TX_STATE is idle or early: the buffer is ours until we
    // request.
    let tx = unsafe { TX.get() };
    tx.bytes[..n].copy_from_slice(&bytes[..n]);
    tx.len = n;
    if !due {
        return false;
    }
    if state == TX_IDLE {
        request();
    } else if TX_STATE
        .compare_exchange(TX_EARLY, TX_LEAD, Ordering::AcqRel, Ordering::Acquire)
        .is_err()
    {
        // the early lead ended meanwhile (TX_EARLY_DONE)
        TX_STATE.store(TX_REQUESTED, Ordering::Release);
        board::UartIrq::pend();
    }
    true
}

/// Sends the reply [`load`] loaded, its first start bit no earlier than
/// `not_before_us` from now unless `load` started it already, and returns
/// once the last stop bit has left the wire and DE is released.
pub async fn finish(started: bool, not_before_us: u32) {
    if !started {
        if TX_STATE.load(Ordering::Acquire) != TX_IDLE {
            return;
        }
        // DE rises the lead before the earliest start (or now, and the
        // start waits for the lead). One time-driver tick more: a wait of
        // n ticks may start late in a tick.
        let wait = not_before_us.saturating_sub(DE_LEAD_US.load(Ordering::Relaxed));
        if wait > 0 {
            embassy_time::Timer::after_micros(u64::from(wait) + 1).await;
        }
        request();
    }
    TX_DONE.wait().await;
    // A software DE is released by now (the SysTick interrupt signalled at
    // the end of the tail). The USART's own DEDT tail still runs after TC:
    // whatever follows the reply (`apply_line` disables the USART) waits
    // for it.
    let tail = DE_TAIL_US.load(Ordering::Relaxed);
    if tail > 0 && !de_is_software() {
        embassy_time::Timer::after_micros(u64::from(tail) + 1).await;
    }
}

/// Starts the loaded reply: DE raised and its lead timed by SysTick, whose
/// interrupt then requests it, or requested at once (no software lead).
fn request() {
    begin_reply();
    let lead = DE_LEAD_US.load(Ordering::Relaxed);
    if lead > 0 {
        // SysTick's interrupt starts the reply at the end of the lead
        raise_for_lead(TX_LEAD, lead);
    } else {
        TX_STATE.store(TX_REQUESTED, Ordering::Release);
        board::UartIrq::pend(); // the interrupt starts it
    }
}

/// Before a reply's DE or transmission starts: [`TX_DONE`] cleared for
/// it, and a frame gap SysTick still timed has run by the return, as a
/// gap (it never ends a lead).
fn begin_reply() {
    TX_DONE.reset();
    de_timer_stop();
}

/// Raises DE and times its lead (SysTick), in `state` meanwhile. No
/// transmission runs: no interrupt touches DE.
fn raise_for_lead(state: u8, lead_us: u32) {
    set_de(true);
    TX_STATE.store(state, Ordering::Release);
    de_timer_start(lead_us);
}

/// Software times DE for the line in force ([`apply_line`]).
fn de_is_software() -> bool {
    DE_SOFTWARE.load(Ordering::Relaxed)
}

/// Raises or drops DE where software drives it (on the G431 while PA57 /
/// PA58 exceed DEAT / DEDT): the USART's DE pin taken over as a GPIO
/// (output data set first, so the switch from the alternate function, low
/// between frames, is glitch-free) and handed back to the USART low.
/// Called by the dispatcher to raise it (and to drop a DE raised for a
/// reply that did not come, with SysTick stopped) and by the SysTick
/// interrupt to drop it,
/// never both at once (a transmission runs between them); GPIOA's mode
/// register has no other writer while the drive runs.
#[cfg(feature = "board-g431")]
fn set_de(high: bool) {
    use embassy_stm32::pac::gpio::vals::Moder;
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
}

/// Raises or drops DE: always software on the F103 (a GPIO; one write to
/// its set/reset register, atomic).
#[cfg(feature = "board-f103")]
fn set_de(high: bool) {
    board::DE_PORT.bsrr().write(|w| {
        w.set_bs(board::DE_PIN, high);
        w.set_br(board::DE_PIN, !high);
    });
}

/// F103: arms SysTick for the rest of t3.5 after the last byte while a
/// frame arrives and no reply is under way (a lead or a tail has SysTick
/// then; the end of either calls this again). Called by the USART and
/// SysTick interrupts, which share a priority, and by thread code
/// (`drop_early`), which SysTick's or the USART's interrupt may preempt:
/// each arms the same gap from the same atomics, the last one wins.
#[cfg(feature = "board-f103")]
fn arm_gap_if_receiving() {
    if !RECEIVING.load(Ordering::Relaxed) || TX_STATE.load(Ordering::Acquire) != TX_IDLE {
        return;
    }
    let last = LAST_BYTE_AT_US.load(Ordering::Relaxed);
    let t35 = T35_US.load(Ordering::Relaxed);
    de_timer_start(super::calc::reply_wait_us(now_us(), last, t35));
}
