"""A position move on both images, checked through the registers (0x6064,
0x6041, SPEC §8) and by the step pulses the firmware's timer put on the STEP
pin (`--trace-steps`), and the RS-485 driver enable around every reply
(`--trace-line`)."""

import csv
import os
import subprocess
import time
from pathlib import Path


from conftest import (ROOT, TICK_NS, LIMITS, PA_BASE, ACCELERATION, ACTUAL_POSITION, CONTROLWORD,
                      DECELERATION, MODE, MOTOR_RUNNING, OPERATION_ENABLED, PROFILE_VELOCITY,
                      STATE_MASK, TARGET_POSITION, TARGET_REACHED, Master, pulse_for)

DISTANCE = 2000
SCHEDULE = Path(os.environ.get("FW_SIM_SCHEDULE_BIN")
                or ROOT / "target" / "debug" / "examples" / "step_schedule")


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
    # the firmware counts a step when it loads it into the timer: the pin
    # lags the position by up to one step period (src/firmware/steps.rs)
    time.sleep(0.05)
    fw.alive()
    pulses = read_csv(steps)
    assert len(pulses) == DISTANCE, f"{board}: {len(pulses)} pulses for {DISTANCE} steps"
    assert {p["dir"] for p in pulses} == {"1"}, "one direction throughout"
    times = [int(p["time_ns"]) for p in pulses]
    assert times == sorted(times)
    # the timers run from the emulated clock: the shortest period is the
    # triangle's peak, 2000 steps at 10 r/s² (100000 steps/s²) reach
    # sqrt(2000 * 100000) steps/s, 70.7 µs; the move lasts 2 * sqrt(2000 /
    # 100000) s less one step period
    shortest = min(b - a for a, b in zip(times, times[1:]))
    assert 70_000 <= shortest <= 72_000, f"{board}: shortest period {shortest} ns"
    assert 270e6 < times[-1] - times[0] < 283e6, f"{board}: {times[-1] - times[0]} ns"

    assert all(int(p["width_ns"]) > 0 for p in pulses)
    # the move back: as many pulses, the other direction
    m.write32(TARGET_POSITION, 0)
    m.write(CONTROLWORD, 0x001F)
    m.write(CONTROLWORD, 0x000F)
    m.wait(settled, 10, "back at 0")
    assert m.read32(ACTUAL_POSITION) == 0
    time.sleep(0.05)
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


def host_schedule(board: str, distance: int, v: int, a: int, d: int) -> list[int]:
    """Step ticks relative to the first, from the core's planner at the
    board's step tick (examples/step_schedule.rs)."""
    out = subprocess.run([str(SCHEDULE), board, str(distance), str(v), str(a), str(d)],
                         capture_output=True, text=True, timeout=60, check=True).stdout
    return [int(x) for x in out.split()]


def traced_move(start_fw, board, tmp_path) -> list[int]:
    """The STEP pin's rising edges (ns) of a 2000-step move at 50 000
    steps/s with 100 000 steps/s² ramps."""
    steps = tmp_path / "steps.csv"
    m = Master(start_fw(board, "--trace-steps", str(steps)).client())
    m.enable()
    m.write(MODE, 1)
    m.write32(PROFILE_VELOCITY, 50)
    m.write(ACCELERATION, 100)
    m.write(DECELERATION, 100)
    m.write32(TARGET_POSITION, DISTANCE)
    m.write(CONTROLWORD, 0x001F)
    m.write(CONTROLWORD, 0x000F)
    m.wait(settled, 10, "target reached")
    time.sleep(0.05)
    return [int(p["time_ns"]) for p in read_csv(steps)]


def test_pulses_follow_the_hosts_step_schedule(start_fw, board, tmp_path):
    """Issue's step-output bound: every pulse from the second on is where
    the core's planner puts it (relative to the second), within one tick
    of the board's step timer."""
    tick_ns = TICK_NS[board]
    host = host_schedule(board, DISTANCE, 50_000, 100_000, 100_000)
    pin = traced_move(start_fw, board, tmp_path)
    assert len(pin) == len(host) == DISTANCE
    for k in range(1, DISTANCE):
        got = (pin[k] - pin[1]) / tick_ns
        want = host[k] - host[1]
        assert abs(got - want) <= 1, f"{board}: step {k} at {got} ticks, schedule {want}"


