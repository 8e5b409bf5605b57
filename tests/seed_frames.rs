//! Every worked frame of seed 000 (SPEC §10), fed byte by byte with
//! timestamps through the frame assembler and the dispatcher; replies
//! compared byte for byte.

mod common;
use common::*;

/// A 0x06 request is answered by its echo (seed 000 §7.3).
fn echo(bus: &mut Bus, request: &str) {
    let f = hex(request);
    assert_eq!(bus.send(&f), Some(f.clone()), "request {request}");
}

/// A 0x10 request is answered `addr 10 start quantity CRC` (seed 000 §7.4).
fn write_reply(request: &[u8]) -> Vec<u8> {
    with_crc(&request[..6])
}

fn exchange(bus: &mut Bus, request: &str, reply: &str) {
    assert_eq!(
        bus.send(&hex(request)),
        Some(hex(reply)),
        "request {request}"
    );
}

fn written(bus: &mut Bus, request: &str) {
    let f = hex(request);
    assert_eq!(bus.send(&f), Some(write_reply(&f)), "request {request}");
}

#[test]
fn programming_example_writes_nine_words_in_table_order() {
    // Seed 000 §6.1 "编程说明": 0x6040, 0x6060, 0x6081 (2), 0x6083, 0x6084,
    // 0x6085, 0x607A (2) in one request (SPEC §5).
    let mut bus = Bus::new();
    exchange(
        &mut bus,
        "01 10 60 40 00 09 12 00 0F 00 01 00 00 00 64 00 64 00 64 00 64 00 03 0D 40 40 1C",
        "01 10 60 40 00 09 1F DB",
    );
    let od = bus.device.od();
    assert_eq!(od.controlword(), 0x000F);
    assert_eq!(od.mode(), 1);
    assert_eq!(od.profile_velocity(), 100);
    assert_eq!(
        (
            od.acceleration(),
            od.deceleration(),
            od.quick_stop_deceleration()
        ),
        (100, 100, 100)
    );
    assert_eq!(od.target_position(), 200_000);
    // The RW entries read back, walking the same table order (0x6081..0x607A).
    assert_eq!(
        bus.read(0x6081, 7),
        Ok(vec![0, 100, 100, 100, 100, 3, 0x0D40])
    );
}

#[test]
fn single_register_writes_of_the_programming_example() {
    let mut bus = Bus::new();
    echo(&mut bus, "01 06 60 83 00 64 67 C9");
    echo(&mut bus, "01 06 60 84 00 64 D6 08");
    assert_eq!(bus.read(0x6083, 2), Ok(vec![100, 100]));
}

#[test]
fn target_position_in_word_order_0() {
    // SPEC §5.1 / seed 000 §6.1 and §7.2, 0x6000 = 0.
    let mut bus = Bus::new();
    exchange(
        &mut bus,
        "01 10 60 7A 00 02 04 00 03 0D 40 29 96",
        "01 10 60 7A 00 02 7E 11",
    );
    assert_eq!(bus.device.od().target_position(), 200_000);
    exchange(
        &mut bus,
        "01 03 60 7A 00 02 FB D2",
        "01 03 04 00 03 0D 40 0F 53",
    );
}

#[test]
fn target_position_in_word_order_1() {
    // SPEC §5.1: the same 200000 with the low word first.
    let mut bus = Bus::new();
    echo(&mut bus, "01 06 60 00 00 01 56 0A"); // 0x6000 = 1
    exchange(
        &mut bus,
        "01 10 60 7A 00 02 04 0D 40 00 03 9F 8F",
        "01 10 60 7A 00 02 7E 11",
    );
    assert_eq!(bus.device.od().target_position(), 200_000);
    exchange(
        &mut bus,
        "01 03 60 7A 00 02 FB D2",
        "01 03 04 0D 40 00 03 B9 4A",
    );
    // Back to order 0: the same value reads high word first.
    echo(&mut bus, "01 06 60 00 00 00 97 CA");
    exchange(
        &mut bus,
        "01 03 60 7A 00 02 FB D2",
        "01 03 04 00 03 0D 40 0F 53",
    );
}

