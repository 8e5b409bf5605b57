//! Homing sequencer (SPEC §8.6): methods 1..=8 as a list of search phases.
//!
//! Each phase runs in one direction at the fast (0x6099) or slow (0x609B)
//! speed until a switch condition holds; the drive's control loop feeds it
//! the switch states and the raw position at every call. The origin is the
//! deciding switch's latched edge ([`SwitchEdges`], glue that samples the
//! switches late) if that edge lies on the current leg, else the position
//! at the call (glue that calls control at the step where a switch changed,
//! e.g. the virtual drive). Phases ("left" = negative = towards the CW limit):
//!
//! | method | phases |
//! |---|---|
//! | 1 | (on CW: leave it right) · seek CW left → origin |
//! | 2 | mirror of 1 |
//! | 3 | (on home: pass it right) · seek home left → origin; CW on the way: reverse, seek home right → origin |
//! | 4 | mirror of 3 |
//! | 5 | (unless on CW: seek CW left, fast) · leave CW right, slow · seek CW left, slow → origin |
//! | 6 | mirror of 5 |
//! | 7 | (on home: pass home right, slow) · else seek home left, fast (CW: reverse, seek home right, fast) then pass home right, slow · seek home left, slow → origin |
//! | 8 | mirror of 7 |
//!
//! Methods 1/5 find the CW limit's edge, 2/6 the CCW limit's, 7 the home
//! switch's right edge and 8 its left edge from any start. Methods 3/4
//! follow SPEC §8.6 literally ("left; if the CW limit is reached, reverse;
//! stop on the home switch"; the origin is the deciding edge): 3 finds the
//! right edge when it meets the switch moving left, the left edge when it
//! meets it moving right after reversing at the CW limit (4 mirrored).
//! Started on the home switch, 3 leaves it to the right and comes back to
//! its right edge (the edge its search direction meets; 4 mirrored). After
//! a reversal, reaching the other limit (or the same one again) is a
//! homing error.

use super::{SwitchEdges, Switches};

/// 0x6098 (SPEC §8.6).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HomingMethod {
    /// Left to the CW limit.
    CwLimit = 1,
    /// Right to the CCW limit.
    CcwLimit = 2,
    /// Left to the home switch, reversing at the CW limit; the origin is
    /// the first switch edge met.
    HomeLeft = 3,
    /// Right to the home switch, reversing at the CCW limit; the origin is
    /// the first switch edge met.
    HomeRight = 4,
    /// Fast to the CW limit, slow back to its edge.
    CwLimitTwoSpeed = 5,
    /// Fast to the CCW limit, slow back to its edge.
    CcwLimitTwoSpeed = 6,
    /// Fast left to the home switch, slow to its right edge.
    HomeLeftTwoSpeed = 7,
    /// Fast right to the home switch, slow to its left edge.
    HomeRightTwoSpeed = 8,
}

impl HomingMethod {
    pub fn from_register(v: i16) -> Option<Self> {
        Some(match v {
            1 => Self::CwLimit,
            2 => Self::CcwLimit,
            3 => Self::HomeLeft,
            4 => Self::HomeRight,
            5 => Self::CwLimitTwoSpeed,
            6 => Self::CcwLimitTwoSpeed,
            7 => Self::HomeLeftTwoSpeed,
            8 => Self::HomeRightTwoSpeed,
            _ => return None,
        })
    }

    /// Speed cap, r/min: methods 1–4 300, 5–8 1200.
    pub fn max_rpm(self) -> u32 {
        if (self as u8) <= 4 {
            300
        } else {
            1200
        }
    }

    /// Methods 2, 4, 6, 8 search to the right: they are the mirror images.
    fn mirrored(self) -> bool {
        (self as u8) & 1 == 0
    }
}

/// What a phase waits for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Until {
    /// The limit at the end we move towards becomes active.
    LimitActive,
    /// The limit behind us (which we are on) releases.
    LimitReleased,
    /// The home switch becomes active.
    HomeActive,
    /// The home switch has been active and releases.
    HomePassed,
}

/// One search phase (directions before mirroring: `left` = negative).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Phase {
    left: bool,
    slow: bool,
    until: Until,
    /// Meeting this phase's condition is the origin.
    origin: bool,
}

