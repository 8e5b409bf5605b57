//! The simulated encoder on each drive's motor (SPEC §8.8), built from the
//! `--encoder` / `--stall-at` / `--slip` / `--encoder-noise` options
//! (docs/closed-loop.md); the simulation host (`SimHost`) reads it before
//! each control call, as the firmware's encoder timer is read.

use modbus_drive::closed_loop::sim::SimEncoder;
use modbus_drive::Device;

use crate::virtual_drive::cli::EncoderFaults;

/// PA17 that `--encoder` sets when the drive has none: a 1000-line
/// encoder after ×4 decoding.
const SIM_ENCODER_COUNTS: u16 = 4000;

/// `--encoder` at start-up: PA17 = [`SIM_ENCODER_COUNTS`] unless the
/// drive's (saved) PA17 names a resolution already.
pub(super) fn wire(device: &mut Device, f: EncoderFaults) {
    if f.on && device.params().encoder_counts_per_rev() == 0 {
        device.configure(|pa, _| pa.set_encoder_counts_per_rev(SIM_ENCODER_COUNTS));
    }
}

/// The simulated encoder with the `--stall-at` / `--slip` /
/// `--encoder-noise` faults.
pub(super) fn sim_encoder(f: EncoderFaults) -> SimEncoder {
    let mut e = SimEncoder::new().with_noise(f.noise_counts);
    if let Some(at) = f.stall_at {
        e = e.with_stall_at(i64::from(at));
    }
    if let Some((steps, at)) = f.slip {
        e = e.with_slip(i64::from(steps), i64::from(at));
    }
    e
}
