"""Closed loop as a commissioning engineer tries it (SPEC §8.8): the virtual
drive's simulated encoder with a stall, the following-error fault it raises,
and fault reset and re-enable afterwards."""

import time

from conftest import (ACCELERATION, ACTUAL_POSITION, BIT13, CONTROLWORD, DECELERATION, MODE,
                      OPERATION_ENABLED, PROFILE_VELOCITY, QUICK_STOP_DECELERATION, STATE_MASK,
                      SWITCH_ON_DISABLED, TARGET_POSITION, TARGET_REACHED, Master)

FOLLOWING_ERROR_WINDOW = 0x6065
FOLLOWING_ERROR_TIMEOUT = 0x6066
FOLLOWING_ERROR_ACTUAL = 0x60F4
ERROR_REGISTER = 0x1001
DP_EPO = 0x0005  # DP-EPo low word, DP-EPo. high word (SPEC §9)
DP_ERR = 0x0013
PA17 = 0x0064 + 17
FAULT_MASK = 0x004F  # bit 5 is open in the fault states (SPEC §8.1)
FAULT = 0x0008


def move_to(m: Master, target: int):
    """Position mode, 10 r/s, 100 r/s² ramps, 0x6085 = 200 r/s²; latches
    `target` with a bit 4 edge (SPEC §8.4)."""
    m.write(MODE, 1)
    m.write32(PROFILE_VELOCITY, 100)
    m.write(ACCELERATION, 1000)
    m.write(DECELERATION, 1000)
    m.write(QUICK_STOP_DECELERATION, 2000)
    m.write32(TARGET_POSITION, target)
    m.write(CONTROLWORD, 0x001F)
    m.write(CONTROLWORD, 0x000F)


def dp_epo(m: Master) -> int:
    r = m.c.read_holding_registers(DP_EPO, count=2, device_id=m.id)
    assert not r.isError(), r
    low, high = r.registers
    v = (high << 16) | low
    return v - (1 << 32) if v & 0x8000_0000 else v


def test_a_stall_faults_the_drive_and_fault_reset_and_re_enable_work(start_drive):
    d = start_drive("--no-status", "--stall-at", "20000", pty=False)
    m = Master(d.client("tcp"))
    assert m.read(PA17) == 4000, "--encoder sets PA17 when the drive has none"
    m.write32(FOLLOWING_ERROR_WINDOW, 200, signed=False)
    m.write(FOLLOWING_ERROR_TIMEOUT, 10)
    m.enable()
    move_to(m, 100_000)
    m.wait(lambda s: s & FAULT_MASK == FAULT, 5, "the following-error fault")
    sw = m.statusword()
    assert sw & BIT13, hex(sw)
    assert m.read(ERROR_REGISTER) == 1 << 5
    # DP-Err bits 0..7 are 0x1001; bit 8 says the store was blank at boot
    assert m.read(DP_ERR) & 0xFF == 1 << 5
    # the motor stands at the stall; the steps sent past it are the error
    assert abs(m.read32(ACTUAL_POSITION) - 20_000) <= 2
    error = m.read32(FOLLOWING_ERROR_ACTUAL)
    assert 2_000 < error < 5_000, error
    assert dp_epo(m) == error
    assert "fault: FollowingError" in d.stderr()

    m.write(CONTROLWORD, 0x0000)
    m.write(CONTROLWORD, 0x0080)
    sw = m.statusword()
    assert sw & STATE_MASK == SWITCH_ON_DISABLED and not sw & BIT13, hex(sw)
    assert m.read(ERROR_REGISTER) == 0
    m.enable()
    # re-enabling takes the measured position: no error left
    assert abs(m.read32(FOLLOWING_ERROR_ACTUAL)) <= 2
    move_to(m, 0)
    m.wait(lambda s: s & TARGET_REACHED and s & STATE_MASK == OPERATION_ENABLED, 5,
           "the move back")
    time.sleep(0.05)
    assert not m.statusword() & BIT13
    assert abs(m.read32(ACTUAL_POSITION)) <= 2


def test_a_slip_below_the_window_runs_on_and_one_above_it_faults(start_drive):
    """A drive slipping 150 steps (window 200: no fault,
    the error stays), and one slipping 500 (fault, bit 13, 0x1001 bit 5)."""
    for slip, faults in (("150@30000", False), ("500@30000", True)):
        d = start_drive("--no-status", "--slip", slip, "--encoder-noise", "2", pty=False)
        m = Master(d.client("tcp"))
        m.write32(FOLLOWING_ERROR_WINDOW, 200, signed=False)
        m.write(FOLLOWING_ERROR_TIMEOUT, 10)
        m.enable()
        move_to(m, 100_000)
        if faults:
            m.wait(lambda s: s & FAULT_MASK == FAULT, 5, "the following-error fault")
            assert m.statusword() & BIT13
            assert m.read(ERROR_REGISTER) == 1 << 5
        else:
            m.wait(lambda s: s & TARGET_REACHED and s & STATE_MASK == OPERATION_ENABLED, 5,
                   "the end of the move")
            time.sleep(0.05)
            sw = m.statusword()
            assert sw & STATE_MASK == OPERATION_ENABLED and not sw & BIT13, hex(sw)
            assert m.read(ERROR_REGISTER) == 0
            # two noisy readings count: the one the encoder's reference was
            # taken from at enable and the last; ±2 counts each are ±10
            # steps at 4000 counts / 10 000 steps, and each of the two
            # count-to-step conversions rounds down by less than a step
            err, pos = m.read32(FOLLOWING_ERROR_ACTUAL), m.read32(ACTUAL_POSITION)
            assert 139 <= err <= 161, err
            assert 99_839 <= pos <= 99_861, pos
        d.stop()
