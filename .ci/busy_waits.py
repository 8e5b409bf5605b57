#!/usr/bin/env python3
"""No busy wait longer than 10 µs in thread mode or an interrupt
(docs/firmware.md, "Busy waits"): every `asm::delay` call in src/ must be
written `board::SYSCLK_HZ / 1_000_000 * NAME` with `NAME` a `const` of the
same file holding a literal number of µs; its worst case, three core cycles
per requested cycle (cortex-m 0.7.10's `asm::delay` loop on Cortex-M3/M4,
its own docs), must stay within the bound. Blocking delays of embassy-time
or embedded-hal (`block_for`, `delay_us` / `delay_ms` / `delay_ns`) are
refused outright. Prints each call site with its bound; exits 1 on any
violation."""

import re
import sys
from pathlib import Path

BOUND_US = 10
CYCLES_PER_REQUESTED = 3
CALL = re.compile(r"asm::delay\s*\(([^;]*)\)\s*;")
ARG = re.compile(r"^\s*board::SYSCLK_HZ\s*/\s*1_000_000\s*\*\s*([A-Z][A-Z0-9_]*)\s*$")
FORBIDDEN = re.compile(r"\bblock_for\s*\(|\.delay_(us|ms|ns)\s*\(")


def const_value(text: str, name: str):
    m = re.search(rf"const\s+{name}\s*:\s*u32\s*=\s*([0-9_]+)\s*;", text)
    return int(m.group(1).replace("_", "")) if m else None


def main(root: Path) -> int:
    bad = 0
    sites = 0
    for path in sorted(root.rglob("*.rs")):
        text = path.read_text()
        code = re.sub(r"//[^\n]*", "", text)  # comments may name anything
        for m in FORBIDDEN.finditer(code):
            line = code[: m.start()].count("\n") + 1
            print(f"{path}:{line}: blocking delay `{m.group(0)}`: await a timer instead")
            bad += 1
        for m in CALL.finditer(code):
            sites += 1
            line = code[: m.start()].count("\n") + 1
            arg = ARG.match(m.group(1))
            value = const_value(text, arg.group(1)) if arg else None
            if value is None:
                print(f"{path}:{line}: asm::delay({m.group(1).strip()}): write it as "
                      "board::SYSCLK_HZ / 1_000_000 * CONST with CONST a literal µs const of this file")
                bad += 1
                continue
            worst = value * CYCLES_PER_REQUESTED
            ok = worst <= BOUND_US
            print(f"{path}:{line}: asm::delay {arg.group(1)} = {value} µs asked, "
                  f"at most {worst} µs ({'ok' if ok else f'over {BOUND_US} µs'})")
            bad += 0 if ok else 1
    print(f"busy waits: {sites} asm::delay call site(s), {bad} violation(s), bound {BOUND_US} µs")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1] if len(sys.argv) > 1 else "src")))
