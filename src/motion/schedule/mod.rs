//! The step schedule between the planner (thread mode) and the step-timer
//! interrupt, and the interrupt side that consumes it ([`StepSource`]).
//!
//! A [`Segment`] is Klipper's `(interval, count, add)` with three more
//! terms: `count` steps, the first `interval` after the previous step;
//! after each step the interval grows by `add`, `add` by `add2`, `add2` by
//! `add3` and `add3` by `add4`. The intervals are thus a quartic in the
//! step number (the step times a quintic), which lets the planner match
//! the profile's time, velocity and acceleration at both ends of every
//! segment, so that the motor sees no velocity or acceleration jump from
//! one segment to the next. Times are timer ticks in Q32.32 fixed point;
//! `add2`, `add3` and `add4` may carry more fraction bits
//! ([`Segment::fine_bits`]), of which `add` takes the whole 2^-32 units.
//!
//! # A ring of per-step delays
//!
//! [`StepSchedule::push`] (thread mode) expands each segment — or, with
//! [`StepSchedule::push_steps`], its next steps — into its steps' integer
//! delays, one `u32` per step, in a ring of [`SCHEDULE_STEPS`] entries: it
//! accumulates the exact Q32.32 times (the five adds per step above) and
//! carries the fraction of each time into
//! the next (`frac`, whose origin is half a tick in when a run starts from
//! rest), so every delay rounds its exact time to the nearest tick and
//! rounding never accumulates. The interrupt only pops one delay per step.
//! An entry is a delay (1 ..= `MAX_DELAY_TICKS`), the end sentinel `END`
//! (0), or a direction marker (`MARK_FORWARD` / `MARK_BACKWARD`, the top two
//! values): a push whose direction differs from the previous push's starts
//! with a marker (directions change at rest only, so markers are rare).
//! Delays from 2^31 ticks on are valid too but, like markers and the
//! sentinel, go the slow way (below).
//!
//! # Sharing between thread mode and the interrupt
//!
//! [`StepSchedule`] is a lock-free single-producer / single-consumer ring
//! built from atomics only (no `unsafe`, no critical section): the planner
//! pushes with `&StepSchedule`, the interrupt pops with the same shared
//! reference. The firmware keeps it in a `static` (all zeros: .bss,
//! src/firmware/steps.rs), hands it to [`crate::Device::control`] in the
//! control loop and owns a [`StepSource`] inside the step engine's refill
//! interrupt (on a host: `motion::sim::SimAxis`).
//! Exactly one context may push and exactly one may pop.
//!
//! The drive has one core, and the consumer's interrupt is never preempted by
//! thread mode or by the limit-switch interrupt (it has the highest
//! priority): each context sees the other's stores whole and in program
//! order, so only the compiler must keep them in order. Every access is
//! therefore Relaxed (a plain `ldr`/`str` on Cortex-M, also on M0, which
//! has no atomic read-modify-write; none is used), with a `compiler_fence`
//! where the order matters; no `dmb` anywhere (it would matter only
//! between cores). Host builds run producer and consumer on one thread.
//!
//! - `head` (producer): the index the next push writes; `ring[head]` always
//!   holds `END`. A push writes its entries after `head`, then the new
//!   sentinel behind them, and only then overwrites the old sentinel with
//!   its first entry: the interrupt, which reads `ring[next]`, never sees a
//!   half-written push, and needs no look at `head` per step. One slot
//!   stays spare for the sentinel.
//! - `next` (consumer, one store per step): the index of the entry after
//!   the step announced and not yet made (the pending one, at `next − 1`),
//!   or, when idle, after the last entry taken. The producer never writes
//!   the slot at `next − 1`.
//! - The position is not stored per step: [`StepSchedule::position`]
//!   derives it as `base_pos + dir · (next − base_idx)`, where the base
//!   (position, index, direction) is rewritten only in the slow path under
//!   a sequence count.
//! - Thread mode and the limit-switch interrupt never make the interrupt
//!   read their flags per step either: they store the flag (flush, limits,
//!   brake rate), then raise attention (clear `quiet`, the one byte the
//!   interrupt reads per step besides the ring); the interrupt sets `quiet`
//!   before it reads the flags, so no change is lost. It clears `quiet`
//!   itself while it is idle or braking, so that a start from rest goes the
//!   slow way, and a braking step the brake's own short way
//!   (`brake_plain`: the interval, and the base's position moved on by one
//!   store, since brake steps are no ring entries).
//! - A drop of the queue (flush, the limit brake's end, [`StepSource::cancel`])
//!   moves `next` to `head` and takes the direction of the last push
//!   (`head_backward`, stored before `head`), so that the markers it
//!   skipped cannot leave the interrupt in the wrong direction.
//!
//! The schedule keeps no exact time beside the delays, in any build: one
//! layout on every target. Who needs the exact times (the simulation,
//! `motion::sim::SimAxis`, whose tests check the pulses against
//! the exact profile) passes a [`StepSink`] to the push
//! ([`StepSchedule::push_steps`]), which tells it each step's ring index
//! and carried fraction ([`PushedSteps::fractions`]) and keeps them in
//! its own storage; the firmware passes `()`, which compiles to nothing.
//!
//! # Files
//!
//! [`segment`]: the segment and its expansion into delays; [`ring`]: the
//! shared ring ([`StepSchedule`], producer side); [`source`]: the
//! interrupt side ([`StepSource`]); [`brake`]: the limit brake's rate and
//! intervals; [`sink`]: the hook that reports the pushed steps' exact times.
//!
//! # Worst-case interrupt cost
//!
//! [`StepSource::advance`] per step (the fast path, `advance_plain`):
//! load `next`, the entry there and `quiet`, two compares, store
//! `next + 1`. No multiplication, no division, no loop, no `dmb` (the
//! step-interrupt benchmark counts its instructions, docs/benchmarks.md). The slow path
//! (a start from rest, the end of the queue, a marker, a delay from 2^31
//! ticks, a flag raised) rewrites the position base under the sequence
//! count; it takes at most one marker and one step, so it is constant
//! time too. A braking step (below) costs seven 32×32 → 64-bit multiplies
//! and 32-bit shifts, still no division and no loop; while the motor is
//! fast, a stride of braking steps costs that once and each of its steps
//! an addition. The brake's start reads the delays ahead once (a loop of
//! a fixed length and a shift: `mean_ahead`), in the slow path or ahead
//! of it ([`StepSource::prepare_brake`]). At constant speed the
//! step engine takes a run of equal delays at once
//! ([`StepSource::advance_run`]: one store of `next`, and no per-step
//! work where the producer noted the run as it pushed a constant speed
//! of whole ticks, three stores a push; a compare per step elsewhere);
//! at a limit's edge it gives back the steps it had been handed and not
//! made ([`StepSource::take_back`]) so that the brake starts nearer the
//! edge. The expansion is
//! thread mode's, in [`StepSchedule::push`]: a short loop per step when
//! the higher terms fit 32 bits (`Expansion::narrow`, the common segment;
//! a longer one otherwise) plus a fixed cost per push.
//!
//! # Limit brake (SPEC §8.7)
//!
//! A limit switch must stop motion towards it with the quick stop
//! deceleration 0x6085 *at once*: the planner only appends behind its
//! queued horizon, and the control loop runs every millisecond. So the
//! limit-switch interrupt (a third context) writes the logical limit states
//! with [`StepSchedule::set_limits`] (raising attention), and
//! [`StepSource::advance`], when its next step goes towards an active limit
//! while the brake is armed (checked when attention is raised and at every
//! start from rest or direction marker, the only places where either can
//! change) ([`StepSchedule::set_brake_rate`], written by the drive: 0x6085
//! outside homing, disarmed in homing where the sequencer decides at the
//! limits), stops taking entries and decelerates on its own from the
//! interval of the step it would have made (its exact one, the mean of the
//! delays ahead): each interval grows by
//! the factor `(1 - 2q)^-1/2 ≈ 1 + q + 3/2 q² + 5/2 q³ + 35/8 q⁴` with `q = a·p²`
//! (`p` the interval, `a` the deceleration in steps/tick²), which is
//! `v² ← v² - 2a` per step, the constant deceleration, in a few multiplies.
//! It stops when `q ≥ 1/4` (less than two steps from rest), drops the queue
//! and latches ([`LimitBrake::done`]): any segment pushed before the planner
//! noticed is dropped, until thread mode calls
//! [`StepSchedule::release_brake`] (the planner does, once it has taken the
//! position back: [`crate::motion::Planner::stop_at_once`]). A flush
//! requested while braking is carried out when the brake ends.

