//! Parameters, DP monitor and EE operations on the wire (SPEC §7, §9; seed
//! 001). Seed 001 gives formats, not frames: the frames here are built from
//! those formats with their CRCs and the replies compared byte for byte.

mod common;

use common::*;
use modbus_drive::device::{Device, Identity};
use modbus_drive::dictionary::{Range, PA_COUNT};
use modbus_drive::event::Event;
use modbus_drive::params::{
    BootOutcome, EeOp, ParamSet, ParamStore, Params, SimFlash, FIRMWARE_VERSION, PA,
};

type Store = ParamStore<SimFlash<2>>;

fn store() -> Store {
    ParamStore::new(SimFlash::new(), 0..4096).unwrap()
}

/// A device booted from `store`, as the glue does at power-up.
fn booted(store: &mut Store) -> Bus {
    let mut device = Device::new(Identity::new(TEST_HARDWARE));
    device.apply_boot(&store.boot());
    let mut bus = Bus::with_device(device);
    bus.events();
    bus
}

/// New format (PA2 ≥ 7050): `addr 10 00 3A 00 01 02 00 0k CRC`.
fn ee_new(address: u8, k: u8) -> Vec<u8> {
    frame(address, &[0x10, 0x00, 0x3A, 0x00, 0x01, 0x02, 0x00, k])
}

/// Old format: `addr 06 00 00 00 0k CRC`.
fn ee_old(address: u8, k: u8) -> Vec<u8> {
    frame(address, &[0x06, 0x00, 0x00, 0x00, k])
}

/// Sends an EE request, checks that nothing is answered until the
/// operation ran, runs it and returns the deferred reply.
fn ee(bus: &mut Bus, store: &mut Store, request: &[u8]) -> Option<Vec<u8>> {
    assert_eq!(bus.send(request), None, "the reply waits for the operation");
    assert!(bus.device.busy());
    let reply = bus.poll_storage(store);
    assert!(!bus.device.busy());
    reply
}

/// EE `k` in the new format, expecting the standard 0x10 reply.
fn ee_new_ok(bus: &mut Bus, store: &mut Store, k: u8) {
    let a = bus.device.address();
    let reply = ee(bus, store, &ee_new(a, k));
    assert_eq!(reply, Some(frame(a, &[0x10, 0x00, 0x3A, 0x00, 0x01])));
}

/// EE `k` in the old format, expecting the echo once done.
fn ee_old_ok(bus: &mut Bus, store: &mut Store, k: u8) {
    let a = bus.device.address();
    let request = ee_old(a, k);
    assert_eq!(ee(bus, store, &request), Some(request));
}

/// EE `k` in the old or the new format, expecting success.
fn ee_ok(bus: &mut Bus, store: &mut Store, k: u8, old: bool) {
    if old {
        ee_old_ok(bus, store, k)
    } else {
        ee_new_ok(bus, store, k)
    }
}

fn pa_addr(n: u16) -> u16 {
    0x0064 + n
}

// ---- SPEC §7: every PA's range ------------------------------------------

#[test]
fn every_assigned_pa_accepts_its_range_and_refuses_beyond_it() {
    // the writable parameters with a range, from the table
    let ranged: Vec<usize> = (0..PA_COUNT)
        .filter(|&n| !PA[n].read_only() && PA[n].range() != Range::Any)
        .collect();
    assert!(ranged.len() >= 14, "{ranged:?}");
    let mut tried = 0;
    for &n in &ranged {
        let d = PA[n];
        let mut accepted = vec![d.min(), d.max()];
        let mut refused = vec![];
        if let Some(v) = d.min().checked_sub(1) {
            refused.push(v);
        }
        if let Some(v) = d.max().checked_add(1) {
            refused.push(v);
        }
        if let Range::OffOr(lo, _) = d.range() {
            accepted.push(lo as u16);
            refused.extend([1, lo as u16 - 1]);
        }
        // Both 0x10 and 0x06, each on a fresh drive (PA51..53 move it).
        for single in [false, true] {
            for &v in &accepted {
                let mut bus = Bus::new();
                let r = if single {
                    bus.write_single(pa_addr(n as u16), v)
                } else {
                    bus.write(pa_addr(n as u16), &[v])
                };
                assert_eq!(r, Ok(()), "PA{n} = {v}");
                assert_eq!(bus.device.params().get(n), v);
                assert_eq!(bus.read(pa_addr(n as u16), 1), Ok(vec![v]), "PA{n}");
                tried += 1;
            }
            for &v in &refused {
                let mut bus = Bus::new();
                let r = if single {
                    bus.write_single(pa_addr(n as u16), v)
                } else {
                    bus.write(pa_addr(n as u16), &[v])
                };
                assert_eq!(r, Err(3), "PA{n} = {v} is out of range (§5.2 step 8)");
                assert_eq!(bus.device.params().get(n), d.default(), "nothing stored");
                tried += 1;
            }
        }
    }
    println!("PA ranges: {tried} writes checked");
    assert!(tried >= ranged.len() * 2 * 3);
}

