//! Reset and clock control: RM0440 §7.4 (G4) and RM0008 §7.3 (F1).
//! Oscillator and PLL ready bits follow their ON bits at once (no start-up
//! delay), SWS follows SW, the enable/reset registers are plain storage.
//! Clock frequencies are derived from the registers: SYSCLK, HCLK, PCLK1/2,
//! the APB timer clocks (×2 when the APB prescaler is not 1: RM0440 §7.2.15,
//! RM0008 §7.2) and the USART1 kernel clock.

use super::Access;

#[derive(Debug)]
pub struct Rcc {
    g4: bool,
    hse_hz: u32,
    regs: Vec<(u32, u32, u32)>,
}

/// Clocks derived from the registers.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Clocks {
    pub sysclk: u32,
    pub hclk: u32,
    pub pclk1: u32,
    pub pclk2: u32,
    pub tim_apb1: u32,
    /// TIM1 / TIM8's kernel clock: the APB2 timer clock (same ×2 rule).
    pub tim_apb2: u32,
    pub usart1: u32,
}

impl Rcc {
    pub fn new(g4: bool, hse_hz: u32) -> Self {
        // (offset, reset value, writable mask)
        let regs = if g4 {
            vec![
                (0x00, 0x0000_0500, 0x010D_0300), // CR
                (0x04, 0x4000_0000, 0x7F00_0000), // ICSCR
                (0x08, 0x0000_0005, 0x7F00_3FF3), // CFGR
                (0x0C, 0x0000_1000, 0xFF7F_7FF3), // PLLCFGR
                (0x18, 0, 0x63F),                 // CIER
                (0x1C, 0, 0),                     // CIFR
                (0x20, 0, 0x7BF),                 // CICR
                (0x28, 0, u32::MAX),              // AHB1RSTR
                (0x2C, 0, u32::MAX),              // AHB2RSTR
                (0x30, 0, u32::MAX),              // AHB3RSTR
                (0x38, 0, u32::MAX),              // APB1RSTR1
                (0x3C, 0, u32::MAX),              // APB1RSTR2
                (0x40, 0, u32::MAX),              // APB2RSTR
                (0x48, 0x0000_0100, u32::MAX),    // AHB1ENR (FLASHEN)
                (0x4C, 0, u32::MAX),              // AHB2ENR
                (0x50, 0, u32::MAX),              // AHB3ENR
                (0x58, 0x0000_0400, u32::MAX),    // APB1ENR1 (RTCAPBEN)
                (0x5C, 0, u32::MAX),              // APB1ENR2
                (0x60, 0, u32::MAX),              // APB2ENR
                (0x68, 0x0000_130F, u32::MAX),    // AHB1SMENR
                (0x6C, 0x050F_667F, u32::MAX),    // AHB2SMENR
                (0x70, 0x0000_0101, u32::MAX),    // AHB3SMENR
                (0x78, 0xD2FE_CD3F, u32::MAX),    // APB1SMENR1
                (0x7C, 0x0000_0103, u32::MAX),    // APB1SMENR2
                (0x80, 0x0437_F801, u32::MAX),    // APB2SMENR
                (0x88, 0, u32::MAX),              // CCIPR
                (0x90, 0, 0x0301_8379),           // BDCR
                (0x94, 0x0C00_0000, 0x0080_0001), // CSR (PINRSTF, BORRSTF)
                (0x98, 0, 1),                     // CRRCR
                (0x9C, 0, u32::MAX),              // CCIPR2
            ]
        } else {
            vec![
                (0x00, 0x0000_0083, 0x010D_00F9), // CR
                (0x04, 0, 0x077F_FFF3),           // CFGR
                (0x08, 0, 0x009F_1F00),           // CIR
                (0x0C, 0, u32::MAX),              // APB2RSTR
                (0x10, 0, u32::MAX),              // APB1RSTR
                (0x14, 0x0000_0014, u32::MAX),    // AHBENR
                (0x18, 0, u32::MAX),              // APB2ENR
                (0x1C, 0, u32::MAX),              // APB1ENR
                (0x20, 0, 0x0001_8305),           // BDCR
                (0x24, 0x0C00_0000, 0x0100_0001), // CSR
            ]
        };
        Self { g4, hse_hz, regs }
    }

    fn get(&self, off: u32) -> u32 {
        self.regs.iter().find(|r| r.0 == off).map_or(0, |r| r.1)
    }

