//! Power state machine, quick stop, halt, limits and faults through frames
//! (SPEC §8.1, §8.2, §8.3, §8.4, §8.7).

mod common;

use common::axis::{check_dynamics, Rig};
use modbus_drive::dictionary::DriveLayer;
use modbus_drive::motion::sim::SimAxis;
use modbus_drive::motion::Switches;

const WARNING: u16 = 1 << 7;
const HALT: u16 = 1 << 8;
const RUNNING: u16 = 1 << 9;
const REACHED: u16 = 1 << 10;
const HOME: u16 = 1 << 11;
const BIT12: u16 = 1 << 12;
const BIT13: u16 = 1 << 13;
const CW: u16 = 1 << 14;
const CCW: u16 = 1 << 15;

fn rig() -> Rig {
    Rig::new(SimAxis::new(10_000_000))
}

fn cw(rig: &mut Rig, v: u16) {
    rig.controlword(v);
}

/// Enabled at once (0x000F), then the common position move.
fn moving(rig: &mut Rig, target: i32) {
    rig.controlword(0x000F);
    rig.start_position_move(target);
}

#[test]
fn cia402_sequence_and_outputs() {
    let mut rig = rig();
    // SPEC §8.2: bit 5 = 0 only in quick stop active
    assert_eq!(
        rig.statusword(),
        0x0060,
        "switch on disabled after power-up"
    );
    let out = |r: &Rig| {
        let o = r.bus.device.drive().outputs();
        (o.brake_released(), o.power_stage())
    };
    assert_eq!(out(&rig), (false, false));
    cw(&mut rig, 0x0006);
    assert_eq!(rig.statusword(), 0x0021);
    assert_eq!(out(&rig), (false, false));
    cw(&mut rig, 0x0007);
    assert_eq!(rig.statusword(), 0x0033);
    assert_eq!(out(&rig), (true, false));
    cw(&mut rig, 0x000F);
    assert_eq!(rig.statusword(), 0x0037);
    assert_eq!(out(&rig), (true, true));
    cw(&mut rig, 0x0007);
    assert_eq!(rig.statusword(), 0x0033);
    cw(&mut rig, 0x0006);
    assert_eq!(rig.statusword(), 0x0021);
    cw(&mut rig, 0x0000);
    assert_eq!(rig.statusword(), 0x0060);
    assert_eq!(rig.bus.read(0x1001, 1), Ok(vec![0]));
}

#[test]
fn disable_while_moving_stops_step_output_at_once() {
    for leave in [0x0000, 0x0006, 0x0007] {
        let mut rig = rig();
        moving(&mut rig, 1_000_000);
        rig.run_us(300_000);
        assert!(rig.velocity_rpm() > 0);
        cw(&mut rig, leave);
        let at = rig.axis.steps();
        rig.run_us(1_000);
        // at most the one step already on the timer
        assert!(
            rig.axis.steps() <= at + 1,
            "{leave:#06x}: {} steps after",
            rig.axis.steps() - at
        );
        assert!(rig.at_rest());
        // enabling again does not resume the dropped set-point
        cw(&mut rig, 0x000F);
        rig.run_us(10_000);
        assert!(rig.at_rest());
        assert_eq!(i64::from(rig.position()), rig.axis.position());
    }
}

/// Steps from the quick stop command to rest, with option `code`.
fn quick_stop_distance(code: i16) -> i64 {
    let mut rig = rig();
    rig.bus.write_single(0x605A, code as u16).unwrap();
    moving(&mut rig, 1_000_000);
    rig.run_us(300_000); // cruising at 100000 steps/s
    assert_eq!(rig.velocity_rpm(), 600);
    let from = rig.axis.position();
    cw(&mut rig, 0x000B); // bit 2 = 0: quick stop
    assert_eq!(rig.statusword() & 0x006F, 0x0007, "quick stop active");
    rig.run_until(1_000_000, |r| r.at_rest());
    // stays in quick stop active until enabled again
    rig.run_us(10_000);
    assert_eq!(rig.statusword() & 0x006F, 0x0007);
    assert!(rig.bus.device.drive().outputs().power_stage());
    cw(&mut rig, 0x000F);
    assert_eq!(rig.statusword() & 0x006F, 0x0027, "operation enabled again");
    rig.axis.position() - from
}

