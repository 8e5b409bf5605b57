//! Host checks of the firmware's HAL-free parts (issue 6): the arithmetic in
//! `src/firmware/calc.rs` and the parameter flash region in
//! `src/firmware/flash.rs`, both included by path — the rest of
//! `src/firmware/` only builds for the boards.

#[path = "../src/firmware/calc.rs"]
#[allow(dead_code)]
mod calc;
#[path = "../src/firmware/feed.rs"]
mod feed;
#[path = "../src/firmware/flash.rs"]
#[allow(dead_code)]
mod flash;
#[path = "../src/firmware/trim.rs"]
mod trim;

use calc::*;
use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use feed::fill_half;
use flash::{FlashRegion, RegionError};
use modbus_drive::motion::burst::{Burst, BurstWriter, PulseShape};
use modbus_drive::motion::schedule::brake_rate;
use modbus_drive::motion::{Segment, StepSchedule, StepSource};
use modbus_drive::rtu::{CharFormat, LineConfig};
use std::sync::atomic::{AtomicU32, Ordering};
use trim::cut_runs;

const G431_TICK_HZ: u32 = 170_000_000;
const F103_TICK_HZ: u32 = 72_000_000;

fn line(baud: u32, format: CharFormat) -> LineConfig {
    LineConfig::new(baud, format)
}

// ---------------------------------------------------------------- serial line

#[test]
fn receiver_timeout_is_t35_in_bit_times_spec_1() {
    assert_eq!(t35_rto_bits(line(9600, CharFormat::N1)), 35); // 3.5 × 10 bits
    assert_eq!(t35_rto_bits(line(19_200, CharFormat::E1)), 39); // 3.5 × 11 = 38.5
    assert_eq!(t35_rto_bits(line(115_200, CharFormat::N1)), 202); // 1750 µs = 201.6 bits
    assert_eq!(t35_rto_bits(line(38_400, CharFormat::N2)), 68); // 1750 µs = 67.2 bits
                                                                // never shorter than the core's t3.5, and at most one bit longer
    for baud in [9600, 19_200, 38_400, 57_600, 115_200] {
        for format in [
            CharFormat::N1,
            CharFormat::E1,
            CharFormat::O1,
            CharFormat::N2,
        ] {
            let l = line(baud, format);
            let rto_ns = u64::from(t35_rto_bits(l)) * 1_000_000_000 / u64::from(baud);
            let t35_ns = u64::from(l.timing().t35_us()) * 1000;
            let bit_ns = 1_000_000_000 / u64::from(baud);
            assert!(rto_ns + 1000 >= t35_ns, "{l:?}: {rto_ns} ns < t3.5");
            assert!(rto_ns <= t35_ns + bit_ns, "{l:?}: {rto_ns} ns too long");
        }
    }
}

#[test]
fn reply_waits_out_the_delay_from_the_last_byte_even_across_a_wrap_spec_1() {
    assert_eq!(reply_wait_us(1000, 1000, 1750), 1750);
    assert_eq!(reply_wait_us(2000, 1000, 1750), 750);
    assert_eq!(reply_wait_us(5000, 1000, 1750), 0);
    assert_eq!(reply_wait_us(100, u32::MAX - 99, 1750), 1550); // 200 µs across the wrap
}

// ---------------------------------------------------------------- step output

#[test]
fn step_shape_keeps_the_pulse_asked_for_and_never_goes_below_the_dir_set_up_minimum() {
    for hz in [G431_TICK_HZ, F103_TICK_HZ] {
        let safe = StepShape::safe(hz);
        let ns = |ticks: u32| u64::from(ticks) * 1_000_000_000 / u64::from(hz);
        assert!(ns(safe.pulse_ticks) >= 2500, "pulse ≥ 2.5 µs at {hz} Hz");
        assert!(
            ns(safe.dir_setup_ticks) >= 5000,
            "DIR set-up ≥ 5 µs at {hz} Hz"
        );
        // the pulse as the core reads PA15 (Params::step_pulse_ns), to the
        // tick above; PA16 below its minimum gives the minimum
        let short = StepShape::from_params(500, 20, hz);
        assert!((500..500 + 1_000_000_000 / u64::from(hz)).contains(&ns(short.pulse_ticks)));
        assert_eq!(short.dir_setup_ticks, safe.dir_setup_ticks);
        let wide = StepShape::from_params(10_000, 200, hz); // 10 µs, 20 µs
        assert_eq!(ns(wide.pulse_ticks), 10_000);
        assert_eq!(ns(wide.dir_setup_ticks), 20_000);
        assert_eq!(
            StepShape::from_params(100_000, u16::MAX, hz),
            StepShape::from_params(100_000, 1000, hz),
            "DIR set-up capped at 100 µs"
        );
    }
    assert_eq!(StepShape::safe(G431_TICK_HZ).pulse_ticks, 425);
    assert_eq!(StepShape::safe(F103_TICK_HZ).pulse_ticks, 180);
}

#[test]
fn the_step_timer_tick_is_a_whole_division_of_the_timer_clock() {
    // both boards step at TIM1's own clock: prescaler 0
    assert_eq!(step_prescaler(170_000_000, G431_TICK_HZ), Some(0));
    assert_eq!(step_prescaler(72_000_000, F103_TICK_HZ), Some(0));
    assert_eq!(step_prescaler(170_000_000, 10_000_000), Some(16));
    assert_eq!(
        step_prescaler(72_000_000, 10_000_000),
        None,
        "7.2: not whole"
    );
    assert_eq!(
        step_prescaler(1_000_000, 10_000_000),
        None,
        "faster than the clock"
    );
    assert_eq!(step_prescaler(170_000_000, 1000), None, "PSC is 16 bits");
    assert_eq!(step_prescaler(65_536_000, 1000), Some(u16::MAX));
    assert_eq!(step_prescaler(170_000_000, 0), None);
}

