"""Modbus TCP connection management (implementation guide §4.2.1): idle
connections close after `--tcp-idle-timeout`; with 32 connected, a new
client closes the one idle the longest, never one with a request in
flight; the counters reach the page. A pymodbus client is the real one."""

from __future__ import annotations

import json
import re
import socket
import struct
import time
import urllib.request

from pymodbus.client import ModbusTcpClient

from conftest import STATUSWORD

MAX_CLIENTS = 32
READ_SW = bytes([0x03]) + struct.pack(">HH", STATUSWORD, 1)


def start(start_drive, *flags):
    d = start_drive("--no-status", "--modbus-tcp", "127.0.0.1:0", "--web", "127.0.0.1:0",
                    *flags, tcp=False, pty=False)
    assert d.modbus_tcp_port, d.stderr()
    d.web_port = int(re.search(r"web: page on http://127\.0\.0\.1:(\d+)/", d.stderr()).group(1))
    return d


def counters(d) -> dict:
    """The Modbus TCP counters as the page shows them (published every
    100 ms: the tests poll with `wait_counters`)."""
    url = f"http://127.0.0.1:{d.web_port}/api/state"
    deadline = time.monotonic() + 3
    while True:
        with urllib.request.urlopen(url, timeout=5) as r:
            body = r.read()
        # empty until the drive loop's first publication after `ready`
        if body or time.monotonic() > deadline:
            return json.loads(body)["modbus_tcp"]
        time.sleep(0.02)


def wait_counters(d, pred, timeout=3.0) -> dict:
    deadline = time.monotonic() + timeout
    while True:
        c = counters(d)
        if pred(c) or time.monotonic() > deadline:
            return c
        time.sleep(0.05)


def connect(d) -> socket.socket:
    s = socket.create_connection(("127.0.0.1", d.modbus_tcp_port), timeout=2)
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return s


def closed_by_server(s: socket.socket, timeout: float) -> bool:
    s.settimeout(timeout)
    try:
        return s.recv(1) == b""
    except ConnectionResetError:
        return True
    except socket.timeout:
        return False


def served_within(d, seconds: float) -> float:
    """A pymodbus client connects and reads the statusword; the time it
    took, asserted below `seconds`."""
    t0 = time.monotonic()
    c = ModbusTcpClient("127.0.0.1", port=d.modbus_tcp_port, timeout=seconds, retries=0)
    try:
        assert c.connect()
        rr = c.read_holding_registers(STATUSWORD, count=1, device_id=1)
        took = time.monotonic() - t0
        assert not rr.isError(), rr
    finally:
        c.close()
    assert took < seconds, took
    return took


def test_1000_cycles_and_32_idle_squatters_then_a_client_is_served_within_1s(start_drive):
    d = start(start_drive)
    for i in range(1000):
        s = connect(d)
        if i % 10 == 0:  # some cycles carry a request, the rest only connect
            s.sendall(struct.pack(">HHHB", i, 0, len(READ_SW) + 1, 1) + READ_SW)
            assert len(s.recv(64)) == 11
        s.close()
    c = wait_counters(d, lambda c: c["connections"] == 0 and c["requests"] == 100)
    assert (c["connections"], c["requests"]) == (0, 100), c
    squatters = [connect(d) for _ in range(MAX_CLIENTS)]
    try:
        c = wait_counters(d, lambda c: c["connections"] == MAX_CLIENTS)
        assert c["connections"] == MAX_CLIENTS, c
        served_within(d, 1.0)
        # the squatter idle the longest (the first) made room
        assert closed_by_server(squatters[0], 1.0)
        c = wait_counters(d, lambda c: c["evicted"] == 1)
        assert (c["evicted"], c["refused"], c["idle_closed"]) == (1, 0, 0), c
        # the client left: one more squatter fills the place again, and the
        # next client takes the place of the next oldest squatter
        squatters.append(connect(d))
        c = wait_counters(d, lambda c: c["connections"] == MAX_CLIENTS)
        assert c["connections"] == MAX_CLIENTS, c
        served_within(d, 1.0)
        assert closed_by_server(squatters[1], 1.0)
        assert not closed_by_server(squatters[2], 0.2)
        assert wait_counters(d, lambda c: c["evicted"] == 2)["evicted"] == 2
    finally:
        for s in squatters:
            s.close()
    assert "idle the longest, to admit" in d.stderr()


def test_connections_with_a_request_in_flight_are_kept_at_the_cap(start_drive):
    d = start(start_drive)
    busy = [connect(d) for _ in range(MAX_CLIENTS)]
    try:
        # each is in the middle of a request (the first 4 bytes of an MBAP
        # header: the rest may take up to the ADU timeout, 1 s)
        for i, s in enumerate(busy):
            s.sendall(struct.pack(">HH", i, 0))
        c = wait_counters(d, lambda c: c["connections"] == MAX_CLIENTS)
        assert c["connections"] == MAX_CLIENTS, c
        late = connect(d)
        assert closed_by_server(late, 0.5), "refused: every connection is busy"
        late.close()
        c = wait_counters(d, lambda c: c["refused"] == 1)
        assert (c["refused"], c["evicted"]) == (1, 0), c
        # none of the busy ones was closed for it: each finishes its request
        for i, s in enumerate(busy[:4]):
            s.sendall(struct.pack(">HB", len(READ_SW) + 1, 1) + READ_SW)
            s.settimeout(2)
            reply = s.recv(64)
            assert reply[:2] == struct.pack(">H", i) and len(reply) == 11, reply
    finally:
        for s in busy:
            s.close()


def test_an_idle_connection_closes_after_the_idle_timeout(start_drive):
    d = start(start_drive, "--tcp-idle-timeout", "1")
    idle = connect(d)
    active = connect(d)
    try:
        t0 = time.monotonic()
        # a connection that keeps asking stays open past the timeout
        while time.monotonic() - t0 < 1.6:
            active.sendall(struct.pack(">HHHB", 7, 0, len(READ_SW) + 1, 1) + READ_SW)
            active.settimeout(2)
            assert len(active.recv(64)) == 11
            time.sleep(0.2)
        assert closed_by_server(idle, 1.0)
        took = time.monotonic() - t0
        assert 0.9 <= took < 2.5, took
        assert not closed_by_server(active, 0.1)
        c = wait_counters(d, lambda c: c["idle_closed"] == 1)
        assert (c["idle_closed"], c["connections"], c["idle_timeout_s"]) == (1, 1, 1), c
    finally:
        idle.close()
        active.close()
    assert "(idle for 1 s)" in d.stderr()


def test_idle_timeout_zero_keeps_connections_and_the_default_is_60_s(start_drive):
    d = start(start_drive, "--tcp-idle-timeout", "0")
    s = connect(d)
    try:
        assert counters(d)["idle_timeout_s"] is None
        assert not closed_by_server(s, 1.5)
    finally:
        s.close()
    assert counters(start(start_drive))["idle_timeout_s"] == 60
