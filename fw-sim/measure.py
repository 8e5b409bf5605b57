#!/usr/bin/env python3
"""Measurements of both firmware images from emulated time (fw-sim), written
to docs/generated/fw-sim.md. Run after building the images and the runner
(`bash .ci/fw-sim.sh` does both):

    .venv/e2e/bin/python fw-sim/measure.py

- reply latency: from the end of a request's last stop bit to the start bit
  of the reply's first character (`--trace-line`), at 115200 and 19200 baud,
  and at 115200 while the motor runs at the board's step rate limit;
- CPU load at rest and while stepping in velocity mode at 50k, 190k, 200k
  steps/s and the board's step rate limit (Board::max_step_rate in
  src/boards.rs; 190k is a period of a whole number of ticks and a fraction
  on both boards, the others whole):
  the share of core cycles not spent asleep in WFI/WFE (`--stats`), under the
  runner's one-cycle-per-instruction assumption (docs/fw-sim.md, "Time");
- core cycles a step on ramps: a position move at the board's limit that
  is all ramp, under `--profile`, the instructions a step of the planner,
  the expansion, the integer helpers and the refill side;
- the highest step rate at which every pulse is on time: position moves at
  0x6081 rising to the board's limit, each traced pulse (`--trace-steps`)
  compared with the core planner's schedule for the same move at the board's
  step tick (examples/step_schedule.rs) within one tick;
- the step engine's DMA refills under a flood: a move at the highest rate
  the board keeps on time while the master floods the bus with reads, and
  the firmware's own count of refills that came too late (its log line
  `step engine: N refill(s) came a buffer half late`).

- the window after reset in which the safety outputs are not yet driven:
  core cycles from the reset vector until ENABLE, BRAKE, STEP and DE are
  all outputs (`--trace-pins`).

`--only flood` runs the flood section alone, taking each board's
rate from the docs/generated/fw-sim.md of an earlier full run, and prints
it without writing the file; `--only reset` runs the reset-window section
alone and prints it.

`--only stepping-latency` prints the reply latency while stepping at each
board's limit, likewise without writing the file; `--only ramp-cost` the
core cycles a step on ramps.
"""

from __future__ import annotations

import argparse
import csv
import os
import re
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from pymodbus.exceptions import ModbusIOException

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "fw_sim"))
import conftest as c  # noqa: E402  (the test harness: runner, master, register names)

OUT = ROOT / "docs" / "generated" / "fw-sim.md"
BAUD_PA52 = c.PA_BASE + 52
REQUESTS = 20
# reads while stepping at the limit: enough that a reply meeting a control
# part and a refill at once shows in the tail
STEPPING_REQUESTS = 500
# the reply latency the step engine's issue asks for while stepping: t3.5 +
TARGET_OVER_T35_US = 50
# the planner's ceiling for each board, read from the source it lives in:
# MAX_STEP_RATE at the ring length the board's image is built with (the
# feature long-schedule or longer-schedule, in its Cargo feature)
def _ceilings() -> dict[str, int]:
    src = (ROOT / "src" / "motion" / "planner" / "mod.rs").read_text()
    rate = {}  # the ring feature a cfg asks for (None: neither) -> its ceiling
    for cfg, value in re.findall(r"#\[cfg\((.*)\)\]\npub const MAX_STEP_RATE: u32 = ([0-9_]+);", src):
        wanted = re.findall(r'feature = "([a-z-]+)"', re.sub(r'not\(feature = "[a-z-]+"\)', "", cfg))
        rate[wanted[0] if wanted else None] = int(value)
    cargo = (ROOT / "Cargo.toml").read_text()
    def ring(board: str) -> str | None:
        features = re.search(rf"^board-{board} = \[(.*)\]$", cargo, re.M)[1]
        return next((f for f in ("longer-schedule", "long-schedule") if f'"{f}"' in features), None)
    return {b: rate[ring(b)] for b in c.BOARDS}


MAX_STEP_RATE = _ceilings()


# each board's step rate limit (Board::max_step_rate in src/boards.rs): the
# firmware clamps faster set-points to it, so nothing faster can be measured
LIMITS = c.LIMITS
RATES = {b: sorted({0, 50_000, 190_000, 200_000, LIMITS[b]}) for b in c.BOARDS}
# the planner's steepest ramp (MAX_ACCEL, steps/s²): the shortest moves
# that reach each rate
MAX_ACCEL = int(re.search(r"pub const MAX_ACCEL: u64 = ([0-9_]+);",
                          (ROOT / "src" / "motion" / "planner" / "mod.rs").read_text())[1])
