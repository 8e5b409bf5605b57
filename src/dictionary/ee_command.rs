//! The EE command register (0x003A, or 0x0000 in the old format; SPEC §9):
//! which operation a write asks for. Running it is the parameter store's
//! job (`params/ee.rs`).

/// An EE operation code (register 0x003A, or the old 0x06 to 0x0000).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EeOp {
    /// EE-Set (1).
    Save = 1,
    /// EE-rd (2).
    Reload = 2,
    /// EE-bA (3).
    Backup = 3,
    /// EE-rS (4).
    RestoreBackup = 4,
    /// EE-dEF (5).
    RestoreDefaults = 5,
}

impl EeOp {
    /// From the register value; `None` outside 1..=5 (→ exception 3).
    pub fn from_code(v: u16) -> Option<Self> {
        Some(match v {
            1 => Self::Save,
            2 => Self::Reload,
            3 => Self::Backup,
            4 => Self::RestoreBackup,
            5 => Self::RestoreDefaults,
            _ => return None,
        })
    }

    pub fn code(self) -> u16 {
        self as u16
    }
}
