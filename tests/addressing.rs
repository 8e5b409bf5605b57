//! Own address, broadcast, foreign addresses (SPEC §2) and the deferred
//! address / line change (SPEC §7).

mod common;
use common::*;
use modbus_drive::dictionary::OdValues;
use modbus_drive::event::{Event, FrameError};
use modbus_drive::rtu::{CharFormat, LineConfig};

#[test]
fn broadcast_writes_are_executed_and_never_answered() {
    let mut bus = Bus::new();
    assert_eq!(bus.request(0, &[0x06, 0x60, 0x83, 0x00, 0x64]), None);
    assert_eq!(bus.device.od().acceleration(), 100);
    assert_eq!(bus.request(0, &write_pdu(0x607A, &[0x0003, 0x0D40])), None);
    assert_eq!(bus.device.od().target_position(), 200_000);
    assert!(bus.sent.is_empty());
    let c = bus.device.slave().counters().clone();
    assert_eq!(
        (c.slave_messages(), c.no_response(), c.exceptions()),
        (2, 2, 0)
    );
}

#[test]
fn a_broadcast_that_fails_validation_changes_nothing_and_is_counted() {
    let mut bus = Bus::new();
    // 0x6083 = 5 valid, then 0x6060 … no: 0x605A = -1 refused (code 3).
    assert_eq!(bus.request(0, &write_pdu(0x605A, &[0xFFFF])), None);
    assert_eq!(bus.request(0, &[0x06, 0x60, 0x41, 0x00, 0x00]), None); // RO
    assert_eq!(bus.device.od(), &OdValues::default());
    assert!(bus.sent.is_empty());
    assert_eq!(bus.device.slave().counters().exceptions(), 2);
    let refused: Vec<_> = bus
        .events()
        .into_iter()
        .filter(|e| {
            matches!(
                e,
                Event::Exception {
                    answered: false,
                    ..
                }
            )
        })
        .collect();
    assert_eq!(refused.len(), 2);
}

#[test]
fn broadcast_reads_and_other_functions_are_ignored() {
    let mut bus = Bus::new();
    assert_eq!(bus.request(0, &[0x03, 0x60, 0x7A, 0x00, 0x02]), None);
    assert_eq!(bus.request(0, &[0x08, 0x00, 0x04, 0x00, 0x00]), None);
    assert!(!bus.device.slave().listen_only(), "0x08/0x04 not executed");
    assert_eq!(bus.request(0, &[0x2B, 0x0E, 0x01, 0x00]), None);
    assert_eq!(bus.request(0, &[0x41]), None, "no exception 1 either");
    let c = bus.device.slave().counters().clone();
    assert_eq!(
        (c.slave_messages(), c.no_response(), c.exceptions()),
        (4, 4, 0)
    );
    // Still answering unicast.
    assert_eq!(bus.read(0x6000, 1), Ok(vec![0]));
}

#[test]
fn foreign_addresses_are_silent_even_with_a_bad_crc() {
    let mut bus = Bus::new();
    for address in [2, 17, 247, 248, 250, 255] {
        let f = frame(address, &[0x06, 0x60, 0x83, 0x00, 0x64]);
        assert_eq!(bus.send(&f), None, "address {address}");
        let mut bad = f.clone();
        bad[6] ^= 0x5A;
        assert_eq!(bus.send(&bad), None, "address {address}, bad CRC");
        // a request that would be an exception at our address
        assert_eq!(bus.request(address, &[0x03, 0x60, 0x90, 0x00, 0x01]), None);
    }
    assert_eq!(bus.device.od().acceleration(), 0);
    let c = bus.device.slave().counters().clone();
    assert_eq!(c.bus_messages(), 12, "good frames on the bus");
    assert_eq!(c.bus_errors(), 6, "CRC errors on the bus");
    assert_eq!(c.slave_messages(), 0);
    assert!(bus.events().iter().all(|e| matches!(
        e,
        Event::FrameError {
            kind: FrameError::Crc,
            answered: false,
            ..
        }
    )));
}

#[test]
fn addresses_248_to_255_are_never_ours() {
    // PA51 cannot hold them (§2, §7).
    let mut bus = Bus::new();
    for a in 248..=255u16 {
        assert_eq!(bus.write_single(0x0064 + 51, a), Err(3));
    }
    assert_eq!(bus.device.address(), 1);
}

#[test]
fn address_change_is_answered_from_the_old_address_then_effective() {
    // SPEC §7: PA51 = 5 written at address 1.
    let mut bus = Bus::new();
    let req = frame(1, &[0x06, 0x00, 0x97, 0x00, 0x05]); // 0x0064 + 51
    assert_eq!(bus.send(&req), Some(req.clone()), "echo from address 1");
    assert_eq!(bus.device.address(), 5);
    assert!(bus.events().contains(&Event::AddressChanged { address: 5 }));
    assert_eq!(bus.request(1, &[0x03, 0x00, 0x97, 0x00, 0x01]), None);
    assert_eq!(
        bus.request(5, &[0x03, 0x00, 0x97, 0x00, 0x01]),
        Some(frame(5, &[0x03, 0x02, 0x00, 0x05]))
    );
}

