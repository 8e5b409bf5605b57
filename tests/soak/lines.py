"""Several buses at once for one soak (docs/testing.md).

The soak's pace is set by the line's timing (replies, silences, gaps), not
by the host's CPU, so K independent buses run K times as many frames in
the same time. Each line is the whole set-up of a single-line soak: its own
`modbus-drive --drives 1,2` process, its own pty with both drives on it, its
own seed (--seed + i) and its share of the frames, run by soak.py as its own
process (`--line-json`). Every check of a line stays the line's; the report
lists each line and then the totals across lines, and holds only if every
line holds.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_SEED = 7
BAD = ("missing replies", "replies that should not exist", "wrong replies", "position errors")


def shares(frames: int, k: int) -> list[int]:
    """`frames` split into `k` shares that differ by one at most."""
    return [frames // k + (1 if i < frames % k else 0) for i in range(k)]


def command(args) -> str:
    """The command that writes `args.out`, as a reader types it."""
    out = Path(args.out).resolve()
    shown = out.relative_to(ROOT) if out.is_relative_to(ROOT) else out
    cmd = f"tests/soak/run.sh --frames {args.frames}"
    if args.lines != 1:
        cmd += f" --lines {args.lines}"
    if args.seed != DEFAULT_SEED:
        cmd += f" --seed {args.seed}"
    if args.no_faults:
        cmd += " --no-faults"
    return cmd + f" --out {shown}"


def run(soak_py: Path, args) -> bool:
    """Runs `args.lines` lines of `soak_py` at once; prints (and with
    `args.out` writes) every line's report and the totals."""
    keep = os.environ.get("SOAK_KEEP")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        procs = []
        t0 = time.monotonic()
        for i, n in enumerate(shares(args.frames, args.lines)):
            env = dict(os.environ)
            if keep:
                env["SOAK_KEEP"] = str(Path(keep) / f"line-{i}")
            result = work / f"line-{i}.json"
            cmd = [sys.executable, str(soak_py), "--frames", str(n), "--seed", str(args.seed + i),
                   "--line-name", f"line {i}", "--line-json", str(result)]
            procs.append((i, result, subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL)))
        results = []
        for i, result, proc in procs:
            status = proc.wait()
            res = json.loads(result.read_text()) if result.exists() else None
            if res is None:
                res = {"name": f"line {i}", "ok": False,
                       "report": [f"line {i}: no result (exit status {status}), see its errors above"]}
            res["ok"] &= status == 0
            results.append(res)
        wall = time.monotonic() - t0
    report = []
    for res in results:
        report += res["report"] + [""]
    if len(results) > 1:
        report += totals(results, wall)
    else:
        report.pop()
    ok = all(res["ok"] for res in results)
    print("\n".join(report))
    if args.out:
        Path(args.out).write_text(
            f"# Soak figures (generated)\n\nWritten by `{command(args)}` (seed {args.seed}"
            + (f", lines seeded {args.seed}..{args.seed + args.lines - 1}" if args.lines > 1 else "")
            + f"); {'every check held' if ok else 'FAILED'}.\n\n```\n" + "\n".join(report) + "\n```\n")
    return ok


def totals(results: list[dict], wall: float) -> list[str]:
    """The lines' counts added up, with the worst RSS growth of a drive
    process; a line without a result is counted as not held."""
    done = [r for r in results if "counts" in r]
    held = sum(1 for r in results if r["ok"])
    frames = sum(r["counts"]["frames"] for r in done)
    out = [f"totals: {len(results)} lines (each its own bus and drive process), {held} held; "
           f"{frames} frames in {wall:.0f} s wall ({wall / max(frames, 1) * 1000:.2f} ms a frame in all)"]
    kinds: dict[str, int] = {}
    for r in done:
        for k, v in r["kinds"].items():
            kinds[k] = kinds.get(k, 0) + v
    out.append("  by kind: " + ", ".join(f"{k} {v}" for k, v in sorted(kinds.items())))
    names = list(done[0]["counts"]) if done else []
    for k in names:
        v = sum(r["counts"][k] for r in done)
        out.append(f"  {k:<32}{v:>8}" + ("   (must be 0)" if k in BAD else ""))
    for k in ("counter mismatches", "broken frames", "late reads"):
        v = sum(r[k] for r in done)
        out.append(f"  {k:<32}{v:>8}   (must be 0)")
    sends, seen = sum(r["sends"] for r in done), sum(r["sends seen read"] for r in done)
    how = " or ".join(sorted({r["seen by"] for r in done}))
    out.append(f"  {'sends seen read ' + how:<32}{seen:>8}   of {sends}")
    if done:
        worst = max(done, key=lambda r: r["rss growth"])
        out.append(f"  {'worst drive RSS growth (KiB)':<32}{worst['rss growth']:>+8}   "
                   f"({worst['name']}; must be <= {worst['rss limit']})")
    if len(done) < len(results):
        out.append(f"  lines without a result          {len(results) - len(done):>8}   (must be 0)")
    return out
