//! The simulation host: what a board's glue does around [`Device`] for one
//! axis, played on a simulated axis ([`SimAxis`]) and encoder
//! ([`SimEncoder`]). The virtual drive, the host tests, the fuzz harness
//! and the commissioning page all drive their axis through it, so the
//! loop "run the axis → at a switch edge or when [`Device::poll_at`] says,
//! read the encoder → [`Device::control`] → start the idle step
//! interrupt" is written once.

use super::{Device, CONTROL_PERIOD_US};
use crate::closed_loop::sim::SimEncoder;
use crate::motion::sim::{RunStop, SimAxis, StepRecord};
use crate::motion::{StepSchedule, SwitchEdges, Switches};

/// One simulated axis under a device, borrowed for a run. The parts stay
/// the caller's, so tests may look at (or play) them between runs.
pub struct SimHost<'a> {
    device: &'a mut Device,
    axis: &'a mut SimAxis,
    schedule: &'a StepSchedule,
    encoder: Option<(&'a mut SimEncoder, bool)>,
    switches: Option<&'a dyn SwitchView>,
    in_parts: bool,
}

/// What the drive sees of the axis's switches, where a host changes it
/// (e.g. switches forced from the commissioning page).
pub trait SwitchView {
    fn seen(&self, axis: Switches) -> Switches;
}

impl<'a> SimHost<'a> {
    pub fn new(device: &'a mut Device, axis: &'a mut SimAxis, schedule: &'a StepSchedule) -> Self {
        Self {
            device,
            axis,
            schedule,
            encoder: None,
            switches: None,
            in_parts: false,
        }
    }

    /// Each control call made as the firmware makes it, in parts
    /// ([`Device::begin_control_latched`], then [`Device::top_up_with`]
    /// while [`Device::fill_paused`]), back to back: nothing else runs on
    /// this host between them.
    pub fn in_parts(mut self) -> Self {
        self.in_parts = true;
        self
    }

    /// An encoder on the motor, read before every control call when it is
    /// `wired` or the drive's PA17 names a resolution (else the drive
    /// stays open loop, SPEC §8.8).
    pub fn with_encoder(mut self, encoder: &'a mut SimEncoder, wired: bool) -> Self {
        self.encoder = Some((encoder, wired));
        self
    }

    /// What the drive sees of the axis's switches (e.g. forced from the
    /// commissioning page).
    pub fn with_switches(mut self, view: &'a dyn SwitchView) -> Self {
        self.switches = Some(view);
        self
    }

    /// One control call at `now_us`, as the glue makes it: the encoder
    /// read first, then [`Device::control`], then the idle step interrupt
    /// started if the schedule has work.
    pub fn control(&mut self, now_us: u64) {
        if let Some((encoder, wired)) = self.encoder.as_mut() {
            let pa = self.device.params();
            if *wired || pa.encoder_counts_per_rev() != 0 {
                encoder.set_scale(
                    pa.encoder_counts_per_rev(),
                    pa.steps_per_rev(),
                    pa.encoder_inverted(),
                );
                let raw = encoder.update(self.axis.position(), self.axis.is_running());
                self.device.set_encoder_count(raw);
            }
        }
        let seen = self.axis.switches();
        let seen = self.switches.map_or(seen, |view| view.seen(seen));
        if self.in_parts {
            let edges = SwitchEdges::default();
            self.device
                .begin_control_latched(now_us, seen, edges, self.schedule);
            while self.device.fill_paused() {
                self.device.top_up_with(self.schedule, &mut *self.axis);
            }
        } else {
            self.device
                .control_with(now_us, seen, self.schedule, &mut *self.axis);
        }
        self.axis.kick(self.schedule);
    }

    /// Runs the axis up to `until_us`, making every step, with a control
    /// call at each step that changed a switch (SPEC §8.6: the origin is
    /// the step where the edge was seen) and whenever [`Device::poll_at`]
    /// falls due. No call at `until_us` itself unless it is due.
    pub fn run_to(&mut self, until_us: u64, on_step: impl FnMut(StepRecord)) {
        self.run(until_us, true, on_step);
    }

    /// After the host was held up (suspended, a debugger) for longer than
    /// it wants to make up: the axis runs to `now_us` with control calls at
    /// its switch edges only, then one control call at `now_us`.
    pub fn resume_at(&mut self, now_us: u64, on_step: impl FnMut(StepRecord)) {
        self.run(now_us, false, on_step);
        self.control(now_us);
    }

    fn run(&mut self, until_us: u64, periodic: bool, mut on_step: impl FnMut(StepRecord)) {
        loop {
            let due = self.device.poll_at();
            let to = if periodic {
                due.min(until_us)
            } else {
                until_us
            };
            // the simulated limit-switch interrupt applies PA14 as the board's
            self.axis
                .set_limit_enable(self.device.params().limit_enable());
            let stop = self
                .axis
                .run_until(self.schedule, self.axis.us_to_ticks(to), &mut on_step);
            if stop == RunStop::SwitchChanged {
                let last = due.saturating_sub(CONTROL_PERIOD_US);
                self.control(self.axis.now_us().max(last));
            } else if periodic && due <= until_us {
                self.control(due);
            } else {
                return;
            }
        }
    }

    /// [`Self::run_to`] `now_us`, then a control call there: what a host
    /// does after it handled a frame (the set-point reaches the planner at
    /// once) or whenever it needs the drive up to date at `now_us`.
    pub fn control_at(&mut self, now_us: u64, on_step: impl FnMut(StepRecord)) {
        self.run_to(now_us, on_step);
        // run_to left poll_at after now_us; not a whole period after it
        // unless the last call was at now_us
        if self.device.poll_at() < now_us + CONTROL_PERIOD_US {
            self.control(now_us);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::device::Identity;

    /// (Switch edges: the homing and limit tests, through `tests/common`.)
    #[test]
    fn control_is_called_when_poll_at_falls_due_and_after_a_frame() {
        let mut device = Device::new(Identity::new("t"));
        let mut axis = SimAxis::new(10_000_000).with_home(0, 10);
        let schedule = StepSchedule::new();
        // before the first call: due at once
        assert_eq!(device.poll_at(), 0);
        SimHost::new(&mut device, &mut axis, &schedule).run_to(5_500, |_| {});
        // calls at 0, 1000, …, 5000: the next one a period after the last
        assert_eq!(device.poll_at(), 6_000);
        // after a frame: a call at once, the period counts from there
        SimHost::new(&mut device, &mut axis, &schedule).control_at(5_700, |_| {});
        assert_eq!(device.poll_at(), 6_700);
        // a second control_at at the same instant changes nothing
        SimHost::new(&mut device, &mut axis, &schedule).control_at(5_700, |_| {});
        assert_eq!(device.poll_at(), 6_700);
    }
}
