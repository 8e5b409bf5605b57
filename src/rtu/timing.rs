//! Character time, t1.5 and t3.5 from the line settings (SPEC §1).

/// Character format (PA53): 8 data bits with parity / stop bits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CharFormat {
    /// 8 data bits, no parity, 1 stop bit (PA53 = 0, default).
    N1,
    /// Even parity, 1 stop bit (PA53 = 1).
    E1,
    /// Odd parity, 1 stop bit (PA53 = 2).
    O1,
    /// No parity, 2 stop bits (PA53 = 3).
    N2,
}

impl CharFormat {
    /// From PA53; `None` outside 0..=3.
    pub fn from_pa53(v: u16) -> Option<Self> {
        match v {
            0 => Some(Self::N1),
            1 => Some(Self::E1),
            2 => Some(Self::O1),
            3 => Some(Self::N2),
            _ => None,
        }
    }

    /// Bits on the wire per character: start + 8 data + parity/stop.
    pub fn bits_per_char(self) -> u32 {
        match self {
            Self::N1 => 10,
            Self::E1 | Self::O1 | Self::N2 => 11,
        }
    }
}

/// Baud rate and character format of the serial line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LineConfig {
    baud: u32,
    format: CharFormat,
}

impl LineConfig {
    #[inline]
    pub const fn new(baud: u32, format: CharFormat) -> Self {
        Self { baud, format }
    }

    #[inline]
    pub const fn baud(&self) -> u32 {
        self.baud
    }

    #[inline]
    pub const fn format(&self) -> CharFormat {
        self.format
    }
}

impl LineConfig {
    /// The SPEC §1 default: 115200 8N1.
    pub const DEFAULT: Self = Self {
        baud: 115_200,
        format: CharFormat::N1,
    };

    /// Baud rate from PA52; `None` outside 0..=4.
    pub fn baud_from_pa52(v: u16) -> Option<u32> {
        match v {
            0 => Some(9_600),
            1 => Some(19_200),
            2 => Some(38_400),
            3 => Some(57_600),
            4 => Some(115_200),
            _ => None,
        }
    }

    /// From PA52 and PA53; `None` if either is out of range.
    pub fn from_params(pa52: u16, pa53: u16) -> Option<Self> {
        Some(Self {
            baud: Self::baud_from_pa52(pa52)?,
            format: CharFormat::from_pa53(pa53)?,
        })
    }

    pub fn timing(self) -> FrameTiming {
        FrameTiming::new(self)
    }
}

impl Default for LineConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Inter-character limits in microseconds.
///
/// `tc_us` is one character time (rounded up). Up to and including 19200
/// baud `t15_us` / `t35_us` are 1.5 / 3.5 character times (rounded up);
/// above it they are fixed at 750 µs / 1750 µs (Modbus over Serial Line
/// V1.02 §2.5.1.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FrameTiming {
    tc_us: u32,
    t15_us: u32,
    t35_us: u32,
}

impl FrameTiming {
    #[inline]
    pub const fn tc_us(&self) -> u32 {
        self.tc_us
    }

    #[inline]
    pub const fn t15_us(&self) -> u32 {
        self.t15_us
    }

    #[inline]
    pub const fn t35_us(&self) -> u32 {
        self.t35_us
    }
}

impl FrameTiming {
    pub const fn new(line: LineConfig) -> Self {
        let bits = match line.format {
            CharFormat::N1 => 10u64,
            _ => 11u64,
        };
        let baud = if line.baud == 0 { 1 } else { line.baud as u64 };
        let tc_us = div_ceil(bits * 1_000_000, baud) as u32;
        if line.baud > 19_200 {
            Self {
                tc_us,
                t15_us: 750,
                t35_us: 1750,
            }
        } else {
            Self {
                tc_us,
                t15_us: div_ceil(15 * bits * 1_000_000, 10 * baud) as u32,
                t35_us: div_ceil(35 * bits * 1_000_000, 10 * baud) as u32,
            }
        }
    }
}

/// Rounded-up division in 32 bits: every operand above fits (at most
/// 35 × 11 × 10⁶ over a 32-bit baud rate, or 10 × 19200 in the branch
/// that multiplies it), and a 64-bit division is a software routine on
/// the firmware's core.
const fn div_ceil(a: u64, b: u64) -> u64 {
    (a as u32).div_ceil(b as u32) as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn at_9600_8n1_the_gaps_scale_with_the_character_time() {
        let t = LineConfig {
            baud: 9600,
            format: CharFormat::N1,
        }
        .timing();
        assert_eq!(t.tc_us, 1042); // 10 bits / 9600 = 1041.67 µs
        assert_eq!(t.t15_us, 1563); // 1562.5 µs
        assert_eq!(t.t35_us, 3646); // 3645.8 µs
    }

    #[test]
    fn at_19200_with_parity_eleven_bits_count() {
        let t = LineConfig {
            baud: 19200,
            format: CharFormat::E1,
        }
        .timing();
        assert_eq!(t.tc_us, 573); // 11 / 19200 = 572.9 µs
        assert_eq!(t.t15_us, 860); // 859.4 µs
        assert_eq!(t.t35_us, 2006); // 2005.2 µs
    }

    #[test]
    fn above_19200_the_gaps_are_fixed() {
        for baud in [38_400, 57_600, 115_200] {
            let t = LineConfig {
                baud,
                format: CharFormat::N1,
            }
            .timing();
            assert_eq!((t.t15_us, t.t35_us), (750, 1750));
        }
        assert_eq!(LineConfig::DEFAULT.timing().tc_us, 87); // 86.8 µs
    }

    #[test]
    fn parameters_map_to_lines() {
        assert_eq!(
            LineConfig::from_params(0, 1),
            Some(LineConfig {
                baud: 9600,
                format: CharFormat::E1
            })
        );
        assert_eq!(LineConfig::from_params(4, 0), Some(LineConfig::DEFAULT));
        assert_eq!(LineConfig::from_params(5, 0), None);
        assert_eq!(LineConfig::from_params(0, 4), None);
    }
}
