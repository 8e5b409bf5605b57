#!/usr/bin/env python3
"""The page on a hostile network: a flood of connections and a slow-loris
client against the release binary's `--web`, while a Modbus TCP master
polls the drive and a page client polls `/api/state`; both measured.

    .venv/web/bin/python tests/web/hostile.py [--out docs/generated/web-load.md]

prints the figures (and writes them to --out). tests/web/test_hostile.py
runs the same phases and asserts on them. Environment: MODBUS_DRIVE_BIN.
"""

from __future__ import annotations

import argparse
import os
import re
import select
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path

from pymodbus.client import ModbusTcpClient

ROOT = Path(__file__).resolve().parents[2]
# the process helpers shared with tests/e2e
_E2E = ROOT / "tests" / "e2e"
if str(_E2E) not in sys.path:
    sys.path.append(str(_E2E))
from processes import stop_process  # noqa: E402

BIN = Path(os.environ.get("MODBUS_DRIVE_BIN", ROOT / "target" / "release" / "modbus-drive"))
STATUSWORD = 0x6041


class Drive:
    """One run of the release binary with `--modbus-tcp` and `--web`."""

    def __init__(self, workdir: Path, web: str = "127.0.0.1:0", extra: tuple[str, ...] = ()):
        self.log_path = workdir / "drive.log"
        self._err = open(self.log_path, "wb")
        self.proc = subprocess.Popen(
            [str(BIN), "--no-status", "--no-pty", "--modbus-tcp", "127.0.0.1:0",
             "--web", web, *extra],
            stdout=subprocess.PIPE, stderr=self._err, cwd=workdir)
        r, _, _ = select.select([self.proc.stdout], [], [], 10)
        line = self.proc.stdout.readline() if r else b""
        if line != b"ready\n":
            self.stop()
            raise RuntimeError(f"no `ready`: {line!r}\n{self.log()}")
        log = self.log()
        self.mbap_port = int(re.search(r"modbus-tcp: listening on 127\.0\.0\.1:(\d+)", log).group(1))
        m = re.search(r"web: page on (http://[^/]+:(\d+)/(\?token=([\w.~-]+))?)", log)
        self.printed_url, self.web_port, self.token = m.group(1), int(m.group(2)), m.group(4)
        # what a client on this machine opens
        self.base = f"http://127.0.0.1:{self.web_port}/"

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def rss_kib(self) -> int:
        for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
        return 0

    def threads(self) -> int:
        return len(os.listdir(f"/proc/{self.proc.pid}/task"))

    def stop(self):
        stop_process(self.proc, self._err)


def http(url: str, method: str = "GET", headers: dict | None = None, timeout: float = 5):
    """(status, headers, body) of one request; HTTP errors are answers too."""
    req = urllib.request.Request(url, method=method, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=timeout) as r:
            return r.status, r.headers, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.headers, e.read()


def raw_status(port: int, data: bytes, timeout: float = 10) -> int | None:
    """Sends `data` as is; the status code of the answer, None if the
    connection closed without one."""
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as s:
        s.sendall(data)
        got = b""
        try:
            while b"\r\n" not in got:
                chunk = s.recv(4096)
                if not chunk:
                    break
                got += chunk
        except (ConnectionResetError, socket.timeout):
            pass
    m = re.match(rb"HTTP/1\.1 (\d+)", got)
    return int(m.group(1)) if m else None


@dataclass
class Probe:
    """Latencies of a master's reads and of a page client's polls."""
    master_s: list[float] = field(default_factory=list)
    page_s: list[float] = field(default_factory=list)
    master_errors: int = 0
    page_errors: int = 0
    # polls answered 503 or closed unanswered, then tried again at once
    page_retries: int = 0


class Watch:
    """A pymodbus master reading the statusword every 20 ms and a page
    client getting /api/state every 100 ms (as the page does), each
    timing every answer, in threads until stopped. A bounded server may
    turn a request away in a flood it cannot tell from the page (503, or
    closed unanswered): the page client then asks again at once, and its
    latency runs until it is served (10 s at most, else an error)."""

    def __init__(self, drive: Drive):
        self.drive = drive
        self.probe = Probe()
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._master, daemon=True),
                         threading.Thread(target=self._page, daemon=True)]

    def __enter__(self):
        for t in self._threads:
            t.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        for t in self._threads:
            t.join(10)

    def take(self) -> Probe:
        """What was measured since the last take."""
        p, self.probe = self.probe, Probe()
        return p

    def _master(self):
        client = ModbusTcpClient("127.0.0.1", port=self.drive.mbap_port, timeout=3, retries=0)
        client.connect()
        while not self._stop.is_set():
            t0 = time.monotonic()
            try:
                rr = client.read_holding_registers(STATUSWORD, count=1, device_id=1)
                ok = not rr.isError()
            except Exception:  # noqa: BLE001  (a timeout is what is counted)
                ok = False
                client.close()
                client.connect()
            if ok:
                self.probe.master_s.append(time.monotonic() - t0)
            else:
                self.probe.master_errors += 1
            self._stop.wait(0.02)
        client.close()

    def _page(self):
        url = self.drive.base + "api/state"
        headers = {"X-Modbus-Drive-Token": self.drive.token} if self.drive.token else {}
        while not self._stop.is_set():
            t0 = time.monotonic()
            ok = False
            while not ok and time.monotonic() - t0 < 10:
                try:
                    status, _, _ = http(url, headers=headers, timeout=10)
                except OSError:
                    status = None
                ok = status == 200
                if status in (503, None):
                    self.probe.page_retries += 1
                elif not ok:
                    break
            if ok:
                self.probe.page_s.append(time.monotonic() - t0)
            else:
                self.probe.page_errors += 1
            self._stop.wait(0.1)


