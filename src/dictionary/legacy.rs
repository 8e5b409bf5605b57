//! The legacy map of seed 001 (SPEC §9): blocks of address-contiguous 16-bit
//! registers below 0x00A0, next to (not overlapping) the §5 table.
//!
//! - the DP monitor 0x0000..=0x0017 (RO, read from the drive layer,
//!   `dictionary/monitor.rs`); 0x0000 is also the old-format EE command
//!   register when *written* (seed 001 format 3(1): `06 00 00 00 0k`);
//! - the EE command register 0x003A (new format, `10 00 3A 00 01 02 00 0k`),
//!   write-only;
//! - the parameter block PA0..PA59 at 0x0064..=0x009F.
//!
//! An accepted write of an EE command register only records the operation
//! in [`Registers::ee_request`]; `Device` runs it and sends the reply once
//! it is done (SPEC §9). Values outside 1..=5 get exception 3.
//!
//! A block only describes itself; the request walk (quantity, access,
//! ranges, all-or-nothing, word order) is shared with the §5 table in
//! [`super::Registers`].

use super::{dp_value, EeOp, Params, DP_BASE, DP_LAST, PA, PA_COUNT};
use super::{DriveLayer, Registers};
use crate::rtu::Exception;

/// First address of PA0.
pub const PA_BASE: u16 = 0x0064;
/// Address of PA59.
pub const PA_LAST: u16 = PA_BASE + PA_COUNT as u16 - 1;
/// The EE command register of the new format (PA2 ≥ 7050).
pub const EE_COMMAND: u16 = 0x003A;
/// Written, DP-SPd's address is the EE command register of the old format.
pub const OLD_EE_COMMAND: u16 = DP_BASE;

/// A contiguous run of 16-bit legacy registers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Block {
    /// DP-SPd..DP-rES at 0x0000..=0x0017 (and the old EE command).
    Monitor,
    /// 0x003A.
    EeCommand,
    /// PA0..PA59 (SPEC §7) at 0x0064..=0x009F.
    Params,
}

impl Block {
    /// The block that holds `address`, if any.
    pub const fn at(address: u16) -> Option<Self> {
        match address {
            DP_BASE..=DP_LAST => Some(Self::Monitor),
            EE_COMMAND => Some(Self::EeCommand),
            PA_BASE..=PA_LAST => Some(Self::Params),
            _ => None,
        }
    }

    /// Last address of the block: a request running past it gets
    /// exception 2 (§5.2 step 6).
    pub const fn last(self) -> u16 {
        match self {
            Self::Monitor => DP_LAST,
            Self::EeCommand => EE_COMMAND,
            Self::Params => PA_LAST,
        }
    }

    /// A write to `address` gets exception 5 (§5.2 step 7).
    pub const fn read_only(self, address: u16) -> bool {
        match self {
            Self::Monitor => address != OLD_EE_COMMAND,
            Self::EeCommand => false,
            Self::Params => PA[pa_number(address)].read_only(),
        }
    }

    /// An accepted write of this block is an EE operation (the only
    /// writable address of [`Self::Monitor`] is the old EE command).
    pub const fn runs_ee_operation(self) -> bool {
        matches!(self, Self::Monitor | Self::EeCommand)
    }

    /// A read of `address` gets exception 7 (§5.2 step 7).
    pub const fn write_only(self, _address: u16) -> bool {
        match self {
            Self::EeCommand => true,
            Self::Monitor | Self::Params => false,
        }
    }

    /// Whether `value` may be written to `address` (§5.2 step 8).
    pub fn accepts(self, address: u16, value: u16) -> bool {
        match self {
            Self::Monitor | Self::EeCommand => EeOp::from_code(value).is_some(),
            Self::Params => Params::valid(pa_number(address), value),
        }
    }

    pub fn read<D: DriveLayer>(self, address: u16, regs: &Registers<'_, D>) -> u16 {
        match self {
            Self::Monitor => dp_value(address, regs.drive, regs.pa, regs.store_status),
            Self::EeCommand => 0, // write-only: never read
            Self::Params => regs.pa.get(pa_number(address)),
        }
    }

    /// Stores a validated value. The EE command registers only record the
    /// operation: its flash work, and a failure of it (exception 4, §5.2
    /// step 10), come after the request (`Device::poll_storage`). Both are
    /// single registers between read-only / absent neighbours, so a request
    /// that writes one writes nothing else.
    pub fn store<D: DriveLayer>(
        self,
        address: u16,
        value: u16,
        regs: &mut Registers<'_, D>,
    ) -> Result<(), Exception> {
        match self {
            Self::Monitor | Self::EeCommand => {
                // `accepts` checked the code; the operation runs after the
                // request (Device::poll_storage), its reply waits for it.
                regs.ee_request = EeOp::from_code(value);
                Ok(())
            }
            Self::Params => {
                // PA51/52/53 take effect only after the reply (SPEC §7):
                // `Device::reply_sent` compares them with the ones in force.
                regs.pa.set_unchecked(pa_number(address), value);
                Ok(())
            }
        }
    }
}

/// PA number of an address inside [`Block::Params`].
const fn pa_number(address: u16) -> usize {
    (address.wrapping_sub(PA_BASE) as usize) % PA_COUNT
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pa_block_spans_0x64_to_0x9f() {
        assert_eq!(Block::at(0x0063), None);
        assert_eq!(Block::at(0x0064), Some(Block::Params));
        assert_eq!(Block::at(0x009F), Some(Block::Params));
        assert_eq!(Block::at(0x00A0), None);
        assert_eq!(Block::at(0x0000), Some(Block::Monitor));
        assert_eq!(Block::at(0x0017), Some(Block::Monitor));
        assert_eq!(Block::at(0x0018), None);
        assert_eq!(Block::at(0x0039), None);
        assert_eq!(Block::at(0x003A), Some(Block::EeCommand));
        assert_eq!(Block::at(0x003B), None);
        assert!(!Block::Monitor.read_only(0x0000), "old EE command");
        assert!(Block::Monitor.read_only(0x0001));
        assert!(Block::EeCommand.write_only(0x003A));
        for code in 1..=5 {
            assert!(Block::EeCommand.accepts(0x003A, code));
            assert!(Block::Monitor.accepts(0x0000, code));
        }
        for code in [0, 6, 0xFFFF] {
            assert!(!Block::EeCommand.accepts(0x003A, code));
            assert!(!Block::Monitor.accepts(0x0000, code));
        }
        assert!(Block::Params.read_only(PA_BASE + 2));
        assert!(!Block::Params.accepts(PA_BASE + 51, 0));
        assert!(Block::Params.accepts(PA_BASE + 51, 247));
        assert!(!Block::Params.accepts(PA_BASE + 51, 248));
    }
}
