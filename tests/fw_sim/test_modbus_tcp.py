"""Modbus TCP on both firmware images (`--modbus-tcp`, docs/fw-sim.md): the
runner is a Modbus TCP to RTU gateway in front of the emulated RS-485 line,
so pymodbus' default TCP client (MBAP framing), mbpoll's TCP mode and raw
MBAP requests reach the unmodified firmware through its USART. The unit
identifier is the slave address; a unit nobody answers gets exception 0x0B
from the gateway; unit 0 is a broadcast, done and not answered (Modbus TCP
guide V1.0b §3.1.3, gateways)."""

import re
import select
import socket
import struct
import subprocess

from pymodbus.client import ModbusTcpClient

from conftest import ACCELERATION, PROFILE_VELOCITY, STATUSWORD, Master, free_port

SWITCH_ON_DISABLED = 0x0060
READ_SW = bytes([0x03]) + struct.pack(">HH", STATUSWORD, 1)


def start(start_fw, board, *flags):
    port = free_port()
    fw = start_fw(board, "--modbus-tcp", f"127.0.0.1:{port}", *flags)
    return fw, port


def mbap(tid: int, unit: int, pdu: bytes, protocol: int = 0) -> bytes:
    return struct.pack(">HHHB", tid, protocol, len(pdu) + 1, unit) + pdu


def sw_reply(tid: int, unit: int = 1) -> bytes:
    return struct.pack(">HHHBBBH", tid, 0, 5, unit, 0x03, 2, SWITCH_ON_DISABLED)


class Raw:
    def __init__(self, port: int):
        self.s = socket.create_connection(("127.0.0.1", port), timeout=2)
        self.s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.s.close()

    def ask(self, b: bytes, timeout: float = 2.0, want: int | None = None) -> bytes:
        """Sends `b`; returns what comes back until 0.2 s of quiet (or
        `want` bytes) within `timeout`."""
        self.s.sendall(b)
        out, t = b"", timeout
        while want is None or len(out) < want:
            r, _, _ = select.select([self.s], [], [], t)
            if not r:
                break
            chunk = self.s.recv(4096)
            if not chunk:
                break
            out += chunk
            t = 0.2
        return out


def test_pymodbus_tcp_client_reads_and_writes(start_fw, board):
    fw, port = start(start_fw, board)
    c = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
    assert c.connect()
    m = Master(c, 1)
    assert m.statusword() == SWITCH_ON_DISABLED, board
    m.write(ACCELERATION, 321)
    m.write32(PROFILE_VELOCITY, 123456)
    assert m.read(ACCELERATION) == 321
    assert m.read32(PROFILE_VELOCITY) == 123456
    # a register that does not exist: the firmware's exception 11 (SPEC §5.2)
    r = c.read_holding_registers(0x6090, count=1, device_id=1)
    assert r.isError() and r.exception_code == 11, f"{board}: {r}"
    c.close()
    fw.alive()


def test_mbap_framing_through_the_gateway(start_fw, board):
    """The transaction identifier and unit come back; two requests in one
    segment are answered in order; a foreign protocol identifier is skipped;
    a unit nobody answers gets 0x0B; a broadcast write is done, not
    answered, and the next transaction is."""
    fw, port = start(start_fw, board)
    with Raw(port) as raw:
        assert raw.ask(mbap(0xBEEF, 1, READ_SW), want=11) == sw_reply(0xBEEF), board
        two = mbap(1, 1, READ_SW) + mbap(2, 1, READ_SW)
        assert raw.ask(two, want=22) == sw_reply(1) + sw_reply(2)
        foreign = mbap(3, 1, READ_SW, protocol=7) + mbap(4, 1, READ_SW)
        assert raw.ask(foreign, want=11) == sw_reply(4)
        assert raw.ask(mbap(5, 7, READ_SW), want=9) == struct.pack(">HHHBBB", 5, 0, 3, 7,
                                                                   0x83, 0x0B)
        write_acc = bytes([0x06]) + struct.pack(">HH", ACCELERATION, 77)
        assert raw.ask(mbap(6, 0, write_acc), timeout=0.5) == b""
        read_acc = bytes([0x03]) + struct.pack(">HH", ACCELERATION, 1)
        assert raw.ask(mbap(7, 1, read_acc), want=11) == struct.pack(">HHHBBBH", 7, 0, 5, 1, 3,
                                                                      2, 77)
    fw.alive()


def test_modbus_tcp_and_rtu_over_tcp_share_the_line(start_fw, board):
    """Both front ends reach the same USART: a value written over raw RTU
    (--tcp) is read back over Modbus TCP."""
    fw, port = start(start_fw, board)
    rtu = fw.client()
    Master(rtu).write(ACCELERATION, 999)
    rtu.close()
    c = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
    assert c.connect()
    assert Master(c, 1).read(ACCELERATION) == 999
    c.close()


def test_mbpoll_over_modbus_tcp(start_fw, board):
    fw, port = start(start_fw, board)
    out = subprocess.run(["mbpoll", "-m", "tcp", "-a", "1", "-0", "-r", str(STATUSWORD), "-c",
                          "1", "-1", "-o", "2", "-p", str(port), "127.0.0.1"],
                         capture_output=True, text=True, timeout=20)
    fw.alive()
    assert out.returncode == 0, out.stdout + out.stderr
    assert re.search(rf"\[{STATUSWORD}\]:\s+{SWITCH_ON_DISABLED}\b", out.stdout), out.stdout
