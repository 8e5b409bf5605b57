"""A position move at the documented maximum acceleration and deceleration
(0x6083 = 0x6084 = 2000, 2 000 000 steps/s² at PA10 = 10000) on both
images: it starts, reaches its target and puts exactly its steps on the
STEP pin, forwards and back. The F103's 8 MHz step tick once made the first
step of such a move wrap into a delay of minutes (tests/board_ticks.rs runs
every limit on the host at both ticks). The profile velocity, 5 r/s, is one
both images' step engines keep up with under emulation; the velocity
limit is not what this test is about.
"""

import csv

from conftest import (ACCELERATION, ACTUAL_POSITION, CONTROLWORD, DECELERATION, MODE,
                      MOTOR_RUNNING, OPERATION_ENABLED, PROFILE_VELOCITY, STATE_MASK,
                      TARGET_POSITION, TARGET_REACHED, Master)

ACCEL_LIMIT = 2000  # 0.1 r/s²
VELOCITY = 50  # 0.1 r/s
# two ramps and a cruise between them
DISTANCE = 25_000


def settled(sw):
    return sw & TARGET_REACHED and not sw & MOTOR_RUNNING


def test_a_move_at_the_acceleration_limit_runs(start_fw, board, tmp_path):
    steps = tmp_path / "steps.csv"
    fw = start_fw(board, "--trace-steps", str(steps))
    m = Master(fw.client())
    m.enable()
    m.write(MODE, 1)
    m.write32(PROFILE_VELOCITY, VELOCITY)
    m.write(ACCELERATION, ACCEL_LIMIT)
    m.write(DECELERATION, ACCEL_LIMIT)
    assert (m.read(ACCELERATION), m.read(DECELERATION)) == (ACCEL_LIMIT, ACCEL_LIMIT)
    for target, direction in ((DISTANCE, "1"), (0, "0")):
        before = len(list(csv.DictReader(open(steps))))
        m.write32(TARGET_POSITION, target)
        m.write(CONTROLWORD, 0x001F)
        m.write(CONTROLWORD, 0x000F)
        m.wait(settled, 20, f"{board}: target {target} reached")
        assert m.read32(ACTUAL_POSITION) == target
        sw = m.statusword()
        assert sw & STATE_MASK == OPERATION_ENABLED, f"{board}: statusword 0x{sw:04X}"
        fw.alive()
        pulses = list(csv.DictReader(open(steps)))[before:]
        assert len(pulses) == DISTANCE, f"{board}: {len(pulses)} pulses for {DISTANCE} steps"
        assert {p["dir"] for p in pulses} == {direction}
        times = [int(p["time_ns"]) for p in pulses]
        assert times == sorted(times)
        assert all(int(p["width_ns"]) > 0 for p in pulses)