mod brake;
mod ring;
mod segment;
mod sink;
mod source;
#[cfg(test)]
mod tests;

pub use brake::{brake_rate, LimitBrake};
pub use ring::StepSchedule;
pub use segment::{Segment, MAX_FINE_BITS};
pub use sink::{PushedSteps, StepSink};
pub use source::{NextStep, StepSource};

/// Entries of the per-step ring (a power of two): delays plus the rare
/// direction markers, one slot for the end sentinel and the pending step.
/// At the highest step rate ([`crate::motion::MAX_STEP_RATE`]) a full ring
/// lasts more than two 1 ms control periods. The feature `long-schedule`
/// doubles it (4 KiB of RAM), and with it that rate; `longer-schedule`
/// doubles both again (8 KiB).
#[cfg(feature = "longer-schedule")]
pub const SCHEDULE_STEPS: usize = 2048;
#[cfg(all(feature = "long-schedule", not(feature = "longer-schedule")))]
pub const SCHEDULE_STEPS: usize = 1024;
#[cfg(not(feature = "long-schedule"))]
pub const SCHEDULE_STEPS: usize = 512;

/// Fractional bits of schedule times: Q32.32 ticks.
pub const TICK_FRAC_BITS: u32 = 32;

/// Ring entry: end of the queue (the sentinel at `head`).
const END: u32 = 0;
/// Ring entries: the steps after it go in the positive / negative direction.
const MARK_FORWARD: u32 = u32::MAX;
const MARK_BACKWARD: u32 = u32::MAX - 1;
/// Longest delay an entry holds, ticks (the top two values are markers).
/// Longer ones are clamped; the planner's slowest interval (0.1 steps/s) is
/// 10 s, 2^32 ticks would be 429 s at 10 MHz.
const MAX_DELAY_TICKS: u32 = u32::MAX - 2;

/// Half a tick in Q0.32: the time origin of a run from rest.
const HALF_TICK: u32 = 1 << (TICK_FRAC_BITS - 1);

fn dir(forward: bool) -> i32 {
    if forward {
        1
    } else {
        -1
    }
}
