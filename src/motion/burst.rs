//! The step engine's timer entries: what one DMA burst writes into the
//! step timer's preload registers at each update event (docs/firmware.md,
//! "Step engine by timer and DMA"), made from the schedule's per-step
//! delays by [`BurstWriter`].
//!
//! An entry ([`Burst`]) is one timer period, or several alike: ARR, RCR
//! (the periods less one: the timer's repetition counter makes the next
//! update event, and so the next burst, only after them), CCR1 (the STEP
//! pulse at the start of each period, PWM mode 1: 0 = no pulse) and CCR2
//! (DIR for the whole entry: 0 low, `0xFFFF` high). At constant speed the
//! steps' periods are alike, so one entry (one DMA burst) makes many
//! pulses, and the refill that writes the entries runs that much less often.
//! The writer turns "a pulse `delay` ticks after the previous one, with DIR
//! at `level`" into entries so that
//!
//! - every pulse rises exactly `delay` ticks after the previous one (the
//!   sum of the entries between them), unless the delay is shorter than
//!   the entries already written since (the schedule ran dry: the writer
//!   counts the step as late, [`BurstWriter::late`]);
//! - no entry is longer than the idle entry ([`PulseShape::idle_ticks`]):
//!   a longer interval is a pulse entry followed by idle entries, exact to
//!   the tick. The entries written ahead of the timer then span at most a
//!   buffer's length of idle entries, which the planner's horizon covers,
//!   so the writer never needs a step the planner has not queued yet (a
//!   longer entry, repeated by the timer's repetition counter, would reach
//!   past it on a slow move and make the steps after it late);
//! - only steps the feed has and gives in a run ([`StepFeed::run`]: the
//!   schedule's equal delays at constant speed) are repeated, up to
//!   [`MAX_PERIODS`] and the idle entry's length, so the entries
//!   ahead of the timer reach no further than at rest;
//! - no entry is shorter than [`MIN_ENTRY_TICKS`], so the next burst always
//!   lands before the update event that needs it;
//! - DIR changes only at an update event with no pulse high, at least the
//!   set-up time before the next rising edge and at least the same time
//!   (the hold) after the last falling edge;
//! - a pulse entry's length is only known with the next step; when the
//!   schedule has none yet, the writer closes it with the last interval (a
//!   cruise that merely ran late continues on time) and fills on with idle
//!   entries of [`PulseShape::idle_ticks`] (a start from rest).
//!
//! The writer is constant time per entry and per step (no loop, no
//! division). The firmware's DMA refill calls [`BurstWriter::fill`] on
//! the half of the buffer just consumed; the host tests run the same code.

/// Shortest entry, ticks: the DMA burst (four half-words) for the entry
/// after it must complete within it, at any bus load.
pub const MIN_ENTRY_TICKS: u32 = 64;
/// Most periods in one entry: the F1's 8-bit repetition counter (the G4's
/// has 16 bits).
pub const MAX_PERIODS: u32 = 256;
/// Longest single period: a 16-bit ARR below its maximum (with ARR at
/// 0xFFFF, CCR2 = 0xFFFF would drop DIR for the period's last tick).
const MAX_PERIOD_TICKS: u32 = u16::MAX as u32;

/// One DMA burst: ARR, RCR, CCR1, CCR2, in the timer's register order.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Burst {
    arr: u16,
    rcr: u16,
    ccr1: u16,
    ccr2: u16,
}

impl Burst {
    /// All registers zero: what a buffer holds before it is first written.
    pub const ZERO: Burst = Burst {
        arr: 0,
        rcr: 0,
        ccr1: 0,
        ccr2: 0,
    };

    fn new(ticks: u32, pulse_ticks: u32, dir_high: bool) -> Self {
        debug_assert!((1..=MAX_PERIOD_TICKS).contains(&ticks));
        Self {
            arr: (ticks - 1) as u16,
            rcr: 0,
            ccr1: pulse_ticks as u16,
            ccr2: if dir_high { u16::MAX } else { 0 },
        }
    }

    /// The four register values, in burst order (ARR, RCR, CCR1, CCR2).
    pub fn registers(&self) -> [u16; 4] {
        [self.arr, self.rcr, self.ccr1, self.ccr2]
    }

    /// Length of the entry, ticks: `(ARR + 1) · (RCR + 1)`.
    pub fn ticks(&self) -> u32 {
        self.period_ticks() * self.periods()
    }

    /// Length of one of its periods, ticks: `ARR + 1`.
    pub fn period_ticks(&self) -> u32 {
        u32::from(self.arr) + 1
    }

    /// Its periods, each alike (with its pulse, if any): `RCR + 1`.
    pub fn periods(&self) -> u32 {
        u32::from(self.rcr) + 1
    }

