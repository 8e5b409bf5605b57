//! Embedded flash: the interface registers (RM0440 §5.7 / RM0008 §3.3 with
//! PM0075) and the parameter pages as a file (`--state`).
//!
//! - ACR latency / prefetch / caches read back what was written.
//! - KEYR: KEY1 then KEY2 unlocks CR; any other write locks it until the
//!   next reset (G4 also raises a bus error: reported as a fault).
//! - Programming (G4: a double word written as two aligned 32-bit words;
//!   F1: one aligned half word) with CR.PG set, into an erased location
//!   (all ones; writing all zeros is allowed), BSY for the datasheet's
//!   programming time; misuse sets the error flags (G4 PGSERR, PGAERR,
//!   SIZERR, PROGERR, WRPERR; F1 PGERR, WRPRTERR) instead of writing.
//! - Page erase (G4 PER + PNB + STRT, F1 PER + AR + STRT), BSY for the
//!   erase time. Mass erase and option bytes are not modelled.
//! - `--write-protect`: the parameter pages are write-protected, as the
//!   option bytes' WRP areas (G4) / WRP bits (F1) would make them: erase and
//!   program set WRPERR (RM0440 §5.7.5) / WRPRTERR (RM0008 §3.3 FLASH_SR,
//!   PM0075 §2.3.3-2.3.4) and change nothing.
//! - Only the parameter pages are writable flash here; programming or
//!   erasing a page of code stops the runner (`Fault`).

use std::fs::File;
use std::io::{Seek, SeekFrom, Write};
use std::path::PathBuf;

use super::Access;

pub const KEY1: u32 = 0x4567_0123;
pub const KEY2: u32 = 0xCDEF_89AB;

#[derive(Debug)]
pub enum Op {
    Program { at: u32, bytes: Vec<u8> },
    Erase { page: u32 },
}

#[derive(Debug)]
pub struct Flash {
    g4: bool,
    pub region_base: u32,
    pub data: Vec<u8>,
    flash_base: u32,
    flash_end: u32,
    page: u32,
    file: Option<PathBuf>,
    acr: u32,
    cr: u32,
    sr: u32,
    ar: u32,
    eccr: u32,
    key_stage: u8,
    locked_for_good: bool,
    /// G4: the first word of a double word.
    half: Option<(u32, u32)>,
    busy: Option<(u64, Op)>,
    t_prog: u64,
    t_erase: u64,
    /// Operations started (programs + erases), for the power cut.
    pub ops_started: u64,
    pub cut_at: Option<u64>,
    pub cut: bool,
    /// The parameter pages are write-protected (`--write-protect`).
    pub write_protected: bool,
}

pub enum FlashWrite {
    Done,
    Fault(String),
}

