#!/usr/bin/env python3
"""Flash size breakdown of the firmware images, per crate and per function.

Reads each ELF with the toolchain's llvm-size (sections) and llvm-nm
(symbols, `--print-size --size-sort`), attributes every flash symbol to a
crate, and writes one Markdown file with the totals, the per-crate table and
the largest functions and tables of each board.

Flash = every section placed in flash plus the .data image, the same sum the
firmware stage checks against its budget. Symbols carry the bytes of their
own code or table; what no symbol covers (alignment padding, the few
assembly symbols without a size) is listed as "unattributed", so each
board's crate column adds up to its flash total.

Usage: size_report.py OUT.md BOARD=ELF [BOARD=ELF ...]
"""
import os
import re
import subprocess
import sys
from collections import defaultdict

FLASH = (0x0800_0000, 0x0810_0000)
RAM = (0x2000_0000, 0x2010_0000)
TOP_FUNCTIONS = 40

# legacy Rust mangling escapes that llvm-nm -C leaves in place
ESCAPES = [("$LT$", "<"), ("$GT$", ">"), ("$C$", ","), ("$u7b$", "{"),
           ("$u7d$", "}"), ("$u20$", " "), ("$RF$", "&"), ("$BP$", "*"),
           ("$LP$", "("), ("$RP$", ")"), ("$u27$", "'"), ("$u5b$", "["),
           ("$u5d$", "]"), ("$u3b$", ";"), ("$u21$", "!"), ("$u2b$", "+"),
           ("..", "::")]
HASH = re.compile(r"::h[0-9a-f]{16}$")


def tool(name):
    sysroot = subprocess.check_output(["rustc", "--print", "sysroot"], text=True).strip()
    host = re.search(r"^host: (.*)$", subprocess.check_output(["rustc", "-vV"], text=True),
                     re.M).group(1)
    return os.path.join(sysroot, "lib", "rustlib", host, "bin", name)


def readable(sym):
    sym = HASH.sub("", sym)
    for esc, ch in ESCAPES:
        sym = sym.replace(esc, ch)
    if sym.startswith("_<"):
        sym = sym[1:]
    return sym


def crate_of(name):
    """The crate whose code a symbol is: the first path segment, or the
    implementing type's crate for `<T as Trait>::f`; unmangled symbols by
    what defines them."""
    s = name
    while s.startswith("<") or s.startswith("&") or s.startswith("*"):
        s = s.lstrip("<&*").removeprefix("mut ").removeprefix("const ")
    m = re.match(r"[A-Za-z_][A-Za-z0-9_]*", s)
    head = m.group(0) if m else s
    if "::" in s[: len(head) + 2]:
        if head in ("u8", "u16", "u32", "u64", "u128", "i8", "i16", "i32", "i64",
                    "i128", "usize", "isize", "bool", "char", "str"):
            return "core"
        return head
    if s.startswith("[") or s.startswith("("):
        return "core"
    if re.match(r"__aeabi_|__(u|)(div|mod)|__mul|__ash|__lsh|mem(cpy|set|move|cmp)$|__udiv|__umod", s):
        return "compiler_builtins"
    if head in ("Reset", "DefaultHandler", "DefaultHandler_", "HardFault", "HardFault_",
                "DefaultPreInit", "__pre_init", "__RESET_VECTOR", "__EXCEPTIONS",
                "__INTERRUPTS", "_defmt_acquire", "_defmt_release", "_defmt_write",
                "_defmt_flush", "_defmt_timestamp", "_defmt_panic", "__defmt_default_panic"):
        return "cortex_m_rt / defmt (runtime symbols)"
    if re.fullmatch(r"[A-Z0-9_]+", head):
        return "interrupt handlers (src/firmware, embassy)"
    if head == "main":
        return "modbus_drive"
    return head


def sections(elf):
    out = subprocess.check_output([tool("llvm-size"), "-A", "-d", elf], text=True)
    rows = []
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[1].isdigit() and parts[2].isdigit():
            rows.append((parts[0], int(parts[1]), int(parts[2])))
    return rows


def flash_total(secs):
    total = 0
    for name, size, addr in secs:
        if FLASH[0] <= addr < FLASH[1]:
            total += size
        elif RAM[0] <= addr < RAM[1] and name == ".data":
            total += size
    return total


def symbols(elf):
    out = subprocess.check_output(
        [tool("llvm-nm"), "--print-size", "--size-sort", "-C", elf], text=True)
    syms, seen = [], set()
    for line in out.splitlines():
        parts = line.split(None, 3)
        if len(parts) != 4:
            continue
        addr, size, kind, name = int(parts[0], 16), int(parts[1], 16), parts[2], parts[3]
        in_flash = FLASH[0] <= addr < FLASH[1]
        is_data = RAM[0] <= addr < RAM[1] and kind in "dD"
        # identical code folding leaves several names on one body: count it once
        if size and (in_flash or is_data) and addr not in seen:
            seen.add(addr)
            syms.append((size, kind, readable(name)))
    return syms


def board_report(board, elf):
    secs = sections(elf)
    total = flash_total(secs)
    syms = symbols(elf)
    per_crate = defaultdict(int)
    for size, _, name in syms:
        per_crate[crate_of(name)] += size
    attributed = sum(per_crate.values())
    per_crate["unattributed (padding, symbols without a size)"] = total - attributed
    return total, secs, per_crate, sorted(syms, reverse=True)


def main():
    out_path, pairs = sys.argv[1], sys.argv[2:]
    reports = [(b, e, board_report(b, e)) for b, e in (p.split("=", 1) for p in pairs)]
    lines = [
        "# Firmware size (generated)",
        "",
        "Written by `.ci/size.sh` (`.ci/size_report.py` over the `fw` profile ELFs);",
        "do not edit. How it is measured and the budgets: `docs/firmware-size.md`.",
        "",
        "| board | flash, B | .text | .rodata | .vector_table | .data |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for board, _, (total, secs, _, _) in reports:
        by = {n: s for n, s, _ in secs}
        lines.append(f"| {board} | {total} | {by.get('.text', 0)} | {by.get('.rodata', 0)} | "
                     f"{by.get('.vector_table', 0)} | {by.get('.data', 0)} |")
    lines.append("")
    for board, elf, (total, _, per_crate, syms) in reports:
        lines += [f"## {board}", "", f"`{elf}`: {total} B of flash.", "",
                  "| crate | B | % |", "|---|---:|---:|"]
        for crate, size in sorted(per_crate.items(), key=lambda kv: -kv[1]):
            lines.append(f"| {crate} | {size} | {100 * size / total:.1f} |")
        lines += ["", f"Largest {TOP_FUNCTIONS} symbols (code `t`, tables `r`, .data `d`);",
                  "inlined functions count in their caller (the async tasks' `poll`",
                  "holds what the task inlined):", "",
                  "| B | kind | symbol |", "|---:|---|---|"]
        for size, kind, name in syms[:TOP_FUNCTIONS]:
            shown = name if len(name) <= 110 else name[:107] + "..."
            lines.append(f"| {size} | {kind} | `{shown}` |")
        lines.append("")
    os.makedirs(os.path.dirname(out_path) or ".", exist_ok=True)
    with open(out_path, "w") as f:
        f.write("\n".join(lines))
    for board, _, (total, _, per_crate, _) in reports:
        top = ", ".join(f"{c} {s}" for c, s in
                        sorted(per_crate.items(), key=lambda kv: -kv[1])[:5])
        print(f"{board}: flash {total} B ({top})")


if __name__ == "__main__":
    main()
