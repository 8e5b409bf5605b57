//! File-backed NOR flash (`--state FILE`): the virtual drive's parameter
//! flash, with the semantics of the real part so that the storage code runs
//! here exactly as on the STM32 (SPEC §9: saved data survives power loss).
//!
//! - Erase sets a whole erase unit to 0xFF; a write can only clear bits (the
//!   stored byte becomes `old & new`), as on NOR cells.
//! - Geometry of the STM32G4 data area: 8-byte program unit, 2 KiB pages.
//! - Every operation goes to the file at once (write-through, then
//!   `sync_data`), so killing the process at any instant leaves the file as
//!   the flash would be after a power cut between two operations.
//! - Several drives share one file: drive `n` of `--drives` owns the byte
//!   range `[n * capacity, (n + 1) * capacity)`. Regions go by position in
//!   the list, not by address, because a saved PA51 may change the address.

use std::fs::{File, OpenOptions};
use std::io;
use std::os::unix::fs::FileExt;
use std::path::Path;

use embedded_storage::nor_flash::{
    check_erase, check_read, check_write, ErrorType, NorFlash, NorFlashError, NorFlashErrorKind,
    ReadNorFlash,
};

/// Program unit of the STM32G4 flash (a double word).
pub const WRITE_SIZE: usize = 8;
/// Page size of the STM32G4 flash (single-bank mode).
pub const ERASE_SIZE: usize = 2048;
/// Flash given to each drive: four pages.
pub const REGION_BYTES: usize = 4 * ERASE_SIZE;

/// An error of the file flash.
#[derive(Debug)]
pub enum FlashError {
    /// Misaligned or out-of-range request (a bug in the caller).
    Nor(NorFlashErrorKind),
    /// The file could not be read or written: the "flash" failed. The cause
    /// is kept in [`FileFlash::take_io_error`] for the log, since the
    /// storage layer reduces every flash error to its kind.
    Io,
}

impl NorFlashError for FlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            Self::Nor(k) => *k,
            Self::Io => NorFlashErrorKind::Other,
        }
    }
}

impl From<NorFlashErrorKind> for FlashError {
    fn from(k: NorFlashErrorKind) -> Self {
        Self::Nor(k)
    }
}

/// One drive's region of the state file.
pub struct FileFlash {
    file: File,
    base: u64,
    capacity: usize,
    io_error: Option<io::Error>,
}

impl FileFlash {
    /// Opens (or creates) `path` and returns the region of drive `index`.
    /// Missing bytes up to the end of the region are created erased (0xFF);
    /// bytes beyond it are left alone.
    pub fn open(path: &Path, index: usize, capacity: usize) -> io::Result<Self> {
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(path)?;
        let base = (index * capacity) as u64;
        let end = base + capacity as u64;
        let len = file.metadata()?.len();
        if len < end {
            let fill = vec![0xFF; (end - len) as usize];
            file.write_all_at(&fill, len)?;
            file.sync_data()?;
        }
        Ok(Self {
            file,
            base,
            capacity,
            io_error: None,
        })
    }

    /// The file error behind the last [`FlashError::Io`], once.
    pub fn take_io_error(&mut self) -> Option<io::Error> {
        self.io_error.take()
    }

    fn io<T>(&mut self, r: io::Result<T>) -> Result<T, FlashError> {
        r.map_err(|e| {
            self.io_error = Some(e);
            FlashError::Io
        })
    }
}

impl ErrorType for FileFlash {
    type Error = FlashError;
}

impl ReadNorFlash for FileFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        check_read(self, offset, bytes.len())?;
        let r = self
            .file
            .read_exact_at(bytes, self.base + u64::from(offset));
        self.io(r)
    }

    fn capacity(&self) -> usize {
        self.capacity
    }
}

