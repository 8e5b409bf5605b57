#!/usr/bin/env python3
"""Fails when a type of the core declares a field visible outside the crate.

The core is `src/` without its hosts (`src/firmware/`, `src/virtual/`,
`src/main.rs`, `src/bin/`), as for .ci/layers.py. Its types keep their
fields private and give other code getters, constructors and named
operations (docs/architecture.md states the rule and why). A field with a
plain `pub` — in a `struct { … }` or a tuple struct `struct X(pub T)` — is
reported as file:line; `pub(crate)` / `pub(super)` / `pub(in …)` stay
inside the crate and pass.

Usage: python3 .ci/private_fields.py [SRC_DIR]   (default: src)
"""

import re
import sys
from pathlib import Path

HOSTS = {"firmware", "virtual", "bin"}

STRUCT = re.compile(r"\bstruct\s+[A-Za-z_][A-Za-z0-9_]*")
PUB_FIELD = re.compile(r"^pub(?!\s*\()\b")


def strip_comments(text: str) -> str:
    """`text` with comments and string / char literals blanked (newlines
    and lengths kept, so offsets still give line numbers)."""
    out = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i))
            i = j
        elif text.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if text.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif text.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c == "'" and re.match(r"'(\\.|[^\\'])'", text[i : i + 4]):
            lit = re.match(r"'(\\.|[^\\'])'", text[i : i + 4]).group(0)
            out.append("'" + " " * (len(lit) - 2) + "'")
            i += len(lit)
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            out.append('"' + re.sub(r"[^\n]", " ", text[i + 1 : j]) + '"')
            i = j + 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def balanced(code: str, start: int, open_: str, close: str) -> int:
    """Index just past the bracket that closes the one at `start`."""
    depth = 0
    for i in range(start, len(code)):
        if code[i] == open_:
            depth += 1
        elif code[i] == close:
            depth -= 1
            if depth == 0:
                return i + 1
    return len(code)


def top_level_items(body: str, offset: int):
    """(offset, text) of each comma-separated item of a field list."""
    depth, begin = 0, 0
    for i, c in enumerate(body + ","):
        if c in "([{<":
            depth += 1
        elif c in ")]}" or (c == ">" and body[i - 1 : i] != "-"):
            depth -= 1
        elif c == "," and depth == 0:
            item = body[begin:i]
            stripped = item.lstrip()
            yield offset + begin + len(item) - len(stripped), stripped
            begin = i + 1


def public_fields(code: str):
    """Offsets of the `pub` fields of every struct in `code`."""
    for m in STRUCT.finditer(code):
        i = m.end()
        # generics
        while i < len(code) and code[i].isspace():
            i += 1
        if i < len(code) and code[i] == "<":
            i = balanced(code, i, "<", ">")
        rest = re.match(r"[^;{(]*", code[i:])
        i += rest.end() if rest else 0
        if i >= len(code) or code[i] == ";":
            continue  # unit struct
        open_, close = (code[i], "}" if code[i] == "{" else ")")
        end = balanced(code, i, open_, close)
        for at, item in top_level_items(code[i + 1 : end - 1], i + 1):
            # attributes before the field
            while item.startswith("#["):
                j = balanced(item, 1, "[", "]")
                skipped = len(item) - len(item[j:].lstrip())
                at, item = at + skipped, item[j:].lstrip()
            if PUB_FIELD.match(item):
                yield at


def main() -> int:
    src = Path(sys.argv[1] if len(sys.argv) > 1 else "src")
    bad = 0
    for f in sorted(src.rglob("*.rs")):
        rel = f.relative_to(src)
        if rel.parts[0] in HOSTS or rel.parts == ("main.rs",):
            continue
        code = strip_comments(f.read_text(encoding="utf-8"))
        for at in public_fields(code):
            line = code.count("\n", 0, at) + 1
            text = code.splitlines()[line - 1].strip()
            print(f"{f}:{line}: public field of a core type: {text}")
            bad += 1
    if bad:
        print(
            f"{bad} public field(s) in the core: keep fields private and "
            "give getters / constructors (docs/architecture.md)"
        )
        return 1
    print("core fields: all private")
    return 0


if __name__ == "__main__":
    sys.exit(main())