#[test]
fn quick_stop_options() {
    // 1: 0x6084 (1e6 steps/s²): v²/2d = 5000 steps, plus what was queued
    // (≤ horizon 3 ms + one segment of 1 ms at 100000 steps/s)
    let d1 = quick_stop_distance(1);
    assert!((5_000..=5_000 + 400).contains(&d1), "option 1: {d1}");
    // 2: 0x6085 (2e6 steps/s²): 2500 steps
    let d2 = quick_stop_distance(2);
    assert!((2_500..=2_500 + 400).contains(&d2), "option 2: {d2}");
    // 0 and 3..: at once (one step at most)
    for code in [0, 3, 32767] {
        let d = quick_stop_distance(code);
        assert!(d <= 1, "option {code}: {d}");
    }
    // negative codes are refused on the bus
    let mut rig = rig();
    assert_eq!(rig.bus.write_single(0x605A, 0xFFFF), Err(3));
}

#[test]
fn quick_stop_then_enable_waits_for_the_stop() {
    let mut rig = rig();
    rig.bus.write_single(0x605A, 1).unwrap();
    moving(&mut rig, 1_000_000);
    rig.run_us(300_000);
    cw(&mut rig, 0x000B);
    cw(&mut rig, 0x000F); // enable during the stop
    assert_eq!(
        rig.statusword() & 0x006F,
        0x0007,
        "still quick stop while stopping"
    );
    rig.run_until(1_000_000, |r| r.at_rest());
    rig.run_us(1_000);
    assert_eq!(rig.statusword() & 0x006F, 0x0027);
}

#[test]
fn halt_and_resume_in_position_mode() {
    let mut rig = rig();
    moving(&mut rig, 300_000);
    rig.run_us(500_000);
    cw(&mut rig, 0x010F);
    assert_eq!(rig.statusword() & (HALT | REACHED), HALT);
    rig.run_until(1_000_000, |r| r.at_rest());
    // with halt, bit 10 means "velocity 0"
    assert_eq!(
        rig.statusword() & (HALT | REACHED | RUNNING),
        HALT | REACHED
    );
    let held = rig.axis.position();
    rig.run_us(50_000);
    assert_eq!(rig.axis.position(), held);
    cw(&mut rig, 0x000F);
    rig.run_until(10_000_000, |r| r.at_rest());
    assert_eq!(rig.position(), 300_000);
    assert_eq!(rig.statusword(), 0x0037 | BIT12 | REACHED);
    check_dynamics(&rig.steps, rig.tick_hz, 100_000.0, 1_000_000.0);
}

#[test]
fn new_target_behind_decelerates_reverses_and_arrives() {
    let mut rig = rig();
    moving(&mut rig, 1_000_000);
    rig.run_us(300_000);
    rig.write_i32(0x607A, 10_000); // behind the motor
    cw(&mut rig, 0x003F); // bit 5: at once
    cw(&mut rig, 0x002F);
    rig.run_until(10_000_000, |r| r.at_rest());
    assert_eq!(rig.position(), 10_000);
    assert_eq!(rig.axis.position(), 10_000);
    check_dynamics(&rig.steps, rig.tick_hz, 100_000.0, 1_000_000.0);
}

#[test]
fn refused_set_points_set_the_warning() {
    let mut rig = rig();
    moving(&mut rig, 0);
    assert_eq!(rig.statusword() & WARNING, 0);
    // relative to the previous target, beyond i32: refused (SPEC §8.4)
    rig.write_i32(0x607A, 2_000_000_000);
    cw(&mut rig, 0x001F);
    cw(&mut rig, 0x004F);
    rig.run_us(10_000);
    cw(&mut rig, 0x005F);
    cw(&mut rig, 0x004F);
    let s = rig.statusword();
    assert_eq!(
        s & (WARNING | BIT12),
        WARNING | BIT12,
        "refused, slot still free"
    );
    rig.run_us(10_000);
    // still running to the first target
    assert_eq!(
        rig.bus.device.drive().monitor().command_position(),
        2_000_000_000
    );
    // drop it: leave operation enabled and come back
    cw(&mut rig, 0x0007);
    cw(&mut rig, 0x000F);
    rig.run_us(1_000);
    // zero velocity: cannot run
    rig.write_i32(0x6081, 0);
    rig.write_i32(0x607A, 0);
    cw(&mut rig, 0x001F);
    cw(&mut rig, 0x000F);
    assert_eq!(rig.statusword() & WARNING, WARNING);
    // a good one clears it
    rig.write_i32(0x6081, 100);
    cw(&mut rig, 0x001F);
    assert_eq!(rig.statusword() & WARNING, 0);
}

