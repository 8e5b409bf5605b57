//! The schedule's unit tests: expansion, ring, interrupt side and limit
//! brake together.

use core::sync::atomic::{AtomicU32, Ordering};

use super::brake::*;
use super::segment::*;
use super::*;

const ONE: u64 = 1 << TICK_FRAC_BITS;

fn seg(interval: u64, add: i64, add2: i64, count: u32, forward: bool) -> Segment {
    Segment::new(interval, add, add2, 0, 0, count, forward)
}

/// A xorshift64 stream from `seed`: the tests' reproducible randomness.
fn xorshift(seed: u64) -> impl FnMut() -> u64 {
    let mut x = seed;
    move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    }
}

/// The narrow loop of `Expansion::run` gives the same delays, terms,
/// fraction and delay sum as `Expansion::step` one step at a time, on
/// random segments from tiny to huge terms; it is taken for most
/// (small higher terms) and refused at the edges of its bounds.
#[test]
fn the_narrow_loop_expands_like_step_by_step() {
    let mut next = xorshift(0x2545_F491_4F6C_DD1D);
    let narrow_ring = [const { AtomicU32::new(0) }; SCHEDULE_STEPS];
    let (mut narrow, mut wide) = (0, 0);
    let check = |x: Expansion, steps: usize| {
        let mut a = x;
        let mut b = x;
        // the loop takes NARROW_STEPS at a time: the first pass decides
        let took_narrow = a.narrow(steps.min(NARROW_STEPS));
        a.run(&narrow_ring[..steps]);
        for (k, entry) in narrow_ring[..steps].iter().enumerate() {
            assert_eq!(entry.load(Ordering::Relaxed), b.step(), "step {k}");
        }
        let terms = |e: &Expansion| (e.interval, e.add, e.add2, e.add3, e.add4, e.frac, e.sum);
        assert_eq!(terms(&a), terms(&b));
        took_narrow
    };
    for i in 0..20_000u32 {
        // each term's size drawn on its own, signs at random
        let mut term = |lo: u32, span: u64| {
            let t = next() >> (lo + (next() % span) as u32);
            if next() & 1 == 0 {
                t
            } else {
                t.wrapping_neg()
            }
        };
        let interval = term(1, 1) >> (i % 40);
        let x = Expansion {
            interval,
            add: term(8, 50),
            add2: term(16, 48),
            add3: term(24, 40),
            add4: term(30, 34),
            fine: (term(0, 1) % (u64::from(MAX_FINE_BITS) + 1)) as u32,
            frac: term(0, 1) as u32,
            sum: term(0, 1) as u32,
        };
        let steps = 1 + (term(0, 1) % (SCHEDULE_STEPS as u64 - 1)) as usize;
        if check(x, steps) {
            narrow += 1;
        } else {
            wide += 1;
        }
    }
    assert!(
        narrow > 1_000 && wide > 1_000,
        "narrow {narrow}, wide {wide}"
    );
    // at the edges: add2 reaching i32::MAX exactly after 100 steps
    // (taken), one unit beyond (refused); intervals from exactly 1 tick
    // (taken) and just below (refused)
    let edge = |add2: u64, add3: u64, interval: u64| Expansion {
        interval,
        add: 0,
        add2,
        add3,
        add4: 0,
        fine: 0,
        frac: 0,
        sum: 0,
    };
    let top = (1u64 << 31) - 1 - 100 * 1000;
    assert!(check(edge(top, 1000, 1 << 50), 100));
    assert!(!check(edge(top + 1, 1000, 1 << 50), 100));
    assert!(check(edge(0, 0, ONE), 300));
    assert!(!check(edge(0, 0, ONE - 1), 300));
}

fn drain(src: &mut StepSource, sched: &StepSchedule) -> ([u32; 64], usize) {
    let mut out = [0; 64];
    let mut n = 0;
    while let Some(s) = src.advance(sched) {
        out[n] = s.delay_ticks();
        n += 1;
    }
    (out, n)
}

#[test]
fn steps_counted_equal_schedule_and_intervals_are_exact() {
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    sched.push(seg(10 * ONE, ONE as i64, 0, 3, true)).unwrap();
    sched.push(seg(5 * ONE + ONE / 2, 0, 0, 4, false)).unwrap();
    let (d, n) = drain(&mut src, &sched);
    assert_eq!(n, 7);
    assert_eq!(&d[..3], &[10, 11, 12]);
    // 5.5 ticks each: the fraction is carried, never lost (sum = 22).
    assert_eq!(d[3..7].iter().sum::<u32>(), 22);
    assert!(d[..n].iter().all(|&x| x > 0));
    assert_eq!(sched.position(), 3 - 4);
    assert!(!sched.is_running());
    assert!(sched.is_empty());
}