#[test]
fn pa2_is_read_only_and_reports_the_firmware_version() {
    let mut bus = Bus::new();
    assert_eq!(bus.read(pa_addr(2), 1), Ok(vec![FIRMWARE_VERSION]));
    const { assert!(FIRMWARE_VERSION >= 7050, "new EE format supported") };
    assert_eq!(bus.write(pa_addr(2), &[FIRMWARE_VERSION]), Err(5));
    assert_eq!(bus.write_single(pa_addr(2), 7000), Err(5));
    // A block write touching PA2 is refused as a whole (all-or-nothing).
    assert_eq!(bus.write(pa_addr(0), &[1, 2, 3]), Err(5));
    assert_eq!(bus.device.params().get(0), 0);
}

#[test]
fn unassigned_pas_store_any_value() {
    let mut bus = Bus::new();
    let any = (0..PA_COUNT).filter(|&n| !PA[n].read_only() && PA[n].range() == Range::Any);
    for n in any.map(|n| n as u16) {
        assert_eq!(bus.write(pa_addr(n), &[0xFFFF]), Ok(()));
        assert_eq!(bus.write_single(pa_addr(n), 0), Ok(()));
    }
}

// ---- SPEC §7: effects -----------------------------------------------------

/// PA57 / PA58, the RS-485 driver-enable lead and tail (docs/firmware.md):
/// one bit time by default, 0..=MAX_DE_BITS bit times, exception 3 beyond (nothing
/// stored), saved by EE-Set and in force after a power cycle; a saved value
/// out of that range (PA57/PA58 were unassigned before, any value) loads
/// as the default.
#[test]
fn pa57_pa58_driver_enable_lead_and_tail() {
    use modbus_drive::params::Slot;
    use modbus_drive::rtu::{DriverEnable, MAX_DE_BITS};
    let mut s = store();
    let mut bus = booted(&mut s);
    assert_eq!(bus.read(pa_addr(57), 2), Ok(vec![1, 1]));
    assert_eq!(bus.device.params().driver_enable(), DriverEnable::new(1, 1));
    for (n, v) in [
        (57u16, MAX_DE_BITS + 1),
        (58, MAX_DE_BITS + 1),
        (57, 0xFFFF),
    ] {
        assert_eq!(bus.write_single(pa_addr(n), v), Err(3), "PA{n} = {v}");
        assert_eq!(bus.write(pa_addr(n), &[v]), Err(3), "PA{n} = {v}");
    }
    // a block write with one value out of range stores neither
    assert_eq!(bus.write(pa_addr(57), &[4, MAX_DE_BITS + 1]), Err(3));
    assert_eq!(bus.read(pa_addr(57), 2), Ok(vec![1, 1]));
    assert_eq!(bus.write(pa_addr(57), &[4, MAX_DE_BITS]), Ok(()));
    assert_eq!(
        bus.device.params().driver_enable(),
        DriverEnable::new(4, MAX_DE_BITS)
    );
    ee_new_ok(&mut bus, &mut s, 1); // EE-Set
    assert_eq!(bus.write(pa_addr(57), &[0, 0]), Ok(()));
    assert_eq!(bus.read(pa_addr(57), 2), Ok(vec![0, 0]));
    let mut bus = booted(&mut s);
    assert_eq!(bus.read(pa_addr(57), 2), Ok(vec![4, MAX_DE_BITS]));
    // EE-dEF: back to one bit time
    ee_new_ok(&mut bus, &mut s, 5);
    assert_eq!(bus.read(pa_addr(57), 2), Ok(vec![1, 1]));

    let mut old = ParamSet::defaults();
    old.pa_mut().set_unchecked(57, 500);
    old.pa_mut().set_unchecked(58, 7);
    s.save(Slot::Saved, &old).unwrap();
    let boot = s.boot();
    assert_eq!(boot.outcome(), BootOutcome::Loaded { fixed: 1 });
    let mut bus = booted(&mut s);
    assert_eq!(bus.read(pa_addr(57), 2), Ok(vec![1, 7]));
}

