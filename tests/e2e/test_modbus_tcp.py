"""Modbus TCP (`--modbus-tcp`, issue 18): MBAP framing as HMI/SCADA tools,
PLC soft-masters and pymodbus' default TCP client speak it, per the
"MODBUS Messaging on TCP/IP Implementation Guide V1.0b": transaction id
echoed, protocol id 0, length checked, unit id routed to the drive with
that address. Raw-socket tests build every MBAP header by hand."""

from __future__ import annotations

import re
import select
import socket
import struct
import subprocess
import threading
import time

from pymodbus.client import ModbusTcpClient

from conftest import (ACCELERATION, STATUSWORD, Master)

SWITCH_ON_DISABLED_SW = 0x0060


def start(start_drive, *flags):
    d = start_drive("--no-status", "--modbus-tcp", "127.0.0.1:0", *flags, tcp=False, pty=False)
    assert d.modbus_tcp_port, d.stderr()
    return d


def client(d, **kw) -> ModbusTcpClient:
    c = ModbusTcpClient("127.0.0.1", port=d.modbus_tcp_port, timeout=2, retries=0, **kw)
    assert c.connect()
    return c


def mbap(tid: int, unit: int, pdu: bytes, protocol: int = 0, length: int | None = None) -> bytes:
    if length is None:
        length = len(pdu) + 1
    return struct.pack(">HHHB", tid, protocol, length, unit) + pdu


READ_SW = bytes([0x03]) + struct.pack(">HH", STATUSWORD, 1)


class Raw:
    """A plain TCP connection speaking MBAP bytes."""

    def __init__(self, d):
        self.s = socket.create_connection(("127.0.0.1", d.modbus_tcp_port), timeout=2)
        self.s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def send(self, b: bytes):
        self.s.sendall(b)

    def recv(self, timeout: float = 1.0) -> bytes:
        """What arrives within `timeout` (until 50 ms of quiet); b"" if
        nothing; None if the server closed the connection."""
        out = b""
        t = timeout
        while True:
            r, _, _ = select.select([self.s], [], [], t)
            if not r:
                return out
            try:
                chunk = self.s.recv(4096)
            except ConnectionResetError:
                return None if not out else out
            if not chunk:
                return None if not out else out
            out += chunk
            t = 0.05

    def ask(self, b: bytes, timeout: float = 1.0):
        self.send(b)
        return self.recv(timeout)

    def close(self):
        self.s.close()


def sw_response(tid: int, unit: int, sw: int = SWITCH_ON_DISABLED_SW) -> bytes:
    return struct.pack(">HHHBBBH", tid, 0, 5, unit, 0x03, 2, sw)


def mbpoll_tcp(port: int, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["mbpoll", "-m", "tcp", "-q", "-1", "-o", "2", *args,
                           "127.0.0.1", "-p", str(port)],
                          capture_output=True, text=True, timeout=20)


def test_mbpoll_reads_the_statusword_over_modbus_tcp(start_drive):
    d = start(start_drive)
    r = mbpoll_tcp(d.modbus_tcp_port, "-a", "1", "-r", str(STATUSWORD + 1), "-c", "1")
    assert r.returncode == 0, r.stdout + r.stderr
    # -q: no banner, just the value; 0x0060 = 96 at power-up (SPEC §8.1)
    assert r.stdout.strip() == f"-- Polling slave 1...\n[{STATUSWORD + 1}]: \t96", r.stdout


