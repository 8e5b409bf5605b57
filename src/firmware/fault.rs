//! When the firmware fails: the watchdog, and the path every fault takes.
//!
//! Fault path ([`stop`], from a panic, HardFault or an NMI that is not a
//! parameter-page ECC error): interrupts off, then by direct register
//! writes (`board::safe_outputs`, no driver, no lock, no stack beyond a
//! few words) the step timer stopped (CEN and CC1E off), STEP driven low as
//! a GPIO, BRAKE low (brake applied), the RS-485 driver released; ENABLE
//! keeps its level for the brake's engage time PA23 (the power stage holds
//! the axis while the brake closes, docs/drive.md "Brake sequencing"; none
//! of these faults is in the power stage, which the drive has no signal
//! of), timed by SysTick polled with the watchdog fed meanwhile — the one
//! wait by polling in the firmware, in a path that never returns and with
//! every interrupt off — then ENABLE low (power stage off). Then one log
//! line, and the chip waits for the watchdog to reset it — started here if
//! the fault came before `main` started it. Reset rather than halt: after the reset the drive is back on
//! the bus in "switch on disabled" with the brake applied (SPEC §8.1), so
//! the master sees what happened and nothing moves until it enables again;
//! a halted drive would be silent until someone power-cycles it. The wait
//! (the watchdog timeout) holds the outputs safe meanwhile and gives a
//! probe time to read the log line.
//!
//! HardFault resets the stack pointer to the top of the stack before any
//! Rust code runs, so a stack overflow (flip-link puts the stack at the
//! bottom of RAM, where an overflow faults) still reaches the fault path
//! instead of locking the core up with the step timer still pulsing.
//!
//! Watchdog: the IWDG, fed by the control loop at each tick, and only
//! while every other long-lived task has checked in ([`Supervised`]: the
//! dispatcher). Such a task is busy from the event it handles until it
//! waits again; a wait for its next event (a frame) is not a hang, an
//! interrupt ends it. Busy for
//! longer than `calc::TASK_LIMIT_US` (the longest legitimate frame, reply
//! and EE operation) is a stuck task: the control loop stops feeding and
//! the watchdog resets the chip, whose pins are safe from the first
//! instructions (`__pre_init`, board files). A stuck control loop feeds
//! nothing either. Timeout
//! `calc::WATCHDOG_TIMEOUT_US`: the longest legitimate stall of the control
//! loop is an EE operation on the dispatcher (same thread: a page erase of
//! up to 40 ms on either chip, a sequential-storage page move erases once
//! and rewrites a few records: `calc::LONGEST_STALL_US`); the timeout keeps
//! three times that even with the LSI at the top of its tolerance (the
//! F103's runs up to 1.5 times its nominal 40 kHz; `tests/firmware_calc.rs`
//! checks both boards). A control loop stopped for longer is a hung
//! firmware: the step schedule has run dry long before (the planner's
//! horizon), the reset brings the outputs to their safe levels. The IWDG
//! stops while a debug probe halts the core (DBGMCU), so a breakpoint does
//! not reset the chip.
//!
//! G431 flash ECC: a double-word cut short by a power loss in the middle of
//! programming can read back with a double ECC error, which raises the NMI.
//! In the parameter pages that is the parameter store's read failing, not
//! a fault: the NMI clears the flag and notes the address
//! ([`take_flash_read_fault`]), the read returns, and the flash region
//! reports the read as failed (flash.rs), so the boot loads the defaults
//! and says why instead of faulting at every power-up; `main` then erases
//! that page and boots the store again. The sets on that page are lost
//! (the drive runs on the defaults, or on what the other page still holds,
//! and reports it), but the store works again: a word with an ECC error
//! fails every read until its page is erased. Anywhere else (code,
//! constants) it is the fault path.

use core::sync::atomic::{AtomicBool, AtomicU16, AtomicU32, Ordering};

use embassy_stm32::pac;

use super::{board, calc};

#[cfg(feature = "board-g431")]
const LSI_HZ: (u32, u32) = calc::LSI_G431_HZ;
#[cfg(feature = "board-f103")]
const LSI_HZ: (u32, u32) = calc::LSI_F103_HZ;
/// IWDG PR and RLR for the timeout at the nominal LSI.
const IWDG_SETTINGS: (u8, u16) = match calc::iwdg_settings(calc::WATCHDOG_TIMEOUT_US, LSI_HZ.0) {
    Some(s) => s,
    None => panic!("watchdog timeout out of the IWDG's range"),
};

