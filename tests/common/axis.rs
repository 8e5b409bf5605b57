//! Motion test harness: a [`Planner`] (or a whole `Device`) driven by a
//! control loop over a [`SimAxis`], recording every step, and the checks of
//! the planner's exactness bounds (docs/drive.md).
#![allow(dead_code)]

use modbus_drive::closed_loop::sim::SimEncoder;
use modbus_drive::device::sim::SimHost;
use modbus_drive::device::CONTROL_PERIOD_US;
use modbus_drive::motion::sim::{RunStop, SimAxis, StepRecord};
use modbus_drive::motion::{Fill, Goal, Planner, PlannerConfig, StepSchedule};

pub const Q: f64 = 4294967296.0;

/// A planner on a simulated axis, with a fixed control period.
pub struct PlannerRun {
    pub sched: Box<StepSchedule>,
    pub planner: Planner,
    pub axis: SimAxis,
    pub steps: Vec<StepRecord>,
    pub now_us: u64,
    pub period_us: u64,
    pub goals: std::collections::VecDeque<Goal>,
    /// `now_us` of the last control call if the schedule was idle (empty,
    /// interrupt stopped) when it filled: the planner then restarts its
    /// clock there, so a goal given before that call starts at that time
    /// (otherwise after its last planned step).
    pub idle_fill_us: Option<u64>,
}

impl PlannerRun {
    pub fn new(tick_hz: u32, period_us: u64) -> Self {
        // the shipped segment length: the exactness bounds hold for what
        // the drive runs (segments end on the fit's error bound or this
        // time, profile/length.rs `segment_len`)
        let cfg = PlannerConfig::default()
            .with_tick_hz(tick_hz)
            .with_horizon_us((2 * period_us + 1000) as u32);
        Self {
            sched: Box::new(StepSchedule::new()),
            planner: Planner::new(cfg),
            axis: SimAxis::new(tick_hz),
            steps: Vec::new(),
            now_us: 0,
            period_us,
            goals: Default::default(),
            idle_fill_us: None,
        }
    }

    /// One control call at `now_us`: fill, handing over queued goals when
    /// a motion ends, then start the interrupt.
    pub fn control(&mut self) {
        let idle = !self.sched.is_running() && self.sched.is_empty();
        for _ in 0..16 {
            match self
                .planner
                .fill_with(self.now_us, &self.sched, &mut self.axis)
            {
                Fill::Ended => {
                    if let Some(g) = self.goals.pop_front() {
                        assert!(self.planner.set_goal(g));
                    }
                }
                _ => break,
            }
        }
        self.idle_fill_us = idle.then_some(self.now_us);
        self.axis.kick(&self.sched);
    }

    /// Runs one control period.
    pub fn tick(&mut self) {
        let until = self.axis.us_to_ticks(self.now_us + self.period_us);
        let steps = &mut self.steps;
        while self.axis.run_until(&self.sched, until, |s| steps.push(s)) == RunStop::SwitchChanged {
        }
        self.now_us += self.period_us;
        self.control();
    }

    pub fn run_until_rest(&mut self, max_us: u64) {
        let end = self.now_us + max_us;
        loop {
            self.tick();
            if self.planner.at_rest(&self.sched) && self.goals.is_empty() {
                return;
            }
            assert!(self.now_us < end, "no rest after {max_us} µs");
        }
    }
}

/// Velocities (steps/s, signed) between consecutive exact step times.
pub fn exact_velocities(steps: &[StepRecord], tick_hz: u32) -> Vec<(f64, f64)> {
    // (time of the interval's midpoint in s, velocity)
    steps
        .windows(2)
        .map(|w| {
            let dt = w[1].exact().wrapping_sub(w[0].exact()) as f64 / Q / f64::from(tick_hz);
            let t = w[0].exact() as f64 / Q / f64::from(tick_hz) + dt / 2.0;
            let v = if w[1].forward() { 1.0 / dt } else { -1.0 / dt };
            (t, v)
        })
        .collect()
}

