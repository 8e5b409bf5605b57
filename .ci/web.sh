#!/usr/bin/env bash
# web stage: the commissioning page of the release binary (`--web`) in
# headless Chromium driven by Selenium, while pymodbus masters work the same
# drive over its RTU-over-TCP line and its Modbus TCP port. Writes
# docs/web.png, a screenshot of the page taken during a move.
set -euo pipefail
cd "$(dirname "$0")/.."

bash .ci/deps.sh base web

source .ci/lib.sh
venv=.venv/web
pytest_venv "$venv" tests/web/requirements.txt
release_binary web
CHROMIUM=/usr/bin/chromium CHROMEDRIVER=/usr/bin/chromedriver \
  WEB_SCREENSHOT="${WEB_SCREENSHOT:-docs/web.png}" \
  run_pytest web "$venv" tests/web "$@"
