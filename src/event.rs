//! What the core reports for the glue to log (defmt on the probe, stderr on
//! the host). The core itself never logs.
//!
//! [`crate::device::Device`] queues these; the glue drains them with
//! `Device::take_event`. Other parts add their own variants here (state
//! changes, faults, parameters loaded); the enum is `non_exhaustive` so that
//! the glue keeps a catch-all arm.

use crate::drive::DriveEvent;
use crate::params::{BootOutcome, EeError, EeOp};
use crate::rtu::Exception;
use crate::rtu::LineConfig;

/// Why a received frame was not used (SPEC §1, §3, §6).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// CRC mismatch (§3, code 10 when answered).
    Crc,
    /// UART parity error in one of its bytes (§3, code 9 when answered).
    Parity,
    /// Silence > t1.5 inside the frame, or a framing error (§1).
    Broken,
    /// Fewer than 4 bytes (§1).
    TooShort,
    /// Longer than 256 bytes or bytes lost by the UART (§1).
    Overrun,
}

/// One thing that happened in the core.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Event {
    /// A frame was discarded. `address` is its first byte when it had one
    /// (CRC / parity errors); `answered` says whether exception 9/10 went
    /// out (§3: own address, PA54 = 1, vendor profile).
    FrameError {
        kind: FrameError,
        address: Option<u8>,
        answered: bool,
    },
    /// A request to us (or a broadcast) was refused (§5.2). `answered` is
    /// false for broadcasts.
    Exception {
        function: u8,
        exception: Exception,
        answered: bool,
    },
    /// Diagnostics 0x08/0x04 put the slave in listen-only mode (`true`), or
    /// 0x08/0x01 took it out (`false`).
    ListenOnly(bool),
    /// Diagnostics 0x08/0x01 or 0x08/0x0A cleared the §6 counters.
    CountersCleared,
    /// A new slave address (PA51) took effect after the reply (§7).
    AddressChanged { address: u8 },
    /// New line settings (PA52/PA53) took effect after the reply (§7).
    LineChanged(LineConfig),
    /// At power-up: the saved parameter set was loaded, or defaults are in
    /// use because the store was blank or unreadable (SPEC §9; DP-Err too).
    ParamsLoaded(BootOutcome),
    /// An EE operation (SPEC §9) finished; `error` is why it failed (the
    /// master got exception 4).
    EeDone { op: EeOp, error: Option<EeError> },
    /// The drive layer changed state, faulted, stopped at a limit, homed
    /// (SPEC §8).
    Drive(DriveEvent),
}
