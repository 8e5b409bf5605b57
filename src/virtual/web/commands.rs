//! What the page's buttons and table edits mean in Modbus requests. Each
//! command is the sequence of requests a master would send (SPEC §8); the
//! page runs them in order and stops at the first refusal.

use modbus_drive::drive::PowerState;
use modbus_drive::Device;

use super::force::Switch;
use super::modbus::{Pdu, EE_REGISTER};
use crate::virtual_drive::registers::{position, DataType, PA_BASE, PA_COUNT, TABLE};

const CONTROLWORD: u16 = 0x6040;
const MODE: u16 = 0x6060;
const PROFILE_VELOCITY: u16 = 0x6081;
const TARGET_POSITION: u16 = 0x607A;

/// Controlword values (SPEC §8.1, §8.4).
mod cw {
    pub const DISABLE_VOLTAGE: u16 = 0x0000;
    pub const SHUTDOWN: u16 = 0x0006;
    pub const SWITCH_ON: u16 = 0x0007;
    pub const ENABLE: u16 = 0x000F;
    pub const QUICK_STOP: u16 = 0x000B;
    pub const FAULT_RESET: u16 = 0x0080;
    pub const NEW_SET_POINT: u16 = 1 << 4;
    pub const IMMEDIATELY: u16 = 1 << 5;
    pub const RELATIVE: u16 = 1 << 6;
    pub const HALT: u16 = 1 << 8;
}

/// Modes of 0x6060.
const POSITION_MODE: u16 = 1;
const VELOCITY_MODE: u16 = 3;
const HOMING_MODE: u16 = 6;

/// A motion profile typed on the page: speed in 0.1 rev/s (0x6081),
/// acceleration and deceleration in 0.1 rev/s² (0x6083 / 0x6084).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Profile {
    pub speed: u32,
    pub accel: u16,
}

#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Command {
    /// Write `value` to the register at `index` (a §5 entry or a PA).
    Write {
        index: u16,
        value: i64,
    },
    Enable,
    Disable,
    FaultReset,
    QuickStop,
    Halt,
    Jog {
        forward: bool,
        profile: Profile,
    },
    JogStop,
    Move {
        target: i32,
        relative: bool,
        profile: Profile,
    },
    Home,
    /// EE-Set: save the working parameters (SPEC §9).
    Save,
    /// EE-dEF: restore the defaults and save them (SPEC §9).
    Defaults,
    /// Any request PDU typed on the page (function code and data).
    Raw(Vec<u8>),
    /// Force a switch of the simulated axis (`None` releases it).
    Force {
        switch: Switch,
        state: Option<bool>,
    },
}

/// One request of a command, with what it is for in words.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Step {
    pub label: String,
    pub pdu: Pdu,
}

fn step(label: impl Into<String>, pdu: Pdu) -> Step {
    Step {
        label: label.into(),
        pdu,
    }
}

fn controlword(value: u16) -> Step {
    step(
        format!("0x6040 = 0x{value:04X}"),
        Pdu::write_single(CONTROLWORD, value),
    )
}

fn mode(value: u16) -> Step {
    step(format!("0x6060 = {value}"), Pdu::write_single(MODE, value))
}

/// 0x6081 (2 words), 0x6083, 0x6084 in one 0x10 (table order, SPEC §5).
fn profile(p: Profile, signed_speed: i32, low_word_first: bool) -> Step {
    let [a, b] = Pdu::words32(signed_speed as u32, low_word_first);
    step(
        format!("0x6081 = {signed_speed}, 0x6083 = 0x6084 = {}", p.accel),
        Pdu::write_multiple(PROFILE_VELOCITY, &[a, b, p.accel, p.accel]),
    )
}

/// What the requests of a command depend on: the drive's power state and
/// its word order (0x6000), as last known.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ctx {
    pub state: PowerState,
    pub low_first: bool,
}

impl Ctx {
    pub fn of(device: &Device) -> Self {
        Self {
            state: device.drive().state(),
            low_first: device.od().word_order() == 1,
        }
    }
}