/// The position is derived (no per-step store): after every call it
/// counts exactly the steps made, across segment ends, reversals, a
/// flush and a stop (steps counted equal the schedule).
#[test]
fn derived_position_counts_the_steps_made() {
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    sched.push(seg(10 * ONE, 0, 0, 3, true)).unwrap();
    sched.push(seg(10 * ONE, 0, 0, 2, false)).unwrap();
    sched.push(seg(10 * ONE, 0, 0, 4, true)).unwrap();
    let mut made = 0i32;
    let mut pending: Option<bool> = None;
    for _ in 0..6 {
        if let Some(fwd) = pending {
            made += if fwd { 1 } else { -1 };
        }
        pending = src.advance(&sched).map(|s| s.forward());
        assert_eq!(sched.position(), made);
    }
    sched.request_flush();
    made += if pending.unwrap() { 1 } else { -1 };
    assert_eq!(src.advance(&sched), None);
    assert_eq!(sched.position(), made);
    assert_eq!(made, 3 - 2 + 1);
    sched.push(seg(10 * ONE, 0, 0, 2, false)).unwrap();
    while src.advance(&sched).is_some() {}
    assert_eq!(sched.position(), made - 2);
}

#[test]
fn second_difference_term() {
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    sched
        .push(seg(10 * ONE, ONE as i64, ONE as i64, 4, true))
        .unwrap();
    let (d, n) = drain(&mut src, &sched);
    // intervals 10, 11, 13, 16
    assert_eq!(&d[..n], &[10, 11, 13, 16]);
}

#[test]
fn negative_add_and_flush() {
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    sched
        .push(seg(100 * ONE, -(ONE as i64), 0, 50, true))
        .unwrap();
    assert_eq!(src.advance(&sched).map(|s| s.delay_ticks()), Some(100));
    assert_eq!(src.advance(&sched).map(|s| s.delay_ticks()), Some(99));
    assert!(sched.is_running());
    sched.request_flush();
    // the step announced before the flush was made: counted, then stop.
    assert_eq!(src.advance(&sched), None);
    assert_eq!(sched.position(), 2);
    assert!(!sched.flush_pending());
    assert!(!sched.is_running());
    assert!(sched.is_empty());
}

/// Steps until the source stops, each checked for its delay and
/// direction.
fn run_out(src: &mut StepSource, sched: &StepSchedule, delay: u32, forward: bool) -> i32 {
    let mut n = 0;
    while let Some(s) = src.advance(sched) {
        assert_eq!((s.delay_ticks(), s.forward()), (delay, forward), "step {n}");
        n += 1;
    }
    n
}

#[test]
fn ring_full_refuses_and_wraps() {
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    let steps = |count: usize, forward: bool| seg(ONE, 0, 0, count as u32, forward);
    let one = steps(1, true);
    assert_eq!(sched.free(), SCHEDULE_STEPS - 3);
    assert!(sched.push(steps(0, true)).is_err());
    // all or nothing: one step more than the room is refused whole
    let big = steps(SCHEDULE_STEPS - 1, true);
    assert_eq!(sched.push(big), Err(big));
    assert!(sched.is_empty());
    // the same direction needs no marker: the whole room, then full
    sched.push(steps(SCHEDULE_STEPS - 2, true)).unwrap();
    assert_eq!((sched.free(), sched.push(one)), (0, Err(one)));
    // the start frees the slot kept while idle, each step made one
    // more; the pending step's slot is never written
    for made in 0..2 {
        assert_eq!(src.advance(&sched).map(|s| s.delay_ticks()), Some(1));
        assert_eq!(sched.position(), made);
        sched.push(one).unwrap();
        assert_eq!((sched.free(), sched.push(one)), (0, Err(one)));
    }
    assert_eq!(
        run_out(&mut src, &sched, 1, true),
        SCHEDULE_STEPS as i32 - 2
    );
    assert_eq!(sched.position(), SCHEDULE_STEPS as i32);
    // round and round the ring (40 × 200..435 entries), each round turning
    // round (one marker), refilled while running
    let mut expect = sched.position();
    let mut forward = true;
    for round in 0..40 {
        forward = !forward;
        let count = 100 + 3 * round;
        sched.push(steps(count, forward)).unwrap();
        assert_eq!(src.advance(&sched).map(|s| s.forward()), Some(forward));
        sched.push(steps(count, forward)).unwrap();
        let made = 1 + run_out(&mut src, &sched, 1, forward);
        assert_eq!(made, 2 * count as i32);
        expect += if forward { made } else { -made };
        assert_eq!(sched.position(), expect);
        assert!(sched.is_empty() && !sched.is_running());
    }
}