# the rates the on-time section tries, and the grid the boards' limits are
# rounded down to (Board::max_step_rate)
STEP_GRID = 50_000
ON_TIME_RATES = {b: list(range(STEP_GRID, LIMITS[b] + 1, STEP_GRID)) for b in c.BOARDS}
CRUISE_STEPS = 2_000  # steps at the top rate in each move
# the step timer's tick (Board::step_tick_hz in src/boards.rs)
TICK_NS = c.TICK_NS
SCHEDULE = Path(os.environ.get("FW_SIM_SCHEDULE_BIN")
                or ROOT / "target" / "debug" / "examples" / "step_schedule")
STEPS_PER_REV = 10_000  # PA10 default (SPEC §7)
# EE-Set (SPEC §9): the parameters saved, new format, k = 1
EE_SET = c.with_crc(c.hexb("01 10 00 3A 00 01 02 00 01"))
# the firmware's warning when a DMA refill came a buffer half late
# (src/firmware/control.rs)
LATE_REFILL_LOG = re.compile(r"step engine: (\d+) refill\(s\) came a buffer half late")
LATENCY_MOVE_S = 0.3  # emulated seconds at the top rate, each way


def unlimited_to(m: c.Master, rate: int):
    """PA12 at its maximum (6000 r/min) and PA15 at the widest STEP pulse
    `rate` allows (conftest.pulse_for): nothing but the board's own limit
    clamps a speed up to `rate` (SPEC §8.4, docs/drive.md)."""
    m.write(c.PA_BASE + 12, 6000)
    if rate:
        m.write(c.PA_BASE + 15, c.pulse_for(rate))


