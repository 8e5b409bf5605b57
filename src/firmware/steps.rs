//! Step output by timer and DMA (docs/firmware.md, "Step engine by timer
//! and DMA"): the advanced timer TIM1 makes STEP (CH1N) and DIR (CH2N) in
//! hardware, a DMA channel loads its period, repetition count, pulse width
//! and DIR level at every update event from a circular buffer of timer
//! entries, and TIM3 counts the pulses made from TIM1's OC1REF.
//!
//! The CPU works per refill, not per step: the DMA channel's half-transfer
//! and transfer-complete interrupts hand back the half of the buffer just
//! read, and the refill writes it again from the core's step schedule
//! through `motion::burst::BurstWriter`, in the same core code the host
//! tests run. At constant speed an entry is a run of alike periods that
//! the repetition counter plays, so a refill comes once per several
//! steps. A DMA burst reaches the preload registers, which take effect at
//! the update event after the one that requested it, so an entry is
//! written a buffer half and two periods before it acts.
//!
//! [`SCHEDULE`] is the core's lock-free `StepSchedule`
//! (src/motion/schedule/mod.rs): the control loop fills it through
//! `Device::control`, the refill owns the `StepSource` that empties it, and
//! the limit-switch interrupt writes the active limits into it
//! (`set_limits`), so the next refill brakes with 0x6085 (SPEC §8.7).
//!
//! Pulses made are TIM3's count, never inferred: the STEP pin's position
//! ([`read_at_pin_position`]) is the schedule's position less the steps
//! handed to the timer and not yet made, which the homing latch takes at
//! a switch edge.
//!
//! Shared state, none of it behind a lock (priority.rs: nothing masks the
//! refill): [`SCHEDULE`] lock-free, [`ENGINE`] and [`BUFFER`] owned by the
//! refill interrupt (set up before it is enabled; the DMA reads the buffer
//! half the refill is not writing), the hand-over of PA15/PA16 and PA11 in
//! atomics, and what [`read_at_pin_position`] reads under a sequence count.

use core::sync::atomic::{AtomicBool, AtomicI32, AtomicU32, Ordering};

use embassy_stm32::interrupt::typelevel::{Handler, Interrupt};
use embassy_stm32::pac;
use embassy_stm32::pac::timer::vals::{Mms, Ocm, Ossi, Sms, Ts};
use modbus_drive::motion::burst::{Burst, BurstWriter, PulseShape, MAX_PERIODS};
use modbus_drive::motion::{StepSchedule, StepSource};

use super::board;
use super::calc::{StepLedger, StepShape, LEDGER_WORDS, LONG_RUN};
use super::feed::fill_half;
use super::owned::IrqOwned;
use super::trim::cut_runs;

/// The step schedule between the control loop and the refill. Its `const`
/// initialiser is all zeros, so it lives in .bss and costs no flash image.
static SCHEDULE: StepSchedule = StepSchedule::new();

/// The step schedule.
pub fn schedule() -> &'static StepSchedule {
    &SCHEDULE
}

/// Entries in one half of the DMA buffer: the refill runs once per half,
/// and a step written now acts at most two halves later.
const HALF: usize = 8;
// the ledger tells a long run by its length, which no buffer of pulses
// ahead of the pin reaches
const _: () = assert!(2 * HALF as u32 * MAX_PERIODS < LONG_RUN as u32);
/// Half-words one entry's DMA burst moves (ARR, RCR, CCR1, CCR2).
const BURST_HALF_WORDS: usize = 4;

/// The DMA's circular buffer, read by the DMA channel and written only by
/// the refill (a half after the DMA has read it).
static BUFFER: IrqOwned<[Burst; 2 * HALF]> = IrqOwned::new([Burst::ZERO; 2 * HALF]);

/// PA11: DIR inverted (written by the control loop).
static DIR_INVERTED: AtomicBool = AtomicBool::new(false);
/// STEP width and DIR set-up in ticks, packed (`StepShape::packed`).
static SHAPE: AtomicU32 = AtomicU32::new(0);

