"""The manual's programs (seed 000 chapter 6) run through the pymodbus
client API, over the pty and over TCP, with positions and statuswords
asserted (SPEC §8). The simulated axis counts the steps the core emits in
real time, so these take a few seconds each."""

import time

from conftest import (ACCELERATION, ACTUAL_POSITION, ACTUAL_VELOCITY, BIT12, BIT13, CCW_LIMIT,
                      CONTROLWORD, CW_LIMIT, DECELERATION, HOME_OFFSET, HOMING_ACCELERATION,
                      HOMING_METHOD, HOMING_SPEED, HOMING_ZERO_SPEED, MODE, MODE_DISPLAY,
                      MOTOR_RUNNING, OPERATION_ENABLED, PROFILE_VELOCITY,
                      QUICK_STOP_DECELERATION, STATE_MASK, TARGET_POSITION, TARGET_REACHED,
                      VOLTAGE_ENABLED, Master)

HALT = 1 << 8



def settled(sw):
    return sw & TARGET_REACHED and not sw & MOTOR_RUNNING


def test_position_mode_single_point(start_drive, transport):
    """6.1 "单点运动": 200000 steps at 5 r/s, 10 r/s² ramps."""
    d = start_drive("--no-status")
    m = Master(d.client(transport))
    m.enable()
    m.write(MODE, 1)
    assert m.read_i16(MODE_DISPLAY) == 1
    m.write32(PROFILE_VELOCITY, 50)
    m.write(ACCELERATION, 100)
    m.write(DECELERATION, 100)
    m.write(QUICK_STOP_DECELERATION, 100)
    m.write32(TARGET_POSITION, 200000)
    sw = m.statusword()
    assert sw & BIT12, "a new set-point can be accepted (SPEC §8.4)"
    t0 = time.monotonic()
    m.write(CONTROLWORD, 0x001F)  # latch the set-point and run
    m.write(CONTROLWORD, 0x000F)  # bit 4 back to 0 for the next latch
    running = m.wait(lambda s: s & MOTOR_RUNNING, 2, "motor running")
    mid = m.read32(ACTUAL_POSITION)
    assert 0 < mid < 200000
    assert m.read32(ACTUAL_VELOCITY) > 0
    seen = m.wait(settled, 10, "target reached")
    elapsed = time.monotonic() - t0
    assert m.read32(ACTUAL_POSITION) == 200000, "the final position is exact (SPEC §8.4)"
    sw = m.statusword()
    assert sw & STATE_MASK == OPERATION_ENABLED and sw & VOLTAGE_ENABLED
    assert sw & TARGET_REACHED and sw & BIT12
    assert not sw & MOTOR_RUNNING
    assert m.read32(ACTUAL_VELOCITY) == 0
    # 20 rev at 5 r/s plus one ramp time (0.5 s): 4.5 s of motion, in real time.
    assert 4.0 < elapsed < 7.0, elapsed
    assert running and seen


def test_position_mode_two_points_without_stopping(start_drive, transport):
    """6.1 "多点运动，两点间不需要停留", the manual's controlwords 0x025F /
    0x024F: bit 9 = 1, bit 5 = 0 — the motor reaches the first target at
    5 r/s and carries on at 10 r/s. They also set bit 6 (relative, SPEC
    §8.4): 0 + 200000, then 200000 + 600000 = 800000."""
    d = start_drive("--no-status")
    m = Master(d.client(transport))
    m.enable()
    m.write(MODE, 1)
    m.write(ACCELERATION, 100)
    m.write(DECELERATION, 100)
    m.write32(PROFILE_VELOCITY, 50)
    m.write32(TARGET_POSITION, 200000)
    m.write(CONTROLWORD, 0x025F)
    m.write(CONTROLWORD, 0x024F)
    m.wait(lambda s: s & MOTOR_RUNNING, 2, "motor running")
    m.write32(PROFILE_VELOCITY, 100)
    m.write32(TARGET_POSITION, 600000)
    m.write(CONTROLWORD, 0x025F)
    # Sample velocity while passing the first target: it never drops to 0.
    velocities = []
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        pos = m.read32(ACTUAL_POSITION)
        vel = m.read32(ACTUAL_VELOCITY)
        if 150000 < pos < 450000:
            velocities.append(vel)
        if settled(m.statusword()):
            break
    assert m.read32(ACTUAL_POSITION) == 800000
    assert velocities and min(velocities) > 0, velocities
    assert max(velocities) > 500, "second segment at 10 r/s = 600 r/min"


