//! The writer's entries played on a model of the timer: pulse times, DIR
//! timing, entry lengths.

use super::*;

/// What the timer makes of `entries` from tick 0: each pulse's rise and
/// DIR level, after checking every entry's bounds and that DIR changes
/// only at least `setup` after a pulse's fall and `setup` before the next
/// rise.
fn play(entries: &[Burst], shape: PulseShape) -> Vec<(u64, bool)> {
    let mut t = 0u64;
    let mut pulses: Vec<(u64, bool)> = Vec::new();
    let mut level: Option<bool> = None;
    let mut changed_at: Option<u64> = None;
    for (i, b) in entries.iter().enumerate() {
        let [arr, _, ccr1, _] = b.registers();
        assert!(b.period_ticks() >= MIN_ENTRY_TICKS, "entry {i}: {b:?}");
        assert!(b.periods() <= MAX_PERIODS, "entry {i}: {b:?}");
        assert!(
            b.ticks() <= shape.idle_ticks(),
            "entry {i}: longer than the idle entry"
        );
        if b.pulse_ticks() != 0 {
            assert!(u32::from(ccr1) <= u32::from(arr), "entry {i}: {b:?}");
        }
        if level.is_some_and(|l| l != b.dir_high()) {
            if let Some(&(rise, _)) = pulses.last() {
                let fall = rise + u64::from(shape.width);
                assert!(
                    t >= fall + u64::from(shape.dir_setup),
                    "entry {i}: DIR held too short"
                );
            }
            changed_at = Some(t);
        }
        level = Some(b.dir_high());
        for _ in 0..b.periods() {
            if b.pulse_ticks() != 0 {
                if let Some(c) = changed_at.take() {
                    assert!(
                        t >= c + u64::from(shape.dir_setup),
                        "entry {i}: DIR set-up too short"
                    );
                }
                pulses.push((t, b.dir_high()));
            }
            t += u64::from(b.period_ticks());
        }
    }
    pulses
}

/// Writes `steps` in fills of `chunk` entries (refills of half a DMA
/// buffer), the schedule giving nothing where `dry(k)` (before step k).
fn write(
    shape: PulseShape,
    steps: &[(u32, bool)],
    chunk: usize,
    dry: impl Fn(usize) -> bool,
) -> (Vec<Burst>, BurstWriter) {
    let mut w = BurstWriter::new(shape, steps.first().is_none_or(|s| s.1));
    let mut out = Vec::new();
    let mut k = 0;
    let mut buf = vec![Burst::default(); chunk];
    let mut rounds = 0;
    // each dry point gives nothing once
    let mut dried = usize::MAX;
    while k < steps.len() || w.busy() {
        w.fill(&mut buf, &mut || {
            if k < steps.len() && !(dry(k) && dried != k) {
                k += 1;
                Some(steps[k - 1])
            } else {
                dried = k;
                None
            }
        });
        out.extend_from_slice(&buf);
        rounds += 1;
        assert!(rounds < 1_000_000);
    }
    // and a last fill: the pulse entry of the last step is closed
    w.fill(&mut buf, &mut || None);
    out.extend_from_slice(&buf);
    (out, w)
}

fn shape() -> PulseShape {
    // 2.5 µs, 5 µs, 100 µs at 72 MHz
    PulseShape::new(180, 360, 7200)
}

/// A feed of `steps` with plain steps (in the direction of the step
/// before) and, with `runs`, the runs of equal delays after them.
struct Plain {
    steps: Vec<(u32, bool)>,
    at: usize,
    runs: bool,
    /// Takes whole runs too ([`Plain::whole_runs`]), as many as the
    /// steps ahead hold; counts them.
    whole: bool,
    whole_taken: u32,
}

impl StepFeed for Plain {
    fn next_step(&mut self) -> Option<(u32, bool)> {
        let s = self.steps.get(self.at).copied();
        self.at += usize::from(s.is_some());
        s
    }

    fn plain_step(&mut self) -> Option<u32> {
        let (&(d, l), &(_, before)) = (
            self.steps.get(self.at)?,
            self.steps.get(self.at.checked_sub(1)?)?,
        );
        (l == before).then(|| {
            self.at += 1;
            d
        })
    }