#[test]
fn address_in_force_is_used_until_the_reply_has_gone() {
    // Between the write and `reply_sent` the old address still holds.
    use modbus_drive::device::{Device, Identity, Response};
    use modbus_drive::rtu::{RxEvent, MAX_FRAME};
    let mut dev = Device::new(Identity::new(TEST_HARDWARE));
    let mut reply = [0u8; MAX_FRAME];
    let req = frame(1, &[0x06, 0x00, 0x97, 0x00, 0x05]);
    let rx = RxEvent::Frame {
        bytes: &req,
        parity_error: false,
    };
    assert_eq!(dev.handle_rx(rx, &mut reply), Response::Reply(8));
    assert_eq!(dev.address(), 1);
    assert_eq!(dev.params().address(), 5, "the parameter itself is written");
    assert_eq!(dev.reply_sent(), None, "the line did not change");
    assert_eq!(dev.address(), 5);
}

#[test]
fn de_lead_and_tail_take_effect_after_the_reply() {
    // PA57 = 3 (0x0064 + 57): the reply to the write still goes out with
    // the DE lead / tail in force; `reply_sent` then hands the glue the
    // line (unchanged) to apply with the new ones, once.
    use modbus_drive::device::{Device, Identity, Response};
    use modbus_drive::rtu::{DriverEnable, RxEvent, MAX_FRAME};
    let mut dev = Device::new(Identity::new(TEST_HARDWARE));
    let line = dev.line();
    let mut reply = [0u8; MAX_FRAME];
    let req = frame(1, &[0x06, 0x00, 0x9D, 0x00, 0x03]);
    let rx = RxEvent::Frame {
        bytes: &req,
        parity_error: false,
    };
    assert_eq!(dev.handle_rx(rx, &mut reply), Response::Reply(8));
    assert_eq!(dev.driver_enable(), DriverEnable::new(1, 1));
    assert_eq!(dev.params().driver_enable(), DriverEnable::new(3, 1));
    assert_eq!(
        dev.reply_sent(),
        Some(line),
        "apply the line with the new DE"
    );
    assert_eq!(dev.driver_enable(), DriverEnable::new(3, 1));
    assert_eq!(dev.reply_sent(), None, "nothing changed since");
}

#[test]
fn baud_change_takes_effect_after_the_reply() {
    // PA52 = 0 (9600) written at 115200: the reply goes out at 115200
    // timing, the next request is received at 9600 timing.
    let mut bus = Bus::new();
    let req = frame(1, &[0x06, 0x00, 0x98, 0x00, 0x00]); // 0x0064 + 52
    assert_eq!(bus.send(&req), Some(req.clone()));
    let sent = bus.sent.last().unwrap().clone();
    assert_eq!(sent.start_us - sent.request_end_us, 1750, "old t3.5");
    assert_eq!(bus.device.line(), LineConfig::new(9600, CharFormat::N1));
    assert_eq!(bus.timing().t35_us(), 3646);
    assert_eq!(bus.read(0x0098, 1), Ok(vec![0]));
    let sent = bus.sent.last().unwrap().clone();
    assert_eq!(sent.start_us - sent.request_end_us, 3646, "new t3.5");
    // A format change (PA53 = 1, 8E1) is deferred the same way.
    assert_eq!(bus.write_single(0x0099, 1), Ok(()));
    assert_eq!(bus.device.line().format(), CharFormat::E1);
}

#[test]
fn response_delay_pa56_adds_to_t35() {
    let mut bus = Bus::with_params(|pa| pa.set_unchecked(56, 3));
    assert_eq!(bus.read(0x6000, 1), Ok(vec![0]));
    let sent = bus.sent.last().unwrap();
    assert_eq!(sent.start_us - sent.request_end_us, 1750 + 3000);
}

#[test]
fn device_with_another_address_answers_only_it() {
    let mut bus = Bus::with_params(|pa| pa.set_unchecked(51, 247));
    assert_eq!(bus.request(1, &[0x03, 0x60, 0x00, 0x00, 0x01]), None);
    assert_eq!(
        bus.request(247, &[0x03, 0x60, 0x00, 0x00, 0x01]),
        Some(frame(247, &[0x03, 0x02, 0x00, 0x00]))
    );
    // CRC errors are answered at the own address only.
    let mut f = frame(247, &[0x03, 0x60, 0x00, 0x00, 0x01]);
    f[7] ^= 1;
    assert_eq!(bus.send(&f), Some(exception(247, 0x03, 10)));
}
