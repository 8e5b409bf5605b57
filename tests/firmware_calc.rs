//! Host checks of the firmware's HAL-free parts (issue 6): the arithmetic in
//! `src/firmware/calc.rs` and the parameter flash region in
//! `src/firmware/flash.rs`, both included by path — the rest of
//! `src/firmware/` only builds for the boards.

#[path = "../src/firmware/calc.rs"]
#[allow(dead_code)]
mod calc;
#[path = "../src/firmware/flash.rs"]
#[allow(dead_code)]
mod flash;

use calc::*;
use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use flash::{FlashRegion, RegionError};
use modbus_drive::rtu::{CharFormat, LineConfig};

const G431_TICK_HZ: u32 = 10_000_000;
const F103_TICK_HZ: u32 = 8_000_000;

fn line(baud: u32, format: CharFormat) -> LineConfig {
    LineConfig { baud, format }
}

// ---------------------------------------------------------------- serial line

#[test]
fn receiver_timeout_is_t35_in_bit_times_spec_1() {
    assert_eq!(t35_rto_bits(line(9600, CharFormat::N1)), 35); // 3.5 × 10 bits
    assert_eq!(t35_rto_bits(line(19_200, CharFormat::E1)), 39); // 3.5 × 11 = 38.5
    assert_eq!(t35_rto_bits(line(115_200, CharFormat::N1)), 202); // 1750 µs = 201.6 bits
    assert_eq!(t35_rto_bits(line(38_400, CharFormat::N2)), 68); // 1750 µs = 67.2 bits
                                                                // never shorter than the core's t3.5, and at most one bit longer
    for baud in [9600, 19_200, 38_400, 57_600, 115_200] {
        for format in [
            CharFormat::N1,
            CharFormat::E1,
            CharFormat::O1,
            CharFormat::N2,
        ] {
            let l = line(baud, format);
            let rto_ns = u64::from(t35_rto_bits(l)) * 1_000_000_000 / u64::from(baud);
            let t35_ns = u64::from(l.timing().t35_us) * 1000;
            let bit_ns = 1_000_000_000 / u64::from(baud);
            assert!(rto_ns + 1000 >= t35_ns, "{l:?}: {rto_ns} ns < t3.5");
            assert!(rto_ns <= t35_ns + bit_ns, "{l:?}: {rto_ns} ns too long");
        }
    }
}

#[test]
fn reply_waits_out_the_delay_from_the_last_byte_even_across_a_wrap_spec_1() {
    assert_eq!(reply_wait_us(1000, 1000, 1750), 1750);
    assert_eq!(reply_wait_us(2000, 1000, 1750), 750);
    assert_eq!(reply_wait_us(5000, 1000, 1750), 0);
    assert_eq!(reply_wait_us(100, u32::MAX - 99, 1750), 1550); // 200 µs across the wrap
}

// ---------------------------------------------------------------- step output

#[test]
fn step_shape_never_goes_below_the_safe_minimums() {
    for hz in [G431_TICK_HZ, F103_TICK_HZ] {
        let safe = StepShape::safe(hz);
        let ns = |ticks: u32| u64::from(ticks) * 1_000_000_000 / u64::from(hz);
        assert!(ns(safe.pulse_ticks) >= 2500, "pulse ≥ 2.5 µs at {hz} Hz");
        assert!(
            ns(safe.dir_setup_ticks) >= 5000,
            "DIR set-up ≥ 5 µs at {hz} Hz"
        );
        assert_eq!(
            StepShape::from_params(10, 20, hz),
            safe,
            "below the minimum → minimum"
        );
        let wide = StepShape::from_params(100, 200, hz); // 10 µs, 20 µs
        assert_eq!(ns(wide.pulse_ticks), 10_000);
        assert_eq!(ns(wide.dir_setup_ticks), 20_000);
        assert_eq!(
            StepShape::from_params(u16::MAX, u16::MAX, hz),
            StepShape::from_params(1000, 1000, hz),
            "capped at 100 µs"
        );
    }
    assert_eq!(StepShape::safe(G431_TICK_HZ).pulse_ticks, 25);
    assert_eq!(StepShape::safe(F103_TICK_HZ).pulse_ticks, 20);
}

