//! The DP monitor of seed 001 at 0x0000..=0x0017 (SPEC §9): read-only
//! 16-bit items, in the order of seed 001's table, from live drive state.
//! [`DP_ITEMS`] names each item once; [`dp_value`] computes it; the docs
//! table (docs/generated/registers.md) is generated from [`DP_ITEMS`].
//!
//! Signed values are two's complement; 32-bit ones are split in address
//! order low word, high word (seed 001 "DP-PoS / DP-PoS."), whatever 0x6000.

use super::{DriveLayer, Params};

/// One DP item: its seed 001 name, what this drive reports there, unit.
/// Its address is [`DP_BASE`] + its place in [`DP_ITEMS`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DpItem {
    name: &'static str,
    what: &'static str,
    unit: &'static str,
}

impl DpItem {
    /// Seed 001's name, e.g. "DP-SPd".
    pub const fn name(&self) -> &'static str {
        self.name
    }
    /// What this drive reports there.
    pub const fn what(&self) -> &'static str {
        self.what
    }
    /// Its unit ("" for codes and flags).
    pub const fn unit(&self) -> &'static str {
        self.unit
    }
}

const fn dp(name: &'static str, what: &'static str, unit: &'static str) -> DpItem {
    DpItem { name, what, unit }
}

/// The items, by address from [`DP_BASE`].
#[rustfmt::skip]
pub const DP_ITEMS: [DpItem; 24] = [
    dp("DP-SPd", "actual speed (0x606C), signed, saturated to i16", "r/min"),
    dp("DP-PoS", "actual position (0x6064), low word", "steps"),
    dp("DP-PoS.", "actual position, high word", "steps"),
    dp("DP-CPo", "command position (target of the running or last move), low word", "steps"),
    dp("DP-CPo.", "command position, high word", "steps"),
    dp("DP-EPo", "following error (0x60F4), low word; 0 without an encoder (PA17 = 0)", "steps"),
    dp("DP-EPo.", "following error, high word", "steps"),
    dp("DP-trq", "torque: 0 (not measured)", ""),
    dp("DP-I", "motor current: 0 (not measured)", ""),
    dp("DP-LSP", "linear speed: 0 (no lead known)", ""),
    dp("DP-Cnt", "control mode: the mode in force (0x6061: 0, 1, 3, 6)", ""),
    dp("DP-Frq", "step frequency, unsigned, saturated at 65535", "10 steps/s"),
    dp("DP-CS", "speed command (the profile's commanded speed), signed", "r/min"),
    dp("DP-Ct", "torque command: 0 (no torque control)", ""),
    dp("DP-APo", "position within one revolution, 0..PA10-1", "steps"),
    dp("DP-In", "inputs, 1 = active after PA13: bit 0 CW limit, 1 CCW limit, 2 home", "bits"),
    dp("DP-oUt", "outputs: bit 0 power stage enabled, bit 1 brake released", "bits"),
    dp("DP-Cod", "encoder signals: 0", ""),
    dp("DP-m", "load inertia ratio: 0 (not estimated)", ""),
    dp("DP-Err", "bits 0..7: 0x1001 error register; bit 8 defaults in use (store blank at boot); \
        bit 9 defaults in use (saved set unreadable); bit 10 last EE operation failed in the flash",
        "bits"),
    dp("DP-tL", "torque limit: 0 (none)", ""),
    dp("DP-IA", "phase A current: 0 (not measured)", ""),
    dp("DP-IC", "phase C current: 0 (not measured)", ""),
    dp("DP-rES", "why the chip last reset, as the glue reports it: 0 power-on or brown-out, 1 reset pin, \
        2 independent watchdog, 3 software, 4 window watchdog, 5 low-power, 6 option-byte load, \
        7 none flagged; 0 on the virtual drive", ""),
];

/// First DP item.
pub const DP_BASE: u16 = 0x0000;
/// Last DP item.
pub const DP_LAST: u16 = DP_BASE + DP_ITEMS.len() as u16 - 1;
/// DP-Err's address.
pub const DP_ERR: u16 = 0x0013;
/// DP-rES's address: the reset cause.
pub const DP_RES: u16 = 0x0017;

/// What the DP monitor needs from the drive beyond the §5 entries (see
/// [`DriveLayer::monitor`]); all zero for a drive that does not know.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DriveMonitor {
    /// Where the running (or last) move is commanded to, steps.
    command_position: i32,
    /// Steps per second being generated now, signed.
    step_rate_steps_per_s: i32,
    /// Speed the profile commands now (before ramps), r/min, signed.
    speed_command_rpm: i32,
    /// Switch inputs, 1 = active (after PA13 polarity): bit 0 CW limit,
    /// bit 1 CCW limit, bit 2 home.
    inputs: u16,
    /// Outputs: bit 0 power stage enabled, bit 1 brake released (§8.1).
    outputs: u16,
    /// Commanded − measured position, steps (0x60F4, SPEC §8.8).
    following_error: i32,
}