#[test]
fn limit_blocks_motion_towards_it() {
    let mut rig = Rig::new(
        SimAxis::new(10_000_000)
            .with_cw_limit(-20_000)
            .with_home(-100, 100),
    );
    assert_eq!(rig.statusword() & HOME, HOME, "home switch shown (bit 11)");
    moving(&mut rig, -100_000);
    rig.run_until(5_000_000, |r| r.at_rest());
    // stopped with 0x6085 (2e6 steps/s²) past the edge: 2500 steps + horizon
    let p = rig.axis.position();
    assert!(
        (-20_000 - 2_500 - 300..=-20_000).contains(&p),
        "stopped at {p}"
    );
    let s = rig.statusword();
    assert_eq!(s & (CW | WARNING | CCW), CW | WARNING);
    // further towards it: refused; away from it: runs
    rig.write_i32(0x607A, -30_000);
    cw(&mut rig, 0x001F);
    cw(&mut rig, 0x000F);
    rig.run_us(10_000);
    assert_eq!(rig.axis.position(), p);
    rig.write_i32(0x607A, 0);
    cw(&mut rig, 0x001F);
    cw(&mut rig, 0x000F);
    rig.run_until(5_000_000, |r| r.at_rest());
    assert_eq!(rig.axis.position(), 0);
    assert_eq!(rig.statusword() & (CW | WARNING), 0);
}

#[test]
fn limits_disabled_by_pa14_do_not_block() {
    let mut rig = Rig::new(SimAxis::new(10_000_000).with_cw_limit(-20_000));
    rig.bus.write_single(0x0064 + 14, 0).unwrap(); // PA14 = 0
    moving(&mut rig, -30_000);
    rig.run_until(5_000_000, |r| r.at_rest());
    assert_eq!(rig.axis.position(), -30_000);
    assert_eq!(rig.statusword() & CW, 0);
}

fn control_with(rig: &mut Rig, sw: Switches) {
    rig.bus
        .device
        .control_with(rig.now_us, sw, &rig.sched, &mut rig.axis);
}

#[test]
fn both_limits_are_a_fault_reset_only_when_gone() {
    let mut rig = rig();
    cw(&mut rig, 0x000F);
    let both = Switches::new(true, true, false);
    control_with(&mut rig, both);
    control_with(&mut rig, both);
    assert_eq!(rig.statusword(), 0x0028 | CW | CCW, "fault (bit 5 = 1)");
    assert_eq!(rig.error_register(), 0x0001);
    assert!(!rig.bus.device.drive().outputs().power_stage());
    // cause still there: no reset
    rig.bus.write_single(0x6040, 0x0080).unwrap();
    control_with(&mut rig, both);
    assert_eq!(rig.statusword() & 0x006F, 0x0028);
    // cause gone, but no rising edge of bit 7
    let one = Switches::new(true, false, false);
    control_with(&mut rig, one);
    rig.bus.write_single(0x6040, 0x0080).unwrap();
    assert_eq!(rig.statusword() & 0x006F, 0x0028);
    // nothing else acts in fault
    rig.bus.write_single(0x6040, 0x000F).unwrap();
    assert_eq!(rig.statusword() & 0x006F, 0x0028);
    rig.bus.write_single(0x6040, 0x0080).unwrap();
    assert_eq!(rig.statusword() & 0x006F, 0x0060, "reset");
    assert_eq!(rig.error_register(), 0);
}

#[test]
fn communication_loss_while_enabled() {
    let mut rig = rig();
    rig.bus.write_single(0x0064 + 20, 100).unwrap(); // PA20 = 100 ms
    rig.control();
    // not enabled: no timer
    rig.run_us(300_000);
    assert_eq!(rig.statusword(), 0x0060);
    moving(&mut rig, 1_000_000);
    rig.run_us(90_000);
    assert_eq!(
        rig.statusword() & 0x004F,
        0x0007,
        "a frame every 90 ms keeps it alive"
    );
    rig.run_us(90_000);
    assert_eq!(rig.statusword() & 0x004F, 0x0007);
    rig.run_us(101_000);
    // fault reaction (quick stop ramp, bit 5 = 1: SPEC §8.2) then fault
    assert_eq!(rig.statusword() & 0x006F, 0x002F, "fault reaction active");
    rig.run_until(1_000_000, |r| r.at_rest());
    rig.control();
    assert_eq!(rig.bus.read(0x6041, 1).unwrap()[0] & 0x006F, 0x0028);
    assert_eq!(rig.error_register(), 0x0010);
    cw(&mut rig, 0x0080);
    assert_eq!(rig.statusword() & 0x006F, 0x0060);
    assert_eq!(rig.error_register(), 0);
}

