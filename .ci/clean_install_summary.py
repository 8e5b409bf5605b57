#!/usr/bin/env python3
"""The record of a clean-machine run (`.ci/clean-install.sh DIR --run-ci`),
from its log: what the machine lacked, how each install step and each stage
of `.ci/run` went, and the exit status. Writes docs/generated/clean-install.md.

    python3 .ci/clean_install_summary.py /var/tmp/ci-run.log
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

OUT = Path(__file__).resolve().parents[1] / "docs" / "generated" / "clean-install.md"
# what each stage prints when its tests ran (pytest's last line, cargo's
# per-binary results summed)
PYTEST = re.compile(r"^=+ (.*(?:passed|failed).*) in [0-9.]+s")
CARGO = re.compile(r"^test result: (\w+)\. (\d+) passed; (\d+) failed")


def main() -> int:
    log = Path(sys.argv[1])
    lines = log.read_text(errors="replace").splitlines()
    steps, stages, missing, status = [], [], None, None
    stage, cargo = None, [0, 0]
    for line in lines:
        if line.startswith("---- ") and re.match(r"---- \d\d:\d\d:\d\d ", line):
            steps.append(line[5:])
            if "exit status" in line:
                status = line[14:]
        elif line.startswith("==== ") and line.endswith(" ===="):
            if stage:
                stages.append((stage, cargo))
            stage, cargo = [line[5:-5], ""], [0, 0]
        elif line.startswith("deps (") and "missing" in line and missing is None:
            missing = line
        elif stage and (m := PYTEST.match(line)):
            stage[1] = m[1]
        elif stage and (m := CARGO.match(line)):
            cargo[0] += int(m[2])
            cargo[1] += int(m[3])
    if stage:
        stages.append((stage, cargo))
    if status is None:
        sys.exit(f"{log}: no exit status line (the run did not finish)")
    out = ["# Clean-machine run of `.ci/run` (generated)", "",
           "Written by `.ci/clean_install_summary.py` from the log of",
           "`.ci/clean-install.sh /var/tmp/ci-root --run-ci`; do not edit. What the",
           "script does: [../testing.md](../testing.md), \"A fresh clone's `.ci/run`, on",
           "a clean machine\".", "", "## Steps (wall-clock time of each start)", ""]
    out += [f"- {s}" for s in steps]
    if missing:
        out += ["", "Before the run, `.ci/deps.sh --check` of the chroot:", "", f"    {missing}"]
    out += ["", "## Stages of `.ci/run`", "", "| stage | tests |", "|---|---|"]
    for (name, pytest), (passed, failed) in stages:
        if name == "done":
            continue
        tests = pytest or (f"cargo: {passed} passed, {failed} failed" if passed or failed
                           else "(no test count printed: passed if the run's status is 0)")
        out.append(f"| {name} | {tests} |")
    out += ["", f"**{status}**", ""]
    OUT.write_text("\n".join(out))
    print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