def test_velocity_mode(start_drive, transport):
    """6.2: 0x010F holds, 0x000F runs, a new 0x6081 ramps to the new speed,
    0x010F stops again (SPEC §8.5)."""
    d = start_drive("--no-status")
    m = Master(d.client(transport))
    m.enable()
    m.write(MODE, 3)
    assert m.read_i16(MODE_DISPLAY) == 3
    m.write(CONTROLWORD, 0x010F)
    m.write32(PROFILE_VELOCITY, 10)  # 1 r/s
    m.write(ACCELERATION, 100)
    m.write(DECELERATION, 100)
    time.sleep(0.2)
    assert m.read32(ACTUAL_VELOCITY) == 0, "halted"
    m.write(CONTROLWORD, 0x000F)
    m.wait(lambda s: s & TARGET_REACHED, 3, "target velocity reached")
    assert m.read32(ACTUAL_VELOCITY) == 60  # 1 r/s = 60 r/min
    m.write32(PROFILE_VELOCITY, 100)  # 10 r/s, reached after 0.9 s at 10 r/s²
    time.sleep(0.2)
    assert 60 < m.read32(ACTUAL_VELOCITY) < 600, "ramping, not jumping"
    m.wait(lambda s: s & TARGET_REACHED, 3, "new target velocity reached")
    assert m.read32(ACTUAL_VELOCITY) == 600
    p1 = m.read32(ACTUAL_POSITION)
    time.sleep(0.2)
    assert m.read32(ACTUAL_POSITION) > p1 + 10000, "running at 100000 steps/s"
    m.write(CONTROLWORD, 0x010F)
    m.wait(lambda s: s & HALT and s & BIT12, 3, "speed 0 under halt")
    assert m.read32(ACTUAL_VELOCITY) == 0
    p2 = m.read32(ACTUAL_POSITION)
    time.sleep(0.2)
    assert m.read32(ACTUAL_POSITION) == p2, "stopped"


def test_homing_method_1_to_the_cw_limit(start_drive, transport):
    """6.3 with the manual's parameters: method 1, 100 r/s² ramps, 10 r/s
    (capped at 300 r/min for methods 1-4), offset 1000 at 10 r/s. The CW
    limit sits at -20000 steps: the origin is its edge, the drive moves to
    origin + 1000 and calls that 0 (SPEC §8.6)."""
    d = start_drive("--no-status", "--cw-limit", "-20000", "--ccw-limit", "500000")
    m = Master(d.client(transport))
    m.enable()
    m.write(MODE, 6)
    m.write(HOMING_METHOD, 1)
    m.write(HOMING_ACCELERATION, 1000)
    m.write32(HOMING_SPEED, 100, signed=False)
    m.write32(HOMING_ZERO_SPEED, 100, signed=False)
    m.write32(HOME_OFFSET, 1000)
    m.write(CONTROLWORD, 0x001F)
    seen = m.wait(lambda s: s & BIT12 and s & TARGET_REACHED, 10, "homing done (bits 12, 10)")
    assert any(s & MOTOR_RUNNING for s in seen), "it moved"
    sw = m.statusword()
    assert not sw & BIT13, "no homing error"
    assert m.read32(ACTUAL_POSITION) == 0
    assert not sw & CW_LIMIT, "1000 steps off the limit"
    # The origin is exactly the limit edge: in position mode, -1000 is the
    # edge (the switch is active there) and -999 is not.
    m.write(CONTROLWORD, 0x000F)
    m.write(MODE, 1)
    m.write32(PROFILE_VELOCITY, 10)
    m.write(ACCELERATION, 100)
    m.write(DECELERATION, 100)
    m.write(QUICK_STOP_DECELERATION, 1000)
    for target, limit in ((-999, False), (-1000, True)):
        m.write32(TARGET_POSITION, target)
        m.write(CONTROLWORD, 0x001F)
        m.write(CONTROLWORD, 0x000F)
        m.wait(lambda s: not s & MOTOR_RUNNING and (s & TARGET_REACHED or s & CW_LIMIT), 5,
               f"move to {target}")
        assert m.read32(ACTUAL_POSITION) == target
        assert bool(m.statusword() & CW_LIMIT) == limit, target
    assert not m.statusword() & CCW_LIMIT
