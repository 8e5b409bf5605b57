"""A position move on both images, checked through the registers (0x6064,
0x6041, SPEC §8) and by the step pulses the firmware's timer put on the STEP
pin (`--trace-steps`), and the RS-485 driver enable around every reply
(`--trace-line`)."""

import csv
import time

from conftest import (ACCELERATION, ACTUAL_POSITION, CONTROLWORD, DECELERATION, MODE,
                      MOTOR_RUNNING, OPERATION_ENABLED, PROFILE_VELOCITY, STATE_MASK,
                      TARGET_POSITION, TARGET_REACHED, Master)

DISTANCE = 2000


def settled(sw):
    return sw & TARGET_REACHED and not sw & MOTOR_RUNNING


def read_csv(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def test_position_move_counts_its_pulses(start_fw, board, tmp_path):
    steps = tmp_path / "steps.csv"
    fw = start_fw(board, "--trace-steps", str(steps))
    m = Master(fw.client())
    m.enable()
    m.write(MODE, 1)
    m.write32(PROFILE_VELOCITY, 50)  # 5 r/s
    m.write(ACCELERATION, 100)
    m.write(DECELERATION, 100)
    m.write32(TARGET_POSITION, DISTANCE)
    m.write(CONTROLWORD, 0x001F)
    m.write(CONTROLWORD, 0x000F)
    m.wait(settled, 10, "target reached")
    assert m.read32(ACTUAL_POSITION) == DISTANCE
    sw = m.statusword()
    assert sw & STATE_MASK == OPERATION_ENABLED and sw & TARGET_REACHED
    fw.alive()
    pulses = read_csv(steps)
    assert len(pulses) == DISTANCE, f"{board}: {len(pulses)} pulses for {DISTANCE} steps"
    assert {p["dir"] for p in pulses} == {"1"}, "one direction throughout"
    times = [int(p["time_ns"]) for p in pulses]
    assert times == sorted(times)
    assert all(int(p["width_ns"]) > 0 for p in pulses)
    # the move back: as many pulses, the other direction
    m.write32(TARGET_POSITION, 0)
    m.write(CONTROLWORD, 0x001F)
    m.write(CONTROLWORD, 0x000F)
    m.wait(settled, 10, "back at 0")
    assert m.read32(ACTUAL_POSITION) == 0
    pulses = read_csv(steps)
    assert len(pulses) == 2 * DISTANCE
    assert {p["dir"] for p in pulses[DISTANCE:]} == {"0"}


def test_driver_enable_brackets_every_reply(start_fw, board, tmp_path):
    """DE rises before a reply's first start bit and falls after its last
    stop bit; the receiver hears the next request (SPEC §1)."""
    line = tmp_path / "line.csv"
    fw = start_fw(board, "--trace-line", str(line))
    m = Master(fw.client())
    for _ in range(3):
        m.statusword()
    time.sleep(0.1)  # the last DE fall is written once emulated time reaches it
    fw.alive()
    ev = sorted(((int(r["time_ns"]), r["event"], int(r["value"])) for r in read_csv(line)),
                key=lambda e: e[0])
    de = [(t, v) for t, e, v in ev if e == "de"]
    tx = [t for t, e, _ in ev if e == "tx"]
    assert len(tx) == 3 * 7, f"{board}: three 7-byte replies"
    assert [v for _, v in de] == [1, 0] * 3, f"{board}: DE edges {de}"
    char_ns = 10 * 1e9 / 115200
    for i in range(3):
        rise, fall = de[2 * i][0], de[2 * i + 1][0]
        reply = tx[7 * i: 7 * i + 7]
        assert rise <= reply[0], "DE up before the first start bit"
        assert fall >= reply[-1] + char_ns - 1, "DE down after the last stop bit"
        rx_next = [t for t, e, _ in ev if e == "rx" and t > fall]
        if i < 2:
            assert rx_next, "the next request comes after DE fell"
