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

mod brake;
mod feedback;
mod homing;
pub mod io;
mod limits;
mod position;
mod settings;
mod states;
mod velocity;

use heapless::Deque;

use crate::arith::div_i64;
use crate::dictionary::{Config, DriveLayer, OdValues};
use crate::motion::{
    Fill, Goal, HomingError, Planner, PlannerConfig, StepSchedule, StepSink, SwitchEdges, Switches,
};
use crate::params::{DriveMonitor, Params};
use brake::BrakeSequence;
use feedback::Feedback;
use homing::HomingState;
use position::SetPoint;
use settings::Settings;

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
    power_stage: bool,
    brake_released: bool,
}

impl Outputs {
    #[inline]
    pub const fn new(power_stage: bool, brake_released: bool) -> Self {
        Self {
            power_stage,
            brake_released,
        }
    }

    #[inline]
    pub const fn power_stage(&self) -> bool {
        self.power_stage
    }

    #[inline]
    pub const fn brake_released(&self) -> bool {
        self.brake_released
    }
}

/// Why the drive is in fault (error register bit, SPEC §8.7).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FaultCause {
    /// Both limit switches active at once: bit 0.
    BothLimits,
    /// No valid frame for PA20 ms while operation was enabled: bit 4.
    CommunicationLoss,
    /// The following error stayed above 0x6065 for longer than 0x6066
    /// (SPEC §8.8): bit 5.
    FollowingError,
}

impl FaultCause {
    pub fn error_register_bit(self) -> u16 {
        match self {
            Self::BothLimits => 1 << 0,
            Self::CommunicationLoss => 1 << 4,
            Self::FollowingError => 1 << 5,
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
    /// The last control call's fill paused at its budget
    /// ([`Drive::top_up`]).
    fill_paused: bool,
    frame_seen: bool,
    last_frame_us: u64,
    /// Encoder, measured position and following-error check (SPEC §8.8).
    feedback: Feedback,
    /// When ENABLE and BRAKE follow the state (PA22 / PA23).
    brake: BrakeSequence,
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
            s: Settings::from(Config::new(&od, &pa), cfg),
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
            fill_paused: false,
            frame_seen: true,
            last_frame_us: 0,
            feedback: Feedback::default(),
            brake: BrakeSequence::default(),
            events: Deque::new(),
        }
    }

    /// The planner's timing and limits (step timer frequency, horizon, the
    /// board's step rate and acceleration); at start-up,
    /// before the first control call (it forgets what was planned).
    pub fn set_planner_config(&mut self, cfg: PlannerConfig) {
        self.planner = Planner::new(cfg);
        self.s.set_planner_config(cfg);
    }

    pub fn planner(&self) -> &Planner {
        &self.planner
    }

    pub fn state(&self) -> PowerState {
        self.state
    }

    /// ENABLE and BRAKE now: SPEC §8.1's for the state, sequenced by
    /// PA22 / PA23 when either is set (`brake.rs`, docs/drive.md).
    pub fn outputs(&self) -> Outputs {
        self.brake
            .outputs(self.state_outputs(), self.now_us, self.s.brake_times)
    }

    /// The power stage is on but the brake not yet released (PA22): motion
    /// waits.
    fn brake_holding(&self) -> bool {
        self.brake
            .holding(self.state_outputs(), self.now_us, self.s.brake_times)
    }

    fn update_brake(&mut self) {
        let power = self.state_outputs().power_stage;
        self.brake.update(power, self.now_us, self.s.brake_times);
    }

