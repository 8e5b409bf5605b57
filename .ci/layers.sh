#!/usr/bin/env bash
# Layers stage: the core's modules import each other without a cycle
# (docs/architecture.md states the rule; .ci/layers.py prints the graph),
# and neither do fw-sim's files (each file a module: docs/fw-sim.md).
set -euo pipefail
cd "$(dirname "$0")/.."
python3 .ci/layers.py src
python3 .ci/layers.py --files fw-sim/src
