//! The EE operations and the parameter storage (SPEC §9). The PA set itself
//! (SPEC §7) and the DP monitor are register values and live in
//! [`crate::dictionary`]; they are re-exported here under their old paths.

pub mod ee;
mod migrate;
mod record;
#[cfg(feature = "sim")]
mod sim_flash;
pub mod storage;

pub use crate::dictionary::{
    dp_value, DriveMonitor, PaDef, Params, StoreStatus, DP_BASE, DP_ERR, DP_LAST, FIRMWARE_VERSION,
    PA, PA_COUNT,
};
pub use ee::{execute, EeError, EeOp, PendingEe};
pub use record::{ParamSet, RecordError, RECORD_LEN, RECORD_VERSION};
#[cfg(feature = "sim")]
pub use sim_flash::{SimFlash, SimFlashError, SIM_PAGE_SIZE, SIM_WORD_SIZE};
pub use storage::{Boot, BootOutcome, FlashFault, ParamStore, Slot, StorageError};
