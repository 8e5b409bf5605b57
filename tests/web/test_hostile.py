"""The page's guards, over HTTP against the release binary (no browser):
DNS rebinding (`Host`), the token beyond loopback, the caps on event
streams and request sizes, percent-decoded queries, and a flood of
connections and a slow-loris client while a master and the page client
stay served (the phases of tests/web/hostile.py). Run by .ci/web.sh."""

from __future__ import annotations

import json
import re
import socket
import tempfile
import time
from pathlib import Path

import pytest

from hostile import Drive, http, raw_status, run_phases

MODE_DISPLAY = 0x6061  # follows a write of 0x6060 (write-only)


@pytest.fixture
def workdir():
    with tempfile.TemporaryDirectory() as tmp:
        yield Path(tmp)


@pytest.fixture
def local(workdir):
    d = Drive(workdir)
    try:
        yield d
    finally:
        d.stop()


def mode_of(drive: Drive) -> int:
    status, _, body = http(drive.base + "api/state",
                           headers={"X-Modbus-Drive-Token": drive.token or ""})
    assert status == 200
    rows = json.loads(body)["drives"][0]["od"]
    return next(r["value"] for r in rows if r["index"] == MODE_DISPLAY)


def mode_becomes(drive: Drive, value: int) -> bool:
    """The view is published after the command's answer: poll it."""
    deadline = time.monotonic() + 3
    while mode_of(drive) != value:
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def cmd(drive: Drive, query: str, headers: dict | None = None) -> tuple[int, bytes]:
    h = {"X-Modbus-Drive": "page", **(headers or {})}
    status, _, body = http(drive.base + "api/cmd?" + query, method="POST", headers=h)
    return status, body


def test_a_rebinding_host_is_refused_and_changes_nothing(local):
    port = local.web_port
    for host in ["evil.example", f"evil.example:{port}", f"127.0.0.1.nip.io:{port}",
                 f"localhost.evil.example:{port}"]:
        for path in ["", "api/state", "api/events"]:
            status, _, _ = http(local.base + path, headers={"Host": host})
            assert status == 403, (host, path)
        status, _ = cmd(local, "d=0&c=write&index=0x6060&value=1", {"Host": host})
        assert status == 403, host
    assert mode_of(local) != 1
    # HTTP/1.1 without Host at all
    assert raw_status(port, b"GET /api/state HTTP/1.1\r\n\r\n") == 403
    for host in [f"127.0.0.1:{port}", f"localhost:{port}", "localhost"]:
        assert http(local.base + "api/state", headers={"Host": host})[0] == 200, host


def test_beyond_loopback_a_printed_token_is_required(workdir):
    d = Drive(workdir, web="0.0.0.0:0")
    try:
        assert d.token and re.fullmatch(r"[0-9a-f]{32}", d.token), d.printed_url
        assert d.printed_url.endswith(f"/?token={d.token}")
        wrong = d.token[:-1] + ("0" if d.token[-1] != "0" else "1")
        for path in ["", "api/state", "api/events", "page.js"]:
            assert http(d.base + path)[0] == 401, path
            assert http(d.base + path + f"?token={wrong}")[0] == 401, path
            assert http(d.base + path, headers={"X-Modbus-Drive-Token": wrong})[0] == 401
        for query in ["d=0&c=write&index=0x6060&value=1",
                      f"d=0&c=write&index=0x6060&value=1&token={wrong}"]:
            assert cmd(d, query)[0] == 401
        assert cmd(d, "d=0&c=write&index=0x6060&value=1",
                   {"X-Modbus-Drive-Token": wrong})[0] == 401
        assert mode_of(d) != 1
        # the printed URL works, and its cookie serves the page's requests
        status, headers, _ = http(d.base + f"?token={d.token}")
        assert status == 200
        cookie = headers["Set-Cookie"].split(";")[0]
        assert cookie == f"modbus_drive_token_{d.web_port}={d.token}"
        assert "SameSite=Strict" in headers["Set-Cookie"]
        assert http(d.base + "api/state", headers={"Cookie": cookie})[0] == 200
        status, body = cmd(d, "d=0&c=write&index=0x6060&value=1", {"Cookie": cookie})
        assert status == 200 and b'"ok":true' in body
        assert mode_becomes(d, 1)
        # the token does not replace the page's own header on a POST
        status, _, _ = http(d.base + "api/cmd?d=0&c=enable", method="POST",
                            headers={"Cookie": cookie})
        assert status == 403
    finally:
        d.stop()


