#!/usr/bin/env bash
# Soak on the virtual drive (docs/testing.md): the release binary,
# two drives on one bus (its pty), bus noise while both move, then the
# fault checks.
#   tests/soak/run.sh                  # 1,000,000 frames (the long run)
#   tests/soak/run.sh --frames 100000  # the CI run (.ci/soak.sh)
#   tests/soak/run.sh --out docs/generated/soak.md   # and write the figures
# Uses the e2e virtualenv (.venv/e2e, pymodbus pinned in tests/e2e).
set -euo pipefail
cd "$(dirname "$0")/../.."
venv=.venv/e2e
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
"$venv/bin/pip" install --quiet --disable-pip-version-check -r tests/e2e/requirements.txt
cargo build -q --release --bin modbus-drive
exec "$venv/bin/python" tests/soak/soak.py "$@"
