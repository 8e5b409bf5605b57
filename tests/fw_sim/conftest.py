"""Harness for the firmware-in-the-loop tests: each board's release image
(or, with `dev=True`, its development image, which also logs `info`) run
by fw-sim (docs/fw-sim.md), talked to over raw RTU-over-TCP exactly as
tests/e2e talks to the virtual drive. The frames, exception table and
client helpers are the e2e tests' own (imported, not copied). A runner that
stopped on a fault fails the test that used it, with its message."""

from __future__ import annotations

import importlib.util
import os
import re
import select
import socket
import struct
import subprocess
import time
from pathlib import Path

import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient

ROOT = Path(__file__).resolve().parents[2]
E2E = ROOT / "tests" / "e2e"
SIM = Path(os.environ.get("FW_SIM_BIN") or ROOT / "fw-sim" / "target" / "release" / "fw-sim")
ELF = {
    "g431": Path(os.environ.get("FW_SIM_ELF_G431")
                 or ROOT / "target" / "thumbv7em-none-eabihf" / "fw" / "modbus-drive"),
    "f103": Path(os.environ.get("FW_SIM_ELF_F103")
                 or ROOT / "target" / "thumbv7m-none-eabi" / "fw" / "modbus-drive"),
}
# the development image (cargo fw-dev): the same code with defmt at info,
# for the tests that read an info log line (docs/firmware.md)
ELF_DEV = {
    "g431": Path(os.environ.get("FW_SIM_ELF_DEV_G431")
                 or ROOT / "target" / "thumbv7em-none-eabihf" / "fw-dev" / "modbus-drive"),
    "f103": Path(os.environ.get("FW_SIM_ELF_DEV_F103")
                 or ROOT / "target" / "thumbv7m-none-eabi" / "fw-dev" / "modbus-drive"),
}
BOARDS = ["g431", "f103"]


def _board_figures(fn: str) -> dict[str, int]:
    """Each board's arm of `Board::<fn>` in src/boards.rs (one arm a
    board)."""
    src = (ROOT / "src" / "boards.rs").read_text()
    body = re.search(rf"pub const fn {fn}\(self\) -> u32 \{{(.*?)\n    \}}", src, re.S)[1]
    figures = {b.lower(): int(v.replace("_", ""))
               for b, v in re.findall(r"Board::(\w+) => ([0-9_]+)", body)}
    assert set(figures) == set(BOARDS), (fn, figures)
    return figures


# each board's step tick in ns (the step timer's clock)
TICK_NS = {b: 1e9 / hz for b, hz in _board_figures("step_tick_hz").items()}
# each board's step rate limit, steps/s: the firmware clamps every speed to it
LIMITS = _board_figures("max_step_rate")


def pulse_for(rate: int) -> int:
    """PA15 (0.1 µs) for the widest STEP pulse that `rate` steps/s allows
    (`Params::step_rate_cap`: the period holds the pulse high and as long
    low): 0, the 2.5 µs default, up to 200 000 steps/s."""
    width_ns = 500_000_000 // rate
    return 0 if width_ns >= 2_500 else width_ns // 100
READY_TIMEOUT_S = 30.0
NO_REPLY_WAIT_S = 0.3


