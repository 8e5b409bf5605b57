//! Power state machine, modes and statusword (SPEC §8).
//!
//! The dispatcher calls the [`DriveLayer`] methods when the master writes;
//! they change the state and the mode's set-points at once (so that a read
//! right after a write shows the new state). Motion follows in
//! [`Drive::control`], which the glue calls with the time, the switch states
//! and the shared [`StepSchedule`] (at least every millisecond, and right
//! after a frame or a switch edge): it applies a pending stop-at-once, hands
//! goals to the [`Planner`], fills the schedule, runs homing, the limit
//! checks and the communication-loss timer.

pub mod io;

use heapless::Deque;

use crate::dictionary::{Config, DriveLayer, OdValues};
use crate::motion::planner::MAX_STEP_RATE;
use crate::motion::profile::isqrt;
use crate::motion::schedule::brake_rate;
use crate::motion::{
    Fill, Goal, Homing, HomingError, HomingMethod, HomingStep, Planner, PlannerConfig, Ramp,
    StepSchedule, SwitchEdges, Switches,
};
use crate::params::{DriveMonitor, Params};

/// Power states of SPEC §8.1 (CiA 402).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PowerState {
    NotReadyToSwitchOn,
    SwitchOnDisabled,
    ReadyToSwitchOn,
    SwitchedOn,
    OperationEnabled,
    QuickStopActive,
    FaultReactionActive,
    Fault,
}

impl PowerState {
    /// Statusword bits 0–3, 5, 6 (and 4, "voltage enabled"). Bit 5
    /// ("quick stop") is 0 only in quick stop active (SPEC §8.2); the §8.1
    /// patterns leave it open (`x`) in the other states where CiA 402 does.
    pub fn status_bits(self) -> u16 {
        match self {
            Self::NotReadyToSwitchOn => 0x0020,
            Self::SwitchOnDisabled => 0x0060,
            Self::ReadyToSwitchOn => 0x0021,
            Self::SwitchedOn => 0x0033,
            Self::OperationEnabled => 0x0037,
            Self::QuickStopActive => 0x0017,
            Self::FaultReactionActive => 0x002F,
            Self::Fault => 0x0028,
        }
    }

    /// Steps may run (the power stage is enabled and motion is allowed).
    fn moving_allowed(self) -> bool {
        matches!(
            self,
            Self::OperationEnabled | Self::QuickStopActive | Self::FaultReactionActive
        )
    }
}

/// The two drive outputs of SPEC §8.1.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Outputs {
    pub power_stage: bool,
    pub brake_released: bool,
}

/// Why the drive is in fault (error register bit, SPEC §8.7).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FaultCause {
    /// Both limit switches active at once: bit 0.
    BothLimits,
    /// No valid frame for PA20 ms while operation was enabled: bit 4.
    CommunicationLoss,
}

impl FaultCause {
    pub fn error_register_bit(self) -> u16 {
        match self {
            Self::BothLimits => 1 << 0,
            Self::CommunicationLoss => 1 << 4,
        }
    }
}

/// What the drive reports for the glue to log.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DriveEvent {
    /// The power state changed.
    State(PowerState),
    Fault(FaultCause),
    /// A limit switch stopped motion towards it (`cw` = the CW limit).
    LimitStop {
        cw: bool,
    },
    /// A commanded motion cannot run (statusword bit 7).
    MotionRefused,
    /// Homing found the origin at this raw step count.
    HomingAttained {
        origin: i32,
    },
    HomingDone,
    HomingFailed(HomingError),
    /// The step schedule ran dry while the motor was moving (the control
    /// loop was late by more than the planner's horizon).
    ScheduleUnderrun,
}

/// Controlword bits (SPEC §8.1, §8.4).
mod cw {
    pub const SWITCH_ON: u16 = 1 << 0;
    pub const ENABLE_VOLTAGE: u16 = 1 << 1;
    pub const QUICK_STOP: u16 = 1 << 2;
    pub const ENABLE_OPERATION: u16 = 1 << 3;
    pub const NEW_SET_POINT: u16 = 1 << 4;
    pub const CHANGE_IMMEDIATELY: u16 = 1 << 5;
    pub const RELATIVE: u16 = 1 << 6;
    pub const FAULT_RESET: u16 = 1 << 7;
    pub const HALT: u16 = 1 << 8;
    pub const CHANGE_ON_SET_POINT: u16 = 1 << 9;
}

/// Statusword bits beyond the state (SPEC §8.2).
mod sw {
    pub const WARNING: u16 = 1 << 7;
    pub const HALT: u16 = 1 << 8;
    pub const RUNNING: u16 = 1 << 9;
    pub const TARGET_REACHED: u16 = 1 << 10;
    pub const HOME_SWITCH: u16 = 1 << 11;
    pub const BIT12: u16 = 1 << 12;
    pub const BIT13: u16 = 1 << 13;
    pub const CW_LIMIT: u16 = 1 << 14;
    pub const CCW_LIMIT: u16 = 1 << 15;
}

