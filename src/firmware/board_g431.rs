//! STM32G431CB (Cortex-M4F, 170 MHz): pin map and peripheral choices.
//!
//! | signal | pin | peripheral |
//! |---|---|---|
//! | RS-485 RO → RX | PA10 | USART1_RX (AF7) |
//! | RS-485 DI ← TX | PA9 | USART1_TX (AF7) |
//! | RS-485 DE + /RE | PA12 | USART1_DE (AF7), driven by the USART (CR3.DEM); a GPIO during a reply whose PA57 / PA58 exceed DEAT / DEDT |
//! | STEP | PA7 | TIM1_CH1N (AF6), PWM mode 1, loaded by DMA (steps.rs) |
//! | DIR | PB0 | TIM1_CH2N (AF6), PWM mode 1 (0 % / 100 %), in the same DMA burst |
//! | ENABLE | PB1 | GPIO, high = power stage enabled |
//! | BRAKE | PB2 | GPIO, high = brake released |
//! | CW limit | PB12 | EXTI12 → EXTI15_10, pull-down |
//! | CCW limit | PB13 | EXTI13 → EXTI15_10, pull-down |
//! | HOME | PB14 | EXTI14 → EXTI15_10, pull-down |
//! | encoder A | PB6 | TIM4_CH1 (AF2), encoder mode (started when PA17 > 0) |
//! | encoder B | PB7 | TIM4_CH2 (AF2) |
//!
//! Switch inputs follow the core's `drive::io` convention (a normally open
//! switch is active when its pin is high): the contact (or an opto-coupler
//! output) switches the pin to 3V3, the internal pull-down holds it low
//! otherwise. ENABLE / BRAKE go through `drive::io::PowerOutputs`.
//!
//! The step engine's other parts: TIM3 counts TIM1's pulses (ITR0), DMA1
//! channel 1 (DMAMUX1 channel 0, request TIM1_UP) feeds TIM1.
//!
//! t3.5 comes from the USART's receiver timeout (RTOR), DE from its hardware
//! driver-enable with assertion/deassertion times PA57 / PA58 (rs485.rs).

use embassy_stm32::exti::{ExtiInput, TriggerEdge};
use embassy_stm32::flash::{Blocking as FlashBlocking, Flash};
use embassy_stm32::gpio::{Level, Output, OutputType, Pull, Speed};
use embassy_stm32::mode::Blocking;
use embassy_stm32::peripherals::{PB6, PB7, TIM1, TIM3, TIM4};
use embassy_stm32::timer::complementary_pwm::ComplementaryPwmPin;
use embassy_stm32::timer::low_level::Timer;
use embassy_stm32::timer::{Ch1, Ch2};
use embassy_stm32::usart::{self, Uart};
use embassy_stm32::{bind_interrupts, interrupt, pac, Config, Peri, Peripherals};

use modbus_drive::boards::Board;

use super::flash::FlashRegion;
use super::switches::SwitchInputs;

/// Core clock set by [`config`] (HSI16 / 4 × 85 / 2): busy waits count its cycles.
pub const SYSCLK_HZ: u32 = 170_000_000;

/// This board (its step tick and limits: `PlannerConfig::for_board`).
pub const BOARD: Board = Board::G431;
pub const NAME: &str = Board::G431.chip();

/// Step timer tick (`modbus_drive::boards`, shared with the virtual drive).
pub const STEP_TICK_HZ: u32 = Board::G431.step_tick_hz();

/// The parameter pages: the last two 2 KiB pages (offsets from 0x0800_0000),
/// which `memory-g431.x` leaves out of FLASH.
pub const PARAM_FLASH_START: u32 = 0x1_F000;
pub const PARAM_FLASH_LEN: u32 = 0x1000;

