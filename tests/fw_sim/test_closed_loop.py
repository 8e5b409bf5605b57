"""The closed loop (SPEC §8.8) on both firmware images: fw-sim's motor turns
an encoder whose A and B reach TIM4 in encoder mode through PB6 / PB7
(docs/fw-sim.md), driven by the STEP pulses the image puts out, with the
virtual drive's motor faults (--stall-at, --slip, --encoder-noise). The
scenarios and their bounds are tests/e2e/test_closed_loop.py's: a stall
faults the drive (following error, bit 13, 0x1001 bit 5), fault reset and
re-enable take the measured position and a move back ends on the motor; a
slip below the window runs on, one above it faults; with the window off a
stall only shows the error. Unlike the virtual drive's --encoder, fw-sim
cannot set the firmware's PA17: the test writes it, as commissioning does.
"""

import time

from conftest import (ACTUAL_POSITION, BIT13, CONTROLWORD, OPERATION_ENABLED, STATE_MASK, SWITCH_ON_DISABLED, TARGET_REACHED,
                      Master, e2e_module)

e2e = e2e_module("test_closed_loop")
move_to, dp_epo = e2e.move_to, e2e.dp_epo
WINDOW, TIMEOUT = e2e.FOLLOWING_ERROR_WINDOW, e2e.FOLLOWING_ERROR_TIMEOUT
ERROR_ACTUAL, DP_ERR, PA17 = e2e.FOLLOWING_ERROR_ACTUAL, e2e.DP_ERR, e2e.PA17
ERROR_REGISTER_ADDR = e2e.ERROR_REGISTER
FAULT_MASK, FAULT = e2e.FAULT_MASK, e2e.FAULT
# fw-sim's default encoder: 4000 counts per revolution (a 1000-line one)
COUNTS = 4000
# emulated time runs behind wall time while the image steps fast
WAIT_S = 30


def commission(m: Master, window: int = 200):
    m.write(PA17, COUNTS)
    m.write32(WINDOW, window, signed=False)
    m.write(TIMEOUT, 10)


def settled(sw):
    return sw & TARGET_REACHED and sw & STATE_MASK == OPERATION_ENABLED


def test_a_stall_faults_the_drive_and_fault_reset_and_re_enable_work(start_fw, board):
    fw = start_fw(board, "--stall-at", "20000")
    m = Master(fw.client())
    commission(m)
    m.enable()
    move_to(m, 100_000)
    m.wait(lambda s: s & FAULT_MASK == FAULT, WAIT_S, f"{board}: the following-error fault")
    sw = m.statusword()
    assert sw & BIT13, hex(sw)
    assert m.read(ERROR_REGISTER_ADDR) == 1 << 5
    assert m.read(DP_ERR) & 0xFF == 1 << 5
    # the motor stands at the stall; the steps sent past it are the error
    assert abs(m.read32(ACTUAL_POSITION) - 20_000) <= 2
    error = m.read32(ERROR_ACTUAL)
    assert 2_000 < error < 5_000, error
    assert dp_epo(m) == error

    m.write(CONTROLWORD, 0x0000)
    m.write(CONTROLWORD, 0x0080)
    sw = m.statusword()
    assert sw & STATE_MASK == SWITCH_ON_DISABLED and not sw & BIT13, hex(sw)
    assert m.read(ERROR_REGISTER_ADDR) == 0
    m.enable()
    # re-enabling takes the measured position: no error left
    assert abs(m.read32(ERROR_ACTUAL)) <= 2
    move_to(m, 0)
    m.wait(settled, WAIT_S, f"{board}: the move back")
    time.sleep(0.05)
    assert not m.statusword() & BIT13
    assert abs(m.read32(ACTUAL_POSITION)) <= 2
    fw.alive()


def test_a_slip_below_the_window_runs_on_and_one_above_it_faults(start_fw, board):
    for slip, faults in (("150@30000", False), ("500@30000", True)):
        fw = start_fw(board, "--slip", slip, "--encoder-noise", "2")
        m = Master(fw.client())
        commission(m)
        m.enable()
        move_to(m, 100_000)
        if faults:
            m.wait(lambda s: s & FAULT_MASK == FAULT, WAIT_S, f"{board}: the fault")
            assert m.statusword() & BIT13
            assert m.read(ERROR_REGISTER_ADDR) == 1 << 5
        else:
            m.wait(settled, WAIT_S, f"{board}: the end of the move")
            time.sleep(0.05)
            sw = m.statusword()
            assert sw & STATE_MASK == OPERATION_ENABLED and not sw & BIT13, hex(sw)
            assert m.read(ERROR_REGISTER_ADDR) == 0
            # the e2e test's bounds: ±2 counts of noise on the reference
            # reading and on the last are ±10 steps, plus two roundings
            err, pos = m.read32(ERROR_ACTUAL), m.read32(ACTUAL_POSITION)
            assert 139 <= err <= 161, err
            assert 99_839 <= pos <= 99_861, pos
        fw.alive()
        fw.stop()


def test_with_the_window_off_a_stall_shows_the_error_and_does_not_fault(start_fw, board):
    fw = start_fw(board, "--stall-at", "20000")
    m = Master(fw.client())
    commission(m, window=0xFFFF_FFFF)
    m.enable()
    move_to(m, 40_000)
    m.wait(settled, WAIT_S, f"{board}: the end of the move")
    sw = m.statusword()
    assert not sw & BIT13, hex(sw)
    assert m.read(ERROR_REGISTER_ADDR) == 0
    # the motor stayed at the stall: every step after it is the error
    assert abs(m.read32(ACTUAL_POSITION) - 20_000) <= 2
    assert abs(m.read32(ERROR_ACTUAL) - 20_000) <= 2
    fw.alive()


def test_without_pa17_the_drive_stays_open_loop(start_fw, board):
    """No PA17: the image leaves TIM4 alone and shows the commanded count,
    even though the motor stalled."""
    fw = start_fw(board, "--stall-at", "2000")
    m = Master(fw.client())
    m.write32(WINDOW, 200, signed=False)
    m.write(TIMEOUT, 10)
    m.enable()
    move_to(m, 10_000)
    m.wait(settled, WAIT_S, f"{board}: the end of the move")
    assert m.read32(ACTUAL_POSITION) == 10_000
    assert m.read32(ERROR_ACTUAL) == 0
    assert not m.statusword() & BIT13
    fw.alive()