#[test]
fn address_change_is_answered_from_the_old_address_then_effective() {
    let mut bus = Bus::new();
    let reply = bus.request(1, &write_pdu(pa_addr(51), &[5]));
    assert_eq!(reply, Some(frame(1, &[0x10, 0x00, 0x97, 0x00, 0x01])));
    assert_eq!(bus.device.address(), 5);
    assert_eq!(bus.request(1, &[0x03, 0x00, 0x97, 0x00, 0x01]), None);
    assert_eq!(
        bus.request(5, &[0x03, 0x00, 0x97, 0x00, 0x01]),
        Some(frame(5, &[0x03, 0x02, 0x00, 0x05]))
    );
    assert!(bus.events().contains(&Event::AddressChanged { address: 5 }));
}

#[test]
fn baud_change_takes_effect_after_the_reply() {
    let mut bus = Bus::new();
    let t35_115200 = bus.timing().t35_us();
    assert_eq!(bus.write_single(pa_addr(52), 0), Ok(()));
    let sent = bus.sent.last().unwrap().clone();
    // The reply still went out on the old line: t3.5 of 115200 baud.
    assert_eq!(sent.start_us.wrapping_sub(sent.request_end_us), t35_115200);
    assert_eq!(bus.device.line().baud(), 9_600);
    assert_eq!(bus.timing().t35_us(), 3_646, "3.5 × 10 bits at 9600 baud");
    // The next request is at 9600 baud and is answered after its t3.5.
    assert_eq!(bus.read(pa_addr(52), 1), Ok(vec![0]));
    let sent = bus.sent.last().unwrap();
    assert_eq!(sent.start_us.wrapping_sub(sent.request_end_us), 3_646);
}

#[test]
fn format_change_takes_effect_after_the_reply() {
    let mut bus = Bus::new();
    assert_eq!(bus.write_single(pa_addr(53), 1), Ok(()));
    assert_eq!(
        bus.device.line().format(),
        modbus_drive::rtu::CharFormat::E1
    );
}

#[test]
fn pa56_delays_the_reply() {
    let mut bus = Bus::new();
    assert_eq!(bus.write_single(pa_addr(56), 20), Ok(()));
    let t35 = bus.timing().t35_us();
    assert_eq!(bus.read(pa_addr(56), 1), Ok(vec![20]));
    let sent = bus.sent.last().unwrap();
    assert_eq!(
        sent.start_us.wrapping_sub(sent.request_end_us),
        t35 + 20_000
    );
}

#[test]
fn pa55_selects_the_standard_exception_profile() {
    let mut bus = Bus::new();
    assert_eq!(bus.write_single(pa_addr(2), 1), Err(5));
    assert_eq!(bus.write_single(pa_addr(55), 1), Ok(()));
    assert_eq!(bus.write_single(pa_addr(2), 1), Err(2), "5 → 2 (§5.2)");
}

