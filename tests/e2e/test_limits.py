"""Limits as a commissioning engineer meets them (issue 18): a stop at a
limit switch begins at the step where the edge is seen and takes the
distance 0x6085 gives; a fault the drive starts in is logged at start-up,
on no client's account."""

import re
import time

from conftest import (ACCELERATION, ACTUAL_POSITION, ACTUAL_VELOCITY, CCW_LIMIT, DECELERATION,
                      MODE,
                      PROFILE_VELOCITY, QUICK_STOP_DECELERATION, Master)


def test_a_ccw_limit_stops_the_axis_with_the_quick_stop_distance(start_drive, transport):
    """4.5 r/s (45 000 steps/s at PA10 = 10 000) into a CCW limit at
    10 000 with 0x6085 = 500 (50 r/s²): v²/2a = 2025 steps past the edge.
    The step timer's tick rounds the speed the brake starts from by up to
    1/222 (45 000 steps/s on 10 MHz), the distance by twice that (18
    steps); the control loop alone would stop about 100 steps later."""
    d = start_drive("--no-status", "--ccw-limit", "10000")
    m = Master(d.client(transport))
    m.enable()
    m.write(MODE, 3)
    m.write(ACCELERATION, 1000)
    m.write(DECELERATION, 1000)
    m.write(QUICK_STOP_DECELERATION, 500)
    m.write32(PROFILE_VELOCITY, 45)
    m.wait(lambda s: s & CCW_LIMIT, 5, "the CCW limit")
    deadline = time.monotonic() + 5
    while m.read32(ACTUAL_VELOCITY) != 0:
        assert time.monotonic() < deadline, "still moving"
        time.sleep(0.02)
    over = m.read32(ACTUAL_POSITION) - 10000
    assert 2025 - 18 - 4 <= over <= 2025 + 18 + 2, over
    assert "CCW limit: motion stopped" in d.stderr()


def test_a_fault_present_at_start_up_is_logged_at_start_up(start_drive):
    """Both limits active where the axis starts (a cut cable to normally
    closed switches, staged with --allow-limit-overlap): the fault is in the
    log before `ready`, on no line, and a client connecting later is not
    blamed for it."""
    d = start_drive("--no-status", "--cw-limit", "100", "--ccw-limit", "-100",
                    "--allow-limit-overlap", pty=False)
    log = d.stderr()
    faults = [ln for ln in log.splitlines() if "fault:" in ln]
    assert len(faults) == 1, log
    assert re.search(r"\] drive 1: fault: BothLimits$", faults[0]), faults[0]
    m = Master(d.client("tcp"))
    assert m.read(0x1001) & 1  # error register bit 0 (SPEC §8.7)
    time.sleep(0.1)
    later = [ln for ln in d.stderr().splitlines() if "fault:" in ln]
    assert later == faults, later