const MODE_POSITION: i16 = 1;
const MODE_VELOCITY: i16 = 3;
const MODE_HOMING: i16 = 6;

/// Largest homing speed register value (SPEC §5, §8.6).
const HOMING_SPEED_MAX: u32 = 100_000;

/// One latched position set-point (SPEC §8.4).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct SetPoint {
    /// Target in user steps (0x6064's scale).
    target: i64,
    ramp: Ramp,
    /// Bit 9 when it was latched: the move before it does not stop.
    blend: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum HomingState {
    NotStarted,
    Interrupted,
    Searching(Homing),
    /// Origin found; moving to origin + 0x607C (raw target).
    Offset {
        target: i64,
    },
    Done,
    Failed,
}

/// The configuration the drive works with: a copy of the values the
/// master writes, and what PA10..PA20 mean in steps.
///
/// Kept current by [`Settings::update`] on every accepted write and every
/// control call. A write stores the OD values (a 40-byte copy); the derived
/// step figures are recomputed only when their PA registers changed, so a
/// frame that writes the profile values pays no 64-bit maths (issue 7).
#[derive(Clone, Debug, Default)]
struct Settings {
    od: OdValues,
    /// PA10 and PA12 as last seen (raw registers): the derived figures
    /// below are recomputed when they change.
    steps_per_rev_reg: u16,
    max_speed_rpm_reg: u16,
    steps_per_rev: u64,
    /// PA12 and the maximum step rate, 0.1 steps/s.
    max_velocity: u64,
    limit_enable: u16,
    comm_loss_ms: u16,
}

impl Settings {
    fn from(cfg: Config<'_>) -> Self {
        let mut s = Self {
            // not PA10's register: `update` derives the step figures
            steps_per_rev_reg: cfg.pa.steps_per_rev().wrapping_add(1),
            ..Self::default()
        };
        s.update(cfg);
        s
    }

    /// Takes the values of `cfg`; the step figures of PA10/PA12 only when
    /// those registers changed.
    fn update(&mut self, cfg: Config<'_>) {
        let pa: &Params = cfg.pa;
        self.od.clone_from(cfg.od);
        self.limit_enable = pa.limit_enable();
        self.comm_loss_ms = pa.comm_loss_ms();
        let (spr_reg, rpm_reg) = (pa.steps_per_rev(), pa.max_speed_rpm());
        if spr_reg != self.steps_per_rev_reg || rpm_reg != self.max_speed_rpm_reg {
            self.steps_per_rev_reg = spr_reg;
            self.max_speed_rpm_reg = rpm_reg;
            let spr = u64::from(spr_reg.max(1));
            self.steps_per_rev = spr;
            self.max_velocity = rpm_to_velocity(u64::from(rpm_reg), spr);
        }
    }

    /// 0.1 rev/s (or rev/s²) register → 0.1 steps/s (steps/s²).
    fn steps(&self, reg: u64) -> u64 {
        reg.saturating_mul(self.steps_per_rev)
    }

    /// The profile ramp of 0x6081/0x6083/0x6084, clamped (SPEC §8.4).
    fn profile_ramp(&self) -> Ramp {
        Ramp {
            velocity: self.steps(u64::from(self.od.profile_velocity.unsigned_abs())),
            accel: self.steps(u64::from(self.od.acceleration)),
            decel: self.steps(u64::from(self.od.deceleration)),
        }
        .clamped(self.max_velocity)
    }

    /// Homing ramp at 0x6099 (fast) or 0x609B (slow) with 0x609A, capped
    /// per method (SPEC §8.6).
    fn homing_ramp(&self, method: HomingMethod, slow: bool) -> Ramp {
        let reg = if slow {
            self.od.homing_zero_speed
        } else {
            self.od.homing_speed
        };
        let accel = self.steps(u64::from(self.od.homing_acceleration));
        let cap = rpm_to_velocity(u64::from(method.max_rpm()), self.steps_per_rev);
        Ramp {
            velocity: self.steps(u64::from(reg)),
            accel,
            decel: accel,
        }
        .clamped(self.max_velocity.min(cap))
    }

    fn decel(&self) -> u64 {
        self.steps(u64::from(self.od.deceleration))
    }

    fn quick_stop_decel(&self) -> u64 {
        self.steps(u64::from(self.od.quick_stop_deceleration))
    }

    fn cw_limit_enabled(&self) -> bool {
        self.limit_enable & 1 != 0
    }

    fn ccw_limit_enabled(&self) -> bool {
        self.limit_enable & 2 != 0
    }
}

