//! Cortex-M4 instruction counts on QEMU's `mps2-an386` (docs/benchmarks.md).
//!
//! QEMU runs with `-icount shift=0`: virtual time advances 1 ns per executed
//! instruction. SysTick counts the 25 MHz CPU clock (CLKSOURCE = 1), so one
//! tick is 40 ns = 40 instructions. Each workload is called `n` times
//! through a black-boxed function pointer between two SysTick reads; the same
//! loop around an empty call is subtracted. A run of 1000 NOPs checks the
//! scale before anything else is trusted.
//!
//! Output goes through semihosting; the exit status is non-zero when a
//! result is wrong or a target (docs/benchmarks.md) is missed.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("qemu-bench runs on thumbv7em-none-eabihf under QEMU: use benches/run-qemu.sh");
    std::process::exit(2);
}

#[cfg(target_os = "none")]
mod rt;

#[cfg(target_os = "none")]
// The profile build runs `profile` instead of `run`.
#[cfg_attr(feature = "profile", allow(dead_code))]
mod bench {
    use core::fmt::Write;
    use core::hint::black_box;

    use crate::rt::{exit, Console};
    use workloads::dma_refill::{simulate_dma_move, RefillCost, HALF_ENTRIES};
    use workloads::per_step::{per_step_move, PerStep};
    use workloads::*;

    /// Instructions per SysTick tick: 25 MHz CPU clock, 1 ns per instruction.
    const INSTR_PER_TICK: u64 = 40;

    const SYST_CSR: *mut u32 = 0xE000_E010 as *mut u32;
    const SYST_RVR: *mut u32 = 0xE000_E014 as *mut u32;
    const SYST_CVR: *mut u32 = 0xE000_E018 as *mut u32;

    fn systick_start() {
        // SAFETY: SysTick registers of the Cortex-M4 (ARMv7-M ARM B3.3).
        unsafe {
            SYST_RVR.write_volatile(0x00FF_FFFF);
            SYST_CVR.write_volatile(0);
            // ENABLE, no interrupt, CLKSOURCE = processor clock
            SYST_CSR.write_volatile(0b101);
        }
    }

    #[inline(always)]
    fn systick_now() -> u32 {
        // SAFETY: read of the SysTick current value register.
        unsafe { SYST_CVR.read_volatile() }
    }

    /// Ticks taken by `n` calls of `f` (SysTick counts down, 24 bits), and
    /// the last result.
    #[inline(never)]
    fn ticks<S>(state: &mut S, f: fn(&mut S) -> u32, n: u32) -> (u32, u32) {
        let f = black_box(f);
        let start = systick_now();
        let mut r = 0;
        for _ in 0..n {
            r = f(black_box(&mut *state));
        }
        let end = systick_now();
        (start.wrapping_sub(end) & 0x00FF_FFFF, r)
    }

    /// Instructions per call of `f` in tenths (rounded), the empty call
    /// subtracted.
    fn measure<S>(state: &mut S, f: fn(&mut S) -> u32, n: u32) -> (u64, u32) {
        let (t_empty, _) = ticks(state, empty::<S>, n);
        let (t, r) = ticks(state, f, n);
        if t >= 0x00F0_0000 {
            fail("a measurement came near the 24-bit SysTick wrap: lower n");
        }
        let net = u64::from(t.saturating_sub(t_empty)) * INSTR_PER_TICK;
        (
            (net * 10 + u64::from(n) / 2) / u64::from(n), // rounded
            r,
        )
    }

    fn fail(msg: &str) -> ! {
        let _ = writeln!(Console, "FAIL: {msg}");
        exit(false)
    }

    /// Prints one figure: `tenths` instructions per `unit`, and its limit.
    fn row(name: &str, tenths: u64, unit: &str, target: Option<u64>, ok: &mut bool) {
        let mut c = Console;
        let _ = write!(
            c,
            "{name:<38} {:>7}.{} /{unit:<5}",
            tenths / 10,
            tenths % 10
        );
        match target {
            Some(max) if tenths <= max * 10 => {
                let _ = writeln!(c, "  target <= {max:<5} ok");
            }
            Some(max) => {
                let _ = writeln!(c, "  target <= {max:<5} MISSED");
                *ok = false;
            }
            None => {
                let _ = writeln!(c);
            }
        }
    }

    fn expect(what: &str, got: u32, want: u32) {
        if got != want {
            let _ = writeln!(Console, "FAIL: {what}: result {got}, expected {want}");
            exit(false)
        }
    }

