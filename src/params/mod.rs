//! Parameters PA0..PA59 (SPEC §7), the EE operations and their storage
//! (SPEC §9).

pub mod ee;
pub mod monitor;
mod pa;
mod record;
mod sim_flash;
pub mod storage;

pub use ee::{execute, EeError, EeOp, PendingEe};
pub use monitor::{dp_value, DriveMonitor, StoreStatus, DP_BASE, DP_ERR, DP_LAST};
pub use pa::{PaDef, Params, FIRMWARE_VERSION, PA, PA_COUNT};
pub use record::{ParamSet, RecordError, RECORD_LEN, RECORD_VERSION};
pub use sim_flash::{SimFlash, SimFlashError, SIM_PAGE_SIZE, SIM_WORD_SIZE};
pub use storage::{Boot, BootOutcome, FlashFault, ParamStore, Slot, StorageError};
