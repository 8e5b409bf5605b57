//! A RAM NOR flash with STM32G4 geometry (or another: page and program word
//! sizes are parameters, the STM32F1's are 1 KiB and 2 bytes) that can lose
//! power after any number of word writes or page erases: the test double of the power-loss tests
//! (SPEC §9) and the virtual drive's flash when it keeps no state file.
//!
//! NOR semantics as the storage must expect them:
//! - erase sets a whole 2 KiB page to 0xFF;
//! - a write programs whole 8-byte words (STM32G4 double words), aligned,
//!   each only once between erases (a second write is refused, as the
//!   STM32's PROGERR does), and can only clear bits — except that an
//!   all-zero word may be written over anything, as RM0440 §3.3.8 allows on
//!   the STM32G4 (the sequential-storage map of the firmware before the
//!   journal relied on it to finish a page marker that a cut left half
//!   written; [`SimFlash::set_zero_overwrite`] turns it off for the strict
//!   `NorFlash` contract);
//! - [`SimFlash::cut_power_after`]`(n)`: operations (one word write or one
//!   page erase each) number `n` and beyond fail; operation `n` itself is
//!   left half done — a word with only some of its bits programmed, or a
//!   page erased only part-way with one byte of mixed bits — after which
//!   every access fails until [`SimFlash::power_up`].

use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

/// STM32G4 page (erase unit).
pub const SIM_PAGE_SIZE: usize = 2048;
/// STM32G4 double word (program unit).
pub const SIM_WORD_SIZE: usize = 8;

/// Why an operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SimFlashError {
    /// The power was cut (see [`SimFlash::cut_power_after`]).
    PowerLost,
    /// A failure injected with [`SimFlash::fail_after`].
    Injected,
    NotAligned,
    OutOfBounds,
    /// A word was programmed twice without an erase.
    AlreadyProgrammed,
}

impl NorFlashError for SimFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            Self::NotAligned => NorFlashErrorKind::NotAligned,
            Self::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            _ => NorFlashErrorKind::Other,
        }
    }
}

#[derive(Clone)]
struct Page<const PAGE: usize> {
    bytes: [u8; PAGE],
    /// Word (by index, the tail unused) programmed since the last erase (or
    /// left undefined by a cut).
    programmed: [bool; PAGE],
    erases: u32,
}

/// `PAGES` pages of `PAGE` bytes of simulated NOR flash, addressed from 0,
/// programmed in words of `WORD` bytes.
#[derive(Clone)]
pub struct SimFlash<
    const PAGES: usize,
    const PAGE: usize = SIM_PAGE_SIZE,
    const WORD: usize = SIM_WORD_SIZE,
> {
    pages: [Page<PAGE>; PAGES],
    /// Operations (word writes + page erases) done since power-up.
    ops: u32,
    cut_at: Option<u32>,
    fail_at: Option<u32>,
    powered: bool,
    zero_overwrite: bool,
}

impl<const PAGES: usize, const PAGE: usize, const WORD: usize> Default
    for SimFlash<PAGES, PAGE, WORD>
{
    fn default() -> Self {
        Self::new()
    }
}

impl<const PAGES: usize, const PAGE: usize, const WORD: usize> SimFlash<PAGES, PAGE, WORD> {
    /// Erased flash.
    pub fn new() -> Self {
        Self {
            pages: core::array::from_fn(|_| Page {
                bytes: [0xFF; PAGE],
                programmed: [false; PAGE],
                erases: 0,
            }),
            ops: 0,
            cut_at: None,
            fail_at: None,
            powered: true,
            zero_overwrite: true,
        }
    }

    /// Whether an all-zero word may be written over a programmed one (the
    /// STM32G4 rule, default) or not (the strict `NorFlash` contract).
    pub fn set_zero_overwrite(&mut self, allowed: bool) {
        self.zero_overwrite = allowed;
    }

    /// Operations counted since the last [`Self::power_up`] / creation.
    pub fn ops(&self) -> u32 {
        self.ops
    }

    /// Erase count of each page since creation.
    pub fn erase_counts(&self) -> [u32; PAGES] {
        core::array::from_fn(|i| self.pages[i].erases)
    }

    /// Loses power during operation number `n` (0-based, counted from now).
    pub fn cut_power_after(&mut self, n: u32) {
        self.cut_at = Some(self.ops + n);
    }

    /// Operation number `n` from now fails cleanly (the flash reports an
    /// error, nothing is changed) and so does every later one until
    /// [`Self::power_up`]: a worn-out or locked flash.
    pub fn fail_after(&mut self, n: u32) {
        self.fail_at = Some(self.ops + n);
    }

    /// Whether the power is still on.
    pub fn powered(&self) -> bool {
        self.powered
    }

    /// A reboot: power on again with whatever the cells hold.
    pub fn power_up(&mut self) {
        self.powered = true;
        self.cut_at = None;
        self.fail_at = None;
        self.ops = 0;
    }

