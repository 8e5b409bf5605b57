"""The master tools (`modbus-drive commission | scan | params`) against a
drive on a pseudo-terminal: the test bodies shared by tests/e2e (the
virtual drive), tests/fw_sim (both firmware images under fw-sim) and
tests/web (the page in Chromium).

A *runner* is what the drive runs in. It has `link` (the pty symlink the
master opens), `start(state)` / `stop()` (the runner process, with a
`--state` flash file so that saved parameters survive a restart) and
`master()` (an e2e `Master` on its RTU-over-TCP line, to set and check
registers beside the tool under test)."""

from __future__ import annotations

import json
import re
import select
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

# the shared process helpers of tests/e2e, however this module was loaded
# (pytest, or by path from tests/fw_sim and tests/web)
_E2E = Path(__file__).resolve().parent
if str(_E2E) not in sys.path:
    sys.path.append(str(_E2E))
from processes import stop_process  # noqa: E402

PA = 0x0064  # PA0 (SPEC §9)
STATUSWORD = 0x6041
ACTUAL_POSITION = 0x6064
# the three PAs the save/restore round trip changes, with a value each
# that is not the default (SPEC §7)
ROUND_TRIP = {12: 1500, 13: 5, 56: 3}
OTHER = {12: 2000, 13: 0, 56: 0}


