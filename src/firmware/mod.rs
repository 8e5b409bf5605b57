//! STM32 firmware: embassy-stm32 glue around the core, one file
//! per concern.
//!
//! Follow one request: `rs485.rs` (USART interrupt: timestamp → the core's
//! `FrameAssembler`; t3.5 from the G431 receiver timeout or the F103 gap
//! task) → `rx_slots.rs` (the closed frame handed over) → `dispatch.rs` (`Device::poll`, then the reply at the time it
//! gave and a new line format) → `rs485.rs` (one burst, DE). Follow one
//! set-point: `control.rs` (1 kHz loop, `Device::control` fills the core's
//! `StepSchedule`) → `steps.rs` (the timer + DMA step engine; its refill
//! takes the steps through `feed.rs`, `StepSource::advance`). Switches: `switches.rs` (EXTI → the schedule's
//! limit brake); parameter flash: `flash.rs`;
//! pins and peripherals: `board_g431.rs` / `board_f103.rs`; arithmetic:
//! `calc.rs` (host-tested).
//!
//! Interrupt priorities and the masking rule: `priority.rs`; the watchdog
//! and the fault path (panic, HardFault, NMI): `fault.rs`; the tasks run in
//! thread mode.

#[cfg(all(feature = "board-g431", feature = "board-f103"))]
compile_error!("choose one board feature: board-g431 or board-f103");
#[cfg(not(any(feature = "board-g431", feature = "board-f103")))]
compile_error!("choose a board: `cargo fw` (STM32G431CB) or `cargo fw-f103` (STM32F103C8)");

#[cfg(feature = "sim")]
compile_error!("the firmware is built without the simulation: `--no-default-features` (as `cargo fw` and `cargo fw-f103` do)");

#[cfg(feature = "board-f103")]
#[path = "board_f103.rs"]
mod board;
#[cfg(feature = "board-g431")]
#[path = "board_g431.rs"]
mod board;

mod calc;
mod control;
mod dispatch;
mod encoder;
mod fault;
mod feed;
mod flash;
mod owned;
mod priority;
mod rs485;
mod rx_slots;
mod steps;
mod switches;
mod trim;

use defmt_rtt as _;
use embassy_executor::Spawner;
use embassy_stm32::interrupt::typelevel::Interrupt;
use embedded_storage::nor_flash::ReadNorFlash;
use modbus_drive::device::Identity;
use modbus_drive::motion::PlannerConfig;
use modbus_drive::params::{Boot, ParamStore};
use modbus_drive::rtu::LineConfig;
use modbus_drive::Device;

// This image's step rate limit within the planner's ceiling at the ring
// length it is built with (the feature `long-schedule`).
const _: () = assert!(board::BOARD.max_step_rate() <= modbus_drive::motion::MAX_STEP_RATE);

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    // Why the chip reset (DP-rES), before anything can add a flag; then the
    // flags cleared, so that the next boot sees its own reset alone.
    let rcc = embassy_stm32::pac::RCC;
    let reset_cause = calc::reset_cause_from_csr(rcc.csr().read().0);
    rcc.csr().modify(|w| w.set_rmvf(true));
    let p = embassy_stm32::init(board::config());
    priority::init();
    board::after_init();

    let parts = defmt::unwrap!(
        board::split(p, &rs485::usart_config(LineConfig::DEFAULT)).map_err(rs485::config_error)
    );
    // At once: embassy's init enabled the EXTI interrupts, and the handler
    // can only clear an edge's pending bit through the installed inputs.
    switches::install(parts.switches);

    // SPEC §9: the saved parameter set (or the defaults, and why) before the
    // first frame; its address and line are in force at once.
    let region = defmt::unwrap!(parts.param_flash.ok_or("parameter flash region"));
    let (range, capacity) = (region.range(), region.capacity() as u32);
    let mut store = defmt::unwrap!(ParamStore::new(region, 0..capacity));
    let (line, address, de, dir_inverted) = boot_and_install(&mut store, reset_cause);

    let mut uart = parts.uart;
    defmt::unwrap!(rs485::apply_line(&mut uart, line, de).map_err(rs485::config_error));
    let timer_clock_hz = parts.step_timer.get_clock_frequency().0;
    let prescaler = defmt::unwrap!(
        calc::step_prescaler(timer_clock_hz, board::STEP_TICK_HZ),
        "step timer clock {} Hz is no whole multiple of {} Hz",
        timer_clock_hz,
        board::STEP_TICK_HZ
    );
    let schedule = steps::start(prescaler, dir_inverted);
    // SAFETY: the handler is bound in `board::Irqs`; its state
    // (steps::ENGINE, steps::BUFFER) is initialised by `steps::start` above.
    unsafe { board::StepIrq::enable() };

    defmt::info!(
        "modbus-drive {} on {} (reset cause {=u16}): address {}, line {} (t3.5 = {=u32} µs), parameter flash {:#x} ({} B)",
        env!("CARGO_PKG_VERSION"),
        board::NAME,
        reset_cause,
        address,
        line,
        line.timing().t35_us(),
        range,
        capacity,
    );
    dispatch::EventLog::new().drain(); // how the parameters were loaded

    spawner.spawn(defmt::unwrap!(
        dispatch::dispatcher_task(uart, store).ok(),
        "task spawned twice"
    ));

    // The step engine's pins and pulse counter stay owned here for good,
    // and so does the F103's DE pin (an output that rs485 drives through
    // its set/reset register).
    let _step_pins = (parts.step_pin, parts.dir, parts.pulse_counter);
    #[cfg(feature = "board-f103")]
    let _de_pin = parts.de;
    // From here on a hung thread resets the chip (fault.rs).
    let watchdog = fault::Watchdog::start();
    control::run(
        control::PowerPins::new(parts.enable, parts.brake),
        schedule,
        watchdog,
        encoder::EncoderInput::new(parts.encoder),
    )
    .await
}