/// r/min → 0.1 steps/s, capped at the maximum step rate.
fn rpm_to_velocity(rpm: u64, steps_per_rev: u64) -> u64 {
    (rpm * steps_per_rev / 6).min(u64::from(MAX_STEP_RATE) * 10)
}

/// The drive layer: state machine, modes and the motion it commands.
#[derive(Debug)]
pub struct Drive {
    state: PowerState,
    planner: Planner,
    s: Settings,
    controlword: u16,
    /// Mode in force (0x6061).
    mode: i16,
    halted: bool,
    warning: bool,
    error_register: u16,
    fault: Option<FaultCause>,
    /// In quick stop active, an enable came: return when at rest.
    enable_after_stop: bool,
    /// Stop step output at once at the next control call.
    flush: bool,
    /// Hand the planner a new goal at the next control call.
    replan: bool,
    /// Position mode: the set-point being run and the one-slot buffer.
    active: Option<SetPoint>,
    buffered: Option<SetPoint>,
    /// Base of relative set-points (user steps): the previous latched
    /// target; `None` after enabling, homing or a mode change, when the base
    /// is where the motor comes to rest ([`Drive::relative_base`]).
    last_target: Option<i64>,
    /// Moving towards an active limit was stopped.
    limit_stopping: bool,
    /// The step interrupt's limit brake has been seen and handled.
    limit_braked: bool,
    homing: HomingState,
    /// Raw step count − user position (homing zeroes the user position).
    offset: i64,
    // Last seen by control():
    raw_position: i64,
    velocity: i64,
    running: bool,
    ramping: bool,
    at_rest: bool,
    switches: Switches,
    now_us: u64,
    frame_seen: bool,
    last_frame_us: u64,
    events: Deque<DriveEvent, 8>,
}

impl Default for Drive {
    fn default() -> Self {
        Self::new()
    }
}

impl Drive {
    pub fn new() -> Self {
        Self::with_config(PlannerConfig::default())
    }

    /// With the step timer's frequency and the planner horizon the glue
    /// chose (see [`PlannerConfig`]).
    pub fn with_config(cfg: PlannerConfig) -> Self {
        let od = OdValues::default();
        let pa = Params::defaults();
        Self {
            // SPEC §8.1: after power-up the drive passes to switch on
            // disabled by itself.
            state: PowerState::SwitchOnDisabled,
            planner: Planner::new(cfg),
            s: Settings::from(Config { od: &od, pa: &pa }),
            controlword: 0,
            mode: 0,
            halted: false,
            warning: false,
            error_register: 0,
            fault: None,
            enable_after_stop: false,
            flush: false,
            replan: false,
            active: None,
            buffered: None,
            last_target: None,
            limit_stopping: false,
            limit_braked: false,
            homing: HomingState::NotStarted,
            offset: 0,
            raw_position: 0,
            velocity: 0,
            running: false,
            ramping: false,
            at_rest: true,
            switches: Switches::default(),
            now_us: 0,
            frame_seen: true,
            last_frame_us: 0,
            events: Deque::new(),
        }
    }

    /// The planner's timing (step timer frequency, horizon); at start-up,
    /// before the first control call (it forgets what was planned).
    pub fn set_planner_config(&mut self, cfg: PlannerConfig) {
        self.planner = Planner::new(cfg);
    }

    pub fn planner(&self) -> &Planner {
        &self.planner
    }

    pub fn state(&self) -> PowerState {
        self.state
    }

    /// ENABLE and BRAKE as SPEC §8.1 wants them now.
    pub fn outputs(&self) -> Outputs {
        use PowerState::*;
        Outputs {
            brake_released: matches!(
                self.state,
                SwitchedOn | OperationEnabled | QuickStopActive | FaultReactionActive
            ),
            power_stage: matches!(
                self.state,
                OperationEnabled | QuickStopActive | FaultReactionActive
            ),
        }
    }

    /// A valid frame for this drive (or a broadcast) arrived: restarts the
    /// communication-loss timer (PA20) at the next control call.
    pub fn frame_received(&mut self) {
        self.frame_seen = true;
    }

    /// The oldest event not yet taken.
    pub fn take_event(&mut self) -> Option<DriveEvent> {
        self.events.pop_front()
    }

    fn event(&mut self, e: DriveEvent) {
        // drop the newest when full: the glue drains every control call
        let _ = self.events.push_back(e);
    }

    fn set_state(&mut self, state: PowerState) {
        if state != self.state {
            self.state = state;
            self.event(DriveEvent::State(state));
        }
    }

    fn user_position(&self) -> i64 {
        self.raw_position - self.offset
    }