/// The refill's `StepLedger` for [`read_at_pin_position`], written under
/// [`SEQ`] (`StepLedger::head_word`, then its `start_word`s)...
static LEDGER: [AtomicU32; LEDGER_WORDS] = [const { AtomicU32::new(0) }; LEDGER_WORDS];
/// ...with the schedule's position it goes with ([`publish`]).
static POSITION: AtomicI32 = AtomicI32::new(0);
/// Odd while the refill writes the values above.
static SEQ: AtomicU32 = AtomicU32::new(0);
/// The limits changed: the refill interrupt, pended, cuts the runs ahead
/// of the timer if the motion runs into one ([`limits_changed`]).
static LIMITS_CHANGED: AtomicBool = AtomicBool::new(false);
/// Refills in a row that wrote no pulse (the buffer holds none once two did).
static QUIET_REFILLS: AtomicU32 = AtomicU32::new(0);
/// Refills that found the DMA already in the half they were to write while
/// the buffer held pulses.
static LATE_REFILLS: AtomicU32 = AtomicU32::new(0);

struct Engine {
    writer: BurstWriter,
    source: StepSource,
    /// Width, set-up and idle entry in timer ticks, as last taken from
    /// [`SHAPE`].
    pulse: StepShape,
    ledger: StepLedger,
    /// PA11 as the last refill applied it.
    inverted: bool,
    /// Index of the last entry written in the buffer.
    newest: usize,
}

/// Owned by the refill interrupt once it is enabled (`start` fills it before).
static ENGINE: IrqOwned<Option<Engine>> = IrqOwned::new(None);

#[inline(always)]
fn pulse_shape(s: StepShape) -> PulseShape {
    PulseShape::new(s.pulse_ticks, s.dir_setup_ticks, s.idle_ticks)
}

/// Sets TIM1 (tick `board::STEP_TICK_HZ`: its clock, `prescaler` is
/// `calc::step_prescaler` of it), TIM3 (the
/// pulse counter) and the DMA channel up, fills the buffer idle and starts
/// them, DIR set for the positive direction under PA11 = `dir_inverted`.
/// STEP and DIR are already in their alternate function (`board::split`).
/// Returns the step schedule for the control loop. Call it before the
/// refill interrupt is enabled.
pub fn start(prescaler: u16, dir_inverted: bool) -> &'static StepSchedule {
    let shape = StepShape::safe(board::STEP_TICK_HZ);
    DIR_INVERTED.store(dir_inverted, Ordering::Relaxed);
    SHAPE.store(shape.packed(), Ordering::Relaxed);
    let level = !dir_inverted; // forward
    let mut engine = Engine {
        writer: BurstWriter::new(pulse_shape(shape), level),
        source: StepSource::new(),
        pulse: shape,
        ledger: StepLedger::new(),
        inverted: dir_inverted,
        newest: 2 * HALF - 1,
    };
    // SAFETY: the DMA channel is off and raises no interrupt until it is
    // enabled below (embassy's init has enabled its NVIC line already;
    // the handler finds no engine until this store): nothing else runs on
    // the buffer or the engine.
    let buffer = unsafe { BUFFER.get() };
    engine.writer.fill(buffer, &mut || None);
    // SAFETY: as above.
    unsafe { *ENGINE.get() = Some(engine) };

    board::enable_step_clocks();
    let t = board::STEP_TIMER;
    // the timers were reset by their drivers (`board::split`): whole
    // registers are written, not modified
    t.cr1().write(|w| w.set_arpe(true));
    t.psc().write_value(prescaler);
    // the first period: idle, DIR at its level, no pulse
    t.arr().write(|w| w.set_arr((shape.idle_ticks - 1) as u16));
    t.rcr().write(|w| w.set_rep(0));
    t.ccr(0).write(|w| w.set_ccr(0));
    t.ccr(1)
        .write(|w| w.set_ccr(if level { u16::MAX } else { 0 }));
    t.ccmr_output(0).write(|w| {
        w.set_ocm(0, Ocm::PWM_MODE1);
        w.set_ocpe(0, true);
        w.set_ocm(1, Ocm::PWM_MODE1);
        w.set_ocpe(1, true);
    });
    // only the complementary outputs: each pin is OCxREF itself
    t.ccer().write(|w| {
        w.set_ccne(0, true);
        w.set_ccne(1, true);
    });
    // OC1REF on TRGO: TIM3 counts its rising edges
    t.cr2().write(|w| w.set_mms(Mms::COMPARE_OC1));
    // a burst of ARR, RCR, CCR1, CCR2 through DMAR at each update
    t.dcr().write(|w| {
        w.set_dba(ARR_WORD);
        w.set_dbl((BURST_HALF_WORDS - 1) as u8);
    });
    t.egr().write(|w| w.set_ug(true)); // the first period's registers now
    t.sr().write_value(Default::default());
    // outputs on; a break (the fault path's BG) drives both to their
    // idle level, low
    t.bdtr().write(|w| {
        w.set_ossi(Ossi::IDLE_LEVEL);
        w.set_moe(true);
    });

    let c = board::PULSE_COUNTER;
    c.smcr().write(|w| {
        w.set_ts(Ts::ITR0); // TIM1's TRGO
        w.set_sms(Sms::EXT_CLOCK_MODE);
    });
    c.cr1().write(|w| w.set_cen(true));

    board::route_step_dma();
    let ch = board::STEP_DMA.ch(board::STEP_DMA_CH);
    ch.cr().write(|w| w.set_en(false));
    ch.par().write_value(t.dmar().as_ptr() as u32);
    ch.mar().write_value(buffer.as_ptr() as u32);
    ch.ndtr()
        .write(|w| w.set_ndt((2 * HALF * BURST_HALF_WORDS) as u16));
    ch.cr().write(|w| {
        use pac::bdma::vals::{Dir, Pl, Size};
        w.set_dir(Dir::FROM_MEMORY);
        w.set_msize(Size::BITS16);
        w.set_psize(Size::BITS16);
        w.set_minc(true);
        w.set_circ(true);
        w.set_pl(Pl::VERY_HIGH);
        w.set_htie(true);
        w.set_tcie(true);
        w.set_en(true);
    });
    t.dier().write(|w| w.set_ude(true));
    t.cr1().modify(|w| w.set_cen(true));
    &SCHEDULE
}

