#!/usr/bin/env python3
"""Measurements of both firmware images from emulated time (fw-sim), written
to docs/generated/fw-sim.md. Run after building the images and the runner
(`bash .ci/fw-sim.sh` does both):

    .venv/e2e/bin/python fw-sim/measure.py

- reply latency: from the end of a request's last stop bit to the start bit
  of the reply's first character (`--trace-line`), at 115200 and 19200 baud;
- CPU load while stepping in velocity mode at 50k, 100k steps/s and the
  planner's ceiling (MAX_STEP_RATE in src/motion/):
  the share of core cycles not spent asleep in WFI/WFE (`--stats`), under the
  runner's one-cycle-per-instruction assumption (docs/fw-sim.md, "Time").
"""

from __future__ import annotations

import csv
import re
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "fw_sim"))
import conftest as c  # noqa: E402  (the test harness: runner, master, register names)

OUT = ROOT / "docs" / "generated" / "fw-sim.md"
BAUD_PA52 = c.PA_BASE + 52
REQUESTS = 20
# the planner's ceiling, read from the source it lives in
def _max_step_rate() -> int:
    for path in sorted((ROOT / "src" / "motion").rglob("*.rs")):
        m = re.search(r"pub const MAX_STEP_RATE: u32 = ([0-9_]+);", path.read_text())
        if m:
            return int(m[1])
    raise RuntimeError("MAX_STEP_RATE not found under src/motion")


MAX_STEP_RATE = _max_step_rate()
RATES = sorted({50_000, 100_000, MAX_STEP_RATE})
STEPS_PER_REV = 10_000  # PA10 default (SPEC §7)


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
    at a constant velocity of `rate`."""
    st = work / f"{board}-{rate}.stats"
    fw = c.Firmware(work, board, ["--stats", str(st), "--quiet"])
    try:
        m = c.Master(fw.client())
        m.enable()
        m.write(c.MODE, 3)
        m.write(c.ACCELERATION, 10_000)
        m.write(c.DECELERATION, 10_000)
        m.write32(c.PROFILE_VELOCITY, rate * 10 // STEPS_PER_REV)
        deadline = time.monotonic() + 30
        # 0x606C is in r/min (SPEC §5)
        while m.read32(c.ACTUAL_VELOCITY) * STEPS_PER_REV // 60 < rate:
            assert time.monotonic() < deadline, "never reached the speed"
            time.sleep(0.02)
        a = stats(st)
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


def main() -> int:
    work = Path(tempfile.mkdtemp(prefix="fw-sim-measure-"))
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
    lines += ["", "## CPU load while stepping (velocity mode, constant speed)", "",
              "Share of core cycles not asleep over 0.2 s of emulated time, once",
              "0x606C shows the set speed. The planner caps step rates at",
              f"{MAX_STEP_RATE} steps/s (MAX_STEP_RATE in src/motion/).", "",
              "The last column is how fast the emulator ran meanwhile: emulated",
              "seconds per wall-clock second on the machine that ran this script",
              "(the runner never runs ahead of wall time; below 1 it lags).", "",
              "| board | steps/s set | steps/s measured | CPU load % | emulator speed |",
              "|---|---|---|---|---|"]
    for board in c.BOARDS:
        for rate in RATES:
            load, measured, speed = load_at(board, rate, work)
            lines.append(f"| {board} | {rate} | {measured:.0f} | {load:.1f} | {speed:.2f} |")
            print(lines[-1], flush=True)
    OUT.write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
