#!/usr/bin/env bash
# Benchmark stage of .ci/run (issue 7, README "Proof"): instruction counts
# of the drive core against rmodbus, the crc crate, ramp-maker and a
# Klipper-style step event. Fails when a figure misses its target.
set -euo pipefail
cd "$(dirname "$0")/.."

if ! command -v qemu-system-arm >/dev/null; then
  apt-get update -qq && apt-get install -y -qq qemu-system-arm >/dev/null
fi

# the bench workspace is outside the main crate: lint it here
(cd benches && cargo fmt --all -- --check)
(cd benches && RUSTFLAGS="" cargo clippy -q -p workloads -p qemu-bench --target thumbv7em-none-eabihf -- -D warnings)

echo "-- Cortex-M4 (QEMU mps2-an386, -icount shift=0)"
benches/run-qemu.sh