impl NorFlash for FileFlash {
    const WRITE_SIZE: usize = WRITE_SIZE;
    const ERASE_SIZE: usize = ERASE_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        check_erase(self, from, to)?;
        let erased = vec![0xFF; (to - from) as usize];
        let at = self.base + u64::from(from);
        let r = self
            .file
            .write_all_at(&erased, at)
            .and_then(|()| self.file.sync_data());
        self.io(r)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        check_write(self, offset, bytes.len())?;
        let at = self.base + u64::from(offset);
        let mut cells = vec![0u8; bytes.len()];
        let r = self.file.read_exact_at(&mut cells, at).and_then(|()| {
            // NOR programming only pulls bits to 0.
            for (cell, &b) in cells.iter_mut().zip(bytes) {
                *cell &= b;
            }
            self.file.write_all_at(&cells, at)?;
            self.file.sync_data()
        });
        self.io(r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp(name: &str) -> std::path::PathBuf {
        let p = std::env::temp_dir().join(format!(
            "modbus-drive-flash-{}-{name}.bin",
            std::process::id()
        ));
        let _ = std::fs::remove_file(&p);
        p
    }

    #[test]
    fn a_new_file_reads_erased_and_writes_only_clear_bits() {
        let p = temp("bits");
        let mut f = FileFlash::open(&p, 0, REGION_BYTES).unwrap();
        let mut buf = [0u8; 16];
        f.read(0, &mut buf).unwrap();
        assert_eq!(buf, [0xFF; 16]);
        f.write(8, &[0xF0, 0x0F, 0xAA, 0x55, 0, 0xFF, 0x12, 0x34])
            .unwrap();
        f.write(8, &[0x3C; 8]).unwrap();
        f.read(8, &mut buf[..8]).unwrap();
        assert_eq!(buf[..8], [0x30, 0x0C, 0x28, 0x14, 0, 0x3C, 0x10, 0x34]);
        f.erase(0, ERASE_SIZE as u32).unwrap();
        f.read(8, &mut buf[..8]).unwrap();
        assert_eq!(buf[..8], [0xFF; 8]);
        std::fs::remove_file(&p).unwrap();
    }

    #[test]
    fn contents_survive_reopening_and_regions_do_not_overlap() {
        let p = temp("regions");
        {
            let mut a = FileFlash::open(&p, 0, REGION_BYTES).unwrap();
            let mut b = FileFlash::open(&p, 1, REGION_BYTES).unwrap();
            a.write(0, &[1; 8]).unwrap();
            b.write(0, &[2; 8]).unwrap();
        }
        assert_eq!(
            std::fs::metadata(&p).unwrap().len(),
            2 * REGION_BYTES as u64
        );
        let mut a = FileFlash::open(&p, 0, REGION_BYTES).unwrap();
        let mut b = FileFlash::open(&p, 1, REGION_BYTES).unwrap();
        let mut buf = [0u8; 8];
        a.read(0, &mut buf).unwrap();
        assert_eq!(buf, [1; 8]);
        b.read(0, &mut buf).unwrap();
        assert_eq!(buf, [2; 8]);
        std::fs::remove_file(&p).unwrap();
    }

    #[test]
    fn misaligned_and_out_of_range_requests_are_refused() {
        let p = temp("checks");
        let mut f = FileFlash::open(&p, 0, REGION_BYTES).unwrap();
        let kind = |r: Result<(), FlashError>| r.unwrap_err().kind();
        assert_eq!(kind(f.write(4, &[0; 8])), NorFlashErrorKind::NotAligned);
        assert_eq!(kind(f.write(0, &[0; 4])), NorFlashErrorKind::NotAligned);
        assert_eq!(kind(f.erase(0, 100)), NorFlashErrorKind::NotAligned);
        assert_eq!(
            kind(f.write(REGION_BYTES as u32, &[0; 8])),
            NorFlashErrorKind::OutOfBounds
        );
        let mut buf = [0u8; 2];
        assert_eq!(
            kind(f.read(REGION_BYTES as u32 - 1, &mut buf)),
            NorFlashErrorKind::OutOfBounds
        );
        std::fs::remove_file(&p).unwrap();
    }
}