    /// Base of a relative set-point (SPEC §8.4 bit 6: "relative to the
    /// previous target"). Without a previous target in this mode (after
    /// enabling, homing or a mode change) it is the position at which the
    /// motor comes to rest: where it is when at rest, or the end of the
    /// stop in progress (the one a mode change started), so a set-point
    /// latched during that stop counts from the same place as one latched
    /// after it. `None` while a stop at once is being carried out (the
    /// rest position is known one step later): bit 12 reads 0 then.
    fn relative_base(&self) -> Option<i64> {
        self.last_target
            .or_else(|| Some(self.planner.rest_position()? - self.offset))
    }

    /// Statusword bit 12 in position mode (SPEC §8.4): the one-slot buffer
    /// is free and the base of a relative set-point is known.
    fn set_point_slot_free(&self) -> bool {
        self.buffered.is_none() && self.relative_base().is_some()
    }

    /// The control loop (see the module docs). `switches` are the logical
    /// states (after PA13, e.g. from [`io::SwitchInputs::read`]) sampled now;
    /// `edges` where they began, if the glue latched that (homing origin,
    /// SPEC §8.6), else [`SwitchEdges::default`].
    pub fn control(
        &mut self,
        now_us: u64,
        switches: Switches,
        edges: SwitchEdges,
        sched: &StepSchedule,
        cfg: Config<'_>,
    ) {
        self.s.update(cfg);
        self.now_us = now_us;
        let sw = Switches {
            cw_limit: switches.cw_limit && self.s.cw_limit_enabled(),
            ccw_limit: switches.ccw_limit && self.s.ccw_limit_enabled(),
            home: switches.home,
        };
        self.switches = sw;
        self.raw_position = self.planner.actual_position(sched);
        if self.frame_seen {
            self.frame_seen = false;
            self.last_frame_us = now_us;
        }

        self.limit_brake(sched);

        // §8.7 faults
        if self.fault.is_none() {
            if sw.cw_limit && sw.ccw_limit {
                self.enter_fault(FaultCause::BothLimits);
            } else if self.state == PowerState::OperationEnabled
                && self.s.comm_loss_ms > 0
                && now_us.saturating_sub(self.last_frame_us)
                    >= u64::from(self.s.comm_loss_ms) * 1000
            {
                self.enter_fault(FaultCause::CommunicationLoss);
            }
        }

        if self.state == PowerState::OperationEnabled {
            if self.mode == MODE_HOMING {
                // A disabled limit's edge is never used: the limit never
                // meets a condition (Homing::update).
                self.run_homing(edges);
            } else {
                self.check_limits();
            }
        }

        if self.flush {
            self.flush = false;
            self.planner.stop_at_once(sched);
        }
        if self.replan {
            self.replan = false;
            self.apply_goal(sched);
        }
        let underruns = self.planner.underruns;
        for _ in 0..8 {
            match self.planner.fill(now_us, sched) {
                Fill::Ended => self.motion_ended(),
                _ => break,
            }
        }
        if self.planner.underruns != underruns {
            self.event(DriveEvent::ScheduleUnderrun);
        }

        self.raw_position = self.planner.actual_position(sched);
        self.velocity = self.planner.actual_velocity(sched);
        self.running = sched.is_running() || !sched.is_empty();
        self.ramping = self.planner.ramping(sched);
        self.at_rest = self.planner.at_rest(sched);
        self.after_motion();
    }

    /// State changes that wait for the motor to be at rest.
    fn after_motion(&mut self) {
        if !self.at_rest {
            return;
        }
        match self.state {
            PowerState::FaultReactionActive => self.set_state(PowerState::Fault),
            PowerState::QuickStopActive if self.enable_after_stop => {
                self.enable_after_stop = false;
                self.set_state(PowerState::OperationEnabled);
                self.replan = true;
            }
            _ => {}
        }
        if let Some(sp) = self.active {
            if self.buffered.is_none() && !self.halted && self.user_position() == sp.target {
                self.active = None; // target reached
            }
        }
        if let HomingState::Offset { target } = self.homing {
            if self.raw_position == target && !self.halted {
                // SPEC §8.6: then the actual position becomes 0
                self.offset = self.raw_position;
                self.last_target = None;
                self.homing = HomingState::Done;
                self.event(DriveEvent::HomingDone);
            }
        }
    }

    fn enter_fault(&mut self, cause: FaultCause) {
        self.fault = Some(cause);
        self.error_register |= cause.error_register_bit();
        self.event(DriveEvent::Fault(cause));
        if matches!(
            self.homing,
            HomingState::Searching(_) | HomingState::Offset { .. }
        ) {
            self.homing = HomingState::Failed;
            self.event(DriveEvent::HomingFailed(HomingError::Fault));
        }
        self.active = None;
        self.buffered = None;
        if self.state.moving_allowed() {
            // Fault reaction: the quick stop ramp, or at once without one.
            self.set_state(PowerState::FaultReactionActive);
            self.stop_with(self.s.quick_stop_decel());
        } else {
            self.set_state(PowerState::Fault);
            self.flush = true;
        }
    }