#[test]
fn pa54_0_silences_frame_errors() {
    let mut bus = Bus::new();
    let mut bad = frame(1, &[0x03, 0x00, 0x64, 0x00, 0x01]);
    *bad.last_mut().unwrap() ^= 0xFF;
    assert_eq!(bus.send(&bad), Some(exception(1, 0x03, 10)));
    assert_eq!(bus.write_single(pa_addr(54), 0), Ok(()));
    assert_eq!(bus.send(&bad), None);
}

// ---- SPEC §9: DP monitor --------------------------------------------------

#[test]
fn dp_monitor_reads_in_seed_001_order() {
    let mut s = store();
    let mut bus = booted(&mut s);
    // Seed 001: at most 20 registers per read; this drive allows 125.
    let request = frame(1, &[0x03, 0x00, 0x00, 0x00, 0x14]);
    let reply = bus.send(&request).unwrap();
    let mut expected = vec![0x01, 0x03, 0x28];
    // The drive stands still at 0 (placeholder drive layer: all zero),
    // DP-Cnt 0 (no mode yet), DP-APo 0; DP-Err (0x13) bit 8: the store
    // was blank at boot, defaults are in use.
    let mut words = [0u16; 20];
    words[0x13] = 0x0100;
    for w in words {
        expected.extend_from_slice(&w.to_be_bytes());
    }
    assert_eq!(reply, with_crc(&expected));
    // All 24 items in one read; one more is past the block (§5.2 step 6).
    assert_eq!(bus.read(0x0000, 24).map(|v| v.len()), Ok(24));
    assert_eq!(bus.read(0x0000, 25), Err(2));
    assert_eq!(bus.read(0x0017, 1), Ok(vec![0]));
    assert_eq!(bus.read(0x0018, 1), Err(11));
}

#[test]
fn dp_monitor_is_read_only() {
    let mut bus = Bus::new();
    assert_eq!(bus.write_single(0x0001, 0), Err(5));
    assert_eq!(bus.write(0x0013, &[0]), Err(5));
    // 0x0000 written is the old EE command: two words reach DP-PoS (RO).
    assert_eq!(bus.write(0x0000, &[1, 0]), Err(5));
}

#[test]
fn dp_err_reports_the_store_and_clears_after_a_save() {
    let mut s = store();
    let mut bus = booted(&mut s);
    assert_eq!(bus.read(0x0013, 1), Ok(vec![0x0100]), "blank store");
    ee_new_ok(&mut bus, &mut s, 1);
    assert_eq!(bus.read(0x0013, 1), Ok(vec![0x0000]));
    s.flash().fail_after(0);
    let a = bus.device.address();
    assert_eq!(
        ee(&mut bus, &mut s, &ee_new(a, 1)),
        Some(exception(1, 0x10, 4))
    );
    assert_eq!(bus.read(0x0013, 1), Ok(vec![0x0400]), "flash failed");
}

// ---- SPEC §9: EE operations, both formats --------------------------------

#[test]
fn seed_001_read_of_pa_items_byte_for_byte() {
    let mut bus = Bus::new();
    // PA0..PA19 (0x0064, 20 registers: seed 001's maximum).
    let reply = bus
        .send(&frame(1, &[0x03, 0x00, 0x64, 0x00, 0x14]))
        .unwrap();
    let mut expected = vec![0x01, 0x03, 0x28];
    for n in 0..20 {
        expected.extend_from_slice(&Params::defaults().get(n).to_be_bytes());
    }
    assert_eq!(reply, with_crc(&expected));
    assert_eq!(&reply[3 + 2 * 2..3 + 2 * 3], &[0x1B, 0x94], "PA2 = 7060");
    assert_eq!(
        &reply[3 + 2 * 10..3 + 2 * 11],
        &[0x27, 0x10],
        "PA10 = 10000"
    );
    // Seed 001 write format: `addr 10 00 64+n 00 q 2q data CRC` → `addr 10 00 64+n 00 q CRC`.
    let request = frame(
        1,
        &[0x10, 0x00, 0x6E, 0x00, 0x02, 0x04, 0x0C, 0x80, 0x00, 0x01],
    );
    assert_eq!(
        bus.send(&request),
        Some(frame(1, &[0x10, 0x00, 0x6E, 0x00, 0x02]))
    );
    assert_eq!(
        (bus.device.params().get(10), bus.device.params().get(11)),
        (3200, 1)
    );
}