/// Entries in one half of the step engine's DMA buffer (steps.rs `HALF`).
const HALF: usize = 8;

/// The step engine's refill (steps.rs `refill`) on the host: the core's
/// `StepSource` through `BurstWriter` into one buffer half, the ledger kept
/// as the firmware keeps it (its `EngineFeed`, or with `reference` the
/// plain closure feed, which has no plain steps); and TIM1 played from the
/// entries: per pulse, (ticks since the previous pulse, DIR high).
struct Engine {
    writer: BurstWriter,
    source: StepSource,
    ledger: StepLedger,
    reference: bool,
    /// PA11, and as the refill before applied it.
    inverted: bool,
    inverted_before: bool,
    /// Ticks since the last pulse's rise.
    since: u64,
    pulses: Vec<(u64, bool)>,
    entries: Vec<Burst>,
}

impl Engine {
    fn new(hz: u32) -> Self {
        let shape = StepShape::safe(hz);
        Self {
            writer: BurstWriter::new(
                PulseShape::new(shape.pulse_ticks, shape.dir_setup_ticks, shape.idle_ticks),
                true,
            ),
            source: StepSource::new(),
            ledger: StepLedger::new(),
            reference: false,
            inverted: false,
            inverted_before: false,
            since: 0,
            pulses: Vec::new(),
            entries: Vec::new(),
        }
    }

    /// One refill of a half, then the timer through it.
    fn refill(&mut self, sched: &StepSchedule) {
        let mut half = [Burst::ZERO; HALF];
        let Self {
            writer,
            source,
            ledger,
            inverted,
            ..
        } = self;
        if self.reference {
            let inverted = *inverted;
            writer.fill(&mut half, &mut || {
                let step = source.advance(sched);
                ledger.advanced(step.map(|n| n.forward()));
                step.map(|n| (n.delay_ticks(), n.forward() != inverted))
            });
        } else {
            fill_half(
                writer,
                &mut half,
                source,
                sched,
                ledger,
                *inverted,
                self.inverted_before,
            );
        }
        self.inverted_before = self.inverted;
        self.entries.extend_from_slice(&half);
        for b in half {
            let [arr, rcr, ccr1, _] = b.registers();
            for _ in 0..=rcr {
                if ccr1 > 0 {
                    self.pulses.push((self.since, b.dir_high()));
                    self.since = 0;
                }
                self.since += u64::from(arr) + 1;
            }
        }
    }

    /// Refills until the schedule is done and the writer has nothing left.
    fn run(&mut self, sched: &StepSchedule, max_refills: usize) {
        for _ in 0..max_refills {
            self.refill(sched);
            if !sched.is_running() && sched.is_empty() && !self.writer.busy() {
                break;
            }
        }
    }

    /// The pin's position after the first `made` pulses.
    fn pin_after(&self, made: usize) -> i32 {
        self.pulses[..made]
            .iter()
            .map(|&(_, f)| if f { 1 } else { -1 })
            .sum()
    }
}

const ONE: u64 = 1 << 32;

fn segment(interval_ticks: u64, count: u32, forward: bool) -> Segment {
    Segment::new(interval_ticks * ONE, 0, 0, 0, 0, count, forward)
}

#[test]
fn the_core_schedule_reaches_the_step_pin_edge_to_edge() {
    // 400 steps at 5 kHz forward, 3 slow ones backward (longer than one
    // 16-bit period), then 50 at 1 M steps/s, at the G431's 170 MHz
    let sched = StepSchedule::new();
    sched.push(segment(34_000, 400, true)).unwrap();
    sched.push(segment(3_400_000, 3, false)).unwrap();
    sched.push(segment(170, 50, true)).unwrap();
    let mut e = Engine::new(G431_TICK_HZ);
    e.run(&sched, 10_000);
    let out = &e.pulses;
    assert_eq!(out.len(), 453);
    assert!(out[1..400].iter().all(|&(gap, f)| gap == 34_000 && f));
    assert!(out[400..403].iter().all(|&(gap, f)| gap == 3_400_000 && !f));
    assert!(out[404..].iter().all(|&(gap, f)| gap == 170 && f));
    assert_eq!(sched.position(), 400 - 3 + 50);
    assert_eq!(e.pin_after(453), sched.position());
}

#[test]
fn the_pin_position_is_the_schedules_less_the_steps_not_made() {
    // runs in both directions, each refill checked at every pulse count the
    // DMA can be at: up to two halves (and the preload) behind the writer,
    // each entry a run of up to the idle entry's periods
    let sched = StepSchedule::new();
    let mut e = Engine::new(F103_TICK_HZ);
    let mut checked = 0;
    for (i, (count, forward)) in [(40, true), (7, false), (1, true), (300, false), (2, true)]
        .into_iter()
        .enumerate()
    {
        sched
            .push(segment(720 + 100 * i as u64, count, forward))
            .unwrap();
        for _ in 0..1000 {
            e.refill(&sched);
            let written = e.pulses.len();
            let behind = (2 * HALF + 2) * (F103_TICK_HZ as usize / 20_000 / 720);
            for made in written.saturating_sub(behind)..=written {
                assert_eq!(
                    e.ledger.pin_position(sched.position(), made as u16),
                    e.pin_after(made),
                    "{made} of {written} pulses made"
                );
                checked += 1;
            }
            if !sched.is_running() && sched.is_empty() && !e.writer.busy() {
                break;
            }
        }
    }
    assert_eq!(e.pulses.len(), 350);
    assert_eq!(sched.position(), 40 - 7 + 1 - 300 + 2);
    assert!(checked > 500, "{checked}");
}