    /// Stop with `decel`, or at once when it is 0.
    fn stop_with(&mut self, decel: u64) {
        if decel == 0 {
            self.flush = true;
            self.replan = false;
        } else {
            self.planner.set_goal(Goal::Stop { decel });
            self.replan = false;
        }
    }

    /// §8.7: an active limit blocks motion towards it with 0x6085.
    fn check_limits(&mut self) {
        let heading = self.planner.heading();
        let blocked_cw = self.switches.cw_limit && heading == Some(false);
        let blocked_ccw = self.switches.ccw_limit && heading == Some(true);
        if blocked_cw || blocked_ccw {
            if !self.limit_stopping {
                self.limit_stop(blocked_cw);
                self.stop_with(self.s.quick_stop_decel());
            }
        } else if heading.is_none() {
            self.limit_stopping = false;
        }
    }

    /// Motion towards a limit is being stopped: the set-points go, the
    /// warning and the event are raised (§8.7).
    fn limit_stop(&mut self, cw: bool) {
        self.limit_stopping = true;
        self.warning = true;
        self.active = None;
        self.buffered = None;
        self.event(DriveEvent::LimitStop { cw });
    }

    /// Issue 6 / §8.7: the step interrupt brakes at a limit with 0x6085 on
    /// its own (`motion::schedule`, "Limit brake"). Armed outside homing
    /// (§8.6: there the sequencer decides at the limits); once it has
    /// engaged, the drive reports the stop and the planner forgets its plan
    /// and takes the position back when the brake is over.
    fn limit_brake(&mut self, sched: &StepSchedule) {
        let tick_hz = self.planner.config().tick_hz;
        sched.set_brake_rate(
            (self.mode != MODE_HOMING).then(|| brake_rate(self.s.quick_stop_decel(), tick_hz)),
        );
        match sched.limit_brake() {
            Some(b) if !self.limit_braked => {
                self.limit_braked = true;
                // the control loop may have seen the limit first (a call at
                // the edge step, before the interrupt's next step): one stop
                if !self.limit_stopping {
                    self.limit_stop(!b.forward);
                }
                self.planner.stop_at_once(sched);
            }
            Some(_) => {}
            None => self.limit_braked = false,
        }
    }

    /// The goal the current mode asks for, handed to the planner.
    fn apply_goal(&mut self, sched: &StepSchedule) {
        if self.state != PowerState::OperationEnabled {
            return;
        }
        if self.halted {
            // §8.1: halt decelerates with 0x6084 in every mode (at once
            // when it is 0) and holds; the mode's goal comes back on resume.
            match self.s.decel() {
                0 => self.planner.stop_at_once(sched),
                decel => {
                    self.planner.set_goal(Goal::Stop { decel });
                }
            }
            return;
        }
        let goal = match self.mode {
            MODE_POSITION => self.active.map(|sp| self.move_goal(sp)),
            MODE_VELOCITY => Some(self.velocity_goal()),
            MODE_HOMING => self.homing_goal(),
            _ => None,
        };
        if let Some(goal) = goal {
            if !self.planner.set_goal(goal) {
                self.warning = true;
                self.event(DriveEvent::MotionRefused);
            }
        }
    }

    fn move_goal(&self, sp: SetPoint) -> Goal {
        let end_velocity = match self.buffered {
            Some(next) if next.blend => blend_velocity(sp, next, self.planner.heading()),
            _ => 0,
        };
        Goal::Move {
            target: sp.target + self.offset,
            ramp: sp.ramp,
            end_velocity,
        }
    }

    fn velocity_goal(&mut self) -> Goal {
        let ramp = self.s.profile_ramp();
        let v = self.s.od.profile_velocity;
        let forward = v > 0;
        let blocked = (forward && self.switches.ccw_limit) || (!forward && self.switches.cw_limit);
        if v == 0 || blocked || !ramp.runnable() {
            if v != 0 && (blocked || !ramp.runnable()) {
                self.warning = true;
            }
            let decel = if ramp.decel > 0 {
                ramp.decel
            } else {
                self.s.quick_stop_decel()
            };
            return Goal::Stop { decel };
        }
        self.warning = false;
        Goal::Run { forward, ramp }
    }

    fn homing_goal(&self) -> Option<Goal> {
        let accel = self.s.steps(u64::from(self.s.od.homing_acceleration));
        match self.homing {
            HomingState::Searching(h) => {
                let p = h.phase();
                Some(Goal::Run {
                    forward: !p.left,
                    ramp: self.s.homing_ramp(h.method(), p.slow),
                })
            }
            HomingState::Offset { target } => {
                let method = HomingMethod::from_register(self.s.od.homing_method)?;
                Some(Goal::Move {
                    target,
                    ramp: self.s.homing_ramp(method, true),
                    end_velocity: 0,
                })
            }
            _ => Some(Goal::Stop { decel: accel }),
        }
    }

