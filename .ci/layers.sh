#!/usr/bin/env bash
# Layers stage: the core's modules import each other without a cycle, and
# neither do the virtual drive's files nor fw-sim's (each file a module)
# (docs/architecture.md states the rule; .ci/layers.py prints the graph);
# and no type of the core has a field visible outside the crate
# (.ci/private_fields.py prints each as file:line).
set -euo pipefail
cd "$(dirname "$0")/.."
python3 .ci/layers.py src
python3 .ci/layers.py --files fw-sim/src
python3 .ci/private_fields.py src