def test_the_first_interval_follows_the_hosts_step_schedule(start_fw, board, tmp_path):
    """From rest the planner queues only the first step at first; the step
    timer, which preloads, asks for the second while the first one's period
    runs, finds none and preloads an idle period. The second step, found at
    the first pulse, is due its interval after it and the idle period
    counts towards it (calc::StepShaper): the gap is the schedule's."""
    tick_ns = TICK_NS[board]
    host = host_schedule(board, DISTANCE, 50_000, 100_000, 100_000)
    pin = traced_move(start_fw, board, tmp_path)
    got = (pin[1] - pin[0]) / tick_ns
    assert abs(got - (host[1] - host[0])) <= 1, f"{board}: {got} ticks, schedule {host[1] - host[0]}"


def trapezoid_s(dist: int, v: float, a: float, k: int) -> float:
    """The continuous trapezoid from rest to rest over `dist` steps, cruise
    `v`, acceleration and deceleration `a` (steps/s, steps/s²): the time (s)
    at which it reaches position `k` (tests/common/axis.rs
    `trapezoid_time`, equal ramps)."""
    xa = min(v * v / (2 * a), dist / 2)
    vp = (2 * a * xa) ** 0.5
    ta, tc = vp / a, (dist - 2 * xa) / vp
    if k <= xa:
        return (2 * k / a) ** 0.5
    if k <= dist - xa:
        return ta + (k - xa) / vp
    return ta + tc + ta - (2 * max(dist - k, 0) / a) ** 0.5


def test_a_move_at_the_top_rate_keeps_every_pulse_within_2us_of_the_trapezoid(
        start_fw, board, tmp_path):
    """The step engine's bound on the pin itself: a position move at the
    board's step rate limit (Board::max_step_rate) with 2 000 000 steps/s²
    ramps, PA12 = 6000 r/min and PA10 = 10 000 (its default), the master
    polling the statusword throughout. As many pulses as steps, and every
    pulse within 2 µs of the ideal trapezoid's time for its step (from the
    trapezoid's start that fits the pulses best: the start of a move is not
    on the pin)."""
    rate, accel = LIMITS[board], 2_000_000
    distance = rate * rate // accel + 2_000  # the ramps and a cruise
    steps = tmp_path / "steps.csv"
    m = Master(start_fw(board, "--trace-steps", str(steps), "--quiet").client())
    assert m.read(PA_BASE + 10) == 10_000
    m.enable()
    m.write(MODE, 1)
    m.write(PA_BASE + 12, 6000)
    m.write(PA_BASE + 15, pulse_for(rate))
    # 0x6081 in 0.1 r/s, 0x6083 / 0x6084 in 0.1 r/s² (SPEC §5)
    m.write32(PROFILE_VELOCITY, rate // 1000)
    m.write(ACCELERATION, accel // 1000)
    m.write(DECELERATION, accel // 1000)
    m.write32(TARGET_POSITION, distance)
    m.write(CONTROLWORD, 0x001F)
    m.write(CONTROLWORD, 0x000F)
    polls = len(m.wait(settled, 60, "target reached"))
    assert m.read32(ACTUAL_POSITION) == distance
    time.sleep(0.2)  # the trace is written as emulated time passes
    pin = [int(p["time_ns"]) for p in read_csv(steps)]
    assert len(pin) == distance, f"{board}: {len(pin)} pulses for {distance} steps"
    off = [t - trapezoid_s(distance, rate, accel, k + 1) * 1e9 for k, t in enumerate(pin)]
    start = (max(off) + min(off)) / 2
    worst = max(abs(o - start) for o in off)
    print(f"{board}: {distance} pulses at up to {rate} steps/s, {polls} reads during the "
          f"move; worst {worst:.0f} ns from the trapezoid")
    assert polls > 10, "the master polled throughout"
    assert worst <= 2_000, f"{board}: a pulse {worst:.0f} ns from the trapezoid"