#[test]
fn the_ledger_round_trips_its_hand_over_and_wraps_with_the_counter() {
    let mut l = StepLedger::new();
    for _ in 0..70_000 {
        l.advanced(Some(false));
    }
    l.advanced(Some(true));
    l.advanced(Some(true));
    let words = core::array::from_fn(|k| match k {
        0 => l.head_word(),
        k => l.start_word(k - 1),
    });
    assert_eq!(StepLedger::from_words(&words), l);
    assert_eq!(
        StepLedger::from_words(&[0; LEDGER_WORDS]),
        StepLedger::new()
    );
    // 70 002 given, the last pending: 70 001 counted; 69 990 made, all but
    // one of the backward ones
    let made = (69_990u32 % 65_536) as u16;
    assert_eq!(l.pin_position(0, made), -(-10) - 1);
    l.advanced(None);
    assert_eq!(l.pin_position(0, made), 10 - 2);
}

#[test]
fn a_limit_brakes_at_the_next_refill_within_the_quick_stop_distance_spec_8_7() {
    // 100 000 steps/s at 72 MHz (F103), quick stop 2e6 steps/s²: 2500 steps
    let sched = StepSchedule::new();
    sched.set_brake_rate(Some(brake_rate(20_000_000, F103_TICK_HZ)));
    sched.push(segment(720, sched.free() as u32, true)).unwrap();
    let mut e = Engine::new(F103_TICK_HZ);
    for _ in 0..20 {
        e.refill(&sched);
    }
    let before = e.pulses.len();
    assert!(e.pulses.iter().skip(1).all(|&(gap, _)| gap == 720));
    sched.set_limits(false, true); // the EXTI handler: CCW limit active
    e.run(&sched, 100_000);
    // the steps already written still go out, then the brake
    let braking = (e.pulses.len() - before) as f64;
    assert!((2490.0..=2502.0).contains(&braking), "{braking} steps");
    let after = &e.pulses[before..];
    // never faster (to the tick the delays are rounded to), ending slow
    assert!(after[1..].windows(2).all(|w| w[1].0 + 1 >= w[0].0));
    assert!(
        after.last().is_some_and(|&(gap, _)| gap > 7200),
        "{after:?}"
    );
    assert!(sched.limit_brake().is_some_and(|b| b.done() && b.forward()));
}

/// One engine per feed over its own schedule, driven alike: segments
/// pushed as room allows, PA11 as `inverted` gives it per refill, a limit
/// from refill `limit_at` on. Each engine's ledger is checked after every
/// refill (while PA11 stays 0): with every pulse written made, it gives
/// the pin's position.
/// Returns the pulses (gap, DIR) and the final position.
fn run_both_feeds(
    segs: &[(u64, u32, bool)],
    inverted: &[bool],
    limit_at: Option<usize>,
) -> [(Vec<(u64, bool)>, i32); 2] {
    [false, true].map(|reference| {
        let sched = StepSchedule::new();
        sched.set_brake_rate(Some(brake_rate(20_000_000, F103_TICK_HZ)));
        let mut e = Engine::new(F103_TICK_HZ);
        e.reference = reference;
        let mut next = 0;
        for i in 0..4000 {
            if next == segs.len() && !sched.is_running() && sched.is_empty() && !e.writer.busy() {
                break;
            }
            while next < segs.len() {
                let (interval, count, forward) = segs[next];
                if sched.push(segment(interval, count, forward)).is_err() {
                    break;
                }
                next += 1;
            }
            e.inverted = inverted[i % inverted.len()];
            if limit_at == Some(i) {
                sched.set_limits(true, true);
            }
            e.refill(&sched);
            // (the pulses' DIR is the direction while PA11 stays 0)
            if !inverted.contains(&true) {
                let made = e.pulses.len();
                assert_eq!(
                    e.ledger.pin_position(sched.position(), made as u16),
                    e.pin_after(made),
                    "refill {i}, reference {reference}"
                );
            }
        }
        (e.pulses, sched.position())
    })
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig { cases: 64, ..Default::default() })]

    /// The refill's plain path (`EngineFeed`: `StepSource::advance_plain`,
    /// its runs and the brake's steps) makes every pulse, at every gap and
    /// DIR, and the position the general path makes: short, long and late
    /// steps, reversals; with PA11 changing between refills, as many
    /// pulses and the same position; with the limit brake, a ledger that
    /// gives the pin's position after every refill.
    #[test]
    fn the_plain_path_makes_the_pulses_the_general_path_makes(
        segs in proptest::collection::vec((1u64..20_000, 1u32..300, proptest::bool::ANY), 1..8),
        inverted in proptest::collection::vec(proptest::bool::weighted(0.1), 1..50),
        limit_at in proptest::option::of(0usize..300),
    ) {
        let [plain, general] = run_both_feeds(&segs, &inverted, limit_at);
        match (limit_at.is_some(), inverted.contains(&true)) {
            (false, false) => proptest::prop_assert_eq!(plain, general),
            // PA11 applies from the next step, and a refill with runs has
            // written more of them: the levels flip at other steps
            (false, true) => {
                proptest::prop_assert_eq!(plain.0.len(), general.0.len());
                proptest::prop_assert_eq!(plain.1, general.1);
            }
            // the brake starts from the step the refill has reached, which
            // runs move on: each engine's ledger is what is checked
            (true, _) => {}
        }
    }
}

// ------------------------------------------------- a limit's brake from the pin

/// The step engine with its DMA (steps.rs): a circular buffer of two
/// halves, each written again by the refill once the DMA has read it, and
/// the DMA reading one entry per update event, the timer making its
/// periods' pulses.
struct DmaEngine {
    e: Engine,
    buffer: [Burst; 2 * HALF],
    /// The first entry the DMA has not started.
    unread: usize,
    newest: usize,
    /// Pulses made (direction of each).
    made: Vec<bool>,
}

