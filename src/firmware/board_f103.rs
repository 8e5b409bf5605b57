//! STM32F103C8 (Cortex-M3, 72 MHz, "blue pill" with an 8 MHz crystal): pin
//! map and peripheral choices.
//!
//! | signal | pin | peripheral |
//! |---|---|---|
//! | RS-485 RO → RX | PA10 | USART1_RX (no remap) |
//! | RS-485 DI ← TX | PA9 | USART1_TX (no remap) |
//! | RS-485 DE + /RE | PA8 | GPIO: high the lead PA57 before the first byte, low the tail PA58 after TC |
//! | STEP | PA7 | TIM1_CH1N (partial remap), PWM mode 1, loaded by DMA (steps.rs) |
//! | DIR | PB0 | TIM1_CH2N (partial remap), PWM mode 1 (0 % / 100 %), in the same DMA burst |
//! | ENABLE | PB1 | GPIO, high = power stage enabled |
//! | BRAKE | PB10 | GPIO, high = brake released (PB2 is BOOT1 on the blue pill) |
//! | CW limit | PB12 | EXTI12 → EXTI15_10, pull-down |
//! | CCW limit | PB13 | EXTI13 → EXTI15_10, pull-down |
//! | HOME | PB14 | EXTI14 → EXTI15_10, pull-down |
//! | encoder A | PB6 | TIM4_CH1 (no remap), encoder mode (started when PA17 > 0) |
//! | encoder B | PB7 | TIM4_CH2 (no remap) |
//!
//! Switch inputs follow the core's `drive::io` convention (a normally open
//! switch is active when its pin is high): the contact (or an opto-coupler
//! output) switches the pin to 3V3, the internal pull-down holds it low
//! otherwise. ENABLE / BRAKE go through `drive::io::PowerOutputs`.
//!
//! The step engine's other parts: TIM3 counts TIM1's pulses (ITR0), DMA1
//! channel 5 (TIM1_UP) feeds TIM1. TIM1's partial remap leaves CH1..CH3 on
//! PA8..PA10 unused (PA8 stays DE, PA9 / PA10 the USART) and puts BKIN on
//! PA6, which nothing drives.
//!
//! This USART has no receiver timeout and no driver-enable output: t3.5 is
//! timed by SysTick, and DE is a GPIO raised and dropped by `rs485.rs`
//! (the dispatcher and SysTick).

use embassy_stm32::exti::{ExtiInput, TriggerEdge};
use embassy_stm32::flash::{Blocking as FlashBlocking, Flash};
use embassy_stm32::gpio::{AfioRemap, Level, Output, OutputType, Pull, Speed};
use embassy_stm32::mode::Blocking;
use embassy_stm32::peripherals::{PB6, PB7, TIM1, TIM3, TIM4};
use embassy_stm32::time::Hertz;
use embassy_stm32::timer::complementary_pwm::ComplementaryPwmPin;
use embassy_stm32::timer::low_level::Timer;
use embassy_stm32::timer::{Ch1, Ch2};
use embassy_stm32::usart::{self, Uart};
use embassy_stm32::{bind_interrupts, interrupt, pac, Config, Peri, Peripherals};

use modbus_drive::boards::Board;

use super::flash::FlashRegion;
use super::switches::SwitchInputs;

/// Core clock set by [`config`] (8 MHz HSE × 9): busy waits count its cycles.
pub const SYSCLK_HZ: u32 = 72_000_000;

/// This board (its step tick and limits: `PlannerConfig::for_board`).
pub const BOARD: Board = Board::F103;
pub const NAME: &str = Board::F103.chip();

/// Step timer tick (`modbus_drive::boards`, shared with the virtual drive).
pub const STEP_TICK_HZ: u32 = Board::F103.step_tick_hz();

/// The parameter pages: the last four 1 KiB pages (offsets from
/// 0x0800_0000), which `memory-f103.x` leaves out of FLASH.
pub const PARAM_FLASH_START: u32 = 0xF000;
pub const PARAM_FLASH_LEN: u32 = 0x1000;