/// The requests of `cmd` on a drive in `ctx`, or why the page does not
/// send it (nothing sent then). `Force` has no requests.
pub fn requests(cmd: &Command, ctx: Ctx) -> Result<Vec<Step>, String> {
    let Ctx { state, low_first } = ctx;
    let enabled = state == PowerState::OperationEnabled;
    let need_enabled = || {
        if enabled {
            Ok(())
        } else {
            Err(format!("the drive is {state:?}: enable it first"))
        }
    };
    Ok(match *cmd {
        Command::Write { index, value } => vec![write(index, value, low_first)?],
        Command::Enable => {
            if matches!(state, PowerState::Fault | PowerState::FaultReactionActive) {
                return Err("the drive is in fault: reset the fault first".into());
            }
            [cw::SHUTDOWN, cw::SWITCH_ON, cw::ENABLE]
                .into_iter()
                .map(controlword)
                .collect()
        }
        Command::Disable => vec![controlword(cw::SHUTDOWN)],
        Command::FaultReset => vec![
            controlword(cw::DISABLE_VOLTAGE),
            controlword(cw::FAULT_RESET),
        ],
        Command::QuickStop => vec![controlword(cw::QUICK_STOP)],
        Command::Halt => vec![controlword(cw::ENABLE | cw::HALT)],
        Command::Jog {
            forward,
            profile: p,
        } => {
            need_enabled()?;
            let v = i32::try_from(p.speed).map_err(|_| "jog speed too large")?;
            vec![
                mode(VELOCITY_MODE),
                profile(p, if forward { v } else { -v }, low_first),
                controlword(cw::ENABLE),
            ]
        }
        Command::JogStop => vec![controlword(cw::ENABLE | cw::HALT)],
        Command::Move {
            target,
            relative,
            profile: p,
        } => {
            need_enabled()?;
            let v = i32::try_from(p.speed).map_err(|_| "speed too large")?;
            let base = cw::ENABLE | cw::IMMEDIATELY | if relative { cw::RELATIVE } else { 0 };
            vec![
                mode(POSITION_MODE),
                profile(p, v, low_first),
                step(
                    format!("0x607A = {target}"),
                    Pdu::write_multiple(TARGET_POSITION, &Pdu::words32(target as u32, low_first)),
                ),
                // SPEC §8.4: a rising edge of bit 4 latches the set-point,
                // and the master clears bit 4 for the next latch.
                controlword(base),
                controlword(base | cw::NEW_SET_POINT),
                controlword(base),
            ]
        }
        Command::Home => {
            need_enabled()?;
            // Bit 4 stays set while homing runs; the next command clears it.
            vec![
                mode(HOMING_MODE),
                controlword(cw::ENABLE),
                controlword(cw::ENABLE | cw::NEW_SET_POINT),
            ]
        }
        Command::Save => vec![step(
            "EE-Set (save parameters)",
            Pdu::write_multiple(EE_REGISTER, &[1]),
        )],
        Command::Defaults => vec![step(
            "EE-dEF (restore defaults, and save them)",
            Pdu::write_multiple(EE_REGISTER, &[5]),
        )],
        Command::Raw(ref pdu) => {
            if pdu.is_empty() || pdu.len() > 253 {
                return Err("a PDU has 1..=253 bytes".into());
            }
            vec![step("typed request", Pdu(pdu.clone()))]
        }
        Command::Force { .. } => Vec::new(),
    })
}