    /// The planner finished the last goal's motion (it may still be
    /// stepping out): position mode runs the buffered set-point now, so a
    /// blended move continues without a stop (SPEC §8.4).
    fn motion_ended(&mut self) {
        if self.mode == MODE_POSITION && !self.halted && self.state == PowerState::OperationEnabled
        {
            if let Some(next) = self.buffered.take() {
                self.active = Some(next);
                let goal = self.move_goal(next);
                self.planner.set_goal(goal);
            }
        }
    }

    fn run_homing(&mut self, edges: SwitchEdges) {
        let HomingState::Searching(mut h) = self.homing else {
            return;
        };
        // Also while halted: an edge passed while braking is still the
        // edge (SPEC §8.6: the origin is where it was seen); the next
        // phase's motion waits for the resume (apply_goal).
        match h.update(self.switches, edges, self.raw_position) {
            HomingStep::Continue => {}
            HomingStep::NextPhase => {
                self.homing = HomingState::Searching(h);
                self.replan = true;
            }
            HomingStep::Origin(origin) => {
                let target = origin + i64::from(self.s.od.home_offset);
                self.homing = HomingState::Offset { target };
                self.event(DriveEvent::HomingAttained {
                    origin: origin as i32,
                });
                self.replan = true;
            }
            HomingStep::Failed(e) => {
                self.homing = HomingState::Failed;
                self.event(DriveEvent::HomingFailed(e));
                let accel = self.s.steps(u64::from(self.s.od.homing_acceleration));
                self.stop_with(accel);
            }
        }
        if let HomingState::Searching(_) = self.homing {
            self.homing = HomingState::Searching(h);
        }
    }

    fn start_homing(&mut self) {
        let od = &self.s.od;
        let error = match HomingMethod::from_register(od.homing_method) {
            None => Some(HomingError::NoMethod),
            Some(_)
                if od.homing_speed == 0
                    || od.homing_speed > HOMING_SPEED_MAX
                    || od.homing_zero_speed == 0
                    || od.homing_zero_speed > HOMING_SPEED_MAX
                    || od.homing_acceleration == 0 =>
            {
                Some(HomingError::BadSpeed)
            }
            Some(method) => {
                self.homing = HomingState::Searching(Homing::start(method, self.switches));
                self.replan = true;
                None
            }
        };
        if let Some(e) = error {
            self.homing = HomingState::Failed;
            self.event(DriveEvent::HomingFailed(e));
        }
    }

    /// Position mode, rising edge of bit 4 (SPEC §8.4).
    fn latch_set_point(&mut self, controlword: u16) {
        let Some(base) = self.relative_base().filter(|_| self.set_point_slot_free()) else {
            return; // bit 12 = 0: ignored
        };
        let od = &self.s.od;
        let target = if controlword & cw::RELATIVE != 0 {
            base + i64::from(od.target_position)
        } else {
            i64::from(od.target_position)
        };
        let ramp = self.s.profile_ramp();
        let current = self.active.map_or(self.user_position(), |a| a.target);
        let towards_limit = (target < current && self.switches.cw_limit)
            || (target > current && self.switches.ccw_limit);
        if i32::try_from(target).is_err() || !ramp.runnable() || towards_limit {
            self.warning = true;
            self.event(DriveEvent::MotionRefused);
            return;
        }
        self.warning = false;
        self.last_target = Some(target);
        let sp = SetPoint {
            target,
            ramp,
            blend: controlword & cw::CHANGE_ON_SET_POINT != 0,
        };
        if controlword & cw::CHANGE_IMMEDIATELY != 0 || self.active.is_none() {
            self.active = Some(sp);
        } else {
            self.buffered = Some(sp);
        }
        self.replan = true;
    }

    /// Forgets the position set-points; a homing run in progress becomes
    /// "interrupted" (status 001).
    fn drop_set_points(&mut self) {
        self.active = None;
        self.buffered = None;
        if matches!(
            self.homing,
            HomingState::Searching(_) | HomingState::Offset { .. }
        ) {
            self.homing = HomingState::Interrupted;
        }
    }

    /// Leaves the motion states: stop output at once, forget set-points
    /// (SPEC §8.1).
    fn abort_motion(&mut self) {
        self.flush = true;
        self.replan = false;
        self.enable_after_stop = false;
        self.drop_set_points();
    }

    fn quick_stop(&mut self) {
        self.set_state(PowerState::QuickStopActive);
        self.drop_set_points();
        let decel = match self.s.od.quick_stop_option {
            1 => self.s.decel(),
            2 => self.s.quick_stop_decel(),
            _ => 0, // 0, 3..=32767: at once
        };
        self.stop_with(decel);
    }

