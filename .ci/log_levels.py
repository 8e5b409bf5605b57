#!/usr/bin/env python3
"""The release image logs `warn` and `error` only (docs/firmware.md): no
defmt `info`, `debug` or `trace` string may be in it.

Usage: log_levels.py ELF...

defmt keeps each log string as a symbol of the ELF's `.defmt` section whose
name is JSON naming its level (`"tag":"defmt_info"`); a level filtered out
at build time leaves no symbol. The check lists the symbols below `warn`
and fails if there is one, or if the image has no `warn`/`error` string at
all (then the symbol format is not what this script reads)."""
import os
import re
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from size_report import tool  # noqa: E402

TAG = re.compile(r'"tag":"defmt_(\w+)"')
BELOW_WARN = {"info", "debug", "trace"}


def main(elves):
    bad = 0
    for elf in elves:
        out = subprocess.check_output([tool("llvm-nm"), elf], text=True)
        levels = {}
        for line in out.splitlines():
            m = TAG.search(line)
            if m:
                levels.setdefault(m.group(1), []).append(line.split(None, 2)[-1])
        low = [s for level in sorted(BELOW_WARN) for s in levels.get(level, [])]
        kept = len(levels.get("warn", [])) + len(levels.get("error", []))
        print(f"{elf}: {kept} warn/error log strings, {len(low)} below warn")
        for s in low:
            print(f"  {s}")
        if low or kept == 0:
            bad = 1
    return bad


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
