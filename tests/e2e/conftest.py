"""Harness for the end-to-end tests: the release binary, started
as a user starts it, driven by real Modbus masters over its pseudo-terminal
and over TCP. Every started process is stopped in a `finally`, whatever the
test did; every wait has a timeout."""

from __future__ import annotations

import os
import re
import select
import signal
import socket
import struct
import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
import serial
from pymodbus import FramerType
from pymodbus.client import ModbusSerialClient, ModbusTcpClient

# the shared process helpers of tests/e2e, however this module was loaded
# (pytest, or by path from tests/fw_sim and tests/web)
_E2E = Path(__file__).resolve().parent
if str(_E2E) not in sys.path:
    sys.path.append(str(_E2E))
from processes import stop_process  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def target_dir() -> Path:
    """Where cargo puts the build: `cargo metadata` knows (it honours
    CARGO_TARGET_DIR and .cargo/config.toml); ./target without cargo."""
    try:
        out = subprocess.run(["cargo", "metadata", "--format-version", "1", "--no-deps"],
                             cwd=ROOT, capture_output=True, check=True, timeout=60).stdout
        return Path(json.loads(out)["target_directory"])
    except (OSError, subprocess.SubprocessError, ValueError, KeyError):
        return Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))


BIN = Path(os.environ.get("MODBUS_DRIVE_BIN") or target_dir() / "release" / "modbus-drive")
READY_TIMEOUT_S = 10.0
STOP_TIMEOUT_S = 5.0
BAUD = 115200


def crc16(data: bytes) -> int:
    """CRC-16/MODBUS (SPEC §1), independent of the drive's implementation."""
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def with_crc(body: bytes) -> bytes:
    c = crc16(body)
    return body + bytes([c & 0xFF, c >> 8])


def hexb(s: str) -> bytes:
    return bytes.fromhex(s.replace(" ", ""))


class VirtualDrive:
    """One run of `modbus-drive`."""

    def __init__(self, workdir: Path, args: list[str], tcp: bool = True, pty: bool = True):
        self.workdir = workdir
        self.link = workdir / "ttyVD"
        self.args = list(args)
        if pty:
            self.args = ["--pty-link", str(self.link)] + self.args
        else:
            self.args = ["--no-pty"] + self.args
        if tcp:
            self.args += ["--tcp", "127.0.0.1:0"]
        self.stderr_path = workdir / f"stderr-{time.monotonic_ns()}.log"
        self.proc: subprocess.Popen | None = None
        self.tcp_port: int | None = None
        self.modbus_tcp_port: int | None = None
        self.returncode: int | None = None

    def start(self) -> "VirtualDrive":
        self._stderr = open(self.stderr_path, "wb")
        self.proc = subprocess.Popen(
            [str(BIN), *self.args],
            stdout=subprocess.PIPE,
            stderr=self._stderr,
            cwd=self.workdir,
        )
        deadline = time.monotonic() + READY_TIMEOUT_S
        line = b""
        while time.monotonic() < deadline:
            r, _, _ = select.select([self.proc.stdout], [], [], 0.1)
            if r:
                line = self.proc.stdout.readline()
                break
            if self.proc.poll() is not None:
                break
        if line != b"ready\n":
            self.stop()
            raise RuntimeError(f"no `ready` from {self.args}: {line!r}\n{self.stderr()}")
        m = re.search(r"\] tcp: listening on 127\.0\.0\.1:(\d+)", self.stderr())
        if m:
            self.tcp_port = int(m.group(1))
        m = re.search(r"\] modbus-tcp: listening on 127\.0\.0\.1:(\d+)", self.stderr())
        if m:
            self.modbus_tcp_port = int(m.group(1))
        return self

    def stderr(self) -> str:
        return self.stderr_path.read_text(errors="replace")

    def stop(self, sig: int = signal.SIGTERM) -> int | None:
        """Stops the process (signal, then kill after a timeout)."""
        if self.proc is None:
            return self.returncode
        try:
            self.returncode = stop_process(self.proc, self._stderr, sig=sig)
        finally:
            self.proc = None
        return self.returncode

    # masters -----------------------------------------------------------

    def client(self, transport: str):
        """A pymodbus RTU client over `transport` ("pty" or "tcp")."""
        if transport == "pty":
            c = ModbusSerialClient(str(self.link), framer=FramerType.RTU, baudrate=BAUD,
                                   parity="N", timeout=1, retries=0)
        else:
            c = ModbusTcpClient("127.0.0.1", port=self.tcp_port, framer=FramerType.RTU,
                                timeout=1, retries=0)
        assert c.connect(), f"cannot connect over {transport}"
        return c

    def raw(self, transport: str) -> "RawBus":
        return RawBus(self, transport)