pub const UART: pac::usart::Usart = pac::USART1;
/// DE (PA8): configured as a push-pull output by [`split`] and driven
/// through its set/reset register by rs485.rs.
pub const DE_PORT: pac::gpio::Gpio = pac::GPIOA;
pub const DE_PIN: usize = 8;
pub const STEP_TIMER: pac::timer::TimAdv = pac::TIM1;
pub const PULSE_COUNTER: pac::timer::TimGp16 = pac::TIM3;
pub const STEP_DMA: pac::bdma::Dma = pac::DMA1;
/// DMA1 channel 5 (0-based index), TIM1_UP's (RM0008 table 78).
pub const STEP_DMA_CH: usize = 4;
pub type UartIrq = interrupt::typelevel::USART1;
pub type StepIrq = interrupt::typelevel::DMA1_CHANNEL5;
pub type SwitchIrq = interrupt::typelevel::EXTI15_10;

bind_interrupts!(pub struct Irqs {
    USART1 => super::rs485::UartHandler;
    DMA1_CHANNEL5 => super::steps::StepHandler;
    EXTI15_10 => super::switches::SwitchHandler;
});

/// HSE 8 MHz → PLL × 9 = 72 MHz, APB1 36 MHz; copied from embassy's
/// examples/stm32f1/src/bin/usb_serial.rs at embassy-stm32-v0.6.0.
pub fn config() -> Config {
    use embassy_stm32::rcc::*;
    let mut config = embassy_stm32::Config::default();
    config.rcc.hse = Some(Hse {
        freq: Hertz(8_000_000),
        mode: HseMode::Oscillator,
    });
    config.rcc.pll = Some(Pll {
        src: PllSource::HSE,
        prediv: PllPreDiv::DIV1,
        mul: PllMul::MUL9,
    });
    config.rcc.sys = Sysclk::PLL1_P;
    config.rcc.ahb_pre = AHBPrescaler::DIV1;
    config.rcc.apb1_pre = APBPrescaler::DIV2;
    config.rcc.apb2_pre = APBPrescaler::DIV1;
    config
}

/// What `embassy_stm32::init` leaves out (it turns the prefetch buffer on
/// itself): the watchdog and the step timer stopped while a debug probe
/// halts the core, so a breakpoint neither resets the chip nor leaves STEP
/// pulsing at the last rate.
pub fn after_init() {
    pac::DBGMCU.cr().modify(|w| {
        w.set_iwdg(true);
        w.set_tim1(true);
        w.set_tim3(true);
    });
}

/// The step engine's DMA channel clocked (the timers are, by their
/// drivers in [`split`]).
pub fn enable_step_clocks() {
    pac::RCC.ahbenr().modify(|w| w.set_dma1en(true));
}

/// TIM1_UP has its fixed DMA channel on the F1: nothing to route.
pub fn route_step_dma() {}

/// The fault path's pins (fault.rs, which stops the step timer first), by
/// direct register writes only: STEP (PA7) a push-pull GPIO output driven
/// low, DE (PA8) low = bus released, BRAKE (PB10) low = brake applied, and
/// unless `keep_enable` ENABLE (PB1) low = power stage off. The pins are
/// outputs from `__pre_init` on (above), so these writes act from the
/// first instruction of `main`.
pub fn safe_outputs(keep_enable: bool) {
    use pac::gpio::vals::{CnfOut, Mode};
    pac::GPIOA.bsrr().write(|w| {
        w.set_br(7, true);
        w.set_br(8, true);
    });
    pac::GPIOA.cr(0).modify(|w| {
        w.set_mode(7, Mode::OUTPUT2MHZ);
        w.set_cnf_out(7, CnfOut::PUSH_PULL);
    });
    pac::GPIOB.bsrr().write(|w| {
        w.set_br(1, !keep_enable);
        w.set_br(10, true);
    });
}

