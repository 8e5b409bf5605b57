//! Function 0x08 diagnostics with the §6 counters, listen-only mode and
//! restart, and 0x2B/0x0E device identification (SPEC §4, §6).

mod common;
use common::*;
use modbus_drive::event::Event;

fn diag(bus: &mut Bus, sub: u16, data: u16) -> Option<Vec<u8>> {
    let mut pdu = vec![0x08];
    pdu.extend_from_slice(&sub.to_be_bytes());
    pdu.extend_from_slice(&data.to_be_bytes());
    bus.request(1, &pdu)
}

/// The counter sub-function `sub` returns.
fn counter(bus: &mut Bus, sub: u16) -> u16 {
    let r = diag(bus, sub, 0).expect("a reply");
    assert_eq!(&r[..4], &[0x01, 0x08, 0x00, sub as u8]);
    u16::from_be_bytes([r[4], r[5]])
}

#[test]
fn return_query_data_echoes_any_data() {
    let mut bus = Bus::new();
    for pdu in [
        vec![0x08, 0x00, 0x00, 0xA5, 0x37],
        vec![0x08, 0x00, 0x00],
        vec![0x08, 0x00, 0x00, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10],
    ] {
        assert_eq!(bus.request(1, &pdu), Some(frame(1, &pdu)));
    }
}

#[test]
fn counters_follow_appendix_a() {
    let mut bus = Bus::new();
    // Traffic: 2 good requests to us, 1 exception, 1 broadcast write,
    // 1 frame for another slave, 1 CRC error at us, 1 broken frame,
    // 1 too short frame, 1 overrun.
    assert_eq!(bus.read(0x6000, 1), Ok(vec![0]));
    assert_eq!(bus.write_single(0x6083, 5), Ok(()));
    assert_eq!(bus.read(0x6090, 1), Err(11));
    assert_eq!(bus.request(0, &[0x06, 0x60, 0x84, 0x00, 0x05]), None);
    assert_eq!(bus.request(9, &[0x03, 0x60, 0x00, 0x00, 0x01]), None);
    let mut bad = frame(1, &[0x03, 0x60, 0x00, 0x00, 0x01]);
    bad[2] ^= 1;
    assert_eq!(bus.send(&bad), Some(exception(1, 0x03, 10)));
    bus.feed_gapped([(1, 0), (3, 0), (0x60, 1_000), (0, 0)]);
    bus.idle(20_000);
    assert_eq!(bus.send(&[1, 3]), None);
    assert_eq!(bus.send(&[0; 300]), None);

    // Each counter read counts itself as a bus and slave message first.
    assert_eq!(counter(&mut bus, 0x0B), 6, "bus messages");
    assert_eq!(counter(&mut bus, 0x0C), 3, "bus errors: CRC, broken, short");
    assert_eq!(counter(&mut bus, 0x0D), 2, "exceptions: 11 and 10");
    assert_eq!(counter(&mut bus, 0x0E), 8, "slave messages");
    assert_eq!(counter(&mut bus, 0x0F), 1, "no response: the broadcast");
    assert_eq!(counter(&mut bus, 0x10), 0, "NAK: never");
    assert_eq!(counter(&mut bus, 0x11), 0, "busy");
    assert_eq!(counter(&mut bus, 0x12), 1, "overruns");

    bus.device.set_storage_busy(true);
    assert_eq!(bus.read(0x6000, 1), Err(6));
    bus.device.set_storage_busy(false);
    assert_eq!(counter(&mut bus, 0x11), 1, "busy");
}

#[test]
fn clear_counters_0x0a_echoes_then_clears() {
    let mut bus = Bus::new();
    assert_eq!(bus.read(0x6090, 1), Err(11));
    assert_eq!(
        diag(&mut bus, 0x0A, 0),
        Some(frame(1, &[0x08, 0x00, 0x0A, 0x00, 0x00]))
    );
    assert!(bus.events().contains(&Event::CountersCleared));
    assert_eq!(counter(&mut bus, 0x0D), 0);
    assert_eq!(counter(&mut bus, 0x0E), 2, "the two counter reads since");
    assert_eq!(diag(&mut bus, 0x0A, 1), Some(exception(1, 0x08, 3)));
}

#[test]
fn listen_only_mode_swallows_everything_until_restart() {
    let mut bus = Bus::new();
    assert_eq!(diag(&mut bus, 0x04, 0), None, "0x04 is never answered");
    assert!(bus.device.slave().listen_only());
    assert!(bus.events().contains(&Event::ListenOnly(true)));
    // Nothing acts, nothing answers — not even exceptions or CRC errors.
    assert_eq!(bus.request(1, &[0x06, 0x60, 0x83, 0x00, 0x64]), None);
    assert_eq!(bus.device.od().acceleration(), 0);
    assert_eq!(bus.request(0, &[0x06, 0x60, 0x83, 0x00, 0x64]), None);
    assert_eq!(bus.device.od().acceleration(), 0, "broadcasts neither");
    assert_eq!(bus.request(1, &[0x03, 0x60, 0x90, 0x00, 0x01]), None);
    let mut bad = frame(1, &[0x03, 0x60, 0x00, 0x00, 0x01]);
    bad[3] ^= 1;
    assert_eq!(bus.send(&bad), None);
    assert_eq!(diag(&mut bus, 0x0B, 0), None);
    assert_eq!(diag(&mut bus, 0x0A, 0), None);
    // Counters keep counting meanwhile.
    assert_eq!(bus.device.slave().counters().no_response(), 6);
    assert_eq!(bus.device.slave().counters().bus_errors(), 1);
    // Restart leaves the mode without a reply and clears the counters.
    assert_eq!(diag(&mut bus, 0x01, 0xFF00), None);
    assert!(!bus.device.slave().listen_only());
    assert!(bus.events().contains(&Event::ListenOnly(false)));
    assert_eq!(bus.device.slave().counters(), &Default::default());
    assert_eq!(bus.write_single(0x6083, 100), Ok(()));
}