impl Flash {
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        g4: bool,
        flash_base: u32,
        flash_end: u32,
        page: u32,
        region_base: u32,
        region_len: u32,
        file: Option<PathBuf>,
        t_prog: u64,
        t_erase: u64,
    ) -> std::io::Result<Self> {
        let mut data = vec![0xFF; region_len as usize];
        if let Some(f) = &file {
            match std::fs::read(f) {
                Ok(d) if d.len() == data.len() => data = d,
                Ok(d) => {
                    return Err(std::io::Error::other(format!(
                        "{}: {} bytes, expected {} (the parameter pages of this chip)",
                        f.display(),
                        d.len(),
                        data.len()
                    )))
                }
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => std::fs::write(f, &data)?,
                Err(e) => return Err(e),
            }
        }
        Ok(Self {
            g4,
            region_base,
            data,
            flash_base,
            flash_end,
            page,
            file,
            acr: if g4 { 0x0000_0600 } else { 0x0000_0030 },
            cr: if g4 { 0xC000_0000 } else { 0x0000_0080 },
            sr: 0,
            ar: 0,
            eccr: 0,
            key_stage: 0,
            locked_for_good: false,
            half: None,
            busy: None,
            t_prog,
            t_erase,
            ops_started: 0,
            cut_at: None,
            cut: false,
            write_protected: false,
        })
    }

    /// A reset (or power-up): the interface registers to their reset
    /// values, an operation in progress lost; the array keeps what was
    /// programmed and erased before.
    pub fn reset(&mut self) {
        self.acr = if self.g4 { 0x0000_0600 } else { 0x0000_0030 };
        self.cr = if self.g4 { 0xC000_0000 } else { 0x0000_0080 };
        self.sr = 0;
        self.ar = 0;
        self.eccr = 0;
        self.key_stage = 0;
        self.locked_for_good = false;
        self.half = None;
        self.busy = None;
    }

    fn locked(&self) -> bool {
        self.cr & if self.g4 { 1 << 31 } else { 1 << 7 } != 0
    }
    fn pg(&self) -> bool {
        self.cr & 1 != 0
    }
    fn bsy_bit(&self) -> u32 {
        if self.g4 {
            1 << 16
        } else {
            1
        }
    }

    pub fn irq_level(&self) -> bool {
        if self.g4 {
            (self.cr & (1 << 24) != 0 && self.sr & 1 != 0)
                || (self.cr & (1 << 25) != 0 && self.sr & 0x3FA != 0)
        } else {
            (self.cr & (1 << 12) != 0 && self.sr & (1 << 5) != 0)
                || (self.cr & (1 << 10) != 0 && self.sr & 0x14 != 0)
        }
    }

    pub fn next_event(&self) -> Option<u64> {
        self.busy.as_ref().map(|b| b.0)
    }

    fn start(&mut self, op: Op, t: u64) {
        self.ops_started += 1;
        if self.cut_at == Some(self.ops_started) {
            // the supply fails as the operation starts: it never happens
            self.cut = true;
            return;
        }
        let d = match op {
            Op::Program { .. } => self.t_prog,
            Op::Erase { .. } => self.t_erase,
        };
        self.busy = Some((t + d, op));
    }

    pub fn sync(&mut self, t: u64) -> std::io::Result<()> {
        if self.busy.as_ref().is_some_and(|b| b.0 <= t) {
            let (_, op) = self.busy.take().unwrap();
            match op {
                Op::Program { at, bytes } => {
                    let o = (at - self.region_base) as usize;
                    for (i, b) in bytes.iter().enumerate() {
                        self.data[o + i] &= b;
                    }
                    self.persist(o, bytes.len())?;
                }
                Op::Erase { page } => {
                    let o = (page - self.region_base) as usize;
                    let n = self.page as usize;
                    self.data[o..o + n].fill(0xFF);
                    self.persist(o, n)?;
                }
            }
            // EOP: F1 always, G4 only with EOPIE (RM0440 §5.7.5)
            if !self.g4 || self.cr & (1 << 24) != 0 {
                self.sr |= if self.g4 { 1 } else { 1 << 5 };
            }
        }
        Ok(())
    }

    fn persist(&self, o: usize, n: usize) -> std::io::Result<()> {
        if let Some(p) = &self.file {
            let mut f = File::options().write(true).open(p)?;
            f.seek(SeekFrom::Start(o as u64))?;
            f.write_all(&self.data[o..o + n])?;
            f.sync_data()?;
        }
        Ok(())
    }

    fn in_region(&self, a: u32, n: u32) -> bool {
        a >= self.region_base && a + n <= self.region_base + self.data.len() as u32
    }

    /// The CPU read the parameter pages.
    pub fn read_data(&self, a: u32, size: usize) -> u64 {
        let o = (a - self.region_base) as usize;
        let mut v = 0u64;
        for i in 0..size {
            v |= (self.data[o + i] as u64) << (8 * i);
        }
        v
    }

    /// The CPU wrote to flash memory (program attempt).
    pub fn write_data(&mut self, a: u32, size: usize, v: u64, t: u64) -> FlashWrite {
        if self.g4 {
            const PROGERR: u32 = 1 << 3;
            const WRPERR: u32 = 1 << 4;
            const PGAERR: u32 = 1 << 5;
            const SIZERR: u32 = 1 << 6;
            const PGSERR: u32 = 1 << 7;
            if self.locked() || !self.pg() || self.busy.is_some() || self.cr & 2 != 0 {
                self.sr |= PGSERR;
                self.half = None;
                return FlashWrite::Done;
            }
            if size != 4 {
                self.sr |= SIZERR;
                self.half = None;
                return FlashWrite::Done;
            }
            if !self.in_region(a, 4) {
                if a >= self.flash_base && a < self.flash_end {
                    return FlashWrite::Fault(format!(
                        "firmware programs its own code flash at {a:#010x}"
                    ));
                }
                self.sr |= WRPERR;
                return FlashWrite::Done;
            }
            if self.write_protected {
                self.sr |= WRPERR;
                self.half = None;
                return FlashWrite::Done;
            }
            match self.half.take() {
                None if a.is_multiple_of(8) => self.half = Some((a, v as u32)),
                None => self.sr |= PGAERR,
                Some((first, w0)) if a == first + 4 => {
                    let mut bytes = w0.to_le_bytes().to_vec();
                    bytes.extend_from_slice(&(v as u32).to_le_bytes());
                    let o = (first - self.region_base) as usize;
                    let erased = self.data[o..o + 8].iter().all(|&b| b == 0xFF);
                    if !erased && bytes.iter().any(|&b| b != 0) {
                        self.sr |= PROGERR;
                    } else {
                        self.start(Op::Program { at: first, bytes }, t);
                    }
                }
                Some(_) => self.sr |= PGAERR,
            }
        } else {
            const PGERR: u32 = 1 << 2;
            const WRPRTERR: u32 = 1 << 4;
            if size != 2 || !a.is_multiple_of(2) {
                return FlashWrite::Fault(format!(
                    "{size}-byte write to flash at {a:#010x}: the F1 flash interface takes aligned half words only (bus error)"
                ));
            }
            if self.locked() || !self.pg() || self.busy.is_some() {
                // a write without PG is ignored (no programming)
                return FlashWrite::Done;
            }
            if !self.in_region(a, 2) {
                if a >= self.flash_base && a < self.flash_end {
                    return FlashWrite::Fault(format!(
                        "firmware programs its own code flash at {a:#010x}"
                    ));
                }
                self.sr |= WRPRTERR;
                return FlashWrite::Done;
            }
            if self.write_protected {
                self.sr |= WRPRTERR;
                return FlashWrite::Done;
            }
            let o = (a - self.region_base) as usize;
            let erased = self.data[o] == 0xFF && self.data[o + 1] == 0xFF;
            if !erased && v as u16 != 0 {
                self.sr |= PGERR;
            } else {
                self.start(
                    Op::Program {
                        at: a,
                        bytes: (v as u16).to_le_bytes().to_vec(),
                    },
                    t,
                );
            }
        }
        FlashWrite::Done
    }

    fn erase_page(&mut self, page_addr: u32, t: u64) -> Result<(), String> {
        if !self.in_region(page_addr, self.page) {
            return Err(format!("firmware erases a code page at {page_addr:#010x}"));
        }
        if self.write_protected {
            // G4 WRPERR, F1 WRPRTERR: the same bit
            self.sr |= 1 << 4;
            return Ok(());
        }
        self.start(Op::Erase { page: page_addr }, t);
        Ok(())
    }

    pub fn read(&mut self, off: u32, t: u64) -> Access {
        let _ = t;
        let bsy = if self.busy.is_some() {
            self.bsy_bit()
        } else {
            0
        };
        Access::Ok(if self.g4 {
            match off {
                0x00 => self.acr,
                0x04 | 0x08 | 0x0C => 0,
                0x10 => self.sr | bsy,
                0x14 => self.cr,
                0x18 => self.eccr,
                0x20 => 0xFFEF_F8AA,
                0x24 => 0xFFFF,
                0x28 => 0,
                0x2C | 0x30 => 0xFF,
                0x70 => 0,
                _ => return Access::Unmodelled,
            }
        } else {
            match off {
                0x00 => self.acr,
                0x04 | 0x08 => 0,
                0x0C => self.sr | bsy,
                0x10 => self.cr,
                0x14 => self.ar,
                0x1C => 0x03FF_FFFC,
                0x20 => 0xFFFF_FFFF,
                _ => return Access::Unmodelled,
            }
        })
    }

    fn key(&mut self, v: u32) -> Result<(), String> {
        if self.locked_for_good {
            return Err(
                "FLASH_KEYR written after a wrong key sequence (locked until reset)".into(),
            );
        }
        match (self.key_stage, v) {
            (0, KEY1) => self.key_stage = 1,
            (1, KEY2) => {
                self.key_stage = 0;
                self.cr &= if self.g4 { !(1 << 31) } else { !(1 << 7) };
            }
            _ => {
                self.locked_for_good = true;
                if self.g4 {
                    return Err(format!("wrong FLASH_KEYR sequence (wrote {v:#010x}): bus error, CR locked until reset"));
                }
            }
        }
        Ok(())
    }

    /// Register write; `Err` = a fault the runner reports.
    pub fn write(&mut self, off: u32, v: u32, t: u64) -> Result<Access, String> {
        if self.g4 {
            match off {
                // LATENCY, PRFTEN, ICEN, DCEN, ICRST, DCRST, RUN_PD, SLEEP_PD, DBG_SWEN
                0x00 => self.acr = v & 0x0006_1F0F,
                0x04 | 0x0C => {}
                0x08 => self.key(v)?,
                0x10 => self.sr &= !(v & 0xC3FB),
                0x14 => {
                    if self.locked() {
                        return Ok(Access::Ok(0));
                    }
                    let lock = v & (1 << 31);
                    self.cr = (self.cr & (1 << 30)) | (v & 0x8F07_07FF) | lock;
                    if v & 4 != 0 {
                        return Err("flash mass erase (MER1) is not modelled".into());
                    }
                    if v & (1 << 16) != 0 && v & 2 != 0 {
                        if self.busy.is_some() {
                            self.sr |= 1 << 7;
                        } else {
                            let pnb = (v >> 3) & 0x7F;
                            self.erase_page(self.flash_base + pnb * self.page, t)?;
                        }
                    }
                    self.cr &= !(1 << 16);
                }
                0x18 => {
                    // ECCC / ECCD rc_w1, ECCCIE rw
                    self.eccr = (self.eccr & !(v & 0xC000_0000)) & !(1 << 24) | (v & (1 << 24));
                }
                _ => return Ok(Access::Unmodelled),
            }
        } else {
            match off {
                0x00 => {
                    self.acr = (self.acr & (1 << 5))
                        | (v & 0x1F)
                        | if v & (1 << 4) != 0 { 1 << 5 } else { 0 }
                }
                0x04 => self.key(v)?,
                0x08 => {}
                // PGERR, WRPRTERR, EOP: write 1 to clear
                0x0C => self.sr &= !(v & 0x34),
                0x10 => {
                    if self.locked() {
                        return Ok(Access::Ok(0));
                    }
                    self.cr = v & 0x16F7;
                    if v & 4 != 0 {
                        return Err("flash mass erase (MER) is not modelled".into());
                    }
                    if v & (1 << 6) != 0 && v & 2 != 0 && self.busy.is_none() {
                        let page =
                            (self.ar - self.flash_base) / self.page * self.page + self.flash_base;
                        self.erase_page(page, t)?;
                    }
                    self.cr &= !(1 << 6);
                }
                0x14 => self.ar = v,
                _ => return Ok(Access::Unmodelled),
            }
        }
        Ok(Access::Ok(0))
    }
}