mod random {
    use super::*;
    use proptest::prelude::*;

    /// One master action: a register write or some time passing.
    #[derive(Clone, Debug)]
    enum Act {
        Control(u16),
        Mode(u16),
        Write(u16, i32),
        Wait(u64),
    }

    fn act() -> impl Strategy<Value = Act> {
        prop_oneof![
            prop::sample::select(vec![
                0x0000u16, 0x0006, 0x0007, 0x000B, 0x000F, 0x001F, 0x003F, 0x005F, 0x021F, 0x010F,
                0x0080, 0x007F
            ])
            .prop_map(Act::Control),
            prop::sample::select(vec![1u16, 3, 6]).prop_map(Act::Mode),
            (
                prop::sample::select(vec![0x6081u16, 0x607A, 0x607C, 0x6099, 0x609B]),
                -300_000i32..300_000
            )
                .prop_map(|(r, v)| Act::Write(r, v)),
            (
                prop::sample::select(vec![0x6083u16, 0x6084, 0x6085, 0x609A, 0x605A, 0x6098]),
                0i32..3000
            )
                .prop_map(|(r, v)| Act::Write(r, v)),
            (1u64..200).prop_map(Act::Wait),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 32, ..ProptestConfig::default() })]

        /// Whatever the master writes, the drive never panics, never loses
        /// a step (0x6064 follows the motor), and stepping only happens with
        /// the power stage enabled.
        #[test]
        fn random_master(acts in prop::collection::vec(act(), 1..40)) {
            let mut rig = Rig::new(SimAxis::new(10_000_000).with_cw_limit(-200_000).with_ccw_limit(200_000).with_home(-1000, 1000));
            for a in acts {
                match a {
                    Act::Control(v) => { let _ = rig.bus.write_single(0x6040, v); rig.control(); }
                    Act::Mode(m) => { let _ = rig.bus.write_single(0x6060, m); rig.control(); }
                    Act::Write(r, v) => {
                        let wide = matches!(r, 0x6081 | 0x607A | 0x607C | 0x6099 | 0x609B);
                        let _ = if wide { rig.bus.write(r, &[(v >> 16) as u16, v as u16]) } else { rig.bus.write_single(r, v as u16) };
                        rig.control();
                    }
                    Act::Wait(ms) => {
                        for _ in 0..ms {
                            let before = rig.axis.steps();
                            rig.run_us(1000);
                            if rig.axis.steps() > before + 1 {
                                prop_assert!(rig.bus.device.drive().outputs().power_stage());
                            }
                        }
                    }
                }
            }
            let raw = i64::from(rig.sched.position());
            let net: i64 = rig.steps.iter().map(|s| if s.forward() { 1 } else { -1 }).sum();
            prop_assert_eq!(rig.axis.position(), net);
            prop_assert_eq!(raw, net);
        }
    }
}

/// SPEC §8.2: bit 5 = 0 only in quick stop active; the other bits 0–3, 6
/// as the §8.1 patterns (not ready to switch on cannot be reached: the
/// drive leaves it by itself at power-up).
#[test]
fn bit_5_is_0_only_in_quick_stop_active() {
    use modbus_drive::drive::PowerState::*;
    for (state, bits) in [
        (NotReadyToSwitchOn, 0x0020),
        (SwitchOnDisabled, 0x0060),
        (ReadyToSwitchOn, 0x0021),
        (SwitchedOn, 0x0033),
        (OperationEnabled, 0x0037),
        (QuickStopActive, 0x0017),
        (FaultReactionActive, 0x002F),
        (Fault, 0x0028),
    ] {
        assert_eq!(state.status_bits(), bits, "{state:?}");
    }
    // and on the bus, the reachable ones
    let mut rig = rig();
    assert_eq!(rig.statusword() & 0x006F, 0x0060);
    moving(&mut rig, 1_000_000);
    rig.run_us(10_000);
    cw(&mut rig, 0x000B);
    assert_eq!(rig.statusword() & 0x006F, 0x0007, "quick stop active");
}

