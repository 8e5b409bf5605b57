#!/usr/bin/env bash
# Soak stage of .ci/run (docs/testing.md): 10,000 frames of bus
# noise on two virtual drives plus the fault checks. The full run is
# `tests/soak/run.sh` (100,000 frames, ~15 min).
set -euo pipefail
cd "$(dirname "$0")/.."
bash .ci/deps.sh base
tests/soak/run.sh --frames "${SOAK_FRAMES:-10000}"
