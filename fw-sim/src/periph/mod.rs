//! The peripheral model, one file per peripheral (see docs/fw-sim.md for
//! the reference manual sections).
pub mod bank;
pub mod dma;
pub mod dmamux;
pub mod exti;
pub mod flash;
pub mod gpio;
pub mod iwdg;
pub mod rcc;
pub mod timer;
pub mod usart;

/// The answer of a peripheral to a bus access.
pub enum Access {
    /// The register's value (for a write: ignored).
    Ok(u32),
    /// No register at this offset: the run stops with its address.
    Unmodelled,
    /// A register that exists, set to a mode the model does not have: the
    /// run stops naming it.
    Unsupported(&'static str),
}