    /// Statusword bits 10, 12 and 13 for the mode shown in 0x6061 (SPEC
    /// §8.2, §8.4–§8.6), in every power state: outside operation enabled
    /// the mode has no set-point and no search running, so the bits tell
    /// the same story as at rest in operation enabled (position: slot free,
    /// target reached once at rest; velocity: speed 0 once at rest; homing:
    /// 001 not started / interrupted, and done or error persist).
    fn mode_bits(&self) -> u16 {
        let at_rest = self.at_rest;
        match self.mode {
            MODE_POSITION => {
                let mut b = 0;
                if self.set_point_slot_free() {
                    b |= sw::BIT12;
                }
                let reached = if self.halted {
                    at_rest
                } else {
                    self.active.is_none() && self.buffered.is_none() && at_rest
                };
                if reached {
                    b |= sw::TARGET_REACHED;
                }
                b
            }
            MODE_VELOCITY => {
                let mut b = 0;
                if at_rest {
                    b |= sw::BIT12;
                }
                if self.ramping {
                    b |= sw::BIT13;
                }
                let target = if self.halted || self.state != PowerState::OperationEnabled {
                    0
                } else {
                    i64::from(self.s.od.profile_velocity)
                };
                let reached = if target == 0 {
                    at_rest
                } else {
                    self.running && !self.ramping && (self.velocity > 0) == (target > 0)
                };
                if reached {
                    b |= sw::TARGET_REACHED;
                }
                b
            }
            MODE_HOMING => match self.homing {
                HomingState::NotStarted | HomingState::Interrupted => sw::TARGET_REACHED,
                HomingState::Searching(_) => {
                    if self.halted && at_rest {
                        sw::TARGET_REACHED
                    } else {
                        0
                    }
                }
                HomingState::Offset { .. } => sw::BIT12,
                HomingState::Done => sw::BIT12 | sw::TARGET_REACHED,
                HomingState::Failed => {
                    if at_rest {
                        sw::BIT13 | sw::TARGET_REACHED
                    } else {
                        sw::BIT13
                    }
                }
            },
            _ => 0,
        }
    }
}

/// Speed at which a blended move passes its target (SPEC §8.4 bit 9): the
/// slower of the two moves' speeds, and no faster than the next move can
/// stop from within its distance; 0 if the next move turns back
/// (`heading`: the direction the motor is going).
fn blend_velocity(sp: SetPoint, next: SetPoint, heading: Option<bool>) -> u64 {
    let dist = next.target - sp.target;
    if dist == 0 || heading != Some(dist > 0) {
        return 0;
    }
    let v = sp.ramp.velocity.min(next.ramp.velocity);
    // v² ≤ 2·d·s in 0.1 units: V² ≤ 20·D·s
    let limit = isqrt(20 * u128::from(next.ramp.decel) * u128::from(dist.unsigned_abs()));
    v.min(limit.min(u128::from(u64::MAX)) as u64)
}

impl DriveLayer for Drive {
    fn statusword(&self) -> u16 {
        let mut w = self.state.status_bits();
        if self.warning {
            w |= sw::WARNING;
        }
        if self.halted && self.state == PowerState::OperationEnabled {
            w |= sw::HALT;
        }
        if self.running {
            w |= sw::RUNNING;
        }
        w |= self.mode_bits();
        if self.switches.home {
            w |= sw::HOME_SWITCH;
        }
        if self.switches.cw_limit {
            w |= sw::CW_LIMIT;
        }
        if self.switches.ccw_limit {
            w |= sw::CCW_LIMIT;
        }
        w
    }

    fn mode_display(&self) -> i16 {
        self.mode
    }

    fn actual_position(&self) -> i32 {
        self.user_position() as i32
    }

    fn actual_velocity_rpm(&self) -> i32 {
        (self.velocity * 6 / self.s.steps_per_rev as i64) as i32
    }

    fn error_register(&self) -> u16 {
        self.error_register
    }

    fn monitor(&self) -> DriveMonitor {
        let spr = self.s.steps_per_rev as i64;
        let command = self
            .active
            .map(|a| a.target)
            .or(self.last_target)
            .unwrap_or(self.user_position());
        let speed_command = match self.mode {
            MODE_VELOCITY => i64::from(self.s.od.profile_velocity) * 60 / 10,
            _ => self.active.map_or(0, |a| a.ramp.velocity as i64 * 6 / spr),
        };
        let out = self.outputs();
        DriveMonitor {
            command_position: command as i32,
            step_rate_steps_per_s: (self.velocity / 10) as i32,
            speed_command_rpm: speed_command as i32,
            inputs: u16::from(self.switches.cw_limit)
                | u16::from(self.switches.ccw_limit) << 1
                | u16::from(self.switches.home) << 2,
            outputs: u16::from(out.power_stage) | u16::from(out.brake_released) << 1,
        }
    }

