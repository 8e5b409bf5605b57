#!/usr/bin/env bash
# Soak stage of .ci/run (docs/testing.md): 100,000 frames of bus noise
# over the pty on two virtual drives, plus the fault checks. The long run
# (`tests/soak/run.sh --frames 1000000 --lines 8`) is not a stage.
set -euo pipefail
cd "$(dirname "$0")/.."
bash .ci/deps.sh base
tests/soak/run.sh --frames "${SOAK_FRAMES:-100000}"