class ReceiveQueue:
    """Bytes received but not yet read by the process owning the IPv4 TCP
    socket 127.0.0.1:local_port <-> 127.0.0.1:remote_port: the kernel's
    `rqueue` of that socket, asked by its 4-tuple over Linux' sock_diag
    netlink (what `ss` uses; ~25 µs; /proc/net/tcp takes ~4 ms here). None
    where that cannot be asked (not Linux)."""

    NETLINK_SOCK_DIAG, SOCK_DIAG_BY_FAMILY, NLM_F_REQUEST = 4, 20, 1
    TCP_ESTABLISHED = 1

    def __init__(self, local_port: int, remote_port: int):
        lo = socket.inet_aton("127.0.0.1") + bytes(12)
        sockid = struct.pack("!HH", local_port, remote_port) + lo + lo + \
            struct.pack("=III", 0, 0xFFFF_FFFF, 0xFFFF_FFFF)  # any interface, no cookie
        # inet_diag_req_v2: family, protocol, ext, pad, states, id
        req = struct.pack("=BBBBI", socket.AF_INET, socket.IPPROTO_TCP, 0, 0, 0xFFFF_FFFF) + sockid
        self.request = struct.pack("=IHHII", 16 + len(req), self.SOCK_DIAG_BY_FAMILY,
                                   self.NLM_F_REQUEST, 1, 0) + req
        self.ports = (local_port, remote_port)
        try:
            self.nl = socket.socket(socket.AF_NETLINK, socket.SOCK_DGRAM, self.NETLINK_SOCK_DIAG)
        except (OSError, AttributeError):
            self.nl = None

    def __call__(self) -> int | None:
        if self.nl is None:
            return None
        try:
            self.nl.send(self.request)
            data = self.nl.recv(8192)
        except OSError:
            return None
        _, kind = struct.unpack_from("=IH", data)
        if kind != self.SOCK_DIAG_BY_FAMILY or len(data) < 16 + 76:
            return None  # an error message: no such socket
        # inet_diag_msg: family, state, timer, retrans, id (48 bytes),
        # expires, rqueue, wqueue, ...
        state = data[17]
        ports = struct.unpack_from("!HH", data, 20)
        rqueue = struct.unpack_from("=I", data, 16 + 4 + 48 + 4)[0]
        # a 4-tuple that is not established finds the listener instead
        return rqueue if state == self.TCP_ESTABLISHED and ports == self.ports else None

    def close(self):
        if self.nl is not None:
            self.nl.close()


def wait_until_read(unread: "ReceiveQueue", timeout: float) -> bool | None:
    """Waits until the drive has read every byte sent on a TCP line (its
    socket's receive queue is empty): True once it has, False if it has not
    after `timeout` s, None if that cannot be known here. The virtual drive
    stamps bytes when it reads them, so a pause that must be a pause on its
    line (a frame's end, a gap inside a frame) starts only after this."""
    deadline = time.monotonic() + timeout
    while True:
        queued = unread()
        if queued is None or queued == 0:
            return None if queued is None else True
        if time.monotonic() > deadline:
            return False
        time.sleep(0.0002)


