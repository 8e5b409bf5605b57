//! Motion test harness: a [`Planner`] (or a whole `Device`) driven by a
//! control loop over a [`SimAxis`], recording every step, and the checks of
//! issue 3's exactness bounds.
#![allow(dead_code)]

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
}

impl PlannerRun {
    pub fn new(tick_hz: u32, period_us: u64) -> Self {
        let cfg = PlannerConfig {
            tick_hz,
            horizon_us: (2 * period_us + 1000) as u32,
            max_segment_us: 1000,
        };
        Self {
            sched: Box::new(StepSchedule::new()),
            planner: Planner::new(cfg),
            axis: SimAxis::new(tick_hz),
            steps: Vec::new(),
            now_us: 0,
            period_us,
            goals: Default::default(),
        }
    }

    /// One control call at `now_us`: fill, handing over queued goals when
    /// a motion ends, then start the interrupt.
    pub fn control(&mut self) {
        for _ in 0..16 {
            match self.planner.fill(self.now_us, &self.sched) {
                Fill::Ended => {
                    if let Some(g) = self.goals.pop_front() {
                        assert!(self.planner.set_goal(g));
                    }
                }
                _ => break,
            }
        }
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
            let dt = w[1].exact.wrapping_sub(w[0].exact) as f64 / Q / f64::from(tick_hz);
            let t = w[0].exact as f64 / Q / f64::from(tick_hz) + dt / 2.0;
            let v = if w[1].forward { 1.0 / dt } else { -1.0 / dt };
            (t, v)
        })
        .collect()
}

/// Checks issue 3's velocity and acceleration bounds and the "direction
/// changes only at rest" rule on the exact schedule times:
/// |v| ≤ v_max·1.005, and after the first 10 steps of each run from rest
/// the acceleration between two intervals ≤ a_max·1.02.
pub fn check_dynamics(steps: &[StepRecord], tick_hz: u32, v_max: f64, a_max: f64) {
    let f = f64::from(tick_hz);
    for (i, w) in steps.windows(2).enumerate() {
        assert!(w[1].tick > w[0].tick, "interval not positive at step {i}");
        let dt = w[1].exact.wrapping_sub(w[0].exact) as f64 / Q / f;
        let v = 1.0 / dt;
        assert!(v <= v_max * 1.005 + 1e-9, "step {i}: {v} steps/s > {v_max}");
        if w[1].forward != w[0].forward {
            // the last step before the reversal ends at rest: it takes at
            // least sqrt(2 / a_max)
            let min_dt = (2.0 / a_max).sqrt() * 0.98;
            assert!(
                dt >= min_dt,
                "reversal at step {i} at speed: dt {dt} < {min_dt}"
            );
            if i > 0 {
                let before = w[0].exact.wrapping_sub(steps[i - 1].exact) as f64 / Q / f;
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
            let dt = w[1].exact.wrapping_sub(w[0].exact) as f64 / Q / f;
            if w[1].forward {
                1.0 / dt
            } else {
                -1.0 / dt
            }
        })
        .collect();
    let mut run_start = 0usize;
    for i in 1..vel.len() {
        if steps[i + 1].forward != steps[i].forward {
            run_start = i + 1;
            continue;
        }
        // interval i-1 is steps[i-1]→steps[i], interval i is steps[i]→steps[i+1]
        if i < run_start + 10 {
            continue;
        }
        let dt0 = steps[i].exact.wrapping_sub(steps[i - 1].exact) as f64 / Q / f;
        let dt1 = steps[i + 1].exact.wrapping_sub(steps[i].exact) as f64 / Q / f;
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

/// Issue 3's step time bound against `ideal(k)` (s from `t0_tick`):
/// |t − ideal| ≤ min(1 µs, 5 % of the ideal local interval).
pub fn check_times(steps: &[StepRecord], tick_hz: u32, t0_tick: u64, ideal: impl Fn(f64) -> f64) {
    let f = f64::from(tick_hz);
    let mut prev = 0.0;
    for (i, s) in steps.iter().enumerate() {
        let k = (i + 1) as f64;
        let want = ideal(k);
        let got = (s.tick - t0_tick) as f64 / f;
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
}

impl Rig {
    pub fn new(axis: SimAxis) -> Self {
        Self::with_bus(Bus::new(), axis)
    }

    pub fn with_bus(mut bus: Bus, axis: SimAxis) -> Self {
        let tick_hz = 10_000_000;
        bus.device.drive.set_planner_config(Cfg {
            tick_hz,
            horizon_us: 3000,
            max_segment_us: 1000,
        });
        let mut rig = Self {
            bus,
            sched: Box::new(StepSchedule::new()),
            axis,
            steps: Vec::new(),
            now_us: 0,
            period_us: 1000,
            tick_hz,
        };
        rig.control();
        rig
    }

    /// The glue's control step at the current time, then start the idle
    /// step interrupt.
    pub fn control(&mut self) {
        let sw = self.axis.switches();
        self.bus.device.control(self.now_us, sw, &self.sched);
        self.axis.kick(&self.sched);
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

    /// Runs the control loop for `us`, stopping at every switch change to
    /// call it at that exact step.
    pub fn run_us(&mut self, us: u64) {
        let end = self.now_us + us;
        while self.now_us < end {
            let next = (self.now_us + self.period_us).min(end);
            let until = self.axis.us_to_ticks(next);
            let steps = &mut self.steps;
            if self.axis.run_until(&self.sched, until, |s| steps.push(s)) == RunStop::SwitchChanged
            {
                self.now_us = self.axis.now_us().max(self.now_us);
            } else {
                self.now_us = next;
            }
            self.control();
        }
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
            .position(|s| s.position == position)
            .expect("position reached");
        assert!(i > 0);
        let dt = self.steps[i].exact.wrapping_sub(self.steps[i - 1].exact) as f64 / Q;
        f64::from(self.tick_hz) / dt
    }
}
