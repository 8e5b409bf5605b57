#!/usr/bin/env bash
# Cortex-M4 instruction counts (docs/benchmarks.md): builds benches/qemu
# for thumbv7em-none-eabihf (opt-level "s", fat LTO) and runs it on QEMU
# mps2-an386 with -icount shift=0. Fails when a result is wrong or a target
# is missed. Needs qemu-system-arm (Debian package qemu-system-arm).
set -euo pipefail
cd "$(dirname "$0")"
T=thumbv7em-none-eabihf
# The firmware's .cargo/config.toml (linker, -T flags, probe-rs runner) must
# not leak into this build: environment settings take precedence over it.
export RUSTFLAGS=""
export CARGO_TARGET_THUMBV7EM_NONE_EABIHF_LINKER=rust-lld
export CARGO_TARGET_THUMBV7EM_NONE_EABIHF_RUNNER="qemu-system-arm -machine mps2-an386 -cpu cortex-m4 -nographic -monitor none -serial none -semihosting-config enable=on,target=native -icount shift=0 -kernel"
# The figures live in one place: the file this script writes (docs/generated/).
# Arguments (a subset of workloads) print only, so a partial run never
# replaces the full table.
if [ "$#" -gt 0 ]; then
  exec cargo run -q --release -p qemu-bench --target "$T" "$@"
fi
out=../docs/generated/bench-cortex-m4.md
tmp="$(mktemp)"
trap 'rm -f "$tmp"' EXIT
status=0
cargo run -q --release -p qemu-bench --target "$T" 2>&1 | tee "$tmp" || status=$?
{
  echo "# Cortex-M4 instruction counts (generated)"
  echo
  echo "Written by \`benches/run-qemu.sh\` at $(git rev-parse --short HEAD 2>/dev/null || echo '?')$(git diff --quiet HEAD -- ../src ../benches 2>/dev/null || echo ' + local changes'); do not edit. Method: [../benchmarks.md](../benchmarks.md)."
  echo
  echo '```text'
  cat "$tmp"
  echo '```'
} >"$out"
exit "$status"
