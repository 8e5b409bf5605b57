//! The program: the STM32 firmware on `target_os = "none"` (`src/firmware/`),
//! the virtual drive on a host (`src/virtual/`). Both run the same core
//! ([`modbus_drive::Device`]).
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

// The firmware (src/firmware/): its entry point is `#[embassy_executor::main]`.
#[cfg(target_os = "none")]
mod firmware;

// The virtual drive runs on the simulation (the default feature `sim`).
#[cfg(all(not(target_os = "none"), not(feature = "sim")))]
compile_error!("the virtual drive needs the feature `sim` (a default feature)");

// `virtual` is a reserved word, hence the module name.
#[cfg(not(target_os = "none"))]
#[path = "virtual/mod.rs"]
mod virtual_drive;

#[cfg(not(target_os = "none"))]
fn main() -> std::process::ExitCode {
    virtual_drive::main()
}
