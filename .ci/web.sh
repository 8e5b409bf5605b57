#!/usr/bin/env bash
# web stage: the commissioning page of the release binary (`--web`) in
# headless Chromium driven by Selenium, while pymodbus masters work the same
# drive over its RTU-over-TCP line and its Modbus TCP port. Writes
# docs/web.png, a screenshot of the page taken during a move.
set -euo pipefail
cd "$(dirname "$0")/.."

if [ ! -x /usr/bin/chromium ] || [ ! -x /usr/bin/chromedriver ]; then
  sudo=""
  [ "$(id -u)" -ne 0 ] && sudo="sudo"
  $sudo apt-get update
  $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
    chromium chromium-driver python3-venv
fi

venv=.venv/web
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
"$venv/bin/pip" install --quiet --disable-pip-version-check -r tests/web/requirements.txt

cargo build --release --bin modbus-drive
# The binary is where cargo put it: CARGO_TARGET_DIR or .cargo/config.toml
# may move the target directory away from ./target.
if [ -z "${MODBUS_DRIVE_BIN:-}" ]; then
  target_dir=$(cargo metadata --format-version 1 --no-deps |
    python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')
  export MODBUS_DRIVE_BIN="$target_dir/release/modbus-drive"
fi
[ -x "$MODBUS_DRIVE_BIN" ] || { echo "web: no binary at $MODBUS_DRIVE_BIN" >&2; exit 1; }

set +e
CHROMIUM=/usr/bin/chromium CHROMEDRIVER=/usr/bin/chromedriver \
  WEB_SCREENSHOT="${WEB_SCREENSHOT:-docs/web.png}" \
  "$venv/bin/python" -m pytest tests/web -p no:cacheprovider -v "$@"
rc=$?
set -e
if [ "$rc" -eq 5 ]; then
  # pytest's "no tests collected": the harness is broken, not green.
  echo "web: no tests ran" >&2
  exit 1
fi
exit "$rc"