impl DmaEngine {
    fn new(sched: &StepSchedule) -> Self {
        let mut d = Self {
            e: Engine::new(F103_TICK_HZ),
            buffer: [Burst::ZERO; 2 * HALF],
            unread: 0,
            newest: 2 * HALF - 1,
            made: Vec::new(),
        };
        d.refill(sched, 0);
        d.refill(sched, HALF);
        d
    }

    /// The engine `entries` entries into a cruise at `interval_ticks`
    /// on `sched`, whose brake is armed at 2e6 steps/s² at `tick_hz`.
    fn cruising(sched: &StepSchedule, tick_hz: u32, interval_ticks: u64, entries: usize) -> Self {
        sched.set_brake_rate(Some(brake_rate(20_000_000, tick_hz)));
        sched
            .push(segment(interval_ticks, sched.free() as u32, true))
            .unwrap();
        let mut d = Self::new(sched);
        for _ in 0..entries {
            d.step(sched);
        }
        d
    }

    fn refill(&mut self, sched: &StepSchedule, at: usize) {
        let Engine {
            writer,
            source,
            ledger,
            ..
        } = &mut self.e;
        fill_half(
            writer,
            &mut self.buffer[at..at + HALF],
            source,
            sched,
            ledger,
            false,
            false,
        );
        self.newest = at + HALF - 1;
    }

    /// The DMA starts the next entry and the timer plays it; a half read
    /// is written again.
    fn step(&mut self, sched: &StepSchedule) {
        let b = self.buffer[self.unread];
        for _ in 0..b.periods() {
            if b.pulse_ticks() != 0 {
                self.made.push(b.dir_high());
            }
        }
        self.unread = (self.unread + 1) % (2 * HALF);
        if self.unread.is_multiple_of(HALF) {
            let read = (self.unread + HALF) % (2 * HALF);
            self.refill(sched, read);
        }
    }

    /// Entries played until the schedule and the writer are at rest and
    /// the DMA at a half's start (at most `max`), the ledger giving the
    /// pin's position after each.
    fn play_to_rest_checking_the_pin(&mut self, sched: &StepSchedule, max: usize) {
        let mut entries = 0;
        while sched.is_running()
            || !sched.is_empty()
            || self.e.writer.busy()
            || !self.unread.is_multiple_of(HALF)
        {
            self.step(sched);
            let made = self.made.len() as u16;
            assert_eq!(
                self.e.ledger.pin_position(sched.position(), made),
                self.pin(),
                "entry {entries}, {} made",
                self.made.len()
            );
            entries += 1;
            assert!(entries < max);
        }
    }

    fn pin(&self) -> i32 {
        self.made.iter().map(|&f| if f { 1 } else { -1 }).sum()
    }

    /// What steps.rs does at a limit's edge.
    fn brake_from_the_pin(
        &mut self,
        sched: &StepSchedule,
        mut unread: impl FnMut() -> usize,
    ) -> u32 {
        if !self.e.source.limit_ahead(sched) {
            return 0;
        }
        let cut = cut_runs(
            &mut self.buffer,
            self.newest,
            self.e.writer.level(),
            &mut unread,
        );
        self.e.source.take_back(sched, cut);
        self.e.ledger.taken_back(cut as u16);
        self.e.source.prepare_brake(sched);
        cut
    }
}

#[test]
fn a_limit_cuts_the_runs_ahead_of_the_timer_and_brakes_from_the_pin_spec_8_7() {
    // 100 000 steps/s at 72 MHz, quick stop 2e6 steps/s² (2500 steps)
    for edge_at in [40usize, 41, 47, 53] {
        let sched = StepSchedule::new();
        let mut d = DmaEngine::cruising(&sched, F103_TICK_HZ, 720, edge_at);
        assert!(d.buffer.iter().any(|b| b.periods() > 1), "a cruise in runs");
        let before = d.made.len();
        assert!(sched.set_limits(false, true));
        let unread = d.unread;
        let cut = d.brake_from_the_pin(&sched, || unread);
        assert!(cut > 0);
        // the two entries next to the DMA and the newest keep their runs,
        // the rest one period each
        let span = (d.newest + 2 * HALF - unread) % (2 * HALF);
        let kept: u32 = [0, 1, span]
            .map(|i| d.buffer[(unread + i) % (2 * HALF)].periods())
            .iter()
            .sum();
        let rest = (2..span).filter(|i| d.buffer[(unread + i) % (2 * HALF)].periods() > 1);
        assert_eq!(rest.count(), 0, "{:?}", d.buffer);
        assert!(
            d.buffer[d.newest].periods() > 1,
            "the newest keeps its run: {:?}",
            d.buffer
        );
        // the pin and the schedule agree at every pulse from here on
        d.play_to_rest_checking_the_pin(&sched, 100_000);
        // and the entries still in the buffer
        for _ in 0..2 * HALF {
            d.step(&sched);
        }
        assert_eq!(sched.position(), d.pin());
        // the brake starts within the entries left ahead: the kept runs
        // and one step an entry, not a run an entry
        let after = d.made.len() - before;
        let ahead = kept as usize + 2 * HALF - 3;
        assert!(
            (2490..=2500 + ahead).contains(&after),
            "{after} steps, {ahead} ahead"
        );
        assert!(sched.limit_brake().is_some_and(|b| b.done() && b.forward()));
    }
}

