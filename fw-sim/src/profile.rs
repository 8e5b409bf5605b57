//! `--profile FILE`: instructions executed per function of the firmware
//! since reset, counted per basic block by the CPU's block hook (exact
//! under the runner's one-instruction-per-cycle time) and written with
//! `--stats`' rhythm, most expensive first. Where the CPU load of a
//! measurement goes, without a probe.

use std::collections::HashMap;
use std::path::Path;

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

    /// `insns name` lines per function (`name_of` names the function
    /// holding a block, "?" where none does), most first, then by name.
    fn lines<'a>(&self, name_of: impl Fn(u32) -> Option<&'a str>) -> String {
        let mut per: HashMap<&str, u64> = HashMap::new();
        for (&addr, &n) in &self.blocks {
            *per.entry(name_of(addr).unwrap_or("?")).or_default() += n;
        }
        let mut rows: Vec<_> = per.into_iter().collect();
        rows.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(b.0)));
        rows.iter().map(|(f, n)| format!("{n} {f}\n")).collect()
    }

    /// [`Profile::lines`] by the ELF's symbols, written whole to a new file
    /// and renamed into place, so a reader never sees half of it.
    pub fn write(&self, image: &Image, path: &Path) {
        let tmp = path.with_extension("tmp");
        if std::fs::write(&tmp, self.lines(|a| image.function(a))).is_ok() {
            let _ = std::fs::rename(&tmp, path);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_add_up_per_function_most_first() {
        let mut p = Profile::default();
        p.record(0x100, 4); // f
        p.record(0x108, 2); // f, another block
        p.record(0x200, 5); // g
        p.record(0x100, 4); // f again
        p.record(0x300, 1); // no symbol
        let name = |a: u32| match a {
            0x100..0x200 => Some("f"),
            0x200..0x300 => Some("g"),
            _ => None,
        };
        assert_eq!(p.lines(name), "10 f\n5 g\n1 ?\n");
    }
}
