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
    /// STEP: PA7 (TIM1_CH1N, the images' timer + DMA step engine,
    /// docs/firmware.md); PA6 (TIM3_CH1) where the runner's own tests drive
    /// a general-purpose timer. The STEP pin is the first of these a timer
    /// output drives; `--trace-pins` traces the first.
    pub const STEP: [Pin; 2] = [(0, 7), (0, 6)];
    pub const DIR: Pin = (1, 0);
    pub const CW_LIMIT: Pin = (1, 12);
    pub const CCW_LIMIT: Pin = (1, 13);
    pub const HOME: Pin = (1, 14);
    /// The encoder's A and B: TIM4_CH1 on PB6, TIM4_CH2 on PB7.
    pub const ENCODER: (Pin, Pin) = ((1, 6), (1, 7));
    /// G431: USART1_DE (AF7); F103: a GPIO.
    pub const DE_G431: Pin = (0, 12);
    pub const DE_F103: Pin = (0, 8);
    /// ENABLE (both boards), BRAKE (G431 PB2, F103 PB10).
    pub const ENABLE: Pin = (1, 1);
    pub const BRAKE_G431: Pin = (1, 2);
    pub const BRAKE_F103: Pin = (1, 10);
}

/// The timers' places in the machine's list.
pub mod tim {
    pub const TIM2: usize = 0;
    pub const TIM3: usize = 1;
    pub const TIM4: usize = 2;
    pub const TIM1: usize = 3;
    /// G4 only (the F103C8 has no TIM8).
    pub const TIM8: usize = 4;
}

pub const TIM1: u32 = 0x4001_2C00;
pub const TIM8: u32 = 0x4001_3400;
pub const DMA1: u32 = 0x4002_0000;
/// G4 only.
pub const DMA2: u32 = 0x4002_0400;
pub const DMAMUX1: u32 = 0x4002_0800;

/// Which timer's TRGO reaches internal trigger `itr` of timer `slave`:
/// RM0008 table 86 "TIMx internal trigger connection" (TIM2..TIM5) and the
/// TIM1 / TIM8 table of §14.4.3 (SMCR); RM0440's tim_itr tables of
/// §29.3 / §30.4 ("Interconnect to the tim_itr input multiplexer"), where
/// ITR0..8 are TIM1, TIM2, TIM3, TIM4, TIM5, TIM8, TIM15, TIM16, TIM17
/// for every timer. `None`: a timer the chip or the model does not have.
pub fn itr_source(kind: Kind, slave: usize, itr: u32) -> Option<usize> {
    use tim::*;
    match kind {
        Kind::F103 => match (slave, itr) {
            (TIM1, 1) | (TIM3, 1) | (TIM4, 1) => Some(TIM2),
            (TIM1, 2) | (TIM2, 2) | (TIM4, 2) => Some(TIM3),
            (TIM1, 3) | (TIM2, 3) | (TIM3, 3) => Some(TIM4),
            (TIM2, 0) | (TIM3, 0) | (TIM4, 0) => Some(TIM1),
            // TIM5 / TIM8 are not on the STM32F103C8
            _ => None,
        },
        Kind::G431 => {
            let src = match itr {
                0 => TIM1,
                1 => TIM2,
                2 => TIM3,
                3 => TIM4,
                5 => TIM8,
                _ => return None,
            };
            (src != slave).then_some(src)
        }
    }
}

/// F1: the DMA1 channel (1..7) a timer request reaches, RM0008 table 78
/// "Summary of each channel request"; `req` is the bit of `Fired::dma`
/// (0 update, 1..4 CC1..CC4, 5 trigger, 6 COM).
pub fn f1_dma_channel(timer: usize, req: u32) -> Option<usize> {
    use tim::*;
    Some(match (timer, req) {
        (TIM1, 1) => 2,
        (TIM1, 2) => 3,
        (TIM1, 4) | (TIM1, 5) | (TIM1, 6) => 4,
        (TIM1, 0) => 5,
        (TIM1, 3) => 6,
        (TIM2, 3) => 1,
        (TIM2, 0) => 2,
        (TIM2, 1) => 5,
        (TIM2, 2) | (TIM2, 4) => 7,
        (TIM3, 3) => 2,
        (TIM3, 4) | (TIM3, 0) => 3,
        (TIM3, 1) | (TIM3, 5) => 6,
        (TIM4, 1) => 1,
        (TIM4, 2) => 4,
        (TIM4, 3) => 5,
        (TIM4, 0) => 7,
        _ => return None,
    })
}

/// G4: the DMAMUX request ID of a timer request, RM0440 table 91 "DMAMUX:
/// assignment of multiplexer inputs to resources"; `req` as above.
pub fn g4_request_id(timer: usize, req: u32) -> Option<u32> {
    use tim::*;
    // (CH1, UP, TRIG, COM) of each timer; CH2..CH4 follow CH1
    let (ch1, up, trig, com) = match timer {
        TIM1 => (42, 46, Some(47), Some(48)),
        TIM8 => (49, 53, Some(54), Some(55)),
        TIM2 => (56, 60, None, None),
        TIM3 => (61, 65, Some(66), None),
        TIM4 => (67, 71, None, None),
        _ => return None,
    };
    match req {
        0 => Some(up),
        1..=4 => Some(ch1 + req - 1),
        5 => trig,
        6 => com,
        _ => None,
    }
}

