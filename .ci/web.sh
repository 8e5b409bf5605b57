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

source .ci/lib.sh
venv=.venv/web
pytest_venv "$venv" tests/web/requirements.txt
release_binary web
CHROMIUM=/usr/bin/chromium CHROMEDRIVER=/usr/bin/chromedriver \
  WEB_SCREENSHOT="${WEB_SCREENSHOT:-docs/web.png}" \
  run_pytest web "$venv" tests/web "$@"
