#!/usr/bin/env python3
"""Bus-noise soak and fault checks on the virtual drive (docs/testing.md).

    tests/soak/run.sh --frames 100000 --out docs/generated/soak.md     # the CI's size
    tests/soak/run.sh --frames 1000000 --lines 8 --out docs/generated/soak-1m.md

One bus (the pseudo-terminal of `modbus-drive --drives 1,2`) carries a random mix
of valid requests to both drives (built and decoded by pymodbus' RTU framer),
requests to absent addresses, broadcasts, corrupted CRCs, truncated frames,
random bytes and frames split by long gaps, while both drives run position
moves. Every frame has an expected reply (exact bytes, or a pymodbus-decoded
shape for values that move) or none. Counted: replies expected / got,
missing, replies that should not exist, wrong replies, and at the end of
every move the position error. Every bad count must be 0. At the end each
drive's §6 counters (function 0x08) must equal what the soak sent, and the
drive process's resident memory, sampled all along, must not grow.
With --lines K, K such buses run at once (lines.py), each its own drive
process with its share of the frames and its own seed.

Then the faults (SPEC §8.7), each on a fresh drive: communication loss with
PA20 stops the motor and sets the fault (0x1001 bit 4), fault reset
recovers; a CCW limit hit in the middle of a move stops it with the quick
stop ramp and the position stays exact; both limits active at once (a
wiring fault, staged with overlapping limit windows, --allow-limit-overlap)
in the middle of a move is a fault with error register bit 0, the motor
stops with the quick stop ramp, and fault reset is refused while both stay
active. Exit status 0 only if everything holds.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import select
import signal
import subprocess
import sys
import tempfile
import time
import tty
from pathlib import Path

from pymodbus.framer import FramerRTU
from pymodbus.pdu import DecodePDU, ExceptionResponse
from pymodbus.pdu.register_message import (
    ReadHoldingRegistersRequest,
    WriteMultipleRegistersRequest,
    WriteSingleRegisterRequest,
)

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "e2e"))
from conftest import DriveRead, crc16, wait_until_read, with_crc  # noqa: E402  (the e2e harness)

import lines  # noqa: E402  (tests/soak/lines.py: several buses at once)

BIN = Path(os.environ.get("MODBUS_DRIVE_BIN", ROOT / "target" / "release" / "modbus-drive"))
DRIVES = (1, 2)
# The virtual drive stamps bytes when it *reads* them, so what separates two
# frames on its line is the time between its two reads, not between our two
# sends: a drive process held up by a busy host would read two frames at
# once and merge them. So after every send the soak first waits until the
# drive has read and stamped the bytes (`Bus.drained`, `DriveRead`), and
# only then starts its pause.
# After a frame that must stay unanswered: t3.5 for the frame to close, the
# drive's reply delay (t3.5 again) and a margin, from the moment the drive
# has stamped the frame. It is also the gap that keeps the next frame
# apart, and any gap above t3.5 does that, as it is at least as long
# between the drive's stamps. It is shorter than a loaded host may hold
# the drive up, which is safe: the soak never discards a byte from the
# line, so a reply that comes after this window is read before the next
# send (`Bus.send`: counted as a reply after its window) or inside the
# next frame's window, where it is a reply that should not exist or adds
# bytes that make that reply wrong. A late reply fails the run; it could
# pass only by being, byte for byte, the next frame's expected reply while
# that reply itself never came, and that holds for any window length.
SILENCE_S = 0.006
# Far above t3.5 (+ the drive's 1 ms poll): the halves are two frames.
LONG_GAP_S = 0.020
# A late reply is still a reply: a held-up host must not turn it into a
# missing one (and then into a wrong reply to the next frame). A host
# shared with builds and busy loops holds a process up for seconds now and
# then; waiting longer for an expected reply costs time only when it never
# comes, which fails the run anyway.
REPLY_TIMEOUT_S = 10.0
# How long `Bus.drained` waits for the drive to read (and stamp) what was
# sent; as long as a reply, for the same held-up host.
DRAIN_TIMEOUT_S = 10.0
# Resident memory of the drive process is sampled this often (frames); the
# first samples are the warm-up (buffers reaching their working size).
RSS_EVERY = 2_000
RSS_WARMUP = 10_000
# Allowed difference between the highest resident memory of the last
# and of the first (after warm-up) third of the run: a page or two of
# allocator noise, far below what a leak of a few bytes per frame adds
# over 100,000 frames.
RSS_SLACK_KIB = 256
# A line prints how far it got this often (frames), on stderr.
PROGRESS_EVERY = 10_000
# Diagnostics (0x08) sub-functions of the §6 counters, in SPEC order.
COUNTERS = {0x0B: "bus messages", 0x0C: "bus errors", 0x0D: "exceptions",
            0x0E: "slave messages", 0x0F: "no response"}

# registers (SPEC §5)
CONTROLWORD, STATUSWORD, MODE = 0x6040, 0x6041, 0x6060
VELOCITY, ACCEL, DECEL, QS_DECEL = 0x6081, 0x6083, 0x6084, 0x6085
TARGET, POSITION, ERROR_REGISTER = 0x607A, 0x6064, 0x1001
PA20 = 0x0064 + 20  # communication-loss timeout, ms


def crc_ok(frame: bytes) -> bool:
    return len(frame) >= 4 and crc16(frame) == 0


def frame_error_reply(frame: bytes) -> bytes | None:
    """What the drives answer to a frame with a bad CRC (SPEC §1-§3, PA54 = 1):
    exception 10 from the addressed drive if the frame is long enough to be
    examined, nothing otherwise (too short, broadcast, absent address)."""
    if len(frame) < 4 or len(frame) > 256 or frame[0] not in DRIVES:
        return None
    return with_crc(bytes([frame[0], frame[1] | 0x80, 10]))


def split_i32(v: int) -> list[int]:
    v &= 0xFFFFFFFF
    return [v >> 16, v & 0xFFFF]  # 0x6000 = 0: high word first


# ---------------------------------------------------------------- process


class VirtualDrive:
    def __init__(self, workdir: Path, args: list[str]):
        stamp = time.monotonic_ns()
        self.stderr_path = workdir / f"drive-{stamp}.log"
        self.link = workdir / f"tty-{stamp}"
        self.args = ["--no-status", "--pty-link", str(self.link), *args]
        self.proc: subprocess.Popen | None = None

    def __enter__(self) -> "VirtualDrive":
        self._err = open(self.stderr_path, "wb")
        self.proc = subprocess.Popen([str(BIN), *self.args], stdout=subprocess.PIPE, stderr=self._err)
        r, _, _ = select.select([self.proc.stdout], [], [], 10)
        line = self.proc.stdout.readline() if r else b""
        if line != b"ready\n":
            raise RuntimeError(f"no `ready` from {self.args}: {self.stderr()}")
        return self

    def stderr(self) -> str:
        return self.stderr_path.read_text(errors="replace")

    def rss_kib(self) -> int:
        for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
        raise RuntimeError("no VmRSS")

    def __exit__(self, *exc):
        if self.proc and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self._err.close()


class Bus:
    """The master's end of the one RTU line: the drive's pseudo-terminal,
    opened as a serial port is (raw, 8N1). Every frame sent is also
    classified into the §6 counters each drive must have counted."""

    def __init__(self, vd: VirtualDrive):
        self.fd = os.open(vd.link, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        tty.setraw(self.fd)
        self.framer = FramerRTU(DecodePDU(False))
        self.unread = DriveRead(vd.proc.pid)
        self.sends = 0
        self.confirmed = 0  # sends the drive was seen to have read
        self.late_reads = 0  # sends the drive had not read after DRAIN_TIMEOUT_S
        # told of bytes from the drive found unread when an exchange starts
        self.on_stray = lambda data: None
        self.expected = {d: dict.fromkeys(COUNTERS.values(), 0) for d in DRIVES}

    def close(self):
        os.close(self.fd)

    def classify(self, frame: bytes):
        """What one frame on the line adds to each drive's §6 counters
        (docs/protocol.md): exceptions are added by `exception_replied`."""
        for d in DRIVES:
            e = self.expected[d]
            if len(frame) < 4 or not crc_ok(frame):
                e["bus errors"] += 1
                continue
            e["bus messages"] += 1
            if frame[0] in (d, 0):
                e["slave messages"] += 1
            if frame[0] == 0:
                e["no response"] += 1

    def exception_replied(self, reply: bytes | None):
        if reply and len(reply) == 5 and reply[1] & 0x80 and reply[0] in DRIVES:
            self.expected[reply[0]]["exceptions"] += 1

    def send(self, data: bytes, exchange_starts: bool = True):
        """Sends `data` and returns once the drive process has read it.
        At the start of an exchange, bytes from the drive that nobody read
        yet cannot be a reply to it: they are a reply that came after its
        window. (Inside an exchange, the part of a split frame sent after
        the gap follows the first part's reply.)"""
        if exchange_starts:
            stale = self.pending()
            if stale:
                self.on_stray(stale)
        self.classify(data)
        self.unread.sent += len(data)
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(self.fd, view):]
            except BlockingIOError:
                select.select([], [self.fd], [], 1)
        self.drained()

    def drained(self) -> None:
        """Waits until the drive process has read everything sent so far
        (`wait_until_read`): from then on the drive has stamped the bytes,
        and a pause we make is a pause on its line."""
        self.sends += 1
        seen = wait_until_read(self.unread, DRAIN_TIMEOUT_S)
        if seen:
            self.confirmed += 1
        elif seen is not None:
            self.late_reads += 1

    def read(self, want: int | None, timeout: float) -> bytes:
        """Bytes until `want` (> 0) arrived (then a short quiet period, so
        that extra bytes are seen), or until `timeout` without them; with
        `want` 0 or None, everything that arrives within `timeout`."""
        out = b""
        deadline = time.monotonic() + timeout
        while True:
            if want and len(out) >= want:
                deadline = min(deadline, time.monotonic() + 0.002)
            left = deadline - time.monotonic()
            if left <= 0:
                return out
            r, _, _ = select.select([self.fd], [], [], left)
            if r:
                try:
                    out += os.read(self.fd, 4096)
                except BlockingIOError:
                    pass

    def pending(self) -> bytes:
        """What has arrived and not been read, without waiting."""
        out = b""
        while select.select([self.fd], [], [], 0)[0]:
            try:
                chunk = os.read(self.fd, 4096)
            except BlockingIOError:
                break
            if not chunk:
                break
            out += chunk
        return out

    def read_reply(self, timeout: float) -> bytes:
        """One reply frame: its length follows from its first bytes."""
        out = self.read(3, timeout)
        if len(out) < 3:
            return out
        if out[1] & 0x80:
            want = 5
        elif out[1] == 0x03:
            want = 5 + out[2]
        else:
            want = 8
        return out + self.read(want - len(out), timeout) if len(out) < want else out

    def request(self, pdu) -> tuple[bytes, object]:
        """A valid request built by pymodbus; its reply decoded by pymodbus."""
        frame = self.framer.buildFrame(pdu)
        self.send(frame)
        reply = self.read_reply(REPLY_TIMEOUT_S) if pdu.dev_id else self.read(0, SILENCE_S)
        if not reply:
            return reply, None
        used, decoded = self.framer.handleFrame(reply, pdu.dev_id, 0)
        return reply, decoded if used == len(reply) else None

    def read_regs(self, dev: int, addr: int, count: int) -> list[int]:
        _, r = self.request(ReadHoldingRegistersRequest(address=addr, count=count, dev_id=dev))
        if r is None or isinstance(r, ExceptionResponse) or len(r.registers) != count:
            raise AssertionError(f"read {addr:#06x} x{count} from {dev}: {r}")
        return list(r.registers)

    def write(self, dev: int, addr: int, value: int):
        _, r = self.request(WriteSingleRegisterRequest(address=addr, registers=[value & 0xFFFF], dev_id=dev))
        if dev and (r is None or isinstance(r, ExceptionResponse)):
            raise AssertionError(f"write {addr:#06x} = {value} to {dev}: {r}")

    def write_many(self, dev: int, addr: int, values: list[int]):
        pdu = WriteMultipleRegistersRequest(address=addr, registers=[v & 0xFFFF for v in values], dev_id=dev)
        _, r = self.request(pdu)
        if dev and (r is None or isinstance(r, ExceptionResponse)):
            raise AssertionError(f"write {addr:#06x} = {values} to {dev}: {r}")

    def statusword(self, dev: int) -> int:
        return self.read_regs(dev, STATUSWORD, 1)[0]

    def position(self, dev: int) -> int:
        hi, lo = self.read_regs(dev, POSITION, 2)
        v = hi << 16 | lo
        return v - (1 << 32) if v & 0x8000_0000 else v

    def enable(self, dev: int, mode: int):
        self.write(dev, MODE, mode)
        for cw in (0x06, 0x07, 0x0F):
            self.write(dev, CONTROLWORD, cw)
        sw = self.statusword(dev)
        assert sw & 0x6F == 0x27, f"drive {dev} not in operation enabled: {sw:#06x}"

    def wait(self, dev: int, cond, timeout: float, what: str) -> int:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            sw = self.statusword(dev)
            if cond(sw):
                return sw
            time.sleep(0.01)
        raise AssertionError(f"drive {dev}: {what} not within {timeout} s (statusword {sw:#06x})")