// The safe levels from the first instructions after reset (cortex-m-rt's
// `__pre_init`, called by its reset handler before RAM is initialised and
// before `main`, the clocks and the executor): GPIOA / GPIOB clocked, then
// STEP (PA7), DE (PA8), DIR (PB0), ENABLE (PB1) and BRAKE (PB10) push-pull
// outputs (2 MHz, CNF 00, MODE 10) driven low (output data first, so no
// pin ever drives high). Assembly: nothing before RAM initialisation may
// touch memory, and Rust code cannot promise that (cortex-m-rt's
// `pre_init` docs). `split` later takes the pins over at the same levels;
// the window before this runs is docs/firmware.md's "From reset".
core::arch::global_asm!(
    ".section .text.__pre_init, \"ax\"",
    ".global __pre_init",
    ".type __pre_init, %function",
    ".thumb_func",
    "__pre_init:",
    // RCC_APB2ENR |= IOPAEN | IOPBEN, read back: clocked before the writes
    "ldr r0, =0x40021018",
    "ldr r1, [r0]",
    "orr r1, r1, #0xC",
    "str r1, [r0]",
    "ldr r1, [r0]",
    // GPIOA: BSRR resets PA7 and PA8; CRL nibble 7 and CRH nibble 0 = 0b0010
    "ldr r0, =0x40010800",
    "ldr r1, =0x01800000",
    "str r1, [r0, #0x10]",
    "ldr r1, [r0]",
    "bic r1, r1, #0xF0000000",
    "orr r1, r1, #0x20000000",
    "str r1, [r0]",
    "ldr r1, [r0, #4]",
    "bic r1, r1, #0xF",
    "orr r1, r1, #0x2",
    "str r1, [r0, #4]",
    // GPIOB: BSRR resets PB0, PB1, PB10; CRL nibbles 0, 1 and CRH nibble 2
    "ldr r0, =0x40010C00",
    "ldr r1, =0x04030000",
    "str r1, [r0, #0x10]",
    "ldr r1, [r0]",
    "bic r1, r1, #0xFF",
    "orr r1, r1, #0x22",
    "str r1, [r0]",
    "ldr r1, [r0, #4]",
    "bic r1, r1, #0xF00",
    "orr r1, r1, #0x200",
    "str r1, [r0, #4]",
    "bx lr",
    ".ltorg",
);

/// Everything the firmware drives, configured.
/// The encoder's timer and pins, untouched until the encoder is wanted
/// (`firmware::encoder`).
pub struct EncoderPins {
    pub timer: Peri<'static, TIM4>,
    pub a: Peri<'static, PB6>,
    pub b: Peri<'static, PB7>,
}

pub struct Parts {
    pub uart: Uart<'static, Blocking>,
    pub de: Output<'static>,
    pub step_timer: Timer<'static, TIM1>,
    pub pulse_counter: Timer<'static, TIM3>,
    pub step_pin: ComplementaryPwmPin<'static, TIM1, Ch1, AfioRemap<1>>,
    pub dir: ComplementaryPwmPin<'static, TIM1, Ch2, AfioRemap<1>>,
    pub enable: Output<'static>,
    pub brake: Output<'static>,
    pub switches: SwitchInputs,
    pub encoder: EncoderPins,
    pub param_flash: Option<FlashRegion<Flash<'static, FlashBlocking>>>,
}

pub fn split(p: Peripherals, line: &usart::Config) -> Result<Parts, usart::ConfigError> {
    let uart = Uart::new_blocking(p.USART1, p.PA10, p.PA9, *line)?;
    let step_timer = Timer::new(p.TIM1);
    // STEP and DIR driven low by the timer before their pins become its
    // outputs
    super::steps::outputs_low();
    Ok(Parts {
        uart,
        de: Output::new(p.PA8, Level::Low, Speed::VeryHigh),
        step_timer,
        pulse_counter: Timer::new(p.TIM3),
        step_pin: ComplementaryPwmPin::new(p.PA7, OutputType::PushPull),
        dir: ComplementaryPwmPin::new(p.PB0, OutputType::PushPull),
        // outputs start in the safe state: disabled, brake applied (SPEC §8.1)
        enable: Output::new(p.PB1, Level::Low, Speed::Low),
        brake: Output::new(p.PB10, Level::Low, Speed::Low),
        encoder: EncoderPins {
            timer: p.TIM4,
            a: p.PB6,
            b: p.PB7,
        },
        switches: SwitchInputs::new(
            ExtiInput::new_blocking(p.PB12, p.EXTI12, Pull::Down, TriggerEdge::Any),
            ExtiInput::new_blocking(p.PB13, p.EXTI13, Pull::Down, TriggerEdge::Any),
            ExtiInput::new_blocking(p.PB14, p.EXTI14, Pull::Down, TriggerEdge::Any),
        ),
        param_flash: FlashRegion::new(
            Flash::new_blocking(p.FLASH),
            PARAM_FLASH_START,
            PARAM_FLASH_LEN,
        ),
    })
}
