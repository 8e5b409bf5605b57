#!/usr/bin/env bash
# fw-sim stage: both boards' unmodified release images (cargo fw, cargo
# fw-f103) run on the emulated STM32 of fw-sim/ (docs/fw-sim.md) and are
# driven over the emulated USART by the pytest tests in tests/fw_sim (seed
# 000 frames byte for byte, exceptions, addressing, a position move counted
# in step pulses, one at the acceleration limit, DE around every reply and
# its lead / tail PA57 / PA58, a limit through GPIO/EXTI, a parameter save
# through the flash controller, mbpoll over the pty). Run by .ci/run.
set -euo pipefail
cd "$(dirname "$0")/.."

# unicorn-engine builds its C core with cmake; bindgen needs libclang
# (.ci/packages.txt, asked for by package name)
bash .ci/deps.sh base fw-sim
command -v flip-link >/dev/null || cargo install flip-link --locked
rustup target add thumbv7em-none-eabihf thumbv7m-none-eabi

source .ci/lib.sh
venv=.venv/e2e
pytest_venv "$venv" tests/e2e/requirements.txt

target_of() {
  cargo metadata --format-version 1 --no-deps "$@" |
    python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])'
}

cargo fw
cargo fw-f103
# the core's step schedule for the same moves, to compare the pulses with
cargo build --example step_schedule
( cd fw-sim && cargo fmt -- --check && cargo clippy --release -- -D warnings && cargo build --release )
fw_target=$(target_of)
export FW_SIM_ELF_G431="$fw_target/thumbv7em-none-eabihf/fw/modbus-drive"
export FW_SIM_ELF_F103="$fw_target/thumbv7m-none-eabi/fw/modbus-drive"
export FW_SIM_SCHEDULE_BIN="$fw_target/debug/examples/step_schedule"
export FW_SIM_BIN="$(target_of --manifest-path fw-sim/Cargo.toml)/release/fw-sim"

run_pytest fw-sim "$venv" tests/fw_sim "$@"
