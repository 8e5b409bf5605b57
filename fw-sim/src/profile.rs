//! `--profile FILE`: instructions executed per function of the firmware
//! since reset, counted per basic block by the CPU's block hook (exact
//! under the runner's one-instruction-per-cycle time) and written with
//! `--stats`' rhythm, most expensive first. Where the CPU load of a
//! measurement goes, without a probe.

use std::collections::HashMap;
use std::path::PathBuf;

use crate::elf::Image;

/// Instructions per basic block start address.
#[derive(Default)]
pub struct Profile {
    blocks: HashMap<u32, u64>,
}

impl Profile {
    /// `n` instructions of the block at `addr` ran.
    pub fn record(&mut self, addr: u32, n: u32) {
        *self.blocks.entry(addr).or_default() += u64::from(n);
    }

    /// `insns name` lines per function (the ELF symbol holding each
    /// block), most first; written whole and renamed into place.
    pub fn write(&self, image: &Image, path: &PathBuf) {
        let mut per: HashMap<&str, u64> = HashMap::new();
        for (&addr, &n) in &self.blocks {
            *per.entry(image.function(addr).unwrap_or("?")).or_default() += n;
        }
        let mut rows: Vec<_> = per.into_iter().collect();
        rows.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(b.0)));
        let text: String = rows.iter().map(|(f, n)| format!("{n} {f}\n")).collect();
        let tmp = path.with_extension("tmp");
        if std::fs::write(&tmp, text).is_ok() {
            let _ = std::fs::rename(&tmp, path);
        }
    }
}