#[test]
fn ee_frames_of_seed_001_byte_for_byte() {
    let mut s = store();
    let mut bus = booted(&mut s);
    // Hand-checked frames (CRC-16/MODBUS, low byte first).
    assert_eq!(ee_new(1, 1), hex("01 10 00 3A 00 01 02 00 01 62 CA"));
    assert_eq!(ee_old(1, 1), hex("01 06 00 00 00 01 48 0A"));
    assert_eq!(bus.send(&hex("01 10 00 3A 00 01 02 00 01 62 CA")), None);
    assert_eq!(
        bus.poll_storage(&mut s),
        Some(hex("01 10 00 3A 00 01 21 C4"))
    );
    assert_eq!(bus.send(&hex("01 06 00 00 00 01 48 0A")), None);
    assert_eq!(
        bus.poll_storage(&mut s),
        Some(hex("01 06 00 00 00 01 48 0A"))
    );
}

#[test]
fn ee_set_and_ee_rd_in_both_formats() {
    for old in [false, true] {
        let mut s = store();
        let mut bus = booted(&mut s);
        let run = |bus: &mut Bus, s: &mut Store, k| ee_ok(bus, s, k, old);
        assert_eq!(bus.write(pa_addr(10), &[4000]), Ok(()));
        assert_eq!(bus.write(0x6083, &[250]), Ok(()));
        run(&mut bus, &mut s, 1); // EE-Set
        assert_eq!(bus.write(pa_addr(10), &[5000]), Ok(()));
        assert_eq!(bus.write(0x6083, &[99]), Ok(()));
        run(&mut bus, &mut s, 2); // EE-rd
        assert_eq!(bus.read(pa_addr(10), 1), Ok(vec![4000]));
        assert_eq!(bus.read(0x6083, 1), Ok(vec![250]));
        // And after a power cycle the saved set is what the drive starts with.
        let mut bus = booted(&mut s);
        assert_eq!(bus.read(pa_addr(10), 1), Ok(vec![4000]));
        assert_eq!(bus.read(0x0013, 1), Ok(vec![0]), "loaded, no DP-Err");
    }
}

#[test]
fn ee_ba_and_ee_rs_in_both_formats() {
    for old in [false, true] {
        let mut s = store();
        let mut bus = booted(&mut s);
        let run = |bus: &mut Bus, s: &mut Store, k| ee_ok(bus, s, k, old);
        assert_eq!(bus.write(pa_addr(12), &[1500]), Ok(()));
        run(&mut bus, &mut s, 3); // EE-bA
        assert_eq!(bus.write(pa_addr(12), &[2500]), Ok(()));
        run(&mut bus, &mut s, 1); // EE-Set saves 2500
        run(&mut bus, &mut s, 4); // EE-rS: working and saved := backup
        assert_eq!(bus.read(pa_addr(12), 1), Ok(vec![1500]));
        let mut bus = booted(&mut s);
        assert_eq!(bus.read(pa_addr(12), 1), Ok(vec![1500]), "EE-rS saved it");
    }
}

#[test]
fn ee_def_in_both_formats() {
    for old in [false, true] {
        let mut s = store();
        let mut bus = booted(&mut s);
        assert_eq!(bus.write(pa_addr(20), &[500]), Ok(()));
        ee_new_ok(&mut bus, &mut s, 1);
        ee_ok(&mut bus, &mut s, 5, old);
        assert_eq!(bus.device.params(), &Params::defaults());
        let bus = booted(&mut s);
        assert_eq!(
            bus.device.params(),
            &Params::defaults(),
            "EE-dEF saved them"
        );
    }
}