    /// Its first period alone (a run cut to one step).
    pub fn first_period(&self) -> Burst {
        Burst { rcr: 0, ..*self }
    }

    /// How many more periods the entry may take: while it lasts no more
    /// than `longest` ticks and has no more than [`MAX_PERIODS`].
    fn room(&self, longest: u32) -> u32 {
        room_of(self.period_ticks(), self.periods(), longest)
    }

    /// `more` periods added (within [`Burst::room`]).
    fn repeated(mut self, more: u32) -> Self {
        self.rcr += more as u16;
        self
    }

    /// STEP pulse width at the start of the entry, ticks (0: no pulse).
    pub fn pulse_ticks(&self) -> u32 {
        u32::from(self.ccr1)
    }

    /// DIR level during the whole entry.
    pub fn dir_high(&self) -> bool {
        self.ccr2 != 0
    }
}

/// STEP width, DIR set-up (and hold) and the idle entry, ticks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PulseShape {
    width: u32,
    dir_setup: u32,
    idle: u32,
}

impl PulseShape {
    /// `width` at least 1 tick; `idle_ticks` (the entry length while no
    /// step is scheduled, the latency of a start from rest, and the longest
    /// entry) between twice [`MIN_ENTRY_TICKS`] and 2^16 − 1.
    pub fn new(width_ticks: u32, dir_setup_ticks: u32, idle_ticks: u32) -> Self {
        Self {
            width: width_ticks.clamp(1, MAX_PERIOD_TICKS / 2),
            dir_setup: dir_setup_ticks.min(MAX_PERIOD_TICKS),
            // twice the shortest entry, so that an interval just over it
            // splits into two entries of at least the shortest
            idle: idle_ticks.clamp(2 * MIN_ENTRY_TICKS, MAX_PERIOD_TICKS),
        }
    }

    /// The idle entry's length, ticks.
    pub fn idle_ticks(&self) -> u32 {
        self.idle
    }

    /// Longest entry of repeated periods, ticks: the idle entry. The
    /// entries written ahead of the timer, which a new move waits for,
    /// then last no longer than while idle (a limit cuts the runs among
    /// them, docs/firmware.md).
    fn run_ticks(&self) -> u32 {
        self.idle
    }

    /// Ticks after a pulse's rise until DIR may change.
    fn hold_ticks(&self) -> u32 {
        (self.width + self.dir_setup).max(MIN_ENTRY_TICKS)
    }
}

/// The next step, once known: ticks still to write before its pulse and
/// the DIR level it needs, and how many of those ticks must keep the old
/// level (the hold of a reversal).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Next {
    rest: u32,
    level: bool,
    hold: u32,
}

/// Where [`BurstWriter::fill`] takes its steps from. A closure
/// `FnMut() -> Option<(u32, bool)>` is one that has no plain steps.
pub trait StepFeed {
    /// The next step, `(delay, dir_level)`: its pulse `delay` ticks after
    /// the previous one (or after the start of the last idle entry, from
    /// rest), with DIR at `dir_level`; `None` while there is none. At rest
    /// a `None` ends the asking for the fill: the rest of it is idle.
    fn next_step(&mut self) -> Option<(u32, bool)>;

    /// The next step's delay if it is *plain*: in the direction and at the
    /// DIR level of the step given before it, with nothing else for the
    /// feed to look at. `None` leaves the step to
    /// [`StepFeed::next_step`]. The writer's cruise path takes its steps
    /// here, at no cost per step beyond the delay's range check.
    fn plain_step(&mut self) -> Option<u32> {
        None
    }

    /// Up to `max` more plain steps whose delay is `delay` (one
    /// [`StepFeed::plain_step`] has just given), taken at once: how many.
    /// The writer repeats them in the entry of the step before them, at
    /// no cost per step but the feed's. A feed without runs takes none:
    /// each step is then an entry of its own. Only steps that cost the
    /// feed next to nothing should come in runs: a run's steps all go into
    /// one buffer half, whose refill must be done within the other half's
    /// time, which may be a step per entry.
    /// `max` is asked only once the feed has one such step (it costs a
    /// division).
    fn run(&mut self, delay: u32, max: impl FnOnce() -> u32) -> u32 {
        let _ = (delay, max);
        0
    }
}

impl<F: FnMut() -> Option<(u32, bool)>> StepFeed for F {
    fn next_step(&mut self) -> Option<(u32, bool)> {
        self()
    }
}

/// [`Burst::room`] of an entry of `periods` periods of `period` ticks,
/// without the entry.
#[inline(always)]
fn room_of(period: u32, periods: u32, longest: u32) -> u32 {
    (longest / period).min(MAX_PERIODS).saturating_sub(periods)
}

