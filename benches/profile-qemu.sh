#!/usr/bin/env bash
# Where a workload's instructions go, per function (docs/benchmarks.md):
#   benches/profile-qemu.sh drive-fc06      (see bench::profile for names)
# Runs one call of it on QEMU mps2-an386 with a trace of every executed
# translation block and sums the instructions of each block per function
# between the markers profile_start / profile_end.
set -euo pipefail
cd "$(dirname "$0")"
which="${1:?workload, e.g. drive-fc06}"
export RUSTFLAGS=""
export CARGO_TARGET_THUMBV7EM_NONE_EABIHF_LINKER=rust-lld
export BENCH_PROFILE="$which"
cargo build -q --release -p qemu-bench --features profile --target thumbv7em-none-eabihf
log="$(mktemp)"
trap 'rm -f "$log"' EXIT
qemu-system-arm -machine mps2-an386 -cpu cortex-m4 -nographic -monitor none -serial none \
  -semihosting-config enable=on,target=native -icount shift=0 \
  -kernel target/thumbv7em-none-eabihf/release/qemu-bench \
  -d in_asm,exec,nochain -D "$log"
python3 - "$log" <<'PY'
import re, sys, collections
def demangle(sym):
    # legacy Rust mangling: _ZN <len><segment>... 17h<hash> E
    if not sym.startswith("_ZN"):
        return sym
    i, parts = 3, []
    while i < len(sym) and sym[i].isdigit():
        j = i
        while sym[j].isdigit():
            j += 1
        n = int(sym[i:j])
        parts.append(sym[j:j + n])
        i = j + n
    if parts and re.fullmatch(r"h[0-9a-f]{16}", parts[-1]):
        parts.pop()
    out = "::".join(parts)
    for a, b in (("$LT$", "<"), ("$GT$", ">"), ("$u20$", " "), ("$C$", ","), ("$RF$", "&"), ("..", "::")):
        out = out.replace(a, b)
    return out

tb_len = {}          # host TB pointer -> guest instructions in it
pending = None       # instructions of the block just translated
per_fn = collections.Counter()
inside = False
for line in open(sys.argv[1], errors="replace"):
    if line.startswith("IN:"):
        pending = 0
    elif pending is not None and re.match(r"0x[0-9a-f]+:", line):
        pending += 1
    elif line.startswith("Trace "):
        m = re.match(r"Trace \d+: (0x[0-9a-f]+) \[[0-9a-f]+/([0-9a-f]+)/[^\]]*\] ?(.*)", line)
        if not m:
            continue
        host, pc, sym = m.group(1), m.group(2), m.group(3).strip()
        if pending is not None:
            tb_len[host] = pending
            pending = None
        if sym.startswith("profile_start"):
            inside = True
            continue
        if sym.startswith("profile_end"):
            break
        if inside:
            per_fn[sym or pc] += tb_len.get(host, 0)
total = sum(per_fn.values())
print(f"{total:>6}  instructions in all (the call of the workload included)")
for sym, n in per_fn.most_common():
    print(f"{n:>6}  {100*n/total:5.1f} %  {demangle(sym)[:110]}")
PY
