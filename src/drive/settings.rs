//! The configuration the drive works with, as step figures (PA10, PA12
//! and the OD's ramps in steps), and the plain PA values it acts on.

use super::brake::BrakeTimes;
use crate::arith::div_u64;
use crate::dictionary::{Config, OdValues};
use crate::motion::{HomingMethod, PlannerConfig, Ramp};
use crate::params::Params;

/// What PA10..PA23 mean in steps, and the one OD value the drive shows
/// between calls (0x6081 in the statusword and the monitor); the other OD
/// values are read where they are used, from the dictionary's table
/// ([`Config`]), never copied.
///
/// Kept current by [`Settings::update`] on every accepted write and every
/// control call. The derived step figures are recomputed only when their
/// PA registers changed, so a frame that writes the profile values pays no
/// 64-bit maths.
#[derive(Clone, Debug, Default)]
pub(super) struct Settings {
    /// 0x6081 as last written.
    pub(super) profile_velocity: i32,
    /// PA10 and PA12 as last seen (raw registers): the derived figures
    /// below are recomputed when they change.
    pub(super) steps_per_rev_reg: u16,
    pub(super) max_speed_rpm_reg: u16,
    /// PA15 as last seen: the pulse width's step rate cap follows it.
    pulse_width_reg: u16,
    /// PA10 in force (a u16 register, at least 1): a u32 so that a ramp
    /// register times it is one 32×32-bit multiply, which cannot overflow.
    pub(super) steps_per_rev: u32,
    /// PA12 and the board's maximum step rate, 0.1 steps/s.
    pub(super) max_velocity: u64,
    /// The board's step rate and acceleration limits in 0.1 steps/s and
    /// 0.1 steps/s² ([`PlannerConfig::velocity_cap`] / `accel_cap`): they
    /// clamp every ramp as PA12 does.
    velocity_cap: u64,
    /// The step rate PA15's pulse width allows ([`Params::step_rate_cap`]),
    /// 0.1 steps/s: it clamps too.
    pulse_cap: u64,
    accel_cap: u64,
    pub(super) limit_enable: u16,
    pub(super) comm_loss_ms: u16,
    /// PA22 / PA23.
    pub(super) brake_times: BrakeTimes,
}

impl Settings {
    pub(super) fn from(cfg: Config<'_>, planner: PlannerConfig) -> Self {
        let mut s = Self {
            // not PA10's register: `update` derives the step figures
            steps_per_rev_reg: cfg.pa().steps_per_rev().wrapping_add(1),
            pulse_width_reg: cfg.pa().step_pulse_width().wrapping_add(1),
            velocity_cap: planner.velocity_cap(),
            accel_cap: planner.accel_cap(),
            ..Self::default()
        };
        s.update(cfg);
        s
    }

    /// A new planner configuration (the board's limits): the derived
    /// maximum velocity follows at once.
    pub(super) fn set_planner_config(&mut self, planner: PlannerConfig) {
        self.velocity_cap = planner.velocity_cap();
        self.accel_cap = planner.accel_cap();
        self.max_velocity = self.rpm_to_velocity(u64::from(self.max_speed_rpm_reg));
    }

    /// Takes the values of `cfg`; the step figures of PA10/PA12 only when
    /// those registers changed.
    pub(super) fn update(&mut self, cfg: Config<'_>) {
        let pa: &Params = cfg.pa();
        self.profile_velocity = cfg.od().profile_velocity();
        self.limit_enable = pa.limit_enable();
        self.comm_loss_ms = pa.comm_loss_ms();
        self.brake_times = BrakeTimes {
            release_delay_ms: pa.brake_release_delay_ms(),
            engage_ms: pa.brake_engage_ms(),
        };
        let (spr_reg, rpm_reg) = (pa.steps_per_rev(), pa.max_speed_rpm());
        let pulse_reg = pa.step_pulse_width();
        if spr_reg != self.steps_per_rev_reg
            || rpm_reg != self.max_speed_rpm_reg
            || pulse_reg != self.pulse_width_reg
        {
            self.steps_per_rev_reg = spr_reg;
            self.max_speed_rpm_reg = rpm_reg;
            self.pulse_width_reg = pulse_reg;
            self.steps_per_rev = u32::from(spr_reg.max(1));
            self.pulse_cap = u64::from(pa.step_rate_cap()) * 10;
            self.max_velocity = self.rpm_to_velocity(u64::from(rpm_reg));
        }
    }