/// Checks the planner's velocity and acceleration bounds and the "direction
/// changes only at rest" rule on the exact schedule times:
/// |v| ≤ v_max·1.005, and after the first 10 steps of each run from rest
/// the acceleration between two intervals ≤ a_max·1.02.
pub fn check_dynamics(steps: &[StepRecord], tick_hz: u32, v_max: f64, a_max: f64) {
    let f = f64::from(tick_hz);
    for (i, w) in steps.windows(2).enumerate() {
        assert!(
            w[1].tick() > w[0].tick(),
            "interval not positive at step {i}"
        );
        let dt = w[1].exact().wrapping_sub(w[0].exact()) as f64 / Q / f;
        let v = 1.0 / dt;
        assert!(v <= v_max * 1.005 + 1e-9, "step {i}: {v} steps/s > {v_max}");
        if w[1].forward() != w[0].forward() {
            // the last step before the reversal ends at rest: it takes at
            // least sqrt(2 / a_max)
            let min_dt = (2.0 / a_max).sqrt() * 0.98;
            assert!(
                dt >= min_dt,
                "reversal at step {i} at speed: dt {dt} < {min_dt}"
            );
            if i > 0 {
                let before = w[0].exact().wrapping_sub(steps[i - 1].exact()) as f64 / Q / f;
                assert!(
                    before >= min_dt,
                    "step {i} before the reversal at speed: {before} < {min_dt}"
                );
            }
        }
    }
    let vel: Vec<f64> = steps
        .windows(2)
        .map(|w| {
            let dt = w[1].exact().wrapping_sub(w[0].exact()) as f64 / Q / f;
            if w[1].forward() {
                1.0 / dt
            } else {
                -1.0 / dt
            }
        })
        .collect();
    let mut run_start = 0usize;
    for i in 1..vel.len() {
        if steps[i + 1].forward() != steps[i].forward() {
            run_start = i + 1;
            continue;
        }
        // interval i-1 is steps[i-1]→steps[i], interval i is steps[i]→steps[i+1]
        if i < run_start + 10 {
            continue;
        }
        let dt0 = steps[i].exact().wrapping_sub(steps[i - 1].exact()) as f64 / Q / f;
        let dt1 = steps[i + 1].exact().wrapping_sub(steps[i].exact()) as f64 / Q / f;
        let a = (vel[i] - vel[i - 1]).abs() / ((dt0 + dt1) / 2.0);
        // a long pause at rest (motion ended, next one started later) is
        // not an acceleration of the profile
        if dt1 > 4.0 * (2.0 / a_max).sqrt() + 0.01 || dt0 > 4.0 * (2.0 / a_max).sqrt() + 0.01 {
            run_start = i + 1;
            continue;
        }
        assert!(
            a <= a_max * 1.02 + 1e-9,
            "step {}: acceleration {a} > {a_max} (v {} → {})",
            i + 1,
            vel[i - 1],
            vel[i]
        );
    }
}

/// The continuous trapezoid from rest to rest over `dist` steps with
/// cruise `v`, acceleration `a`, deceleration `d` (steps/s, steps/s²):
/// the time at which it reaches position `k` (s).
pub fn trapezoid_time(dist: f64, v: f64, a: f64, d: f64, k: f64) -> f64 {
    let (mut xa, mut xd, mut vp) = (v * v / (2.0 * a), v * v / (2.0 * d), v);
    if xa + xd > dist {
        vp = (2.0 * a * d * dist / (a + d)).sqrt();
        xa = vp * vp / (2.0 * a);
        xd = dist - xa;
    }
    let ta = vp / a;
    let tc = (dist - xa - xd) / vp;
    if k <= xa {
        (2.0 * k / a).sqrt()
    } else if k <= dist - xd {
        ta + (k - xa) / vp
    } else {
        ta + tc + vp / d - (2.0 * (dist - k).max(0.0) / d).sqrt()
    }
}

/// One step of an ideal continuous profile.
#[derive(Clone, Copy, Debug)]
pub struct IdealStep {
    /// Time of the step, s.
    pub t: f64,
    /// Time of the step before it, or of the start from rest: the local
    /// interval is `t - prev_t`.
    pub prev_t: f64,
    /// Signed velocity at the step, steps/s.
    pub v: f64,
    pub forward: bool,
}

/// A run of steps in one direction: constant-acceleration pieces over the
/// distance `0..=len`, from speed `s0` at time `t0`.
struct Run {
    forward: bool,
    t0: f64,
    s0: f64,
    /// (end of piece, acceleration); the last piece ends at rest.
    pieces: Vec<(f64, f64)>,
}

