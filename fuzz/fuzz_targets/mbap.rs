//! Fuzz target: see harness/mbap.rs for the input format and the checks.
#![no_main]

#[path = "../harness/mod.rs"]
mod harness;

libfuzzer_sys::fuzz_target!(|data: &[u8]| harness::mbap::run(data));
