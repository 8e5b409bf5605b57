//! The checks of the fuzz targets, shared by `fuzz_targets/*` (libFuzzer)
//! and `tests/fuzz_regressions.rs` (`cargo test` replays
//! `fuzz/regressions/<target>/*`). Every `run` decodes arbitrary bytes into
//! a scenario, drives the core with it and panics when an invariant breaks.
// Each fuzz binary uses one of the modules only.
#![allow(dead_code)]

pub mod assembler;
pub mod dispatcher;
pub mod drive;
pub mod mbap;

/// Reads the fuzz input one byte at a time; zeros once it runs out.
pub struct Input<'a> {
    data: &'a [u8],
}

impl<'a> Input<'a> {
    pub fn new(data: &'a [u8]) -> Self {
        Self { data }
    }

    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    pub fn u8(&mut self) -> u8 {
        match self.data.split_first() {
            Some((&b, rest)) => {
                self.data = rest;
                b
            }
            None => 0,
        }
    }

    pub fn u32(&mut self) -> u32 {
        u32::from_le_bytes([self.u8(), self.u8(), self.u8(), self.u8()])
    }

    /// Up to `n` bytes (fewer when the input runs out).
    pub fn bytes(&mut self, n: usize) -> &'a [u8] {
        let (head, rest) = self.data.split_at(n.min(self.data.len()));
        self.data = rest;
        head
    }
}
