//! The peripheral model, one file per peripheral (see docs/fw-sim.md for
//! the reference manual sections).
pub mod bank;
pub mod exti;
pub mod flash;
pub mod gpio;
pub mod iwdg;
pub mod rcc;
pub mod timer;
pub mod usart;