pub const UART: pac::usart::Usart = pac::USART1;
/// USART1_DE (PA12), taken over as a GPIO when PA57 / PA58 exceed what the
/// USART's DEAT / DEDT can time (rs485.rs).
pub const DE_PORT: pac::gpio::Gpio = pac::GPIOA;
pub const DE_PIN: usize = 12;
pub const STEP_TIMER: pac::timer::TimAdv = pac::TIM1;
pub const PULSE_COUNTER: pac::timer::TimGp16 = pac::TIM3;
pub const STEP_DMA: pac::bdma::Dma = pac::DMA1;
/// DMA1 channel 1 (0-based index).
pub const STEP_DMA_CH: usize = 0;
/// TIM1_UP's DMAMUX request (RM0440 table "DMAMUX: assignment of multiplexer inputs to resources").
const TIM1_UP_REQUEST: u8 = 46;
pub type UartIrq = interrupt::typelevel::USART1;
pub type StepIrq = interrupt::typelevel::DMA1_CHANNEL1;
pub type SwitchIrq = interrupt::typelevel::EXTI15_10;

bind_interrupts!(pub struct Irqs {
    USART1 => super::rs485::UartHandler;
    DMA1_CHANNEL1 => super::steps::StepHandler;
    EXTI15_10 => super::switches::SwitchHandler;
});

/// HSI16 → PLL (/4 × 85 /2) = 170 MHz; copied from embassy's
/// examples/stm32g4/src/bin/pll.rs at embassy-stm32-v0.6.0.
pub fn config() -> Config {
    use embassy_stm32::rcc::*;
    let mut config = embassy_stm32::Config::default();
    config.rcc.hsi = true;
    config.rcc.pll = Some(Pll {
        source: PllSource::HSI,
        prediv: PllPreDiv::DIV4,
        mul: PllMul::MUL85,
        divp: None,
        divq: None,
        divr: Some(PllRDiv::DIV2),
    });
    config.rcc.sys = Sysclk::PLL1_R;
    // RM0440 allows range-1 normal mode only up to 150 MHz: 170 needs boost
    config.rcc.boost = true;
    config
}

/// What `embassy_stm32::init` leaves out: flash prefetch (the instruction
/// cache alone misses on every jump into cold code, the step refill
/// included); the watchdog and the step timer stopped while a debug probe
/// halts the core, so a breakpoint neither resets the chip nor leaves STEP
/// pulsing at the last rate.
pub fn after_init() {
    pac::FLASH.acr().modify(|w| w.set_prften(true));
    pac::DBGMCU.apb1lfzr().modify(|w| {
        w.set_iwdg(true);
        w.set_tim3(true);
    });
    pac::DBGMCU.apb2fzr().modify(|w| w.set_tim1(true));
}

/// The step engine's DMA channel clocked (the timers are, by their
/// drivers in [`split`]).
pub fn enable_step_clocks() {
    pac::RCC.ahb1enr().modify(|w| {
        w.set_dma1en(true);
        w.set_dmamux1en(true);
    });
}

/// TIM1's update request to the step engine's DMA channel.
pub fn route_step_dma() {
    pac::DMAMUX1
        .ccr(STEP_DMA_CH)
        .write(|w| w.set_dmareq_id(TIM1_UP_REQUEST));
}

/// The fault path's pins (fault.rs, which stops the step timer first), by
/// direct register writes only: STEP (PA7) and DE (PA12) as GPIO outputs
/// driven low, BRAKE (PB2) low = brake applied, and unless `keep_enable`
/// ENABLE (PB1) low = power stage off. The pins are outputs from
/// `__pre_init` on (above), so these writes act from the first instruction
/// of `main`.
pub fn safe_outputs(keep_enable: bool) {
    use pac::gpio::vals::Moder;
    pac::GPIOA.bsrr().write(|w| {
        w.set_br(7, true);
        w.set_br(12, true);
    });
    pac::GPIOA.moder().modify(|w| {
        w.set_moder(7, Moder::OUTPUT);
        w.set_moder(12, Moder::OUTPUT);
    });
    pac::GPIOB.bsrr().write(|w| {
        w.set_br(1, !keep_enable);
        w.set_br(2, true);
    });
}