def _load(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


# the e2e harness's helpers and register names; its test modules import
# them as `conftest`, which is this module while these tests run
e2e = _load("e2e_conftest", E2E / "conftest.py")
crc16, with_crc, hexb, Master = e2e.crc16, e2e.with_crc, e2e.hexb, e2e.Master
stop_process = e2e.stop_process
for _name in dir(e2e):
    if _name.isupper():
        globals()[_name] = getattr(e2e, _name)


def e2e_module(name: str):
    """A test module of tests/e2e, for its data tables."""
    return _load("e2e_" + name, E2E / f"{name}.py")


FLASH = 0x0800_0000


def elf_image(body: bytes) -> bytes:
    """A hand-assembled ELF32 ARM executable: the vector table (SP
    0x2000_1000, Reset at 0x0800_0008), then `body` (Thumb code and its
    literals) as the FUNC symbol Reset. For tests of the runner itself."""
    code = struct.pack("<II", 0x2000_1000, FLASH + 8 + 1) + body
    shstr = b"\0.text\0.symtab\0.strtab\0.shstrtab\0"
    strtab = b"\0Reset\0"
    symtab = bytes(16) + struct.pack("<IIIBBH", 1, FLASH + 8 + 1, len(body), 0x12, 0, 1)
    ehsize, phsize = 52, 32
    off_text = ehsize + phsize
    off_sym = off_text + len(code)
    off_str = off_sym + len(symtab)
    off_shstr = off_str + len(strtab)
    off_sh = (off_shstr + len(shstr) + 3) & ~3
    eh = b"\x7fELF\x01\x01\x01" + bytes(9) + struct.pack(
        "<HHIIIIIHHHHHH", 2, 40, 1, FLASH + 9, ehsize, off_sh, 0x0500_0200,
        ehsize, phsize, 1, 40, 5, 4)
    ph = struct.pack("<IIIIIIII", 1, off_text, FLASH, FLASH, len(code), len(code), 5, 4)

    def sh(name, kind, flags, addr, off, size, link=0, info=0, align=1, entsize=0):
        return struct.pack("<IIIIIIIIII", name, kind, flags, addr, off, size, link, info,
                           align, entsize)
    shdrs = (bytes(40)
             + sh(1, 1, 6, FLASH, off_text, len(code), align=4)
             + sh(7, 2, 0, 0, off_sym, len(symtab), link=3, info=1, align=4, entsize=16)
             + sh(15, 3, 0, 0, off_str, len(strtab))
             + sh(23, 3, 0, 0, off_shstr, len(shstr)))
    body = eh + ph + code + symtab + strtab + shstr
    return body + bytes(off_sh - len(body)) + shdrs


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Firmware:
    """One fw-sim process running one board's image."""

    def __init__(self, workdir: Path, board: str, flags: list[str], dev: bool = False):
        self.board = board
        self.port = free_port()
        self.workdir = workdir
        self.err_path = workdir / f"fw-sim-{board}-{self.port}.stderr"
        elf = (ELF_DEV if dev else ELF)[board]
        cmd = [str(SIM), "--board", board, "--elf", str(elf),
               "--tcp", f"127.0.0.1:{self.port}", *flags]
        self.err = open(self.err_path, "wb")
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=self.err)
        deadline = time.monotonic() + READY_TIMEOUT_S
        line = b""
        while time.monotonic() < deadline:
            r, _, _ = select.select([self.proc.stdout], [], [], 0.1)
            if r:
                line += os.read(self.proc.stdout.fileno(), 64)
                if b"ready\n" in line:
                    return
            if self.proc.poll() is not None:
                break
        self.stop()
        raise AssertionError(f"fw-sim {board} did not print ready:\n{self.stderr()}")

    def stderr(self) -> str:
        if not self.err.closed:
            self.err.flush()
        return self.err_path.read_text(errors="replace")

    def alive(self):
        """Fails if the runner stopped (a fault it found in the firmware)."""
        rc = self.proc.poll()
        assert rc is None, f"fw-sim {self.board} exited with {rc}:\n{self.stderr()}"

    def stop(self) -> int | None:
        """Stops the runner; returns its exit code if it had stopped by
        itself (a fault), None if it was running."""
        if self.err.closed:
            return self.exited
        rc = self.exited = self.proc.poll()
        stop_process(self.proc, self.err)
        return rc

    def client(self, timeout: float = 1.0) -> ModbusTcpClient:
        c = ModbusTcpClient("127.0.0.1", port=self.port, framer=FramerType.RTU, timeout=timeout,
                            retries=0)
        assert c.connect()
        return c

    def raw(self) -> "RawBus":
        return RawBus(self)


class RawBus:
    """Raw bytes to and from the emulated line."""

    def __init__(self, fw: Firmware):
        self.fw = fw
        self.sock = socket.create_connection(("127.0.0.1", fw.port), timeout=2)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.sock.close()

    def exchange(self, frame: bytes, timeout: float = 1.0, quiet: float = 0.05) -> bytes:
        """Sends `frame` and returns what comes back until `quiet` seconds of
        silence after the first byte (or nothing after `timeout`)."""
        self.sock.sendall(frame)
        got = b""
        deadline = time.monotonic() + timeout
        while True:
            wait = quiet if got else deadline - time.monotonic()
            if wait <= 0:
                break
            r, _, _ = select.select([self.sock], [], [], wait)
            if not r:
                break
            chunk = self.sock.recv(256)
            if not chunk:
                break
            got += chunk
        self.fw.alive()
        return got


@pytest.fixture(params=BOARDS)
def board(request) -> str:
    return request.param


@pytest.fixture
def start_fw(tmp_path):
    """`start_fw(board, *flags)` starts a runner; all are stopped after the
    test, and one that had stopped on a fault fails it."""
    started: list[Firmware] = []

    def start(board: str, *flags: str, dev: bool = False) -> Firmware:
        fw = Firmware(tmp_path, board, list(flags), dev)
        started.append(fw)
        return fw

    try:
        yield start
    finally:
        for fw in started:
            rc = fw.stop()
            assert rc is None, f"fw-sim {fw.board} exited with {rc}:\n{fw.stderr()}"


class AsDrive:
    """A runner seen through the e2e harness's VirtualDrive interface, so
    the e2e tests' programs run unchanged against the firmware."""

    def __init__(self, fw: Firmware):
        self.fw = fw

    def client(self, transport: str) -> ModbusTcpClient:
        assert transport == "tcp"
        return self.fw.client()

    def raw(self, transport: str) -> RawBus:
        assert transport == "tcp"
        return self.fw.raw()

    def stderr(self) -> str:
        return self.fw.stderr()


@pytest.fixture
def start_drive(start_fw, board):
    """The e2e `start_drive(*flags)` fixture, starting `board`'s image
    (the virtual drive's --no-status has no meaning here)."""
    def start(*flags: str) -> AsDrive:
        return AsDrive(start_fw(board, *[f for f in flags if f != "--no-status"]))
    return start


TARGETS = {"g431": "thumbv7em-none-eabihf", "f103": "thumbv7m-none-eabi"}


@pytest.fixture(scope="session")
def fault_test_elf():
    """Each board's image built with the `fault-test` feature (never in a
    release image), in its own target directory."""
    target_dir = ROOT / "target" / "fault-test"
    elfs = {}
    for board, target in TARGETS.items():
        subprocess.run(["cargo", "build", "--profile", "fw", "--bin", "modbus-drive",
                        "--target", target, "--no-default-features",
                        "--features", f"board-{board},fault-test",
                        "--target-dir", str(target_dir)], cwd=ROOT, check=True)
        elfs[board] = target_dir / target / "fw" / "modbus-drive"
    return elfs
