"""Every STEP pulse is a counted step: long moves at the top step rates
with the acceleration of a real axis (0x6083 = 0x6084 = 2000) put exactly
as many pulses on the emulated STEP pin (`--trace-steps`) as 0x6064 counts
(SPEC §8). A DMA refill that came a buffer half late would let the timer
play entries of the half before (pulses the position never counts); the
firmware counts and logs such a refill."""

import csv
import time

import pytest

from conftest import (ACCELERATION, ACTUAL_POSITION, CONTROLWORD, DECELERATION, MODE,
                      MOTOR_RUNNING, PROFILE_VELOCITY, TARGET_POSITION, TARGET_REACHED, Master)

DISTANCE = 25_000
ACCEL = 2000  # 0.1 r/s²: 200 r/s², 2 000 000 steps/s² at 10000 steps/rev


def settled(sw):
    return sw & TARGET_REACHED and not sw & MOTOR_RUNNING


# 0x6081 in 0.1 r/s at 10000 steps/rev: 100 = 100 000 steps/s; each board
# at its top rate (Board::max_step_rate)
@pytest.mark.parametrize("board,velocity", [("f103", 100), ("f103", 200), ("g431", 200)])
def test_pulses_equal_the_position_at_the_top_rate(start_fw, tmp_path, board, velocity):
    steps = tmp_path / "steps.csv"
    fw = start_fw(board, "--trace-steps", str(steps))
    m = Master(fw.client())
    m.enable()
    m.write(MODE, 1)
    m.write32(PROFILE_VELOCITY, velocity)
    m.write(ACCELERATION, ACCEL)
    m.write(DECELERATION, ACCEL)
    m.write32(TARGET_POSITION, DISTANCE)
    m.write(CONTROLWORD, 0x001F)
    m.write(CONTROLWORD, 0x000F)
    m.wait(settled, 20, "target reached")
    assert m.read32(ACTUAL_POSITION) == DISTANCE
    time.sleep(0.05)  # the pin lags the count by the entries written ahead
    fw.alive()
    with open(steps) as f:
        pulses = list(csv.DictReader(f))
    assert len(pulses) == DISTANCE, f"{board}: {len(pulses)} pulses for 0x6064 = {DISTANCE}"
    # the mechanism itself: the refill kept ahead of the DMA throughout
    assert "refill(s) came a buffer half late" not in fw.stderr(), fw.stderr()
