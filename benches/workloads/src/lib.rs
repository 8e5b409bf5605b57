//! The calls the benchmarks measure, on the same inputs for the drive core
//! and for the libraries a user would pick instead.
//!
//! Every workload is an `#[inline(never)]` function taking `&mut` state and
//! returning a value that depends on the work done, so that the runner can
//! call it through a black-boxed function pointer, subtract the cost of an
//! empty call with the same signature, and check the result.
//!
//! Both runners use this crate: `../qemu` (Cortex-M4 instructions under QEMU)
//! and `../host` (x86-64 instructions under valgrind).
#![no_std]

use modbus_drive::motion::{
    Fill, Goal, NextStep, Planner, PlannerConfig, Ramp, StepSchedule, StepSource,
};
use modbus_drive::rtu::{FrameAssembler, LineConfig, RxEvent, RxFlags};

/// The four request frames of the slave-path comparison, CRC included.
pub mod frames {
    /// FC03, read 2 registers: 0x607A target position (seed 000 §6 example).
    pub const READ_2: &[u8] = &[0x01, 0x03, 0x60, 0x7A, 0x00, 0x02, 0xFB, 0xD2];
    /// FC03, read 10 registers from 0x6081 (profile velocity … homing method).
    pub const READ_10: &[u8] = &[0x01, 0x03, 0x60, 0x81, 0x00, 0x0A, 0x8B, 0xE5];
    /// FC10, write 9 registers: seed 000's first worked frame (SPEC §5).
    pub const WRITE_9: &[u8] = &[
        0x01, 0x10, 0x60, 0x40, 0x00, 0x09, 0x12, 0x00, 0x0F, 0x00, 0x01, 0x00, 0x00, 0x00, 0x64,
        0x00, 0x64, 0x00, 0x64, 0x00, 0x64, 0x00, 0x03, 0x0D, 0x40, 0x40, 0x1C,
    ];
    /// FC06, write 0x6083 acceleration = 100 (seed 000 §6 example).
    pub const WRITE_1: &[u8] = &[0x01, 0x06, 0x60, 0x83, 0x00, 0x64, 0x67, 0xC9];

    /// (name, request, length of the normal reply) for every compared frame.
    pub const ALL: [(&str, &[u8], usize); 4] = [
        ("FC03 read 2 regs", READ_2, 5 + 2 * 2),
        ("FC03 read 10 regs", READ_10, 5 + 2 * 10),
        ("FC10 write 9 regs", WRITE_9, 8),
        ("FC06 write 1 reg", WRITE_1, 8),
    ];
}

/// An empty call with the workloads' signature: the baseline subtracted
/// from every measurement.
#[inline(never)]
pub fn empty<S>(_state: &mut S) -> u32 {
    0
}

// ---------------------------------------------------------------- CRC

/// 8 bytes to checksum (the FC03 request without its CRC, plus two bytes).
pub struct CrcInput(pub [u8; 8]);

impl Default for CrcInput {
    fn default() -> Self {
        Self([0x01, 0x03, 0x60, 0x7A, 0x00, 0x02, 0x12, 0x34])
    }
}

/// The drive's CRC (`modbus_drive::rtu::crc16`, table-driven `crc` crate).
#[inline(never)]
pub fn crc_ours_8(input: &mut CrcInput) -> u32 {
    modbus_drive::rtu::crc16(core::hint::black_box(&input.0)).into()
}

const CRC_CRATE: crc::Crc<u16> = crc::Crc::<u16>::new(&crc::CRC_16_MODBUS);

/// The `crc` crate used directly, through its digest API so that it is a
/// code path of its own. (When LLVM keeps one out-of-line `checksum` shared
/// by several callers instead of inlining it with the algorithm's constants
/// folded in, a call costs ~22 instructions more: 106 for 8 bytes.)
#[inline(never)]
pub fn crc_crate_8(input: &mut CrcInput) -> u32 {
    let mut digest = CRC_CRATE.digest();
    digest.update(core::hint::black_box(&input.0));
    digest.finalize().into()
}

// ---------------------------------------------------------------- frame assembler