// The safe levels from the first instructions after reset (cortex-m-rt's
// `__pre_init`, called by its reset handler before RAM is initialised and
// before `main`, the clocks and the executor): GPIOA / GPIOB clocked, then
// STEP (PA7), DE (PA12), DIR (PB0), ENABLE (PB1) and BRAKE (PB2) push-pull
// outputs driven low (output data first, so no pin ever drives high).
// Assembly: nothing before RAM initialisation may touch memory, and Rust
// code cannot promise that (cortex-m-rt's `pre_init` docs). `split` later
// takes the pins over at the same levels; the window before this runs is
// docs/firmware.md's "From reset".
core::arch::global_asm!(
    ".section .text.__pre_init, \"ax\"",
    ".global __pre_init",
    ".type __pre_init, %function",
    ".thumb_func",
    "__pre_init:",
    // RCC_AHB2ENR |= GPIOAEN | GPIOBEN, read back: the ports are clocked
    // before their first write (RM0440 RCC: two AHB cycles)
    "ldr r0, =0x4002104C",
    "ldr r1, [r0]",
    "orr r1, r1, #3",
    "str r1, [r0]",
    "ldr r1, [r0]",
    // GPIOA: BSRR resets PA7 and PA12, MODER 01 (output) for both
    "ldr r0, =0x48000000",
    "ldr r1, =0x10800000",
    "str r1, [r0, #0x18]",
    "ldr r1, [r0]",
    "ldr r2, =0x0300C000",
    "bic r1, r1, r2",
    "ldr r2, =0x01004000",
    "orr r1, r1, r2",
    "str r1, [r0]",
    // GPIOB: BSRR resets PB0..PB2, MODER 01 for each
    "ldr r0, =0x48000400",
    "mov r1, #0x70000",
    "str r1, [r0, #0x18]",
    "ldr r1, [r0]",
    "bic r1, r1, #0x3F",
    "orr r1, r1, #0x15",
    "str r1, [r0]",
    "bx lr",
    ".ltorg",
);

/// For the NMI: a double ECC error in the parameter pages? If so its flag is
/// cleared and its flash offset returned (the read that hit it fails
/// instead, fault.rs).
pub fn take_parameter_ecc_error() -> Option<u32> {
    let eccr = pac::FLASH.eccr().read();
    let ours = super::calc::ecc_error_is_parameter_read(
        eccr.eccd(),
        eccr.sysf_ecc(),
        eccr.addr_ecc(),
        PARAM_FLASH_START..PARAM_FLASH_START + PARAM_FLASH_LEN,
    );
    if !ours {
        return None;
    }
    pac::FLASH.eccr().modify(|w| w.set_eccd(true)); // write 1 to clear
    Some(eccr.addr_ecc())
}

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
    pub step_timer: Timer<'static, TIM1>,
    pub pulse_counter: Timer<'static, TIM3>,
    pub step_pin: ComplementaryPwmPin<'static, TIM1, Ch1>,
    pub dir: ComplementaryPwmPin<'static, TIM1, Ch2>,
    pub enable: Output<'static>,
    pub brake: Output<'static>,
    pub switches: SwitchInputs,
    pub encoder: EncoderPins,
    pub param_flash: Option<FlashRegion<Flash<'static, FlashBlocking>>>,
}

pub fn split(p: Peripherals, line: &usart::Config) -> Result<Parts, usart::ConfigError> {
    let uart = Uart::new_blocking_with_de(p.USART1, p.PA10, p.PA9, p.PA12, *line)?;
    let step_timer = Timer::new(p.TIM1);
    // STEP and DIR driven low by the timer before their pins become its
    // outputs
    super::steps::outputs_low();
    Ok(Parts {
        uart,
        step_timer,
        pulse_counter: Timer::new(p.TIM3),
        step_pin: ComplementaryPwmPin::new(p.PA7, OutputType::PushPull),
        dir: ComplementaryPwmPin::new(p.PB0, OutputType::PushPull),
        // outputs start in the safe state: disabled, brake applied (SPEC §8.1)
        enable: Output::new(p.PB1, Level::Low, Speed::Low),
        brake: Output::new(p.PB2, Level::Low, Speed::Low),
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
        )
        .map(|r| r.with_read_fault(super::fault::take_flash_read_fault)),
    })
}
