//! Parameters PA0..PA59 (SPEC §7), the EE operations and their storage
//! (SPEC §9).

mod pa;

pub use pa::{PaDef, Params, PA, PA_COUNT};