impl Phase {
    #[inline]
    pub const fn left(&self) -> bool {
        self.left
    }

    #[inline]
    pub const fn slow(&self) -> bool {
        self.slow
    }

    #[inline]
    pub const fn until(&self) -> Until {
        self.until
    }

    /// Meeting this phase's condition is the origin.
    #[inline]
    pub const fn origin(&self) -> bool {
        self.origin
    }
}

const fn phase(left: bool, slow: bool, until: Until, origin: bool) -> Phase {
    Phase {
        left,
        slow,
        until,
        origin,
    }
}

/// Why homing failed (statusword bit 13).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HomingError {
    /// 0x6098 is not 1..=8.
    NoMethod,
    /// A speed is 0 or above 100000, or the acceleration is 0.
    BadSpeed,
    /// A limit was reached after reversing (or where none was expected).
    LimitReached,
    /// A fault stopped the drive.
    Fault,
}

/// What the drive should do after [`Homing::update`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HomingStep {
    /// Keep going.
    Continue,
    /// Run the new current phase ([`Homing::phase`]).
    NextPhase,
    /// The origin was found at this raw position: stop, then move to
    /// origin + 0x607C at the slow speed.
    Origin(i64),
    Failed(HomingError),
}

/// Phases of one run (at most 4).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Plan {
    phases: [Phase; 4],
    len: usize,
}

impl Plan {
    fn of(list: &[Phase]) -> Self {
        let mut phases = [phase(true, false, Until::LimitActive, false); 4];
        phases[..list.len()].copy_from_slice(list);
        Self {
            phases,
            len: list.len(),
        }
    }
}

/// The sequencer of one homing run. Directions are stored unmirrored;
/// [`Homing::phase`] returns them as they must run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Homing {
    method: HomingMethod,
    plan: Plan,
    idx: usize,
    /// A limit made us reverse: the next limit is an error.
    reversed: bool,
    /// HomePassed: the home switch has been seen active in this phase.
    home_seen: bool,
    /// Raw position at the previous update: tells which way the motor
    /// moves.
    last_position: Option<i64>,
    /// Where the current leg began: the phase's start, moved along while
    /// the motor still brakes against the phase's direction (so it ends at
    /// the turn, to within one control call). A latched edge counts only
    /// between here and the present position.
    leg_start: Option<i64>,
}

impl Homing {
    /// Plans a run of `method` from the current switch states.
    pub fn start(method: HomingMethod, sw: Switches) -> Self {
        use Until::*;
        let m = method.mirrored();
        // Unmirrored view: "near limit" is the CW one for 1/3/5/7.
        let near = if m { sw.ccw_limit } else { sw.cw_limit };
        let plan = match method {
            HomingMethod::CwLimit | HomingMethod::CcwLimit => {
                if near {
                    Plan::of(&[
                        phase(false, false, LimitReleased, false),
                        phase(true, false, LimitActive, true),
                    ])
                } else {
                    Plan::of(&[phase(true, false, LimitActive, true)])
                }
            }
            HomingMethod::HomeLeft | HomingMethod::HomeRight => {
                if sw.home {
                    Plan::of(&[
                        phase(false, false, HomePassed, false),
                        phase(true, false, HomeActive, true),
                    ])
                } else {
                    Plan::of(&[phase(true, false, HomeActive, true)])
                }
            }
            HomingMethod::CwLimitTwoSpeed | HomingMethod::CcwLimitTwoSpeed => {
                let tail = [
                    phase(false, true, LimitReleased, false),
                    phase(true, true, LimitActive, true),
                ];
                if near {
                    Plan::of(&tail)
                } else {
                    Plan::of(&[phase(true, false, LimitActive, false), tail[0], tail[1]])
                }
            }
            HomingMethod::HomeLeftTwoSpeed | HomingMethod::HomeRightTwoSpeed => {
                let tail = [
                    phase(false, true, HomePassed, false),
                    phase(true, true, HomeActive, true),
                ];
                if sw.home {
                    Plan::of(&tail)
                } else {
                    Plan::of(&[phase(true, false, HomeActive, false), tail[0], tail[1]])
                }
            }
        };
        Self {
            method,
            plan,
            idx: 0,
            reversed: false,
            home_seen: sw.home,
            last_position: None,
            leg_start: None,
        }
    }

