//! The parameter flash region: the last pages of the internal flash, as an
//! embedded-storage `NorFlash` whose offsets start at 0 (SPEC §9 storage; the
//! storage logic on top of it is `params`' business).
//!
//! The board's memory map (`memory-g431.x`, `memory-f103.x`) leaves these pages
//! out of FLASH, so the linker can never place code there. Generic over the
//! flash driver (embassy-stm32's blocking `Flash` on the boards), hence free
//! of HAL types: `tests/firmware_calc.rs` checks it against a RAM flash.
//!
//! A read that the chip reports as failed out of band (the G431's NMI on a
//! double ECC error, fault.rs) is an error of that read: the region asks a
//! `read_fault` hook, which takes and clears the report (the failed flash
//! address), before and after each read. Such a word fails every read
//! until its page is erased, so the region remembers the page, and
//! [`FlashRegion::erase_faulted_page`] erases it: the parameter store then
//! sees a page its own power-loss repair knows (an erased one) instead of
//! one that can never be read again.

use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

/// `len` bytes of `flash` from offset `start` (offsets relative to the flash
/// driver's base), seen as a flash of its own.
pub struct FlashRegion<F> {
    flash: F,
    start: u32,
    len: u32,
    read_fault: Option<fn() -> Option<u32>>,
    /// Region offset of the page of the last failed read.
    faulted_page: Option<u32>,
}

/// Region errors: out of the region, or the driver's own error.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RegionError<E> {
    OutOfBounds,
    Flash(E),
    /// The read returned, but the chip reported it failed (`read_fault`).
    ReadFault,
}

impl<E: NorFlashError> NorFlashError for RegionError<E> {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            Self::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            Self::Flash(e) => e.kind(),
            Self::ReadFault => NorFlashErrorKind::Other,
        }
    }
}

impl<F: NorFlash> FlashRegion<F> {
    /// `start` and `len` must be whole erase pages (checked: `None` if not,
    /// or if the region runs past the end of the flash).
    pub fn new(flash: F, start: u32, len: u32) -> Option<Self> {
        let page = F::ERASE_SIZE as u32;
        let whole_pages = start.is_multiple_of(page) && len.is_multiple_of(page) && len > 0;
        let fits = start.checked_add(len)? as usize <= flash.capacity();
        (whole_pages && fits).then_some(Self {
            flash,
            start,
            len,
            read_fault: None,
            faulted_page: None,
        })
    }

    /// `read_fault` takes and clears the chip's report of a failed read:
    /// the failed address (driver offset) if one happened since the last
    /// call.
    #[cfg_attr(not(feature = "board-g431"), allow(dead_code))] // F103: no flash ECC
    pub fn with_read_fault(self, read_fault: fn() -> Option<u32>) -> Self {
        Self {
            read_fault: Some(read_fault),
            ..self
        }
    }

    /// Erases the page of the last read that failed (see the module docs),
    /// if there was one: `Ok(Some(region offset))` then, `Ok(None)` if not.
    #[cfg_attr(not(feature = "board-g431"), allow(dead_code))] // F103: no flash ECC
    pub fn erase_faulted_page(&mut self) -> Result<Option<u32>, RegionError<F::Error>> {
        let Some(page) = self.faulted_page.take() else {
            return Ok(None);
        };
        self.erase(page, page + F::ERASE_SIZE as u32)?;
        Ok(Some(page))
    }

    /// The region's range in driver offsets.
    pub fn range(&self) -> core::ops::Range<u32> {
        self.start..self.start + self.len
    }

    fn to_flash(&self, offset: u32, n: usize) -> Result<u32, RegionError<F::Error>> {
        let end = offset
            .checked_add(n as u32)
            .ok_or(RegionError::OutOfBounds)?;
        if end > self.len {
            return Err(RegionError::OutOfBounds);
        }
        Ok(self.start + offset)
    }
}

impl<F: NorFlash> ErrorType for FlashRegion<F> {
    type Error = RegionError<F::Error>;
}

impl<F: NorFlash> ReadNorFlash for FlashRegion<F> {
    const READ_SIZE: usize = F::READ_SIZE;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        let at = self.to_flash(offset, bytes.len())?;
        let Some(read_fault) = self.read_fault else {
            return self.flash.read(at, bytes).map_err(RegionError::Flash);
        };
        read_fault(); // a stale report belongs to no read of ours
        self.flash.read(at, bytes).map_err(RegionError::Flash)?;
        let Some(failed) = read_fault() else {
            return Ok(());
        };
        // the reported word if it is ours (it is), else the read's start
        let page = F::ERASE_SIZE as u32;
        let in_region = failed.wrapping_sub(self.start);
        let offset = if in_region < self.len {
            in_region
        } else {
            offset
        };
        self.faulted_page = Some(offset - offset % page);
        Err(RegionError::ReadFault)
    }

    fn capacity(&self) -> usize {
        self.len as usize
    }
}

impl<F: NorFlash> NorFlash for FlashRegion<F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        if from > to {
            return Err(RegionError::OutOfBounds);
        }
        let at = self.to_flash(from, (to - from) as usize)?;
        self.flash
            .erase(at, at + (to - from))
            .map_err(RegionError::Flash)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let at = self.to_flash(offset, bytes.len())?;
        self.flash.write(at, bytes).map_err(RegionError::Flash)
    }
}
