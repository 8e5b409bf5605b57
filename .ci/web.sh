#!/usr/bin/env bash
# web stage (issue 20): the commissioning page of the release binary
# (`--web`) in headless Chromium driven by Selenium, while a pymodbus
# master works the same drive over TCP. Run by .ci/run.
set -euo pipefail
cd "$(dirname "$0")/.."

if [ ! -x /usr/bin/chromium ] || [ ! -x /usr/bin/chromedriver ]; then
  sudo=""
  [ "$(id -u)" -ne 0 ] && sudo="sudo"
  $sudo apt-get update
  $sudo apt-get install -y chromium chromium-driver
fi

venv=.venv/web
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
"$venv/bin/pip" install --quiet --disable-pip-version-check -r tests/web/requirements.txt

cargo build --release --bin modbus-drive

set +e
CHROMIUM=/usr/bin/chromium CHROMEDRIVER=/usr/bin/chromedriver \
  "$venv/bin/python" -m pytest tests/web -p no:cacheprovider -v "$@"
rc=$?
set -e
if [ "$rc" -eq 5 ]; then
  # pytest's "no tests collected": the harness is broken, not green.
  echo "web: no tests ran" >&2
  exit 1
fi
exit "$rc"