/// A write of `value` to `index` in the width and word order the register
/// has; an unknown register gets a one-word write, which the dispatcher
/// refuses as it refuses a master's.
fn write(index: u16, value: i64, low_first: bool) -> Result<Step, String> {
    let data_type = match position(index) {
        Some(p) => TABLE[p].data_type(),
        None => DataType::U16,
    };
    let fits = |lo: i64, hi: i64| {
        if (lo..=hi).contains(&value) {
            Ok(())
        } else {
            Err(format!(
                "{value} does not fit 0x{index:04X} ({data_type:?}: {lo}..={hi})"
            ))
        }
    };
    let label = match pa_number(index) {
        Some(n) => format!("PA{n} (0x{index:04X}) = {value}"),
        None => format!("0x{index:04X} = {value}"),
    };
    let pdu = match data_type {
        DataType::U16 => {
            fits(0, 0xFFFF)?;
            Pdu::write_single(index, value as u16)
        }
        DataType::I16 => {
            fits(i64::from(i16::MIN), i64::from(i16::MAX))?;
            Pdu::write_single(index, value as i16 as u16)
        }
        DataType::U32 => {
            fits(0, i64::from(u32::MAX))?;
            Pdu::write_multiple(index, &Pdu::words32(value as u32, low_first))
        }
        DataType::I32 => {
            fits(i64::from(i32::MIN), i64::from(i32::MAX))?;
            Pdu::write_multiple(index, &Pdu::words32(value as i32 as u32, low_first))
        }
        DataType::Str => return Err(format!("0x{index:04X} is a string")),
    };
    Ok(step(label, pdu))
}

/// PA number of a legacy address in 0x0064..=0x009F.
pub fn pa_number(index: u16) -> Option<usize> {
    let n = usize::from(index.checked_sub(PA_BASE)?);
    (n < PA_COUNT).then_some(n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use modbus_drive::device::Identity;

    fn pdus(cmd: Command, device: &Device) -> Vec<Vec<u8>> {
        requests(&cmd, Ctx::of(device))
            .unwrap()
            .into_iter()
            .map(|s| s.pdu.0)
            .collect()
    }

    #[test]
    fn writes_take_the_registers_width_and_word_order() {
        let mut d = Device::new(Identity::new("t"));
        let w = |d: &Device, index, value| pdus(Command::Write { index, value }, d);
        assert_eq!(w(&d, 0x6060, 3), [vec![0x06, 0x60, 0x60, 0x00, 0x03]]);
        assert_eq!(w(&d, 0x605A, -1), [vec![0x06, 0x60, 0x5A, 0xFF, 0xFF]]);
        assert_eq!(
            w(&d, 0x0064 + 12, 1500),
            [vec![0x06, 0x00, 0x70, 0x05, 0xDC]]
        );
        assert_eq!(
            w(&d, 0x607A, 200_000),
            [vec![
                0x10, 0x60, 0x7A, 0x00, 0x02, 0x04, 0x00, 0x03, 0x0D, 0x40
            ]]
        );
        d.configure(|_, od| od.set_word_order(1));
        assert_eq!(
            w(&d, 0x607A, 200_000),
            [vec![
                0x10, 0x60, 0x7A, 0x00, 0x02, 0x04, 0x0D, 0x40, 0x00, 0x03
            ]]
        );
        // Unknown registers go to the dispatcher (which answers 11).
        assert_eq!(w(&d, 0x6090, 3), [vec![0x06, 0x60, 0x90, 0x00, 0x03]]);
        // What no frame can carry is refused here.
        for (index, value) in [(0x6083, 70_000), (0x6060, 40_000), (0x607A, 1 << 40)] {
            assert!(requests(&Command::Write { index, value }, Ctx::of(&d)).is_err());
        }
        assert!(requests(
            &Command::Write {
                index: 0x1008,
                value: 0
            },
            Ctx::of(&d)
        )
        .is_err());
    }

    #[test]
    fn motion_needs_an_enabled_drive_and_latches_with_a_bit_4_edge() {
        let d = Device::new(Identity::new("t"));
        let p = Profile {
            speed: 100,
            accel: 50,
        };
        let mv = Command::Move {
            target: 5000,
            relative: false,
            profile: p,
        };
        assert!(requests(&mv, Ctx::of(&d)).unwrap_err().contains("enable"));
        assert!(requests(&Command::Home, Ctx::of(&d)).is_err());
        assert_eq!(
            pdus(Command::Enable, &d),
            [0x06, 0x07, 0x0F].map(|c| vec![0x06, 0x60, 0x40, 0x00, c])
        );
        assert_eq!(
            pdus(Command::FaultReset, &d),
            [0x00, 0x80].map(|c| vec![0x06, 0x60, 0x40, 0x00, c])
        );
    }
}