/// Runs the shaper over `steps` and returns, per step, (ticks from the
/// previous step's edge to its rising edge, ticks from the start of the
/// pulse's period to the rising edge, direction), checking the timer
/// registers of every period on the way.
fn run(shape: StepShape, steps: &[Step]) -> Vec<(u32, u32, bool)> {
    let mut shaper = StepShaper::new(shape);
    let mut queue = steps.iter().copied();
    let mut out = Vec::new();
    let mut since_edge = 0u32;
    let mut guard = 0;
    while out.len() < steps.len() {
        guard += 1;
        assert!(guard < 100_000);
        let p = shaper.next_period(|| queue.next());
        let len = u32::from(p.arr) + 1;
        match p.dir {
            Some(forward) => {
                assert!(p.ccr <= p.arr, "a step period has its pulse");
                assert_eq!(len - u32::from(p.ccr), shape.pulse_ticks, "pulse width");
                out.push((since_edge + u32::from(p.ccr), u32::from(p.ccr), forward));
                since_edge = len - u32::from(p.ccr);
            }
            None => {
                assert!(p.ccr > p.arr, "an idle period has no pulse");
                since_edge += len;
            }
        }
    }
    out
}

#[test]
fn steps_keep_their_interval_and_direction() {
    let shape = StepShape::safe(G431_TICK_HZ);
    let steps: Vec<Step> = [1000, 500, 200, 65_536, 70_000, 300_000, 1_000_000]
        .iter()
        .map(|&t| Step {
            forward: true,
            interval_ticks: t,
        })
        .collect();
    let out = run(shape, &steps);
    // the first one counts from the start; the others edge to edge, exactly
    for (i, (s, (gap, _, fwd))) in steps.iter().zip(&out).enumerate().skip(1) {
        assert_eq!(*gap, s.interval_ticks, "step {i}");
        assert!(*fwd);
    }
}

#[test]
fn too_short_intervals_are_stretched_to_a_visible_pulse() {
    let shape = StepShape::safe(G431_TICK_HZ);
    let out = run(
        shape,
        &[Step {
            forward: true,
            interval_ticks: 1,
        }; 3],
    );
    for (gap, _, _) in &out[1..] {
        assert_eq!(*gap, 2 * shape.pulse_ticks);
    }
}

#[test]
fn a_reversal_leaves_dir_set_up_time_before_the_edge() {
    for hz in [G431_TICK_HZ, F103_TICK_HZ] {
        let shape = StepShape::safe(hz);
        let steps = [
            Step {
                forward: true,
                interval_ticks: 60,
            },
            Step {
                forward: false,
                interval_ticks: 60,
            },
            Step {
                forward: true,
                interval_ticks: 60,
            },
        ];
        for (_, edge_in_period, _) in &run(shape, &steps)[1..] {
            // DIR is written when the period starts (+ interrupt latency)
            assert!(*edge_in_period >= shape.dir_setup_ticks + shape.latency_ticks);
        }
    }
}

#[test]
fn no_step_means_idle_periods_and_cancel_drops_the_pending_step() {
    let shape = StepShape::safe(G431_TICK_HZ);
    let mut shaper = StepShaper::new(shape);
    let p = shaper.next_period(|| None);
    assert!(p.ccr > p.arr && p.dir.is_none());
    assert_eq!(u32::from(p.arr) + 1, shape.idle_ticks);
    // a slow step is under way (first chunk issued), then a limit stop
    let p = shaper.next_period(|| {
        Some(Step {
            forward: false,
            interval_ticks: 200_000,
        })
    });
    assert!(p.dir.is_none());
    shaper.cancel();
    let p = shaper.next_period(|| None);
    assert!(
        p.dir.is_none() && p.ccr > p.arr,
        "the cancelled step never fires"
    );
}

// ---------------------------------------------------------------- switches, outputs

#[test]
fn switch_polarity_follows_pa13() {
    // normally open (PA13 bit 0): pulled up, active when the contact pulls low
    assert!(switch_active(false, false));
    assert!(!switch_active(true, false));
    // normally closed (bit 1): active when the contact opens and the pin goes high
    assert!(switch_active(true, true));
    assert!(!switch_active(false, true));
}

#[test]
fn debounce_needs_three_equal_samples() {
    let mut d = Debounce::new(false);
    assert_eq!(d.sample(true), None);
    assert_eq!(d.sample(false), None); // bounce: starts over
    assert_eq!(d.sample(true), None);
    assert_eq!(d.sample(true), None);
    assert_eq!(d.sample(true), Some(true));
    assert!(d.state());
    assert_eq!(d.sample(true), None);
}

