#!/usr/bin/env python3
"""Flash size breakdown of the firmware images, per crate and per function.

Reads each ELF with the toolchain's llvm-size (sections) and llvm-nm
(symbols, `--print-size --size-sort`), attributes every flash symbol to a
crate, and writes one Markdown file with the totals, the per-crate table and
the largest functions and tables of each board.

Flash = every section placed in flash (0x0800_0000..) plus the .data image
(its initial values are stored in flash and copied at boot); static RAM =
every section placed in RAM (.data, .bss, .uninit). The stack is not a
section (flip-link puts it below them) and is not counted. This script is
the one place these sums are made and compared with the budgets: the
firmware stage fails when it exits non-zero.

Symbols carry the bytes of their own code or table; what no symbol covers
is listed per kind (unnamed constants in .rodata; padding elsewhere), so
each board's crate column adds up to its flash total.

Usage: size_report.py OUT.md BOARD=ELF [BOARD=ELF ...]
BOARD is a key of BUDGETS.
"""
import os
import re
import subprocess
import sys
from collections import defaultdict

FLASH = (0x0800_0000, 0x0810_0000)
RAM = (0x2000_0000, 0x2010_0000)
TOP_FUNCTIONS = 40
# board: (flash budget, static RAM budget) in bytes; the firmware stage fails
# above either. Each flash budget is the image's size when it was last set
# plus ROOM, so that growth fails CI (docs/firmware-size.md): after a change
# that is meant to grow an image (or a merge), set the size part to the new
# size from the generated file, keeping ROOM. The targets (F103 ≤ 52 KiB,
# G431 ≤ 56 KiB) are the limits the size part must stay under.
ROOM = 4 * 1024
BUDGETS = {
    "STM32G431CB": (59284 + ROOM, 16 * 1024),
    "STM32F103C8": (56960 + ROOM, 12 * 1024),
}
UNNAMED = "unnamed constants in .rodata (literals, switch and lookup tables)"
PADDING = "alignment padding, unsized symbols"

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


TASKS = "async tasks (src/firmware with what they inlined; embassy TaskStorage::poll)"
PRIMITIVES = ("u8", "u16", "u32", "u64", "u128", "i8", "i16", "i32", "i64", "i128",
              "usize", "isize", "bool", "char", "str")


def crate_of(name):
    """The crate whose code a symbol is: the first path segment, or the
    implementing type's crate for `<T as Trait>::f` (the trait's crate when
    T is a primitive, slice or tuple); unmangled symbols by what defines
    them."""
    if name.startswith("embassy_executor::raw::TaskStorage<F>::poll"):
        # F is the task's future: the firmware's own async fn bodies
        return TASKS
    s = name
    while s.startswith("<") or s.startswith("&") or s.startswith("*"):
        s = s.lstrip("<&*").removeprefix("mut ").removeprefix("const ")
    if s.startswith("[") or s.startswith("("):
        trait = re.search(r" as ([A-Za-z_][A-Za-z0-9_]*)::", s)
        return trait.group(1) if trait else "core"
    m = re.match(r"[A-Za-z_][A-Za-z0-9_]*", s)
    head = m.group(0) if m else s
    if head in PRIMITIVES:
        trait = re.search(r" as ([A-Za-z_][A-Za-z0-9_]*)::", s)
        return trait.group(1) if trait else "core"
    if head == "__rustc":  # the panic entry point core calls
        return "core"
    if "::" in s[: len(head) + 2]:
        return head
    if "embassy_time" in head:
        return "embassy_time"
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


def ram_total(secs):
    return sum(size for _, size, addr in secs if RAM[0] <= addr < RAM[1])


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
            syms.append((size, kind, readable(name), addr))
    return syms


SOURCE_LINE = re.compile(r"^; (/.*):\d+$")
INSN = re.compile(r"^\s*([0-9a-f]{7,8}):")
FUNC = re.compile(r"^([0-9a-f]{8}) <")
REGISTRY = re.compile(r"/registry/src/[^/]+/([A-Za-z0-9_\-]+?)-\d+\.\d+[^/]*/")


