//! The legacy map of seed 001 (SPEC §9): blocks of address-contiguous 16-bit
//! registers below 0x00A0, next to (not overlapping) the §5 table.
//!
//! Today it holds the parameter block PA0..PA59 at 0x0064..=0x009F. The
//! parameters issue (5) adds here, as further [`Block`] variants:
//! - the DP monitor 0x0000..=0x0017 (RO, read from the drive layer),
//! - the EE command register 0x003A (new EE format, `10 00 3A 00 01 02 00 0k`),
//!
//! and handles the old EE format (`06 00 00 00 0k`) in the dispatcher.
//! Until then those addresses are "not an entry" (exception 11).
//!
//! A block only describes itself; the request walk (quantity, access,
//! ranges, all-or-nothing, word order) is shared with the §5 table in
//! [`super::Registers`].

use super::{DriveLayer, Registers};
use crate::params::{Params, PA, PA_COUNT};
use crate::slave::Exception;

/// First address of PA0.
pub const PA_BASE: u16 = 0x0064;
/// Address of PA59.
pub const PA_LAST: u16 = PA_BASE + PA_COUNT as u16 - 1;

/// A contiguous run of 16-bit legacy registers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Block {
    /// PA0..PA59 (SPEC §7) at 0x0064..=0x009F.
    Params,
}

impl Block {
    /// The block that holds `address`, if any.
    pub const fn at(address: u16) -> Option<Self> {
        match address {
            PA_BASE..=PA_LAST => Some(Self::Params),
            _ => None,
        }
    }

    /// Last address of the block: a request running past it gets
    /// exception 2 (§5.2 step 6).
    pub const fn last(self) -> u16 {
        match self {
            Self::Params => PA_LAST,
        }
    }

    /// A write to `address` gets exception 5 (§5.2 step 7).
    pub const fn read_only(self, address: u16) -> bool {
        match self {
            Self::Params => PA[pa_number(address)].read_only,
        }
    }

    /// A read of `address` gets exception 7 (§5.2 step 7).
    pub const fn write_only(self, _address: u16) -> bool {
        match self {
            Self::Params => false,
        }
    }

    /// Whether `value` may be written to `address` (§5.2 step 8).
    pub fn accepts(self, address: u16, value: u16) -> bool {
        match self {
            Self::Params => Params::valid(pa_number(address), value),
        }
    }

    pub fn read<D: DriveLayer>(self, address: u16, regs: &Registers<'_, D>) -> u16 {
        match self {
            Self::Params => regs.pa.get(pa_number(address)),
        }
    }

    /// Stores a validated value. A block whose effect can fail (the EE
    /// command register) returns [`Exception::DeviceFailure`] (§5.2 step
    /// 10); it must then be a block of one register so that nothing else of
    /// the request was stored before it.
    pub fn store<D: DriveLayer>(
        self,
        address: u16,
        value: u16,
        regs: &mut Registers<'_, D>,
    ) -> Result<(), Exception> {
        match self {
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
        // SPEC §9 monitor and EE register: issue 5, not entries yet.
        assert_eq!(Block::at(0x0000), None);
        assert_eq!(Block::at(0x003A), None);
        assert!(Block::Params.read_only(PA_BASE + 2));
        assert!(!Block::Params.accepts(PA_BASE + 51, 0));
        assert!(Block::Params.accepts(PA_BASE + 51, 247));
        assert!(!Block::Params.accepts(PA_BASE + 51, 248));
    }
}