def test_a_given_token_is_required_on_loopback_too(workdir):
    token = "a-given-token-0123456789"
    d = Drive(workdir, extra=("--web-token", token))
    try:
        assert d.token == token
        assert http(d.base + "api/state")[0] == 401
        assert http(d.base + "api/state?token=a-given-token-012345678")[0] == 401
        assert http(d.base + f"api/state?token={token}")[0] == 200
    finally:
        d.stop()


def test_event_streams_are_capped_and_freed(local):
    cap = 8
    streams = []
    try:
        for _ in range(cap):
            s = socket.create_connection(("127.0.0.1", local.web_port), timeout=5)
            s.sendall("GET /api/events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
            assert s.recv(64).startswith(b"HTTP/1.1 200"), "a stream under the cap"
            streams.append(s)
        status, _, _ = http(local.base + "api/events")
        assert status == 503
        # the page and commands are not held up by the open streams
        assert http(local.base + "api/state")[0] == 200
        streams.pop().close()
        # the stream's thread sees the close at its next write (2 s at most)
        deadline = time.monotonic() + 10
        while True:
            with socket.create_connection(("127.0.0.1", local.web_port), timeout=5) as s:
                s.sendall(b"GET /api/events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
                if s.recv(64).startswith(b"HTTP/1.1 200"):
                    break
            assert time.monotonic() < deadline, "a closed stream's slot never came back"
            time.sleep(0.5)
    finally:
        for s in streams:
            s.close()


def test_oversize_requests_are_refused(local):
    port = local.web_port
    head = b"GET /api/state HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Big: " + b"a" * 10_000 + b"\r\n\r\n"
    assert raw_status(port, head) == 431
    body = b"POST /api/cmd?d=0&c=enable HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 100000\r\n\r\n"
    assert raw_status(port, body) == 413
    assert http(local.base + "api/state?" + "x" * 3000)[0] == 414
    chunked = b"POST /api/cmd HTTP/1.1\r\nHost: 127.0.0.1\r\nTransfer-Encoding: chunked\r\n\r\n"
    assert raw_status(port, chunked) == 501
    assert raw_status(port, b"NONSENSE\r\n\r\n") == 400


def test_query_values_are_percent_decoded(local):
    # what the page's URLSearchParams sends for a typed "+1"
    status, body = cmd(local, "d=0&c=write&index=0x6060&value=%2B1")
    assert status == 200 and b'"ok":true' in body, body
    assert mode_becomes(local, 1)
    status, body = cmd(local, "d=0&c=write&index=0x6060&value=%2")
    assert status == 400 and b"well-formed" in body, body


def test_a_flood_and_a_slow_loris_leave_the_page_and_a_master_served(local):
    # the figures of docs/generated/web-load.md come from the same phases
    phases = run_phases(local, flood_n=500, loris_n=300, loris_s=8.0)
    for name, probe, got in phases:
        assert probe.master_errors == 0, name
        assert probe.page_errors == 0, name
        assert probe.master_s and max(probe.master_s) < 1.0, (name, max(probe.master_s))
        assert probe.page_s and max(probe.page_s) < 2.0, (name, max(probe.page_s))
    _, _, flood = phases[1]
    assert flood.get("hung", 0) == 0, flood
    assert flood.get("200", 0) > 0, flood
    assert sum(v for k, v in flood.items() if k != "hung") == 500, flood
    _, _, loris = phases[2]
    # every stalled connection is closed by the server: at the request
    # time limit (5 s) or, beyond the cap on connections, to admit others
    assert loris["closed_by_server"] == 300, loris
    assert loris["last_closed_s"] < 7.0, loris
    _, _, after = phases[3]
    # a fixed pool: reader, workers and the loop, no thread per client
    assert after["threads"] <= 16, after