def source_of(path, package_src):
    """Who wrote the source line `path`: a file of this crate, another
    crate (by its registry directory) or Rust's own library."""
    if path.startswith(package_src):
        return "src/" + path[len(package_src):]
    m = REGISTRY.search(path)
    if m:
        return m.group(1).replace("-", "_")
    if "compiler-builtins" in path:
        return "compiler_builtins"
    if "/library/" in path or path.startswith("/rustc/"):
        return LIBRARY
    if "/out/" in path:
        return "embassy_stm32 (generated)"
    return "other"


LIBRARY = "core library"


def by_source(elf):
    """Bytes of .text per source the line table names: an inlined function's
    instructions count for the file they came from, not for their caller.
    Rust's own library (integer methods, slices, `Option`, `Cell`...) is
    nearly always inlined; its lines count for the last source line before
    them in the same function that is not the library, i.e. the code that
    used it."""
    out = subprocess.check_output(
        [tool("llvm-objdump"), "-d", "-l", "--no-show-raw-insn", elf], text=True)
    package_src = os.path.abspath("src") + "/"
    per, cur, prev = defaultdict(int), "no line information", None
    # the same per async task (embassy's TaskStorage::poll, by address)
    tasks, task = defaultdict(lambda: defaultdict(int)), None
    user = None
    for line in out.splitlines():
        if FUNC.match(line):
            cur, user = "no line information", None
            task = line.split()[0] if TASK_POLL in line else None
            continue
        m = SOURCE_LINE.match(line)
        if m:
            cur = source_of(m.group(1), package_src)
            if cur == LIBRARY and user:
                cur = user
            elif cur != LIBRARY:
                user = cur
            continue
        m = INSN.match(line)
        if m:
            addr = int(m.group(1), 16)
            if prev is not None and 0 < addr - prev[0] <= 8:
                per[prev[1]] += addr - prev[0]
                if prev[2]:
                    tasks[prev[2]][prev[1]] += addr - prev[0]
            prev = (addr, cur, task)
    return per, tasks


# embassy's poll of one task, mangled: holds that task's async fn body
TASK_POLL = "TaskStorage$LT$F$GT$4poll"
TASK_ROWS = 12


def board_report(elf):
    secs = sections(elf)
    total = flash_total(secs)
    ram = ram_total(secs)
    syms = symbols(elf)
    per_crate = defaultdict(int)
    for size, _, name, _ in syms:
        per_crate[crate_of(name)] += size
    # what no symbol covers, by section: .rodata's are the compiler's unnamed
    # constants, elsewhere it is alignment padding and unsized symbols
    for name, size, addr in secs:
        if not (FLASH[0] <= addr < FLASH[1] or name == ".data") or not size:
            continue
        covered = sum(s for s, _, _, a in syms if addr <= a < addr + size)
        key = UNNAMED if name == ".rodata" else PADDING
        per_crate[key] += size - covered
    return total, ram, secs, per_crate, sorted(syms, reverse=True)