    fn run(&mut self, delay: u32, max: impl FnOnce() -> u32) -> u32 {
        if !self.runs {
            return 0;
        }
        let alike = self.alike_ahead(delay, max() as usize);
        self.at += alike;
        alike as u32
    }
}

impl Plain {
    /// How many of the next steps, `max` at most, are `delay` in the last
    /// step's direction.
    fn alike_ahead(&self, delay: u32, max: usize) -> usize {
        let level = self.steps[self.at - 1].1;
        self.steps[self.at..]
            .iter()
            .take(max)
            .take_while(|&&s| s == (delay, level))
            .count()
    }

    /// [`BurstWriter::fill_runs`]' `take`: whole runs if `whole`, as
    /// many as the steps ahead hold in the last step's direction.
    fn whole_runs(&mut self, delay: u32, per: &mut dyn FnMut() -> u32, entries: u32) -> u32 {
        if !self.whole {
            return 0;
        }
        let per = per();
        let runs = (self.alike_ahead(delay, usize::MAX) as u32 / per).min(entries);
        self.at += (runs * per) as usize;
        self.whole_taken += runs;
        runs
    }
}

/// Writes `steps` through a [`Plain`] feed in fills of `chunk` entries.
fn write_plain(steps: &[(u32, bool)], chunk: usize, runs: bool) -> Vec<Burst> {
    write_feed(steps, chunk, runs, false).0
}

/// [`write_plain`], with whole runs if `whole`; and how many the writer
/// took.
fn write_feed(steps: &[(u32, bool)], chunk: usize, runs: bool, whole: bool) -> (Vec<Burst>, u32) {
    let mut w = BurstWriter::new(shape(), steps.first().is_none_or(|s| s.1));
    let mut feed = Plain {
        steps: steps.to_vec(),
        at: 0,
        runs,
        whole,
        whole_taken: 0,
    };
    let mut out = Vec::new();
    let mut buf = vec![Burst::default(); chunk];
    let fill = |w: &mut BurstWriter, buf: &mut [Burst], feed: &mut Plain| {
        let (n, _) = w.fill_runs(buf, |d, per, entries| feed.whole_runs(d, per, entries));
        w.fill(&mut buf[n..], feed);
    };
    while feed.at < steps.len() || w.busy() {
        fill(&mut w, &mut buf, &mut feed);
        out.extend_from_slice(&buf);
    }
    fill(&mut w, &mut buf, &mut feed);
    out.extend_from_slice(&buf);
    (out, feed.whole_taken)
}

#[test]
fn whole_runs_make_the_entries_runs_make() {
    // cruises at two speeds (one a whole number of runs, one not), a
    // ramp between, a reversal, in fills of several sizes: the entries
    // are the same bit for bit, and most of a cruise's came as copies
    let mut steps = vec![(144u32, true); 25 * 40];
    steps.extend((0..40).map(|k| (144 + 7 * k, true)));
    steps.extend(vec![(500u32, true); 333]);
    steps.extend(vec![(700u32, false); 50]);
    for chunk in [1, 3, 8, 16] {
        let (runs, none) = write_feed(&steps, chunk, true, false);
        let (whole, taken) = write_feed(&steps, chunk, true, true);
        assert_eq!(none, 0);
        assert_eq!(runs, whole, "fills of {chunk}");
        if chunk > 1 {
            assert!(taken > 20, "fills of {chunk}: {taken} whole runs");
        }
    }
}

#[test]
fn a_cruise_in_runs_is_an_entry_a_run() {
    let steps = vec![(144u32, true); 1000]; // 500 000 steps/s at 72 MHz
    let out = write_plain(&steps, 16, true);
    let pulses = play(&out, shape());
    assert_eq!(pulses.len(), 1000);
    for p in pulses.windows(2) {
        assert_eq!(p[1].0 - p[0].0, 144);
    }
    // runs of as many periods as the idle entry holds (50)
    let first = out.iter().position(|b| b.pulse_ticks() != 0).unwrap();
    let last = out.iter().rposition(|b| b.pulse_ticks() != 0).unwrap();
    assert!(last - first <= 1000 / 50 + 1, "{}", last - first);
    assert!(out.iter().all(|b| b.periods() <= 50));
}

