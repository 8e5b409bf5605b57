#!/usr/bin/env bash
# e2e stage (issue 4): the release binary of the virtual drive, started as a
# user starts it, driven by real Modbus masters (pymodbus over the pty and
# over TCP, mbpoll and socat over the pty, pymodbus, mbpoll and Node
# modbus-serial over Modbus TCP). Run by .ci/run.
set -euo pipefail
cd "$(dirname "$0")/.."

missing=()
command -v mbpoll >/dev/null || missing+=(mbpoll)
command -v socat >/dev/null || missing+=(socat)
# Node modbus-serial, the Node-RED / Node HMI client (tests/e2e/node)
command -v node >/dev/null || missing+=(nodejs)
command -v npm >/dev/null || missing+=(npm)
if [ ${#missing[@]} -gt 0 ]; then
  sudo=""
  [ "$(id -u)" -ne 0 ] && sudo="sudo"
  $sudo apt-get update
  $sudo apt-get install -y "${missing[@]}"
fi

venv=.venv/e2e
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
"$venv/bin/pip" install --quiet --disable-pip-version-check -r tests/e2e/requirements.txt

(cd tests/e2e/node && npm ci --omit=optional --no-audit --no-fund --loglevel=error)

cargo build --release --bin modbus-drive
# The binary is where cargo put it: CARGO_TARGET_DIR or .cargo/config.toml
# may move the target directory away from ./target.
if [ -z "${MODBUS_DRIVE_BIN:-}" ]; then
  target_dir=$(cargo metadata --format-version 1 --no-deps |
    python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')
  export MODBUS_DRIVE_BIN="$target_dir/release/modbus-drive"
fi
[ -x "$MODBUS_DRIVE_BIN" ] || { echo "e2e: no binary at $MODBUS_DRIVE_BIN" >&2; exit 1; }

set +e
"$venv/bin/python" -m pytest tests/e2e -p no:cacheprovider -v "$@"
rc=$?
set -e
if [ "$rc" -eq 5 ]; then
  # pytest's "no tests collected": the harness is broken, not green.
  echo "e2e: no tests ran" >&2
  exit 1
fi
exit "$rc"