#[test]
fn no_run_is_cut_while_the_motion_leaves_the_limit() {
    let sched = StepSchedule::new();
    let mut d = DmaEngine::cruising(&sched, F103_TICK_HZ, 720, 40);
    let buffer = d.buffer;
    assert!(sched.set_limits(true, false)); // CW: blocks backward only
    let unread = d.unread;
    assert_eq!(d.brake_from_the_pin(&sched, || unread), 0);
    assert_eq!(d.buffer, buffer);
}

#[test]
fn a_run_is_cut_only_two_entries_or_more_ahead_of_the_dma() {
    // the DMA moves on 0, 1 or 2 entries at each look while the runs are cut
    for moves in [0usize, 1, 2] {
        let sched2 = StepSchedule::new();
        let mut d = DmaEngine::cruising(&sched2, F103_TICK_HZ, 720, 40);
        let before = d.buffer;
        let first = d.unread;
        let span = (d.newest + 2 * HALF - first) % (2 * HALF);
        sched2.set_limits(false, true);
        let mut looks = Vec::new();
        // (never a round of the buffer: at most to the newest entry)
        let cut = d.brake_from_the_pin(&sched2, || {
            let moved = (moves * looks.len()).min(span);
            looks.push(moved);
            (first + moved) % (2 * HALF)
        });
        // look k (after the first) decides the k-th run of the candidates
        // (the newest keeps its run)
        let mut expect = 0;
        let mut k = 1;
        for i in 2..span {
            let b = before[(first + i) % (2 * HALF)];
            if b.periods() == 1 {
                continue;
            }
            let was_cut = d.buffer[(first + i) % (2 * HALF)] != b;
            assert_eq!(was_cut, i >= looks[k] + 2, "offset {i}, moves {moves}");
            expect += u32::from(was_cut) * (b.periods() - 1);
            k += 1;
        }
        assert_eq!(cut, expect);
        assert!(moves > 0 || cut > 0);
    }
}

// ---------------------------------------------------------------- switches

#[test]
fn debounce_needs_three_equal_samples() {
    let mut d = Debounce::new(false);
    assert_eq!(d.sample(true), None);
    assert_eq!(d.sample(false), None); // bounce: starts over
    assert_eq!(d.sample(true), None);
    assert_eq!(d.sample(true), None);
    assert_eq!(d.sample(true), Some(true));
    assert!(d.state());
    assert_eq!(d.sample(true), None);
}

/// SPEC §8.6 origin at the edge: the switch interrupt latches the step
/// count at the first reading away from the stable state; the control loop
/// hands it over with the debounced change, three samples later.
#[test]
fn latched_switch_hands_over_the_first_edge_with_the_change() {
    let mut s = LatchedSwitch::new(false);
    s.edge(false, 5); // no change: nothing latched
    s.edge(true, 100); // first contact (EXTI)
    s.edge(false, 101); // bounce
    s.edge(true, 103); // contact again: the first edge is kept
    assert_eq!(s.sample(true), None);
    assert_eq!(s.sample(true), None);
    s.edge(true, 140);
    assert_eq!(s.sample(true), Some(Some(100)));
    assert!(s.state());
    // spent: the next change latches anew (release)
    assert_eq!(s.sample(true), None);
    s.edge(false, 300);
    for _ in 0..2 {
        assert_eq!(s.sample(false), None);
    }
    assert_eq!(s.sample(false), Some(Some(300)));
    assert!(!s.state());
}

/// A glitch the debounce filters out is forgotten at the first sample that
/// reads the stable state, so it is never taken for a later change's edge;
/// a change the interrupt missed (e.g. PA13 polarity flipped) has no edge
/// unless the sample's own reading latches it.
#[test]
fn latched_switch_forgets_a_filtered_glitch() {
    let mut s = LatchedSwitch::new(false);
    s.edge(true, 50);
    assert_eq!(s.sample(true), None);
    assert_eq!(s.sample(false), None); // back at the stable state: forgotten
    s.edge(true, 80);
    for _ in 0..2 {
        assert_eq!(s.sample(true), None);
    }
    assert_eq!(s.sample(true), Some(Some(80)));
    let mut s = LatchedSwitch::new(false);
    for _ in 0..2 {
        assert_eq!(s.sample(true), None);
    }
    assert_eq!(s.sample(true), Some(None));
}

#[test]
fn frame_error_logs_are_rate_limited() {
    let mut r = RateLimit::new(1000);
    assert_eq!(r.allow(0), Some(0));
    assert_eq!(r.allow(10), None);
    assert_eq!(r.allow(999), None);
    assert_eq!(r.allow(1000), Some(2));
    assert_eq!(r.allow(u32::MAX), Some(0)); // wraps without a panic
    assert_eq!(r.allow(5), None);
}

// ---------------------------------------------------------------- flash region

/// 8 KiB of RAM pretending to be flash with 2 KiB pages and 8-byte writes
/// (the STM32G4's geometry).
struct RamFlash(Vec<u8>);

#[derive(Debug, PartialEq)]
struct RamFlashError;

impl NorFlashError for RamFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        NorFlashErrorKind::Other
    }
}

impl ErrorType for RamFlash {
    type Error = RamFlashError;
}

impl ReadNorFlash for RamFlash {
    const READ_SIZE: usize = 1;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), RamFlashError> {
        let o = offset as usize;
        bytes.copy_from_slice(self.0.get(o..o + bytes.len()).ok_or(RamFlashError)?);
        Ok(())
    }
    fn capacity(&self) -> usize {
        self.0.len()
    }
}

impl NorFlash for RamFlash {
    const WRITE_SIZE: usize = 8;
    const ERASE_SIZE: usize = 2048;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), RamFlashError> {
        self.0
            .get_mut(from as usize..to as usize)
            .ok_or(RamFlashError)?
            .fill(0xFF);
        Ok(())
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), RamFlashError> {
        let o = offset as usize;
        self.0
            .get_mut(o..o + bytes.len())
            .ok_or(RamFlashError)?
            .copy_from_slice(bytes);
        Ok(())
    }
}