def test_mbpoll_as_the_issue_gives_it_polls_while_pymodbus_writes(start_drive):
    """`mbpoll -m tcp -a 1 -r 24642 -c 1 127.0.0.1 -p PORT` exactly (1-based
    reference 24642 = 0x6041; it polls once a second until stopped), while
    pymodbus' default TCP client works on its own connection."""
    d = start(start_drive)
    # stdbuf: mbpoll's stdout is a pipe here, unbuffered so lines come as polled
    p = subprocess.Popen(["stdbuf", "-o0", "mbpoll", "-m", "tcp", "-a", "1", "-r", "24642",
                          "-c", "1", "127.0.0.1", "-p", str(d.modbus_tcp_port)],
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        m = Master(client(d))
        polls = []
        deadline = time.monotonic() + 10
        while len(polls) < 2:
            assert time.monotonic() < deadline, polls
            r, _, _ = select.select([p.stdout], [], [], 0.5)
            if not r:
                continue
            line = p.stdout.readline()
            assert line, f"mbpoll ended: {p.wait()}"
            if line.startswith("[24642]:"):
                polls.append(line.split()[1])
                m.write(ACCELERATION, 100 + len(polls))  # between two polls
        assert polls == ["96", "96"], polls  # 0x0060, switch on disabled
        assert m.read(ACCELERATION) == 102
    finally:
        p.terminate()
        p.wait(5)


def test_pymodbus_tcp_client_reads_and_writes(start_drive):
    d = start(start_drive)
    m = Master(client(d))
    assert m.statusword() == SWITCH_ON_DISABLED_SW
    m.write(ACCELERATION, 321)
    assert m.read(ACCELERATION) == 321
    m.enable()  # the CiA 402 sequence works over Modbus TCP as over RTU


def test_two_clients_at_once_each_get_their_own_transactions(start_drive):
    d = start(start_drive)
    errors = []

    def worker():
        try:
            c = client(d)
            for i in range(40):
                r = c.read_holding_registers(STATUSWORD, count=1, device_id=1)
                assert not r.isError() and r.registers == [SWITCH_ON_DISABLED_SW], r
            c.close()
        except Exception as e:  # noqa: BLE001 - reported below
            errors.append(e)

    # plus a raw connection held open across both, pipelining two requests
    raw = Raw(d)
    threads = [threading.Thread(target=worker) for _ in range(2)]
    for t in threads:
        t.start()
    got = raw.ask(mbap(7, 1, READ_SW) + mbap(8, 1, READ_SW))
    while got is not None and len(got) < 22:
        more = raw.recv()
        if not more:
            break
        got += more
    for t in threads:
        t.join(30)
    raw.close()
    assert not errors, errors
    assert got == sw_response(7, 1) + sw_response(8, 1)
    # mbpoll alongside a client that stays connected
    c = client(d)
    r = mbpoll_tcp(d.modbus_tcp_port, "-a", "1", "-r", str(STATUSWORD + 1), "-c", "1")
    assert r.returncode == 0, r.stderr
    assert c.read_holding_registers(STATUSWORD, count=1, device_id=1).registers == [0x60]
    assert d.stderr().count(": connected") >= 5


def bad_adus(d) -> int:
    counts = re.findall(r"\((\d+) bad ADUs\)", d.stderr())
    return int(counts[-1]) if counts else 0


def wait_for_log(d, needle: str, timeout: float = 2.0):
    deadline = time.monotonic() + timeout
    while needle not in d.stderr():
        assert time.monotonic() < deadline, f"no `{needle}` in\n{d.stderr()}"
        time.sleep(0.02)


def test_malformed_mbap_headers_are_dropped_per_the_guide_and_counted(start_drive):
    d = start(start_drive)
    bystander = client(d)  # keeps being served throughout

    # protocol id 1: discarded without a reply, the connection goes on
    raw = Raw(d)
    assert raw.ask(mbap(1, 1, READ_SW, protocol=1), timeout=0.5) == b""
    wait_for_log(d, "protocol id 1 is not Modbus (0)")
    assert raw.ask(mbap(2, 1, READ_SW)) == sw_response(2, 1)
    assert bad_adus(d) == 1

    # length 0, 1 (no function code) and beyond 254 (oversize): the stream
    # cannot be delimited any more, the server closes the connection
    for n, length in enumerate((0, 1, 255, 0xFFFF), start=2):
        raw = Raw(d)
        assert raw.ask(mbap(3, 1, READ_SW, length=length)) is None, length
        wait_for_log(d, f"MBAP length {length} outside 2..=254: connection closed")
        assert bad_adus(d) == n
        raw.close()
    # an oversize ADU with a consistent length field: 255 bytes after the
    # header -> the same (refused on the header, nothing buffered)
    raw = Raw(d)
    assert raw.ask(mbap(4, 1, bytes([0x10]) + bytes(254))) is None
    assert bad_adus(d) == 6

    # a truncated header, then the client goes away: dropped, counted
    raw = Raw(d)
    raw.send(mbap(5, 1, READ_SW)[:4])
    time.sleep(0.1)
    raw.close()
    wait_for_log(d, "4 bytes of an unfinished request dropped")
    assert bad_adus(d) == 7
    # a header whose PDU never comes: the same when the client closes
    raw = Raw(d)
    raw.send(mbap(6, 1, READ_SW)[:9])
    time.sleep(0.1)
    raw.close()
    wait_for_log(d, "9 bytes of an unfinished request dropped")
    assert bad_adus(d) == 8

    # a length field larger than what follows, the client waiting: the
    # rest never comes; after the ADU timeout the connection is closed
    # (whatever came next would be read as the missing bytes)
    raw = Raw(d)
    t0 = time.monotonic()
    assert raw.ask(mbap(7, 1, READ_SW, length=9), timeout=3) is None
    assert 0.9 < time.monotonic() - t0 < 2.5
    wait_for_log(d, "(the rest of a request did not come within 1000 ms), "
                    "12 bytes of an unfinished request dropped")
    assert bad_adus(d) == 9

    # the server never stopped serving
    r = bystander.read_holding_registers(STATUSWORD, count=1, device_id=1)
    assert r.registers == [SWITCH_ON_DISABLED_SW]
    assert d.proc.poll() is None
    assert "panicked" not in d.stderr()


def test_a_request_split_across_segments_and_a_bad_pdu(start_drive):
    d = start(start_drive)
    raw = Raw(d)
    req = mbap(0xBEEF, 1, READ_SW)
    for b in req[:-1]:
        raw.send(bytes([b]))
        time.sleep(0.005)
    assert raw.ask(req[-1:]) == sw_response(0xBEEF, 1)
    # a 0x03 PDU one byte short: the drive's own exception (vendor code 8
    # byte count, SPEC §5.2), in an MBAP response with the transaction id
    assert raw.ask(mbap(9, 1, READ_SW[:-1])) == struct.pack(">HHHBBB", 9, 0, 3, 1, 0x83, 8)
    # an unknown function: exception 1
    assert raw.ask(mbap(10, 1, b"\x41")) == struct.pack(">HHHBBB", 10, 0, 3, 1, 0xC1, 1)
    # length 2, a function code without its data; length 8, a whole request
    # and two bytes more: the MBAP header is sound, the PDU is not, so the
    # drive answers as to the same PDU on the serial line (byte count)
    assert raw.ask(mbap(11, 1, b"\x03")) == struct.pack(">HHHBBB", 11, 0, 3, 1, 0x83, 8)
    assert raw.ask(mbap(12, 1, READ_SW + b"\x00\x00")) == \
        struct.pack(">HHHBBB", 12, 0, 3, 1, 0x83, 8)
    # none of these is a bad ADU
    assert bad_adus(d) == 0
    assert raw.ask(mbap(13, 1, READ_SW)) == sw_response(13, 1)


READ_MISSING = bytes([0x03]) + struct.pack(">HH", STATUSWORD + 1, 1)  # 0x6042: no entry


def test_without_the_flag_a_missing_register_looks_like_an_unreachable_drive(start_drive):
    """Vendor code 11 (register does not exist, SPEC §5.2) is, on Modbus TCP,
    the byte a gateway sends for "target device failed to respond": a SCADA
    marks the drive offline. Why --standard-exceptions exists."""
    d = start(start_drive)
    raw = Raw(d)
    missing = raw.ask(mbap(1, 1, READ_MISSING))
    unreachable = raw.ask(mbap(2, 9, READ_SW))  # no drive 9: the gateway's 0x0B
    assert missing[7:] == unreachable[7:] == bytes([0x83, 0x0B])


def test_standard_exceptions_flag_sets_pa55(start_drive):
    d = start(start_drive, "--standard-exceptions")
    raw = Raw(d)
    # the byte count exception 8 becomes 3 (SPEC §5.2, PA55 = 1)
    assert raw.ask(mbap(9, 1, READ_SW[:-1])) == struct.pack(">HHHBBB", 9, 0, 3, 1, 0x83, 3)
    # a missing register: 2, no longer the gateway's 0x0B
    assert raw.ask(mbap(10, 1, READ_MISSING)) == struct.pack(">HHHBBB", 10, 0, 3, 1, 0x83, 2)
    # writing the read-only statusword: 2, not 5 (a generic master's "acknowledge")
    write_sw = bytes([0x06]) + struct.pack(">HH", STATUSWORD, 7)
    assert raw.ask(mbap(11, 1, write_sw)) == struct.pack(">HHHBBB", 11, 0, 3, 1, 0x86, 2)
    assert Master(client(d)).read(0x0064 + 55) == 1  # PA55 reads 1
    # the log names the cause and what was sent
    wait_for_log(d, "exception 8 (ByteCountMismatch), sent as 3 (PA55 = 1)")
    wait_for_log(d, "exception 5 (WriteReadOnly), sent as 2 (PA55 = 1)")


def test_unit_ids_route_to_the_drive_with_that_address(start_drive):
    d = start(start_drive, "--drives", "1,2")
    c = client(d)
    one, two = Master(c, 1), Master(c, 2)
    one.write(ACCELERATION, 111)
    two.write(ACCELERATION, 222)
    assert (one.read(ACCELERATION), two.read(ACCELERATION)) == (111, 222)

    raw = Raw(d)
    # unit 3: no drive there -> gateway target failed to respond (0x0B)
    assert raw.ask(mbap(1, 3, READ_SW)) == struct.pack(">HHHBBB", 1, 0, 3, 3, 0x83, 0x0B)
    # unit 255 with two drives: no path (0x0A)
    assert raw.ask(mbap(2, 255, READ_SW)) == struct.pack(">HHHBBB", 2, 0, 3, 255, 0x83, 0x0A)
    # unit 0: a broadcast write, executed by both, answered by none
    write_acc = bytes([0x06]) + struct.pack(">HH", ACCELERATION, 77)
    assert raw.ask(mbap(3, 0, write_acc), timeout=0.5) == b""
    assert (one.read(ACCELERATION), two.read(ACCELERATION)) == (77, 77)
    # the transaction after the broadcast is answered as usual
    assert raw.ask(mbap(4, 2, READ_SW)) == sw_response(4, 2)


def test_unit_0_and_255_reach_a_single_drive(start_drive):
    d = start(start_drive, "--drives", "5")
    raw = Raw(d)
    for tid, unit in ((1, 5), (2, 255), (3, 0)):
        assert raw.ask(mbap(tid, unit, READ_SW)) == sw_response(tid, unit), unit
    assert raw.ask(mbap(4, 1, READ_SW)) == struct.pack(">HHHBBB", 4, 0, 3, 1, 0x83, 0x0B)


def test_rtu_over_tcp_and_modbus_tcp_side_by_side(start_drive):
    d = start_drive("--no-status", "--modbus-tcp", "127.0.0.1:0", pty=False)
    assert d.tcp_port and d.modbus_tcp_port and d.tcp_port != d.modbus_tcp_port
    Master(d.client("tcp")).write(ACCELERATION, 999)
    assert Master(client(d)).read(ACCELERATION) == 999


def test_a_client_that_leaves_mid_ee_operation_does_not_leave_the_drive_busy(start_drive):
    d = start(start_drive)
    raw = Raw(d)
    # EE-Save (SPEC §9): 0x10 to 0x003A, value 1; the reply waits for flash
    raw.send(mbap(1, 1, bytes.fromhex("10 00 3A 00 01 02 00 01")))
    raw.close()
    time.sleep(0.3)
    r = Master(client(d)).read(STATUSWORD)
    assert r == SWITCH_ON_DISABLED_SW  # not exception 6 (busy)


def test_device_identification_over_modbus_tcp(start_drive):
    """What a SCADA asks first of a new device: function 0x2B / MEI 0x0E,
    basic objects (vendor, product code, revision), in one MBAP response."""
    d = start(start_drive)
    r = Raw(d).ask(mbap(0x0102, 1, bytes([0x2B, 0x0E, 0x01, 0x00])))
    tid, proto, length, unit = struct.unpack(">HHHB", r[:7])
    assert (tid, proto, unit, length) == (0x0102, 0, 1, len(r) - 6)
    pdu = r[7:]
    assert pdu[:3] == bytes([0x2B, 0x0E, 0x01]) and pdu[3] == 0x81, pdu.hex()
    assert pdu[4:7] == bytes([0, 0, 3]), "all in one response, three objects"
    objs, i = {}, 7
    while i < len(pdu):
        objs[pdu[i]] = pdu[i + 2:i + 2 + pdu[i + 1]]
        i += 2 + pdu[i + 1]
    assert sorted(objs) == [0, 1, 2] and all(objs.values()), objs