impl Run {
    /// Time (s) and speed at distance `x` (≤ the last piece's end).
    fn at(&self, x: f64) -> (f64, f64) {
        let (mut x0, mut t0, mut s0) = (0.0, self.t0, self.s0);
        let last = self.pieces.len() - 1;
        for (i, &(end, acc)) in self.pieces.iter().enumerate() {
            let xe = x.min(end);
            let dx = (xe - x0).max(0.0);
            let (t, s) = if i == last && acc < 0.0 {
                // the final ramp to rest, timed from its end (no
                // cancellation near v = 0)
                let t_end = t0 + s0 / -acc;
                let left = (end - xe).max(0.0);
                (
                    t_end - (2.0 * left / -acc).sqrt(),
                    (2.0 * -acc * left).sqrt(),
                )
            } else if dx == 0.0 {
                (t0, s0)
            } else if acc == 0.0 {
                (t0 + dx / s0, s0)
            } else {
                let s = (s0 * s0 + 2.0 * acc * dx).max(0.0).sqrt();
                (t0 + 2.0 * dx / (s + s0), s)
            };
            if x <= end || i == last {
                return (t, s);
            }
            (x0, t0, s0) = (end, t, s);
        }
        unreachable!()
    }

    /// Appends its whole steps `1..=len` to `out`.
    fn steps(&self, len: i64, out: &mut Vec<IdealStep>) {
        let mut prev_t = self.t0;
        for k in 1..=len {
            let (t, s) = self.at(k as f64);
            out.push(IdealStep {
                t,
                prev_t,
                v: if self.forward { s } else { -s },
                forward: self.forward,
            });
            prev_t = t;
        }
    }
}

/// A trapezoid over `dist` steps from speed `s0` (≤ `v`) to rest, with
/// cruise `v`, acceleration `a`, deceleration `d`; a triangle if short.
fn to_rest(forward: bool, s0: f64, t0: f64, dist: i64, v: f64, a: f64, d: f64) -> Run {
    let dd = dist as f64;
    let vp2 = (v * v)
        .min((2.0 * a * d * dd + d * s0 * s0) / (a + d))
        .max(s0 * s0);
    let x1 = (vp2 - s0 * s0) / (2.0 * a);
    let x2 = dd - vp2 / (2.0 * d);
    Run {
        forward,
        t0,
        s0,
        pieces: vec![(x1, a), (x2.max(x1), 0.0), (dd, -d)],
    }
}

/// A stop from speed `s0` at time `t0` to rest after exactly `n` whole
/// steps: cruise, then `d`, as the planner's stops do (docs/drive.md); when `n`
/// is a hair short of the continuous stop distance (see `ideal_goal`), the
/// ramp over `n` steps is correspondingly a hair steeper.
fn stop_run(forward: bool, s0: f64, t0: f64, n: i64, d: f64) -> Run {
    let stop = s0 * s0 / (2.0 * d);
    let pieces = if n as f64 >= stop {
        vec![(n as f64 - stop, 0.0), (n as f64, -d)]
    } else {
        vec![(0.0, 0.0), (n as f64, -(s0 * s0) / (2.0 * n as f64))]
    };
    Run {
        forward,
        t0,
        s0,
        pieces,
    }
}

/// Below this (steps) the planner's fixed-point rounding decides a knife
/// edge either way (it is about 2^-32 step times the ratio of the slopes).
const KNIFE_EDGE: f64 = 1e-5;

