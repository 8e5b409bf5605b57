//! `--trace-calls FILE`: which firmware function runs when. One CSV line,
//! emulated time in ns and the function's name, each time a basic block of
//! another function than the block before it starts: calls, returns and
//! interrupt entries and exits alike, from reset on. Where the time goes
//! between two events of the other traces (a request's last byte and its
//! reply's first start bit in `--trace-line`), which `--profile`'s totals
//! cannot tell. A line per change, so for short runs; written out with
//! `--stats`' rhythm.

use std::collections::HashMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use crate::elf::Symbols;

pub struct CallTrace {
    out: BufWriter<File>,
    symbols: Symbols,
    /// The symbol index of each block seen (`None`: in no symbol).
    of_block: HashMap<u32, Option<usize>>,
    /// The function of the block before.
    last: Option<Option<usize>>,
}

impl CallTrace {
    pub fn create(path: &Path, symbols: Symbols) -> std::io::Result<Self> {
        let mut out = BufWriter::new(File::create(path)?);
        writeln!(out, "time_ns,function")?;
        Ok(Self {
            out,
            symbols,
            of_block: HashMap::new(),
            last: None,
        })
    }

    /// A basic block at `addr` starts at `t_ps` (emulated ps).
    pub fn block(&mut self, t_ps: u64, addr: u32) {
        let f = match self.of_block.get(&addr) {
            Some(&f) => f,
            None => {
                let f = self.symbols.index(addr);
                self.of_block.insert(addr, f);
                f
            }
        };
        if self.last == Some(f) {
            return;
        }
        self.last = Some(f);
        let name = f.map_or("?", |i| self.symbols.name(i));
        let _ = writeln!(self.out, "{},{name}", (t_ps + 500) / 1000);
    }

    pub fn flush(&mut self) {
        let _ = self.out.flush();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_line_each_time_another_function_runs() {
        let path = std::env::temp_dir().join(format!("call-trace-{}.csv", std::process::id()));
        let symbols = Symbols::new(vec![
            (0x200, 0x10, "g".to_string()),
            (0x100, 0x20, "f".to_string()),
        ]);
        let mut t = CallTrace::create(&path, symbols).unwrap();
        t.block(1_000, 0x100); // f
        t.block(2_000, 0x108); // f again: no line
        t.block(3_400, 0x201); // g (Thumb bit)
        t.block(4_000, 0x120); // past f's end: none
        t.block(6_600, 0x110); // f
        t.flush();
        let text = std::fs::read_to_string(&path).unwrap();
        let _ = std::fs::remove_file(&path);
        assert_eq!(text, "time_ns,function\n1,f\n3,g\n4,?\n7,f\n");
    }
}