/// A run ([`StepSource::advance_run`]) takes the equal delays after a
/// plain step, up to what `max` allows and never past the ring's end
/// (the next plain step goes on from the ring's start): round and round
/// the ring, with the ring topped up meanwhile, every step is taken once
/// and the position counts them; a run stops at the first other delay.
#[test]
fn runs_take_each_equal_step_once_and_stop_at_the_ring_end() {
    const TOTAL: u32 = 6 * SCHEDULE_STEPS as u32;
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    let mut rng = xorshift(0x9E37_79B9_7F4A_7C15);
    sched.push(seg(7 * ONE, 0, 0, 100, true)).unwrap();
    let mut pushed = 100;
    assert_eq!(src.advance(&sched).map(|s| s.delay_ticks()), Some(7));
    let (mut made, mut wraps) = (1, 0);
    while made < TOTAL {
        while pushed < TOTAL && sched.free() >= 64 {
            let n = (TOTAL - pushed).min(64);
            sched.push(seg(7 * ONE, 0, 0, n, true)).unwrap();
            pushed += n;
        }
        assert_eq!(src.advance_plain(&sched), Some(7), "step {made}");
        made += 1;
        let start = sched.next.load(Ordering::Relaxed);
        let ask = (rng() % 300) as u32;
        let taken = src.advance_run(&sched, 7, || ask);
        let at = start as usize % SCHEDULE_STEPS;
        assert!(taken <= ask && at + taken as usize <= SCHEDULE_STEPS);
        if taken < ask && at + (taken as usize) < SCHEDULE_STEPS {
            // stopped early, not at the ring's end: the queue's end
            assert_eq!(made + taken, pushed, "a run stopped at {made}");
        }
        wraps += usize::from(at + taken as usize == SCHEDULE_STEPS);
        made += taken;
        assert_eq!(
            sched.position(),
            made as i32 - 1,
            "the pending step not yet made"
        );
    }
    assert_eq!(made, TOTAL);
    assert!(wraps > 0, "no run reached the ring's end");
    assert!(src.advance(&sched).is_none());
    assert_eq!(sched.position(), TOTAL as i32);
    // an other delay ends a run at once
    sched.push(seg(7 * ONE, 0, 0, 2, true)).unwrap();
    sched.push(seg(9 * ONE, 0, 0, 3, true)).unwrap();
    assert_eq!(src.advance(&sched).map(|s| s.delay_ticks()), Some(7));
    assert_eq!(src.advance_plain(&sched), Some(7));
    assert_eq!(src.advance_run(&sched, 7, || 100), 0);
    assert_eq!(src.advance_plain(&sched), Some(9));
    assert_eq!(src.advance_run(&sched, 9, || 100), 2);
}

/// A constant speed of whole ticks is a run the producer notes as it
/// pushes it: a run takes it without reading it (an entry inside it
/// changed behind the schedule's back is taken as the run's), and
/// growing pushes of the same delay make it longer.
#[test]
fn a_noted_run_is_taken_without_reading_its_entries() {
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    sched.push(seg(7 * ONE, 0, 0, 50, true)).unwrap();
    sched.push(seg(7 * ONE, 0, 0, 50, true)).unwrap();
    assert_eq!(src.advance(&sched).map(|s| s.delay_ticks()), Some(7));
    assert_eq!(src.advance_plain(&sched), Some(7));
    let start = sched.next.load(Ordering::Relaxed);
    sched
        .entry(start.wrapping_add(60))
        .store(8, Ordering::Relaxed);
    assert_eq!(src.advance_run(&sched, 7, || 1000), 98);
    // a delay with a fraction, and a ramp, note nothing: compared
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    for s in [
        seg(7 * ONE + 1, 0, 0, 50, true),
        seg(7 * ONE, 1, 0, 50, true),
    ] {
        sched.push(s).unwrap();
        let (d, n) = drain(&mut src, &sched);
        assert!(d[..n].iter().all(|&d| d == 7), "{:?}", &d[..n]);
    }
    sched.push(seg(7 * ONE + 1, 0, 0, 50, true)).unwrap();
    assert_eq!(src.advance(&sched).map(|s| s.delay_ticks()), Some(7));
    let start = sched.next.load(Ordering::Relaxed);
    sched
        .entry(start.wrapping_add(20))
        .store(8, Ordering::Relaxed);
    assert_eq!(src.advance_run(&sched, 7, || 1000), 20);
}