class DriveRead:
    """Whether the drive process has read every byte sent to it: its
    `rchar` (/proc/PID/io: bytes its read calls returned) against what
    was sent, for a line that is the only thing it reads (a pty with one
    master: the soak's bus, `RawBus` on the pty).
    (FIONREAD on the pty cannot tell: bytes written reach the reader's
    queue through a kernel worker, so an empty queue may mean "not there
    yet".) None where /proc/PID/io cannot be read.

    Read is not stamped yet: the drive takes the time of the bytes after
    its read returns, so a drive held up between the two would stamp them
    late, and a pause started at the read would be shorter on its clock
    (two frames merge). So the bytes count as read only once the drive is
    also back asleep in poll (/proc/PID/wchan), which it reaches only after
    stamping and handling what it read: from then on a pause of ours is at
    least as long on its clock."""

    def __init__(self, pid: int):
        self.path = Path(f"/proc/{pid}/io")
        self.wchan = Path(f"/proc/{pid}/wchan")
        self.base = self.rchar()
        self.sent = 0
        # an idle drive sleeps in poll: if wchan never says so, it cannot tell
        deadline = time.monotonic() + 1.0
        self.wchan_tells = False
        while not self.wchan_tells and time.monotonic() < deadline:
            self.wchan_tells = "poll" in self.read_wchan()
            time.sleep(0.01)

    def read_wchan(self) -> str:
        try:
            return self.wchan.read_text()
        except OSError:
            return ""

    def in_poll(self) -> bool | None:
        """Whether the drive is asleep in poll (None: the kernel does not say)."""
        return "poll" in self.read_wchan() if self.wchan_tells else None

    def rchar(self) -> int | None:
        try:
            for line in self.path.read_text().splitlines():
                if line.startswith("rchar:"):
                    return int(line.split()[1])
        except OSError:
            pass
        return None

    def __call__(self) -> int | None:
        """Bytes sent and not yet read (as `ReceiveQueue` in the e2e harness)."""
        now = self.rchar()
        if now is None or self.base is None:
            return None
        unread = max(0, self.sent - (now - self.base))
        if unread == 0 and self.in_poll() is False:
            return 1  # read, not yet stamped
        return unread


class RawBus:
    """Raw bytes to and from the drive: a frame out, whatever comes back."""

    def __init__(self, drive: VirtualDrive, transport: str):
        self.transport = transport
        if transport == "pty":
            self.port = serial.Serial(str(drive.link), BAUD, timeout=0)
            self.sock = None
            self.unread = DriveRead(drive.proc.pid)
        else:
            self.sock = socket.create_connection(("127.0.0.1", drive.tcp_port), timeout=2)
            self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.sock.setblocking(False)
            self.port = None
            self.unread = ReceiveQueue(drive.tcp_port, self.sock.getsockname()[1])
            # the socket's queue says read; the drive's wchan says stamped
            self.stamp = DriveRead(drive.proc.pid)

    def close(self):
        if self.port:
            self.port.close()
        if self.sock:
            self.sock.close()
            self.unread.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def write(self, frame: bytes):
        """Writes `frame` and returns once the drive has read and stamped
        it, so a pause after it is a pause on the drive's line even on a
        busy host (`wait_until_read`; on the pty through `DriveRead`)."""
        if self.port:
            self.port.write(frame)
            self.port.flush()
            self.unread.sent += len(frame)
        else:
            self.sock.sendall(frame)
        wait_until_read(self.unread, 5.0)
        if self.sock:
            deadline = time.monotonic() + 5.0
            while self.stamp.in_poll() is False and time.monotonic() < deadline:
                time.sleep(0.0002)

    def _read_some(self, timeout: float) -> bytes:
        if self.port:
            r, _, _ = select.select([self.port.fileno()], [], [], timeout)
            return self.port.read(4096) if r else b""
        r, _, _ = select.select([self.sock], [], [], timeout)
        if not r:
            return b""
        try:
            return self.sock.recv(4096)
        except BlockingIOError:
            return b""

    def read_reply(self, timeout: float = 1.0, quiet: float = 0.05) -> bytes:
        """Everything that arrives until `quiet` s of silence after the first
        byte, or nothing after `timeout` s."""
        first = self._read_some(timeout)
        if not first:
            return b""
        out = first
        while True:
            more = self._read_some(quiet)
            if not more:
                return out
            out += more

    def exchange(self, frame: bytes, timeout: float = 1.0) -> bytes:
        self.drain()
        self.write(frame)
        return self.read_reply(timeout)

    def drain(self):
        while self._read_some(0.0):
            pass


@pytest.fixture
def start_drive(tmp_path):
    """`start_drive(*flags)` starts the binary; all are stopped afterwards."""
    started: list[VirtualDrive] = []

    def start(*flags: str, tcp: bool = True, pty: bool = True) -> VirtualDrive:
        d = VirtualDrive(tmp_path, list(flags), tcp=tcp, pty=pty)
        started.append(d)
        return d.start()

    try:
        yield start
    finally:
        for d in started:
            d.stop()


