"""The program as a user meets it: flags, `ready`, transports, signals,
trace and plot (issue 4)."""

import csv
import os
import signal
import socket
import subprocess
import time

import pytest

from conftest import BIN, hexb, with_crc

READ_STATUSWORD = hexb("01 03 60 41 00 01")


def run(*args, timeout=10):
    return subprocess.run([str(BIN), *args], capture_output=True, timeout=timeout)


def test_help_documents_every_flag_and_exits_0():
    r = run("--help")
    assert r.returncode == 0
    text = r.stdout.decode()
    for flag in ("--pty-link", "--no-pty", "--tcp", "--drives", "--cw-limit", "--ccw-limit",
                 "--home-switch", "--state", "--trace", "--plot", "--no-status", "--help"):
        assert flag in text, flag


@pytest.mark.parametrize("args,needle", [
    (["--bogus"], "unknown argument"),
    (["--tcp", "nowhere"], "ADDR:PORT"),
    (["--drives", "0,1"], "1..=247"),
    (["--drives", "1,1"], "twice"),
    (["--home-switch", "9:1"], "FROM must not exceed TO"),
    (["--cw-limit"], "needs a value"),
    (["--pty-link", "--no-status"], "--pty-link needs a value, got the flag `--no-status`"),
    (["--drives", "1", "--drives", "2"], "--drives given twice"),
    (["--trace", "t.csv", "--plot", "t.csv"], "same file"),
    (["--no-pty", "--tcp", "127.0.0.1:5020", "--modbus-tcp", "127.0.0.1:5020"],
     "one address cannot serve two listeners"),
    (["--modbus-tcp", "localhost:502"], "--modbus-tcp localhost:502: expected ADDR:PORT"),
    (["/dev/ttyUSB0"], "unknown argument `/dev/ttyUSB0`"),
])
def test_bad_flags_get_a_clear_message_and_exit_2(args, needle):
    r = run(*args)
    assert r.returncode == 2
    assert needle in r.stderr.decode()
    assert r.stdout == b"", "nothing on stdout, in particular no `ready`"


def test_a_port_in_use_is_reported_not_panicked_on(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        r = run("--no-pty", "--tcp", f"127.0.0.1:{port}")
    err = r.stderr.decode()
    assert r.returncode == 1, err
    assert f"--tcp 127.0.0.1:{port}: cannot listen" in err
    assert "in use" in err and "port 0 for a free one" in err
    assert "panicked" not in err
    assert r.stdout == b""


@pytest.mark.parametrize("make,needle", [
    (lambda p: p.write_text("my notes"), "a regular file is there"),
    (lambda p: p.mkdir(), "a directory is there"),
])
def test_a_pty_link_onto_something_not_a_symlink_is_refused_and_left_alone(tmp_path, make,
                                                                           needle):
    link = tmp_path / "ttyVD"
    make(link)
    r = run("--pty-link", str(link))
    err = r.stderr.decode()
    assert r.returncode == 1, err
    assert f"--pty-link {link}: {needle}" in err, err
    assert "pseudo-terminal" not in err, "the pty itself was fine"
    assert not link.is_symlink() and (link.is_dir() or link.read_text() == "my notes")
    r = run("--pty-link", str(tmp_path / "no" / "such" / "dir"))
    assert r.returncode == 1
    assert f"directory {tmp_path / 'no' / 'such'} does not exist" in r.stderr.decode()


@pytest.mark.parametrize("flag", ["--trace", "--plot", "--state"])
def test_a_file_that_cannot_be_written_is_reported_at_start_up(tmp_path, flag):
    """Not at the end of a session, when the plot would be drawn."""
    bad = tmp_path / "missing" / "f"
    r = run("--no-status", flag, str(bad))
    err = r.stderr.decode()
    assert r.returncode == 1, err
    assert str(bad) in err and "No such file or directory" in err, err
    assert flag in err, err
    assert r.stdout == b"", "no `ready`"


def test_ready_is_the_only_stdout_line_and_the_pty_link_points_at_the_pty(start_drive):
    d = start_drive()
    assert d.link.is_symlink()
    target = os.readlink(d.link)
    assert target.startswith("/dev/pts/")
    assert f"pty {target}" in d.stderr(), "the pty path is printed"
    d.stop()
    assert not d.link.exists(), "the link is removed on exit"


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_stops_cleanly_and_writes_trace_and_plot(start_drive, tmp_path, sig):
    csv_path = tmp_path / "t.csv"
    svg_path = tmp_path / "p.svg"
    d = start_drive("--trace", str(csv_path), "--plot", str(svg_path))
    time.sleep(0.3)
    assert d.stop(sig) == 0, d.stderr()
    rows = list(csv.reader(csv_path.open()))
    assert rows[0] == ["time_s", "address", "position_steps", "velocity_rpm", "statusword",
                       "mode"]
    assert len(rows) > 10, "sampled while running"
    assert rows[1][1] == "1"
    assert svg_path.read_text().startswith("<svg")


def test_several_tcp_connections_are_served_at_once(start_drive):
    d = start_drive("--no-status")
    raws = [d.raw("tcp") for _ in range(3)]
    try:
        # All three requests are in flight before any reply is read: each
        # connection is its own line and gets its own reply.
        for r in raws:
            r.write(with_crc(READ_STATUSWORD))
        for r in raws:
            reply = r.read_reply()
            assert reply[:3] == hexb("01 03 02"), reply.hex()
            assert with_crc(reply[:-2]) == reply
    finally:
        for r in raws:
            r.close()
    assert d.stderr().count("connected") == 3


def test_pty_and_tcp_work_at_the_same_time(start_drive):
    d = start_drive()
    with d.raw("pty") as p, d.raw("tcp") as t:
        frame = with_crc(READ_STATUSWORD)
        assert p.exchange(frame)[:3] == hexb("01 03 02")
        assert t.exchange(frame)[:3] == hexb("01 03 02")


def test_a_plain_serial_tool_reads_the_pty(start_drive):
    """socat, a tool that knows nothing of Modbus, opens the pty as a serial
    port: the bytes of a request go in, the bytes of the reply come out."""
    d = start_drive()
    frame = with_crc(READ_STATUSWORD)
    r = subprocess.run(
        ["socat", "-t", "0.5", "-T", "1", "STDIO", f"{d.link},raw,echo=0,b115200"],
        input=frame, capture_output=True, timeout=10)
    assert r.stdout[:3] == hexb("01 03 02"), (r.stdout.hex(), r.stderr)
    assert len(r.stdout) == 7
    assert with_crc(r.stdout[:5]) == r.stdout