/// Makes [`Burst`] entries from per-step delays (module docs).
#[derive(Clone, Debug)]
pub struct BurstWriter {
    shape: PulseShape,
    /// The last step's pulse starts the next entry written.
    open: bool,
    /// DIR level of the last pulse (and of the entries since).
    level: bool,
    /// Ticks written since the last pulse's rise (saturating), or, while
    /// idle, since the start of the last idle entry.
    since: u32,
    /// Interval between the last two pulses: a pulse entry's length when
    /// the step after it is not known yet.
    last_interval: u32,
    next: Option<Next>,
    /// At rest: no pulse written since the last idle entry.
    resting: bool,
    late: u32,
    pulses: u32,
}

impl BurstWriter {
    /// At rest, DIR at `level`.
    pub fn new(shape: PulseShape, level: bool) -> Self {
        Self {
            shape,
            open: false,
            level,
            since: 0,
            last_interval: shape.idle,
            next: None,
            resting: true,
            late: 0,
            pulses: 0,
        }
    }

    /// New STEP width / DIR set-up, from the next step on.
    pub fn set_shape(&mut self, shape: PulseShape) {
        self.shape = shape;
    }

    /// Steps whose pulse came later than their delay (the schedule ran dry
    /// while the entries before them were written), since the start.
    pub fn late(&self) -> u32 {
        self.late
    }

    /// DIR level of the last entry written, or of the pulse that opens
    /// the next one.
    pub fn level(&self) -> bool {
        self.level
    }

    /// Pulses written since the start.
    pub fn pulses(&self) -> u32 {
        self.pulses
    }

    /// The writer has a step it has not finished writing (its pulse, or
    /// the time before it).
    pub fn busy(&self) -> bool {
        self.open || self.next.is_some()
    }

    /// Writes `out` whole: the entries of the steps `feed` gives, asked
    /// for only when the writer needs one, and idle entries when it gives
    /// none; the feed's runs ([`StepFeed::run`]) repeat the entry of the
    /// step before them. Returns the pulses written.
    pub fn fill(&mut self, out: &mut [Burst], feed: &mut impl StepFeed) -> u32 {
        let before = self.pulses;
        let run = self.shape.run_ticks();
        let mut n = 0;
        while n < out.len() {
            if self.open && self.next.is_none() {
                // Cruise and ramps: a pulse is open and the feed's steps
                // are plain, so each is one period, its delay whole, at
                // the open pulse's level (what the general path below
                // writes for them, without its cases); the feed's run of
                // steps alike after it repeats its entry.
                let (width, idle, level) = (self.shape.width, self.shape.idle, self.level);
                let (mut written, mut last, mut full) = (0, self.last_interval, false);
                while let Some(delay) = feed.plain_step() {
                    last = delay;
                    if !(MIN_ENTRY_TICKS..=idle).contains(&delay) {
                        self.accept(delay, level);
                        break;
                    }
                    let b = Burst::new(delay, width.min(delay / 2), level);
                    let alike = feed.run(delay, || b.room(run));
                    out[n] = b.repeated(alike);
                    written += 1 + alike;
                    n += 1;
                    if n == out.len() {
                        full = true;
                        break;
                    }
                }
                self.pulses += written;
                self.last_interval = last;
                if full {
                    break;
                }
            }
            // a step whose pulse starts right where the entries end leaves
            // the pulse open: its entry's length is the step after it, so
            // a slot may need two steps
            let mut asked = 0;
            while self.next.is_none() && asked < 2 {
                let Some((delay, level)) = feed.next_step() else {
                    if self.resting && !self.open {
                        // at rest and the feed has nothing: the rest of the
                        // fill waits idle too. A feed gets no new step while
                        // a fill runs (the refill preempts whoever pushes),
                        // so asking again per entry would only cost the
                        // idle drive's time.
                        let idle = self.entry();
                        out[n..].fill(idle);
                        return self.pulses - before;
                    }
                    break;
                };
                asked += 1;
                self.accept(delay, level);
            }
            out[n] = self.entry();
            n += 1;
        }
        self.pulses - before
    }

