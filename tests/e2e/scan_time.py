"""Measures a full scan at one baud (`modbus-drive scan --baud 115200`:
247 addresses in each of the four formats) of the virtual drive over its
pseudo-terminal, and writes the figure to docs/generated/scan.md.

Run by .ci/e2e.sh with the e2e venv's python:
    python tests/e2e/scan_time.py --out docs/generated/scan.md"""

from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from conftest import BIN, VirtualDrive  # noqa: E402
import commission  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, help="the markdown file to write (else stdout)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        d = VirtualDrive(Path(tmp), ["--no-status"], tcp=False).start()
        try:
            load = os.getloadavg()[0]
            wall, out = commission.full_scan_at_one_baud(BIN, d.link)
        finally:
            d.stop()
    if out.returncode != 0:
        print(out.stdout + out.stderr, file=sys.stderr)
        return 1
    found = [l for l in out.stdout.splitlines() if l.startswith("address")]
    done = re.search(r"scan done: .*", out.stderr)
    text = f"""# Scan time (generated)

Written by `tests/e2e/scan_time.py --out` (run by `.ci/e2e.sh`): a full scan at one baud,
`modbus-drive scan --serial PTY --baud {commission.SCAN_BAUD}` (247 addresses in each of the
four formats of PA53), of one virtual drive at address 1 over its pseudo-terminal; release
binary, this machine: {os.cpu_count()} cores, load average {load:.1f} when it started.

| | |
|---|---|
| wall time of the command | {wall:.1f} s |
| the scan's own last line | `{done.group(0) if done else "?"}` |
| drives found | {len(found)}: `{found[0] if found else "-"}` |
"""
    if a.out:
        a.out.write_text(text)
    else:
        print(text)
    print(f"scan: {wall:.1f} s for a full scan at {commission.SCAN_BAUD}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