def ready_at(m: c.Master, mode: int, rate: int):
    """Operation enabled in `mode` (0x6060: 1 position, 3 velocity), both
    ramps at MAX_ACCEL and 0x6081 at `rate`, nothing but the board's limit
    clamping it."""
    m.enable()
    m.write(c.MODE, mode)
    # 0x6083/0x6084 in 0.1 r/s², 0x6081 in 0.1 r/s (SPEC §5)
    m.write(c.ACCELERATION, MAX_ACCEL * 10 // STEPS_PER_REV)
    m.write(c.DECELERATION, MAX_ACCEL * 10 // STEPS_PER_REV)
    unlimited_to(m, rate)
    m.write32(c.PROFILE_VELOCITY, rate * 10 // STEPS_PER_REV)


def latencies(fw: c.Firmware, trace: Path, n: int) -> list[float]:
    """µs from each request's end to its reply's first start bit."""
    with fw.raw() as bus:
        for _ in range(n):
            bus.exchange(c.with_crc(c.hexb("01 03 60 41 00 01")))
            time.sleep(0.01)
    time.sleep(0.1)
    rows = [(int(r["time_ns"]), r["event"]) for r in csv.DictReader(open(trace))]
    rows.sort()
    out, last_rx, waiting = [], None, False
    for t, ev in rows:
        if ev == "rx":
            last_rx, waiting = t, True
        elif ev == "tx" and waiting:
            out.append((t - last_rx) / 1000)
            waiting = False
    return out[-n:]


def stats(path: Path) -> dict[str, int]:
    for _ in range(100):
        try:
            return {k: int(v) for k, v in (line.split() for line in path.read_text().splitlines())}
        except (OSError, ValueError):
            time.sleep(0.01)
    raise RuntimeError(f"no stats in {path}")


def wait_stats(path: Path, after_ns: int) -> dict[str, int]:
    while True:
        s = stats(path)
        if s["time_ns"] >= after_ns:
            return s
        time.sleep(0.02)


def load_at(board: str, rate: int, work: Path) -> tuple[float, float, float]:
    """(CPU load %, measured step rate, emulated seconds per wall second)
    at a constant velocity of `rate` (0: at rest, operation enabled)."""
    st = work / f"{board}-{rate}.stats"
    fw = c.Firmware(work, board, ["--stats", str(st), "--quiet"])
    try:
        m = c.Master(fw.client())
        m.enable()
        m.write(c.MODE, 3)
        m.write(c.ACCELERATION, 10_000)
        m.write(c.DECELERATION, 10_000)
        unlimited_to(m, rate)
        m.write32(c.PROFILE_VELOCITY, rate * 10 // STEPS_PER_REV)
        deadline = time.monotonic() + 30
        # 0x606C is in r/min (SPEC §5)
        while m.read32(c.ACTUAL_VELOCITY) * STEPS_PER_REV // 60 < rate:
            assert time.monotonic() < deadline, "never reached the speed"
            time.sleep(0.02)
        if rate == 0:
            time.sleep(0.1)  # the enable's last frame answered
        # fw-sim writes the stats every 50 ms of wall time: the snapshot
        # at hand may be from before the speed was reached (at a board's
        # top rate the ramp then fell into the window); one written well
        # after the speed was seen starts it
        a = wait_stats(st, stats(st)["time_ns"] + 120_000_000)
        w0 = time.monotonic()
        b = wait_stats(st, a["time_ns"] + 200_000_000)  # 0.2 s of emulated time
        speed = (b["time_ns"] - a["time_ns"]) / 1e9 / (time.monotonic() - w0)
        busy = b["busy_cycles"] - a["busy_cycles"]
        asleep = b["sleep_cycles"] - a["sleep_cycles"]
        steps = (b["steps"] - a["steps"]) / ((b["time_ns"] - a["time_ns"]) / 1e9)
        fw.alive()
        return 100 * busy / (busy + asleep), steps, speed
    finally:
        fw.stop()


def profile(path: Path) -> dict[str, int]:
    """`--profile`: instructions per firmware function since reset."""
    for _ in range(100):
        try:
            return {name: int(n) for n, name in
                    (line.split(" ", 1) for line in path.read_text().splitlines())}
        except (OSError, ValueError):
            time.sleep(0.01)
    raise RuntimeError(f"no profile in {path}")


# What makes the delays in the core, by the functions `--profile` names:
# the planner (goals, profile, segments and their fits) and the schedule's
# expansion of segments into delays; the refill side (the step source, the
# burst writer, the firmware's refill and its interrupt) apart; the integer
# helpers both call (wide shifts and divisions) apart, as the glue calls a
# few of them too.
RAMP_COST_PARTS = [
    ("planner", ("modbus_drive::motion::planner", "modbus_drive::motion::profile")),
    ("expansion", ("modbus_drive::motion::schedule::segment",
                   "modbus_drive::motion::schedule::ring::StepSchedule::push")),
    ("arithmetic helpers", ("modbus_drive::arith", "__aeabi_", "compiler_builtins::int")),
    ("refill", ("modbus_drive::firmware::steps", "modbus_drive::motion::burst",
                "modbus_drive::motion::schedule::source", "DMA1_CHANNEL")),
]


def ramp_cost(board: str, work: Path) -> tuple[int, int, list[float], float]:
    """A position move from rest to rest at the board's limit that is all
    ramp (distance v²/a: the deceleration starts where the acceleration
    ends), the bus quiet: (steps/s at the top, steps, instructions a step
    per RAMP_COST_PARTS entry, all the core's busy cycles a step)."""
    rate = LIMITS[board]
    distance = rate * rate // MAX_ACCEL
    st, pf = work / f"{board}-ramp.stats", work / f"{board}-ramp.profile"
    fw = c.Firmware(work, board, ["--stats", str(st), "--profile", str(pf), "--quiet"])
    try:
        m = c.Master(fw.client())
        ready_at(m, 1, rate)
        m.write32(c.TARGET_POSITION, distance)
        # a snapshot from after the last frame, before the start
        a = wait_stats(st, stats(st)["time_ns"] + 20_000_000)
        pa = profile(pf)
        m.write(c.CONTROLWORD, 0x001F)
        m.c.close()
        deadline = time.monotonic() + 120
        while stats(st)["steps"] - a["steps"] < distance:
            assert time.monotonic() < deadline, f"{board}: ramp move unfinished"
            time.sleep(0.02)
        b = wait_stats(st, stats(st)["time_ns"] + 20_000_000)
        pb = profile(pf)
        fw.alive()
    finally:
        fw.stop()
    steps = b["steps"] - a["steps"]
    assert steps == distance, (board, steps, distance)
    parts = [sum(n - pa.get(name, 0) for name, n in pb.items() if name.startswith(prefixes))
             / steps for _, prefixes in RAMP_COST_PARTS]
    return rate, steps, parts, (b["busy_cycles"] - a["busy_cycles"]) / steps


def ramp_cost_section(work: Path) -> list[str]:
    lines = ["", "## Core cycles a step making the delays on ramps", "",
             "A position move from rest to rest at the board's step rate limit and",
             f"the planner's steepest acceleration ({MAX_ACCEL} steps/s²), all ramp",
             "(distance v²/a), no frame meanwhile, under `fw-sim --profile`:",
             "instructions a step (one cycle each, docs/fw-sim.md) in the functions",
             "that make the delays — the planner (`motion::planner`, `motion::profile`)",
             "and the expansion (`motion::schedule::segment`, the push) — then in the",
             "integer helpers they call (the glue calls a few of them too) and, for",
             "comparison, on the refill side (`firmware::steps`, `motion::burst`, the",
             "step source, the DMA interrupt); the last column is every busy cycle",
             "of the move a step. Machine-outlined fragments (`OUTLINED_FUNCTION_*`)",
             "are in no column but the last.", "",
             "| board | steps/s at the top | steps | "
             + " | ".join(name for name, _ in RAMP_COST_PARTS) + " | all busy cycles |",
             "|---|---|---|" + "---|" * (len(RAMP_COST_PARTS) + 1)]
    for board in c.BOARDS:
        rate, steps, parts, busy = ramp_cost(board, work)
        lines.append(f"| {board} | {rate} | {steps} | "
                     + " | ".join(f"{x:.1f}" for x in parts) + f" | {busy:.1f} |")
        print(lines[-1], flush=True)
    return lines


def host_schedule(board: str, distance: int, rate: int, accel: int) -> list[int]:
    """Step ticks relative to the first (examples/step_schedule.rs)."""
    out = subprocess.run([str(SCHEDULE), board, str(distance), str(rate), str(accel), str(accel)],
                         capture_output=True, text=True, timeout=120, check=True).stdout
    return [int(x) for x in out.split()]


def pulses(path: Path) -> list[int]:
    with open(path) as f:
        return [int(r["time_ns"]) for r in csv.DictReader(f)]


def on_time(board: str, work: Path, polled: bool) -> list[tuple[int, int, int, float, float,
                                                                float]]:
    """Per rate: (steps/s, distance, pulses, shortest period µs, worst
    deviation in ticks of pulses 2.. from the schedule, relative to pulse 2,
    first interval minus the schedule's in ticks). One runner, moves back
    and forth; `polled`: the master reads the statusword every 20 ms of wall
    time during each move, otherwise the bus is quiet until the pulses are
    out."""
    tick = TICK_NS[board]
    trace = work / f"{board}-on-time-{polled}.steps.csv"
    fw = c.Firmware(work, board, ["--trace-steps", str(trace), "--quiet"])
    out = []
    try:
        m = c.Master(fw.client())
        m.enable()
        m.write(c.MODE, 1)
        # 0x6083/0x6084 in 0.1 r/s², 0x6081 in 0.1 r/s (SPEC §5)
        m.write(c.ACCELERATION, MAX_ACCEL * 10 // STEPS_PER_REV)
        m.write(c.DECELERATION, MAX_ACCEL * 10 // STEPS_PER_REV)
        at, seen, sign = 0, 0, 1
        for rate in ON_TIME_RATES[board]:
            distance = rate * rate // MAX_ACCEL + CRUISE_STEPS
            at += sign * distance
            sign = -sign
            unlimited_to(m, rate)
            m.write32(c.PROFILE_VELOCITY, rate * 10 // STEPS_PER_REV)
            m.write32(c.TARGET_POSITION, at)
            m.write(c.CONTROLWORD, 0x001F)
            m.write(c.CONTROLWORD, 0x000F)
            if polled:
                m.wait(lambda sw: sw & c.TARGET_REACHED and not sw & c.MOTOR_RUNNING, 120,
                       f"{board}: move at {rate} steps/s")
            deadline = time.monotonic() + 120
            while len(pulses(trace)) < seen + distance:  # the pin lags the count
                assert time.monotonic() < deadline, f"{board}: pulses missing at {rate}"
                time.sleep(0.02)
            time.sleep(0.2)  # a late one would be seen, and the move is over
            m.wait(lambda sw: sw & c.TARGET_REACHED and not sw & c.MOTOR_RUNNING, 10,
                   f"{board}: move at {rate} steps/s")
            assert m.read32(c.ACTUAL_POSITION) == at
            pin = pulses(trace)[seen:]
            seen += len(pin)
            host = host_schedule(board, distance, rate, MAX_ACCEL)
            assert len(host) == distance, (board, rate, len(host))
            # a pulse too many or too few is off the schedule from there on
            worst = max(abs((pin[k] - pin[1]) / tick - (host[k] - host[1]))
                        for k in range(1, min(len(pin), distance)))
            first = (pin[1] - pin[0]) / tick - (host[1] - host[0])
            shortest = min(b - a for a, b in zip(pin, pin[1:])) / 1000
            out.append((rate, distance, len(pin), shortest, worst, first))
            print(board, out[-1], flush=True)
        fw.alive()
    finally:
        fw.stop()
    return out


def read_flood(port: int, stop: threading.Event, answered: list[int]):
    """Reads of 0x6041 for this drive, the next sent as soon as the reply
    is in (after a short gap so it opens a new frame; resent after 0.2 s of
    wall time without one). `answered[0]`: replies received."""
    request = c.with_crc(c.hexb("01 03 60 41 00 01"))
    reply_len = 7  # address, function, byte count, one register, CRC
    with socket.create_connection(("127.0.0.1", port), timeout=2) as s:
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        got = 0
        while not stop.is_set():
            s.sendall(request)
            want, deadline = got + reply_len, time.monotonic() + 0.2
            while got < want and time.monotonic() < deadline:
                s.settimeout(max(0.001, deadline - time.monotonic()))
                try:
                    chunk = s.recv(256)
                except socket.timeout:
                    break
                if not chunk:
                    return
                got += len(chunk)
            answered[0] = got // reply_len
            time.sleep(0.003)


def flooded_move(board: str, rate: int, work: Path) -> tuple[int, int, int]:
    """A position move of `rate` steps/s at the steepest ramp there and
    back while `read_flood` runs. (distance, reads answered, refills the
    firmware reported late: the DMA read a buffer half before the refill
    had written it again)."""
    st = work / f"{board}-flood.stats"
    fw = c.Firmware(work, board, ["--stats", str(st)])
    distance = int(rate * LATENCY_MOVE_S) + rate * rate // MAX_ACCEL
    answered = [0]
    try:
        m = c.Master(fw.client())
        ready_at(m, 1, rate)
        steps0 = stats(st)["steps"]
        for k, target in enumerate((distance, 0)):
            m.write32(c.TARGET_POSITION, target)
            m.write(c.CONTROLWORD, 0x001F)
            m.write(c.CONTROLWORD, 0x000F)
            # the master is silent while the flood has the bus: two senders
            # would garble each other's frames on the one line
            m.c.close()
            stop, count = threading.Event(), [0]
            flooder = threading.Thread(target=read_flood, args=(fw.port, stop, count))
            flooder.start()
            try:
                deadline = time.monotonic() + 120
                while stats(st)["steps"] < steps0 + (k + 1) * distance:
                    assert time.monotonic() < deadline, f"{board}: move at {rate} steps/s"
                    time.sleep(0.05)
            finally:
                stop.set()
                flooder.join()
            answered[0] += count[0]
            time.sleep(0.2)  # the last reply is out, and a late refill is logged
            # a fresh client: the old one's socket heard the flood's replies
            m = c.Master(fw.client())
            m.wait(lambda sw: sw & c.TARGET_REACHED and not sw & c.MOTOR_RUNNING, 10,
                   f"{board}: move at {rate} steps/s")
            assert m.read32(c.ACTUAL_POSITION) == target
        fw.alive()
    finally:
        fw.stop()
    late = [int(x) for x in LATE_REFILL_LOG.findall(fw.stderr())]
    return distance, answered[0], max(late, default=0)


def flood_section(work: Path, rates: dict[str, int]) -> list[str]:
    lines = ["", "## DMA refills while the bus is flooded", "",
             "The step engine's refill (the DMA channel's half-transfer and",
             "transfer-complete interrupt, src/firmware/steps.rs) must write each",
             "buffer half again before the DMA comes back to it; a refill that finds",
             "the DMA already in the half it is to write counts itself late, and the",
             "control loop logs the count (`step engine: N refill(s) came a buffer",
             "half late`, src/firmware/control.rs). The last column is the largest",
             "count logged (0: no such line).", "",
             "Each board: a position move at the highest rate it keeps every pulse on",
             f"time (the section above, bus polled), ramps at MAX_ACCEL, {LATENCY_MOVE_S} s",
             "of emulated time at that rate each way, there and back. From each move's",
             "start to its last pulse the master floods the bus with reads of 0x6041",
             "for this drive, the next request 3 ms of wall-clock time after each",
             "reply (less emulated time when the emulator lags).", "",
             "| board | steps/s | distance each way | reads answered | refills late |",
             "|---|---|---|---|---|"]
    for board in c.BOARDS:
        rate = rates[board]
        distance, answered, late = flooded_move(board, rate, work)
        lines.append(f"| {board} | {rate} | {distance} | {answered} | {late} |")
        print(lines[-1], flush=True)
    return lines


def limit_brake(board: str, work: Path) -> tuple[int, int, int, float, int, int, int]:
    """Velocity mode at the board's limit into the CCW limit, 0x6085 at
    MAX_ACCEL, the master polling 0x6041 every 20 ms of wall-clock time
    throughout, then an EE-Set: (steps/s, v²/2a, steps past the edge, CPU
    load % while braking, reads sent while braking, reads answered of
    them, USART overruns the drive counted: function 8, sub-function 0x12,
    bytes of stack never reached since power-on)."""
    rate = LIMITS[board]
    brake = rate * rate // (2 * MAX_ACCEL)
    edge = 2 * brake + 20_000  # up to speed, then a cruise
    st = work / f"{board}-brake.stats"
    fw = c.Firmware(work, board, ["--ccw-limit", str(edge), "--stats", str(st), "--quiet"])
    try:
        m = c.Master(fw.client())
        ramp = MAX_ACCEL * 10 // STEPS_PER_REV  # 0.1 r/s² (SPEC §5)
        m.write(c.QUICK_STOP_DECELERATION, ramp)
        ready_at(m, 3, rate)
        snaps, sent, answered = [], 0, 0
        deadline = time.monotonic() + 60
        while True:
            assert time.monotonic() < deadline, f"{board}: the brake at {rate} steps/s"
            s = stats(st)
            if s["steps"] > edge and snaps and snaps[-1]["steps"] == s["steps"] \
                    and s["time_ns"] - snaps[-1]["time_ns"] >= 50_000_000:
                break  # at rest
            if not snaps or s["time_ns"] != snaps[-1]["time_ns"]:
                snaps.append(s)
            if s["steps"] > edge:
                sent += 1
                try:
                    m.statusword()
                    answered += 1
                except ModbusIOException:
                    pass
            time.sleep(0.02)
        over = m.read32(c.ACTUAL_POSITION) - edge
        # the snapshots taken from the edge until the last that still moved
        final = snaps[-1]["steps"]
        moving = [x for x in snaps if edge < x["steps"] < final]
        a, b = moving[0], moving[-1]
        busy = b["busy_cycles"] - a["busy_cycles"]
        asleep = b["sleep_cycles"] - a["sleep_cycles"]
        m.c.close()
        with fw.raw() as bus:
            reply = bus.exchange(c.with_crc(c.hexb("01 08 00 12 00 00")))
            overruns = int.from_bytes(reply[4:6], "big")
            # an EE-Set: the store's save, the deepest call after the boot's
            assert bus.exchange(EE_SET, timeout=3) == c.with_crc(c.hexb("01 10 00 3A 00 01"))
        time.sleep(0.5)  # the save's erase and programs done, the stats rewritten
        stack = stats(st)["stack_untouched"]
        fw.alive()
    finally:
        fw.stop()
    return rate, brake, over, 100 * busy / max(1, busy + asleep), sent, answered, overruns, stack


def limit_brake_section(work: Path) -> list[str]:
    lines = ["", "## A limit brake from the board's limit", "",
             "Velocity mode at the board's step rate limit into the CCW limit",
             f"(`--ccw-limit`), quick stop deceleration 0x6085 at {MAX_ACCEL} steps/s²",
             "(SPEC §8.7: the limit brakes from the edge step), the master reading",
             "0x6041 every 20 ms of wall-clock time throughout. Steps past the edge",
             "are 0x6064 at rest less the edge: v²/2a plus the steps the timer had",
             "been handed (docs/firmware.md, \"Limits\"). The CPU load is over",
             "the `--stats` snapshots between the edge and the last step; the",
             "overruns are the drive's own count afterwards (function 8,",
             "sub-function 0x12): a receiver the core left unserved too long.", "",
             "| board | steps/s | v²/2a | steps past the edge | CPU load % while braking "
             "| reads while braking | answered | USART overruns |",
             "|---|---|---|---|---|---|---|---|"]
    stacks = {}
    for board in c.BOARDS:
        rate, brake, over, load, sent, answered, overruns, stacks[board] = limit_brake(board, work)
        lines.append(f"| {board} | {rate} | {brake} | {over} | {load:.1f} | {sent} "
                     f"| {answered} | {overruns} |")
        print(lines[-1], flush=True)
    lines += ["", "## Stack headroom", "",
              "Bytes at the far end of the stack region (below the statics, flip-link)",
              "never written from power-on to the end of the run above and an EE-Set",
              "after it: fw-sim paints the region at power-on (fw-sim/src/stack.rs,",
              "`--stats`). The boot's `install_device` (the `Device` built on its",
              "frame) is the deepest call; an interrupt in it stacks its frames",
              "below (docs/firmware.md, \"Sizes\").", "",
              "| board | stack never reached, B |", "|---|---|"]
    lines += [f"| {board} | {stacks[board]} |" for board in c.BOARDS]
    return lines


def stepping_latency(board: str, rate: int, work: Path) -> list[float]:
    """Reply latencies (µs, as `latencies`) of STEPPING_REQUESTS reads sent
    while the motor runs at `rate` steps/s in velocity mode."""
    trace = work / f"{board}-stepping.line.csv"
    fw = c.Firmware(work, board, ["--trace-line", str(trace), "--quiet"])
    try:
        m = c.Master(fw.client())
        ready_at(m, 3, rate)
        deadline = time.monotonic() + 30
        # 0x606C is in r/min (SPEC §5)
        while m.read32(c.ACTUAL_VELOCITY) * STEPS_PER_REV // 60 < rate:
            assert time.monotonic() < deadline, f"{board}: never reached {rate} steps/s"
            time.sleep(0.02)
        m.c.close()
        lat = latencies(fw, trace, STEPPING_REQUESTS)
        m = c.Master(fw.client())
        assert m.read32(c.ACTUAL_VELOCITY) * STEPS_PER_REV // 60 >= rate, "still at speed"
        fw.alive()
    finally:
        fw.stop()
    assert len(lat) == STEPPING_REQUESTS, (board, len(lat))
    return lat


def stepping_latency_section(work: Path) -> list[str]:
    lines = ["", "## Reply latency while stepping at the board's limit", "",
             f"{STEPPING_REQUESTS} reads of 0x6041 at 115200 baud, sent while the motor runs in",
             "velocity mode at the board's step rate limit (Board::max_step_rate),",
             "measured as the first section does; t3.5 is 1750 µs. The last column",
             f"counts the replies later than t3.5 + {TARGET_OVER_T35_US} µs.", "",
             "| board | steps/s | min µs | mean µs | 99th percentile µs | max µs "
             f"| max − t3.5 µs | over t3.5 + {TARGET_OVER_T35_US} µs |",
             "|---|---|---|---|---|---|---|---|"]
    for board in c.BOARDS:
        lat = sorted(stepping_latency(board, LIMITS[board], work))
        over = sum(1 for x in lat if x - 1750 > TARGET_OVER_T35_US)
        lines.append(f"| {board} | {LIMITS[board]} | {lat[0]:.1f} | {statistics.mean(lat):.1f} "
                     f"| {lat[len(lat) * 99 // 100]:.1f} | {lat[-1]:.1f} | {lat[-1] - 1750:.1f} "
                     f"| {over} of {len(lat)} |")
        print(lines[-1], flush=True)
    return lines


def reset_window_section(work: Path) -> list[str]:
    """Cycles from reset until every safety output is driven (`--trace-pins`)."""
    from test_safety import boots, pin_rows, undriven_window
    lines = ["", "## Outputs undriven after reset", "",
             "Core cycles from the reset vector until ENABLE, BRAKE, STEP and DE are",
             "all driven outputs (`--trace-pins`, first boot; the same after a",
             "watchdog reset): the window in which only the board's pull resistors",
             "hold them (docs/firmware.md, \"From reset\"). The core clock then is",
             "the reset clock: HSI16 on the G431, HSI 8 MHz on the F103.", "",
             "| board | cycles | µs at the reset clock | first driven states |",
             "|---|---|---|---|"]
    for board, hz in (("g431", 16_000_000), ("f103", 8_000_000)):
        trace = work / f"{board}.pins.csv"
        fw = c.Firmware(work, board, ["--trace-pins", str(trace), "--quiet"])
        try:
            c.Master(fw.client()).statusword()
            fw.alive()
        finally:
            fw.stop()
        window, first = undriven_window(boots(pin_rows(trace))[0])
        states = ", ".join(f"{p} {s}" for p, s in sorted(first.items()))
        lines.append(f"| {board} | {window} | {window * 1e6 / hz:.2f} | {states} |")
        print(lines[-1], flush=True)
    return lines


def rates_from_file() -> dict[str, int]:
    """Each board's highest on-time rate with the bus polled, from the last
    full run's output."""
    found = dict(re.findall(r"^- (\w+), bus polled: every pulse on time up to \*\*(\d+) steps/s",
                            OUT.read_text(), re.M))
    return {b: int(found[b]) for b in c.BOARDS}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", choices=["flood", "stepping-latency", "reset", "ramp-cost"],
                    help="run one section and print it; the file is not written")
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="fw-sim-measure-"))
    if args.only == "flood":
        print("\n".join(flood_section(work, rates_from_file())))
        return 0
    if args.only == "stepping-latency":
        print("\n".join(stepping_latency_section(work)))
        return 0
    if args.only == "reset":
        print("\n".join(reset_window_section(work)))
        return 0
    if args.only == "ramp-cost":
        print("\n".join(ramp_cost_section(work)))
        return 0
    lines = ["# fw-sim measurements (generated)", "",
             "Written by `fw-sim/measure.py` from emulated time; do not edit. Method and",
             "assumptions (one cycle per instruction) in [../fw-sim.md](../fw-sim.md).", ""]
    lines += ["## Reply latency: end of request to the reply's first start bit", "",
              f"{REQUESTS} reads of 0x6041 each; t3.5 is 1750 µs above 19200 baud and",
              "3.5 character times (1823 µs) at 19200 (SPEC §1).", "",
              "| board | baud | min µs | mean µs | max µs |", "|---|---|---|---|---|"]
    for board in c.BOARDS:
        for baud in (115200, 19200):
            trace = work / f"{board}-{baud}.line.csv"
            fw = c.Firmware(work, board, ["--trace-line", str(trace), "--quiet"])
            try:
                if baud == 19200:
                    m = c.Master(fw.client())
                    m.write(BAUD_PA52, 1)  # applies after this write's reply
                    m.c.close()
                    time.sleep(0.05)
                lat = latencies(fw, trace, REQUESTS)
                fw.alive()
            finally:
                fw.stop()
            assert len(lat) == REQUESTS, (board, baud, lat)
            lines.append(f"| {board} | {baud} | {min(lat):.1f} | {statistics.mean(lat):.1f} "
                         f"| {max(lat):.1f} |")
            print(lines[-1], flush=True)
    lines += stepping_latency_section(work)
    lines += ["", "## CPU load while stepping (velocity mode, constant speed)", "",
              "Share of core cycles not asleep over 0.2 s of emulated time, from",
              "0.12 s of emulated time or more after 0x606C shows the set speed",
              "(0: at rest, operation enabled; no frame meanwhile), so that no part",
              "of the ramp falls in the window. Each board's step rate is clamped to",
              "its limit (Board::max_step_rate in src/boards.rs: "
              + ", ".join(f"{b} {LIMITS[b]}" for b in c.BOARDS) + " steps/s).", "",
              "The last column is how fast the emulator ran meanwhile: emulated",
              "seconds per wall-clock second on the machine that ran this script",
              "(the runner never runs ahead of wall time; below 1 it lags).", "",
              "Ticks a step is the step timer's period at that rate: where it has a",
              "fraction the delays alternate between two whole numbers of ticks, so",
              "few steps in a row are alike and the refill writes about one timer",
              "entry a step, as on a ramp; where it is whole a run of alike steps",
              "is one entry (docs/firmware.md, \"Step rate limits\").", "",
              "| board | steps/s set | ticks a step | steps/s measured | CPU load % | emulator speed |",
              "|---|---|---|---|---|---|"]
    for board in c.BOARDS:
        for rate in RATES[board]:
            load, measured, speed = load_at(board, rate, work)
            ticks = f"{1e9 / c.TICK_NS[board] / rate:.2f}" if rate else "-"
            lines.append(f"| {board} | {rate} | {ticks} | {measured:.0f} | {load:.1f} | {speed:.2f} |")
            print(lines[-1], flush=True)
    lines += ramp_cost_section(work)
    lines += ["", "## Highest step rate with every pulse on time", "",
              f"Position moves from rest at 0x6081 rising in {STEP_GRID} steps/s increments",
              "up to the board's step rate limit (the firmware clamps above it), ramps",
              "at the planner's steepest",
              f"acceleration (MAX_ACCEL, {MAX_ACCEL} steps/s²), each long enough for",
              f"{CRUISE_STEPS} steps at the set rate, one runner, back and forth. Every",
              "traced STEP pulse is compared with the core planner's",
              "schedule for the same move at the board's step tick",
              "(examples/step_schedule.rs); the pin and the schedule are aligned at",
              "the second pulse. A rate passes when every pulse from the second on is",
              "within one step-timer tick of the schedule and the pulse count equals the",
              "distance. The first interval from rest is listed apart (docs/fw-sim.md,",
              "\"Findings\").", "",
              "Bus: `quiet` — no frame from the moment the move is started until its",
              "last pulse; `polled` — the master reads the statusword every 20 ms of",
              "wall-clock time throughout the move (a few ms of emulated time apart,",
              "depending on the emulator's speed, so these rows vary from run to run).", "",
              "| board | bus | steps/s | distance | pulses | shortest period µs "
              "| worst deviation, ticks | first interval − schedule, ticks | on time |",
              "|---|---|---|---|---|---|---|---|---|"]
    highest = {}
    for board in c.BOARDS:
        for polled in (False, True):
            bus = "polled" if polled else "quiet"
            for rate, distance, n, shortest, worst, first in on_time(board, work, polled):
                ok = worst <= 1 and n == distance
                if ok and highest.get((board, bus), 0) == rate - STEP_GRID:
                    highest[board, bus] = rate
                lines.append(f"| {board} | {bus} | {rate} | {distance} | {n} | {shortest:.3f} "
                             f"| {worst:.2f} | {first:+.2f} | {'yes' if ok else 'no'} |")
                print(lines[-1], flush=True)
    lines += [""]
    for (board, bus), top in sorted(highest.items()):
        ceiling = (" (the planner's ceiling)" if top == MAX_STEP_RATE[board]
                   else " (the board's limit)" if top == LIMITS[board] else "")
        lines.append(f"- {board}, bus {bus}: every pulse on time up to **{top} steps/s**{ceiling}.")
    lines += flood_section(work, {b: highest.get((b, "polled"), STEP_GRID) for b in c.BOARDS})
    lines += limit_brake_section(work)
    lines += reset_window_section(work)
    OUT.write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