/// A timer output: (timer, channel 0..3, the complementary OCxN).
pub type TimerOut = (usize, usize, bool);

/// The timer outputs that may drive a pin in its alternate function (on
/// the F1 two peripherals can share a pin; the machine takes the enabled
/// one): the G4's AF numbers from DS12589's alternate function table, the
/// F1's timer pins of RM0008 §9.3.7 ("Timer alternate function
/// remapping") without remap, except TIM1's partial remap
/// (`f1_tim1_remap` = AFIO_MAPR.TIM1_REMAP = 01: CH1N..CH3N on PA7, PB0,
/// PB1 and BKIN on PA6, where no remap has them on PB13..PB15 and PB12);
/// cross-checked with the STM32 data of embassy's stm32-metapac. `af` is
/// the G4's AFRx value (ignored on the F1).
pub fn timer_outputs_at(
    kind: Kind,
    pin: pins::Pin,
    af: u32,
    f1_tim1_remap: u32,
) -> [Option<TimerOut>; 2] {
    use tim::*;
    let (port, n) = pin;
    let nu = n as usize;
    match kind {
        Kind::F103 => {
            let partial = f1_tim1_remap == 1;
            let general = match (port, n) {
                (0, 0..=3) => Some((TIM2, nu, false)),
                (0, 6) => Some((TIM3, 0, false)),
                (0, 7) => Some((TIM3, 1, false)),
                (1, 0) => Some((TIM3, 2, false)),
                (1, 1) => Some((TIM3, 3, false)),
                (1, 6..=9) => Some((TIM4, nu - 6, false)),
                _ => None,
            };
            let tim1 = match (port, n) {
                (0, 8..=11) => Some((TIM1, nu - 8, false)),
                (0, 7) if partial => Some((TIM1, 0, true)),
                (1, 0) if partial => Some((TIM1, 1, true)),
                (1, 1) if partial => Some((TIM1, 2, true)),
                (1, 13..=15) if !partial => Some((TIM1, nu - 13, true)),
                _ => None,
            };
            [general, tim1]
        }
        Kind::G431 => [
            match (port, n, af) {
                (0, 0..=3, 1) => Some((TIM2, nu, false)),
                (0, 5, 1) | (0, 15, 1) => Some((TIM2, 0, false)),
                (1, 3, 1) => Some((TIM2, 1, false)),
                (1, 10, 1) | (0, 9, 10) => Some((TIM2, 2, false)),
                (1, 11, 1) | (0, 10, 10) => Some((TIM2, 3, false)),
                (0, 6, 2) | (1, 4, 2) => Some((TIM3, 0, false)),
                (0, 4, 2) | (0, 7, 2) | (1, 5, 2) => Some((TIM3, 1, false)),
                (1, 0, 2) => Some((TIM3, 2, false)),
                (1, 1, 2) | (1, 7, 10) => Some((TIM3, 3, false)),
                (1, 6..=9, 2) => Some((TIM4, nu - 6, false)),
                (0, 11, 10) => Some((TIM4, 0, false)),
                (0, 12, 10) => Some((TIM4, 1, false)),
                (0, 13, 10) => Some((TIM4, 2, false)),
                (0, 8..=10, 6) => Some((TIM1, nu - 8, false)),
                (0, 11, 11) => Some((TIM1, 3, false)),
                (0, 7, 6) | (0, 11, 6) | (1, 13, 6) => Some((TIM1, 0, true)),
                (1, 0, 6) | (0, 12, 6) | (1, 14, 6) => Some((TIM1, 1, true)),
                (1, 1, 6) | (1, 15, 4) | (1, 9, 12) => Some((TIM1, 2, true)),
                (0, 15, 2) | (1, 6, 5) => Some((TIM8, 0, false)),
                (0, 14, 5) | (1, 8, 10) => Some((TIM8, 1, false)),
                (1, 9, 10) => Some((TIM8, 2, false)),
                (0, 7, 4) | (1, 3, 4) => Some((TIM8, 0, true)),
                (1, 0, 4) | (1, 4, 4) => Some((TIM8, 1, true)),
                (1, 1, 4) | (1, 5, 3) => Some((TIM8, 2, true)),
                _ => None,
            },
            None,
        ],
    }
}

/// G4 break inputs: (timer, port, pin, AF) of each TIMx_BKIN pin
/// (DS12589's alternate function table).
pub const G4_BKIN: &[(usize, usize, u8, u32)] = &[
    (tim::TIM1, 0, 6, 6),
    (tim::TIM1, 0, 14, 6),
    (tim::TIM1, 0, 15, 9),
    (tim::TIM1, 1, 8, 12),
    (tim::TIM1, 1, 10, 12),
    (tim::TIM1, 1, 12, 6),
    (tim::TIM8, 0, 0, 9),
    (tim::TIM8, 0, 6, 4),
    (tim::TIM8, 0, 10, 11),
    (tim::TIM8, 1, 7, 5),
];