/// The frame assembler at 115200 8N1, bytes back to back.
///
/// The receive interrupt makes one call per byte; so does this feed, through
/// black-boxed function pointers. [`AssemblerFeed::harness_only`] runs the
/// same loop with empty calls: the difference, divided by the frame length,
/// is the assembler's own cost per received byte (its call included).
pub struct AssemblerFeed {
    assembler: FrameAssembler,
    now_us: u32,
    tc_us: u32,
    t35_us: u32,
    /// The frame fed by [`assembler_frame`].
    pub frame: &'static [u8],
    push: fn(&mut FrameAssembler, u8, u32) -> u32,
    poll: fn(&mut FrameAssembler, u32) -> u32,
}

impl AssemblerFeed {
    pub fn new(frame: &'static [u8]) -> Self {
        Self::with(frame, assembler_push, assembler_poll)
    }

    /// The feed loop alone: every call is an empty one.
    pub fn harness_only(frame: &'static [u8]) -> Self {
        Self::with(frame, empty_push, empty_poll)
    }

    fn with(
        frame: &'static [u8],
        push: fn(&mut FrameAssembler, u8, u32) -> u32,
        poll: fn(&mut FrameAssembler, u32) -> u32,
    ) -> Self {
        let timing = LineConfig::DEFAULT.timing();
        Self {
            assembler: FrameAssembler::new(timing),
            now_us: 0,
            tc_us: timing.tc_us(),
            t35_us: timing.t35_us(),
            frame,
            push,
            poll,
        }
    }
}

/// What the UART receive interrupt does with one byte.
#[inline(never)]
pub fn assembler_push(a: &mut FrameAssembler, byte: u8, at_us: u32) -> u32 {
    // a byte never closes the previous frame here: `poll` did
    a.push(byte, at_us, RxFlags::NONE).is_some().into()
}

/// What the t3.5 timer does: close the frame; returns its length.
#[inline(never)]
pub fn assembler_poll(a: &mut FrameAssembler, now_us: u32) -> u32 {
    match a.poll(now_us) {
        Some(RxEvent::Frame { bytes, .. }) => bytes.len() as u32,
        _ => 0,
    }
}

#[inline(never)]
fn empty_push(_: &mut FrameAssembler, _: u8, _: u32) -> u32 {
    0
}

#[inline(never)]
fn empty_poll(_: &mut FrameAssembler, _: u32) -> u32 {
    0
}

/// Every byte of one frame through `push`, then the `poll` that closes it
/// after t3.5. Returns what `poll` returned (the frame length).
#[inline(never)]
pub fn assembler_frame(s: &mut AssemblerFeed) -> u32 {
    let frame = core::hint::black_box(s.frame);
    let push = core::hint::black_box(s.push);
    let poll = core::hint::black_box(s.poll);
    let mut t = s.now_us;
    for &b in frame {
        t = t.wrapping_add(s.tc_us);
        push(&mut s.assembler, b, t);
    }
    let len = poll(&mut s.assembler, t.wrapping_add(s.t35_us));
    s.now_us = t.wrapping_add(s.t35_us + s.tc_us);
    len
}

// ---------------------------------------------------------------- the drive's slave path

/// The whole slave path of one drive: `Device::handle_rx` on a closed frame
/// (CRC check, address, dispatch, dictionary, reply with CRC).
pub struct DriveSlave {
    device: modbus_drive::Device,
    reply: [u8; modbus_drive::rtu::MAX_FRAME],
    /// The request [`drive_slave_frame`] processes.
    pub request: &'static [u8],
}

impl DriveSlave {
    pub fn new(request: &'static [u8]) -> Self {
        Self {
            device: modbus_drive::Device::new(modbus_drive::device::Identity::new("bench")),
            reply: [0; modbus_drive::rtu::MAX_FRAME],
            request,
        }
    }

    /// The reply buffer (its first bytes are the last reply).
    pub fn reply(&self) -> &[u8] {
        &self.reply
    }
}

