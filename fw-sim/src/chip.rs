//! The two chips and boards: memories (datasheets), peripheral base
//! addresses (RM0440 §2.2.2 memory map / RM0008 §3.3), interrupt numbers and
//! the board's pin assignment (src/firmware/board_*.rs).

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// STM32G431CB: Cortex-M4F, RM0440.
    G431,
    /// STM32F103C8: Cortex-M3, RM0008.
    F103,
}

#[derive(Clone, Copy, Debug)]
pub struct Chip {
    pub kind: Kind,
    pub name: &'static str,
    pub flash_base: u32,
    pub flash_len: u32,
    /// Erase page of the main flash (G4 2 KiB, F1 medium density 1 KiB).
    pub page: u32,
    pub sram_base: u32,
    pub sram_len: u32,
    /// Clock at reset (HSI16 / HSI 8 MHz) and the board's crystal.
    pub reset_sysclk: u32,
    pub hse_hz: u32,
    /// LSI (IWDG clock), datasheet typical.
    pub lsi_hz: u32,
    pub cpuid: u32,
    pub dbgmcu_idcode: u32,
    pub has_fpu: bool,
    pub gpioa: u32,
    pub gpiob: u32,
    /// Flash programming / page erase times, datasheet typical (ps).
    pub t_prog_ps: u64,
    pub t_erase_ps: u64,
}

pub const TIM2: u32 = 0x4000_0000;
pub const TIM3: u32 = 0x4000_0400;
pub const TIM4: u32 = 0x4000_0800;
pub const IWDG: u32 = 0x4000_3000;
pub const PWR: u32 = 0x4000_7000;
/// SYSCFG (G4) / AFIO (F1).
pub const SYSCFG_AFIO: u32 = 0x4001_0000;
pub const EXTI: u32 = 0x4001_0400;
pub const USART1: u32 = 0x4001_3800;
pub const RCC: u32 = 0x4002_1000;
pub const FLASH_IF: u32 = 0x4002_2000;
pub const DBGMCU: u32 = 0xE004_2000;

/// Interrupt numbers: the same on both parts for what the firmware uses.
pub const IRQ_FLASH: usize = 4;
pub const IRQ_TIM2: usize = 28;
pub const IRQ_TIM3: usize = 29;
pub const IRQ_TIM4: usize = 30;
pub const IRQ_USART1: usize = 37;
pub const IRQ_EXTI15_10: usize = 40;
pub const IRQ_EXTI0: usize = 6;
pub const IRQ_EXTI9_5: usize = 23;
/// Number of external interrupts: G4 102, F103 60 (rounded to what NVIC holds).
pub const N_IRQ: usize = 112;

impl Chip {
    pub fn new(kind: Kind) -> Self {
        match kind {
            Kind::G431 => Self {
                kind,
                name: "STM32G431CB",
                flash_base: 0x0800_0000,
                flash_len: 128 * 1024,
                page: 2048,
                sram_base: 0x2000_0000,
                // SRAM1 16 KiB + SRAM2 6 KiB + CCM SRAM 10 KiB aliased
                // contiguously (RM0440 §2.4)
                sram_len: 32 * 1024,
                reset_sysclk: 16_000_000,
                hse_hz: 8_000_000,
                lsi_hz: 32_000,
                // Cortex-M4 r0p1
                cpuid: 0x410F_C241,
                // DEV_ID 0x468 (category 2), REV_ID 0x2000
                dbgmcu_idcode: 0x2000_6468,
                has_fpu: true,
                gpioa: 0x4800_0000,
                gpiob: 0x4800_0400,
                // DS12589: t_prog 81.7 µs (double word), t_ERASE 22.02 ms
                t_prog_ps: 81_700_000,
                t_erase_ps: 22_020_000_000,
            },
            Kind::F103 => Self {
                kind,
                name: "STM32F103C8",
                flash_base: 0x0800_0000,
                flash_len: 64 * 1024,
                page: 1024,
                sram_base: 0x2000_0000,
                sram_len: 20 * 1024,
                reset_sysclk: 8_000_000,
                hse_hz: 8_000_000,
                lsi_hz: 40_000,
                // Cortex-M3 r1p1
                cpuid: 0x411F_C231,
                // DEV_ID 0x410 (medium density), REV_ID 0x2003
                dbgmcu_idcode: 0x2003_6410,
                has_fpu: false,
                gpioa: 0x4001_0800,
                gpiob: 0x4001_0C00,
                // DS5319: t_prog 52.5 µs (half word), t_ERASE 20 ms (min 20, max 40)
                t_prog_ps: 52_500_000,
                t_erase_ps: 20_000_000_000,
            },
        }
    }
    pub fn is_g4(&self) -> bool {
        self.kind == Kind::G431
    }
    pub fn flash_end(&self) -> u32 {
        self.flash_base + self.flash_len
    }
}

/// Board pins the runner watches or drives (src/firmware/board_*.rs).
pub mod pins {
    /// (port 0 = A, 1 = B, pin)
    pub type Pin = (usize, u8);
    pub const STEP: Pin = (0, 6);
    pub const DIR: Pin = (1, 0);
    pub const CW_LIMIT: Pin = (1, 12);
    pub const CCW_LIMIT: Pin = (1, 13);
    pub const HOME: Pin = (1, 14);
    /// The encoder's A and B: TIM4_CH1 on PB6, TIM4_CH2 on PB7.
    pub const ENCODER: (Pin, Pin) = ((1, 6), (1, 7));
    /// G431: USART1_DE (AF7); F103: a GPIO.
    pub const DE_G431: Pin = (0, 12);
    pub const DE_F103: Pin = (0, 8);
}