    pub fn method(&self) -> HomingMethod {
        self.method
    }

    /// The phase to run, mirrored for methods 2/4/6/8.
    pub fn phase(&self) -> Phase {
        let mut p = self.plan.phases[self.idx];
        if self.method.mirrored() {
            p.left = !p.left;
        }
        p
    }

    /// Checks the current phase's condition against the switch states at
    /// raw position `position`; `edges` are where the switches' states
    /// began, if the glue latched them (SPEC §8.6 origin).
    pub fn update(&mut self, sw: Switches, edges: SwitchEdges, position: i64) -> HomingStep {
        let p = self.phase();
        let moved = position - self.last_position.unwrap_or(position);
        self.last_position = Some(position);
        let leg_start = self.leg_start.get_or_insert(position);
        if moved != 0 && (moved < 0) != p.left {
            *leg_start = position;
            // Still braking from the previous phase, against this one: what
            // the switches do now is no edge of this phase (e.g. 7 overshoots
            // the switch it found fast and must not take its far edge as
            // "passed").
            self.home_seen = false;
            return HomingStep::Continue;
        }
        // the limit in the direction of travel, and the one behind
        let (ahead, behind, edge_ahead) = if p.left {
            (sw.cw_limit, sw.ccw_limit, edges.cw_limit)
        } else {
            (sw.ccw_limit, sw.cw_limit, edges.ccw_limit)
        };
        if sw.home {
            self.home_seen = true;
        }
        let met = match p.until {
            Until::LimitActive => ahead,
            Until::LimitReleased => !behind,
            Until::HomeActive => sw.home,
            Until::HomePassed => self.home_seen && !sw.home,
        };
        if met {
            if p.origin {
                // The deciding edge: origin phases wait for the limit ahead
                // (an enabled one: `sw` has PA14 applied, so a disabled
                // limit's edge never gets here) or for the home switch.
                let edge = if p.until == Until::LimitActive {
                    edge_ahead
                } else {
                    edges.home
                };
                return HomingStep::Origin(
                    self.edge_on_leg(edge, position, p.left).unwrap_or(position),
                );
            }
            self.advance(sw, position);
            return HomingStep::NextPhase;
        }
        if ahead && p.until != Until::LimitActive {
            // Only a search for the home switch may reverse at a limit, and
            // only once (SPEC §8.6: the opposite limit after reversing is an
            // error).
            if self.reversed || p.until != Until::HomeActive {
                return HomingStep::Failed(HomingError::LimitReached);
            }
            self.reversed = true;
            // Search the other way. 3/4: the first home edge met that way
            // is the origin (SPEC §8.6); 7/8 (fast search): the slow phases
            // that follow pass the switch and come back to its edge.
            let here = &mut self.plan.phases[self.idx];
            here.left = !here.left;
            self.home_seen = sw.home;
            self.leg_start = Some(position);
            return HomingStep::NextPhase;
        }
        HomingStep::Continue
    }

    fn advance(&mut self, sw: Switches, position: i64) {
        if self.idx + 1 < self.plan.len {
            self.idx += 1;
        }
        self.home_seen = sw.home;
        self.leg_start = Some(position);
    }

    /// A latched edge (wrapping step count) if it lies on the current leg,
    /// running `left` or not: between where the motion in this phase's
    /// direction began and `position`. Anything else is stale (e.g. passed
    /// while still braking against the phase) and is not the origin.
    fn edge_on_leg(&self, edge: Option<i32>, position: i64, left: bool) -> Option<i64> {
        // Relative to now, in wrapping i32 like the step counts (a leg is
        // far shorter than 2^31 steps).
        let back = edge?.wrapping_sub(position as i32);
        let leg = self.leg_start.map_or(0, |s| (s - position) as i32);
        let on_leg = if left {
            (0..=leg).contains(&back)
        } else {
            (leg..=0).contains(&back)
        };
        on_leg.then_some(position + i64::from(back))
    }
}
