//! Linker set-up for the firmware (issue 6). Host builds get nothing.
//!
//! The board's memory map (`memory-<board>.x`, which keeps the parameter
//! flash pages out of FLASH) is copied to `OUT_DIR/memory.x`, where
//! cortex-m-rt's `link.x` includes it from. Nothing named `memory.x` may
//! exist in the package root: the linker searches there before OUT_DIR, so
//! a root file would silently win over the board's own map.
use std::{env, fs, path::PathBuf};

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    if env::var("CARGO_CFG_TARGET_OS").as_deref() != Ok("none") {
        return;
    }
    assert!(
        !std::path::Path::new("memory.x").exists(),
        "a memory.x in the package root would shadow the board's memory map"
    );
    let memory = if env::var_os("CARGO_FEATURE_BOARD_F103").is_some() {
        "memory-f103.x"
    } else {
        "memory-g431.x" // STM32G431CB, the primary board
    };
    println!("cargo:rerun-if-changed={memory}");
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    fs::copy(memory, out.join("memory.x")).expect("copy the board's memory map");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    // Identical code folding: functions whose machine code is the same
    // (monomorphisations that differ only in a type) are kept once.
    println!("cargo:rustc-link-arg-bins=--icf=all");
}