/// SPEC §8.2 / §8.4–§8.6: bits 10, 12, 13 describe the mode in 0x6061 in
/// every state, not only in operation enabled.
#[test]
fn mode_bits_in_every_state() {
    const MODE: u16 = BIT13 | BIT12 | REACHED;
    let mut rig = rig();
    // homing: not started = 001, also when not enabled
    cw(&mut rig, 0x000F);
    rig.bus.write_single(0x6060, 6).unwrap();
    cw(&mut rig, 0x0007);
    assert_eq!(
        rig.statusword(),
        0x0033 | REACHED,
        "switched on, homing 001"
    );
    cw(&mut rig, 0x0000);
    assert_eq!(rig.statusword() & MODE, REACHED, "switch on disabled: 001");
    // velocity: speed 0 (bit 12) and target velocity 0 reached at rest
    rig.bus.write_single(0x6060, 3).unwrap();
    rig.control();
    assert_eq!(rig.statusword(), 0x0060 | BIT12 | REACHED);
    cw(&mut rig, 0x0006);
    assert_eq!(rig.statusword(), 0x0021 | BIT12 | REACHED);
    // velocity, quick stop: not 0 while braking, 0 at rest
    cw(&mut rig, 0x000F);
    rig.write_i32(0x6081, 100);
    rig.write(0x6083, &[1000, 1000, 2000]);
    rig.run_us(200_000);
    rig.bus.write_single(0x605A, 2).unwrap();
    cw(&mut rig, 0x000B);
    assert_eq!(rig.statusword() & (BIT12 | REACHED), 0, "braking");
    rig.run_until(1_000_000, |r| r.at_rest());
    assert_eq!(rig.statusword(), 0x0017 | BIT12 | REACHED);
    // position: slot free, target reached at rest, in any state
    cw(&mut rig, 0x0000);
    rig.bus.write_single(0x6060, 1).unwrap();
    rig.control();
    assert_eq!(rig.statusword(), 0x0060 | BIT12 | REACHED);
    cw(&mut rig, 0x0007);
    assert_eq!(rig.statusword(), 0x0033 | BIT12 | REACHED);
}

/// SPEC §8.4 bit 6 ("relative to the previous target"): after a mode
/// change there is no previous position-mode target; the change stops the
/// old motion with 0x6084 and a relative set-point counts from where the
/// motor comes to rest, whether it is latched after the stop or during it
/// (docs/drive.md, Position mode).
#[test]
fn relative_set_point_after_a_mode_change_counts_from_rest() {
    let mut ends = Vec::new();
    for latch_during_stop in [false, true] {
        let mut rig = rig();
        cw(&mut rig, 0x000F);
        rig.bus.write_single(0x6060, 3).unwrap();
        rig.write_i32(0x6081, 50); // 5 r/s = 50000 steps/s
        rig.write(0x6083, &[100, 100]); // 10 r/s² = 1e5 steps/s²
        rig.run_us(1_000_000);
        assert_eq!(rig.velocity_rpm(), 300);
        let at_change = rig.axis.position(); // ≈ 37500
        rig.bus.write_single(0x6060, 1).unwrap();
        rig.control();
        rig.write_i32(0x607A, 1000);
        let rest = if latch_during_stop {
            assert!(!rig.at_rest());
            assert_eq!(rig.statusword() & BIT12, BIT12, "base known: slot free");
            None
        } else {
            rig.run_until(1_000_000, |r| r.at_rest());
            Some(rig.axis.position())
        };
        cw(&mut rig, 0x005F); // new set-point, relative
        cw(&mut rig, 0x000F);
        rig.run_until(2_000_000, |r| r.at_rest());
        let end = rig.axis.position();
        assert_eq!(i64::from(rig.position()), end);
        assert_eq!(rig.statusword(), 0x0037 | BIT12 | REACHED);
        // stopped with 0x6084: v²/2d = 12500 steps plus what was queued
        // (≤ 4 ms at 50000 steps/s), then 1000 further on
        let stop = end - 1000 - at_change;
        assert!((12_500..=12_500 + 200).contains(&stop), "stop {stop}");
        if let Some(rest) = rest {
            assert_eq!(end, rest + 1000);
        }
        assert!(rig.steps.iter().all(|s| s.forward()), "never backwards");
        ends.push(end);
    }
    assert_eq!(ends[0], ends[1], "latched during the stop or after it");
}