#[test]
fn ee_rd_changing_address_and_baud_answers_first_then_takes_effect() {
    let mut s = store();
    let mut bus = booted(&mut s);
    assert_eq!(bus.write(pa_addr(51), &[9]), Ok(()));
    assert_eq!(bus.device.address(), 9);
    assert_eq!(bus.write_single(pa_addr(52), 2), Ok(())); // 38400
    ee_new_ok(&mut bus, &mut s, 1); // saved: address 9, 38400 baud
    assert_eq!(bus.write(pa_addr(51), &[3]), Ok(()));
    assert_eq!(bus.write_single(pa_addr(52), 4), Ok(()));
    assert_eq!(bus.device.address(), 3);
    // EE-rd at address 3: answered from 3 on 115200, then 9 / 38400.
    let reply = ee(&mut bus, &mut s, &ee_old(3, 2));
    assert_eq!(reply, Some(ee_old(3, 2)));
    assert_eq!(bus.device.address(), 9);
    assert_eq!(bus.device.line().baud(), 38_400);
    assert_eq!(bus.request(3, &[0x03, 0x00, 0x97, 0x00, 0x01]), None);
    assert_eq!(bus.read(pa_addr(51), 1), Ok(vec![9]));
}

#[test]
fn ee_def_answers_from_the_old_address() {
    let mut s = store();
    let mut bus = booted(&mut s);
    assert_eq!(bus.write(pa_addr(51), &[42]), Ok(()));
    assert_eq!(
        ee(&mut bus, &mut s, &ee_new(42, 5)),
        Some(frame(42, &[0x10, 0x00, 0x3A, 0x00, 0x01]))
    );
    assert_eq!(bus.device.address(), 1);
}

#[test]
fn other_requests_during_an_ee_operation_get_exception_6() {
    let mut s = store();
    let mut bus = booted(&mut s);
    assert_eq!(bus.send(&ee_new(1, 1)), None);
    assert!(bus.device.busy());
    assert_eq!(bus.device.pending_ee(), Some(EeOp::Save));
    // Reads, writes and a second EE request all pass validation → busy.
    assert_eq!(
        bus.send(&frame(1, &[0x03, 0x00, 0x64, 0x00, 0x01])),
        Some(exception(1, 0x03, 6))
    );
    assert_eq!(
        bus.send(&frame(1, &[0x06, 0x00, 0x6E, 0x01, 0x90])),
        Some(exception(1, 0x06, 6))
    );
    assert_eq!(bus.send(&ee_old(1, 2)), Some(exception(1, 0x06, 6)));
    assert_eq!(
        bus.send(&frame(1, &[0x03, 0x60, 0x41, 0x00, 0x01])),
        Some(exception(1, 0x03, 6))
    );
    // SPEC §9: *other requests* — diagnostics and identification too, and
    // a busy diagnostics request does not act (no listen-only, no clear).
    assert_eq!(
        bus.send(&frame(1, &[0x08, 0x00, 0x00, 0x12, 0x34])),
        Some(exception(1, 0x08, 6))
    );
    assert_eq!(
        bus.send(&frame(1, &[0x08, 0x00, 0x04, 0x00, 0x00])),
        Some(exception(1, 0x08, 6))
    );
    assert!(!bus.device.slave().listen_only());
    assert_eq!(
        bus.send(&frame(1, &[0x08, 0x00, 0x0A, 0x00, 0x00])),
        Some(exception(1, 0x08, 6))
    );
    assert_eq!(
        bus.send(&frame(1, &[0x2B, 0x0E, 0x01, 0x00])),
        Some(exception(1, 0x2B, 6))
    );
    // Validation comes first (§5.2: steps 1..8 before 9).
    assert_eq!(
        bus.send(&frame(1, &[0x06, 0x00, 0x97, 0x00, 0x00])),
        Some(exception(1, 0x06, 3))
    );
    assert_eq!(
        bus.send(&frame(1, &[0x08, 0x00, 0x0A, 0x00, 0x01])),
        Some(exception(1, 0x08, 3))
    );
    assert_eq!(
        bus.send(&frame(1, &[0x08, 0x00, 0x20, 0x00, 0x00])),
        Some(exception(1, 0x08, 1))
    );
    assert_eq!(
        bus.device.params().get(10),
        10_000,
        "nothing stored while busy"
    );
    assert_eq!(
        bus.device.slave().counters().busy(),
        8,
        "counters not cleared"
    );
    // The operation completes with its own reply, then requests work again.
    assert_eq!(
        bus.poll_storage(&mut s),
        Some(frame(1, &[0x10, 0x00, 0x3A, 0x00, 0x01]))
    );
    assert_eq!(bus.read(pa_addr(10), 1), Ok(vec![10_000]));
    assert_eq!(bus.poll_storage(&mut s), None, "nothing waits any more");
}