/// The ideal continuous profiles of a change of goal ("move to `target`",
/// SPEC §8.4 bit 5) handed over at position `x0` with signed velocity `v0`
/// at time `t0` (s), cruise `v`, acceleration `a`, deceleration `d`
/// (steps/s, steps/s²): on towards the target if it can still stop there
/// with `d`; else stop with `d` on a whole step (cruising up to the last
/// point from which `d` ends on one, as the README says stops do), then
/// from rest to the target. Each profile is its steps after `x0`. There
/// are two when the continuous stop distance is within [`KNIFE_EDGE`] of a
/// whole step (a goal arriving during a ramp to rest with the same `d` is
/// exactly there): stop there or one step later.
pub fn ideal_goal(
    x0: i64,
    v0: f64,
    t0: f64,
    target: i64,
    v: f64,
    a: f64,
    d: f64,
) -> Vec<Vec<IdealStep>> {
    let from_rest = |x: i64, t: f64, out: &mut Vec<IdealStep>| {
        let dist = target - x;
        if dist != 0 {
            to_rest(dist > 0, 0.0, t, dist.abs(), v, a, d).steps(dist.abs(), out);
        }
    };
    if v0 == 0.0 {
        let mut out = Vec::new();
        from_rest(x0, t0, &mut out);
        return vec![out];
    }
    let forward = v0 > 0.0;
    let s0 = v0.abs();
    let ahead = if forward { target - x0 } else { x0 - target };
    let stop = s0 * s0 / (2.0 * d);
    let mut candidates = Vec::new();
    if ahead > 0 && stop <= ahead as f64 + KNIFE_EDGE {
        let mut out = Vec::new();
        to_rest(forward, s0, t0, ahead, v, a, d).steps(ahead, &mut out);
        candidates.push(out);
    }
    if ahead <= 0 || stop > ahead as f64 - KNIFE_EDGE {
        let lo = (stop - KNIFE_EDGE).ceil().max(1.0) as i64;
        let hi = (stop + KNIFE_EDGE).ceil() as i64;
        for n in lo..=hi {
            let mut out = Vec::new();
            stop_run(forward, s0, t0, n, d).steps(n, &mut out);
            let t = out.last().map_or(t0, |s| s.t);
            from_rest(x0 + if forward { n } else { -n }, t, &mut out);
            candidates.push(out);
        }
    }
    candidates
}

/// A change of goal as the test handed it to the planner.
#[derive(Clone, Copy, Debug)]
pub struct GoalChange {
    /// Steps the planner had queued ([`Planner::planned_steps`]): they keep
    /// the old profile, the new one continues from the last of them.
    pub queued: u64,
    /// [`PlannerRun::idle_fill_us`] of the first control call after the
    /// goal: the planner restarted from rest at that time.
    pub idle_fill_us: Option<u64>,
    pub target: i64,
}

/// The ideal profile of a whole run of goal changes, each continuing from
/// the previous one's ideal state (position, velocity, time) at its
/// `queued` step. At a knife edge both candidates are valid profiles, and
/// which one the planner took can show only much later (a stop one step
/// further moves every step after it): the choices are made jointly, the
/// combination nearest to the steps made over the whole run (least
/// largest time error, a different number of steps counting as far) is
/// taken. Knife edges are rare: almost always one combination.
pub fn ideal_run(
    changes: &[GoalChange],
    steps: &[StepRecord],
    tick_hz: u32,
    v: f64,
    a: f64,
    d: f64,
) -> Vec<IdealStep> {
    let f = f64::from(tick_hz);
    let error = |ideal: &[IdealStep]| {
        if ideal.len() != steps.len() {
            return f64::INFINITY;
        }
        ideal
            .iter()
            .zip(steps)
            .map(|(w, s)| (s.tick() as f64 / f - w.t).abs())
            .fold(0.0, f64::max)
    };
    // depth-first over the changes; each level continues a prefix
    let mut best: Option<(f64, Vec<IdealStep>)> = None;
    let mut stack = vec![(0usize, Vec::<IdealStep>::new())];
    while let Some((i, mut ideal)) = stack.pop() {
        let Some(c) = changes.get(i) else {
            let e = error(&ideal);
            if best.as_ref().is_none_or(|(b, _)| e < *b) {
                best = Some((e, ideal));
            }
            continue;
        };
        ideal.truncate(c.queued as usize);
        let x0: i64 = ideal.iter().map(|s| if s.forward { 1 } else { -1 }).sum();
        let (v0, t0) = match c.idle_fill_us {
            Some(us) => (0.0, us as f64 * 1e-6),
            None => ideal.last().map_or((0.0, 0.0), |s| (s.v, s.t)),
        };
        for cand in ideal_goal(x0, v0, t0, c.target, v, a, d) {
            let mut next = ideal.clone();
            next.extend(cand);
            stack.push((i + 1, next));
        }
    }
    best.expect("at least one profile").1
}

