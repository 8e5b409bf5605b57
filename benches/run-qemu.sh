#!/usr/bin/env bash
# Cortex-M4 instruction counts (issue 7, README "Proof"): builds benches/qemu
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
exec cargo run -q --release -p qemu-bench --target "$T" "$@"