    /// A flash holding `image` (shorter images are padded with 0xFF, longer
    /// ones cut): what the virtual drive reads from its state file. A word
    /// that is not all 0xFF counts as programmed.
    pub fn from_image(image: &[u8]) -> Self {
        let mut f = Self::new();
        for (p, page) in f.pages.iter_mut().enumerate() {
            let start = (p * PAGE).min(image.len());
            let end = ((p + 1) * PAGE).min(image.len());
            page.bytes[..end - start].copy_from_slice(&image[start..end]);
            for (w, programmed) in page.programmed.iter_mut().take(PAGE / WORD).enumerate() {
                let word = &page.bytes[w * WORD..(w + 1) * WORD];
                *programmed = word.iter().any(|&b| b != 0xFF);
            }
        }
        f
    }

    /// The whole contents, `PAGES * PAGE` bytes: what the virtual
    /// drive writes to its state file.
    pub fn image(&self) -> impl Iterator<Item = u8> + '_ {
        self.bytes(0, PAGES * PAGE)
    }

    /// Raw bytes from `offset`.
    pub fn bytes(&self, offset: usize, len: usize) -> impl Iterator<Item = u8> + '_ {
        (offset..offset + len).map(|a| self.pages[a / PAGE].bytes[a % PAGE])
    }

    /// Counts one operation; `Ok(true)` if it is the one the power dies in.
    fn begin_op(&mut self) -> Result<bool, SimFlashError> {
        if !self.powered {
            return Err(SimFlashError::PowerLost);
        }
        if self.fail_at.is_some_and(|f| self.ops >= f) {
            return Err(SimFlashError::Injected);
        }
        let n = self.ops;
        self.ops += 1;
        if self.cut_at == Some(n) {
            self.powered = false;
            return Ok(true);
        }
        Ok(false)
    }

    /// Deterministic "random" bits for the half-done cell of a cut.
    fn noise(&self, salt: u32) -> u8 {
        let mut x = self.ops.wrapping_mul(0x9E37_79B9) ^ salt.wrapping_mul(0x85EB_CA6B);
        x ^= x >> 15;
        x = x.wrapping_mul(0x2C1B_3C6D);
        (x ^ (x >> 12)) as u8
    }

    fn check(offset: u32, len: usize, align: usize) -> Result<(), SimFlashError> {
        let off = offset as usize;
        if !off.is_multiple_of(align) || !len.is_multiple_of(align) {
            return Err(SimFlashError::NotAligned);
        }
        if off + len > PAGES * PAGE {
            return Err(SimFlashError::OutOfBounds);
        }
        Ok(())
    }
}

impl<const PAGES: usize, const PAGE: usize, const WORD: usize> ErrorType
    for SimFlash<PAGES, PAGE, WORD>
{
    type Error = SimFlashError;
}

impl<const PAGES: usize, const PAGE: usize, const WORD: usize> ReadNorFlash
    for SimFlash<PAGES, PAGE, WORD>
{
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        if !self.powered {
            return Err(SimFlashError::PowerLost);
        }
        Self::check(offset, bytes.len(), 1)?;
        let len = bytes.len();
        for (b, v) in bytes.iter_mut().zip(self.bytes(offset as usize, len)) {
            *b = v;
        }
        Ok(())
    }

    fn capacity(&self) -> usize {
        PAGES * PAGE
    }
}

