//! When the firmware fails: the watchdog, and the path every fault takes.
//!
//! Fault path ([`stop`], from a panic, HardFault or an NMI that is not a
//! parameter-page ECC error): interrupts off, then by direct register
//! writes (`board::safe_outputs`, no driver, no lock, no stack beyond a
//! few words) the step timer stopped (CEN and CC1E off), STEP driven low as
//! a GPIO, ENABLE low (power stage off), BRAKE low (brake applied), the
//! RS-485 driver released. Then one log line, and the chip waits for the
//! watchdog to reset it — started here if the fault came before `main`
//! started it. Reset rather than halt: after the reset the drive is back on
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
//! Watchdog: the IWDG, fed by the control loop at each tick. Timeout
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

use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

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

    pub fn feed(&self) {
        pac::IWDG
            .kr()
            .write(|w| w.set_key(pac::iwdg::vals::Key::RESET));
    }
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
    // the step timer is the same TIM3 on both boards: counter and compare
    // output off before the pins are taken over
    let t = board::STEP_TIMER;
    t.cr1().modify(|w| w.set_cen(false));
    t.ccer().modify(|w| w.set_cce(0, false));
    board::safe_outputs();
    pac::IWDG
        .kr()
        .write(|w| w.set_key(pac::iwdg::vals::Key::START));
    if !FAULTED.swap(true, Ordering::Relaxed) {
        defmt::error!(
            "{}: step output stopped, ENABLE off, brake applied; watchdog reset follows",
            fault
        );
    }
    loop {
        // NOP rather than `spin_loop`'s YIELD hint: the same wait, and an
        // instruction every Cortex-M model knows (fw-sim's does not YIELD)
        cortex_m::asm::nop();
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
/// tests): a write of 0xDEAD to register 0xFA17 (function 0x06) panics.
#[cfg(feature = "fault-test")]
pub fn test_trigger(ev: modbus_drive::rtu::RxEvent<'_>) {
    if let modbus_drive::rtu::RxEvent::Frame {
        bytes: [_, 0x06, 0xFA, 0x17, 0xDE, 0xAD, ..],
        ..
    } = ev
    {
        panic!("fault-test trigger");
    }
}