    /// One simulated move in the glue's rhythm: checks that it ends at
    /// `steps`, prints its counts and the interrupt's and the planner's
    /// instructions per step (tenths) against `targets`, returns both.
    fn move_rows(
        name: &str,
        steps: u32,
        cost: MoveCost,
        overhead: u64,
        targets: [Option<u64>; 2],
        ok: &mut bool,
    ) -> (u64, u64) {
        expect(name, cost.final_position as u32, steps);
        let net = |ticks: u32, calls: u32| {
            (u64::from(ticks) * INSTR_PER_TICK * 10).saturating_sub(u64::from(calls) * overhead)
                / u64::from(cost.steps)
        };
        let _ = writeln!(
            Console,
            "   ({} steps, {} interrupt calls, {} planner calls)",
            cost.steps, cost.advance_calls, cost.fill_calls
        );
        let isr = net(cost.advance_clock, cost.advance_calls);
        let planner = net(cost.fill_clock, cost.fill_calls);
        row(
            "step interrupt side (StepSource::advance)",
            isr,
            "step",
            targets[0],
            ok,
        );
        row(
            "planner (Planner::fill), amortised",
            planner,
            "step",
            targets[1],
            ok,
        );
        (isr, planner)
    }

    /// One move by the DMA engine's refill side: checks that it wrote one
    /// pulse per step and none late, prints the refill's instructions per
    /// step (tenths) against `target`.
    fn refill_row(
        name: &str,
        steps: u32,
        cost: RefillCost,
        overhead: u64,
        target: Option<u64>,
        ok: &mut bool,
    ) {
        expect(name, cost.final_position as u32, steps);
        expect("refill: pulses", cost.pulses, steps);
        expect("refill: late steps", cost.late, 0);
        let per_step = (u64::from(cost.refill_clock) * INSTR_PER_TICK * 10)
            .saturating_sub(u64::from(cost.refill_calls) * overhead)
            / u64::from(steps);
        let _ = writeln!(
            Console,
            "   ({} steps, {} refills of {} entries)",
            steps, cost.refill_calls, HALF_ENTRIES
        );
        row(
            "DMA refill (advance + BurstWriter)",
            per_step,
            "step",
            target,
            ok,
        );
    }

    /// 1000 NOPs: checks 40 instructions per tick and the baseline.
    #[inline(never)]
    fn nops_1000(_: &mut ()) -> u32 {
        // SAFETY: NOPs only.
        unsafe { core::arch::asm!(".rept 1000", "nop", ".endr", options(nomem, nostack)) };
        1
    }

    /// The markers benches/profile-qemu.sh looks for in QEMU's trace.
    #[cfg(feature = "profile")]
    #[inline(never)]
    #[no_mangle]
    extern "C" fn profile_start() {
        black_box(1u32);
    }
    #[cfg(feature = "profile")]
    #[inline(never)]
    #[no_mangle]
    extern "C" fn profile_end() {
        black_box(2u32);
    }

    #[cfg(feature = "profile")]
    fn profile_one<S>(state: &mut S, f: fn(&mut S) -> u32) -> ! {
        let f = black_box(f);
        for _ in 0..3 {
            f(state); // warm: first-call paths out of the picture
        }
        profile_start();
        let r = f(black_box(state));
        profile_end();
        let _ = writeln!(Console, "profiled one call, result {r}");
        exit(true)
    }

    /// One call of the workload named `which`, between the two markers.
    #[cfg(feature = "profile")]
    pub fn profile(which: &str) -> ! {
        for (i, (_, frame, _)) in frames::ALL.iter().enumerate() {
            let key = ["fc03-2", "fc03-10", "fc10", "fc06"][i];
            if which.strip_prefix("drive-") == Some(key) {
                profile_one(&mut DriveSlave::new(frame), drive_slave_frame);
            }
            if which.strip_prefix("rmodbus-") == Some(key) {
                profile_one(&mut RmodbusSlave::new(frame), rmodbus_frame);
            }
            if which.strip_prefix("assembler-") == Some(key) {
                profile_one(&mut AssemblerFeed::new(frame), assembler_frame);
            }
        }
        if which == "perstep" {
            profile_one(&mut PerStep::default(), per_step_move);
        }
        if which == "move" {
            fn one_move(_: &mut ()) -> u32 {
                simulate_move(i64::from(RAMP_MOVE_STEPS), || 0).steps
            }
            profile_one(&mut (), one_move);
        }
        fail("BENCH_PROFILE: move, perstep, or drive-|rmodbus-|assembler- + fc03-2|fc03-10|fc10|fc06")
    }