/// A run noted long ago is forgotten by the first push of other delays
/// once the queue has moved far past it, before its wrapping indices
/// could name new entries: here the indices have come round (set by
/// hand) and the new entries at them are not the old run's.
#[test]
fn a_noted_run_is_forgotten_before_its_indices_come_round() {
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    sched.push(seg(7 * ONE, 0, 0, 50, true)).unwrap();
    drain(&mut src, &sched);
    let start = sched.run_from.load(Ordering::Relaxed);
    sched.entry(start).store(END, Ordering::Relaxed);
    sched.head.store(start, Ordering::Relaxed);
    sched.next.store(start, Ordering::Relaxed);
    sched.push(seg(7 * ONE, 1, 0, 10, true)).unwrap();
    sched.push(seg(9 * ONE, 1, 0, 10, true)).unwrap();
    assert_eq!(src.advance(&sched).map(|s| s.delay_ticks()), Some(7));
    assert_eq!(src.advance_run(&sched, 7, || 100), 9);
}

/// The noted run never outlives its entries: a cut inside it ends it
/// there (the entries after the cut are written again with another
/// delay), a cut before it forgets it, a direction marker starts a new
/// one, and a flush followed by the same delay goes on with it. Random
/// pushes, cuts, flushes and runs, each run's count against the entries
/// compared one by one.
#[test]
fn a_noted_run_ends_where_its_entries_do() {
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    let mut rng = xorshift(0xD1B5_4A32_D192_ED03);
    let (mut runs, mut cut_inside) = (0, 0);
    for round in 0..20_000 {
        let r = rng();
        match r % 8 {
            0..=3 if sched.free() >= 40 => {
                let delay = [5, 7, 7, 7][(r >> 8) as usize % 4] * ONE;
                let add = if (r >> 12).is_multiple_of(4) { 3 } else { 0 };
                let n = 1 + (r >> 16) as u32 % 30;
                sched
                    .push(seg(delay, add, 0, n, !(r >> 24).is_multiple_of(16)))
                    .unwrap();
            }
            4 => {
                // a cut somewhere in the queue ahead of the interrupt
                let next = sched.next.load(Ordering::Relaxed);
                let head = sched.head.load(Ordering::Relaxed);
                let ahead = head.wrapping_sub(next);
                if ahead > 1 {
                    let at = next.wrapping_add(1 + (r >> 8) as u32 % (ahead - 1));
                    let inside = sched.run_ahead(at, sched.run_delay.load(Ordering::Relaxed)) > 0;
                    if sched.truncate(at, HALF_TICK) {
                        cut_inside += usize::from(inside);
                    }
                }
            }
            5 if (r >> 8).is_multiple_of(16) => sched.request_flush(),
            _ => {
                let Some(step) = src.advance(&sched) else {
                    continue;
                };
                let delay = step.delay_ticks();
                let start = sched.next.load(Ordering::Relaxed);
                let i = start as usize % SCHEDULE_STEPS;
                let ask = (r >> 8) as u32 % 200;
                let room = (ask as usize).min(SCHEDULE_STEPS - i);
                let expect = if sched.quiet.load(Ordering::Relaxed) {
                    sched.ring()[i..i + room]
                        .iter()
                        .take_while(|e| e.load(Ordering::Relaxed) == delay)
                        .count()
                } else {
                    0
                };
                assert_eq!(
                    src.advance_run(&sched, delay, || ask) as usize,
                    expect,
                    "round {round}"
                );
                runs += usize::from(expect > 0);
            }
        }
    }
    assert!(
        runs > 1000 && cut_inside > 100,
        "{runs} runs, {cut_inside} cuts inside a run"
    );
}

/// A flush that drops a queued direction marker leaves the interrupt
/// in the last push's direction: the next push (which needs no marker)
/// goes the right way.
#[test]
fn a_dropped_marker_does_not_lose_the_direction() {
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    sched.push(seg(10 * ONE, 0, 0, 3, true)).unwrap();
    sched.push(seg(10 * ONE, 0, 0, 3, false)).unwrap();
    assert!(src.advance(&sched).unwrap().forward());
    sched.request_flush();
    assert_eq!(src.advance(&sched), None);
    assert_eq!(sched.position(), 1);
    sched.push(seg(10 * ONE, 0, 0, 2, false)).unwrap();
    assert_eq!(run_out(&mut src, &sched, 10, false), 2);
    assert_eq!(sched.position(), -1);
}

