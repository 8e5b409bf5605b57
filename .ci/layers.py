#!/usr/bin/env python3
"""Fails when the core's modules import each other in a cycle.

The core is `src/` without its hosts: `src/firmware/`, `src/virtual/` and
`src/main.rs` may import every layer, so they are left out (and nothing in
the core may import them). A module is a top-level part of the crate:
`src/rtu/` or `src/rtu.rs` is `rtu`, `src/slave.rs` with `src/slave/` is
`slave`. Every `crate::…` path in code (comments and doc comments skipped)
and every `use super::…` that climbs out of its module is an edge.

Prints the module graph in layer order (lowest first), then either `no
cycle` or each cycle with one file:line that makes each of its edges.
docs/architecture.md states the layer rule this guards.

The virtual drive (`src/virtual/`, the crate's module `virtual_drive`) is
checked too, one node per file: an edge is a `super::…`, `self::…` or
`crate::virtual_drive::…` path to another file's module. A module and the
modules inside it (`run.rs` and `run/serve.rs`) may use each other's items
(that is nesting, not layering); any other cycle fails.

With `--files` every file is a module of its own (`periph/timer.rs` is
`periph::timer`) and the crate root (main.rs / lib.rs) is left out: the
finer check for a crate without a core/host split, such as fw-sim.

Usage: python3 .ci/layers.py [--files] [SRC_DIR]   (default: src)
"""

import re
import sys
from pathlib import Path

HOSTS = {"firmware", "virtual", "main"}

CRATE_PATH = re.compile(r"\bcrate::(\{?)\s*([A-Za-z_][A-Za-z0-9_]*)")
CRATE_GROUP = re.compile(r"\bcrate::\{([^}]*)\}")
SUPER_PATH = re.compile(r"\b((?:super::)+)([A-Za-z_][A-Za-z0-9_]*)?")


def module_path(src: Path, file: Path):
    """The module path of `file` as a list (`src/rtu/crc16.rs` → [rtu, crc16])."""
    parts = list(file.relative_to(src).with_suffix("").parts)
    if parts[-1] == "mod":
        parts.pop()
    return parts


def strip_comments(line: str) -> str:
    """Code part of a line: `//` comments (and doc comments) removed; string
    literals are rare enough in `use` positions not to matter."""
    at = line.find("//")
    return line if at < 0 else line[:at]


def edges_of(src: Path, file: Path):
    """(target module, line number) for every cross-module path in `file`."""
    here = module_path(src, file)
    top = here[0]
    for n, code in code_lines(file):
        targets = []
        for group in CRATE_GROUP.finditer(code):
            for item in group.group(1).split(","):
                name = item.strip().split("::")[0].strip()
                if name:
                    targets.append(name)
        for m in CRATE_PATH.finditer(code):
            if m.group(1) != "{":
                targets.append(m.group(2))
        for m in SUPER_PATH.finditer(code):
            ups = m.group(1).count("super::")
            # `super` of a module file (src/x/mod.rs or src/x.rs) is its
            # parent; of any other file (src/x/y.rs) it is the module itself.
            base = here[: len(here) - ups]
            if not base:
                # climbed to the crate root: the next segment names the module
                if m.group(2):
                    targets.append(m.group(2))
            else:
                targets.append(base[0])
        for t in targets:
            if t != top:
                yield t, n


def graph(src: Path):
    modules = set()
    for f in src.iterdir():
        name = f.stem if f.suffix == ".rs" else f.name
        if name not in ("lib",) and (f.suffix == ".rs" or f.is_dir()):
            modules.add(name)
    core = sorted(modules - HOSTS)
    edges = {m: {} for m in core}
    for f in sorted(src.rglob("*.rs")):
        parts = module_path(src, f)
        if not parts or parts[0] in HOSTS or parts[0] == "lib":
            continue
        for target, n in edges_of(src, f):
            if target in HOSTS:
                sys.exit(f"{f}:{n}: the core imports the host module `{target}`")
            if target in edges[parts[0]] or target not in modules:
                continue
            edges[parts[0]][target] = f"{f}:{n}"
    return core, edges


FULL_PATH = re.compile(r"\b(crate|(?:super::)+)((?:::)?(?:[A-Za-z_][A-Za-z0-9_]*::)*)(\{[^}]*\}|[A-Za-z_][A-Za-z0-9_]*)?")


def code_lines(file: Path):
    """(line number, code) of `file`, comments removed."""
    in_block_comment = False
    for n, raw in enumerate(file.read_text(encoding="utf-8").splitlines(), 1):
        line = raw
        if in_block_comment:
            end = line.find("*/")
            if end < 0:
                continue
            line = line[end + 2 :]
            in_block_comment = False
        start = line.find("/*")
        if start >= 0 and line.find("*/", start) < 0:
            in_block_comment = True
            line = line[:start]
        yield n, strip_comments(line)


