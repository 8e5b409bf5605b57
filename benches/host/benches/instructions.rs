//! Host instruction counts under valgrind (callgrind, via gungraun): the
//! same workloads as the Cortex-M4 bench (../workloads), one call each,
//! state built and warmed up in `setup` so that only the call is counted.
//! `benches/run-host.sh` runs this and prints the ratios.
use std::hint::black_box;

use gungraun::prelude::*;
use gungraun::{Callgrind, EntryPoint};
use workloads::*;

/// Built outside the measurement, leaked so that no drop is measured
/// either, and called once so that first-call paths are out of the way.
fn warm<S>(state: S, f: fn(&mut S) -> u32) -> &'static mut S {
    let s = Box::leak(Box::new(state));
    f(s);
    s
}

fn drive(frame: &'static [u8]) -> &'static mut DriveSlave {
    warm(DriveSlave::new(frame), drive_slave_frame)
}

fn rmodbus(frame: &'static [u8]) -> &'static mut RmodbusSlave {
    warm(RmodbusSlave::new(frame), rmodbus_frame)
}

fn feed(frame: &'static [u8]) -> &'static mut AssemblerFeed {
    warm(AssemblerFeed::new(frame), assembler_frame)
}

fn feed_harness_only(frame: &'static [u8]) -> &'static mut AssemblerFeed {
    warm(AssemblerFeed::harness_only(frame), assembler_frame)
}

fn fixed() -> &'static mut RampMakerFixed {
    warm(RampMakerFixed::default(), ramp_maker_fixed_move)
}

fn float() -> &'static mut RampMakerF32 {
    warm(RampMakerF32::default(), ramp_maker_f32_move)
}

fn klipper() -> &'static mut KlipperStepper {
    warm(KlipperStepper::default(), klipper_step_event)
}

#[library_benchmark]
#[bench::fc03_read_2(args = (frames::READ_2), setup = drive)]
#[bench::fc03_read_10(args = (frames::READ_10), setup = drive)]
#[bench::fc10_write_9(args = (frames::WRITE_9), setup = drive)]
#[bench::fc06_write_1(args = (frames::WRITE_1), setup = drive)]
fn slave_drive(s: &'static mut DriveSlave) -> u32 {
    black_box(drive_slave_frame(black_box(s)))
}

#[library_benchmark]
#[bench::fc03_read_2(args = (frames::READ_2), setup = rmodbus)]
#[bench::fc03_read_10(args = (frames::READ_10), setup = rmodbus)]
#[bench::fc10_write_9(args = (frames::WRITE_9), setup = rmodbus)]
#[bench::fc06_write_1(args = (frames::WRITE_1), setup = rmodbus)]
fn slave_rmodbus(s: &'static mut RmodbusSlave) -> u32 {
    black_box(rmodbus_frame(black_box(s)))
}

#[library_benchmark]
#[bench::fc03_read_2(args = (frames::READ_2), setup = feed)]
#[bench::fc10_write_9(args = (frames::WRITE_9), setup = feed)]
fn assembler(s: &'static mut AssemblerFeed) -> u32 {
    black_box(assembler_frame(black_box(s)))
}

// The same feed loop with empty calls (subtracted from `assembler`).
#[library_benchmark]
#[bench::fc03_read_2(args = (frames::READ_2), setup = feed_harness_only)]
#[bench::fc10_write_9(args = (frames::WRITE_9), setup = feed_harness_only)]
fn assembler_feed_only(s: &'static mut AssemblerFeed) -> u32 {
    black_box(assembler_frame(black_box(s)))
}

// A whole move of `RAMP_MOVE_STEPS` steps (the report divides).
#[library_benchmark]
#[bench::fixed(setup = fixed)]
fn ramp_maker_fixed(s: &'static mut RampMakerFixed) -> u32 {
    black_box(ramp_maker_fixed_move(black_box(s)))
}

#[library_benchmark]
#[bench::f32(setup = float)]
fn ramp_maker_f32(s: &'static mut RampMakerF32) -> u32 {
    black_box(ramp_maker_f32_move(black_box(s)))
}

#[library_benchmark]
#[bench::step(setup = klipper)]
fn klipper_step(s: &'static mut KlipperStepper) -> u32 {
    black_box(klipper_step_event(black_box(s)))
}

// The drive's step generation over the whole move (a 1 kHz control loop
// simulated around planner and interrupt): callgrind counts only inside
// `timed_fill` (planner) or `timed_advance` (step interrupt side).
#[library_benchmark(
    config = LibraryBenchmarkConfig::default()
        .tool(Callgrind::default().entry_point(EntryPoint::Custom("*timed_fill*".into())))
)]
#[bench::planner()]
fn drive_move_planner() -> MoveCost {
    black_box(simulate_move(i64::from(RAMP_MOVE_STEPS), || 0))
}

#[library_benchmark(
    config = LibraryBenchmarkConfig::default()
        .tool(Callgrind::default().entry_point(EntryPoint::Custom("*timed_advance*".into())))
)]
#[bench::isr()]
fn drive_move_isr() -> MoveCost {
    black_box(simulate_move(i64::from(RAMP_MOVE_STEPS), || 0))
}

// The baseline: an empty call with the workloads' signature.
#[library_benchmark]
#[bench::call(setup = klipper)]
fn empty_call(s: &'static mut KlipperStepper) -> u32 {
    black_box(empty(black_box(s)))
}

library_benchmark_group!(name = baseline, benchmarks = [empty_call]);
library_benchmark_group!(
    name = slave_path,
    benchmarks = [slave_drive, slave_rmodbus, assembler, assembler_feed_only]
);
library_benchmark_group!(
    name = steps,
    benchmarks = [
        ramp_maker_fixed,
        ramp_maker_f32,
        klipper_step,
        drive_move_planner,
        drive_move_isr
    ]
);
main!(library_benchmark_groups = baseline, slave_path, steps);