/// A cut (planner/segment.rs `drop_pending`): the entries from the cut on are
/// taken back, the next push continues there with the fraction carried
/// to the cut, and `advance_until` finds the same steps and time as
/// the push made; a cut behind the interrupt's next read, or outside
/// the queue, changes nothing.
#[test]
fn truncate_takes_back_the_entries_ahead_of_the_interrupt() {
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    // 7.25 ticks growing by a quarter: delays with carried fractions
    let whole = seg(7 * ONE + ONE / 4, (ONE / 4) as i64, 0, 10, true);
    let (mut rest, frac0) = (whole, sched.carry_in());
    let pushed = sched.push_steps(&mut rest, 10, &mut ()).unwrap();
    let first = sched.last_pushed_index().wrapping_sub(9);
    // the time of all ten, found again without the ring
    let (mut again, mut frac) = (whole, frac0);
    assert_eq!(
        again.advance_until(&mut frac, u64::MAX >> 1, 10),
        (10, pushed)
    );
    // the interrupt makes three steps
    let made: Vec<u32> = (0..3)
        .map(|_| src.advance(&sched).unwrap().delay_ticks())
        .collect();
    // behind its next read (the pending step's entry), or at the
    // sentinel, or past it: refused
    assert!(!sched.truncate(first.wrapping_add(1), 0));
    assert!(!sched.truncate(first.wrapping_add(10), 0));
    assert!(!sched.truncate(first.wrapping_add(12), 0));
    // cut after six steps: the time of the sixth is where they end
    let (mut cut, mut frac) = (whole, frac0);
    let until = 6 * 7 * ONE + 15 * (ONE / 4) - 1; // just before the sixth
    let (steps, time) = cut.advance_until(&mut frac, until, 10);
    assert_eq!(steps, 6);
    assert_eq!(cut.count(), 4);
    assert_eq!(cut.interval(), whole.interval() + 6 * (ONE / 4));
    assert!(sched.truncate(first.wrapping_add(6), frac));
    assert_eq!(sched.last_pushed_index(), first.wrapping_add(5));
    // a new push follows the sixth step, carrying its fraction
    sched.push(seg(3 * ONE, 0, 0, 2, true)).unwrap();
    let (d, n) = drain(&mut src, &sched);
    let mut all = made.clone();
    all.extend_from_slice(&d[..n]);
    assert_eq!(all.len(), 6 + 2);
    assert_eq!(
        all[..6].iter().map(|&d| u64::from(d)).sum::<u64>(),
        time >> 32
    );
    assert_eq!(&all[6..], &[3, 3]);
    assert_eq!(sched.position(), 8);
    assert!(sched.is_empty());
}

/// Delays from 2^31 ticks on share their top bit with the markers: they
/// go the slow way and still come out whole; an interval below half a
/// tick is a delay of 1, never the sentinel (0).
#[test]
fn long_and_zero_delays() {
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    sched.push(seg(3_000_000_000 * ONE, 0, 0, 3, true)).unwrap();
    sched.push(seg(ONE / 4, 0, 0, 2, true)).unwrap();
    sched.push(seg(7 * ONE, 0, 0, 1, true)).unwrap();
    let (d, n) = drain(&mut src, &sched);
    let long = 3_000_000_000;
    assert_eq!(&d[..n], &[long, long, long, 1, 1, 7]);
    assert_eq!(sched.position(), 6);
}

/// The fractions a push reports ([`StepSink`]), kept by ring slot.
struct Fracs([u32; SCHEDULE_STEPS]);

impl StepSink for Fracs {
    fn pushed(&mut self, steps: &PushedSteps) {
        for (index, frac) in steps.fractions() {
            self.0[index as usize % SCHEDULE_STEPS] = frac;
        }
    }
}

/// The exact time of each step is its tick plus the rounding its
/// delay carried (the reported fraction less half a tick), within ±½ tick;
/// a direction marker takes no fraction.
#[test]
fn reported_fractions_give_the_exact_times() {
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    let mut fracs = Fracs([0; SCHEDULE_STEPS]);
    // 5.5, then 5.5 + 1/3 per step, ticks; backward: after a marker
    let third = (ONE / 3) as i64;
    let mut rest = seg(ONE * 11 / 2, third, 0, 6, false);
    sched.push_steps(&mut rest, 6, &mut fracs).unwrap();
    let (mut tick, mut exact) = (0u64, 0u64);
    let mut interval = ONE * 11 / 2;
    while let Some(s) = src.advance(&sched) {
        tick += u64::from(s.delay_ticks());
        exact += interval;
        interval += third as u64;
        let frac = fracs.0[sched.step_index() as usize % SCHEDULE_STEPS];
        let r = i64::from(frac) - i64::from(HALF_TICK);
        assert!(r.abs() <= 1 << 31, "{r}");
        assert_eq!((tick << 32).wrapping_add(r as u64), exact);
    }
    assert_eq!(tick, 6 * 11 / 2 + 5); // 33 + 15 × ⅓ = 38
    assert_eq!(sched.position(), -6);
}