#[test]
fn enable_and_brake_follow_the_power_state_spec_8_1() {
    // (statusword, enable, brake released)
    for (sw, enable, released, name) in [
        (0x0000, false, false, "not ready to switch on"),
        (0x0040, false, false, "switch on disabled"),
        (0x0021, false, false, "ready to switch on"),
        (0x0033, false, true, "switched on"), // + voltage enabled bit 4
        (0x0037, true, true, "operation enabled"),
        (0x0017, true, true, "quick stop active"),
        (0x000F, false, false, "fault reaction active"),
        (0x0008, false, false, "fault"),
        // what the drive reports: bit 5 = 1 except in quick stop (§8.2)
        (0x0060, false, false, "switch on disabled"),
        (0x002F, false, false, "fault reaction active"),
        (0x0028, false, false, "fault"),
        (0xFF37, true, true, "operation enabled"), // other bits ignored
    ] {
        let out = power_outputs(sw);
        assert_eq!(
            (out.enable, out.brake_released),
            (enable, released),
            "{sw:#06x}"
        );
        assert_eq!(power_state_name(sw), name, "{sw:#06x}");
    }
}

#[test]
fn frame_error_logs_are_rate_limited() {
    let mut r = RateLimit::new(1000);
    assert_eq!(r.allow(0), Some(0));
    assert_eq!(r.allow(10), None);
    assert_eq!(r.allow(999), None);
    assert_eq!(r.allow(1000), Some(2));
    assert_eq!(r.allow(u32::MAX), Some(0)); // wraps without a panic
    assert_eq!(r.allow(5), None);
}

// ---------------------------------------------------------------- flash region

/// 8 KiB of RAM pretending to be flash with 2 KiB pages and 8-byte writes
/// (the STM32G4's geometry).
struct RamFlash(Vec<u8>);

#[derive(Debug, PartialEq)]
struct RamFlashError;

impl NorFlashError for RamFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        NorFlashErrorKind::Other
    }
}

impl ErrorType for RamFlash {
    type Error = RamFlashError;
}

impl ReadNorFlash for RamFlash {
    const READ_SIZE: usize = 1;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), RamFlashError> {
        let o = offset as usize;
        bytes.copy_from_slice(self.0.get(o..o + bytes.len()).ok_or(RamFlashError)?);
        Ok(())
    }
    fn capacity(&self) -> usize {
        self.0.len()
    }
}

impl NorFlash for RamFlash {
    const WRITE_SIZE: usize = 8;
    const ERASE_SIZE: usize = 2048;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), RamFlashError> {
        self.0
            .get_mut(from as usize..to as usize)
            .ok_or(RamFlashError)?
            .fill(0xFF);
        Ok(())
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), RamFlashError> {
        let o = offset as usize;
        self.0
            .get_mut(o..o + bytes.len())
            .ok_or(RamFlashError)?
            .copy_from_slice(bytes);
        Ok(())
    }
}

#[test]
fn the_parameter_region_is_the_last_pages_with_offsets_from_zero() {
    let mut region = FlashRegion::new(RamFlash(vec![0; 8192]), 4096, 4096).expect("whole pages");
    assert_eq!(region.capacity(), 4096);
    assert_eq!(region.range(), 4096..8192);
    region.erase(0, 2048).unwrap();
    region.write(8, &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap();
    let mut b = [0; 10];
    region.read(6, &mut b).unwrap();
    assert_eq!(b, [0xFF, 0xFF, 1, 2, 3, 4, 5, 6, 7, 8]);
}

#[test]
fn the_region_refuses_what_is_outside_it() {
    let mut region = FlashRegion::new(RamFlash(vec![0; 8192]), 4096, 4096).unwrap();
    let mut b = [0; 2];
    assert_eq!(region.read(4095, &mut b), Err(RegionError::OutOfBounds));
    assert_eq!(region.write(4096, &[0; 8]), Err(RegionError::OutOfBounds));
    assert_eq!(
        region.write(u32::MAX - 2, &[0; 8]),
        Err(RegionError::OutOfBounds)
    );
    assert_eq!(region.erase(2048, 6144), Err(RegionError::OutOfBounds));
    assert_eq!(region.erase(2048, 0), Err(RegionError::OutOfBounds));
    assert_eq!(
        RegionError::<RamFlashError>::OutOfBounds.kind(),
        NorFlashErrorKind::OutOfBounds
    );
    // construction: whole pages only, inside the flash
    assert!(FlashRegion::new(RamFlash(vec![0; 8192]), 4000, 4096).is_none());
    assert!(FlashRegion::new(RamFlash(vec![0; 8192]), 4096, 1000).is_none());
    assert!(FlashRegion::new(RamFlash(vec![0; 8192]), 6144, 4096).is_none());
    assert!(FlashRegion::new(RamFlash(vec![0; 8192]), 0, 0).is_none());
}