/// STEP and DIR driven low by TIM1 (its outputs' idle level while MOE is
/// off), so that their pins never float when they become its outputs.
/// Call it with TIM1 clocked, before the pins are switched over.
pub fn outputs_low() {
    let t = board::STEP_TIMER;
    t.bdtr().modify(|w| {
        w.set_moe(false);
        w.set_ossi(Ossi::IDLE_LEVEL);
    });
    t.ccer().write(|w| {
        w.set_ccne(0, true);
        w.set_ccne(1, true);
    });
}

/// The fault path: a software break (MOE off: STEP and DIR at once at
/// their idle level, low), then DMA and timer stopped. Register writes
/// only, from any context.
pub fn stop() {
    let t = board::STEP_TIMER;
    t.egr().write(|w| w.set_bg(0, true));
    t.dier().modify(|w| w.set_ude(false));
    board::STEP_DMA
        .ch(board::STEP_DMA_CH)
        .cr()
        .modify(|w| w.set_en(false));
    t.cr1().modify(|w| w.set_cen(false));
}

/// TIMx_DMAR's base address: ARR, in words from CR1 (0x2C on both chips).
const ARR_WORD: u8 = 0x2C / 4;

/// New STEP width / DIR set-up (PA15/PA16); applies from the next step.
pub fn set_shape(shape: StepShape) {
    SHAPE.store(shape.packed(), Ordering::Relaxed);
}

/// PA11 (DIR inverted); applies from the next step.
pub fn set_dir_inverted(inverted: bool) {
    DIR_INVERTED.store(inverted, Ordering::Relaxed);
}

/// Nothing is queued, no step is under way and the DMA buffer holds no
/// pulse: flash work may start (SPEC §9). Only the control loop fills the
/// schedule, and it cannot run while the dispatcher does flash work, so
/// this stays true through it (the refill then writes idle entries only).
pub fn idle() -> bool {
    SCHEDULE.is_empty() && !SCHEDULE.is_running() && QUIET_REFILLS.load(Ordering::Relaxed) >= 2
}

/// Refills that came a half too late since the start (the DMA read
/// entries of the half before they were written again).
pub fn late_refills() -> u32 {
    LATE_REFILLS.load(Ordering::Relaxed)
}