#[test]
fn cancel_forgets_the_announced_step() {
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    sched.push(seg(ONE, 0, 0, 5, false)).unwrap();
    src.advance(&sched);
    src.advance(&sched);
    src.cancel(&sched);
    assert_eq!(sched.position(), -1);
    assert_eq!(src.advance(&sched), None);
    assert_eq!(sched.position(), -1);
}

// ---- limit brake (SPEC §8.7) ----

const HZ: u32 = 10_000_000;

/// A long run at `interval` ticks per step in one direction.
fn cruise(sched: &StepSchedule, interval: u64, forward: bool) {
    let count = sched.free() as u32;
    sched
        .push(seg(interval * ONE, 0, 0, count, forward))
        .unwrap();
}

#[test]
fn brake_rate_encodes_the_deceleration() {
    for (decel, hz) in [
        (1u64, 1_000_000u32),
        (20, HZ),
        (10_000_000, HZ),
        (20_000_000, 8_000_000),
    ] {
        let r = brake_rate(decel, hz);
        let (m, s) = (f64::from(r & RATE_MANTISSA), r >> RATE_MANTISSA_BITS);
        let a = m / 2f64.powi(s as i32);
        let exact = decel as f64 / 10.0 / f64::from(hz).powi(2);
        assert!(
            (a / exact - 1.0).abs() < 1.0 / f64::from(1u32 << 22),
            "{decel} {hz}: {a} vs {exact}"
        );
        assert!(m >= f64::from(1u32 << 23));
    }
    assert_eq!(
        brake_rate(0, HZ),
        RATE_AT_ONCE,
        "0x6085 = 0: at once (§8.3)"
    );
}

/// `brake_interval`'s series in full-width arithmetic (the reference its
/// 32-bit products are checked against).
fn brake_interval_wide(p: u64, rate: u32) -> Option<u64> {
    let (m, s) = (
        f64::from(rate & RATE_MANTISSA),
        f64::from(rate >> RATE_MANTISSA_BITS),
    );
    let pt = p as f64 / 2f64.powi(32);
    let q = m / 2f64.powf(s) * pt * pt;
    if p >> 56 != 0 || q >= 0.25 {
        return None;
    }
    let f = q + 1.5 * q * q + 2.5 * q.powi(3) + 4.375 * q.powi(4);
    Some(p + (p as f64 * f) as u64)
}

#[test]
fn the_brake_interval_keeps_the_series_to_its_last_bits() {
    // intervals from 64 ticks to 2^24, rates from the slowest quick stop
    // to the steepest, at the boards' ticks
    let mut next = xorshift(0x2545_F491_4F6C_DD1D);
    let mut compared = 0;
    for _ in 0..200_000 {
        let ticks = 64.0 * 2f64.powf((next() % 18_000) as f64 / 1000.0);
        let p = (ticks * 2f64.powi(32)) as u64;
        let decel = 1 + next() % 200_000_000;
        let hz = [8_000_000, 72_000_000, 170_000_000][(next() % 3) as usize];
        let rate = brake_rate(decel, hz);
        match (brake_interval(p, rate), brake_interval_wide(p, rate)) {
            (Some(a), Some(b)) => {
                // q and its powers are Q0.32 (as in the series' design),
                // each rounded or shifted: a unit of the sum is p / 2^32 of
                // the interval, and q's error (2.5 units, times the
                // series' slope, 2.5 at q = 1/4) with the terms' roundings
                // stays below 24 units
                let err = (a as f64 - b as f64).abs();
                assert!(
                    err <= 24.0 * (p >> 32) as f64 + 16.0,
                    "{p} {rate}: {a} vs {b}"
                );
                compared += 1;
            }
            (None, None) => {}
            (a, b) => {
                // only at q = 1/4 itself may the two disagree
                let (m, s) = (
                    f64::from(rate & RATE_MANTISSA),
                    f64::from(rate >> RATE_MANTISSA_BITS),
                );
                let q = m / 2f64.powf(s) * ticks * ticks;
                assert!(
                    (q - 0.25).abs() < 1e-6,
                    "{p} {rate}: {a:?} vs {b:?} at q = {q}"
                );
            }
        }
    }
    assert!(compared > 50_000, "{compared}");
}

