//! Brake sequencing (PA22 release delay, PA23 engage time; docs/drive.md,
//! "Brake sequencing"): ENABLE and BRAKE over time through frames, and
//! motion held until the brake is released.

mod common;

use common::axis::Rig;
use modbus_drive::drive::Outputs;
use modbus_drive::motion::sim::SimAxis;
use modbus_drive::motion::Switches;

const PA22: u16 = 0x0064 + 22;

/// (power stage, brake released)
fn out(rig: &Rig) -> (bool, bool) {
    let o: Outputs = rig.bus.device.drive().outputs();
    (o.power_stage(), o.brake_released())
}

fn sequenced(release_ms: u16, engage_ms: u16) -> Rig {
    let mut rig = Rig::new(SimAxis::new(10_000_000));
    rig.write(PA22, &[release_ms, engage_ms]);
    rig
}

/// Runs the 1 kHz control loop until the outputs differ from `from`;
/// returns the time that took (µs) and the new outputs.
fn until_change(rig: &mut Rig, from: (bool, bool), max_us: u64) -> (u64, (bool, bool)) {
    let t0 = rig.now_us;
    rig.run_until(max_us, |r| out(r) != from);
    (rig.now_us - t0, out(rig))
}

#[test]
fn pa22_pa23_are_range_checked_and_default_to_zero() {
    let mut rig = Rig::new(SimAxis::new(10_000_000));
    assert_eq!(rig.bus.read(PA22, 2), Ok(vec![0, 0]));
    assert_eq!(rig.bus.write(PA22, &[2001]), Err(3));
    assert_eq!(rig.bus.write(PA22 + 1, &[2001]), Err(3));
    assert_eq!(rig.bus.write(PA22, &[2000, 2000]), Ok(()));
    assert_eq!(rig.bus.read(PA22, 2), Ok(vec![2000, 2000]));
}

#[test]
fn defaults_switch_both_outputs_with_the_state() {
    let mut rig = Rig::new(SimAxis::new(10_000_000));
    rig.controlword(0x0007);
    assert_eq!(
        out(&rig),
        (false, true),
        "§8.1: switched on releases the brake"
    );
    rig.controlword(0x000F);
    assert_eq!(out(&rig), (true, true));
    rig.controlword(0x0000);
    assert_eq!(out(&rig), (false, false), "both in the same write");
}

#[test]
fn enable_releases_the_brake_pa22_after_the_power_stage() {
    let mut rig = sequenced(50, 30);
    rig.controlword(0x0006);
    rig.controlword(0x0007);
    assert_eq!(
        out(&rig),
        (false, false),
        "no brake release without the power stage"
    );
    rig.bus.write_single(0x6040, 0x000F).unwrap();
    // read before the control step has timed it: power on, brake applied
    assert_eq!(out(&rig), (true, false));
    rig.control();
    assert_eq!(
        out(&rig),
        (true, false),
        "power stage on, brake still applied"
    );
    let (dt, now) = until_change(&mut rig, (true, false), 100_000);
    assert_eq!(now, (true, true));
    assert!(
        (50_000..=51_000).contains(&dt),
        "released {dt} µs after the power stage"
    );
}

#[test]
fn a_move_waits_for_the_brake() {
    let mut rig = sequenced(40, 0);
    rig.controlword(0x000F);
    let enabled_at = rig.now_us;
    rig.start_position_move(10_000);
    rig.run_until(200_000, |r| r.axis.position() != 0);
    let first_step_us = rig.now_us - enabled_at;
    assert!(out(&rig).1, "moving with the brake released");
    assert!(
        (40_000..=42_000).contains(&first_step_us),
        "first step {first_step_us} µs after enable"
    );
    rig.run_until(2_000_000, |r| r.at_rest());
    assert_eq!(rig.position(), 10_000);
}

#[test]
fn disable_engages_the_brake_at_once_and_holds_pa23() {
    for leave in [0x0000, 0x0006, 0x0007] {
        let mut rig = sequenced(10, 30);
        rig.controlword(0x000F);
        rig.run_us(20_000);
        assert_eq!(out(&rig), (true, true));
        rig.controlword(leave);
        assert_eq!(
            out(&rig),
            (true, false),
            "{leave:#06x}: brake at once, power held"
        );
        let (dt, now) = until_change(&mut rig, (true, false), 100_000);
        assert_eq!(now, (false, false), "{leave:#06x}");
        assert!(
            (29_000..=30_000).contains(&dt),
            "{leave:#06x}: power dropped after {dt} µs"
        );
    }
}

#[test]
fn quick_stop_ramps_with_the_brake_released_then_disable_sequences() {
    let mut rig = sequenced(10, 20);
    rig.controlword(0x000F);
    rig.start_position_move(1_000_000);
    rig.run_us(200_000);
    rig.controlword(0x0002); // quick stop
    assert_eq!(out(&rig), (true, true), "the ramp needs the motor");
    rig.run_until(2_000_000, |r| r.at_rest());
    assert_eq!(
        out(&rig),
        (true, true),
        "§8.1: quick stop active holds with power"
    );
    rig.controlword(0x0000);
    assert_eq!(out(&rig), (true, false));
    let (dt, now) = until_change(&mut rig, (true, false), 100_000);
    assert_eq!(now, (false, false));
    assert!((19_000..=20_000).contains(&dt), "{dt} µs");
}

#[test]
fn a_fault_engages_the_brake_when_the_reaction_ends_and_holds_pa23() {
    let mut rig = sequenced(0, 25);
    rig.controlword(0x000F);
    rig.start_position_move(1_000_000);
    rig.run_us(200_000);
    let both = Switches::new(true, true, false);
    // the both-limits fault: fault reaction (0x6085 ramp, brake released),
    // then fault
    let mut ramp_ms = 0;
    loop {
        rig.now_us += 1000;
        let axis_until = rig.axis.us_to_ticks(rig.now_us);
        rig.axis.run_until(&rig.sched, axis_until, |_| {});
        rig.bus
            .device
            .control_with(rig.now_us, both, &rig.sched, &mut rig.axis);
        rig.axis.kick(&rig.sched);
        if rig.statusword() & 0x004F == 0x0008 {
            break;
        }
        assert_eq!(
            out(&rig),
            (true, true),
            "fault reaction: the motor brakes the axis"
        );
        ramp_ms += 1;
        assert!(ramp_ms < 2000, "fault reaction never ended");
    }
    assert_eq!(out(&rig), (true, false), "fault: brake at once, power held");
    let t0 = rig.now_us;
    while out(&rig) == (true, false) {
        rig.now_us += 1000;
        rig.bus
            .device
            .control_with(rig.now_us, both, &rig.sched, &mut rig.axis);
        assert!(rig.now_us - t0 <= 100_000);
    }
    assert_eq!(out(&rig), (false, false));
    assert_eq!(rig.now_us - t0, 25_000);
}