#[test]
fn the_parameter_region_is_the_last_pages_with_offsets_from_zero() {
    let mut region = FlashRegion::new(RamFlash(vec![0; 8192]), 4096, 4096).expect("whole pages");
    assert_eq!(region.capacity(), 4096);
    assert_eq!(region.range(), 4096..8192);
    region.erase(0, 2048).unwrap();
    region.write(8, &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap();
    let mut b = [0; 10];
    region.read(6, &mut b).unwrap();
    assert_eq!(b, [0xFF, 0xFF, 1, 2, 3, 4, 5, 6, 7, 8]);
}

#[test]
fn the_region_refuses_what_is_outside_it() {
    let mut region = FlashRegion::new(RamFlash(vec![0; 8192]), 4096, 4096).unwrap();
    let mut b = [0; 2];
    assert_eq!(region.read(4095, &mut b), Err(RegionError::OutOfBounds));
    assert_eq!(region.write(4096, &[0; 8]), Err(RegionError::OutOfBounds));
    assert_eq!(
        region.write(u32::MAX - 2, &[0; 8]),
        Err(RegionError::OutOfBounds)
    );
    assert_eq!(region.erase(2048, 6144), Err(RegionError::OutOfBounds));
    assert_eq!(region.erase(2048, 0), Err(RegionError::OutOfBounds));
    assert_eq!(
        RegionError::<RamFlashError>::OutOfBounds.kind(),
        NorFlashErrorKind::OutOfBounds
    );
    // construction: whole pages only, inside the flash
    assert!(FlashRegion::new(RamFlash(vec![0; 8192]), 4000, 4096).is_none());
    assert!(FlashRegion::new(RamFlash(vec![0; 8192]), 4096, 1000).is_none());
    assert!(FlashRegion::new(RamFlash(vec![0; 8192]), 6144, 4096).is_none());
    assert!(FlashRegion::new(RamFlash(vec![0; 8192]), 0, 0).is_none());
}

// ---------------------------------------------------------------- RS-485 DE

/// PA57 / PA58 on the G431's hardware DE: one bit time fits DEAT / DEDT
/// (16 samples), as does 0; two bit times do not (32 > 31), so software
/// raises DE earlier by what DEAT lacks (1/16 bit) and times the tail.
#[test]
fn de_lead_and_tail_on_the_g431_hardware_de() {
    use modbus_drive::rtu::DriverEnable;
    let fast = line(115_200, CharFormat::N1);
    let d = DeDrive::new(DriverEnable::new(1, 1), fast, 16);
    assert_eq!((d.deat, d.dedt, d.software), (16, 16, false));
    let d = DeDrive::new(DriverEnable::new(0, 0), fast, 16);
    assert_eq!((d.deat, d.dedt, d.software), (0, 0, false));
    let d = DeDrive::new(DriverEnable::new(1, 1), fast, 8);
    assert_eq!((d.deat, d.dedt, d.software), (8, 8, false));
    // 2 bits at 9600 baud: DEAT 31/16 bit, 1/16 bit (6.5 µs) in software
    let slow = line(9_600, CharFormat::N1);
    let d = DeDrive::new(DriverEnable::new(2, 1), slow, 16);
    assert_eq!(
        (d.deat, d.software, d.lead_us, d.tail_us),
        (31, true, 7, 105)
    );
    // the lead made is never shorter than asked: software + DEAT
    for baud in [9_600, 19_200, 38_400, 57_600, 115_200] {
        for bits in 0..=modbus_drive::rtu::MAX_DE_BITS {
            for spb in [0u32, 8, 16] {
                let l = line(baud, CharFormat::E1);
                let de = DriverEnable::new(bits, bits);
                let d = DeDrive::new(de, l, spb);
                let hw_us = if spb == 0 {
                    0.0
                } else {
                    f64::from(d.deat) / f64::from(spb) * 1e6 / f64::from(baud)
                };
                let want = f64::from(bits) * 1e6 / f64::from(baud);
                let sw = if d.software {
                    f64::from(d.lead_us)
                } else {
                    0.0
                };
                assert!(hw_us + sw >= want - 1e-9, "{baud} {bits} {spb}: {d:?}");
                if !d.software {
                    assert!((hw_us - want).abs() < 1e-9, "{baud} {bits} {spb}: {d:?}");
                    let tail = f64::from(d.dedt) / f64::from(spb) * 1e6 / f64::from(baud);
                    assert!((tail - want).abs() < 1e-9);
                } else {
                    assert!(f64::from(d.tail_us) >= want);
                    // the USART's DE is low before software hands the pin back
                    assert_eq!(d.dedt, 0, "{baud} {bits} {spb}: {d:?}");
                }
                assert!(d.deat as u32 <= MAX_DE_SAMPLES && d.dedt as u32 <= MAX_DE_SAMPLES);
            }
        }
    }
}

/// The F103 has no hardware DE: software lead and tail, the full time.
#[test]
fn de_lead_and_tail_on_the_f103_gpio() {
    use modbus_drive::rtu::DriverEnable;
    let d = DeDrive::new(DriverEnable::default(), line(115_200, CharFormat::N1), 0);
    assert_eq!((d.software, d.lead_us, d.tail_us), (true, 9, 9));
    let d = DeDrive::new(DriverEnable::new(0, 0), line(9_600, CharFormat::N1), 0);
    assert_eq!((d.software, d.lead_us, d.tail_us), (true, 0, 0));
}

/// The chip's out-of-band report of a failed read (the G431's ECC NMI sets
/// it in the firmware): the failed address, taken and cleared by the
/// region's hook. `u32::MAX`: none.
static ECC_REPORT: AtomicU32 = AtomicU32::new(u32::MAX);

fn take_ecc_report() -> Option<u32> {
    let at = ECC_REPORT.swap(u32::MAX, Ordering::Relaxed);
    (at != u32::MAX).then_some(at)
}

/// Offset of the double word of [`EccFlash`] that fails (none: `u32::MAX`).
static ECC_BAD_AT: AtomicU32 = AtomicU32::new(u32::MAX);

/// RAM flash with one double word whose reads raise the ECC report, as the
/// NMI handler would while the read instruction completes with garbage; an
/// erase of its page makes it good again (as on the chip).
struct EccFlash(RamFlash);

impl ErrorType for EccFlash {
    type Error = RamFlashError;
}

impl ReadNorFlash for EccFlash {
    const READ_SIZE: usize = 1;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), RamFlashError> {
        self.0.read(offset, bytes)?;
        let bad = ECC_BAD_AT.load(Ordering::Relaxed);
        let end = offset + bytes.len() as u32;
        if offset < bad.saturating_add(8) && bad < end {
            bytes.fill(0x5A);
            ECC_REPORT.store(bad, Ordering::Relaxed);
        }
        Ok(())
    }
    fn capacity(&self) -> usize {
        self.0.capacity()
    }
}