/// Steps of the limit brake from `v0` steps/s with `a` steps/s²: their
/// intervals follow v² = v0² - 2an, and the motor stops within the
/// quick stop distance v0²/2a (SPEC §8.7: stop with 0x6085).
#[test]
fn limit_brake_decelerates_at_the_quick_stop_rate() {
    for (v0, a) in [
        (50_000.0f64, 1.0e6f64),
        (2_000.0, 20_000.0),
        (200_000.0, 2.0e6),
    ] {
        let sched = StepSchedule::new();
        let mut src = StepSource::new();
        sched.set_brake_rate(Some(brake_rate((a * 10.0) as u64, HZ)));
        let p0 = (f64::from(HZ) / v0) as u64;
        cruise(&sched, p0, true);
        for _ in 0..10 {
            assert_eq!(src.advance(&sched).unwrap().delay_ticks() as u64, p0);
        }
        sched.set_limits(false, true); // the CCW limit: forward blocked
        let mut n = 0u32;
        let mut t = 0f64;
        while let Some(s) = src.advance(&sched) {
            assert!(s.forward());
            n += 1;
            t += f64::from(s.delay_ticks());
            let v2 = v0 * v0 - 2.0 * a * f64::from(n);
            let exact = f64::from(HZ) / v2.sqrt();
            let got = f64::from(s.delay_ticks());
            assert!(
                (got - exact).abs() <= 1.0 + 0.02 * exact,
                "v0 {v0}, a {a}: step {n}: {got} ticks, exact {exact}"
            );
            assert_eq!(sched.limit_brake(), Some(LimitBrake::new(true, false)));
            assert!(n < 1_000_000);
        }
        let dist = v0 * v0 / (2.0 * a);
        assert!(
            f64::from(n) <= dist && f64::from(n) + 3.0 >= dist,
            "v0 {v0}, a {a}: {n} braking steps, quick stop distance {dist}"
        );
        // time of a constant deceleration: v0/a (minus the last steps)
        let t_exact = v0 / a * f64::from(HZ);
        assert!(t <= t_exact * 1.01, "{t} ticks vs {t_exact}");
        assert_eq!(sched.limit_brake(), Some(LimitBrake::new(true, true)));
        assert!(!sched.is_running() && sched.is_empty());
        assert_eq!(sched.position(), 10 + n as i32);
    }
}

/// A cruise whose interval is no whole number of ticks (its delays
/// alternate): the brake starts from the exact speed, not from the one
/// rounded delay, so it stops at v0²/2a to within what the delays ahead
/// tell of the speed (their mean of 32, within 1/32 tick), where half a
/// tick at a short interval is a large part of the distance.
#[test]
fn limit_brake_starts_from_the_exact_speed_between_whole_ticks() {
    for (ticks, a) in [(20.5f64, 2.0e6f64), (24.37, 2.0e6), (33.9, 1.0e6)] {
        let sched = StepSchedule::new();
        let mut src = StepSource::new();
        sched.set_brake_rate(Some(brake_rate((a * 10.0) as u64, HZ)));
        let count = sched.free() as u32;
        let interval = (ticks * ONE as f64) as u64;
        sched.push(seg(interval, 0, 0, count, true)).unwrap();
        for _ in 0..100 {
            src.advance(&sched).unwrap();
        }
        sched.set_limits(false, true);
        let mut n = 0u32;
        while src.advance(&sched).is_some() {
            n += 1;
        }
        let v0 = f64::from(HZ) / ticks;
        let dist = v0 * v0 / (2.0 * a);
        // v² off by twice the interval's relative error
        let slack = dist * 2.0 / (32.0 * ticks) + 3.0;
        assert!(
            (f64::from(n) - dist).abs() <= slack,
            "{ticks} ticks a step: {n} braking steps, v0²/2a = {dist} (± {slack})"
        );
    }
}

/// A limit met while accelerating: the delays ahead are those of faster
/// steps, and the brake's start takes their mean only while they keep to
/// two neighbouring ticks (else the one delay), so it stops at the exact
/// speed's v²/2a within what one rounded delay would leave (half a tick),
/// at a slow speed (the delays change by ticks a step) as at a fast one
/// (the window's mean).
#[test]
fn limit_brake_met_while_accelerating_starts_from_the_speed_at_the_edge() {
    // (interval, its change a step, both ticks; deceleration steps/s²)
    for (ticks, add, a) in [
        (500.0f64, -2.0f64, 2.0e6f64),
        (80.3, -0.004, 2.0e6),
        (40.7, -0.0004, 1.0e6),
    ] {
        let sched = StepSchedule::new();
        let mut src = StepSource::new();
        sched.set_brake_rate(Some(brake_rate((a * 10.0) as u64, HZ)));
        let count = sched.free() as u32;
        let (interval, step) = ((ticks * ONE as f64) as u64, (add * ONE as f64) as i64);
        sched.push(seg(interval, step, 0, count, true)).unwrap();
        let made = 100u32;
        for _ in 0..made {
            src.advance(&sched).unwrap();
        }
        sched.set_limits(false, true);
        let mut n = 0u32;
        while src.advance(&sched).is_some() {
            n += 1;
        }
        // the step the brake takes over is the one after those made
        let p = ticks + add * f64::from(made);
        let v = f64::from(HZ) / p;
        let dist = v * v / (2.0 * a);
        let slack = dist * 2.0 * 0.5 / p + 3.0;
        assert!(
            (f64::from(n) - dist).abs() <= slack,
            "{ticks} ticks a step, {add} a step: {n} braking steps, v²/2a = {dist} (± {slack})"
        );
    }
}

