//! A sequence of frames driving the drive state machine and motion with
//! time advancing (SPEC §5, §8), on the core's simulated axis the way the
//! glue runs it, through the simulation host (`SimHost`): `Device::control`
//! when `Device::poll_at` says, at switch edges and after every frame, the
//! step interrupt (`StepSource` inside `SimAxis`) making every step due.
//!
//! Input: switch layout, then operations `op a b c d`: `op % 8` = 0..=4 a
//! register write or read from a template of drive registers (values from
//! `a..d`, a tenth of them broadcast), 5 raw bytes with a valid CRC, 6 and 7
//! time advancing by up to 64 ms.
//!
//! Checks: everything the dispatcher target checks on each frame (no reply
//! to a foreign or broadcast address, refused requests change nothing), the
//! statusword is one of the eight §8.1 states after every frame and every
//! control period, and the step schedule never goes backwards in time:
//! every step's timer tick and exact scheduled time are at or after the
//! previous step's.

use super::dispatcher::{check_frame, statusword_is_a_state};
use super::Input;
use modbus_drive::device::sim::SimHost;
use modbus_drive::device::{Identity, CONTROL_PERIOD_US};
use modbus_drive::dictionary::DriveLayer;
use modbus_drive::motion::sim::SimAxis;
use modbus_drive::motion::{PlannerConfig, StepSchedule};
use modbus_drive::rtu::crc16;
use modbus_drive::Device;

/// Controlwords worth trying (§8.1 seed and CiA sequences, halt, set-point
/// bits 4/5/6/9, fault reset, quick stop, disable).
const CONTROLWORDS: [u16; 16] = [
    0x0006, 0x0007, 0x000F, 0x001F, 0x003F, 0x005F, 0x007F, 0x021F, 0x010F, 0x0080, 0x0000, 0x0002,
    0x000B, 0x0001, 0x0003, 0x004F,
];

fn frame(address: u8, pdu: &[u8]) -> Vec<u8> {
    let mut f = Vec::with_capacity(pdu.len() + 3);
    f.push(address);
    f.extend_from_slice(pdu);
    let crc = crc16(&f);
    f.extend_from_slice(&crc.to_le_bytes());
    f
}

fn write_1(index: u16, value: u16) -> Vec<u8> {
    let [i0, i1] = index.to_be_bytes();
    let [v0, v1] = value.to_be_bytes();
    vec![0x06, i0, i1, v0, v1]
}

fn write_32(index: u16, value: u32) -> Vec<u8> {
    let [i0, i1] = index.to_be_bytes();
    let [a, b, c, d] = value.to_be_bytes(); // word order 0: high word first
    vec![0x10, i0, i1, 0, 2, 4, a, b, c, d]
}

/// A request PDU from the template `kind` with values from `v`.
fn template(kind: u8, v: [u8; 4]) -> Vec<u8> {
    let w = u16::from_be_bytes([v[0], v[1]]);
    let small = u16::from(v[1]) * 4; // 0.1 rev/s(²), 0..=1020
    let big = u32::from_be_bytes(v);
    match kind % 20 {
        0..=3 => write_1(0x6040, CONTROLWORDS[usize::from(v[0] % 16)]),
        4 => write_1(0x6060, [1, 3, 6, w][usize::from(v[2] % 4)]),
        5 => write_32(0x6081, (i32::from(v[1] as i8) * 8) as u32), // ±1024 = ±102 rev/s
        6 => write_1(0x6083, small),
        7 => write_1(0x6084, small),
        8 => write_1(0x6085, small),
        9 => write_32(0x607A, (big as i32 >> 12) as u32), // ±2^19 steps
        10 => write_1(0x605A, u16::from(v[0] % 5)),
        11 => write_1(0x6098, u16::from(v[0] % 9)),
        12 => write_32(0x6099, u32::from(small)),
        13 => write_32(0x609B, u32::from(small / 4)),
        14 => write_1(0x609A, small),
        15 => write_32(0x607C, (i32::from(v[1] as i8) * 64) as u32),
        // PA10 steps/rev, PA12 max speed, PA14 limit enable, PA20 comm loss
        16 => write_1(0x0064 + 10, [200, 400, 1600, 10_000][usize::from(v[0] % 4)]),
        17 => write_1(0x0064 + 12, 1 + w % 600),
        18 => write_1(
            0x0064 + [14, 20][usize::from(v[0] % 2)],
            u16::from(v[1] % 4) * 10,
        ),
        _ => vec![
            0x03,
            0x60,
            [0x41, 0x64][usize::from(v[0] % 2)],
            0,
            1 + v[2] % 2,
        ],
    }
}

pub fn run(data: &[u8]) {
    let mut input = Input::new(data);
    let layout = input.u8();
    let cfg = PlannerConfig::default();
    let mut axis = SimAxis::new(cfg.tick_hz());
    if layout & 1 != 0 {
        axis = axis.with_cw_limit(-i64::from(input.u8()) * 50);
    }
    if layout & 2 != 0 {
        axis = axis.with_ccw_limit(i64::from(input.u8()) * 50);
    }
    if layout & 4 != 0 {
        let from = i64::from(input.u8() as i8) * 20;
        axis = axis.with_home(from, from + i64::from(input.u8()));
    }
    let mut device = Device::new(Identity::new("fuzz"));
    let sched = StepSchedule::new();
    let mut reply = [0u8; modbus_drive::rtu::MAX_FRAME];
    let mut now_us: u64 = 0;
    let mut last_step: Option<(u64, u64)> = None;

    for _ in 0..64 {
        if input.is_empty() {
            break;
        }
        let op = input.u8();
        let v = [input.u8(), input.u8(), input.u8(), input.u8()];
        match op % 8 {
            0..=5 => {
                let address = if v[3].is_multiple_of(10) {
                    0
                } else {
                    device.address()
                };
                let bytes = if op % 8 == 5 {
                    let n = usize::from(v[0] % 12);
                    let mut pdu = input.bytes(n).to_vec();
                    pdu.insert(0, v[1]);
                    frame(address, &pdu)
                } else {
                    frame(address, &template(v[0] ^ (op >> 3), v))
                };
                check_frame(&mut device, &bytes, false, &mut reply);
                device.reply_sent();
                SimHost::new(&mut device, &mut axis, &sched).control(now_us);
            }
            _ => {
                let until_us = now_us + u64::from(v[0] % 64 + 1) * CONTROL_PERIOD_US;
                // one control period (and the switch edges in it) a turn
                while device.poll_at() <= until_us {
                    now_us = device.poll_at();
                    let on_step = |step: modbus_drive::motion::sim::StepRecord| {
                        if let Some((tick, exact)) = last_step {
                            assert!(
                                step.tick() >= tick,
                                "step at tick {} after {tick}",
                                step.tick()
                            );
                            assert!(
                                step.exact().wrapping_sub(exact) as i64 >= 0,
                                "step scheduled at {:#x} after {exact:#x}",
                                step.exact()
                            );
                        }
                        last_step = Some((step.tick(), step.exact()));
                    };
                    SimHost::new(&mut device, &mut axis, &sched).run_to(now_us, on_step);
                    while device.take_event().is_some() {}
                    let sw = device.drive().statusword();
                    assert!(statusword_is_a_state(sw), "statusword {sw:#06X}");
                }
            }
        }
    }
}
