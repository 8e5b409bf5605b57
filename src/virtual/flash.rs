//! The virtual drive's parameter flash: the core's STM32G4 NOR model
//! ([`SimFlash`]: 2 KiB pages erased to 0xFF, 8-byte words programmed once,
//! writes only clear bits) persisted to the `--state` file, so the parameter
//! store runs here exactly as on the chip and saved sets survive a restart
//! (SPEC §9).
//!
//! - Write-through: every erase or word write goes to the file at once
//!   (`pwrite` of the bytes it changed, then `sync_data`). A process killed
//!   at any instant leaves the file as the flash would be after a power cut
//!   between two operations; the store's power-loss argument covers that.
//! - The file is opened for each operation: a state file that vanished or
//!   cannot be written is a failed flash (the master gets exception 4), not
//!   a crash.
//! - Several drives share one file: drive `n` of `--drives` owns bytes
//!   `[n * REGION_BYTES, (n + 1) * REGION_BYTES)`. Regions go by position in
//!   the list, not by address, because a saved PA51 may change the address.
//! - Without `--state` the same model lives in memory only.
//! - Time: each operation adds the STM32G4's typical duration
//!   ([`PAGE_ERASE_US`], [`WORD_PROGRAM_US`]) to a tally the event loop uses
//!   to answer an EE operation no earlier than the real chip would.

use std::fs::OpenOptions;
use std::io::{self, Read, Seek, SeekFrom};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use modbus_drive::params::{SimFlash, SimFlashError, SIM_PAGE_SIZE, SIM_WORD_SIZE};

/// Pages per drive: the two the parameter store needs (docs/parameters.md).
pub const REGION_PAGES: usize = 2;
pub const REGION_BYTES: usize = REGION_PAGES * SIM_PAGE_SIZE;
/// STM32G4 page erase, typical (DS12589, t_ERASE).
pub const PAGE_ERASE_US: u64 = 22_000;
/// STM32G4 double-word program, typical (DS12589, t_prog).
pub const WORD_PROGRAM_US: u64 = 82;

/// An error of the file flash.
#[derive(Debug)]
pub enum FlashError {
    /// The NOR model refused the operation.
    Cells(SimFlashError),
    /// The state file could not be written: the "flash" failed. The cause is
    /// kept for the log ([`FileFlash::take_io_error`]), since the storage
    /// layer reduces every flash error to its kind.
    Io,
}

impl NorFlashError for FlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            Self::Cells(e) => e.kind(),
            Self::Io => NorFlashErrorKind::Other,
        }
    }
}

/// One drive's flash region.
pub struct FileFlash {
    cells: SimFlash<REGION_PAGES>,
    /// State file and offset of this region in it; `None`: memory only.
    file: Option<(PathBuf, u64)>,
    io_error: Option<io::Error>,
    busy_us: u64,
}

impl FileFlash {
    /// Flash that forgets everything at exit (no `--state`).
    pub fn in_memory() -> Self {
        Self {
            cells: SimFlash::new(),
            file: None,
            io_error: None,
            busy_us: 0,
        }
    }

    /// Region `index` of the state file `path`. A missing or shorter file is
    /// extended with erased bytes (0xFF) up to the end of the region; bytes
    /// beyond it are left alone.
    pub fn open(path: &Path, index: usize) -> io::Result<Self> {
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(path)?;
        let base = (index * REGION_BYTES) as u64;
        let end = base + REGION_BYTES as u64;
        let len = file.metadata()?.len();
        if len < end {
            // Erased up to the end of this region, including the regions of
            // drives before it that were never opened (no zero-filled holes).
            file.write_all_at(&vec![0xFF; (end - len) as usize], len)?;
            file.sync_data()?;
        }
        let mut image = Vec::with_capacity(REGION_BYTES);
        file.seek(SeekFrom::Start(base))?;
        (&mut file)
            .take(REGION_BYTES as u64)
            .read_to_end(&mut image)?;
        Ok(Self {
            cells: SimFlash::from_image(&image),
            file: Some((path.to_path_buf(), base)),
            io_error: None,
            busy_us: 0,
        })
    }

    /// The file error behind the last [`FlashError::Io`], once.
    pub fn take_io_error(&mut self) -> Option<io::Error> {
        self.io_error.take()
    }

    /// Chip time of the operations since the last call, µs.
    pub fn take_busy_us(&mut self) -> u64 {
        std::mem::take(&mut self.busy_us)
    }