impl DriveMonitor {
    /// The drive's report; each argument as its getter says.
    #[inline]
    pub const fn new(
        command_position: i32,
        step_rate_steps_per_s: i32,
        speed_command_rpm: i32,
        inputs: u16,
        outputs: u16,
        following_error: i32,
    ) -> Self {
        Self {
            command_position,
            step_rate_steps_per_s,
            speed_command_rpm,
            inputs,
            outputs,
            following_error,
        }
    }

    /// Where the running (or last) move is commanded to, steps.
    #[inline]
    pub const fn command_position(&self) -> i32 {
        self.command_position
    }

    /// Steps per second being generated now, signed.
    #[inline]
    pub const fn step_rate_steps_per_s(&self) -> i32 {
        self.step_rate_steps_per_s
    }

    /// Speed the profile commands now (before ramps), r/min, signed.
    #[inline]
    pub const fn speed_command_rpm(&self) -> i32 {
        self.speed_command_rpm
    }

    /// Switch inputs, 1 = active (after PA13 polarity): bit 0 CW limit,
    /// bit 1 CCW limit, bit 2 home.
    #[inline]
    pub const fn inputs(&self) -> u16 {
        self.inputs
    }

    /// Outputs: bit 0 power stage enabled, bit 1 brake released (§8.1).
    #[inline]
    pub const fn outputs(&self) -> u16 {
        self.outputs
    }

    /// Commanded − measured position, steps (0x60F4, SPEC §8.8).
    #[inline]
    pub const fn following_error(&self) -> i32 {
        self.following_error
    }
}

/// State of the parameter store as DP-Err reports it (bits 8..10).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StoreStatus {
    /// At boot the store was blank: defaults are in use.
    defaulted_blank: bool,
    /// At boot the saved set could not be read: defaults are in use.
    defaulted_unreadable: bool,
    /// The last EE operation failed in the flash.
    flash_failed: bool,
    /// DP-rES: why the chip last reset (the glue's code; 0, power-on, for
    /// a drive that does not say).
    reset_cause: u16,
}

impl StoreStatus {
    /// After power-up: how the store's set was obtained, and DP-rES.
    #[inline]
    pub const fn booted(
        defaulted_blank: bool,
        defaulted_unreadable: bool,
        reset_cause: u16,
    ) -> Self {
        Self {
            defaulted_blank,
            defaulted_unreadable,
            flash_failed: false,
            reset_cause,
        }
    }

    /// DP-rES: the glue's code for why the chip last reset.
    #[inline]
    pub fn set_reset_cause(&mut self, code: u16) {
        self.reset_cause = code;
    }

    /// An EE operation ran: `flash_failed` if the flash failed, `saved`
    /// if the store holds a valid saved set now (no longer defaults).
    pub fn ee_done(&mut self, flash_failed: bool, saved: bool) {
        self.flash_failed = flash_failed;
        if saved {
            self.defaulted_blank = false;
            self.defaulted_unreadable = false;
        }
    }

    /// At boot the store was blank: defaults are in use.
    #[inline]
    pub const fn defaulted_blank(&self) -> bool {
        self.defaulted_blank
    }

    /// At boot the saved set could not be read: defaults are in use.
    #[inline]
    pub const fn defaulted_unreadable(&self) -> bool {
        self.defaulted_unreadable
    }

    /// The last EE operation failed in the flash.
    #[inline]
    pub const fn flash_failed(&self) -> bool {
        self.flash_failed
    }

    /// DP-rES: why the chip last reset (the glue's code; 0, power-on, for
    /// a drive that does not say).
    #[inline]
    pub const fn reset_cause(&self) -> u16 {
        self.reset_cause
    }
}

impl StoreStatus {
    /// DP-Err bits 8..10.
    pub fn dp_err_bits(self) -> u16 {
        u16::from(self.defaulted_blank) << 8
            | u16::from(self.defaulted_unreadable) << 9
            | u16::from(self.flash_failed) << 10
    }
}

fn saturate_i16(v: i32) -> u16 {
    v.clamp(i32::from(i16::MIN), i32::from(i16::MAX)) as i16 as u16
}