/// A brake whose start speed was read ahead (`prepare_brake`, where a
/// step engine learns of the limit) makes the same steps as one that
/// reads it as it starts; one read for a limit released before the brake
/// started is forgotten.
#[test]
fn a_brake_prepared_ahead_makes_the_steps_of_one_read_at_its_start() {
    // the delays of a brake after 50 steps of a ramp; `early`: a limit
    // met, read ahead and released 20 steps before
    let brake = |prepare: bool, early: bool| {
        let sched = StepSchedule::new();
        let mut src = StepSource::new();
        sched.set_brake_rate(Some(brake_rate(20_000_000, HZ)));
        let count = sched.free() as u32;
        let interval = (33.37 * ONE as f64) as u64;
        sched
            .push(seg(interval, -(ONE as i64) / 50, 0, count, true))
            .unwrap();
        for k in 0..50 {
            if early && k == 30 {
                sched.set_limits(false, true);
                src.prepare_brake(&sched);
                sched.set_limits(false, false);
            }
            src.advance(&sched).unwrap();
        }
        sched.set_limits(false, true);
        assert!(src.limit_ahead(&sched));
        if prepare {
            src.prepare_brake(&sched);
        }
        std::iter::from_fn(|| src.advance(&sched).map(|s| s.delay_ticks())).collect::<Vec<_>>()
    };
    let plain = brake(false, false);
    assert_eq!(brake(true, false), plain);
    assert_eq!(brake(false, true), plain);
}

#[test]
fn limit_brake_only_towards_the_active_limit_and_only_when_armed() {
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    cruise(&sched, 2000, false);
    src.advance(&sched);
    // armed, but the CCW limit blocks the other direction
    sched.set_brake_rate(Some(brake_rate(10_000_000, HZ)));
    sched.set_limits(false, true);
    assert_eq!(src.advance(&sched).map(|s| s.delay_ticks()), Some(2000));
    assert_eq!(sched.limit_brake(), None);
    // disarmed (homing, §8.6): the CW limit is passed on to the planner
    sched.set_brake_rate(None);
    sched.set_limits(true, false);
    assert_eq!(src.advance(&sched).map(|s| s.delay_ticks()), Some(2000));
    assert_eq!(sched.limit_brake(), None);
    // armed: brakes (the interval grows)
    sched.set_brake_rate(Some(brake_rate(10_000_000, HZ)));
    assert!(src.advance(&sched).unwrap().delay_ticks() > 2000);
    assert_eq!(sched.limit_brake(), Some(LimitBrake::new(false, false)));
}

#[test]
fn limit_brake_latches_until_released_and_defers_a_flush() {
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    sched.set_brake_rate(Some(brake_rate(10_000_000, HZ)));
    cruise(&sched, 200, true);
    src.advance(&sched);
    sched.set_limits(false, true);
    src.advance(&sched);
    // a flush while braking waits for the end of the brake
    sched.request_flush();
    assert!(src.advance(&sched).is_some());
    while src.advance(&sched).is_some() {}
    assert!(!sched.flush_pending());
    // segments pushed before thread mode noticed are dropped, also
    // away from the limit, until the planner releases the brake
    sched.set_limits(false, false);
    cruise(&sched, 200, false);
    assert_eq!(src.advance(&sched), None);
    assert!(sched.is_empty());
    sched.release_brake();
    assert_eq!(sched.limit_brake(), None);
    cruise(&sched, 200, false);
    assert_eq!(src.advance(&sched).map(|s| s.delay_ticks()), Some(200));
}

#[test]
fn limit_at_once_and_from_rest_make_no_step() {
    let sched = StepSchedule::new();
    let mut src = StepSource::new();
    sched.set_brake_rate(Some(brake_rate(0, HZ)));
    sched.set_limits(true, false);
    cruise(&sched, 200, false);
    assert_eq!(src.advance(&sched), None, "0x6085 = 0: no further step");
    assert_eq!(sched.limit_brake(), Some(LimitBrake::new(false, true)));
    sched.release_brake();
    // from rest towards an active limit, at an ordinary deceleration:
    // the first interval from rest is already within two steps of rest
    sched.set_brake_rate(Some(brake_rate(10_000_000, HZ)));
    sched.push(seg(14_142 * ONE, 0, 0, 10, false)).unwrap(); // √(2/a) s
    assert_eq!(src.advance(&sched), None);
    assert_eq!(sched.position(), 0);
}