/// TIM3's count: pulses made since the start, modulo 2^16.
fn pulses_made() -> u16 {
    board::PULSE_COUNTER.cnt().read().cnt()
}

/// `read()` (the switch pins) with the STEP pin's position when it ran:
/// the schedule's position less the steps handed to the timer that it has
/// not made yet (TIM3's count), each in its own direction. The count is
/// read before and after `read`; if a pulse went out in between, the pair
/// is taken again (a few times at most, then the count before it stands:
/// the position is then the step before or at the edge). Call it from a
/// context the refill may preempt.
pub fn read_at_pin_position<T>(read: impl FnMut() -> T) -> (T, i32) {
    let (value, _, pin) = snapshot(read);
    (value, pin)
}

/// Tells the schedule how far the STEP pin is behind its position
/// (`StepSchedule::set_pin_lag`), for the control loop before each
/// control call: the drive reports the pin and waits for it to reach the
/// target.
pub fn publish_pin_lag() {
    let ((), pos, pin) = snapshot(|| ());
    SCHEDULE.set_pin_lag(pos.wrapping_sub(pin), pos);
}

/// `read()` with the schedule's position and the STEP pin's, consistent
/// (see [`read_at_pin_position`]). The refill preempts this whenever it
/// runs and changes what the ledger tells only as it ends ([`publish`]):
/// the ledger, the position and the count are taken in a few loads
/// between two reads of [`SEQ`], again if a refill came between them, and
/// `read()` goes before them, outside that window (the count before it
/// tells whether a pulse came in between). A long window would be cut
/// again and again while the engine is busiest, and the switches' reading
/// holds its EXTI line masked while this runs.
fn snapshot<T>(mut read: impl FnMut() -> T) -> (T, i32, i32) {
    let mut tries = 0;
    loop {
        let before = pulses_made();
        let value = read();
        let (pos, words, made) = loop {
            let seq = SEQ.load(Ordering::Relaxed);
            core::sync::atomic::compiler_fence(Ordering::SeqCst);
            let pos = POSITION.load(Ordering::Relaxed);
            let words: [u32; LEDGER_WORDS] =
                core::array::from_fn(|k| LEDGER[k].load(Ordering::Relaxed));
            let made = pulses_made();
            core::sync::atomic::compiler_fence(Ordering::SeqCst);
            if seq & 1 == 0 && SEQ.load(Ordering::Relaxed) == seq {
                break (pos, words, made);
            }
        };
        if made == before || tries >= 3 {
            let pin = StepLedger::from_words(&words).pin_position(pos, made);
            return (value, pos, pin);
        }
        tries += 1;
    }
}

/// The DMA channel's interrupt: a half of the buffer was read (priority
/// `PRIO_STEP`).
pub struct StepHandler;

impl Handler<board::StepIrq> for StepHandler {
    unsafe fn on_interrupt() {
        let dma = board::STEP_DMA;
        let n = board::STEP_DMA_CH;
        let isr = dma.isr().read();
        let (ht, tc) = (isr.htif(n), isr.tcif(n));
        dma.ifcr().write(|w| {
            w.set_htif(n, ht);
            w.set_tcif(n, tc);
            w.set_gif(n, ht || tc);
        });
        // SAFETY: this interrupt is the buffer's and the engine's only user
        // once enabled; the DMA reads the other half meanwhile.
        let (buffer, engine) = unsafe { (BUFFER.get(), ENGINE.get()) };
        let Some(engine) = engine.as_mut() else {
            return;
        };
        // nothing preempts this interrupt: a load and a store are one
        if LIMITS_CHANGED.load(Ordering::Relaxed) {
            LIMITS_CHANGED.store(false, Ordering::Relaxed);
            brake_from_the_pin(engine, buffer);
        }
        // half-transfer: the first half was read; transfer complete: the
        // second. The DMA must be in the other half than the one written.
        let dma_in_first = dma.ch(n).ndtr().read().ndt() as usize > HALF * BURST_HALF_WORDS;
        let (first, second) = buffer.split_at_mut(HALF);
        for (done, half, late, last) in [
            (ht, first, dma_in_first, HALF - 1),
            (tc, second, !dma_in_first, 2 * HALF - 1),
        ] {
            if done {
                engine.newest = last;
                // a buffer with no pulse in it (idle: two quiet refills)
                // loses nothing when a half plays twice, as while a flash
                // erase stalls the core
                if late && QUIET_REFILLS.load(Ordering::Relaxed) < 2 {
                    LATE_REFILLS.store(late_refills().wrapping_add(1), Ordering::Relaxed);
                }
                refill(engine, half);
            }
        }
    }
}