/// The value of DP item `address` (0x0000..=0x0017; others read 0).
pub fn dp_value<D: DriveLayer>(address: u16, drive: &D, pa: &Params, store: StoreStatus) -> u16 {
    let m = drive.monitor();
    let low = |v: i32| v as u16;
    let high = |v: i32| (v >> 16) as u16;
    match address {
        0x00 => saturate_i16(drive.actual_velocity_rpm()),
        0x01 => low(drive.actual_position()),
        0x02 => high(drive.actual_position()),
        0x03 => low(m.command_position),
        0x04 => high(m.command_position),
        0x05 => low(m.following_error),
        0x06 => high(m.following_error),
        0x0A => drive.mode_display() as u16,
        0x0B => (m.step_rate_steps_per_s.unsigned_abs() / 10).min(u32::from(u16::MAX)) as u16,
        0x0C => saturate_i16(m.speed_command_rpm),
        0x0E => {
            let rev = i32::from(pa.steps_per_rev().max(1));
            drive.actual_position().rem_euclid(rev) as u16
        }
        0x0F => m.inputs,
        0x10 => m.outputs,
        DP_ERR => (drive.error_register() & 0x00FF) | store.dp_err_bits(),
        DP_RES => store.reset_cause,
        // 0x07 torque, 0x08 current, 0x09 linear speed, 0x0D torque
        // command, 0x11 encoder, 0x12 inertia, 0x14 torque limit,
        // 0x15/0x16 phase currents: an open-loop step drive measures none
        // of them (SPEC §9).
        _ => 0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dictionary::Config;

    struct Fake {
        position: i32,
        rpm: i32,
        error: u16,
        m: DriveMonitor,
    }

    impl DriveLayer for Fake {
        fn statusword(&self) -> u16 {
            0
        }
        fn mode_display(&self) -> i16 {
            3
        }
        fn actual_position(&self) -> i32 {
            self.position
        }
        fn actual_velocity_rpm(&self) -> i32 {
            self.rpm
        }
        fn error_register(&self) -> u16 {
            self.error
        }
        fn monitor(&self) -> DriveMonitor {
            self.m
        }
        fn values_written(&mut self, _: Config<'_>) {}
        fn mode_written(&mut self, _: i16, _: Config<'_>) {}
        fn controlword_written(&mut self, _: u16, _: Config<'_>) {}
    }

    fn all(d: &Fake, pa: &Params, s: StoreStatus) -> [u16; 24] {
        core::array::from_fn(|a| dp_value(a as u16, d, pa, s))
    }

    #[test]
    fn items_come_from_the_drive_in_seed_001_order() {
        let d = Fake {
            position: -200_001,
            rpm: -600,
            error: 0x11,
            m: DriveMonitor {
                command_position: 300_000,
                step_rate_steps_per_s: -100_000,
                speed_command_rpm: 600,
                inputs: 0b101,
                outputs: 0b11,
                following_error: -70_000,
            },
        };
        let pa = Params::defaults(); // PA10 = 10000
        let v = all(&d, &pa, StoreStatus::default());
        assert_eq!(v[0x00], (-600i16) as u16);
        assert_eq!([v[0x01], v[0x02]], [0xF2BF, 0xFFFC]); // -200001
        assert_eq!([v[0x03], v[0x04]], [0x93E0, 0x0004]); // 300000
        assert_eq!([v[0x05], v[0x06]], [0xEE90, 0xFFFE]); // -70000
        assert_eq!(v[0x0A], 3);
        assert_eq!(v[0x0B], 10_000);
        assert_eq!(v[0x0C], 600);
        assert_eq!(v[0x0E], 9_999, "-200001 mod 10000");
        assert_eq!(v[0x0F], 0b101);
        assert_eq!(v[0x10], 0b11);
        assert_eq!(v[0x13], 0x11);
        for a in [7, 8, 9, 0x0D, 0x11, 0x12, 0x14, 0x15, 0x16, 0x17] {
            assert_eq!(v[a], 0, "item {a:#04x} is not measured open loop");
        }
    }

    #[test]
    fn saturation_and_store_flags() {
        let d = Fake {
            position: 0,
            rpm: 100_000,
            error: 0x0100, // beyond bit 7: not DP-Err's business
            m: DriveMonitor {
                step_rate_steps_per_s: i32::MAX,
                speed_command_rpm: -100_000,
                ..DriveMonitor::default()
            },
        };
        let s = StoreStatus {
            defaulted_blank: true,
            defaulted_unreadable: false,
            flash_failed: true,
            reset_cause: 2,
        };
        let v = all(&d, &Params::defaults(), s);
        assert_eq!(v[0x17], 2, "DP-rES: the reset cause as given");
        assert_eq!(v[0x00], i16::MAX as u16);
        assert_eq!(v[0x0B], u16::MAX);
        assert_eq!(v[0x0C], i16::MIN as u16);
        assert_eq!(v[0x13], 0x0500);
    }
}