@pytest.fixture(params=["pty", "tcp"])
def transport(request):
    return request.param


# registers (SPEC §5) --------------------------------------------------------
WORD_ORDER = 0x6000
QUICK_STOP_OPTION = 0x605A
CONTROLWORD = 0x6040
MODE = 0x6060
PROFILE_VELOCITY = 0x6081
ACCELERATION = 0x6083
DECELERATION = 0x6084
QUICK_STOP_DECELERATION = 0x6085
TARGET_POSITION = 0x607A
HOME_OFFSET = 0x607C
HOMING_METHOD = 0x6098
HOMING_SPEED = 0x6099
HOMING_ACCELERATION = 0x609A
HOMING_ZERO_SPEED = 0x609B
STATUSWORD = 0x6041
MODE_DISPLAY = 0x6061
ACTUAL_POSITION = 0x6064
ACTUAL_VELOCITY = 0x606C
PA_BASE = 0x0064  # PA0 (SPEC §9)

# statusword (SPEC §8.1/§8.2)
STATE_MASK = 0x006F
SWITCH_ON_DISABLED = 0x0060  # bit 5 = 0 only in quick stop active (SPEC §8.2)
READY_TO_SWITCH_ON = 0x0021
SWITCHED_ON = 0x0023
OPERATION_ENABLED = 0x0027
VOLTAGE_ENABLED = 1 << 4
MOTOR_RUNNING = 1 << 9
TARGET_REACHED = 1 << 10
HOME_SWITCH = 1 << 11
BIT12 = 1 << 12
BIT13 = 1 << 13
CW_LIMIT = 1 << 14
CCW_LIMIT = 1 << 15


class Master:
    """The client API calls a PLC programmer would make (pymodbus)."""

    def __init__(self, client, device_id: int = 1):
        self.c = client
        self.id = device_id

    def write(self, reg: int, value: int):
        r = self.c.write_register(reg, value & 0xFFFF, device_id=self.id)
        assert not r.isError(), f"write 0x{reg:04X} = {value}: {r}"

    def write32(self, reg: int, value: int, signed: bool = True):
        t = self.c.DATATYPE.INT32 if signed else self.c.DATATYPE.UINT32
        regs = self.c.convert_to_registers(value, t)
        r = self.c.write_registers(reg, regs, device_id=self.id)
        assert not r.isError(), f"write 0x{reg:04X} = {value}: {r}"

    def read(self, reg: int) -> int:
        r = self.c.read_holding_registers(reg, count=1, device_id=self.id)
        assert not r.isError(), f"read 0x{reg:04X}: {r}"
        return r.registers[0]

    def read_i16(self, reg: int) -> int:
        return self.c.convert_from_registers([self.read(reg)], self.c.DATATYPE.INT16)

    def read32(self, reg: int) -> int:
        r = self.c.read_holding_registers(reg, count=2, device_id=self.id)
        assert not r.isError(), f"read 0x{reg:04X}: {r}"
        return self.c.convert_from_registers(r.registers, self.c.DATATYPE.INT32)

    def statusword(self) -> int:
        return self.read(STATUSWORD)

    def enable(self):
        """Seed 000's power-up sequence (SPEC §8.1): 0x01, 0x03, 0x0F."""
        for cw, state in ((0x0001, READY_TO_SWITCH_ON), (0x0003, SWITCHED_ON),
                          (0x000F, OPERATION_ENABLED)):
            self.write(CONTROLWORD, cw)
            sw = self.statusword()
            assert sw & STATE_MASK == state, f"after 0x{cw:04X}: statusword 0x{sw:04X}"

    def wait(self, pred, timeout: float, what: str, period: float = 0.02):
        """Polls the statusword until pred(sw) holds; returns the samples."""
        deadline = time.monotonic() + timeout
        seen = []
        while time.monotonic() < deadline:
            sw = self.statusword()
            seen.append(sw)
            if pred(sw):
                return seen
            time.sleep(period)
        raise AssertionError(f"timeout waiting for {what}; last statuswords "
                             f"{[hex(s) for s in seen[-5:]]}")
