//! Frame timing through assembler and dispatcher (SPEC §1): broken frames,
//! frames back to back, gaps just under t1.5, 9600 vs 115200 baud.

mod common;
use common::*;
use modbus_drive::event::{Event, FrameError};

const REQ: &str = "01 03 60 7A 00 02 FB D2";
const REPLY: &str = "01 03 04 00 00 00 00 FA 33";

/// `REQ` with a silence of `gap_us` before byte `at`.
fn with_gap(at: usize, gap_us: u32) -> Vec<(u8, u32)> {
    hex(REQ)
        .into_iter()
        .enumerate()
        .map(|(i, b)| (b, if i == at { gap_us } else { 0 }))
        .collect()
}

fn bus_at(pa52: u16) -> Bus {
    Bus::with_params(|pa| pa.set_unchecked(52, pa52))
}

#[test]
fn reply_of_the_reference_read() {
    let mut bus = Bus::new();
    assert_eq!(bus.send(&hex(REQ)), Some(hex(REPLY)));
}

#[test]
fn a_gap_over_t15_breaks_the_frame_it_is_discarded_and_counted() {
    for pa52 in [0, 4] {
        let mut bus = bus_at(pa52);
        let t15 = bus.timing().t15_us();
        bus.idle(50_000);
        assert!(bus.feed_gapped(with_gap(4, t15 + 1)).is_empty());
        bus.idle(50_000);
        assert!(bus.sent.is_empty(), "PA52 = {pa52}");
        assert_eq!(bus.device.slave().counters().bus_errors(), 1);
        assert_eq!(bus.device.slave().counters().bus_messages(), 0);
        assert!(bus.events().contains(&Event::FrameError {
            kind: FrameError::Broken,
            address: None,
            answered: false
        }));
    }
}

#[test]
fn a_gap_just_under_t15_keeps_the_frame() {
    for pa52 in [0, 1, 2, 4] {
        let mut bus = bus_at(pa52);
        let t15 = bus.timing().t15_us();
        bus.idle(50_000);
        bus.feed_gapped(with_gap(4, t15 - 1));
        bus.idle(50_000);
        assert_eq!(bus.sent.len(), 1, "PA52 = {pa52}");
        assert_eq!(bus.sent[0].bytes, hex(REPLY));
    }
}

#[test]
fn two_frames_separated_by_exactly_t35_are_both_answered() {
    for pa52 in [0, 4] {
        let mut bus = bus_at(pa52);
        let t35 = bus.timing().t35_us();
        bus.idle(50_000);
        let mut bytes: Vec<(u8, u32)> = hex(REQ).into_iter().map(|b| (b, 0)).collect();
        let second = hex("01 06 60 83 00 64 67 C9");
        bytes.extend(
            second
                .iter()
                .enumerate()
                .map(|(i, &b)| (b, if i == 0 { t35 } else { 0 })),
        );
        bus.feed_gapped(bytes);
        bus.idle(50_000);
        let replies: Vec<_> = bus.sent.iter().map(|s| s.bytes.clone()).collect();
        assert_eq!(replies, vec![hex(REPLY), second.clone()], "PA52 = {pa52}");
    }
}

#[test]
fn a_gap_between_t15_and_t35_never_starts_a_new_frame() {
    // Two requests separated by t3.5 − 1: one broken frame, no reply.
    let mut bus = Bus::new();
    let t35 = bus.timing().t35_us();
    bus.idle(50_000);
    let mut bytes: Vec<(u8, u32)> = hex(REQ).into_iter().map(|b| (b, 0)).collect();
    bytes.extend(
        hex(REQ)
            .into_iter()
            .enumerate()
            .map(|(i, b)| (b, if i == 0 { t35 - 1 } else { 0 })),
    );
    bus.feed_gapped(bytes);
    bus.idle(50_000);
    assert!(bus.sent.is_empty());
    assert_eq!(bus.device.slave().counters().bus_errors(), 1);
}

#[test]
fn the_same_gap_is_harmless_at_9600_and_breaks_at_115200() {
    // 1000 µs: < t1.5 = 1563 µs at 9600, > t1.5 = 750 µs at 115200.
    let mut slow = bus_at(0);
    slow.idle(50_000);
    slow.feed_gapped(with_gap(3, 1000));
    slow.idle(50_000);
    assert_eq!(slow.sent.len(), 1);

    let mut fast = bus_at(4);
    fast.idle(50_000);
    fast.feed_gapped(with_gap(3, 1000));
    fast.idle(50_000);
    assert!(fast.sent.is_empty());

    // And t3.5 differs: at 9600 the reply waits 3646 µs, at 115200 1750 µs.
    assert_eq!(slow.sent[0].start_us - slow.sent[0].request_end_us, 3646);
    fast.send(&hex(REQ));
    assert_eq!(fast.sent[0].start_us - fast.sent[0].request_end_us, 1750);
}

#[test]
fn short_and_overlong_frames_are_dropped_and_counted() {
    let mut bus = Bus::new();
    assert_eq!(bus.send(&[0x01, 0x03, 0x60]), None);
    assert_eq!(bus.send(&[0x01; 257]), None);
    let c = bus.device.slave().counters().clone();
    assert_eq!((c.bus_errors(), c.overruns()), (1, 1));
    // A 256-byte frame is examined (here: a CRC error at our address).
    let reply = bus.send(&[0x01; 256]);
    assert_eq!(reply, Some(exception(1, 0x01, 10)));
}