def main():
    out_path, pairs = sys.argv[1], sys.argv[2:]
    reports = [(b, e, board_report(e)) for b, e in (p.split("=", 1) for p in pairs)]
    rustc = subprocess.check_output(["rustc", "-V"], text=True).strip()
    lines = [
        "# Firmware size (generated)",
        "",
        "Written by `.ci/firmware.sh` (`.ci/size_report.py` over the profile `fw`",
        f"ELFs, {rustc}); do not edit. What is counted and the history of",
        "size changes: [../firmware-size.md](../firmware-size.md).",
        "",
        "| board | flash, B | budget, B | left, B | .vector_table | .text | .rodata | .data "
        "| static RAM, B | budget, B |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    bad = []
    for board, _, (total, ram, secs, _, _) in reports:
        flash_budget, ram_budget = BUDGETS[board]
        by = {n: s for n, s, _ in secs}
        lines.append(f"| {board} | {total} | {flash_budget} | {flash_budget - total} | "
                     f"{by.get('.vector_table', 0)} | {by.get('.text', 0)} | "
                     f"{by.get('.rodata', 0)} | {by.get('.data', 0)} | {ram} | {ram_budget} |")
        if total > flash_budget:
            bad.append(f"{board}: FLASH BUDGET EXCEEDED ({total} B > {flash_budget} B)")
        if ram > ram_budget:
            bad.append(f"{board}: RAM BUDGET EXCEEDED ({ram} B > {ram_budget} B)")
    lines.append("")
    for board, elf, (total, _, _, per_crate, syms) in reports:
        lines += [f"## {board}", "", f"`{elf}`: {total} B of flash.", "",
                  "| crate | B | % |", "|---|---:|---:|"]
        for crate, size in sorted(per_crate.items(), key=lambda kv: (-kv[1], kv[0])):
            lines.append(f"| {crate} | {size} | {100 * size / total:.1f} |")
        per_module = defaultdict(int)
        for size, _, name, _ in syms:
            if crate_of(name) == "modbus_drive":
                m = re.search(r"modbus_drive::([a-z_0-9]+)", name)
                per_module[m.group(1) if m else "(other)"] += size
        lines += ["", "The crate `modbus_drive` by module (its own symbols, not what the tasks "
                  "inlined):", "", "| module | B |", "|---|---:|"]
        for module, size in sorted(per_module.items(), key=lambda kv: (-kv[1], kv[0])):
            lines.append(f"| {module} | {size} |")
        lines += ["", "Code (`.text`) by the source it was written in, inlining resolved "
                  "through the debug line table: what the async tasks hold is spread "
                  "over the files it came from, and Rust's library code inlined into a "
                  "function counts for the source that used it (`core library` is what "
                  "was not inlined). The last instruction of each function is not "
                  "counted:", "",
                  "| source | B |", "|---|---:|"]
        per_source, tasks = by_source(elf)
        for src, size in sorted(per_source.items(), key=lambda kv: (-kv[1], kv[0])):
            lines.append(f"| {src} | {size} |")
        for task in sorted(tasks, key=lambda t: -sum(tasks[t].values())):
            srcs = sorted(tasks[task].items(), key=lambda kv: (-kv[1], kv[0]))
            # a task is named by the firmware file its async fn is in
            own = next((s for s, _ in srcs if s.startswith("src/firmware/")), "?")
            lines += ["", f"The async task in `{own}` (embassy `TaskStorage::poll` at "
                      f"0x{task}, {sum(tasks[task].values())} B): its state machine and "
                      f"what it inlined, by source, the largest {TASK_ROWS}:", "",
                      "| source | B |", "|---|---:|"]
            for src, size in srcs[:TASK_ROWS]:
                lines.append(f"| {src} | {size} |")
        lines += ["", f"Largest {TOP_FUNCTIONS} symbols (code `t`/`T`, tables `r`/`R`, "
                  ".data `d`); inlined functions count in their caller:", "",
                  "| B | kind | symbol |", "|---:|---|---|"]
        for size, kind, name, _ in syms[:TOP_FUNCTIONS]:
            shown = name if len(name) <= 110 else name[:107] + "..."
            lines.append(f"| {size} | {kind} | `{shown}` |")
        lines.append("")
    os.makedirs(os.path.dirname(out_path) or ".", exist_ok=True)
    with open(out_path, "w") as f:
        f.write("\n".join(lines))
    for board, _, (total, ram, _, per_crate, _) in reports:
        flash_budget, ram_budget = BUDGETS[board]
        top = ", ".join(f"{c} {s}" for c, s in
                        sorted(per_crate.items(), key=lambda kv: -kv[1])[:4])
        print(f"{board}: flash {total} B of {flash_budget} B ({flash_budget - total} left), "
              f"static RAM {ram} B of {ram_budget} B; largest: {top}")
    for line in bad:
        print(line)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