/// One request through the drive. Returns the reply length (0: silent).
#[inline(never)]
pub fn drive_slave_frame(s: &mut DriveSlave) -> u32 {
    let bytes = core::hint::black_box(s.request);
    let rx = RxEvent::Frame {
        bytes,
        parity_error: false,
    };
    match s.device.handle_rx(rx, &mut s.reply) {
        modbus_drive::device::Response::Reply(n) => n as u32,
        modbus_drive::device::Response::Silent => 0,
    }
}

// ---------------------------------------------------------------- rmodbus

/// Holding registers up to 0x6100 so that the drive's indices exist.
pub const RMODBUS_HOLDINGS: usize = 0x6100;

/// rmodbus 0.13 as a no_std RTU server over its array `ModbusStorage`.
pub struct RmodbusSlave {
    storage: rmodbus::server::storage::ModbusStorage<0, 0, 0, RMODBUS_HOLDINGS>,
    response: heapless::Vec<u8, 256>,
    /// The request [`rmodbus_frame`] processes.
    pub request: &'static [u8],
}

impl RmodbusSlave {
    pub const fn new(request: &'static [u8]) -> Self {
        Self {
            storage: rmodbus::server::storage::ModbusStorage::new(),
            response: heapless::Vec::new(),
            request,
        }
    }

    pub fn response(&self) -> &[u8] {
        &self.response
    }
}

/// One request through rmodbus the way its README does it: parse (CRC
/// check), process, finalize (CRC). Returns the reply length.
#[inline(never)]
pub fn rmodbus_frame(s: &mut RmodbusSlave) -> u32 {
    use rmodbus::{server::ModbusFrame, ModbusProto};
    let request = core::hint::black_box(s.request);
    let mut frame = ModbusFrame::new(1, request, ModbusProto::Rtu, &mut s.response);
    if frame.parse().is_err() {
        return 0;
    }
    if frame.processing_required {
        let done = if frame.readonly {
            frame.process_read(&s.storage)
        } else {
            frame.process_write(&mut s.storage)
        };
        if done.is_err() {
            return 0;
        }
    }
    if frame.response_required && frame.finalize_response().is_err() {
        return 0;
    }
    s.response.len() as u32
}

// ---------------------------------------------------------------- step generation

/// Steps of the move the ramp workloads generate.
pub const RAMP_MOVE_STEPS: u32 = 2000;
/// Its limits: 20 000 steps/s² up to 10 000 steps/s (ramps of 2500 steps
/// would not fit, so it is a triangle of 1000 + 1000 steps).
pub const RAMP_ACCEL_STEPS_PER_S2: u32 = 20_000;
pub const RAMP_MAX_STEPS_PER_S: u32 = 10_000;

/// ramp-maker 0.2's trapezoidal ramp with its default fixed-point number
/// type (`FixedU64<U32>`), time in seconds.
pub struct RampMakerFixed {
    profile: ramp_maker::Trapezoidal,
}

impl Default for RampMakerFixed {
    fn default() -> Self {
        Self {
            profile: ramp_maker::Trapezoidal::new(ramp_maker::trapezoidal::DefaultNum::from_num(
                RAMP_ACCEL_STEPS_PER_S2,
            )),
        }
    }
}

/// One whole move of [`RAMP_MOVE_STEPS`]: the per-step cost is the result
/// divided by that. Returns the number of delays produced.
#[inline(never)]
pub fn ramp_maker_fixed_move(s: &mut RampMakerFixed) -> u32 {
    use ramp_maker::MotionProfile;
    let max = ramp_maker::trapezoidal::DefaultNum::from_num(RAMP_MAX_STEPS_PER_S);
    s.profile
        .enter_position_mode(core::hint::black_box(max), RAMP_MOVE_STEPS);
    let mut n = 0;
    while let Some(delay) = s.profile.next_delay() {
        core::hint::black_box(delay);
        n += 1;
    }
    n
}

/// The same ramp with `f32` (needs an FPU to be cheap).
pub struct RampMakerF32 {
    profile: ramp_maker::Trapezoidal<f32>,
}