#[test]
fn a_flash_failure_is_exception_4_in_both_formats() {
    let mut s = store();
    let mut bus = booted(&mut s);
    s.flash().fail_after(0);
    assert_eq!(
        ee(&mut bus, &mut s, &ee_new(1, 1)),
        Some(exception(1, 0x10, 4))
    );
    assert_eq!(
        ee(&mut bus, &mut s, &ee_old(1, 3)),
        Some(exception(1, 0x06, 4))
    );
    let events = bus.events();
    assert!(events.iter().any(|e| matches!(
        e,
        Event::EeDone {
            op: EeOp::Save,
            error: Some(_)
        }
    )));
    // Exception 4 is 4 in the standard profile too.
    assert_eq!(bus.write_single(pa_addr(55), 1), Ok(()));
    assert_eq!(
        ee(&mut bus, &mut s, &ee_new(1, 5)),
        Some(exception(1, 0x10, 4))
    );
    assert_eq!(
        bus.device.params().get(55),
        1,
        "EE-dEF failed: nothing changed"
    );
}

#[test]
fn ee_rs_without_a_backup_is_exception_4() {
    let mut s = store();
    let mut bus = booted(&mut s);
    assert_eq!(
        ee(&mut bus, &mut s, &ee_new(1, 4)),
        Some(exception(1, 0x10, 4))
    );
}

#[test]
fn broadcast_ee_operations_run_without_a_reply() {
    let mut s = store();
    let mut bus = booted(&mut s);
    assert_eq!(bus.write(pa_addr(10), &[700]), Ok(()));
    assert_eq!(bus.send(&ee_new(0, 1)), None);
    assert!(bus.device.busy());
    assert_eq!(bus.poll_storage(&mut s), None, "broadcast: silent");
    assert!(!bus.device.busy());
    assert_eq!(bus.send(&ee_old(0, 5)), None);
    assert_eq!(bus.poll_storage(&mut s), None);
    assert_eq!(bus.device.params().get(10), 10_000, "EE-dEF ran");
    assert_eq!(s.boot().outcome(), BootOutcome::Loaded { fixed: 0 });
}

#[test]
fn ee_requests_out_of_range_or_misshapen_are_refused() {
    let mut bus = Bus::new();
    for k in [0u8, 6, 0xFF] {
        assert_eq!(bus.send(&ee_new(1, k)), Some(exception(1, 0x10, 3)));
        assert_eq!(bus.send(&ee_old(1, k)), Some(exception(1, 0x06, 3)));
    }
    assert_eq!(bus.read(0x003A, 1), Err(7), "the EE command is write-only");
    assert_eq!(bus.write(0x003A, &[1, 1]), Err(2), "one register only");
    assert_eq!(bus.write(0x0039, &[1]), Err(11));
    assert!(!bus.device.busy());
}

#[test]
fn boot_with_saved_address_and_line_uses_them_at_once() {
    let mut s = store();
    let mut bus = booted(&mut s);
    assert_eq!(bus.write(pa_addr(52), &[1]), Ok(())); // 19200
    assert_eq!(bus.write(pa_addr(51), &[33]), Ok(()));
    ee_new_ok(&mut bus, &mut s, 1);
    let mut bus2 = Bus::new();
    let boot = s.boot();
    bus2.device.apply_boot(&boot);
    assert_eq!(bus2.device.address(), 33);
    assert_eq!(bus2.device.line().baud(), 19_200);
    assert!(bus2
        .events()
        .contains(&Event::ParamsLoaded(BootOutcome::Loaded { fixed: 0 })));
}