    /// ENABLE and BRAKE as SPEC §8.1 gives them for the state.
    fn state_outputs(&self) -> Outputs {
        use PowerState::*;
        Outputs::new(
            matches!(
                self.state,
                OperationEnabled | QuickStopActive | FaultReactionActive
            ),
            matches!(
                self.state,
                SwitchedOn | OperationEnabled | QuickStopActive | FaultReactionActive
            ),
        )
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

    /// The control loop (see the module docs). `switches` are the logical
    /// states (after PA13, e.g. from [`io::SwitchInputs::read`]) sampled now;
    /// `edges` where they began, if the glue latched that (homing origin,
    /// SPEC §8.6), else [`SwitchEdges::default`]. `sink` is told of every
    /// push to `sched` ([`StepSink`]; the firmware passes `()`). With a
    /// fill budget ([`crate::motion::PlannerConfig::with_fill_budget`]) its
    /// parts back to back: [`Drive::begin_control`] and [`Drive::top_up`].
    pub fn control<S: StepSink>(
        &mut self,
        now_us: u64,
        switches: Switches,
        edges: SwitchEdges,
        sched: &StepSchedule,
        sink: &mut S,
        cfg: Config<'_>,
    ) {
        self.begin_control(now_us, switches, edges, sched, cfg);
        while self.fill_paused {
            self.top_up(sched, sink);
        }
    }

    /// The first part of [`Drive::control`]: everything before the fill
    /// (the schedule is not pushed to). Then call [`Drive::top_up`] while
    /// [`Drive::fill_paused`]: glue that bounds how long one call holds
    /// its thread lets other work run between the parts.
    pub fn begin_control(
        &mut self,
        now_us: u64,
        switches: Switches,
        edges: SwitchEdges,
        sched: &StepSchedule,
        cfg: Config<'_>,
    ) {
        self.s.update(cfg);
        self.now_us = now_us;
        let sw = Switches::new(
            switches.cw_limit() && self.s.cw_limit_enabled(),
            switches.ccw_limit() && self.s.ccw_limit_enabled(),
            switches.home(),
        );
        self.switches = sw;
        self.raw_position = self.pin_position(sched);
        if self.frame_seen {
            self.frame_seen = false;
            self.last_frame_us = now_us;
        }

        self.update_brake();
        self.limit_brake(sched, cfg.od());
        self.update_feedback(now_us, cfg);

        // §8.7 faults
        if self.fault.is_none() {
            if sw.cw_limit() && sw.ccw_limit() {
                self.enter_fault(FaultCause::BothLimits, cfg.od());
            } else if self.state == PowerState::OperationEnabled
                && self.s.comm_loss_ms > 0
                && now_us.saturating_sub(self.last_frame_us)
                    >= u64::from(self.s.comm_loss_ms) * 1000
            {
                self.enter_fault(FaultCause::CommunicationLoss, cfg.od());
            }
        }

        if self.state == PowerState::OperationEnabled {
            if self.mode == MODE_HOMING {
                // A disabled limit's edge is never used: the limit never
                // meets a condition (Homing::update).
                self.run_homing(edges, cfg.od());
            } else {
                self.check_limits(cfg.od());
            }
        }

        if self.flush {
            self.flush = false;
            self.planner.stop_at_once(sched);
        }
        // a goal waits while the brake is still applied (PA22)
        if self.replan && !self.brake_holding() {
            self.replan = false;
            self.apply_goal(sched, cfg.od());
        }
        self.fill_paused = true;
    }

    /// The control call begun by [`Drive::begin_control`] has more to do:
    /// call [`Drive::top_up`].
    pub fn fill_paused(&self) -> bool {
        self.fill_paused
    }

    /// The next part of the control call begun by [`Drive::begin_control`],
    /// at its time: its fill, as far as the planner's fill budget goes
    /// (to the end without one), and once the fill is complete what
    /// follows it (what is shown of the motion, state changes at rest).
    /// Nothing when [`Drive::fill_paused`] is false. The parts together do
    /// what [`Drive::control`] does.
    pub fn top_up<S: StepSink>(&mut self, sched: &StepSchedule, sink: &mut S) {
        if !self.fill_paused {
            return;
        }
        let underruns = self.planner.underruns();
        self.fill_paused = false;
        for _ in 0..8 {
            match self.planner.fill_with(self.now_us, sched, sink) {
                Fill::Ended => self.motion_ended(),
                Fill::Paused => {
                    self.fill_paused = true;
                    break;
                }
                _ => break,
            }
        }
        if self.planner.underruns() != underruns {
            self.event(DriveEvent::ScheduleUnderrun);
        }
        if self.fill_paused {
            return;
        }

        self.raw_position = self.pin_position(sched);
        self.velocity = self.planner.actual_velocity(sched);
        let lagging = !sched.pin_settled();
        self.running = sched.is_running() || !sched.is_empty() || lagging;
        self.ramping = self.planner.ramping(sched);
        self.at_rest = self.planner.at_rest(sched) && !lagging;
        self.after_motion();
        self.update_brake();
    }

    /// The raw position of the STEP pin: what the schedule counts less the
    /// steps the step output has not made yet (`StepSchedule::pin_lag`).
    /// What the drive reports, homes and compares with the encoder; the
    /// planner plans from the schedule's own count.
    fn pin_position(&self, sched: &StepSchedule) -> i64 {
        self.planner.actual_position(sched) - i64::from(sched.pin_lag())
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

    /// The goal the current mode asks for, handed to the planner.
    fn apply_goal(&mut self, sched: &StepSchedule, od: &OdValues) {
        if self.state != PowerState::OperationEnabled {
            return;
        }
        if self.halted {
            // §8.1: halt decelerates with 0x6084 in every mode (at once
            // when it is 0) and holds; the mode's goal comes back on resume.
            match self.s.decel(od) {
                0 => self.planner.stop_at_once(sched),
                decel => {
                    self.planner.set_goal(Goal::Stop { decel });
                }
            }
            return;
        }
        let goal = match self.mode {
            MODE_POSITION => self.active.map(|sp| self.move_goal(sp)),
            MODE_VELOCITY => Some(self.velocity_goal(od)),
            MODE_HOMING => self.homing_goal(od),
            _ => None,
        };
        if let Some(goal) = goal {
            if !self.planner.set_goal(goal) {
                self.warning = true;
                self.event(DriveEvent::MotionRefused);
            }
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
}

impl DriveLayer for Drive {
    fn statusword(&self) -> u16 {
        self.status()
    }

    fn mode_display(&self) -> i16 {
        self.mode
    }

    fn actual_position(&self) -> i32 {
        self.reported_position() as i32
    }

    fn actual_velocity_rpm(&self) -> i32 {
        div_i64(self.velocity * 6, i64::from(self.s.steps_per_rev)) as i32
    }

    fn error_register(&self) -> u16 {
        self.error_register
    }

    fn following_error(&self) -> i32 {
        self.following_error_steps()
    }

    fn monitor(&self) -> DriveMonitor {
        let spr = i64::from(self.s.steps_per_rev);
        let command = self
            .active
            .map(|a| a.target)
            .or(self.last_target)
            .unwrap_or(self.user_position());
        let speed_command = match self.mode {
            MODE_VELOCITY => i64::from(self.s.profile_velocity) * 6,
            _ => self
                .active
                .map_or(0, |a| div_i64(a.ramp.velocity() as i64 * 6, spr)),
        };
        let out = self.outputs();
        DriveMonitor::new(
            command as i32,
            div_i64(self.velocity, 10) as i32,
            speed_command as i32,
            u16::from(self.switches.cw_limit())
                | u16::from(self.switches.ccw_limit()) << 1
                | u16::from(self.switches.home()) << 2,
            u16::from(out.power_stage) | u16::from(out.brake_released) << 1,
            self.following_error_steps(),
        )
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
    fn mode_written(&mut self, mode: i16, cfg: Config<'_>) {
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
            let decel = self.s.decel(cfg.od());
            self.stop_with(decel);
            self.replan = mode == MODE_VELOCITY;
        }
    }

    // As for `mode_written`: `self.s` is current.
    fn controlword_written(&mut self, controlword: u16, cfg: Config<'_>) {
        self.apply_controlword(controlword, cfg.od());
    }
}