/// Issue 3's step time bound, min(1 µs, 5 % of the local interval), for
/// every step against `ideal` (absolute times from tick 0), and the
/// direction of every step.
pub fn check_ideal_times(steps: &[StepRecord], tick_hz: u32, ideal: &[IdealStep]) {
    assert_eq!(steps.len(), ideal.len(), "steps made vs ideal");
    let f = f64::from(tick_hz);
    for (i, (s, want)) in steps.iter().zip(ideal).enumerate() {
        assert_eq!(s.forward(), want.forward, "direction of step {}", i + 1);
        let got = s.tick() as f64 / f;
        let bound = (1e-6f64).min(0.05 * (want.t - want.prev_t));
        assert!(
            (got - want.t).abs() <= bound,
            "step {}: {got} s vs ideal {} s (bound {bound})",
            i + 1,
            want.t
        );
    }
}

/// Issue 3's step time bound against `ideal(k)` (s from `t0_tick`):
/// |t − ideal| ≤ min(1 µs, 5 % of the ideal local interval).
pub fn check_times(steps: &[StepRecord], tick_hz: u32, t0_tick: u64, ideal: impl Fn(f64) -> f64) {
    let f = f64::from(tick_hz);
    let mut prev = 0.0;
    for (i, s) in steps.iter().enumerate() {
        let k = (i + 1) as f64;
        let want = ideal(k);
        let got = (s.tick() - t0_tick) as f64 / f;
        let bound = (1e-6f64).min(0.05 * (want - prev));
        assert!(
            (got - want).abs() <= bound,
            "step {}: {got} s vs ideal {want} s (bound {bound})",
            i + 1
        );
        prev = want;
    }
}

use super::{hex, Bus};
use modbus_drive::boards::Board;
use modbus_drive::motion::PlannerConfig as Cfg;

/// The whole device behind the frame path, with a control loop over a
/// simulated axis: what the virtual drive / firmware glue does.
pub struct Rig {
    pub bus: Bus,
    pub sched: Box<StepSchedule>,
    pub axis: SimAxis,
    pub steps: Vec<StepRecord>,
    /// Control-loop clock, µs.
    pub now_us: u64,
    pub period_us: u64,
    pub tick_hz: u32,
    /// A simulated encoder on the motor, read before every control call
    /// (SPEC §8.8), scaled with the drive's PA17 / PA10 / PA18.
    pub encoder: Option<SimEncoder>,
    /// Each control call in parts, as the firmware makes it
    /// (`SimHost::in_parts`).
    pub in_parts: bool,
}

impl Rig {
    pub fn new(axis: SimAxis) -> Self {
        Self::with_bus(Bus::new(), axis)
    }

    pub fn with_bus(bus: Bus, axis: SimAxis) -> Self {
        Self::with_config(
            bus,
            axis,
            Cfg::default()
                .with_tick_hz(10_000_000)
                .with_horizon_us(3000)
                .with_max_segment_us(1000),
        )
    }

    /// The planner as `board`'s firmware configures it (its step tick and
    /// limits, the default horizon and segment length), on an axis at that
    /// tick.
    pub fn on_board(board: Board, axis: impl FnOnce(SimAxis) -> SimAxis) -> Self {
        let tick_hz = board.step_tick_hz();
        let cfg = Cfg::for_board(board);
        Self::with_config(Bus::new(), axis(SimAxis::new(tick_hz)), cfg)
    }

    /// The planner configured as `cfg` says, on an axis at its tick.
    pub fn with_planner(cfg: Cfg) -> Self {
        Self::with_config(Bus::new(), SimAxis::new(cfg.tick_hz()), cfg)
    }

    fn with_config(mut bus: Bus, axis: SimAxis, cfg: Cfg) -> Self {
        let tick_hz = cfg.tick_hz();
        bus.device.set_planner_config(cfg);
        let mut rig = Self {
            bus,
            sched: Box::new(StepSchedule::new()),
            axis,
            steps: Vec::new(),
            now_us: 0,
            period_us: CONTROL_PERIOD_US,
            tick_hz,
            encoder: None,
            in_parts: false,
        };
        rig.control();
        rig
    }

