#!/usr/bin/env bash
# e2e stage (docs/testing.md): the release binary of the virtual drive, started as a
# user starts it, driven by real Modbus masters (pymodbus over the pty and
# over TCP, mbpoll and socat over the pty, pymodbus, mbpoll and Node
# modbus-serial over Modbus TCP). Run by .ci/run.
set -euo pipefail
cd "$(dirname "$0")/.."

# mbpoll, socat, and Node for modbus-serial, the Node-RED / Node HMI
# client (tests/e2e/node): .ci/packages.txt
bash .ci/deps.sh base e2e

source .ci/lib.sh
venv=.venv/e2e
pytest_venv "$venv" tests/e2e/requirements.txt

(cd tests/e2e/node && npm ci --omit=optional --no-audit --no-fund --loglevel=error)

release_binary e2e
# the full scan's time at one baud (docs/commissioning.md)
"$venv/bin/python" tests/e2e/scan_time.py --out docs/generated/scan.md
run_pytest e2e "$venv" tests/e2e "$@"
