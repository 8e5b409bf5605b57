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
# firmware images under fw-sim too, so fw-sim's packages (cmake, libclang-dev)
# are this stage's as well: asked for by name (.ci/packages.txt)
bash .ci/deps.sh base web fw-sim

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