    /// The simulation host over this rig's device, axis, schedule and
    /// encoder (the loop the virtual drive and the fuzz harness run too).
    fn host(&mut self) -> SimHost<'_> {
        let host = SimHost::new(&mut self.bus.device, &mut self.axis, &self.sched);
        let host = if self.in_parts { host.in_parts() } else { host };
        match self.encoder.as_mut() {
            Some(e) => host.with_encoder(e, true),
            None => host,
        }
    }

    /// The glue's control step at the current time: the encoder read, the
    /// control call, then the idle step interrupt started.
    pub fn control(&mut self) {
        let now_us = self.now_us;
        self.host().control(now_us);
    }

    /// Sends a frame (hex) and returns the reply; the control loop runs
    /// right after it, as the glue does.
    pub fn send(&mut self, frame: &str) -> Option<Vec<u8>> {
        let reply = self.bus.send(&hex(frame));
        self.control();
        reply
    }

    /// Sends a seed frame that must be echoed (0x06) or answered with the
    /// standard 0x10 reply.
    pub fn send_ok(&mut self, frame: &str) {
        let f = hex(frame);
        let reply = self.bus.send(&f).expect("a reply");
        if f[1] == 0x06 {
            assert_eq!(reply, f, "echo of {frame}");
        } else {
            assert_eq!(reply[1], f[1], "reply to {frame}: {reply:02X?}");
            assert_eq!(&reply[..6], &f[..6], "reply to {frame}");
        }
        self.control();
    }

    pub fn write(&mut self, start: u16, words: &[u16]) {
        self.bus.write(start, words).expect("write accepted");
        self.control();
    }

    pub fn write_i32(&mut self, start: u16, v: i32) {
        self.write(start, &[(v >> 16) as u16, v as u16]);
    }

    /// Writes 0x6040 and runs the control loop once.
    pub fn controlword(&mut self, v: u16) {
        self.bus
            .write_single(0x6040, v)
            .expect("controlword accepted");
        self.control();
    }

    /// From operation enabled: position mode, 10 r/s, 100 r/s², quick stop
    /// 200 r/s² (PA10 = 10 000: 1e5 steps/s, 1e6 and 2e6 steps/s²), then
    /// latches `target` with a bit 4 edge (SPEC §8.4).
    pub fn start_position_move(&mut self, target: i32) {
        self.bus.write_single(0x6060, 1).expect("mode accepted");
        self.write_i32(0x6081, 100);
        self.write(0x6083, &[1000, 1000, 2000]);
        self.write_i32(0x607A, target);
        self.controlword(0x001F);
        self.controlword(0x000F);
    }

    /// Runs the control loop for `us`, stopping at every switch change to
    /// call it at that exact step, and calls it at the end.
    pub fn run_us(&mut self, us: u64) {
        let end = self.now_us + us;
        let mut steps = std::mem::take(&mut self.steps);
        self.host().control_at(end, |s| steps.push(s));
        self.steps = steps;
        self.now_us = end;
    }

    /// Runs until `done(rig)` holds (checked every control period), at most
    /// `max_us`; panics if it never does.
    pub fn run_until(&mut self, max_us: u64, mut done: impl FnMut(&mut Self) -> bool) {
        let end = self.now_us + max_us;
        while !done(self) {
            assert!(
                self.now_us < end,
                "condition not met within {max_us} µs (position {})",
                self.axis.position()
            );
            self.run_us(self.period_us);
        }
    }

    /// 0x6041 read over the bus.
    pub fn statusword(&mut self) -> u16 {
        self.bus.read(0x6041, 1).expect("statusword")[0]
    }

    /// 0x6064 read over the bus (word order 0).
    pub fn position(&mut self) -> i32 {
        let w = self.bus.read(0x6064, 2).expect("position");
        ((u32::from(w[0]) << 16) | u32::from(w[1])) as i32
    }

    /// 0x606C read over the bus (word order 0), r/min.
    pub fn velocity_rpm(&mut self) -> i32 {
        let w = self.bus.read(0x606C, 2).expect("velocity");
        ((u32::from(w[0]) << 16) | u32::from(w[1])) as i32
    }

    pub fn error_register(&mut self) -> u16 {
        self.bus.read(0x1001, 1).expect("error register")[0]
    }

    /// The motor has stopped and nothing is queued.
    pub fn at_rest(&self) -> bool {
        !self.axis.is_running() && self.sched.is_empty()
    }

    /// Step-rate (steps/s) of the interval ending at the first step that
    /// reached `position` in the log.
    pub fn speed_at(&self, position: i64) -> f64 {
        let i = self
            .steps
            .iter()
            .position(|s| s.position() == position)
            .expect("position reached");
        assert!(i > 0);
        let dt = self.steps[i]
            .exact()
            .wrapping_sub(self.steps[i - 1].exact()) as f64
            / Q;
        f64::from(self.tick_hz) / dt
    }
}