// The watchdog's argument (module docs), checked at build time: the
// registers' timeout with the LSI at the top of its tolerance.
const _: () = assert!(
    calc::iwdg_timeout_us(IWDG_SETTINGS.0, IWDG_SETTINGS.1, LSI_HZ.1) >= 3 * calc::LONGEST_STALL_US
);

/// The running IWDG; [`Watchdog::feed`] at least every
/// `calc::WATCHDOG_TIMEOUT_US` or the chip resets.
pub struct Watchdog(());

impl Watchdog {
    /// Sets the timeout and starts the IWDG: from now on only a reset stops it.
    pub fn start() -> Self {
        use pac::iwdg::vals::{Key, Pr};
        let w = pac::IWDG;
        w.kr().write(|w| w.set_key(Key::ENABLE)); // unlock PR and RLR
        w.pr().write(|w| w.set_pr(Pr::from_bits(IWDG_SETTINGS.0)));
        w.rlr().write(|w| w.set_rl(IWDG_SETTINGS.1));
        w.kr().write(|w| w.set_key(Key::START));
        Self(())
    }

    /// Feeds the IWDG if every supervised task has checked in (module
    /// docs); the control loop's own tick is the check of itself.
    pub fn feed(&self) {
        let now = now_ms();
        if DISPATCHER.overdue(now) {
            if !STUCK_LOGGED.swap(true, Ordering::Relaxed) {
                defmt::error!("a task is stuck: watchdog no longer fed, reset follows");
            }
            return;
        }
        pac::IWDG
            .kr()
            .write(|w| w.set_key(pac::iwdg::vals::Key::RESET));
    }
}

static STUCK_LOGGED: AtomicBool = AtomicBool::new(false);

/// ms since boot, wrapping (the time driver's).
fn now_ms() -> u32 {
    // the crate's 32-bit-step division: `as_millis` would link
    // compiler_builtins' 64-bit one for this single use
    modbus_drive::arith::div_u64(embassy_time::Instant::now().as_micros(), 1000) as u32
}

/// A long-lived task the watchdog supervises besides the control loop:
/// busy since when (ms + 1, 0 = waiting for its next event).
pub struct Supervised(AtomicU32);

impl Supervised {
    const fn new() -> Self {
        Self(AtomicU32::new(0))
    }
    /// The task took up an event (again): its time starts now.
    pub fn busy(&self) {
        self.0
            .store(now_ms().wrapping_add(1).max(1), Ordering::Relaxed);
    }
    /// The task waits for its next event.
    pub fn idle(&self) {
        self.0.store(0, Ordering::Relaxed);
    }
    fn overdue(&self, now: u32) -> bool {
        let since = self.0.load(Ordering::Relaxed);
        since != 0 && now.wrapping_add(1).wrapping_sub(since) > calc::TASK_LIMIT_US / 1000
    }
}

pub static DISPATCHER: Supervised = Supervised::new();

/// PA23 as the control loop last saw it: the fault path's brake hold.
static BRAKE_ENGAGE_MS: AtomicU16 = AtomicU16::new(0);

/// The control loop passes PA23 on (see [`stop`]).
pub fn set_brake_engage_ms(ms: u16) {
    BRAKE_ENGAGE_MS.store(ms, Ordering::Relaxed);
}

/// No ECC error noted in [`FLASH_READ_FAULT`].
const NO_FAULT: u32 = u32::MAX;
/// The flash offset of a double ECC error in the parameter pages since the
/// last [`take_flash_read_fault`] (set by the NMI).
static FLASH_READ_FAULT: AtomicU32 = AtomicU32::new(NO_FAULT);

/// The flash region's read-fault hook (flash.rs): the offset of a
/// parameter-page read reported failed since the last call.
#[cfg_attr(not(feature = "board-g431"), allow(dead_code))] // F103: no ECC
pub fn take_flash_read_fault() -> Option<u32> {
    let at = FLASH_READ_FAULT.swap(NO_FAULT, Ordering::Relaxed);
    (at != NO_FAULT).then_some(at)
}

/// Set at the first entry into [`stop`]: a fault inside the fault path
/// (e.g. in the log line) goes straight to the wait.
static FAULTED: AtomicBool = AtomicBool::new(false);

