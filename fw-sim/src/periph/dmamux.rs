//! DMAMUX1 of the G4: RM0440 §13. Twelve request-line multiplexer channels
//! on the G431 (0..5 feed DMA1 channels 1..6, 6..11 DMA2 channels 1..6):
//! each CxCR names the peripheral request (DMAREQ_ID, RM0440 table 91)
//! that reaches its DMA channel. Synchronisation (SE), event generation
//! (EGE) and the request generators (GE) are not modelled: setting one
//! stops the runner; their other bits are storage.

use super::Access;

pub const CHANNELS: usize = 12;

#[derive(Debug, Default)]
pub struct DmaMux {
    ccr: [u32; CHANNELS],
    rgcr: [u32; 4],
}

impl DmaMux {
    /// The multiplexer channels that pass request `id` on.
    pub fn routes(&self, id: u32) -> impl Iterator<Item = usize> + '_ {
        (0..CHANNELS).filter(move |&c| id != 0 && self.ccr[c] & 0x7F == id)
    }

    pub fn read(&self, off: u32) -> Access {
        Access::Ok(match off {
            0x00..=0x2C => self.ccr[(off / 4) as usize],
            0x80 | 0x84 => 0,
            0x100..=0x10C => self.rgcr[((off - 0x100) / 4) as usize],
            0x140 | 0x144 => 0,
            _ => return Access::Unmodelled,
        })
    }

    pub fn write(&mut self, off: u32, v: u32) -> Access {
        match off {
            0x00..=0x2C => {
                if v & ((1 << 16) | (1 << 9)) != 0 {
                    return Access::Unsupported("DMAMUX synchronisation / event generation");
                }
                self.ccr[(off / 4) as usize] = v & 0x1FFF_FF7F;
            }
            0x84 | 0x144 => {}
            0x100..=0x10C => {
                if v & (1 << 16) != 0 {
                    return Access::Unsupported("DMAMUX request generator");
                }
                self.rgcr[((off - 0x100) / 4) as usize] = v;
            }
            _ => return Access::Unmodelled,
        }
        Access::Ok(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_channel_passes_the_request_it_names() {
        let mut m = DmaMux::default();
        m.write(0x08, 65); // channel 2 (DMA1 channel 3): TIM3_UP
        assert_eq!(m.routes(65).collect::<Vec<_>>(), [2]);
        assert_eq!(m.routes(71).count(), 0);
        assert!(matches!(
            m.write(0x08, 65 | 1 << 16),
            Access::Unsupported(_)
        ));
        assert!(matches!(m.read(0x30), Access::Unmodelled));
    }
}
