"""mbpoll (Debian's libmodbus master) over the pseudo-terminal: a read of
0x6041 and a write of 0x6083 (issue 4). `-P none`: mbpoll's default parity
is even, the drive's line is 8N1 (SPEC §1)."""

import re
import signal
import subprocess
import time

from conftest import ACCELERATION, ACTUAL_POSITION, ROOT, Master


def mbpoll(link, *args):
    """One mbpoll run: RTU, 115200 8N1, address 1, PDU addressing (-0),
    once (-1), 2 s time-out. Arguments written `=value` are values to write
    (they go after the device)."""
    base = ["mbpoll", "-m", "rtu", "-b", "115200", "-P", "none", "-a", "1", "-0", "-1", "-o", "2"]
    opts = [a for a in args if not a.startswith("=")]
    values = [a[1:] for a in args if a.startswith("=")]
    return subprocess.run([*base, *opts, str(link), *values],
                          capture_output=True, text=True, timeout=20)


def test_mbpoll_reads_the_statusword(start_drive):
    d = start_drive("--no-status")
    r = mbpoll(d.link, "-t", "4:hex", "-r", str(0x6041), "-c", "1")
    assert r.returncode == 0, r.stdout + r.stderr
    # after power-up the drive is in switch on disabled (SPEC §8.1), bit 5
    # set as in every state but quick stop active (SPEC §8.2)
    assert f"[{0x6041}]: \t0x0060" in r.stdout, r.stdout


def test_mbpoll_writes_the_acceleration(start_drive):
    d = start_drive("--no-status")
    r = mbpoll(d.link, "-t", "4", "-r", str(0x6083), "=250")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Written 1 references" in r.stdout, r.stdout
    assert Master(d.client("tcp")).read(ACCELERATION) == 250


def readme_session() -> str:
    """The mbpoll block of the first session (docs/first-commands.md, which
    the README links to), as a newcomer copies it."""
    doc = (ROOT / "docs" / "first-commands.md").read_text()
    m = re.search(r"```sh\n(M=\"mbpoll.*?)```", doc, re.S)
    assert m, "docs/first-commands.md: the mbpoll session block is gone"
    return m.group(1)


def readme_console(program: str) -> tuple[str, str]:
    """The README's first `$ program ...` console block: the command line
    and the output it shows."""
    readme = (ROOT / "README.md").read_text()
    for block in re.findall(r"```console\n(.*?)```", readme, re.S):
        lines = block.splitlines()
        if lines and lines[0].startswith(f"$ {program} "):
            return lines[0][2:], "\n".join(lines[1:])
    raise AssertionError(f"README: no console block starting with `$ {program}`")


def test_the_readmes_first_read_prints_what_the_readme_shows(start_drive):
    """README's second first command, run unchanged but for the link path,
    prints exactly the output the README shows under it."""
    d = start_drive("--no-status")
    command, shown = readme_console("mbpoll")
    command = command.replace("/tmp/ttyDRIVE", str(d.link))
    r = subprocess.run(["bash", "-euo", "pipefail", "-c", command],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 0, r.stdout + r.stderr
    assert r.stdout.strip() == shown.strip(), r.stdout


def test_the_readmes_drive_prints_what_the_readme_shows(start_drive):
    """README's first command: the drive prints `ready` (the fixture waits
    for exactly that line) and then the lines the README shows, the pty's
    own name and the timestamps aside."""
    command, shown = readme_console("cargo")
    assert command.startswith("cargo run --release -- --pty-link /tmp/ttyDRIVE")
    lines = shown.splitlines()
    assert lines[0] == "ready", lines
    d = start_drive()
    time.sleep(0.3)
    got = d.stderr().splitlines()
    d.stop(signal.SIGINT)
    for want in lines[1:]:
        stamped = re.fullmatch(r"\[ *\d+\.\d{3}\] (.*)", want)
        pattern = re.escape(stamped.group(1) if stamped else want)
        pattern = pattern.replace("/dev/pts/0", r"/dev/pts/\d+").replace("/tmp/ttyDRIVE", ".*")
        if stamped:
            pattern = r"\[ *\d+\.\d{3}\] " + pattern
        assert any(re.fullmatch(pattern, line) for line in got), (want, got)


def test_the_readme_session_works_as_written(start_drive, tmp_path):
    """The README's first commands: start the drive with a pty link, run
    the mbpoll lines unchanged (only the link path differs), and the move
    arrives at 200000 steps; the plot is written on exit."""
    plot = tmp_path / "move.svg"
    d = start_drive("--no-status", "--plot", str(plot))
    script = readme_session().replace("/tmp/ttyDRIVE", str(d.link))
    r = subprocess.run(["bash", "-euo", "pipefail", "-c", script],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    assert f"[{0x6064}]:" in r.stdout, r.stdout  # the position was read
    m = Master(d.client("tcp"))
    deadline = time.monotonic() + 30
    while m.read32(ACTUAL_POSITION) != 200000:
        assert time.monotonic() < deadline, "the README's move did not arrive"
        time.sleep(0.1)
    assert d.stop(signal.SIGINT) == 0
    assert plot.exists() and plot.stat().st_size > 0
