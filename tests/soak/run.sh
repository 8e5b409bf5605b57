#!/usr/bin/env bash
# Soak on the virtual drive (docs/testing.md): the release binary,
# two drives on one bus (its pty), bus noise while both move, then the
# fault checks. --lines K runs K such buses at once, sharing the frames.
#   tests/soak/run.sh --frames 100000 --out docs/generated/soak.md   # the CI's size
#   tests/soak/run.sh --frames 1000000 --out docs/generated/soak-1m.md      # the long run, one line
# Uses the e2e virtualenv (.venv/e2e, pymodbus pinned in tests/e2e).
set -euo pipefail
cd "$(dirname "$0")/../.."
venv=.venv/e2e
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
"$venv/bin/pip" install --quiet --disable-pip-version-check -r tests/e2e/requirements.txt
cargo build -q --release --bin modbus-drive
exec "$venv/bin/python" tests/soak/soak.py "$@"