/// A mode change with 0x6084 = 0 stops at once (docs/drive.md); until the step
/// interrupt has done so the rest position is not known: bit 12 = 0 and a
/// set-point edge is ignored (SPEC §8.4), then the slot frees.
#[test]
fn mode_change_with_a_stop_at_once_frees_the_slot_at_rest() {
    let mut rig = rig();
    moving(&mut rig, 1_000_000);
    rig.run_us(300_000);
    rig.bus.write_single(0x6084, 0).unwrap();
    rig.bus.write_single(0x6060, 6).unwrap();
    rig.bus.write_single(0x6060, 1).unwrap();
    rig.write_i32(0x607A, 1000);
    rig.control();
    assert_eq!(rig.statusword() & BIT12, 0, "stop at once pending");
    cw(&mut rig, 0x005F); // ignored
    cw(&mut rig, 0x000F);
    rig.run_us(1_000);
    assert!(rig.at_rest());
    let rest = rig.axis.position();
    rig.run_us(10_000);
    assert_eq!(rig.axis.position(), rest, "the edge was ignored");
    assert_eq!(rig.statusword() & (BIT12 | REACHED), BIT12 | REACHED);
    rig.bus.write_single(0x6084, 1000).unwrap();
    cw(&mut rig, 0x005F);
    cw(&mut rig, 0x000F);
    rig.run_until(1_000_000, |r| r.at_rest());
    assert_eq!(rig.axis.position(), rest + 1000);
}

/// SPEC §8.1: halt decelerates with 0x6084 in position and velocity mode
/// (not with 0x6085), at once when 0x6084 = 0 (docs/drive.md).
#[test]
fn halt_decelerates_with_0x6084() {
    // cruising at 100000 steps/s; 0x6084 = 1e6 steps/s²: 5000 steps
    // (0x6085 = 2e6 would be 2500), plus ≤ 4 ms queued
    for mode in [1u16, 3] {
        for (decel, min, max) in [(1000u16, 5_000, 5_000 + 400), (0, 0, 1)] {
            let mut rig = rig();
            moving(&mut rig, 1_000_000);
            rig.bus.write_single(0x6060, mode).unwrap();
            if mode == 3 {
                rig.control();
                rig.run_us(1_000);
            }
            cw(&mut rig, 0x000F);
            rig.run_us(300_000);
            assert_eq!(rig.velocity_rpm(), 600, "mode {mode}");
            // velocity mode replans on any write: 0 there is only
            // tried in position mode
            if decel == 0 && mode == 3 {
                continue;
            }
            rig.bus.write_single(0x6084, decel).unwrap();
            let at = rig.axis.position();
            cw(&mut rig, 0x010F);
            rig.run_until(1_000_000, |r| r.at_rest());
            let braked = rig.axis.position() - at;
            assert!(
                (min..=max).contains(&braked),
                "mode {mode}, 0x6084 = {decel}: {braked}"
            );
            assert_eq!(rig.statusword() & (HALT | REACHED), HALT | REACHED);
        }
    }
}

/// A step output that is handed steps ahead of its pin (the firmware's
/// timer + DMA engine) tells the schedule how many it has not made
/// (`StepSchedule::set_pin_lag`): 0x6064 is the pin's position, and the
/// target is reached (bit 10) and the motor at rest (bit 9 clear) only
/// once the pin has caught up with every step counted, those counted
/// after the lag was measured too.
#[test]
fn the_position_and_target_reached_wait_for_the_pin() {
    let mut rig = rig();
    moving(&mut rig, 500);
    rig.run_until(1_000_000, |r| r.statusword() & REACHED != 0);
    assert_eq!(rig.position(), 500);
    // the last three steps counted are still on their way to the pin
    let at = rig.sched.position();
    rig.sched.set_pin_lag(3, at);
    rig.control();
    assert_eq!(rig.position(), 497, "0x6064 is the pin's");
    let sw = rig.statusword();
    assert_eq!(sw & REACHED, 0, "not reached before the pin: {sw:#06x}");
    assert_ne!(sw & RUNNING, 0, "still running: {sw:#06x}");
    // a lag of 0 measured before the last three were counted says nothing
    // of them: the output was handed them after it looked
    rig.sched.set_pin_lag(0, at - 3);
    rig.control();
    let sw = rig.statusword();
    assert_eq!(sw & REACHED, 0, "not reached on an old lag: {sw:#06x}");
    assert_ne!(sw & RUNNING, 0, "still running on an old lag: {sw:#06x}");
    rig.sched.set_pin_lag(0, at);
    rig.control();
    assert_eq!(rig.position(), 500);
    let sw = rig.statusword();
    assert_eq!((sw & REACHED, sw & RUNNING), (REACHED, 0), "{sw:#06x}");
}