impl<const PAGES: usize, const PAGE: usize, const WORD: usize> NorFlash
    for SimFlash<PAGES, PAGE, WORD>
{
    const WRITE_SIZE: usize = WORD;
    const ERASE_SIZE: usize = PAGE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        if to < from {
            return Err(SimFlashError::OutOfBounds);
        }
        Self::check(from, (to - from) as usize, PAGE)?;
        for p in from as usize / PAGE..to as usize / PAGE {
            let cut = self.begin_op()?;
            let noise = self.noise(p as u32);
            let page = &mut self.pages[p];
            page.erases += 1;
            if cut {
                // Erased part-way: a prefix is 0xFF, one byte has mixed bits,
                // the rest keeps its old contents; every word of the page is
                // in an undefined state for programming.
                let upto = usize::from(noise) * PAGE / 256;
                page.bytes[..upto].fill(0xFF);
                page.bytes[upto] |= noise | 0x01;
                for (w, programmed) in page.programmed.iter_mut().take(PAGE / WORD).enumerate() {
                    *programmed = (w + 1) * WORD > upto;
                }
                return Err(SimFlashError::PowerLost);
            }
            page.bytes.fill(0xFF);
            page.programmed.fill(false);
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        Self::check(offset, bytes.len(), WORD)?;
        for (i, word) in bytes.chunks_exact(WORD).enumerate() {
            let addr = offset as usize + i * WORD;
            let (p, at) = (addr / PAGE, addr % PAGE);
            let zeros = word.iter().all(|&b| b == 0);
            if self.powered
                && self.pages[p].programmed[at / WORD]
                && !(zeros && self.zero_overwrite)
            {
                return Err(SimFlashError::AlreadyProgrammed);
            }
            let cut = self.begin_op()?;
            let noise = self.noise(addr as u32);
            let page = &mut self.pages[p];
            page.programmed[at / WORD] = true;
            for (k, (cell, &v)) in page.bytes[at..at + WORD].iter_mut().zip(word).enumerate() {
                // A cut programs the first bytes fully and some bits of the
                // next ones: only bits that were to be cleared get cleared.
                let keep_ones = match (cut, k) {
                    (false, _) => 0,
                    (true, k) if k < usize::from(noise % 8) => 0,
                    (true, k) => noise.rotate_left(k as u32) | 0x80,
                };
                *cell &= v | keep_ones;
            }
            if cut {
                return Err(SimFlashError::PowerLost);
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nor_rules_are_enforced() {
        let mut f = SimFlash::<2>::new();
        assert_eq!(f.write(4, &[0; 8]), Err(SimFlashError::NotAligned));
        assert_eq!(f.write(0, &[0; 4]), Err(SimFlashError::NotAligned));
        assert_eq!(f.erase(0, 100), Err(SimFlashError::NotAligned));
        assert_eq!(f.write(4096, &[0; 8]), Err(SimFlashError::OutOfBounds));
        f.write(8, &[0x12; 8]).unwrap();
        assert_eq!(
            f.write(8, &[0x12; 8]),
            Err(SimFlashError::AlreadyProgrammed)
        );
        let mut b = [0; 8];
        f.read(8, &mut b).unwrap();
        assert_eq!(b, [0x12; 8]);
        f.write(8, &[0; 8]).unwrap(); // STM32G4: zeros over anything
        f.set_zero_overwrite(false);
        assert_eq!(f.write(8, &[0; 8]), Err(SimFlashError::AlreadyProgrammed));
        f.read(8, &mut b).unwrap();
        assert_eq!(b, [0; 8]);
        f.erase(0, 2048).unwrap();
        f.read(8, &mut b).unwrap();
        assert_eq!(b, [0xFF; 8]);
        f.write(8, &[0x34; 8]).unwrap();
        assert_eq!(f.erase_counts(), [1, 0]);
    }

    #[test]
    fn an_image_round_trips() {
        let mut f = SimFlash::<2>::new();
        f.write(2048 + 16, &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap();
        let image: [u8; 4096] = {
            let mut b = [0; 4096];
            b.iter_mut().zip(f.image()).for_each(|(d, s)| *d = s);
            b
        };
        let mut g = SimFlash::<2>::from_image(&image);
        assert!(g.image().eq(f.image()));
        assert_eq!(
            g.write(2048 + 16, &[0x55; 8]),
            Err(SimFlashError::AlreadyProgrammed)
        );
        g.write(2048 + 24, &[0x55; 8]).unwrap();
    }

    #[test]
    fn a_cut_leaves_the_word_half_programmed_and_stops_everything() {
        let mut f = SimFlash::<1>::new();
        f.cut_power_after(1);
        f.write(0, &[0x40u8; 16]).unwrap_err();
        assert!(!f.powered());
        let mut b = [0; 16];
        assert_eq!(f.read(0, &mut b), Err(SimFlashError::PowerLost));
        f.power_up();
        f.read(0, &mut b).unwrap();
        assert_eq!(b[..8], [0x40; 8], "the word before the cut is complete");
        assert_ne!(b[8..], [0x40; 8], "the cut word is not complete");
        assert_ne!(b[8..], [0xFF; 8], "the cut word is not untouched");
        assert!(
            b[8..].iter().all(|&v| v & 0x40 == 0x40),
            "only cleared bits"
        );
        assert_eq!(
            f.write(8, &[0x40; 8]),
            Err(SimFlashError::AlreadyProgrammed),
            "a half-programmed word needs an erase"
        );
    }

    #[test]
    fn a_cut_erase_leaves_old_bytes() {
        let mut f = SimFlash::<1>::new();
        f.write(2040, &[0; 8]).unwrap();
        f.cut_power_after(0);
        f.erase(0, 2048).unwrap_err();
        f.power_up();
        let tail: u8 = f.bytes(2040, 8).fold(0xFF, |a, b| a & b);
        assert_ne!(tail, 0xFF, "the end of the page was not reached");
    }

    #[test]
    fn injected_failure_changes_nothing() {
        let mut f = SimFlash::<1>::new();
        f.fail_after(0);
        assert_eq!(f.write(0, &[0; 8]), Err(SimFlashError::Injected));
        assert!(f.bytes(0, 8).all(|b| b == 0xFF));
    }
}
