#!/usr/bin/env python3
"""Fails when docs or code comments name a file that does not exist.

Scans docs/*.md, README.md and the comments (`//`, `//!`, `///`) of every
.rs file under src/, tests/, fuzz/harness/ and benches/ for paths:

- anything that starts with `src/`, `tests/`, `fuzz/`, `benches/`,
  `docs/` or `.ci/` (relative links such as `../src/x.rs` included) must
  exist from the repository root;
- in a comment, a bare module path such as `motion/schedule.rs` must
  exist under src/, under a directory above the file, or from the root;
  a bare file name such as `schedule.rs` must be the name of some file of
  the repository. A path whose first directory exists nowhere here names
  another project's file (e.g. embassy's examples) and is skipped.

Usage: python3 .ci/paths.py   (from the repository root; prints each stale
path with file:line, exit 1 if any)
"""

import re
import sys
from pathlib import Path

ROOTS = ("src/", "tests/", "fuzz/", "benches/", "docs/", ".ci/")
ROOTED = re.compile(
    r"(?<![\w./-])(?:\.\./)*((?:src|tests|fuzz|benches|docs|\.ci)/[\w./-]*\w)"
)
# a module path or file name in a comment: dir/file.rs, file.rs
BARE = re.compile(r"(?<![\w./-])((?:[a-z_0-9]+/)*[a-z_0-9]+\.rs)\b")


def comment_of(line: str):
    at = line.find("//")
    return None if at < 0 else line[at:]


def bases(root: Path, where: Path):
    """Where a path named in `where` may be rooted: the repository, src/,
    and every directory above `where` (its crate's root included)."""
    out = [root, root / "src"]
    d = where.parent
    while d != Path(".") and d != d.parent:
        out.append(root / d)
        d = d.parent
    return out


def check_text(root: Path, where: Path, n: int, text: str, bare: bool, names, bad: list):
    for m in ROOTED.finditer(text):
        p = m.group(1)
        if any(c in p for c in "<>*{}…"):
            continue
        if not any((b / p.rstrip("/.")).exists() for b in bases(root, where)):
            bad.append(f"{where}:{n}: {p}")
    if not bare:
        return
    for m in BARE.finditer(text):
        p = m.group(1)
        if p.startswith(ROOTS) or p.startswith("examples/"):
            continue
        if "/" not in p:
            if p not in names:
                bad.append(f"{where}:{n}: {p}")
            continue
        first = p.split("/")[0]
        places = bases(root, where)
        if not any((b / first).exists() for b in places):
            continue  # another project's path
        if not any((b / p).exists() for b in places):
            bad.append(f"{where}:{n}: {p}")


def main():
    root = Path(".")
    bad = []
    names = {
        f.name
        for top in ("src", "tests", "fuzz", "benches", "examples", "fw-sim")
        for f in Path(top).rglob("*.rs")
        if "target" not in f.parts
    } | {"build.rs"}
    docs = sorted(Path("docs").glob("*.md")) + [Path("README.md")]
    for f in docs:
        for n, line in enumerate(f.read_text(encoding="utf-8").splitlines(), 1):
            check_text(root, f, n, line, False, names, bad)
    for top in ("src", "tests", "fuzz/harness", "benches"):
        for f in sorted(Path(top).rglob("*.rs")):
            if "target" in f.parts:
                continue
            for n, line in enumerate(f.read_text(encoding="utf-8").splitlines(), 1):
                c = comment_of(line)
                if c is not None:
                    check_text(root, f, n, c, True, names, bad)
    for b in bad:
        print(f"stale path: {b}")
    if bad:
        sys.exit(1)
    print("every named path exists")


if __name__ == "__main__":
    main()