#[test]
fn restart_when_listening_normally_answers_then_clears() {
    let mut bus = Bus::new();
    assert_eq!(bus.read(0x6090, 1), Err(11));
    for data in [0x0000, 0xFF00] {
        assert_eq!(
            diag(&mut bus, 0x01, data),
            Some(frame(1, &[0x08, 0x00, 0x01, (data >> 8) as u8, 0x00]))
        );
        assert_eq!(bus.device.slave().counters(), &Default::default());
    }
    assert_eq!(diag(&mut bus, 0x01, 0x1234), Some(exception(1, 0x08, 3)));
    assert_eq!(diag(&mut bus, 0x04, 0x0001), Some(exception(1, 0x08, 3)));
    assert!(!bus.device.slave().listen_only());
}

#[test]
fn unsupported_sub_functions_are_exception_1() {
    let mut bus = Bus::new();
    for sub in [0x02, 0x03, 0x09, 0x13, 0x14, 0x15, 0xFFFF] {
        assert_eq!(
            diag(&mut bus, sub, 0),
            Some(exception(1, 0x08, 1)),
            "sub {sub:#x}"
        );
    }
}

// ---- 0x2B / 0x0E ----

/// The basic objects of a device built with `Identity::new(TEST_HARDWARE)`.
fn objects() -> [Vec<u8>; 3] {
    [
        b"modbus-drive".to_vec(),
        TEST_HARDWARE.as_bytes().to_vec(),
        env!("CARGO_PKG_VERSION").as_bytes().to_vec(),
    ]
}

fn id_reply(code: u8, ids: &[u8]) -> Vec<u8> {
    let mut pdu = vec![0x2B, 0x0E, code, 0x81, 0x00, 0x00, ids.len() as u8];
    for &id in ids {
        let v = &objects()[usize::from(id)];
        pdu.push(id);
        pdu.push(v.len() as u8);
        pdu.extend_from_slice(v);
    }
    frame(1, &pdu)
}

#[test]
fn basic_stream_returns_objects_0_to_2() {
    let mut bus = Bus::new();
    assert_eq!(
        bus.request(1, &[0x2B, 0x0E, 0x01, 0x00]),
        Some(id_reply(1, &[0, 1, 2]))
    );
    assert_eq!(
        bus.request(1, &[0x2B, 0x0E, 0x01, 0x01]),
        Some(id_reply(1, &[1, 2]))
    );
    // Unknown start object: the stream restarts at 0.
    assert_eq!(
        bus.request(1, &[0x2B, 0x0E, 0x01, 0x80]),
        Some(id_reply(1, &[0, 1, 2]))
    );
    // Regular and extended stream: answered at the basic level.
    assert_eq!(
        bus.request(1, &[0x2B, 0x0E, 0x02, 0x00]),
        Some(id_reply(2, &[0, 1, 2]))
    );
    assert_eq!(
        bus.request(1, &[0x2B, 0x0E, 0x03, 0x00]),
        Some(id_reply(3, &[0, 1, 2]))
    );
}

#[test]
fn individual_access_returns_one_object_or_exception_2() {
    let mut bus = Bus::new();
    for id in 0..=2 {
        assert_eq!(
            bus.request(1, &[0x2B, 0x0E, 0x04, id]),
            Some(id_reply(4, &[id]))
        );
    }
    for id in [3, 0x80, 0xFF] {
        assert_eq!(
            bus.request(1, &[0x2B, 0x0E, 0x04, id]),
            Some(exception(1, 0x2B, 2))
        );
    }
}

#[test]
fn identification_objects_match_the_string_registers() {
    // SPEC §4: objects 0..2 come from 0x1008 / 0x1009 / 0x100A.
    let mut bus = Bus::new();
    for (i, reg) in [0x1008u16, 0x1009, 0x100A].into_iter().enumerate() {
        let words = bus.read(reg, 8).expect("string entry");
        let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_be_bytes()).collect();
        let mut expect = objects()[i].clone();
        expect.resize(16, 0);
        assert_eq!(
            bytes, expect,
            "{reg:#06x}: first char in the high byte, NUL padded"
        );
    }
    // All three strings in one read of 24 words.
    assert_eq!(bus.read(0x1008, 24).map(|w| w.len()), Ok(24));
}