/// The core built from the saved parameters and installed
/// ([`install_device`]), the store read first ([`read_boot`]). Not async
/// and not inlined: what it holds between the two stays on the stack, not
/// in `main`'s future (a static).
#[inline(never)]
fn boot_and_install(
    store: &mut dispatch::Store,
    reset_cause: u16,
) -> (LineConfig, u8, modbus_drive::rtu::DriverEnable, bool) {
    let boot = read_boot(store);
    install_device(&boot, reset_cause)
}

/// The saved parameters (the store's boot: an old layout taken over, the
/// journal read). A function of its own, called before
/// [`install_device`], not from it: reading the store goes deep, and
/// below `install_device`'s frame, which holds the whole `Device`, it
/// overran the F103's stack once the step ring was long.
#[inline(never)]
fn read_boot(store: &mut dispatch::Store) -> Boot {
    #[cfg_attr(not(feature = "board-g431"), allow(unused_mut))]
    let mut boot = store.boot();
    // A page the G431 cannot read (flash ECC after a power cut, fault.rs)
    // is erased and the store read again, before the step timer runs —
    // when the store could not read around it: an unreadable entry is
    // one the journal skips, keeping the sets before it.
    #[cfg(feature = "board-g431")]
    if matches!(
        boot.outcome(),
        modbus_drive::params::BootOutcome::Unreadable(_)
    ) {
        if let Ok(Some(page)) = store.flash().erase_faulted_page() {
            defmt::warn!(
                "parameter page at offset {:#x} unreadable (flash ECC): erased",
                page
            );
            boot = store.boot();
        }
    }
    boot
}

/// Builds the core from the saved parameters `boot` and installs it for
/// the tasks; returns the line, address, DE lead / tail and PA11 in
/// force. A function of its own, not inlined: the `Device` is built on
/// its frame, which is gone once it is installed (in `main`'s frame it
/// would stay under every call of the control loop, `main` awaiting it),
/// and a `Device` local of `main` would stay in main's future (a static)
/// after it has been moved to the dispatcher: its RAM twice. Built by
/// the installing closure and set up once installed, so that the frame
/// holds as few of its copies as the compiler makes for one move: this
/// is the deepest the F103's stack goes (docs/firmware.md, "Sizes").
#[inline(never)]
fn install_device(
    boot: &Boot,
    reset_cause: u16,
) -> (LineConfig, u8, modbus_drive::rtu::DriverEnable, bool) {
    // The planner times steps in the step timer's ticks
    // (calc::step_prescaler) and keeps to the board's limits; it fills
    // the schedule in parts that the control loop spaces out.
    dispatch::install(|| {
        Device::with_planner_config(
            Identity::new(board::NAME),
            PlannerConfig::for_board(board::BOARD).with_fill_budget(control::FILL_BUDGET),
        )
    });
    defmt::unwrap!(dispatch::with_device(|device| {
        device.set_reset_cause(reset_cause);
        device.apply_boot(boot);
        (
            device.line(),
            device.address(),
            device.driver_enable(),
            device.params().direction_inverted(),
        )
    }))
}
