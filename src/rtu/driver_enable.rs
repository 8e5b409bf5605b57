//! RS-485 driver enable (DE) timing: how long the transceiver's driver is
//! switched on before the first start bit of a reply (lead, PA57) and
//! kept on after its last stop bit (tail, PA58), in bit times of the line
//! in force (PA57/PA58 are unassigned in SPEC §7; docs/firmware.md, "RS-485
//! driver enable", lists the transceivers each setting suits).
//!
//! A transceiver needs its driver-enable time before the line carries our
//! level: a start bit sent earlier is lost or shortened. A lead in bit
//! times scales with the baud, so one setting holds at every PA52; the
//! tail keeps the last stop bit driven until the receivers have sampled
//! it. Both stay below t3.5, the silence after which a master may send.

use super::LineConfig;

/// Largest lead or tail, bit times: one character. Below the shortest t3.5
/// (`capped_below_the_shortest_t35` checks it), so a held driver never
/// meets a master that keeps to t3.5; and the firmware holds the tail in
/// its USART interrupt (a wake-up of its dispatcher could come much later),
/// which keeps the control loop waiting up to about twice that long, inside
/// the planner's horizon at every baud.
pub const MAX_DE_BITS: u16 = 10;

/// PA57 / PA58 default: one bit time.
pub const DEFAULT_DE_BITS: u16 = 1;

/// DE lead and tail, in bit times.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DriverEnable {
    lead_bits: u16,
    tail_bits: u16,
}

impl Default for DriverEnable {
    fn default() -> Self {
        Self::new(DEFAULT_DE_BITS, DEFAULT_DE_BITS)
    }
}

impl DriverEnable {
    /// Lead and tail in bit times, each capped at [`MAX_DE_BITS`].
    pub const fn new(lead_bits: u16, tail_bits: u16) -> Self {
        Self {
            lead_bits: cap(lead_bits),
            tail_bits: cap(tail_bits),
        }
    }

    pub const fn lead_bits(self) -> u16 {
        self.lead_bits
    }

    pub const fn tail_bits(self) -> u16 {
        self.tail_bits
    }

    /// The lead at `line`'s baud, µs, rounded up (a minimum stays one).
    pub const fn lead_us(self, line: LineConfig) -> u32 {
        bits_to_us(self.lead_bits, line.baud())
    }

    /// The tail at `line`'s baud, µs, rounded up.
    pub const fn tail_us(self, line: LineConfig) -> u32 {
        bits_to_us(self.tail_bits, line.baud())
    }
}

const fn cap(bits: u16) -> u16 {
    if bits > MAX_DE_BITS {
        MAX_DE_BITS
    } else {
        bits
    }
}

/// `bits` ≤ [`MAX_DE_BITS`], so the product stays far inside a `u32`.
const fn bits_to_us(bits: u16, baud: u32) -> u32 {
    let baud = if baud == 0 { 1 } else { baud };
    (bits as u32 * 1_000_000).div_ceil(baud)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rtu::CharFormat;

    fn line(baud: u32) -> LineConfig {
        LineConfig::new(baud, CharFormat::N1)
    }

    #[test]
    fn one_bit_by_default_rounded_up_to_whole_us() {
        let de = DriverEnable::default();
        assert_eq!((de.lead_bits(), de.tail_bits()), (1, 1));
        assert_eq!(de.lead_us(line(115_200)), 9); // 8.68 µs
        assert_eq!(de.lead_us(line(9_600)), 105); // 104.2 µs
        assert_eq!(DriverEnable::new(0, 3).tail_us(line(19_200)), 157); // 156.25
        assert_eq!(DriverEnable::new(0, 3).lead_us(line(19_200)), 0);
    }

    #[test]
    fn capped_below_the_shortest_t35() {
        let de = DriverEnable::new(u16::MAX, 21);
        assert_eq!((de.lead_bits(), de.tail_bits()), (MAX_DE_BITS, MAX_DE_BITS));
        // every line PA52 / PA53 can select: the longest tail ends before t3.5
        for pa52 in 0..=4 {
            for pa53 in 0..=3 {
                let l = LineConfig::from_params(pa52, pa53).unwrap();
                assert!(de.tail_us(l) < l.timing().t35_us(), "{l:?}");
            }
        }
    }
}