#[test]
fn position_mode_program() {
    // Seed 000 §6.1 "位置模式代码例程", every frame with a good CRC.
    let mut bus = Bus::new();
    for f in [
        "01 06 60 40 00 01 57 DE",
        "01 06 60 40 00 03 D6 1F",
        "01 06 60 40 00 0F D6 1A",
        "01 06 60 60 00 01 56 14",
        "01 06 60 83 00 64 67 C9",
        "01 06 60 84 00 64 D6 08",
    ] {
        echo(&mut bus, f);
    }
    written(&mut bus, "01 10 60 7A 00 02 04 00 03 0D 40 29 96");
    echo(&mut bus, "01 06 60 40 00 1F D7 D6");
    echo(&mut bus, "01 06 60 40 00 0F D6 1A");
    // The three multi-point variants.
    for (set, reset, last) in [
        (
            "01 06 60 40 00 1F D7 D6",
            "01 06 60 40 00 0F D6 1A",
            "01 06 60 40 00 1F D7 D6",
        ),
        (
            "01 06 60 40 02 5F D7 46",
            "01 06 60 40 02 4F D6 8A",
            "01 06 60 40 02 5F D7 46",
        ),
        (
            "01 06 60 40 00 7F D7 FE",
            "01 06 60 40 00 6F D6 32",
            "01 06 60 40 02 7F D6 9E",
        ),
    ] {
        written(&mut bus, "01 10 60 81 00 02 04 00 00 00 32 13 D4");
        assert_eq!(bus.device.od().profile_velocity(), 50);
        written(&mut bus, "01 10 60 7A 00 02 04 00 03 0D 40 29 96");
        echo(&mut bus, set);
        echo(&mut bus, reset);
        written(&mut bus, "01 10 60 81 00 02 04 00 00 00 64 93 EA");
        assert_eq!(bus.device.od().profile_velocity(), 100);
        written(&mut bus, "01 10 60 7A 00 02 04 00 09 27 C0 17 54");
        assert_eq!(bus.device.od().target_position(), 600_000);
        echo(&mut bus, last);
        assert_eq!(
            bus.device.od().controlword(),
            u16::from_be_bytes([hex(last)[4], hex(last)[5]])
        );
    }
}

#[test]
fn velocity_mode_program() {
    // Seed 000 §6.2 (the 0x6081 frames with bad CRCs are in
    // `misprinted_frames_are_crc_errors`).
    let mut bus = Bus::new();
    for f in [
        "01 06 60 40 00 01 57 DE",
        "01 06 60 40 00 03 D6 1F",
        "01 06 60 40 00 0F D6 1A",
        "01 06 60 60 00 03 D7 D5",
        "01 06 60 40 01 0F D7 8A",
        "01 06 60 83 00 64 67 C9",
        "01 06 60 84 00 64 D6 08",
        "01 06 60 40 00 0F D6 1A",
        "01 06 60 40 01 0F D7 8A",
    ] {
        echo(&mut bus, f);
    }
    assert_eq!(bus.device.od().mode(), 3);
}

