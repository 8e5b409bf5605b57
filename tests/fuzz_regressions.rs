//! Replays every input under `fuzz/regressions/<target>/` through the same
//! checks the fuzz targets run (fuzz/harness/): hand-made seeds that walk
//! each target's main paths, and every input a fuzzing run ever failed on.
//! SPEC §1 (assembler), §2, §3, §5.2, §8.1 (dispatcher), §8 (drive); the
//! MBAP rules of the Modbus TCP guide (mbap).

#[path = "../fuzz/harness/mod.rs"]
mod harness;

use std::path::Path;

fn replay(target: &str, run: fn(&[u8])) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz/regressions")
        .join(target);
    let mut n = 0;
    for entry in std::fs::read_dir(&dir).expect("regression directory") {
        let path = entry.expect("directory entry").path();
        let data = std::fs::read(&path).expect("regression input");
        let outcome = std::panic::catch_unwind(|| run(&data));
        assert!(outcome.is_ok(), "{} fails", path.display());
        n += 1;
    }
    assert!(n > 0, "no inputs in {}", dir.display());
}

#[test]
fn assembler_regressions_hold() {
    replay("assembler", harness::assembler::run);
}

#[test]
fn dispatcher_regressions_hold() {
    replay("dispatcher", harness::dispatcher::run);
}

#[test]
fn drive_regressions_hold() {
    replay("drive", harness::drive::run);
}

#[test]
fn mbap_regressions_hold() {
    replay("mbap", harness::mbap::run);
}

/// The state check of the dispatcher target accepts the eight §8.1
/// patterns (whatever the other bits) and nothing else.
#[test]
fn the_statusword_check_knows_the_eight_states() {
    use harness::dispatcher::statusword_is_a_state as ok;
    // bit 5 is `x` in four of them: the drive sets it (SPEC §8.2, bit 5 = 0
    // only in quick stop active), the check takes either
    for sw in [
        0x0000, 0x0040, 0x0021, 0x0023, 0x0027, 0x0007, 0x000F, 0x0008, 0x0020, 0x0060, 0x002F,
        0x0028,
    ] {
        assert!(ok(sw) && ok(sw | 0xFF90), "{sw:#06X}");
    }
    for sw in [
        0x0041, 0x0001, 0x0061, 0x0003, 0x0025, 0x0047, 0x0009, 0x004F,
    ] {
        assert!(!ok(sw), "{sw:#06X}");
    }
}