#[derive(Clone, Copy, defmt::Format)]
pub enum Fault {
    Panic,
    Hard,
    Nmi,
}

/// The fault path (see the module docs). Never returns.
pub fn stop(fault: Fault) -> ! {
    cortex_m::interrupt::disable();
    // the step engine stopped (a break: STEP low at once) before the pins
    // are taken over
    super::steps::stop();
    let first = !FAULTED.swap(true, Ordering::Relaxed);
    board::safe_outputs(true);
    pac::IWDG
        .kr()
        .write(|w| w.set_key(pac::iwdg::vals::Key::START));
    if first {
        hold_for_the_brake(BRAKE_ENGAGE_MS.load(Ordering::Relaxed));
    }
    board::safe_outputs(false);
    if first {
        defmt::error!(
            "{}: step output stopped, brake applied, ENABLE off; watchdog reset follows",
            fault
        );
    }
    loop {
        // NOP rather than `spin_loop`'s YIELD hint: the same wait, and an
        // instruction every Cortex-M model knows (fw-sim's does not YIELD)
        cortex_m::asm::nop();
    }
}

/// The fault path's brake hold: `ms` milliseconds by SysTick's count flag
/// (1 ms periods of the core clock; interrupts are off), the watchdog fed
/// at each.
fn hold_for_the_brake(ms: u16) {
    if ms == 0 {
        return;
    }
    // SAFETY: the fault path owns the core from here on (interrupts off,
    // never returns); SysTick's DE timing is over with the USART.
    unsafe {
        let st = &*cortex_m::peripheral::SYST::PTR;
        st.csr.write(0);
        st.rvr.write(board::SYSCLK_HZ / 1000 - 1);
        st.cvr.write(0);
        st.csr.write(1 << 2 | 1); // core clock, enabled, no interrupt
        for _ in 0..ms {
            while st.csr.read() & (1 << 16) == 0 {} // COUNTFLAG, cleared by the read
            pac::IWDG
                .kr()
                .write(|w| w.set_key(pac::iwdg::vals::Key::RESET));
        }
        st.csr.write(0);
    }
}

#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    stop(Fault::Panic)
}

// HardFault: a fresh stack first (see the module docs), then the fault
// path. The vector table points at this symbol (cortex-m-rt's `HardFault`).
core::arch::global_asm!(
    ".section .HardFault.user, \"ax\"",
    ".global HardFault",
    ".type HardFault, %function",
    ".thumb_func",
    "HardFault:",
    "ldr r0, =_stack_start",
    "bic r0, r0, #7",
    "msr msp, r0",
    "isb",
    "b {entry}",
    ".ltorg",
    entry = sym hard_fault_entry,
);

extern "C" fn hard_fault_entry() -> ! {
    stop(Fault::Hard)
}

#[cortex_m_rt::exception]
unsafe fn NonMaskableInt() {
    #[cfg(feature = "board-g431")]
    if let Some(at) = board::take_parameter_ecc_error() {
        FLASH_READ_FAULT.store(at, Ordering::Relaxed);
        return; // the read that hit it reports it (flash.rs)
    }
    stop(Fault::Nmi)
}

/// Test builds only (`--features fault-test`, for the firmware-in-the-loop
/// tests): a write (function 0x06) to register 0xFA17 of 0xDEAD panics, of
/// 0x5717 sticks the dispatcher (it never finishes that frame), of 0xC0DE
/// sticks the control loop (it never ticks again). Returns true for the
/// dispatcher's.
#[cfg(feature = "fault-test")]
pub fn test_trigger(ev: modbus_drive::rtu::RxEvent<'_>) -> bool {
    let modbus_drive::rtu::RxEvent::Frame {
        bytes: [_, 0x06, 0xFA, 0x17, hi, lo, ..],
        ..
    } = ev
    else {
        return false;
    };
    match u16::from_be_bytes([*hi, *lo]) {
        0xDEAD => panic!("fault-test trigger"),
        0xC0DE => {
            CONTROL_STUCK.store(true, Ordering::Relaxed);
            false
        }
        0x5717 => true,
        _ => false,
    }
}

#[cfg(feature = "fault-test")]
static CONTROL_STUCK: AtomicBool = AtomicBool::new(false);

/// Test builds only: the control loop is to stick ([`test_trigger`]).
#[cfg(feature = "fault-test")]
pub fn control_stuck() -> bool {
    CONTROL_STUCK.load(Ordering::Relaxed)
}