def flood(port: int, n: int, timeout_s: float = 15) -> dict[str, int]:
    """`n` connections at once, each sending a request for /api/state;
    what each got: an answer's status, or closed without one."""
    socks = []
    outcome: dict[str, int] = {}
    for _ in range(n):
        s = socket.socket()
        s.setblocking(False)
        try:
            s.connect(("127.0.0.1", port))
        except BlockingIOError:
            pass
        socks.append(s)
    req = f"GET /api/state HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode()
    pending = {}
    deadline = time.monotonic() + timeout_s
    unsent = list(socks)
    while unsent and time.monotonic() < deadline:
        _, w, _ = select.select([], unsent, [], 1)
        for s in w:
            try:
                s.send(req)
                pending[s] = b""
            except OSError:
                outcome["refused"] = outcome.get("refused", 0) + 1
            unsent.remove(s)
    while pending and time.monotonic() < deadline:
        r, _, _ = select.select(list(pending), [], [], 1)
        for s in r:
            try:
                chunk = s.recv(65536)
            except OSError:
                chunk = b""
            if chunk:
                pending[s] += chunk
                continue
            m = re.match(rb"HTTP/1\.1 (\d+)", pending.pop(s))
            key = m.group(1).decode() if m else "closed"
            outcome[key] = outcome.get(key, 0) + 1
    outcome["hung"] = len(pending) + len(unsent)
    for s in socks:
        s.close()
    return outcome


def slow_loris(port: int, n: int, seconds: float) -> dict[str, float]:
    """`n` connections that send a request head one byte every 0.5 s for
    `seconds`; how many the server closed, and after how long."""
    socks = []
    for _ in range(n):
        s = socket.create_connection(("127.0.0.1", port), timeout=5)
        s.setblocking(False)
        socks.append(s)
    head = f"GET /api/state HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nX-Slow: ".encode() + b"a" * 10_000
    opened = time.monotonic()
    closed_after: dict[socket.socket, float] = {}
    i = 0
    while time.monotonic() - opened < seconds:
        for s in socks:
            if s in closed_after:
                continue
            try:
                s.send(head[i:i + 1])
                data = s.recv(4096)
                if data == b"" or data.startswith(b"HTTP/1.1 408"):
                    closed_after[s] = time.monotonic() - opened
            except BlockingIOError:
                pass
            except OSError:
                closed_after[s] = time.monotonic() - opened
        i += 1
        time.sleep(0.5)
    for s in socks:
        s.close()
    times = sorted(closed_after.values())
    return {"connections": n, "closed_by_server": len(times),
            "first_closed_s": times[0] if times else float("nan"),
            "last_closed_s": times[-1] if times else float("nan")}


def summary(xs: list[float]) -> str:
    if not xs:
        return "none"
    xs = sorted(xs)
    p99 = xs[min(len(xs) - 1, int(0.99 * len(xs)))]
    return (f"n {len(xs)}, median {statistics.median(xs) * 1000:.1f} ms, "
            f"p99 {p99 * 1000:.1f} ms, max {xs[-1] * 1000:.1f} ms")


def run_phases(drive: Drive, flood_n: int = 500, loris_n: int = 300,
               loris_s: float = 8.0) -> list[tuple[str, Probe, dict]]:
    """Quiet, flood, slow loris: what the master and the page client saw in
    each, and what the attack got."""
    out = []
    with Watch(drive) as w:
        time.sleep(2)
        out.append(("quiet", w.take(), {}))
        got = flood(drive.web_port, flood_n)
        out.append((f"{flood_n} connections at once", w.take(), got))
        got = slow_loris(drive.web_port, loris_n, loris_s)
        out.append((f"slow loris, {loris_n} connections", w.take(), got))
        time.sleep(1)
        out.append(("after", w.take(), {"threads": drive.threads(), "rss_kib": drive.rss_kib()}))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", help="write the figures (markdown) here too")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        drive = Drive(Path(tmp))
        try:
            phases = run_phases(drive)
        finally:
            drive.stop()
    lines = ["# The page under load (generated)", "",
             "Written by `tests/web/hostile.py --out` (release binary, this machine: "
             f"{os.cpu_count()} cores, shared). One drive with `--web` and `--modbus-tcp`; "
             "a pymodbus master reads 0x6041 every 20 ms over Modbus TCP and a page "
             "client GETs /api/state every 100 ms while each phase runs.", "",
             "| phase | master reads | master errors | page polls | page retries | page errors | attack got |",
             "|---|---|---|---|---|---|---|"]
    for name, p, got in phases:
        lines.append(f"| {name} | {summary(p.master_s)} | {p.master_errors} | "
                     f"{summary(p.page_s)} | {p.page_retries} | {p.page_errors} | "
                     f"{', '.join(f'{k} {v:.3g}' if isinstance(v, float) else f'{k} {v}' for k, v in got.items())} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        Path(args.out).write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