#[test]
fn homing_mode_program() {
    // Seed 000 §6.3.
    let mut bus = Bus::new();
    for f in [
        "01 06 60 40 00 01 57 DE",
        "01 06 60 40 00 03 D6 1F",
        "01 06 60 40 00 0F D6 1A",
        "01 06 60 60 00 06 17 D6",
        "01 06 60 98 00 01 D7 E5",
        "01 06 60 9A 03 E8 B7 5B",
    ] {
        echo(&mut bus, f);
    }
    written(&mut bus, "01 10 60 99 00 02 04 00 00 00 64 93 40");
    written(&mut bus, "01 10 60 9B 00 02 04 00 00 00 64 12 99");
    written(&mut bus, "01 10 60 7C 00 02 04 00 00 03 E8 5C 62");
    let od = bus.device.od();
    assert_eq!(
        (
            od.homing_method(),
            od.homing_acceleration(),
            od.homing_speed()
        ),
        (1, 1000, 100)
    );
    assert_eq!((od.homing_zero_speed(), od.home_offset()), (100, 1000));

    // The same parameters in one request: 0x607C (2), 0x6098, 0x6099 (2),
    // 0x609A, 0x609B (2) = 8 words in table order.
    let mut bus = Bus::new();
    written(
        &mut bus,
        "01 10 60 7C 00 08 10 00 00 03 E8 00 01 00 00 00 64 03 E8 00 00 00 64 09 42",
    );
    let od = bus.device.od();
    assert_eq!(
        (od.home_offset(), od.homing_method(), od.homing_speed()),
        (1000, 1, 100)
    );
    assert_eq!(
        (od.homing_acceleration(), od.homing_zero_speed()),
        (1000, 100)
    );
    echo(&mut bus, "01 06 60 40 00 1F D7 D6");
    echo(&mut bus, "01 06 60 40 01 1F D6 46");
}

#[test]
fn two_word_write_of_0x6083_and_0x6084_in_both_orders() {
    // Seed 000 §7.4; SPEC §10 corrects the printed quantity 4 to 2.
    for order in ["01 06 60 00 00 00 97 CA", "01 06 60 00 00 01 56 0A"] {
        let mut bus = Bus::new();
        echo(&mut bus, order);
        exchange(
            &mut bus,
            "01 10 60 83 00 02 04 00 64 00 64 53 EC",
            "01 10 60 83 00 02 AE 20",
        );
        assert_eq!(bus.read(0x6083, 2), Ok(vec![100, 100]));
    }
}

#[test]
fn unknown_register_0x6090_is_exception_11() {
    // Seed 000 §7.5; SPEC §5.2 (the seed prints the function byte as 06).
    let mut bus = Bus::new();
    exchange(&mut bus, "01 06 60 90 00 03 D7 E6", "01 86 0B 03 A7");
}

/// The frames SPEC §10 names as misprinted, plus the explanation-table
/// frame `01 06 60 7A 00 03 D6 08` (seed 000 §6.1 "报文 2"), whose CRC is
/// also wrong.
const MISPRINTED: [&str; 4] = [
    "01 10 60 81 00 02 04 00 00 0A 12 06",
    "01 10 60 81 00 04 08 00 00 0A 00 64 00 64 10 52",
    "01 10 60 81 00 02 04 00 00 0A 64 93 EA",
    "01 06 60 7A 00 03 D6 08",
];

#[test]
fn misprinted_frames_are_crc_errors() {
    // SPEC §3, PA54 = 1 (default): exception 10 with the function byte | 0x80.
    let mut bus = Bus::new();
    for f in MISPRINTED {
        let request = hex(f);
        assert_eq!(
            bus.send(&request),
            Some(exception(1, request[1], 10)),
            "request {f}"
        );
    }
    assert_eq!(bus.device.od().profile_velocity(), 0, "nothing stored");
    assert_eq!(bus.device.slave().counters().bus_errors(), 4);
}

#[test]
fn misprinted_frames_are_silent_with_pa54_0() {
    // SPEC §3, PA54 = 0: strict Modbus, silent.
    let mut bus = Bus::with_params(|pa| pa.set_unchecked(54, 0));
    for f in MISPRINTED {
        assert_eq!(bus.send(&hex(f)), None, "request {f}");
    }
    assert_eq!(bus.device.slave().counters().bus_errors(), 4);
}

#[test]
fn seed_frames_at_9600_baud_too() {
    // The same exchange on the slowest line (PA52 = 0).
    let mut bus = Bus::with_params(|pa| pa.set_unchecked(52, 0));
    assert_eq!(bus.timing().t35_us(), 3646);
    exchange(
        &mut bus,
        "01 10 60 7A 00 02 04 00 03 0D 40 29 96",
        "01 10 60 7A 00 02 7E 11",
    );
    exchange(
        &mut bus,
        "01 03 60 7A 00 02 FB D2",
        "01 03 04 00 03 0D 40 0F 53",
    );
}