#[test]
fn runs_make_the_pulses_single_entries_make() {
    // a cruise, a ramp (no two delays alike), a cruise at another speed,
    // a reversal: the same pulses with the feed's runs as without
    let mut steps = vec![(144u32, true); 300];
    steps.extend((0..40).map(|k| (144 + 7 * k, true)));
    steps.extend(vec![(500u32, true); 100]);
    steps.extend(vec![(700u32, false); 50]);
    let single = write_plain(&steps, 8, false);
    let runs = write_plain(&steps, 8, true);
    assert!(single.iter().all(|b| b.periods() == 1));
    assert!(runs.iter().any(|b| b.periods() > 1));
    let (a, b) = (play(&single, shape()), play(&runs, shape()));
    assert_eq!(a.len(), steps.len());
    // the same gaps between pulses and the same DIR at each
    let gaps = |p: &[(u64, bool)]| {
        p.windows(2)
            .map(|w| (w[1].0 - w[0].0, w[1].1))
            .collect::<Vec<_>>()
    };
    assert_eq!(gaps(&a), gaps(&b));
}

#[test]
fn long_intervals_are_exact_in_entries_no_longer_than_the_idle_one() {
    // from 65 537 ticks (just over one period) to 10 s at 72 MHz
    let delays = [
        65_537u32,
        65_536,
        65_535,
        98_304,
        8_454_143,
        8_454_144,
        720_000_000,
        1_000,
    ];
    let steps: Vec<_> = delays.iter().map(|&d| (d, false)).collect();
    let (out, w) = write(shape(), &steps, 8, |_| false);
    let pulses = play(&out, shape());
    assert_eq!(pulses.len(), delays.len());
    for (k, p) in pulses.windows(2).enumerate() {
        assert_eq!(p[1].0 - p[0].0, u64::from(delays[k + 1]), "step {}", k + 1);
    }
    assert_eq!(w.late(), 0);
    // no entry longer than the idle one (`play` checks each): 10 s is
    // about 10 s / 100 µs of them
    let ticks: u64 = out.iter().map(|b| u64::from(b.ticks())).sum();
    assert!(out.len() as u64 <= ticks / 7200 + 2 * delays.len() as u64 + 8);
}

#[test]
fn a_cruise_that_runs_dry_continues_on_time() {
    // the schedule gives nothing before every 7th step: the pulse entry
    // is closed with the last interval, which is the next one's
    let steps = vec![(300u32, true); 200];
    let (out, w) = write(shape(), &steps, 4, |k| k % 7 == 0);
    let pulses = play(&out, shape());
    assert_eq!(pulses.len(), 200);
    for p in pulses.windows(2) {
        assert_eq!(p[1].0 - p[0].0, 300);
    }
    assert_eq!(w.late(), 0);
}

#[test]
fn a_dry_refill_closes_the_pulse_with_the_interval_just_written() {
    // a slow first step, then a cruise: the pulse entry open when the
    // schedule runs dry is closed with the cruise's interval, not the
    // first step's, so the cruise goes on on time
    let mut steps = vec![(5_000u32, true)];
    steps.extend(std::iter::repeat_n((300u32, true), 100));
    let (out, w) = write(shape(), &steps, 4, |k| k == 50);
    let pulses = play(&out, shape());
    assert_eq!(pulses.len(), 101);
    for p in pulses[1..].windows(2) {
        assert_eq!(p[1].0 - p[0].0, 300);
    }
    assert_eq!(w.late(), 0);
}