    /// 0.1 rev/s (or rev/s²) register → 0.1 steps/s (steps/s²).
    /// Below 2^48 (a u32 register times a u16 PA10): no saturation needed.
    pub(super) fn steps(&self, reg: u32) -> u64 {
        u64::from(reg) * u64::from(self.steps_per_rev)
    }

    /// The profile ramp of 0x6081/0x6083/0x6084, clamped (SPEC §8.4).
    pub(super) fn profile_ramp(&self, od: &OdValues) -> Ramp {
        Ramp::new(
            self.steps(od.profile_velocity().unsigned_abs()),
            self.steps(u32::from(od.acceleration())),
            self.steps(u32::from(od.deceleration())),
        )
        .clamped(self.max_velocity, self.accel_cap)
    }

    /// Homing ramp at 0x6099 (fast) or 0x609B (slow) with 0x609A, capped
    /// per method (SPEC §8.6).
    pub(super) fn homing_ramp(&self, od: &OdValues, method: HomingMethod, slow: bool) -> Ramp {
        let reg = if slow {
            od.homing_zero_speed()
        } else {
            od.homing_speed()
        };
        let accel = self.steps(u32::from(od.homing_acceleration()));
        let cap = self.rpm_to_velocity(u64::from(method.max_rpm()));
        Ramp::new(self.steps(reg), accel, accel).clamped(self.max_velocity.min(cap), self.accel_cap)
    }

    pub(super) fn decel(&self, od: &OdValues) -> u64 {
        self.steps(u32::from(od.deceleration()))
    }

    pub(super) fn quick_stop_decel(&self, od: &OdValues) -> u64 {
        self.steps(u32::from(od.quick_stop_deceleration()))
    }

    pub(super) fn cw_limit_enabled(&self) -> bool {
        self.limit_enable & 1 != 0
    }

    pub(super) fn ccw_limit_enabled(&self) -> bool {
        self.limit_enable & 2 != 0
    }
}

impl Settings {
    /// r/min → 0.1 steps/s at PA10, capped at the board's maximum step
    /// rate and at the rate PA15's pulse width allows.
    fn rpm_to_velocity(&self, rpm: u64) -> u64 {
        div_u64(rpm * u64::from(self.steps_per_rev), 6)
            .min(self.velocity_cap)
            .min(self.pulse_cap)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_follow_every_pa10_pa12_and_pa15_change() {
        // SPEC §7 PA10 (steps/rev) and PA12 (max speed), and PA15's step
        // rate cap, are derived only when they change (Settings::update);
        // each change must show.
        let mut od = OdValues::default();
        od.set_profile_velocity(-7);
        let mut pa = Params::defaults();
        let mut s = Settings::from(Config::new(&od, &pa), PlannerConfig::default());
        for (spr, rpm, pa15) in [
            (400, 3000, 0),
            (400, 100, 0),
            (0, 100, 0),
            (12_800, 100, 0),
            (12_800, 3000, 0),
            (12_800, 3000, 5),
            (12_800, 3000, 1000),
            (12_800, 3000, 0),
        ] {
            pa.set_unchecked(10, spr);
            pa.set_unchecked(12, rpm);
            pa.set_unchecked(15, pa15);
            s.update(Config::new(&od, &pa));
            let spr = u64::from(spr.max(1));
            assert_eq!(u64::from(s.steps_per_rev), spr);
            let v = (u64::from(rpm) * spr / 6)
                .min(PlannerConfig::default().velocity_cap())
                .min(u64::from(pa.step_rate_cap()) * 10);
            assert_eq!(s.max_velocity, v, "PA10 {spr} PA12 {rpm} PA15 {pa15}");
            assert_eq!(s.profile_velocity, od.profile_velocity());
        }
    }

    #[test]
    fn step_figures_of_the_largest_registers_are_exact() {
        // the widest register (u32) times the largest PA10 (u16): the
        // product the saturating u64 multiply gave, without saturating
        let od = OdValues::default();
        let mut pa = Params::defaults();
        pa.set_unchecked(10, u16::MAX);
        let mut s = Settings::from(Config::new(&od, &pa), PlannerConfig::default());
        s.update(Config::new(&od, &pa));
        for reg in [0, 1, u32::from(u16::MAX), u32::MAX] {
            let want = u64::from(reg).saturating_mul(u64::from(u16::MAX));
            assert_eq!(s.steps(reg), want, "register {reg}");
        }
    }
}