    /// Ready bits that follow their ON bits, SWS that follows SW.
    fn derived(&self, off: u32, v: u32) -> u32 {
        match off {
            0x00 => {
                let mut v = v;
                // HSIRDY (G4 bit 10 / F1 bit 1) follows HSION (8 / 0)
                let (hsion, hsirdy) = if self.g4 { (8, 10) } else { (0, 1) };
                v = (v & !(1 << hsirdy)) | (((v >> hsion) & 1) << hsirdy);
                v = (v & !(1 << 17)) | (((v >> 16) & 1) << 17); // HSERDY
                v = (v & !(1 << 25)) | (((v >> 24) & 1) << 25); // PLLRDY
                v
            }
            // LSIRDY / LSERDY / HSI48RDY (bit 1) follow LSION / LSEON /
            // HSI48ON (bit 0): G4 CSR, BDCR, CRRCR; F1 CSR, BDCR
            0x94 | 0x90 | 0x98 if self.g4 => (v & !2) | ((v & 1) << 1),
            0x24 | 0x20 if !self.g4 => (v & !2) | ((v & 1) << 1),
            0x08 if self.g4 => (v & !0xC) | ((v & 3) << 2),
            0x04 if !self.g4 => (v & !0xC) | ((v & 3) << 2),
            _ => v,
        }
    }

    pub fn read(&mut self, off: u32) -> Access {
        match self.regs.iter().find(|r| r.0 == off) {
            Some(r) => Access::Ok(self.derived(off, r.1)),
            None => Access::Unmodelled,
        }
    }

    pub fn write(&mut self, off: u32, v: u32) -> Access {
        let g4 = self.g4;
        match self.regs.iter_mut().find(|r| r.0 == off) {
            Some(r) => {
                // CSR RMVF (G4 bit 23 / F1 bit 24) clears the reset flags
                if off == if g4 { 0x94 } else { 0x24 } && v & (1 << if g4 { 23 } else { 24 }) != 0 {
                    r.1 &= 0x00FF_FFFF;
                }
                r.1 = (r.1 & !r.2) | (v & r.2);
                Access::Ok(0)
            }
            None => Access::Unmodelled,
        }
    }

    /// RCC_CSR's reset flags (bits 24..31; both chips).
    pub fn reset_flags(&self) -> u32 {
        self.get(self.csr()) & 0xFF00_0000
    }

    /// Sets RCC_CSR's reset flags after a reset (the rest of the register
    /// keeps its reset value).
    pub fn set_reset_flags(&mut self, flags: u32) {
        let off = self.csr();
        if let Some(r) = self.regs.iter_mut().find(|r| r.0 == off) {
            r.1 = (r.1 & 0x00FF_FFFF) | (flags & 0xFF00_0000);
        }
    }

    fn csr(&self) -> u32 {
        if self.g4 {
            0x94
        } else {
            0x24
        }
    }

    pub fn clocks(&self) -> Clocks {
        let cr = self.derived(0, self.get(0));
        let (cfgr, hsi) = if self.g4 {
            (self.get(0x08), 16_000_000u64)
        } else {
            (self.get(0x04), 8_000_000u64)
        };
        let pll = if self.g4 {
            let p = self.get(0x0C);
            let src = match p & 3 {
                2 => hsi,
                3 => self.hse_hz as u64,
                _ => 0,
            };
            let m = ((p >> 4) & 0xF) as u64 + 1;
            let n = ((p >> 8) & 0x7F) as u64;
            let r = [2, 4, 6, 8][((p >> 25) & 3) as usize];
            src / m * n / r
        } else {
            let src = if cfgr & (1 << 16) != 0 {
                self.hse_hz as u64 / if cfgr & (1 << 17) != 0 { 2 } else { 1 }
            } else {
                hsi / 2
            };
            let mul = (((cfgr >> 18) & 0xF) as u64 + 2).min(16);
            src * mul
        };
        // SWS follows SW at once (see `derived`)
        let sysclk = match cfgr & 3 {
            0 if !self.g4 => hsi,
            1 if self.g4 => hsi,
            1 if !self.g4 => self.hse_hz as u64,
            2 if self.g4 => self.hse_hz as u64,
            2 if !self.g4 && cr & (1 << 25) != 0 => pll,
            3 if self.g4 && cr & (1 << 25) != 0 => pll,
            _ => hsi,
        };
        let hpre = (cfgr >> 4) & 0xF;
        let hdiv = if hpre < 8 {
            1
        } else {
            [2, 4, 8, 16, 64, 128, 256, 512][(hpre - 8) as usize]
        };
        let hclk = sysclk / hdiv;
        let apb = |bits: u32| if bits < 4 { 1 } else { 1u64 << (bits - 3) };
        let d1 = apb((cfgr >> 8) & 7);
        let d2 = apb((cfgr >> 11) & 7);
        let pclk1 = hclk / d1;
        let pclk2 = hclk / d2;
        let tim_apb1 = if d1 == 1 { pclk1 } else { pclk1 * 2 };
        let tim_apb2 = if d2 == 1 { pclk2 } else { pclk2 * 2 };
        let usart1 = if self.g4 {
            match self.get(0x88) & 3 {
                0 => pclk2,
                1 => sysclk,
                2 => hsi,
                _ => 32_768,
            }
        } else {
            pclk2
        };
        Clocks {
            sysclk: sysclk as u32,
            hclk: hclk as u32,
            pclk1: pclk1 as u32,
            pclk2: pclk2 as u32,
            tim_apb1: tim_apb1 as u32,
            tim_apb2: tim_apb2 as u32,
            usart1: usart1 as u32,
        }
    }
}
