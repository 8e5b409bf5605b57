//! Modbus exception codes (SPEC §5.2): what a refused request is answered
//! with, under either exception profile (PA55).

/// The exception codes of seed 000 (SPEC §5.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Exception {
    IllegalFunction = 1,
    IllegalDataAddress = 2,
    IllegalDataValue = 3,
    DeviceFailure = 4,
    WriteReadOnly = 5,
    Busy = 6,
    ReadWriteOnly = 7,
    ByteCountMismatch = 8,
    Parity = 9,
    Crc = 10,
    NoSuchRegister = 11,
}

impl Exception {
    /// The vendor code (PA55 = 0).
    pub const fn vendor_code(self) -> u8 {
        self as u8
    }

    /// The code sent under the profile PA55 selects; `None` when the
    /// standard profile sends nothing (9 and 10, §5.2).
    pub const fn code(self, standard_profile: bool) -> Option<u8> {
        if !standard_profile {
            return Some(self as u8);
        }
        match self {
            Self::WriteReadOnly | Self::ReadWriteOnly | Self::NoSuchRegister => Some(2),
            Self::ByteCountMismatch => Some(3),
            Self::Parity | Self::Crc => None,
            other => Some(other as u8),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn standard_profile_maps_vendor_codes() {
        // SPEC §5.2: PA55 = 1 → 5, 7, 11 → 2; 8 → 3; 9/10 never sent.
        use Exception::*;
        let all = [
            IllegalFunction,
            IllegalDataAddress,
            IllegalDataValue,
            DeviceFailure,
            WriteReadOnly,
            Busy,
            ReadWriteOnly,
            ByteCountMismatch,
            Parity,
            Crc,
            NoSuchRegister,
        ];
        let standard = [
            Some(1),
            Some(2),
            Some(3),
            Some(4),
            Some(2),
            Some(6),
            Some(2),
            Some(3),
            None,
            None,
            Some(2),
        ];
        for (i, (e, s)) in all.iter().zip(standard).enumerate() {
            assert_eq!(e.code(false), Some(i as u8 + 1));
            assert_eq!(e.vendor_code(), i as u8 + 1);
            assert_eq!(e.code(true), s, "{e:?}");
        }
    }
}
