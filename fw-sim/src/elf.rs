//! The firmware ELF: loadable segments, the symbol table (a fault's PC is
//! named by the function around it) and the addresses of the WFI / WFE /
//! SEV instructions the runner handles itself.

use object::{Object, ObjectSymbol, SymbolKind};

pub struct Image {
    pub bytes: Vec<u8>,
    symbols: Symbols,
    pub rtt: Option<u32>,
}

/// The ELF's text and data symbols: (address, size, name), sorted by
/// address.
#[derive(Clone)]
pub struct Symbols(Vec<(u32, u32, String)>);

impl Symbols {
    /// From (address, size, name) in any order.
    pub fn new(mut symbols: Vec<(u32, u32, String)>) -> Self {
        symbols.sort();
        Self(symbols)
    }

    /// The symbol at or below `addr` (Thumb bit cleared): its index and
    /// `addr`'s offset in it.
    fn nearest(&self, addr: u32) -> Option<(usize, u32)> {
        let a = addr & !1;
        let i = self.0.partition_point(|s| s.0 <= a).checked_sub(1)?;
        Some((i, a - self.0[i].0))
    }

    /// The index of the symbol holding `addr`, if one does.
    pub fn index(&self, addr: u32) -> Option<usize> {
        let (i, off) = self.nearest(addr)?;
        (off < self.size(i).max(1)).then_some(i)
    }

    /// The size of the symbol at `index` (0: unsized).
    fn size(&self, index: usize) -> u32 {
        self.0[index].1
    }

    /// The name of the symbol at `index`.
    pub fn name(&self, index: usize) -> &str {
        &self.0[index].2
    }
}

impl Image {
    pub fn load(bytes: Vec<u8>) -> Result<Self, String> {
        let file = object::File::parse(&*bytes).map_err(|e| format!("not an ELF file: {e}"))?;
        let mut symbols = Vec::new();
        let mut rtt = None;
        for s in file.symbols() {
            let Ok(name) = s.name() else { continue };
            if name == "_SEGGER_RTT" {
                rtt = Some(s.address() as u32);
            }
            if matches!(s.kind(), SymbolKind::Text | SymbolKind::Data)
                && !name.is_empty()
                && !name.starts_with('$')
            {
                let name = rustc_demangle(name);
                symbols.push(((s.address() as u32) & !1, s.size() as u32, name));
            }
        }
        Ok(Self {
            bytes: bytes.clone(),
            symbols: Symbols::new(symbols),
            rtt,
        })
    }

    /// Physical load addresses: a segment's LMA differs from its VMA for
    /// .data (copied from flash at reset). The loader needs the LMA.
    pub fn load_segments(&self) -> Result<Vec<(u32, Vec<u8>)>, String> {
        let file = object::File::parse(&*self.bytes).map_err(|e| e.to_string())?;
        let mut out = Vec::new();
        if let object::File::Elf32(elf) = &file {
            use object::read::elf::ProgramHeader;
            let endian = elf.endian();
            for ph in elf.elf_program_headers() {
                if ph.p_type(endian) != object::elf::PT_LOAD || ph.p_filesz(endian) == 0 {
                    continue;
                }
                let data = ph.data(endian, &*self.bytes).map_err(|_| "bad segment")?;
                out.push((ph.p_paddr(endian), data.to_vec()));
            }
        }
        Ok(out)
    }

    /// The symbols (`--trace-calls` names the functions by them).
    pub fn symbols(&self) -> Symbols {
        self.symbols.clone()
    }

    /// The name of the symbol holding `addr`, if one does.
    pub fn function(&self, addr: u32) -> Option<&str> {
        self.symbols.index(addr).map(|i| self.symbols.name(i))
    }

    /// `name+offset` of the symbol holding `addr`, or of the nearest
    /// unsized one below it; "?" if none.
    pub fn symbol(&self, addr: u32) -> String {
        match self.symbols.nearest(addr) {
            Some((i, off)) if off < self.symbols.size(i).max(1) || self.symbols.size(i) == 0 => {
                format!("{}+{off:#x}", self.symbols.name(i))
            }
            _ => "?".into(),
        }
    }

    /// Every halfword in the loaded code equal to `op` (the WFI, WFE, SEV
    /// encodings); a match inside data is harmless (never executed).
    pub fn find_hint(&self, op: u16, segs: &[(u32, Vec<u8>)]) -> Vec<u64> {
        let mut v = Vec::new();
        for (a, d) in segs {
            if *a < 0x0800_0000 || *a >= 0x0810_0000 {
                continue;
            }
            for (i, w) in d.chunks_exact(2).enumerate() {
                if u16::from_le_bytes([w[0], w[1]]) == op {
                    v.push((*a + 2 * i as u32) as u64);
                }
            }
        }
        v
    }
}

fn rustc_demangle(s: &str) -> String {
    // legacy Rust mangling: _ZN...E with length-prefixed parts
    let Some(body) = s.strip_prefix("_ZN").and_then(|b| b.strip_suffix('E')) else {
        return s.to_string();
    };
    let mut parts = Vec::new();
    let mut rest = body;
    while !rest.is_empty() {
        let n: String = rest.chars().take_while(|c| c.is_ascii_digit()).collect();
        let Ok(len) = n.parse::<usize>() else {
            return s.to_string();
        };
        rest = &rest[n.len()..];
        if rest.len() < len {
            return s.to_string();
        }
        parts.push(&rest[..len]);
        rest = &rest[len..];
    }
    if parts
        .last()
        .is_some_and(|p| p.starts_with('h') && p.len() == 17)
    {
        parts.pop();
    }
    parts
        .join("::")
        .replace("$LT$", "<")
        .replace("$GT$", ">")
        .replace("$u20$", " ")
        .replace("..", "::")
}