def tool(bin_path: Path, *args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([str(bin_path), *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


class Commission:
    """`modbus-drive commission --serial LINK --web 127.0.0.1:0` running."""

    def __init__(self, bin_path: Path, workdir: Path, *args: str):
        self.log_path = workdir / f"commission-{time.monotonic_ns()}.log"
        self._log = open(self.log_path, "wb")
        self.proc = subprocess.Popen([str(bin_path), "commission", *map(str, args),
                                      "--web", "127.0.0.1:0"],
                                     stdout=subprocess.PIPE, stderr=self._log)
        r, _, _ = select.select([self.proc.stdout], [], [], 10)
        line = self.proc.stdout.readline() if r else b""
        if line != b"ready\n":
            self.stop()
            raise AssertionError(f"commission: no `ready`: {line!r}\n{self.log()}")
        m = re.search(r"web: page on (http://127\.0\.0\.1:\d+/)", self.log())
        self.url = m.group(1)

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def state(self) -> dict:
        with urllib.request.urlopen(self.url + "api/state", timeout=5) as r:
            return json.load(r)["drives"][0]

    def cmd(self, **params) -> dict:
        q = "&".join(f"{k}={v}" for k, v in {"d": 0, **params}.items())
        req = urllib.request.Request(self.url + "api/cmd?" + q, method="POST",
                                     headers={"X-Modbus-Drive": "page"})
        with urllib.request.urlopen(req, timeout=10) as r:
            return json.load(r)

    def wait(self, pred, what: str, timeout: float = 20) -> dict:
        deadline = time.monotonic() + timeout
        s = None
        while time.monotonic() < deadline:
            try:
                s = self.state()
                if pred(s):
                    return s
            except (OSError, ValueError):
                pass
            time.sleep(0.1)
        raise AssertionError(f"{what}: last state {s and {k: s[k] for k in ('state', 'link')}}"
                             f"\n{self.log()}")

    def stop(self):
        stop_process(self.proc, self._log)


def move_to_address_17_at_19200_8e1(runner):
    """PA52 = 1 (19200), PA53 = 1 (8E1), then PA51 = 17: each takes effect
    after its reply (SPEC §7)."""
    m = runner.master()
    m.write(PA + 52, 1)
    m.write(PA + 53, 1)
    m.write(PA + 51, 17)


def scan_finds_the_drive_at_its_address_and_line(runner, bin_path: Path):
    move_to_address_17_at_19200_8e1(runner)
    out = tool(bin_path, "scan", "--serial", runner.link, "--baud", "19200", "--format", "8E1")
    assert out.returncode == 0, out.stdout + out.stderr
    lines = [l for l in out.stdout.splitlines() if l.startswith("address")]
    assert len(lines) == 1, out.stdout
    assert re.match(r"address +17 +line 19200 8E1 +firmware \d+ +state SwitchOnDisabled$",
                    lines[0]), lines[0]
    assert "scan done: 1 drive(s)" in out.stderr, out.stderr


# the baud the full scan is measured and tested at: the drive's default
SCAN_BAUD = 115200


def full_scan_at_one_baud(bin_path: Path, link, baud: int = SCAN_BAUD):
    """`scan --baud B` without --format: 247 addresses in each of the four
    formats of PA53. Returns the wall time in seconds and the tool's run."""
    t0 = time.monotonic()
    out = tool(bin_path, "scan", "--serial", link, "--baud", baud, timeout=600)
    return time.monotonic() - t0, out


def params_round_trip_survives_a_restart(runner, bin_path: Path, tmp: Path, suffix: str):
    """save → change three PAs → restore (diff, --yes, read back, EE-Set) →
    restart the runner on its --state file → the three values are back."""
    m = runner.master()
    for n, v in ROUND_TRIP.items():
        m.write(PA + n, v)
    f = tmp / f"drive.{suffix}"
    out = tool(bin_path, "params", "save", "--serial", runner.link, f)
    assert out.returncode == 0, out.stderr
    text = f.read_text()
    assert "7060" in text and ("steps per revolution" in text), text
    # a client connected after the tool ran: on fw-sim's shared line the
    # tool's replies reach every master, as on an RS-485 bus
    m = runner.master()
    for n, v in OTHER.items():
        m.write(PA + n, v)
    # without --yes: the differences, nothing written
    out = tool(bin_path, "params", "restore", "--serial", runner.link, f)
    assert out.returncode == 0, out.stderr
    for n in ROUND_TRIP:
        assert re.search(rf"^PA{n} .* {OTHER[n]} -> {ROUND_TRIP[n]}$", out.stdout, re.M), out.stdout
    assert "3 change(s)" in out.stdout, out.stdout
    assert runner.master().read(PA + 12) == OTHER[12]
    out = tool(bin_path, "params", "restore", "--serial", runner.link, f, "--yes")
    assert out.returncode == 0, out.stdout + out.stderr
    assert "wrote 3 change(s), read each back, saved them (EE-Set)" in out.stdout, out.stdout
    runner.stop()
    runner.start()
    m = runner.master()
    for n, v in ROUND_TRIP.items():
        assert m.read(PA + n) == v, f"PA{n} after the restart"


def an_out_of_range_restore_writes_nothing(runner, bin_path: Path, tmp: Path):
    f = tmp / "drive.toml"
    out = tool(bin_path, "params", "save", "--serial", runner.link, f)
    assert out.returncode == 0, out.stderr
    text = f.read_text()
    # a valid change beside the bad one: it must not be written either
    bad = re.sub(r"^PA13 = \d+", "PA13 = 6", text, flags=re.M)
    bad = re.sub(r"^PA51 = \d+", "PA51 = 300", bad, flags=re.M)
    f.write_text(bad)
    out = tool(bin_path, "params", "restore", "--serial", runner.link, f, "--yes")
    assert out.returncode == 1, out.stdout + out.stderr
    assert "PA51 (slave address) = 300 is out of its range 1..=247" in out.stderr, out.stderr
    assert "nothing written" in out.stderr
    m = runner.master()  # connected after the tool ran (see above)
    assert m.read(PA + 13) == 0
    # a file from another firmware version: refused before any write
    other = re.sub(r"^firmware = \d+", "firmware = 7000", text, flags=re.M)
    other = re.sub(r"^PA13 = \d+", "PA13 = 6", other, flags=re.M)
    f.write_text(other)
    out = tool(bin_path, "params", "restore", "--serial", runner.link, f, "--yes")
    assert out.returncode == 1 and "firmware 7000" in out.stderr, out.stderr
    assert runner.master().read(PA + 13) == 0


def the_page_follows_the_line_away_and_back(runner, bin_path: Path, tmp: Path):
    """The runner stops mid-session: the page says the drive is gone (with
    the frame) and a command reports the step that got no reply; the
    runner starts again on the same link and the page finds it."""
    page = Commission(bin_path, tmp, "--serial", runner.link)
    try:
        s = page.wait(lambda s: s["link"]["ok"] and s["pa"][2]["value"] is not None,
                      "the page reads the drive")
        assert s["state"] == "SwitchOnDisabled"
        runner.stop()
        s = page.wait(lambda s: not s["link"]["ok"], "the page sees the drive gone")
        assert s["state"] == "NotAnswering"
        assert re.search(r"request 01 03 ", s["link"]["error"]), s["link"]
        r = page.cmd(c="enable")
        assert not r["ok"] and r["steps"][0]["answer"] == "no reply", r
        assert "stopped at step 1 of 3 (0x6040 = 0x0006)" in r["error"], r
        assert len(r["steps"]) == 1, "nothing sent past the failing step"
        runner.start()
        page.wait(lambda s: s["link"]["ok"] and s["state"] == "SwitchOnDisabled",
                  "the page finds the drive again")
    finally:
        page.stop()


def the_page_moves_the_drive(runner, bin_path: Path, tmp: Path):
    """Over /api (what the page's buttons send): enable, move 10 000 steps,
    target reached; the scope's rate is what the line gave."""
    page = Commission(bin_path, tmp, "--serial", runner.link)
    try:
        page.wait(lambda s: s["link"]["ok"], "the page reads the drive")
        r = page.cmd(c="enable")
        assert r["ok"], r
        r = page.cmd(c="move", target=10000, relative=0, speed=100, accel=200)
        assert r["ok"], r
        s = page.wait(lambda s: s["position"] == 10000 and s["statusword"] & (1 << 10),
                      "target reached", timeout=30)
        assert s["link"]["rate"] > 0
    finally:
        page.stop()
    # after the page, once its last reply has left the wire: one master at
    # a time on a shared line (fw-sim's is one bus, as RS-485 is)
    time.sleep(0.3)
    pos = runner.master().read32(ACTUAL_POSITION)
    assert pos == 10000, pos


def a_restore_follows_the_drive_to_its_new_address_and_line(runner, bin_path: Path, tmp: Path):
    """A file with another address, baud and format: those are written
    last, the master follows the drive for the read-backs and the EE-Set."""
    f = tmp / "moved.toml"
    out = tool(bin_path, "params", "save", "--serial", runner.link, f)
    assert out.returncode == 0, out.stderr
    text = f.read_text()
    for n, v in ((51, 17), (52, 1), (53, 1), (12, 1500)):
        text = re.sub(rf"^PA{n} = \d+", f"PA{n} = {v}", text, flags=re.M)
    f.write_text(text)
    out = tool(bin_path, "params", "restore", "--serial", runner.link, f, "--yes")
    assert out.returncode == 0, out.stdout + out.stderr
    order = re.findall(r"^PA(\d+) ", out.stdout, re.M)
    assert order == ["12", "52", "53", "51"], out.stdout
    assert "wrote 4 change(s)" in out.stdout, out.stdout
    runner.stop()
    runner.start()
    m = runner.master(17)
    assert [m.read(PA + n) for n in (51, 52, 53, 12)] == [17, 1, 1, 1500]


# statusword power states (SPEC §8.1): the bits that tell them apart
STATE_MASK = 0x006F
SWITCH_ON_DISABLED = 0x0040  # under mask 0x004F
OPERATION_ENABLED = 0x0027
FAULT_BIT = 1 << 3
HOME_SWITCH_BIT = 1 << 11
HOMING_ATTAINED = 1 << 12
HOMING_ERROR = 1 << 13
TARGET_REACHED = 1 << 10
ERROR_REGISTER = 0x1001
# where the homing test's home switch is: the window test_programs uses
HOME_WINDOW = "-5000:-3000"


def after_the_page(runner):
    """A master of our own once the page has stopped and its last reply has
    left the wire: one master at a time on a shared line (fw-sim's is one
    bus, as RS-485 is)."""
    time.sleep(0.5)
    return runner.master()


def the_page_jogs_the_drive(runner, bin_path: Path, tmp: Path):
    """Jog + and − with Jog stop between, through /api as the page's
    buttons send them; the position the page shows follows the motor, and
    a read of our own afterwards finds it where the page left it, the
    drive still enabled (halt, not disable)."""
    page = Commission(bin_path, tmp, "--serial", runner.link)
    try:
        page.wait(lambda s: s["link"]["ok"], "the page reads the drive")
        # a jog needs an enabled drive: refused before any request
        r = page.cmd(c="jog", dir="pos", speed=20, accel=200)
        assert not r["ok"] and r["steps"] == [] and "enable it first" in r["error"], r
        assert page.cmd(c="enable")["ok"]
        r = page.cmd(c="jog", dir="pos", speed=20, accel=200)
        assert r["ok"] and len(r["steps"]) == 3, r
        page.wait(lambda s: s["position"] > 2000 and s["velocity"] != 0, "jogging forward")
        r = page.cmd(c="jogstop")
        assert r["ok"], r
        s = page.wait(lambda s: s["velocity"] == 0 and s["position"] > 2000,
                      "stopped after Jog stop")
        forward = s["position"]
        assert page.cmd(c="jog", dir="neg", speed=20, accel=200)["ok"]
        page.wait(lambda s: s["position"] < forward - 2000 and s["velocity"] != 0,
                  "jogging back")
        assert page.cmd(c="jogstop")["ok"]
        time.sleep(0.5)
        s = page.wait(lambda s: s["velocity"] == 0, "stopped again")
        s2 = page.wait(lambda x: x["position"] == s["position"], "standing still")
        shown = s2["position"]
        assert s2["state"] == "OperationEnabled", s2["state"]
    finally:
        page.stop()
    m = after_the_page(runner)
    assert m.read32(ACTUAL_POSITION) == shown
    assert m.statusword() & STATE_MASK == OPERATION_ENABLED, hex(m.statusword())


def the_page_homes_the_drive(runner, bin_path: Path, tmp: Path):
    """Homing method 3 (SPEC §8.6) to the runner's home switch at
    HOME_WINDOW, set up with the page's table writes and started with its
    Start homing: homing attained, and the origin is the switch's edge
    (position 0 with the switch active) in a read of our own afterwards."""
    page = Commission(bin_path, tmp, "--serial", runner.link)
    try:
        page.wait(lambda s: s["link"]["ok"], "the page reads the drive")
        assert page.cmd(c="enable")["ok"]
        for index, value in ((0x6098, 3), (0x609A, 1000), (0x6099, 20), (0x609B, 10),
                             (0x607C, 0)):
            r = page.cmd(c="write", index=index, value=value)
            assert r["ok"], r
        r = page.cmd(c="home")
        assert r["ok"] and len(r["steps"]) == 3, r
        s = page.wait(lambda s: s["statusword"] & HOMING_ATTAINED
                      and s["statusword"] & TARGET_REACHED, "homing done", timeout=40)
        assert not s["statusword"] & HOMING_ERROR, hex(s["statusword"])
    finally:
        page.stop()
    m = after_the_page(runner)
    assert m.read32(ACTUAL_POSITION) == 0
    sw = m.statusword()
    assert sw & HOME_SWITCH_BIT, f"the origin is the switch's edge: {sw:#06x}"
    assert sw & HOMING_ATTAINED and not sw & HOMING_ERROR, hex(sw)


def the_page_resets_a_comm_loss_fault(runner, bin_path: Path, tmp: Path):
    """PA20 = 200 ms and the drive enabled through the page; the page stops
    (its polling was the traffic): the drive faults with error register
    bit 4 (SPEC §8.7). A new page shows the fault, refuses Enable before
    sending anything, and its Fault reset brings the drive to switch on
    disabled, which a read of our own confirms after the page."""
    page = Commission(bin_path, tmp, "--serial", runner.link)
    try:
        page.wait(lambda s: s["link"]["ok"], "the page reads the drive")
        assert page.cmd(c="write", index=PA + 20, value=200)["ok"]
        assert page.cmd(c="enable")["ok"]
        page.wait(lambda s: s["state"] == "OperationEnabled", "enabled")
    finally:
        page.stop()
    m = after_the_page(runner)
    sw = 0
    for _ in range(40):
        # silence longer than PA20 between two reads (each read is traffic)
        time.sleep(0.5)
        sw = m.statusword()
        if sw & FAULT_BIT:
            break
    assert sw & FAULT_BIT, f"no comm-loss fault: {sw:#06x}"
    assert m.read(ERROR_REGISTER) & (1 << 4), "error register bit 4 (communication)"
    page = Commission(bin_path, tmp, "--serial", runner.link)
    try:
        page.wait(lambda s: s["link"]["ok"] and s["state"] == "Fault", "the page shows the fault")
        r = page.cmd(c="enable")
        assert not r["ok"] and r["steps"] == [] and "reset the fault" in r["error"], r
        r = page.cmd(c="reset")
        assert r["ok"], r
        assert [st["label"] for st in r["steps"]] == ["0x6040 = 0x0000", "0x6040 = 0x0080"], r
        page.wait(lambda s: s["state"] == "SwitchOnDisabled", "fault reset")
    finally:
        page.stop()
    m = after_the_page(runner)
    sw = m.statusword()
    assert sw & 0x004F == SWITCH_ON_DISABLED and not sw & FAULT_BIT, hex(sw)