/// The enabled limits changed (the switches' reading): if the motion
/// runs into one, the refill interrupt cuts the runs the timer has not
/// reached, so that the brake the next refill starts comes a step per
/// entry later, not a run per entry.
pub fn limits_changed() {
    LIMITS_CHANGED.store(true, Ordering::Relaxed);
    board::StepIrq::pend();
}

/// Entries of the buffer the DMA has not started: the first one's index.
fn unread() -> usize {
    let left = board::STEP_DMA.ch(board::STEP_DMA_CH).ndtr().read().ndt() as usize;
    let started = (2 * HALF * BURST_HALF_WORDS - left).div_ceil(BURST_HALF_WORDS);
    started % (2 * HALF)
}

/// Cuts the runs ahead of the timer (`trim::cut_runs`) when the pending
/// step runs into an active limit, and takes their steps back from the
/// schedule and the ledger, published as the refill publishes them; then
/// reads the brake's start speed (`StepSource::prepare_brake`), here and
/// not in the refill that starts the brake.
#[inline(never)]
fn brake_from_the_pin(e: &mut Engine, buffer: &mut [Burst; 2 * HALF]) {
    if !e.source.limit_ahead(&SCHEDULE) {
        return;
    }
    let cut = cut_runs(buffer, e.newest, e.writer.level(), unread);
    if cut != 0 {
        e.source.take_back(&SCHEDULE, cut);
        e.ledger.taken_back(cut as u16);
        publish(&e.ledger, false);
    }
    e.source.prepare_brake(&SCHEDULE);
}

/// The ledger (its start words too if `starts`) and the schedule's
/// position, with [`SEQ`] odd while they are written: what [`snapshot`]
/// reads. The refill's last stores, after the buffer is written: no pulse
/// of the entries just written can be made before them, since the DMA
/// reads the other half meanwhile.
#[inline(always)]
fn publish(ledger: &StepLedger, starts: bool) {
    let seq = SEQ.load(Ordering::Relaxed);
    SEQ.store(seq.wrapping_add(1), Ordering::Relaxed);
    core::sync::atomic::compiler_fence(Ordering::SeqCst);
    POSITION.store(SCHEDULE.position(), Ordering::Relaxed);
    LEDGER[0].store(ledger.head_word(), Ordering::Relaxed);
    if starts {
        for (k, word) in LEDGER[1..].iter().enumerate() {
            word.store(ledger.start_word(k), Ordering::Relaxed);
        }
    }
    core::sync::atomic::compiler_fence(Ordering::SeqCst);
    SEQ.store(seq.wrapping_add(2), Ordering::Relaxed);
}

/// Writes `half` from the schedule. One copy for both halves.
#[inline(never)]
fn refill(e: &mut Engine, half: &mut [Burst]) {
    let inverted = DIR_INVERTED.load(Ordering::Relaxed);
    let shape = SHAPE.load(Ordering::Relaxed);
    if shape != e.pulse.packed() {
        e.pulse = e.pulse.with_packed(shape);
        e.writer.set_shape(pulse_shape(e.pulse));
    }
    let Engine {
        writer,
        source,
        ledger,
        inverted: inverted_before,
        ..
    } = e;
    let runs = ledger.newest_run();
    let pulses = fill_half(
        writer,
        half,
        source,
        &SCHEDULE,
        ledger,
        inverted,
        *inverted_before,
    );
    *inverted_before = inverted;
    publish(ledger, ledger.newest_run() != runs);
    let quiet = if pulses == 0 && !writer.busy() {
        QUIET_REFILLS.load(Ordering::Relaxed).saturating_add(1)
    } else {
        0
    };
    QUIET_REFILLS.store(quiet, Ordering::Relaxed);
}
