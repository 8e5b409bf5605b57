//! The power state a master reads from a statusword (SPEC §8.2, the CiA 402
//! state bits), for a drive whose state the master cannot ask for by name.

use modbus_drive::drive::PowerState;

/// The state statusword bits 0..3, 5, 6 encode; `None` for a pattern no
/// state has.
pub fn power_state(statusword: u16) -> Option<PowerState> {
    use PowerState::*;
    // bits 0..3 and 6 decide these; bit 5 (quick stop) is either
    let wide = statusword & 0x004F;
    // these need bit 5 too
    let narrow = statusword & 0x006F;
    Some(match (wide, narrow) {
        (0x0000, _) => NotReadyToSwitchOn,
        (0x0040, _) => SwitchOnDisabled,
        (0x000F, _) => FaultReactionActive,
        (0x0008, _) => Fault,
        (_, 0x0021) => ReadyToSwitchOn,
        (_, 0x0023) => SwitchedOn,
        (_, 0x0027) => OperationEnabled,
        (_, 0x0007) => QuickStopActive,
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_state_reads_back_from_the_bits_the_drive_sets() {
        use PowerState::*;
        for s in [
            NotReadyToSwitchOn,
            SwitchOnDisabled,
            ReadyToSwitchOn,
            SwitchedOn,
            OperationEnabled,
            QuickStopActive,
            FaultReactionActive,
            Fault,
        ] {
            // with the mode and status bits above bit 6 set or not
            for high in [0x0000, 0xFF80] {
                assert_eq!(
                    power_state(s.status_bits() | high),
                    Some(s),
                    "{s:?} {high:#x}"
                );
            }
        }
        assert_eq!(power_state(0x0060), Some(SwitchOnDisabled));
        assert_eq!(power_state(0x0001), None);
    }
}