def file_graph(src: Path):
    """The graph of `--files`: each file a module named by its full path,
    an edge to the longest module that prefixes a `crate::` / `super::`
    path (a group `a::{b, c::d}` is one path per item)."""
    files = {}
    for f in sorted(src.rglob("*.rs")):
        parts = module_path(src, f)
        if parts and parts != ["main"] and parts != ["lib"]:
            files["::".join(parts)] = (f, parts)
    names = sorted(files)
    edges = {m: {} for m in names}

    def resolve(path):
        for k in range(len(path), 0, -1):
            name = "::".join(path[:k])
            if name in files:
                return name
        return None

    for name, (f, here) in files.items():
        for n, code in code_lines(f):
            for m in FULL_PATH.finditer(code):
                if m.group(1) == "crate":
                    base = []
                else:
                    base = here[: len(here) - m.group(1).count("super::")]
                prefix = [p for p in m.group(2).split("::") if p]
                tail = m.group(3) or ""
                items = tail[1:-1].split(",") if tail.startswith("{") else [tail]
                for item in items:
                    rest = [p.strip() for p in item.split("::") if p.strip()]
                    target = resolve(base + prefix + rest)
                    if target and target != name and target not in edges[name]:
                        edges[name][target] = f"{f}:{n}"
    return names, edges


def cycles(core, edges):
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in core:
        if v not in index:
            visit(v)
    return out


def layers(core, edges):
    """Layer of each module: 0 for one that imports nothing of the core,
    else one more than the highest layer it imports (acyclic graphs only)."""
    layer = {}

    def of(v):
        if v not in layer:
            layer[v] = 1 + max((of(w) for w in edges[v]), default=-1)
        return layer[v]

    for v in core:
        of(v)
    return layer


HOST_PATH = re.compile(
    r"\b(crate::virtual_drive::|(?:super::)+|self::)(\{[^}]*\}|[A-Za-z_][A-Za-z0-9_]*(?:::[A-Za-z_][A-Za-z0-9_]*)*)"
)


def host_graph(root: Path):
    """Modules of a host directory, one per file, and the edges between
    modules of which neither holds the other."""
    files = sorted(root.rglob("*.rs"))
    mods = {}
    for f in files:
        parts = list(f.relative_to(root).with_suffix("").parts)
        if parts[-1] == "mod":
            parts.pop()
        mods[tuple(parts)] = f
    edges = {m: {} for m in mods}

    def resolve(base, names):
        """The deepest module of `base` + `names`."""
        at = tuple(base)
        for n in names:
            if at + (n,) in mods:
                at = at + (n,)
            else:
                break
        return at

    for m, f in mods.items():
        for n, code in code_lines(f):
            for hit in HOST_PATH.finditer(code):
                head, rest = hit.group(1), hit.group(2)
                # `super` is the module's parent, whichever file holds it
                if head.startswith("crate::"):
                    base = ()
                elif head == "self::":
                    base = m
                else:
                    base = m[: max(len(m) - head.count("super::"), 0)]
                paths = (
                    [p.strip() for p in rest[1:-1].split(",")]
                    if rest.startswith("{")
                    else [rest]
                )
                for p in paths:
                    names = [x for x in p.split("::") if x and x != "self"]
                    target = resolve(base, names)
                    nested = target[: len(m)] == m or m[: len(target)] == target
                    if not nested and target not in edges[m]:
                        edges[m][target] = f"{f}:{n}"
    return sorted(mods), edges


def main():
    args = sys.argv[1:]
    files = "--files" in args
    args = [a for a in args if a != "--files"]
    src = Path(args[0] if args else "src")
    virtual = src / "virtual"
    if not files and virtual.is_dir():
        vmods, vedges = host_graph(virtual)
        found = cycles(vmods, vedges)

        def name(m):
            return "virtual::" + "::".join(m) if m else "virtual"

        if found:
            for comp in found:
                print("import cycle in the virtual drive between: " + ", ".join(map(name, comp)))
                for v in comp:
                    for w, where in sorted(vedges[v].items()):
                        if w in comp:
                            print(f"  {name(v)} -> {name(w)}  ({where})")
            sys.exit(1)
        print(f"virtual drive: {len(vmods)} modules, no cycle")
    core, edges = file_graph(src) if files else graph(src)
    found = cycles(core, edges)
    if found:
        for comp in found:
            print("import cycle between: " + ", ".join(comp))
            for v in comp:
                for w, where in sorted(edges[v].items()):
                    if w in comp:
                        print(f"  {v} -> {w}  ({where})")
        sys.exit(1)
    layer = layers(core, edges)
    width = max([12] + [len(v) for v in core])
    for v in sorted(core, key=lambda v: (layer[v], v)):
        below = ", ".join(sorted(edges[v])) or "-"
        print(f"layer {layer[v]}: {v:<{width}} imports {below}")
    print("no cycle")


if __name__ == "__main__":
    main()
