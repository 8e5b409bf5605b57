//! The dispatcher against a drive-layer double: live entries are read
//! through [`DriveLayer`], and an accepted write tells it values, then mode,
//! then controlword (SPEC §5, §5.2).

mod common;
use common::{frame, with_crc, write_pdu};
use modbus_drive::dictionary::{Config, DriveLayer, Identity, OdValues, Registers};
use modbus_drive::params::Params;
use modbus_drive::rtu::{RxEvent, MAX_FRAME};
use modbus_drive::slave::{Response, Slave};

#[derive(Debug, Clone, PartialEq)]
enum Call {
    Values { target: i32, velocity: i32 },
    Mode(i16),
    Controlword { cw: u16, target: i32 },
}

#[derive(Default)]
struct Double {
    statusword: u16,
    mode: i16,
    position: i32,
    velocity_rpm: i32,
    error: u16,
    calls: Vec<Call>,
}

impl DriveLayer for Double {
    fn statusword(&self) -> u16 {
        self.statusword
    }
    fn mode_display(&self) -> i16 {
        self.mode
    }
    fn actual_position(&self) -> i32 {
        self.position
    }
    fn actual_velocity_rpm(&self) -> i32 {
        self.velocity_rpm
    }
    fn error_register(&self) -> u16 {
        self.error
    }
    fn values_written(&mut self, cfg: Config<'_>) {
        self.calls.push(Call::Values {
            target: cfg.od().target_position(),
            velocity: cfg.od().profile_velocity(),
        });
    }
    fn mode_written(&mut self, mode: i16, _cfg: Config<'_>) {
        self.calls.push(Call::Mode(mode));
    }
    fn controlword_written(&mut self, cw: u16, cfg: Config<'_>) {
        self.calls.push(Call::Controlword {
            cw,
            target: cfg.od().target_position(),
        });
    }
}

struct Rig {
    slave: Slave,
    od: OdValues,
    pa: Params,
    drive: Double,
    identity: Identity,
}

impl Rig {
    fn new() -> Self {
        Self {
            slave: Slave::new(),
            od: OdValues::default(),
            pa: Params::defaults(),
            drive: Double::default(),
            identity: Identity::new("double"),
        }
    }

    /// One whole frame through the dispatcher at address 1.
    fn frame(&mut self, bytes: &[u8]) -> Option<Vec<u8>> {
        let mut regs = Registers::new(&mut self.od, &mut self.pa, &mut self.drive, &self.identity);
        let mut reply = [0u8; MAX_FRAME];
        let rx = RxEvent::Frame {
            bytes,
            parity_error: false,
        };
        match self.slave.handle(rx, 1, &mut regs, &mut reply).response() {
            Response::Reply(n) => Some(reply[..n].to_vec()),
            Response::Silent => None,
        }
    }
}

#[test]
fn live_entries_are_read_from_the_drive_layer_in_both_word_orders() {
    let mut rig = Rig::new();
    rig.drive = Double {
        statusword: 0x1637,
        mode: 6,
        position: -200_000, // 0xFFFC_F2C0
        velocity_rpm: -600, // 0xFFFF_FDA8
        error: 0x0011,
        calls: Vec::new(),
    };
    // 0x6041, 0x6061, 0x6064 (2), 0x606C (2) in table order.
    let read = frame(1, &[0x03, 0x60, 0x41, 0x00, 0x06]);
    assert_eq!(
        rig.frame(&read),
        Some(frame(
            1,
            &[0x03, 12, 0x16, 0x37, 0x00, 0x06, 0xFF, 0xFC, 0xF2, 0xC0, 0xFF, 0xFF, 0xFD, 0xA8]
        ))
    );
    rig.od.set_word_order(1);
    assert_eq!(
        rig.frame(&read),
        Some(frame(
            1,
            &[0x03, 12, 0x16, 0x37, 0x00, 0x06, 0xF2, 0xC0, 0xFF, 0xFC, 0xFD, 0xA8, 0xFF, 0xFF]
        ))
    );
    assert_eq!(
        rig.frame(&frame(1, &[0x03, 0x10, 0x01, 0x00, 0x01])),
        Some(frame(1, &[0x03, 0x02, 0x00, 0x11]))
    );
    assert!(rig.drive.calls.is_empty(), "reads act on nothing");
}

#[test]
fn controlword_acts_after_mode_after_values() {
    // Seed 000's programming example: controlword 0x000F and target 200000
    // in one request; the controlword must see the new target (§5.2).
    let mut rig = Rig::new();
    let req = [
        0x01, 0x10, 0x60, 0x40, 0x00, 0x09, 0x12, 0x00, 0x0F, 0x00, 0x01, 0x00, 0x00, 0x00, 0x64,
        0x00, 0x64, 0x00, 0x64, 0x00, 0x64, 0x00, 0x03, 0x0D, 0x40,
    ];
    assert!(rig.frame(&with_crc(&req)).is_some());
    assert_eq!(
        rig.drive.calls,
        vec![
            Call::Values {
                target: 200_000,
                velocity: 100
            },
            Call::Mode(1),
            Call::Controlword {
                cw: 0x000F,
                target: 200_000
            },
        ]
    );
}

#[test]
fn only_written_mode_and_controlword_are_signalled() {
    let mut rig = Rig::new();
    assert!(rig.frame(&frame(1, &write_pdu(0x607A, &[0, 5]))).is_some());
    assert_eq!(
        rig.drive.calls,
        vec![Call::Values {
            target: 5,
            velocity: 0
        }]
    );
    rig.drive.calls.clear();
    assert!(rig
        .frame(&frame(1, &[0x06, 0x60, 0x40, 0x00, 0x06]))
        .is_some());
    assert_eq!(
        rig.drive.calls,
        vec![
            Call::Values {
                target: 5,
                velocity: 0
            },
            Call::Controlword { cw: 6, target: 5 }
        ]
    );
    rig.drive.calls.clear();
    // A PA write is a value change too (steps per revolution, speed cap…).
    assert!(rig
        .frame(&frame(1, &[0x06, 0x00, 0x6E, 0x0F, 0xA0]))
        .is_some());
    assert_eq!(rig.pa.steps_per_rev(), 4000);
    assert_eq!(rig.drive.calls.len(), 1);
}

#[test]
fn rejected_and_broadcast_requests() {
    let mut rig = Rig::new();
    // Refused: nothing stored, the drive layer hears nothing.
    let bad = frame(1, &write_pdu(0x6060, &[7]));
    assert_eq!(rig.frame(&bad), Some(frame(1, &[0x90, 0x03])));
    assert!(rig.drive.calls.is_empty());
    assert_eq!(rig.od, OdValues::default());
    // Broadcast: executed, silent, the drive layer acts.
    assert_eq!(rig.frame(&frame(0, &[0x06, 0x60, 0x40, 0x00, 0x0F])), None);
    assert_eq!(
        rig.drive.calls,
        vec![
            Call::Values {
                target: 0,
                velocity: 0
            },
            Call::Controlword { cw: 15, target: 0 }
        ]
    );
}

#[test]
fn a_frame_event_shorter_than_four_bytes_is_not_trusted() {
    // The assembler never hands these over; the dispatcher still must not
    // index past them.
    let mut rig = Rig::new();
    for bytes in [&[][..], &[1], &[1, 3], &[1, 3, 0]] {
        assert_eq!(rig.frame(bytes), None);
    }
    assert_eq!(rig.slave.counters().bus_errors(), 4);
}