    #[inline(never)]
    fn nothing() -> u32 {
        0
    }

    /// 1013 NOPs: not a multiple of 40, so timed regions around it land on
    /// every phase of the SysTick tick; their average must still be exact.
    #[inline(never)]
    fn nops_1013() -> u32 {
        // SAFETY: NOPs only.
        unsafe { core::arch::asm!(".rept 1013", "nop", ".endr", options(nomem, nostack)) };
        1
    }

    pub fn run() -> ! {
        systick_start();
        let mut ok = true;
        let mut c = Console;
        let _ = writeln!(
            c,
            "QEMU mps2-an386 (Cortex-M4), -icount shift=0, SysTick x {INSTR_PER_TICK}; \
             instructions per call, empty call subtracted"
        );

        // ---- harness check
        let (nop, _) = measure(&mut (), nops_1000, 100);
        row("harness: 1000 NOPs", nop, "call", None, &mut ok);
        if nop.abs_diff(10_000) > 10 {
            fail("1000 NOPs did not measure as 1000 +- 1 instructions");
        }

        // ---- CRC
        let mut crc_in = CrcInput::default();
        let (ours, r1) = measure(&mut crc_in, crc_ours_8, 1000);
        let (theirs, r2) = measure(&mut crc_in, crc_crate_8, 1000);
        expect("crc16 = crc crate", r1, r2);
        row(
            "crc crate CRC_16_MODBUS, 8 bytes",
            theirs,
            "call",
            None,
            &mut ok,
        );
        row(
            "modbus-drive rtu::crc16, 8 bytes",
            ours,
            "call",
            None,
            &mut ok,
        );

        // ---- frame assembler, per received byte: (one `push` call per byte
        // + the `poll` that closes the frame) minus the same feed loop with
        // empty calls, divided by the frame length
        for (name, frame, _) in frames::ALL {
            let mut feed = AssemblerFeed::new(frame);
            let (t, len) = measure(&mut feed, assembler_frame, 1000);
            expect("assembler frame length", len, frame.len() as u32);
            let mut harness = AssemblerFeed::harness_only(frame);
            let (t0, _) = measure(&mut harness, assembler_frame, 1000);
            let mut label = heapless::String::<48>::new();
            let _ = write!(label, "frame assembler: {name} ({} B)", frame.len());
            let per_byte = t.saturating_sub(t0) / frame.len() as u64;
            row(&label, per_byte, "byte", Some(25), &mut ok);
        }

        // ---- the slave path against rmodbus on the same four frames
        let _ = writeln!(
            c,
            "-- slave path per frame: modbus-drive Device::handle_rx vs rmodbus 0.13 \
             (no_std, ModbusStorage: parse + process + finalize)"
        );
        for (name, frame, reply_len) in frames::ALL {
            let mut theirs = RmodbusSlave::new(frame);
            let (t_theirs, len) = measure(&mut theirs, rmodbus_frame, 200);
            expect("rmodbus reply length", len, reply_len as u32);
            expect(
                "rmodbus reply function",
                theirs.response()[1].into(),
                frame[1].into(),
            );
            let mut ours = DriveSlave::new(frame);
            let (t_ours, len) = measure(&mut ours, drive_slave_frame, 200);
            expect("modbus-drive reply length", len, reply_len as u32);
            expect(
                "modbus-drive reply function",
                ours.reply()[1].into(),
                frame[1].into(),
            );
            let mut label = heapless::String::<48>::new();
            let _ = write!(label, "rmodbus: {name}");
            row(&label, t_theirs, "frame", None, &mut ok);
            label.clear();
            let _ = write!(label, "modbus-drive: {name}");
            // target: at most 40 % of rmodbus (tenths, rounded down)
            row(&label, t_ours, "frame", Some(t_theirs * 4 / 100), &mut ok);
            let _ = writeln!(
                c,
                "{:<38} {:>7}.{} %     target <= 40 %",
                "  = share of rmodbus",
                t_ours * 100 / t_theirs,
                (t_ours * 1000 / t_theirs) % 10
            );
        }

        // ---- step generation
        let _ = writeln!(
            c,
            "-- step generation ({RAMP_MOVE_STEPS}-step move, per step)"
        );
        let mut fixed = RampMakerFixed::default();
        let (t, steps) = measure(&mut fixed, ramp_maker_fixed_move, 3);
        expect("ramp-maker (fixed) delays per move", steps, RAMP_MOVE_STEPS);
        let ramp_fixed = t / u64::from(steps);
        row(
            "ramp-maker 0.2 trapezoidal, fixed",
            ramp_fixed,
            "step",
            None,
            &mut ok,
        );
        let mut float = RampMakerF32::default();
        let (t, steps) = measure(&mut float, ramp_maker_f32_move, 20);
        expect("ramp-maker (f32) delays per move", steps, RAMP_MOVE_STEPS);
        let ramp_f32 = t / u64::from(steps);
        row(
            "ramp-maker 0.2 trapezoidal, f32",
            ramp_f32,
            "step",
            None,
            &mut ok,
        );
        let mut klipper = KlipperStepper::default();
        let (t, _) = measure(&mut klipper, klipper_step_event, 10_000);
        row("Klipper-style step event", t, "step", None, &mut ok);

        // ---- the drive's step generation, in the glue's rhythm: timed
        // regions around every planner fill and every interrupt step
        let _ = writeln!(
            c,
            "-- modbus-drive step generation: the same move, 1 kHz control loop, \
             10 MHz step timer, SysTick read around every call"
        );
        let regions = 4000;
        let clock_only = time_regions(systick_now, nothing, regions);
        let with_nops = time_regions(systick_now, nops_1013, regions);
        // tenths of an instruction per region
        let per_region = |ticks: u32| u64::from(ticks) * INSTR_PER_TICK * 10 / u64::from(regions);
        let check = per_region(with_nops) - per_region(clock_only);
        row(
            "harness: 1013 NOPs in timed regions",
            check,
            "call",
            None,
            &mut ok,
        );
        if check.abs_diff(10_130) > 10 {
            fail("timed regions did not average to 1013 +- 1 instructions");
        }
        let overhead = per_region(clock_only);
        let (isr, planner) = move_rows(
            "simulated move: final position",
            RAMP_MOVE_STEPS,
            simulate_move(i64::from(RAMP_MOVE_STEPS), systick_now),
            overhead,
            [Some(20), Some(60)],
            &mut ok,
        );
        let _ = writeln!(
            c,
            "   planner + interrupt = {:.2} x ramp-maker fixed, {:.2} x ramp-maker f32 (per step)",
            (isr + planner) as f32 / ramp_fixed as f32,
            (isr + planner) as f32 / ramp_f32 as f32
        );

        // ---- the timer + DMA engine's CPU share: the refill (designed,
        // not yet used by the firmware: docs/firmware.md)
        let _ = writeln!(
            c,
            "-- the same move by the timer + DMA engine's refill side (workloads/src/dma_refill.rs)"
        );
        refill_row(
            "DMA refill: final position",
            RAMP_MOVE_STEPS,
            simulate_dma_move(i64::from(RAMP_MOVE_STEPS), MOVE_RAMP, systick_now),
            overhead,
            Some(20),
            &mut ok,
        );

        // ---- the same on a faster move, for information (no target)
        let _ = writeln!(
            c,
            "-- for information, no target: the seed's move, {SEED_MOVE_STEPS} steps at \
             50 000 steps/s, 100 000 steps/s², same rhythm"
        );
        move_rows(
            "seed move: final position",
            SEED_MOVE_STEPS,
            simulate_move_with(i64::from(SEED_MOVE_STEPS), SEED_RAMP, systick_now),
            overhead,
            [None, None],
            &mut ok,
        );

        refill_row(
            "seed move by DMA refill: final position",
            SEED_MOVE_STEPS,
            simulate_dma_move(i64::from(SEED_MOVE_STEPS), SEED_RAMP, systick_now),
            overhead,
            None,
            &mut ok,
        );

        // ---- a design experiment, for information (no target)
        let _ = writeln!(
            c,
            "-- for information, no target: the same {RAMP_MOVE_STEPS}-step move by a per-step \
             planner (experiment, workloads/src/per_step.rs), same rhythm"
        );
        let mut per_step = PerStep::default();
        let (t, steps) = measure(&mut per_step, per_step_move, 3);
        expect("per-step experiment: steps", steps, RAMP_MOVE_STEPS);
        row(
            "per-step exact roots, whole move",
            t / u64::from(steps),
            "step",
            None,
            &mut ok,
        );

        if ok {
            let _ = writeln!(c, "all targets met");
        } else {
            let _ = writeln!(c, "FAIL: a target was missed");
        }
        exit(ok)
    }
}

#[cfg(target_os = "none")]
#[no_mangle]
extern "C" fn bench_main() -> ! {
    #[cfg(feature = "profile")]
    bench::profile(option_env!("BENCH_PROFILE").unwrap_or(""));
    #[cfg(not(feature = "profile"))]
    bench::run()
}