    /// Writes bytes `[offset, offset + len)` of the cells to the file.
    fn persist(&mut self, offset: u32, len: usize) -> Result<(), FlashError> {
        let Some((path, base)) = &self.file else {
            return Ok(());
        };
        let bytes: Vec<u8> = self.cells.bytes(offset as usize, len).collect();
        let at = base + u64::from(offset);
        let r = OpenOptions::new()
            .write(true)
            .open(path)
            .and_then(|f| f.write_all_at(&bytes, at).and_then(|()| f.sync_data()));
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
        self.cells.read(offset, bytes).map_err(FlashError::Cells)
    }

    fn capacity(&self) -> usize {
        REGION_BYTES
    }
}

impl NorFlash for FileFlash {
    const WRITE_SIZE: usize = SIM_WORD_SIZE;
    const ERASE_SIZE: usize = SIM_PAGE_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.cells.erase(from, to).map_err(FlashError::Cells)?;
        self.busy_us += PAGE_ERASE_US * u64::from(to.saturating_sub(from)) / SIM_PAGE_SIZE as u64;
        self.persist(from, to.saturating_sub(from) as usize)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.cells.write(offset, bytes).map_err(FlashError::Cells)?;
        self.busy_us += WORD_PROGRAM_US * (bytes.len() / SIM_WORD_SIZE) as u64;
        self.persist(offset, bytes.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp(name: &str) -> PathBuf {
        let p = std::env::temp_dir().join(format!(
            "modbus-drive-flash-{}-{name}.bin",
            std::process::id()
        ));
        let _ = std::fs::remove_file(&p);
        p
    }

    #[test]
    fn a_new_file_is_erased_and_what_is_written_is_in_the_file_at_once() {
        let p = temp("through");
        let mut f = FileFlash::open(&p, 0).unwrap();
        let mut buf = [0u8; 16];
        f.read(0, &mut buf).unwrap();
        assert_eq!(buf, [0xFF; 16]);
        assert_eq!(std::fs::read(&p).unwrap(), vec![0xFF; REGION_BYTES]);
        f.write(8, &[0xF0, 0x0F, 0xAA, 0x55, 0, 0xFF, 0x12, 0x34])
            .unwrap();
        // written through before anything else happens
        assert_eq!(
            std::fs::read(&p).unwrap()[8..16],
            [0xF0, 0x0F, 0xAA, 0x55, 0, 0xFF, 0x12, 0x34]
        );
        assert_eq!(f.take_busy_us(), WORD_PROGRAM_US);
        f.erase(0, SIM_PAGE_SIZE as u32).unwrap();
        assert_eq!(std::fs::read(&p).unwrap()[8..16], [0xFF; 8]);
        assert_eq!(f.take_busy_us(), PAGE_ERASE_US);
        std::fs::remove_file(&p).unwrap();
    }

    #[test]
    fn nor_rules_hold_after_a_restart() {
        let p = temp("rules");
        FileFlash::open(&p, 0)
            .unwrap()
            .write(0, &[0x0F; 8])
            .unwrap();
        let mut f = FileFlash::open(&p, 0).unwrap();
        let mut buf = [0u8; 8];
        f.read(0, &mut buf).unwrap();
        assert_eq!(buf, [0x0F; 8]);
        // a programmed word cannot be programmed again before an erase
        assert!(matches!(
            f.write(0, &[0x03; 8]),
            Err(FlashError::Cells(SimFlashError::AlreadyProgrammed))
        ));
        assert_eq!(
            f.write(4, &[0; 8]).unwrap_err().kind(),
            NorFlashErrorKind::NotAligned
        );
        assert_eq!(
            f.write(REGION_BYTES as u32, &[0; 8]).unwrap_err().kind(),
            NorFlashErrorKind::OutOfBounds
        );
        std::fs::remove_file(&p).unwrap();
    }

    #[test]
    fn regions_of_several_drives_do_not_overlap() {
        let p = temp("regions");
        FileFlash::open(&p, 1).unwrap().write(0, &[2; 8]).unwrap();
        FileFlash::open(&p, 0).unwrap().write(0, &[1; 8]).unwrap();
        let file = std::fs::read(&p).unwrap();
        assert_eq!(file.len(), 2 * REGION_BYTES);
        assert_eq!(file[..8], [1; 8]);
        assert_eq!(file[REGION_BYTES..REGION_BYTES + 8], [2; 8]);
        std::fs::remove_file(&p).unwrap();
    }

    #[test]
    fn a_state_file_that_vanished_is_a_failed_flash() {
        let p = temp("vanished");
        let mut f = FileFlash::open(&p, 0).unwrap();
        std::fs::remove_file(&p).unwrap();
        assert_eq!(
            f.write(0, &[0; 8]).unwrap_err().kind(),
            NorFlashErrorKind::Other
        );
        assert_eq!(
            f.take_io_error().map(|e| e.kind()),
            Some(io::ErrorKind::NotFound)
        );
    }
}