impl Default for RampMakerF32 {
    fn default() -> Self {
        Self {
            profile: ramp_maker::Trapezoidal::new(RAMP_ACCEL_STEPS_PER_S2 as f32),
        }
    }
}

#[inline(never)]
pub fn ramp_maker_f32_move(s: &mut RampMakerF32) -> u32 {
    use ramp_maker::MotionProfile;
    s.profile.enter_position_mode(
        core::hint::black_box(RAMP_MAX_STEPS_PER_S as f32),
        RAMP_MOVE_STEPS,
    );
    let mut n = 0;
    while let Some(delay) = s.profile.next_delay() {
        core::hint::black_box(delay);
        n += 1;
    }
    n
}

/// Stands in for a GPIO output data register.
pub static STEP_PORT_ODR: core::sync::atomic::AtomicU32 = core::sync::atomic::AtomicU32::new(0);

/// Klipper's step timer event (`stepper_event` in klipper/src/stepper.c):
/// the reference for a step interrupt's work — toggle the step pin, count
/// down, advance the wake time by `interval`, then `interval += add`.
pub struct KlipperStepper {
    pub waketime: u32,
    pub interval: u32,
    pub add: i32,
    pub count: u32,
    /// Step pin mask in [`STEP_PORT_ODR`].
    pub step_pin: u32,
}

impl Default for KlipperStepper {
    fn default() -> Self {
        Self {
            waketime: 0,
            interval: 1000,
            add: 1,
            count: u32::MAX,
            step_pin: 1 << 5,
        }
    }
}

/// One step event. Returns the next wake time (0 when the move ended).
#[inline(never)]
pub fn klipper_step_event(s: &mut KlipperStepper) -> u32 {
    use core::sync::atomic::Ordering::Relaxed;
    // gpio_out_toggle_noirq: ODR ^= bit (plain load and store)
    STEP_PORT_ODR.store(STEP_PORT_ODR.load(Relaxed) ^ s.step_pin, Relaxed);
    let count = s.count.wrapping_sub(1);
    if count != 0 {
        s.count = count;
        s.waketime = s.waketime.wrapping_add(s.interval);
        s.interval = s.interval.wrapping_add(s.add as u32);
        return s.waketime;
    }
    // stepper_load_next: the benchmark keeps the move endless
    s.count = u32::MAX;
    0
}

// ---------------------------------------------------------------- the drive's step generation

/// The comparison move in the planner's units (0.1 steps/s, 0.1 steps/s²):
/// the same 2000-step triangle as the ramp-maker workloads.
pub const MOVE_RAMP: Ramp = Ramp::new(
    RAMP_MAX_STEPS_PER_S as u64 * 10,
    RAMP_ACCEL_STEPS_PER_S2 as u64 * 10,
    RAMP_ACCEL_STEPS_PER_S2 as u64 * 10,
);

/// The seed's move (`seed_move_precision_margins`, docs/drive.md "Planner and
/// precision"): 200 000 steps at 50 000 steps/s, 100 000 steps/s² — a
/// faster move, on which the planner's per-call and per-segment costs
/// spread over more steps. Reported for information, without a target.
pub const SEED_MOVE_STEPS: u32 = 200_000;
pub const SEED_RAMP: Ramp = Ramp::new(500_000, 1_000_000, 1_000_000);

/// Control-loop period of the simulated glue (the firmware's 1 kHz loop).
pub const CONTROL_PERIOD_US: u64 = 1000;

/// What one simulated move cost, in clock units summed over the timed
/// calls (see [`simulate_move`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MoveCost {
    /// Steps the interrupt side produced.
    pub steps: u32,
    /// Position the interrupt side ended at.
    pub final_position: i32,
    pub fill_calls: u32,
    pub fill_clock: u32,
    pub advance_calls: u32,
    pub advance_clock: u32,
}

/// The planner's work for one control period (out of line so that the
/// host bench can count it alone and the M4 bench can time it).
#[inline(never)]
pub fn timed_fill(p: &mut Planner, now_us: u64, sched: &StepSchedule) -> Fill {
    p.fill(now_us, sched)
}