#[test]
fn a_step_the_schedule_gives_too_late_is_counted() {
    // a ramp up that runs dry: the provisional entry (the last, longer
    // interval) overruns the next, shorter one
    let steps: Vec<_> = (0..50).map(|k| (2000 - 20 * k, true)).collect();
    let (out, w) = write(shape(), &steps, 4, |k| k == 20);
    let pulses = play(&out, shape());
    assert_eq!(pulses.len(), 50);
    assert_eq!(w.late(), 1);
    for (k, p) in pulses.windows(2).enumerate() {
        if k + 1 != 20 {
            assert_eq!(p[1].0 - p[0].0, u64::from(steps[k + 1].0), "step {}", k + 1);
        }
    }
}

#[test]
fn reversals_keep_dir_set_up_and_hold() {
    // back and forth, with short and long gaps at the turns
    let mut steps = Vec::new();
    for (k, gap) in [100u32, 5_000, 70_000, 64].into_iter().enumerate() {
        let level = k % 2 == 0;
        steps.push((gap, level));
        steps.extend(std::iter::repeat_n((400u32, level), 5));
    }
    let (out, _) = write(shape(), &steps, 3, |k| k % 4 == 1);
    let pulses = play(&out, shape()); // checks set-up and hold
    assert_eq!(pulses.len(), steps.len());
    for (p, s) in pulses.iter().zip(&steps) {
        assert_eq!(p.1, s.1, "DIR at the pulse");
    }
}

#[test]
fn idle_entries_while_nothing_is_scheduled() {
    let mut w = BurstWriter::new(shape(), true);
    let mut buf = [Burst::default(); 8];
    // at rest the feed is asked once a fill: nothing can be pushed while
    // a fill runs
    let mut asked = 0;
    for _ in 0..3 {
        assert_eq!(
            w.fill(&mut buf, &mut || {
                asked += 1;
                None
            }),
            0
        );
        for b in buf {
            assert_eq!((b.ticks(), b.pulse_ticks(), b.dir_high()), (7200, 0, true));
        }
    }
    assert_eq!(asked, 3);
    assert!(!w.busy());
    // and a step pushed meanwhile starts the next fill
    let mut steps = [(500u32, true)].into_iter();
    assert_eq!(w.fill(&mut buf, &mut || steps.next()), 1);
    assert_ne!(buf[0].pulse_ticks(), 0);
}

/// Random step streams (delays from the shortest entry to beyond the
/// repetition counter's reach, random directions, random dry refills):
/// every entry within the timer's bounds, DIR set-up and hold kept, one
/// pulse per step, and every pulse exactly its delay after the previous
/// one unless counted late or a reversal had to be stretched.
#[test]
fn random_streams() {
    let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut next = move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    for case in 0..300 {
        let n = 1 + (next() % 200) as usize;
        let mut level = next() & 1 == 0;
        let steps: Vec<(u32, bool)> = (0..n)
            .map(|_| {
                if next() % 16 == 0 {
                    level = !level;
                }
                let d = match next() % 8 {
                    0 => 64 + (next() % 200) as u32,
                    1 => 60_000 + (next() % 20_000) as u32,
                    2 => (next() % 50_000_000) as u32 + 64,
                    _ => 100 + (next() % 3_000) as u32,
                };
                (d, level)
            })
            .collect();
        let chunk = 1 + (next() % 32) as usize;
        let dry_mask = next();
        let shape = PulseShape::new(
            1 + (next() % 200) as u32,
            (next() % 400) as u32,
            64 + (next() % 20_000) as u32,
        );
        let (out, w) = write(shape, &steps, chunk, |k| dry_mask >> (k % 64) & 1 != 0);
        let pulses = play(&out, shape);
        assert_eq!(pulses.len(), n, "case {case}");
        let mut off = 0;
        for (k, p) in pulses.windows(2).enumerate() {
            let (d, lv) = steps[k + 1];
            assert_eq!(p[1].1, lv, "case {case} step {}", k + 1);
            let got = p[1].0 - p[0].0;
            if got != u64::from(d) {
                assert!(got > u64::from(d), "case {case} step {}: early", k + 1);
                off += 1;
            }
        }
        let reversals = steps.windows(2).filter(|s| s[0].1 != s[1].1).count() as u32;
        assert!(
            off <= w.late() + reversals,
            "case {case}: {off} off time, {} late",
            w.late()
        );
    }
}