# ---------------------------------------------------------------- noise soak

# ramps of the soak moves: 0.1 rev/s and 0.1 rev/s², PA10 = 10000 steps/rev
SOAK_VELOCITY, SOAK_ACCEL, SOAK_DECEL, SOAK_QS = 50, 100, 100, 200


class Soak:
    def __init__(self, bus: Bus, seed: int, vd: VirtualDrive, name: str):
        self.bus, self.rng, self.seed, self.vd, self.name = bus, random.Random(seed), seed, vd, name
        bus.on_stray = self.stray
        self.counter_mismatches = 0
        self.rss_growth = 0
        self.elapsed = 0.0
        self.rss: list[tuple[int, int]] = []  # (frames, KiB)
        self.report: list[str] = []
        self.n = dict.fromkeys(
            ("frames", "replies expected", "replies got", "missing replies",
             "replies that should not exist", "wrong replies", "moves checked",
             "position errors"), 0)
        self.kinds: dict[str, int] = {}
        self.target = {d: 0 for d in DRIVES}
        self.moving = {d: False for d in DRIVES}

    def count(self, kind: str):
        self.kinds[kind] = self.kinds.get(kind, 0) + 1
        self.n["frames"] += 1

    def expect(self, sent: list[bytes], replies: list[bytes | None], gap_s: float = 0.0, shape=None):
        """Sends the frame(s) (with `gap_s` between parts) and compares what
        comes back with the concatenated expected replies; `shape` checks a
        reply whose values move (pymodbus-decoded) instead of its bytes."""
        for i, part in enumerate(sent):
            if i:
                time.sleep(gap_s)
            self.bus.send(part, exchange_starts=not i)
        want = b"".join(r for r in replies if r)
        for r in replies:
            self.bus.exception_replied(r)
        n_expected = sum(1 for r in replies if r) + (1 if shape else 0)
        self.n["replies expected"] += n_expected
        if shape:
            got = self.bus.read(shape[0], REPLY_TIMEOUT_S)
        elif want:
            got = self.bus.read(len(want), REPLY_TIMEOUT_S)
        else:
            got = self.bus.read(0, SILENCE_S)
        if n_expected and replies[-1] is None and not shape:
            # the last part is still an open frame in the drives: let it
            # close (t3.5) before the next frame, or the two would merge
            time.sleep(SILENCE_S)
        if not n_expected:
            if got:
                self.n["replies that should not exist"] += 1
                self.log(f"unexpected reply {got.hex()} to {[p.hex() for p in sent]}")
            return
        if not got:
            self.n["missing replies"] += 1
            self.log(f"no reply to {[p.hex() for p in sent]}")
            return
        ok = shape[1](got) if shape else got == want
        if ok:
            self.n["replies got"] += n_expected
        else:
            self.n["wrong replies"] += 1
            self.log(f"wrong reply {got.hex()} (expected {want.hex() or 'shape'}) to {[p.hex() for p in sent]}")

    def stray(self, data: bytes):
        self.n["replies that should not exist"] += 1
        self.log(f"reply after its window {data.hex()} (unread at the next send)")

    def log(self, msg: str):
        print(f"  ! {self.name}, frame {self.n['frames']}: {msg}", file=sys.stderr, flush=True)

    # -- frame kinds

    def valid(self, dev: int) -> tuple[bytes, bytes | None, object]:
        """A valid request to `dev` (0: broadcast): frame, exact reply or a
        (length, check) shape for registers whose values move."""
        fr = self.bus.framer
        k = self.rng.randrange(5)
        if k == 0:  # the ramps we wrote: exact values
            req = fr.buildFrame(ReadHoldingRegistersRequest(address=ACCEL, count=3, dev_id=dev))
            body = bytes([dev, 3, 6]) + b"".join(v.to_bytes(2, "big") for v in (SOAK_ACCEL, SOAK_DECEL, SOAK_QS))
            return req, with_crc(body), None
        if k == 1:  # statusword .. actual velocity: 6 words that move
            req = fr.buildFrame(ReadHoldingRegistersRequest(address=STATUSWORD, count=6, dev_id=dev))

            def check(reply, dev=dev):
                used, r = FramerRTU(DecodePDU(False)).handleFrame(reply, dev, 0)
                return used == len(reply) and not isinstance(r, ExceptionResponse) and \
                    r is not None and len(r.registers) == 6
            return req, None, (5 + 12, check)
        if k == 2:  # rewrite the quick stop deceleration: echo
            req = fr.buildFrame(WriteSingleRegisterRequest(address=QS_DECEL, registers=[SOAK_QS], dev_id=dev))
            return req, req, None
        if k == 3:  # rewrite the three ramps: FC10 reply
            req = fr.buildFrame(WriteMultipleRegistersRequest(
                address=ACCEL, registers=[SOAK_ACCEL, SOAK_DECEL, SOAK_QS], dev_id=dev))
            return req, with_crc(req[:6]), None
        # a register that does not exist: exception 11 (SPEC §5.2)
        req = fr.buildFrame(ReadHoldingRegistersRequest(address=0x6090, count=1, dev_id=dev))
        return req, with_crc(bytes([dev, 0x83, 11])), None

    def one(self):
        rng = self.rng
        kind = rng.choices(
            ["valid", "absent", "broadcast", "bad crc", "truncated", "random", "long gap"],
            weights=[40, 10, 8, 10, 10, 10, 8])[0]
        self.count(kind)
        dev = rng.choice(DRIVES)
        if kind == "valid":
            req, rep, shape = self.valid(dev)
            self.expect([req], [rep], shape=shape)
        elif kind == "absent":
            other = rng.choice([a for a in range(3, 256)])
            req, _, _ = self.valid(1)
            self.expect([with_crc(bytes([other]) + req[1:-2])], [None])
        elif kind == "broadcast":
            req, _, _ = self.valid(1)
            body = bytes([0]) + req[1:-2]
            if body[1] == 0x03:
                body = bytes([0, 0x03, 0x60, 0x41, 0, 1])  # a broadcast read: ignored
            self.expect([with_crc(body)], [None])
        elif kind == "bad crc":
            req, _, _ = self.valid(rng.choice([dev, dev, 7]))
            bad = req[:-2] + bytes([req[-2] ^ rng.randrange(1, 256), req[-1]])
            self.expect([bad], [frame_error_reply(bad)])
        elif kind == "truncated":
            req, _, _ = self.valid(dev)
            cut = req[: rng.randrange(1, len(req))]
            if crc_ok(cut):
                return
            self.expect([cut], [frame_error_reply(cut)])
        elif kind == "random":
            junk = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40)))
            if rng.random() < 0.5:
                junk = bytes([rng.choice(DRIVES)]) + junk[1:]
            if crc_ok(junk):
                return
            self.expect([junk], [frame_error_reply(junk)])
        elif kind == "long gap":
            req, _, _ = self.valid(dev)
            k = rng.randrange(1, len(req))
            a, b = req[:k], req[k:]
            if crc_ok(a) or crc_ok(b):
                return
            self.expect([a, b], [frame_error_reply(a), frame_error_reply(b)], gap_s=LONG_GAP_S)
    # -- moves

    def moves(self):
        """Checks finished moves, starts new ones (position mode, SPEC §8.4)."""
        for d in DRIVES:
            sw = self.bus.statusword(d)
            if self.moving[d]:
                if not sw & (1 << 10):
                    continue
                pos = self.bus.position(d)
                self.n["moves checked"] += 1
                if pos != self.target[d]:
                    self.n["position errors"] += 1
                    self.log(f"drive {d} ended at {pos}, target {self.target[d]}")
                self.moving[d] = False
            target = self.rng.randrange(-30_000, 30_000)
            self.bus.write_many(d, TARGET, split_i32(target))
            self.bus.write(d, CONTROLWORD, 0x1F)  # new set-point, absolute
            self.bus.write(d, CONTROLWORD, 0x0F)
            self.target[d], self.moving[d] = target, True

    def run(self, frames: int) -> bool:
        for d in DRIVES:
            self.bus.write_many(d, VELOCITY, split_i32(SOAK_VELOCITY))
            self.bus.write_many(d, ACCEL, [SOAK_ACCEL, SOAK_DECEL, SOAK_QS])
            self.bus.enable(d, 1)
        t0 = time.monotonic()
        next_rss = 0
        while self.n["frames"] < frames:
            if self.n["frames"] % 100 == 0:
                self.moves()
            if self.n["frames"] % PROGRESS_EVERY == 0 and self.n["frames"]:
                print(f"{self.name}: {self.n['frames']} of {frames} frames, "
                      f"{time.monotonic() - t0:.0f} s", file=sys.stderr, flush=True)
            if self.n["frames"] >= next_rss:
                self.rss.append((self.n["frames"], self.vd.rss_kib()))
                next_rss += RSS_EVERY
            self.one()
        # let the last moves finish and check them
        for d in DRIVES:
            if self.moving[d]:
                self.bus.wait(d, lambda sw: sw & (1 << 10), 10, "target reached")
        self.moves()
        self.rss.append((self.n["frames"], self.vd.rss_kib()))
        elapsed = time.monotonic() - t0
        self.elapsed = elapsed
        self.say(f"{self.name} (seed {self.seed}): {self.n['frames']} frames on one bus (a pty), drives {DRIVES}, "
                 f"{elapsed:.0f} s ({elapsed / self.n['frames'] * 1000:.2f} ms a frame)")
        self.say("  by kind: " + ", ".join(f"{k} {v}" for k, v in sorted(self.kinds.items())))
        bad = ("missing replies", "replies that should not exist", "wrong replies", "position errors")
        for k, v in self.n.items():
            self.say(f"  {k:<32}{v:>8}" + ("   (must be 0)" if k in bad else ""))
        good = all(self.n[k] == 0 for k in bad) and self.n["moves checked"] > 0
        good &= self.n["replies got"] == self.n["replies expected"]
        good &= self.check_counters()
        good &= self.check_rss()
        return good

    def say(self, line: str):
        print(line)
        self.report.append(line)

    def check_counters(self) -> bool:
        """Each drive's §6 counters (16-bit, wrapping) against what the
        soak sent; each read counts itself (counted before it is handled)."""
        good = True
        for d in DRIVES:
            for sub, name in COUNTERS.items():
                req = with_crc(bytes([d, 0x08, 0x00, sub, 0x00, 0x00]))
                self.bus.send(req)
                reply = self.bus.read(8, REPLY_TIMEOUT_S)
                want = self.bus.expected[d][name] & 0xFFFF
                got = int.from_bytes(reply[4:6], "big") if len(reply) == 8 and crc_ok(reply) else None
                same = got == want
                good &= same
                self.counter_mismatches += not same
                self.say(f"  drive {d} {name:<24}{got if got is not None else '-':>8}   "
                         f"sent {self.bus.expected[d][name]} (mod 65536: {want})"
                         + ("" if same else "   MISMATCH"))
        return good

    def check_rss(self) -> bool:
        """Resident memory after the warm-up: the last third's highest
        sample against the first third's."""
        after = [kib for f, kib in self.rss if f >= min(RSS_WARMUP, self.n["frames"] // 10)]
        third = max(1, len(after) // 3)
        first, last = max(after[:third]), max(after[-third:])
        growth = last - first
        self.rss_growth = growth
        self.say(f"  drive RSS (KiB), {len(self.rss)} samples every {RSS_EVERY} frames: "
                 f"start {self.rss[0][1]}, first third max {first}, last third max {last}, "
                 f"growth {growth:+d}   (must be <= {RSS_SLACK_KIB})")
        return growth <= RSS_SLACK_KIB


# ---------------------------------------------------------------- faults


def fault_comm_loss(workdir: Path) -> None:
    with VirtualDrive(workdir, ["--drives", "1"]) as vd:
        bus = Bus(vd)
        bus.write_many(1, VELOCITY, split_i32(20))  # velocity mode: 2 rev/s
        bus.write_many(1, ACCEL, [100, 100, 200])
        bus.write(1, PA20, 200)  # 200 ms
        bus.enable(1, 3)
        time.sleep(0.1)
        bus.statusword(1)  # last frame before the silence
        time.sleep(0.5)  # > PA20 without a frame
        sw = bus.statusword(1)
        assert sw & 0x4F == 0x08, f"communication loss: not in fault: {sw:#06x}"
        err = bus.read_regs(1, ERROR_REGISTER, 1)[0]
        assert err & (1 << 4), f"communication loss: error register {err:#06x}"
        p1 = bus.position(1)
        time.sleep(0.2)
        assert bus.position(1) == p1, "communication loss: the motor still moves"
        assert not bus.statusword(1) & (1 << 9), "communication loss: bit 9 (running) set"
        bus.write(1, PA20, 0)
        bus.write(1, CONTROLWORD, 0x00)
        bus.write(1, CONTROLWORD, 0x80)  # fault reset (bit 7 rising edge)
        sw = bus.statusword(1)
        assert sw & 0x4F == 0x40, f"fault reset: not switch on disabled: {sw:#06x}"
        bus.enable(1, 3)  # and it runs again
        bus.wait(1, lambda sw: sw & (1 << 9), 2, "running again")
        print("fault: communication loss (PA20 = 200 ms) stops the motor, sets fault + 0x1001 bit 4;"
              " fault reset recovers: ok")


def fault_both_limits(workdir: Path) -> None:
    # A wiring fault: the CW limit active at and below 1000, the CCW limit at
    # and above 500, so both are active on 500..=1000 (--allow-limit-overlap).
    cw_edge, ccw_edge = 1000, 500
    args = ["--drives", "1", "--cw-limit", str(cw_edge), "--ccw-limit", str(ccw_edge),
            "--allow-limit-overlap"]
    with VirtualDrive(workdir, args) as vd:
        bus = Bus(vd)
        # 0.5 rev/s, 10 rev/s², quick stop 10 rev/s² (PA10 = 10000 steps/rev)
        v, a, qs = 5, 100, 100
        bus.write_many(1, VELOCITY, split_i32(v))
        bus.write_many(1, ACCEL, [a, a, qs])
        bus.enable(1, 1)  # at 0 only the CW limit is active: no fault
        err = bus.read_regs(1, ERROR_REGISTER, 1)[0]
        assert err == 0, f"both limits: error register {err:#06x} with one limit active"
        bus.write_many(1, TARGET, split_i32(5000))
        bus.write(1, CONTROLWORD, 0x1F)
        bus.write(1, CONTROLWORD, 0x0F)
        bus.wait(1, lambda sw: sw & 0x4F == 0x08, 5, "fault")
        err = bus.read_regs(1, ERROR_REGISTER, 1)[0]
        assert err == 1 << 0, f"both limits: error register {err:#06x}, want bit 0 alone"
        sw = bus.statusword(1)
        assert sw & (1 << 14) and sw & (1 << 15), f"both limits: bits 14/15 not both set: {sw:#06x}"
        p1 = bus.position(1)
        time.sleep(0.2)
        assert bus.position(1) == p1, "both limits: the motor still moves in fault"
        # the fault reaction is the quick stop ramp from cruise: v²/2d past
        # the edge, started by the control loop as a new goal, so it begins
        # within the planner's horizon (3 ms) of the control call at the
        # edge's step: at most 3 ms of cruise steps late, and the ramp's
        # last whole step
        v_steps, qs_steps = v * 1000, qs * 1000
        expect = ccw_edge + v_steps ** 2 / (2 * qs_steps)
        late = v_steps * 3 / 1000 + 2
        assert expect - 2 <= p1 <= expect + late, \
            f"both limits: stopped at {p1}, quick stop ramp ends at {expect:.0f} (+{late:.0f} allowed)"
        # fault reset is refused while both are still active (SPEC §8.1)
        bus.write(1, CONTROLWORD, 0x00)
        bus.write(1, CONTROLWORD, 0x80)
        sw = bus.statusword(1)
        assert sw & 0x4F == 0x08, f"both limits: fault reset accepted while both active: {sw:#06x}"
        print(f"fault: both limits active (overlap {ccw_edge}..{cw_edge}) mid-move: fault, 0x1001 = bit 0,"
              f" quick stop at {p1} (v²/2d: {expect:.0f}), fault reset refused while both active: ok")


def fault_limit_mid_move(workdir: Path) -> None:
    limit = 5000
    with VirtualDrive(workdir, ["--drives", "1", "--ccw-limit", str(limit), "--cw-limit", "-50000"]) as vd:
        bus = Bus(vd)
        # 2 rev/s, 10 rev/s² (cruise after 2000 steps, before the limit),
        # quick stop 4 rev/s² (PA10 = 10000 steps/rev)
        v, a, qs = 20, 100, 40
        bus.write_many(1, VELOCITY, split_i32(v))
        bus.write_many(1, ACCEL, [a, a, qs])
        bus.enable(1, 1)
        bus.write_many(1, TARGET, split_i32(40_000))
        bus.write(1, CONTROLWORD, 0x1F)
        bus.write(1, CONTROLWORD, 0x0F)
        bus.wait(1, lambda sw: sw & (1 << 15), 5, "CCW limit active (bit 15)")
        bus.wait(1, lambda sw: not sw & (1 << 9), 5, "stopped")
        pos = bus.position(1)
        # at cruise when the limit came: v²/(2·qs) steps of quick stop ramp
        v_steps, qs_steps = v * 1000, qs * 1000
        expect = limit + v_steps ** 2 / (2 * qs_steps)
        # the ramp starts at the limit's step; 2 % of the stopping distance
        # covers the ramp's last whole steps and a control period
        assert abs(pos - expect) <= 0.02 * (expect - limit), f"limit: stopped at {pos}, quick stop ramp ends at {expect:.0f}"
        assert bus.statusword(1) & (1 << 15), "limit: bit 15 dropped while on the limit"
        # the position is still exact: back below the limit, bit 15 clears
        # exactly at the edge's position, and a move lands exactly
        for target in (limit, limit - 1, 1234, 0):
            bus.write(1, CONTROLWORD, 0x0F)  # leave quick stop / re-enable if needed
            bus.write_many(1, TARGET, split_i32(target))
            bus.write(1, CONTROLWORD, 0x1F)
            bus.write(1, CONTROLWORD, 0x0F)
            bus.wait(1, lambda sw: sw & (1 << 10) and not sw & (1 << 9), 10, f"at {target}")
            got = bus.position(1)
            assert got == target, f"limit: move to {target} ended at {got}"
            ccw = bool(bus.statusword(1) & (1 << 15))
            assert ccw == (target >= limit), f"limit: bit 15 = {ccw} at {target}"
        print(f"fault: CCW limit at {limit} mid-move stops with the quick-stop ramp at {pos}"
              f" (v²/2d: {expect:.0f}); moves afterwards land exactly, bit 15 flips at the edge: ok")


def run_line(frames: int, seed: int, name: str, result: Path) -> int:
    """One bus, `frames` frames: the soak of one line (lines.py runs each
    line as its own process through this). Writes what it found to
    `result` (JSON) for the totals."""
    keep = os.environ.get("SOAK_KEEP")  # a directory for the drive's log
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(keep or tmp)
        work.mkdir(parents=True, exist_ok=True)
        with VirtualDrive(work, ["--drives", "1,2"]) as vd:
            bus = Bus(vd)
            soak = Soak(bus, seed, vd, name)
            try:
                ok = soak.run(frames)
            except AssertionError as e:
                # a request of the soak's own (a move, a counter) went
                # wrong: the line stops there and does not hold
                soak.say(f"{name} (seed {seed}): STOPPED at frame {soak.n['frames']} of {frames}: {e}")
                ok = False
            # The soak sends every frame in one write and never pauses
            # inside one, so the drives must see no broken frame (silence
            # > t1.5 inside it). Both drives frame the same line: drive 1's
            # count is the line's.
            broken = len(re.findall(r"drive 1 on pty: broken frame", vd.stderr()))
            soak.say(f"  {'broken frames in the drive log':<32}{broken:>8}   (must be 0)")
            # Sends the drive had not read after DRAIN_TIMEOUT_S: the pause
            # after them was not a pause on the drive's line.
            soak.say(f"  {'sends read late by the drive':<32}{bus.late_reads:>8}   (must be 0)")
            how = "(rchar, wchan)" if bus.unread.wchan_tells else "(rchar only)"
            soak.say(f"  {'sends seen read ' + how:<32}{bus.confirmed:>8}   of {bus.sends}")
            ok &= broken == 0 and bus.late_reads == 0
            bus.close()
    result.write_text(json.dumps({
        "name": name, "seed": seed, "ok": ok, "elapsed_s": soak.elapsed,
        "report": soak.report, "counts": soak.n, "kinds": soak.kinds,
        "counter mismatches": soak.counter_mismatches, "rss growth": soak.rss_growth,
        "rss limit": RSS_SLACK_KIB,
        "broken frames": broken, "late reads": bus.late_reads,
        "sends": bus.sends, "sends seen read": bus.confirmed, "seen by": how,
    }))
    return 0 if ok else 1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=1_000_000, help="in all, shared by the lines")
    ap.add_argument("--lines", type=int, default=1,
                    help="independent buses run at once, each `modbus-drive --drives 1,2` on its own pty")
    ap.add_argument("--out", help="write the figures (markdown) to this file too")
    ap.add_argument("--seed", type=int, default=7, help="line i uses seed + i")
    ap.add_argument("--no-faults", action="store_true")
    ap.add_argument("--line-json", type=Path, help=argparse.SUPPRESS)  # one line, for lines.py
    ap.add_argument("--line-name", default="line 0", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.line_json:
        return run_line(args.frames, args.seed, args.line_name, args.line_json)
    if args.lines < 1 or args.frames < args.lines:
        ap.error("--lines must be at least 1 and at most --frames")
    ok = lines.run(Path(__file__), args)
    if not args.no_faults:
        with tempfile.TemporaryDirectory() as tmp:
            work = Path(os.environ.get("SOAK_KEEP") or tmp)
            for check in (fault_comm_loss, fault_both_limits, fault_limit_mid_move):
                try:
                    check(work)
                except AssertionError as e:
                    print(f"fault: {check.__name__}: FAILED: {e}")
                    ok = False
    print("soak: ok" if ok else "soak: FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
