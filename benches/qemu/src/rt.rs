//! Just enough runtime for QEMU: vector table, reset (FPU on, then the
//! bench), fault and panic handlers, ARM semihosting for output and exit.
//! No cortex-m-rt: the bench links with its own bench.ld.

use core::fmt;

type Handler = unsafe extern "C" fn() -> !;

/// Exceptions 1..=15 (the initial stack pointer comes from bench.ld).
#[link_section = ".vector_table"]
#[no_mangle]
#[used]
static VECTORS: [Option<Handler>; 15] = [
    Some(reset),
    Some(fault), // NMI
    Some(fault), // HardFault
    Some(fault), // MemManage
    Some(fault), // BusFault
    Some(fault), // UsageFault
    None,
    None,
    None,
    None,
    Some(fault), // SVCall
    Some(fault), // DebugMonitor
    None,
    Some(fault), // PendSV
    Some(fault), // SysTick (its interrupt is never enabled)
];

#[no_mangle]
unsafe extern "C" fn reset() -> ! {
    // CPACR: full access to CP10/CP11, or the first FPU instruction faults.
    let cpacr = 0xE000_ED88 as *mut u32;
    cpacr.write_volatile(cpacr.read_volatile() | (0xF << 20));
    core::arch::asm!("dsb", "isb");
    crate::bench_main()
}

unsafe extern "C" fn fault() -> ! {
    let _ = fmt::Write::write_str(&mut Console, "FAIL: CPU fault\n");
    exit(false)
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    let _ = fmt::Write::write_fmt(&mut Console, format_args!("FAIL: panic: {info}\n"));
    exit(false)
}

fn semihost(op: u32, arg: u32) -> u32 {
    let r;
    // SAFETY: ARM semihosting call (BKPT 0xAB, r0 = operation, r1 = argument).
    unsafe {
        core::arch::asm!("bkpt #0xab", inout("r0") op => r, in("r1") arg, options(nostack));
    }
    r
}

/// Ends QEMU: exit status 0 (ApplicationExit) or 1 (any other reason).
pub fn exit(ok: bool) -> ! {
    const SYS_EXIT: u32 = 0x18;
    let reason = if ok { 0x2_0026 } else { 0x2_0023 };
    semihost(SYS_EXIT, reason);
    loop {
        core::hint::spin_loop();
    }
}

/// Semihosting console (SYS_WRITE0 of NUL-terminated chunks).
pub struct Console;

impl fmt::Write for Console {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        const SYS_WRITE0: u32 = 0x04;
        let mut buf = [0u8; 65];
        for chunk in s.as_bytes().chunks(64) {
            buf[..chunk.len()].copy_from_slice(chunk);
            buf[chunk.len()] = 0;
            semihost(SYS_WRITE0, buf.as_ptr() as u32);
        }
        Ok(())
    }
}