impl NorFlash for EccFlash {
    const WRITE_SIZE: usize = 8;
    const ERASE_SIZE: usize = 2048;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), RamFlashError> {
        let bad = ECC_BAD_AT.load(Ordering::Relaxed);
        if (from..to).contains(&bad) {
            ECC_BAD_AT.store(u32::MAX, Ordering::Relaxed);
        }
        self.0.erase(from, to)
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), RamFlashError> {
        self.0.write(offset, bytes)
    }
}

#[test]
fn an_ecc_error_in_the_parameter_pages_is_a_read_error_and_its_page_is_repaired() {
    use modbus_drive::params::{BootOutcome, ParamSet, ParamStore, Slot, StorageError};
    // the region is the second half of an 8 KiB flash, like the parameter
    // pages at the end of the chip's
    let region = FlashRegion::new(EccFlash(RamFlash(vec![0xFF; 8192])), 4096, 4096)
        .unwrap()
        .with_read_fault(take_ecc_report);
    let mut store = ParamStore::new(region, 0..4096).unwrap();
    let mut set = ParamSet::defaults();
    set.pa_mut().set_unchecked(11, 1);
    store.save(Slot::Saved, &set).unwrap();
    assert_eq!(store.load(Slot::Saved).unwrap().unwrap().0, set);
    assert_eq!(
        store.flash().erase_faulted_page(),
        Ok(None),
        "nothing failed"
    );

    // a stale report (another read of the chip) fails no read of ours
    ECC_REPORT.store(0x10, Ordering::Relaxed);
    let mut b = [0; 8];
    store.flash().read(0, &mut b).unwrap();

    // a power cut left a double word of a second entry unreadable: the
    // journal skips it and keeps the set before it (SPEC §9)
    let mut newer = set.clone();
    newer.pa_mut().set_unchecked(12, 1500);
    store.save(Slot::Saved, &newer).unwrap();
    ECC_BAD_AT.store(4096 + 8 + 176 + 16, Ordering::Relaxed);
    assert_eq!(
        store.flash().read(8 + 176 + 16, &mut b),
        Err(RegionError::ReadFault),
        "the garbage is not returned as data"
    );
    let boot = store.boot();
    assert_eq!(boot.outcome(), BootOutcome::Loaded { fixed: 0 });
    assert_eq!(*boot.set(), set, "the set before the unreadable entry");
    // the next save goes to the other page (erased first); the unreadable
    // page is erased when the ring comes back to it
    store.save(Slot::Saved, &newer).unwrap();
    assert_eq!(*store.boot().set(), newer);

    // an unreadable page header (a cut while a page was taken into use):
    // the region cannot be read; the firmware erases that page and the
    // page before it is current again, with its sets
    ECC_BAD_AT.store(4096 + 2048, Ordering::Relaxed);
    let boot = store.boot();
    assert!(
        matches!(
            boot.outcome(),
            BootOutcome::Unreadable(StorageError::Flash(_))
        ),
        "{:?}",
        boot.outcome()
    );
    assert_eq!(*boot.set(), ParamSet::defaults());
    assert_eq!(store.flash().erase_faulted_page(), Ok(Some(2048)));
    assert_eq!(store.flash().erase_faulted_page(), Ok(None), "once");
    // (the double at the first page's second entry reads again: the model
    // has one bad double word at a time, so that entry is `newer`)
    let boot = store.boot();
    assert_eq!(boot.outcome(), BootOutcome::Loaded { fixed: 0 });
    assert_eq!(*boot.set(), newer);
    store.save(Slot::Saved, &set).unwrap();
    assert_eq!(*store.boot().set(), set);
}

#[test]
fn only_a_double_ecc_error_in_the_parameter_pages_is_a_read_error() {
    let pages = 0x1_F000..0x2_0000; // the G431's parameter pages
    assert!(ecc_error_is_parameter_read(
        true,
        false,
        0x1_F008,
        pages.clone()
    ));
    assert!(ecc_error_is_parameter_read(
        true,
        false,
        0x1_FFF8,
        pages.clone()
    ));
    // code, constants, the system flash, a corrected error: the fault path
    assert!(!ecc_error_is_parameter_read(
        true,
        false,
        0x1_EFF8,
        pages.clone()
    ));
    assert!(!ecc_error_is_parameter_read(
        true,
        false,
        0x2_0000,
        pages.clone()
    ));
    assert!(!ecc_error_is_parameter_read(
        true,
        true,
        0x1_F008,
        pages.clone()
    ));
    assert!(!ecc_error_is_parameter_read(false, false, 0x1_F008, pages));
}