    /// Entries at the start of `out` for a cruise that goes on: when a
    /// pulse is open and the last delay is one the fast path writes,
    /// `take(delay, per, entries)` takes up to `entries` whole runs of
    /// `per()` steps of that delay, each as at once as [`StepFeed::run`]
    /// takes one (the feed's own, known without reading them, and plain:
    /// in the last step's direction, DIR as it was), and says how many;
    /// it calls `per` (a division) only once it has such a run. Each is
    /// the entry [`BurstWriter::fill`]'s fast path would write for that
    /// run; they are written as copies. Returns the entries and the
    /// pulses; fill the rest of `out` with [`BurstWriter::fill`]. A
    /// refill in a cruise then costs one look at its runs, not one an
    /// entry. A call of its own, not a part of `fill`: in it, the fast
    /// path's loop kept more of its state in memory, which every ramp step
    /// paid for; and a refill on a ramp pays only the checks before `take`
    /// and `take`'s first look.
    #[inline(always)]
    pub fn fill_runs(
        &mut self,
        out: &mut [Burst],
        take: impl FnOnce(u32, &mut dyn FnMut() -> u32, u32) -> u32,
    ) -> (usize, u32) {
        if !self.open || self.next.is_some() {
            return (0, 0);
        }
        let delay = self.last_interval;
        if !(MIN_ENTRY_TICKS..=self.shape.idle).contains(&delay) {
            return (0, 0);
        }
        let mut room = 0;
        let run = self.shape.run_ticks();
        let copies = take(
            delay,
            &mut || {
                // the room of the run's first period: the entry itself is
                // made only for copies (on a ramp there are none)
                room = room_of(delay, 1, run);
                1 + room
            },
            out.len() as u32,
        )
        .min(out.len() as u32);
        if copies == 0 {
            return (0, 0);
        }
        let b = Burst::new(delay, self.shape.width.min(delay / 2), self.level);
        out[..copies as usize].fill(b.repeated(room));
        let pulses = copies * (1 + room);
        self.pulses += pulses;
        (copies as usize, pulses)
    }

    /// Plans the time up to the next pulse.
    fn accept(&mut self, delay: u32, level: bool) {
        let shape = self.shape;
        let reversal = level != self.level;
        let mut rest = delay.saturating_sub(self.since);
        // a step the schedule gave too late (the entries written since the
        // last pulse already run past it); from rest there is no time to
        // keep
        let behind = delay < self.since && !self.resting;
        if rest == 0 && !reversal && !self.open {
            // the entries written since the last pulse (or the last idle
            // one) end on time, or past it: the pulse starts the next entry
            self.late += u32::from(behind);
            self.last_interval = delay;
            self.start_pulse(level);
            return;
        }
        // before the pulse: a whole entry; at a reversal, what the hold
        // still needs at the old level (a whole entry if anything), then
        // the set-up at the new one
        let hold = if reversal {
            match shape.hold_ticks().saturating_sub(self.since) {
                0 => 0,
                h => h.max(MIN_ENTRY_TICKS),
            }
        } else {
            0
        };
        let min_rest = hold
            + if reversal {
                shape.dir_setup.max(MIN_ENTRY_TICKS)
            } else {
                MIN_ENTRY_TICKS
            };
        if rest < min_rest {
            // a reversal's stretch is the shape's, a start from rest has
            // no time to keep; anything else is a step the schedule gave
            // too late
            if !reversal && !self.resting {
                self.late += 1;
            }
            rest = min_rest;
        }
        self.last_interval = delay;
        self.next = Some(Next { rest, level, hold });
    }

    /// The next entry.
    fn entry(&mut self) -> Burst {
        let pulse = if self.open { self.shape.width } else { 0 };
        let Some(mut n) = self.next else {
            // no step known: close the pulse with the last interval, or
            // wait idle
            let len = if self.open {
                self.last_interval.clamp(MIN_ENTRY_TICKS, self.shape.idle)
            } else {
                self.resting = true;
                self.since = 0;
                self.shape.idle
            };
            return self.emit(len, pulse, self.level);
        };
        // the part at the old level first (a reversal's hold), then the rest
        let (budget, level) = if n.hold > 0 {
            (n.hold, self.level)
        } else {
            (n.rest, n.level)
        };
        let len = split(budget, self.shape.idle);
        n.rest -= len;
        n.hold = n.hold.saturating_sub(len);
        let b = self.emit(len, pulse, level);
        if n.rest == 0 {
            self.next = None;
            self.start_pulse(n.level);
        } else {
            self.next = Some(n);
        }
        b
    }

    /// An entry of `period` ticks, with a pulse of
    /// `pulse` ticks (0: none; never more than half the period, so the
    /// driver sees both levels) and DIR at `level`.
    fn emit(&mut self, period: u32, pulse: u32, level: bool) -> Burst {
        let pulse = if pulse != 0 {
            self.open = false;
            self.pulses += 1;
            pulse.min(period / 2)
        } else {
            0
        };
        self.since = self.since.saturating_add(period);
        self.level = level;
        Burst::new(period, pulse, level)
    }

    /// The next entry starts with the pulse of the step just reached.
    fn start_pulse(&mut self, level: bool) {
        self.open = true;
        self.resting = false;
        self.since = 0;
        self.level = level;
    }
}

/// The next entry's length out of `rest` ticks (≥ the minimum entry):
/// all of it if it fits `longest`, else `longest`, or less where the
/// remainder would fall below the minimum entry.
fn split(rest: u32, longest: u32) -> u32 {
    if rest <= longest {
        rest
    } else {
        longest.min(rest - MIN_ENTRY_TICKS)
    }
}

#[cfg(test)]
mod tests;
