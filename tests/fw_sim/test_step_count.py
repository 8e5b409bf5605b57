"""Every STEP pulse is a counted step: long moves at the top step rates
with the acceleration of a real axis (0x6083 = 0x6084 = 2000) put exactly
as many pulses on the emulated STEP pin (`--trace-steps`) as 0x6064 counts
(SPEC §8). A DMA refill that came a buffer half late would let the timer
play entries of the half before (pulses the position never counts); the
firmware counts and logs such a refill."""

import csv
import time

import pytest

from conftest import (ACCELERATION, ACTUAL_POSITION, CONTROLWORD, DECELERATION, LIMITS, MODE,
                      MOTOR_RUNNING, PA_BASE, PROFILE_VELOCITY, TARGET_POSITION, TARGET_REACHED,
                      Master, pulse_for)

ACCEL = 2000  # 0.1 r/s²: 200 r/s², 2 000 000 steps/s² at 10000 steps/rev


def settled(sw):
    return sw & TARGET_REACHED and not sw & MOTOR_RUNNING


# steps/s at 10000 steps/rev; each board at its top rate
# (Board::max_step_rate), with the widest STEP pulse that rate allows
@pytest.mark.parametrize("board,rate", [("f103", 100_000), ("f103", LIMITS["f103"]),
                                        ("g431", LIMITS["g431"])])
def test_pulses_equal_the_position_at_the_top_rate(start_fw, tmp_path, board, rate):
    steps = tmp_path / "steps.csv"
    velocity = rate * 10 // 10_000  # 0x6081, 0.1 r/s
    # ramps at 2e6 steps/s² and a cruise of at least 5000 steps
    distance = max(25_000, rate * rate // 2_000_000 + 5_000)
    fw = start_fw(board, "--trace-steps", str(steps))
    m = Master(fw.client())
    m.enable()
    m.write(PA_BASE + 15, pulse_for(rate))
    m.write(MODE, 1)
    m.write32(PROFILE_VELOCITY, velocity)
    m.write(ACCELERATION, ACCEL)
    m.write(DECELERATION, ACCEL)
    m.write32(TARGET_POSITION, distance)
    m.write(CONTROLWORD, 0x001F)
    m.write(CONTROLWORD, 0x000F)
    m.wait(settled, 20, "target reached")
    assert m.read32(ACTUAL_POSITION) == distance
    # no wait: 0x6064 and target reached follow the pin (StepSchedule::pin_lag)
    fw.alive()
    with open(steps) as f:
        pulses = list(csv.DictReader(f))
    assert len(pulses) == distance, f"{board}: {len(pulses)} pulses for 0x6064 = {distance}"
    # the mechanism itself: the refill kept ahead of the DMA throughout
    assert "refill(s) came a buffer half late" not in fw.stderr(), fw.stderr()


def pin_positions(steps_csv):
    """(time_ns, position) after each traced pulse."""
    pos, out = 0, []
    with open(steps_csv) as f:
        for row in csv.DictReader(f):
            pos += 1 if row["dir"] == "1" else -1
            out.append((int(row["time_ns"]), pos))
    return out


def statusword_replies(line_csv):
    """(time_ns of the first byte, statusword) of every FC03 one-register
    reply the firmware sent (characters closer than 1 ms are one frame)."""
    frames, cur, last = [], [], None
    with open(line_csv) as f:
        for row in csv.DictReader(f):
            if row["event"] != "tx":
                continue
            t = int(row["time_ns"])
            if last is not None and t - last > 1_000_000:
                frames.append(cur)
                cur = []
            cur.append((t, int(row["value"])))
            last = t
    frames.append(cur)
    return [(fr[0][0], fr[3][1] << 8 | fr[4][1]) for fr in frames
            if len(fr) == 7 and [b for _, b in fr[:3]] == [1, 3, 2]]


@pytest.mark.parametrize("board", ["g431", "f103"])
def test_target_reached_waits_for_the_last_pulse(start_fw, tmp_path, board):
    """The engine is handed steps ahead of its timer; 0x6041 must not say
    "target reached, at rest" while pulses of the move are still to come.
    Moves back and forth between 0 and 3000, the statusword read back to
    back: every reply that shows the move done finds the STEP pin at one
    of the two targets."""
    steps, line = tmp_path / "steps.csv", tmp_path / "line.csv"
    fw = start_fw(board, "--trace-steps", str(steps), "--trace-line", str(line))
    m = Master(fw.client())
    m.enable()
    m.write(MODE, 1)
    m.write32(PROFILE_VELOCITY, 200)
    m.write(ACCELERATION, ACCEL)
    m.write(DECELERATION, ACCEL)
    for k in range(12):
        m.write32(TARGET_POSITION, 3000 if k % 2 == 0 else 0)
        m.write(CONTROLWORD, 0x001F)
        m.write(CONTROLWORD, 0x000F)
        deadline = time.monotonic() + 20
        while not settled(m.statusword()):
            assert time.monotonic() < deadline, "move never ended"
    time.sleep(0.1)
    fw.alive()
    pins = pin_positions(steps)
    assert pins and pins[-1][1] == 0
    done = [(t, sw) for t, sw in statusword_replies(line) if settled(sw)]
    assert len(done) >= 12
    for t, sw in done:
        at = 0
        for tp, p in pins:
            if tp >= t:
                break
            at = p
        assert at in (0, 3000), f"{board}: {sw:#06x} sent at {t} ns with the pin at {at}"