#[test]
fn the_watchdog_outlasts_every_legitimate_stall_even_with_a_fast_lsi() {
    for lsi in [LSI_G431_HZ, LSI_F103_HZ] {
        let (pr, rl) = iwdg_settings(WATCHDOG_TIMEOUT_US, lsi.0).unwrap();
        let shortest = iwdg_timeout_us(pr, rl, lsi.1);
        assert!(shortest < WATCHDOG_TIMEOUT_US, "a fast LSI shortens it");
        assert!(
            shortest >= 3 * LONGEST_STALL_US,
            "{shortest} µs at {} Hz",
            lsi.1
        );
    }
    // the F103's LSI may run at 1.5 times its nominal 40 kHz: 2/3
    let (pr, rl) = iwdg_settings(600_000, 40_000).unwrap();
    assert_eq!(iwdg_timeout_us(pr, rl, 60_000), 400_000);
}

#[test]
fn the_watchdog_registers_give_at_least_the_timeout_at_the_nominal_lsi() {
    for lsi in [LSI_G431_HZ.0, LSI_F103_HZ.0] {
        let (pr, rl) = iwdg_settings(WATCHDOG_TIMEOUT_US, lsi).unwrap();
        let t = iwdg_timeout_us(pr, rl, lsi);
        assert!(t >= WATCHDOG_TIMEOUT_US, "{t} µs at {lsi} Hz");
        // the finest divider that reaches it: one count of it is < 1 %
        assert!(t - WATCHDOG_TIMEOUT_US <= (4u32 << pr) * 1_000_000 / lsi);
        if pr > 0 {
            assert!(iwdg_timeout_us(pr - 1, 0xFFF, lsi) < WATCHDOG_TIMEOUT_US);
        }
    }
    // 500 ms at 32 kHz: 16 000 counts, divider 4 → 4000 (at most 4096)
    assert_eq!(iwdg_settings(500_000, 32_000), Some((0, 3999)));
    // 500 ms at 40 kHz: 20 000 counts, divider 8 → 2500
    assert_eq!(iwdg_settings(500_000, 40_000), Some((1, 2499)));
    // the edges: one count, the longest, beyond it
    assert_eq!(iwdg_settings(100, 40_000), Some((0, 0)));
    assert_eq!(iwdg_settings(26_214_400, 40_000), Some((6, 0xFFF)));
    assert_eq!(iwdg_settings(26_214_401, 40_000), None);
}

#[test]
fn the_reset_cause_names_the_internal_reset_not_the_pin_it_pulled() {
    use calc::reset_cause::*;
    const PIN_F: u32 = 1 << 26;
    // reset values after a power-up: PORRSTF / BORRSTF with PINRSTF
    assert_eq!(reset_cause_from_csr(0x0C00_0000), POWER_ON);
    assert_eq!(reset_cause_from_csr(PIN_F), PIN);
    assert_eq!(reset_cause_from_csr(1 << 29 | PIN_F), INDEPENDENT_WATCHDOG);
    assert_eq!(reset_cause_from_csr(1 << 28 | PIN_F), SOFTWARE);
    assert_eq!(reset_cause_from_csr(1 << 30 | PIN_F), WINDOW_WATCHDOG);
    assert_eq!(reset_cause_from_csr(1 << 31 | PIN_F), LOW_POWER);
    assert_eq!(reset_cause_from_csr(1 << 25 | PIN_F), OPTION_BYTES);
    // LSION / LSIRDY and the rest of the register are not flags
    assert_eq!(reset_cause_from_csr(0x0000_0003), NONE_FLAGGED);
    assert_eq!(reset_cause_from_csr(1 << 29 | 3), INDEPENDENT_WATCHDOG);
}

#[test]
fn a_supervised_task_gets_the_longest_legitimate_frame_and_more() {
    use modbus_drive::rtu::{MAX_DE_BITS, MAX_FRAME};
    // at the slowest line with the longest character: 9600 baud, 8N2 (12 bits)
    let bit_us = 1_000_000 / 9_600 + 1;
    let t35_us = 35 * 12 * bit_us / 10 + 1;
    let reply_us = MAX_FRAME as u32 * 12 * bit_us;
    let de_us = 2 * u32::from(MAX_DE_BITS) * bit_us;
    let delay_us = 100_000; // PA56's maximum, ms
    let longest = t35_us + delay_us + LONGEST_STALL_US + de_us + reply_us;
    assert!(
        TASK_LIMIT_US >= longest + longest / 2,
        "{TASK_LIMIT_US} µs for {longest} µs"
    );
    // and the watchdog still resets a stuck task within a few seconds
    const { assert!(TASK_LIMIT_US + WATCHDOG_TIMEOUT_US <= 2_000_000) };
}

/// A run longer than the counts' modulus (2^16, the pulse counter's): a
/// limit brake from 1 000 000 steps/s at 170 MHz takes 250 000 steps in
/// one direction, and the ledger still gives the pin's position at every
/// entry, as the counts wrap.
#[test]
fn the_pin_position_holds_through_a_run_longer_than_the_counts_wrap() {
    let sched = StepSchedule::new();
    let mut d = DmaEngine::cruising(&sched, 170_000_000, 170, 40);
    assert!(sched.set_limits(false, true));
    let unread = d.unread;
    d.brake_from_the_pin(&sched, || unread);
    d.play_to_rest_checking_the_pin(&sched, 1_000_000);
    assert!(d.made.len() > 3 << 16, "{}", d.made.len());
}
