#!/usr/bin/env bash
# web stage: the commissioning page of the release binary (`--web`) in
# headless Chromium driven by Selenium, while pymodbus masters work the same
# drive over its RTU-over-TCP line and its Modbus TCP port. Writes
# docs/web.png, a screenshot of the page taken during a move. The page of
# `modbus-drive commission` (a Modbus master) against the virtual drive and
# both firmware images under fw-sim, each on a pseudo-terminal.
set -euo pipefail
cd "$(dirname "$0")/.."

# the page over a Modbus master (`commission`) is tested against both
# firmware images under fw-sim too: fw-sim's packages (cmake, libclang-dev),
# asked for by name like every stage's (.ci/packages.txt)
bash .ci/deps.sh base fw-sim web

source .ci/lib.sh
venv=.venv/web
pytest_venv "$venv" tests/web/requirements.txt
release_binary web
command -v flip-link >/dev/null || cargo install flip-link --locked
rustup target add thumbv7em-none-eabihf thumbv7m-none-eabi
fw_sim_images
CHROMIUM=/usr/bin/chromium CHROMEDRIVER=/usr/bin/chromedriver \
  WEB_SCREENSHOT="${WEB_SCREENSHOT:-docs/web.png}" \
  run_pytest web "$venv" tests/web "$@"