    fn values_written(&mut self, cfg: Config<'_>) {
        self.s.update(cfg);
        // SPEC §8.5: writing 0x6081 while running ramps to the new speed
        if self.mode == MODE_VELOCITY && self.state == PowerState::OperationEnabled {
            self.replan = true;
        }
    }

    // `values_written` ran just before with the same values (the
    // dispatcher's order, `DriveLayer`): `self.s` is current.
    fn mode_written(&mut self, mode: i16, _cfg: Config<'_>) {
        if mode == self.mode {
            return;
        }
        // A mode change stops what the old mode was doing with 0x6084 (at
        // once if 0); a new position-mode set-point counts from where that
        // stop ends (relative_base). Into velocity mode the new run takes
        // over from the current velocity instead.
        self.drop_set_points();
        self.mode = mode;
        self.last_target = None;
        if self.state == PowerState::OperationEnabled {
            let decel = self.s.decel();
            self.stop_with(decel);
            self.replan = mode == MODE_VELOCITY;
        }
    }

    // As for `mode_written`: `self.s` is current.
    fn controlword_written(&mut self, controlword: u16, _cfg: Config<'_>) {
        use PowerState::*;
        let prev = self.controlword;
        self.controlword = controlword;
        let rising = |bit: u16| controlword & bit != 0 && prev & bit == 0;

        match self.state {
            Fault => {
                // §8.1: fault reset on the rising edge of bit 7, only if the
                // cause is gone (a frame arrived: communication is back).
                let cause_gone = match self.fault {
                    Some(FaultCause::BothLimits) => {
                        !(self.switches.cw_limit && self.switches.ccw_limit)
                    }
                    _ => true,
                };
                if rising(cw::FAULT_RESET) && cause_gone {
                    self.fault = None;
                    self.error_register = 0;
                    self.warning = false;
                    self.set_state(SwitchOnDisabled);
                }
                return;
            }
            FaultReactionActive => return,
            _ => {}
        }

        let (on, voltage, qs, enable) = (
            controlword & cw::SWITCH_ON != 0,
            controlword & cw::ENABLE_VOLTAGE != 0,
            controlword & cw::QUICK_STOP != 0,
            controlword & cw::ENABLE_OPERATION != 0,
        );
        let was = self.state;
        let next = if !voltage {
            if on {
                ReadyToSwitchOn
            } else {
                SwitchOnDisabled
            }
        } else if !qs {
            match was {
                OperationEnabled | QuickStopActive => QuickStopActive,
                _ if on => SwitchedOn,
                _ => SwitchOnDisabled,
            }
        } else if !on {
            ReadyToSwitchOn
        } else if !enable {
            SwitchedOn
        } else {
            OperationEnabled
        };

        match (was, next) {
            (OperationEnabled, QuickStopActive) => {
                self.quick_stop();
                return;
            }
            (QuickStopActive, OperationEnabled) => {
                // §8.1: back once the stop has finished (after_motion)
                self.enable_after_stop = true;
                self.halted = controlword & cw::HALT != 0;
                return;
            }
            (QuickStopActive, QuickStopActive) => return,
            (OperationEnabled | QuickStopActive, _) if next != OperationEnabled => {
                self.abort_motion();
            }
            _ => {}
        }
        self.set_state(next);
        if next != OperationEnabled {
            self.halted = false;
            return;
        }
        if was != OperationEnabled {
            self.frame_seen = true;
            self.last_target = None;
        }

        // Operation enabled: halt and the mode bits.
        let halted = controlword & cw::HALT != 0;
        if halted != self.halted || was != OperationEnabled {
            self.halted = halted;
            self.replan = true;
        }
        match self.mode {
            MODE_POSITION if rising(cw::NEW_SET_POINT) => self.latch_set_point(controlword),
            MODE_HOMING if rising(cw::NEW_SET_POINT) => self.start_homing(),
            _ => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_follow_every_pa10_and_pa12_change() {
        // SPEC §7 PA10 (steps/rev) and PA12 (max speed) are derived only
        // when they change (Settings::update); each change must show.
        let od = OdValues {
            acceleration: 7,
            ..OdValues::default()
        };
        let mut pa = Params::defaults();
        let mut s = Settings::from(Config { od: &od, pa: &pa });
        for (spr, rpm) in [
            (400, 3000),
            (400, 100),
            (0, 100),
            (12_800, 100),
            (12_800, 3000),
        ] {
            pa.set_unchecked(10, spr);
            pa.set_unchecked(12, rpm);
            s.update(Config { od: &od, pa: &pa });
            let spr = u64::from(spr.max(1));
            assert_eq!(s.steps_per_rev, spr);
            let v = (u64::from(rpm) * spr / 6).min(u64::from(MAX_STEP_RATE) * 10);
            assert_eq!(s.max_velocity, v, "PA10 {spr} PA12 {rpm}");
            assert_eq!(s.od, od);
        }
    }
}
