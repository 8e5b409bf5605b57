//! The simulated encoder on each drive's motor (SPEC §8.8): what the
//! firmware's encoder timer does, from the simulated motor, with the
//! `--stall-at` / `--slip` / `--encoder-noise` faults (docs/closed-loop.md).

use modbus_drive::closed_loop::sim::SimEncoder;
use modbus_drive::Device;

use super::drive_slot::DriveSlot;
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

impl DriveSlot {
    /// What the firmware's encoder timer does before a control call: the
    /// counter, here from the simulated motor, scaled as the drive's PA17 /
    /// PA10 / PA18 say (a wired encoder matches them). Nothing while no
    /// encoder is wired and PA17 = 0: the drive stays open loop.
    pub(super) fn read_encoder(&mut self) {
        let pa = self.device.params();
        if !self.encoder_wired && pa.encoder_counts_per_rev() == 0 {
            return;
        }
        self.encoder.set_scale(
            pa.encoder_counts_per_rev(),
            pa.steps_per_rev(),
            pa.encoder_inverted(),
        );
        let raw = self
            .encoder
            .update(self.axis.position(), self.axis.is_running());
        self.device.set_encoder_count(raw);
    }
}
