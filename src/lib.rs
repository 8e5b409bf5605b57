//! modbus-drive core: the hardware-independent part of a Modbus-RTU
//! stepper/servo drive (SPEC = `../shared/SPEC.md`).
//!
//! Sans-IO: bytes, timestamps and switch states go in; reply frames, step
//! schedules and events come out. No HAL, no clock, no logger, no heap. The
//! firmware (`src/firmware/`) and the virtual drive (`src/virtual/`) are thin
//! glue around it.
//!
//! Follow one request: [`rtu::FrameAssembler`] (bytes + timestamps → frame)
//! → [`device::Device::handle_rx`] → [`slave`] (validation, dispatch,
//! counters) → [`dictionary`] (entries, ranges, word order) → reply bytes.
//! Follow one set-point: controlword write → [`drive`] (state machine, modes)
//! → [`motion`] (planner → step schedule) → the step interrupt's
//! [`motion::StepSource`].
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]

pub mod boards;
pub mod closed_loop;
pub mod device;
pub mod dictionary;
pub mod drive;
pub mod event;
pub mod mbap;
pub mod motion;
pub mod params;
pub mod rtu;
pub mod slave;

pub use device::Device;