/// What the step-timer interrupt does at each step.
#[inline(never)]
pub fn timed_advance(src: &mut StepSource, sched: &StepSchedule) -> Option<NextStep> {
    src.advance(sched)
}

/// `n` timed regions around `f` with `clock` read as [`simulate_move`]
/// does: the clock's own cost per region when `f` does nothing.
pub fn time_regions(clock: fn() -> u32, f: fn() -> u32, n: u32) -> u32 {
    let f = core::hint::black_box(f);
    let mut total = 0u32;
    for i in 0..n {
        let t0 = clock();
        f();
        total = total.wrapping_add(t0.wrapping_sub(clock()) & 0x00FF_FFFF);
        dither(i);
    }
    total
}

/// Untimed work of varying length between two timed regions, so that the
/// regions start at every phase of a clock tick and the quantisation of
/// each reading averages out (a fixed loop length can visit only a few
/// phases and bias the sum by up to a tick per region).
#[inline(never)]
pub fn dither(i: u32) {
    for k in 0..(i.wrapping_mul(7) % 41) {
        core::hint::black_box(k);
    }
}

/// The glue around planner and interrupt, simulated: every
/// [`CONTROL_PERIOD_US`] the planner fills the schedule, and the interrupt
/// runs every step that falls into the period, on a 10 MHz step timer.
/// The step tick of every workload here: 10 MHz, the rhythm the bench's
/// figures have been taken in since the first (the firmware's step timer
/// now counts at the timer clock; the instructions per step do not depend
/// on it).
pub const BENCH_TICK_HZ: u32 = 10_000_000;

/// The drive's planner configuration at [`BENCH_TICK_HZ`].
pub fn bench_config() -> PlannerConfig {
    PlannerConfig::default().with_tick_hz(BENCH_TICK_HZ)
}

/// `clock` is read around every `timed_fill` / `timed_advance` call (a
/// down-counter: the M4 bench passes SysTick; the host bench, which counts
/// the two functions with callgrind instead, passes a constant).
pub fn simulate_move(target: i64, clock: fn() -> u32) -> MoveCost {
    simulate_move_with(target, MOVE_RAMP, clock)
}

/// [`simulate_move`] with other limits.
pub fn simulate_move_with(target: i64, ramp: Ramp, clock: fn() -> u32) -> MoveCost {
    let cfg = bench_config();
    let ticks_per_us = u64::from(cfg.tick_hz() / 1_000_000);
    let mut planner = Planner::new(cfg);
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    let mut cost = MoveCost::default();
    planner.set_goal(Goal::Move {
        target,
        ramp,
        end_velocity: 0,
    });
    let mut now_us: u64 = 0;
    // step timer time (ticks) of the interrupt's next call, when armed
    let mut next_at: Option<u64> = None;
    for _ in 0..100_000 {
        let t0 = clock();
        let fill = timed_fill(&mut planner, now_us, &sched);
        cost.fill_clock = cost
            .fill_clock
            .wrapping_add(t0.wrapping_sub(clock()) & 0x00FF_FFFF);
        cost.fill_calls += 1;
        dither(cost.fill_calls);
        let period_end = (now_us + CONTROL_PERIOD_US) * ticks_per_us;
        if next_at.is_none() && !sched.is_empty() {
            next_at = Some(now_us * ticks_per_us); // the glue pends the interrupt
        }
        while let Some(at) = next_at.filter(|&at| at < period_end) {
            let t0 = clock();
            let step = timed_advance(&mut src, &sched);
            cost.advance_clock = cost
                .advance_clock
                .wrapping_add(t0.wrapping_sub(clock()) & 0x00FF_FFFF);
            cost.advance_calls += 1;
            dither(cost.advance_calls);
            next_at = step.map(|s| at + u64::from(s.delay_ticks()));
        }
        now_us += CONTROL_PERIOD_US;
        if matches!(fill, Fill::Idle) && next_at.is_none() && sched.is_empty() {
            break;
        }
    }
    cost.final_position = sched.position();
    cost.steps = sched.position().unsigned_abs();
    cost
}

pub mod dma_refill;
pub mod per_step;
