#!/usr/bin/env bash
# fw-sim stage: both boards' unmodified release images (cargo fw, cargo
# fw-f103; the development images, cargo fw-dev, for the one test that reads
# an info log line) run on the emulated STM32 of fw-sim/ (docs/fw-sim.md) and are
# driven over the emulated USART by the pytest tests in tests/fw_sim (seed
# 000 frames byte for byte, exceptions, addressing, a position move counted
# in step pulses, one at the acceleration limit, DE around every reply and
# its lead / tail PA57 / PA58, a limit through GPIO/EXTI, a parameter save
# through the flash controller, mbpoll over the pty, the closed loop on
# TIM4's encoder mode fed by the emulated motor, DMA seeing the CPU's SRAM).
# The runner's own unit tests (timers, DMA, DMAMUX, master/slave, break,
# encoder, motor) run with its build. Run by .ci/run.
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

( cd fw-sim && cargo fmt -- --check && cargo clippy --release -- -D warnings && cargo test --release )
fw_sim_images
# the core's step schedule for the same moves, to compare the pulses with
cargo build --example step_schedule
export FW_SIM_SCHEDULE_BIN="$(target_of)/debug/examples/step_schedule"
# the master tools (commission, scan, params) drive the images over the pty
release_binary fw-sim
# the development images (defmt info): the step-latency log line
cargo fw-dev
cargo fw-dev-f103
fw_target=$(target_of)
export FW_SIM_ELF_DEV_G431="$fw_target/thumbv7em-none-eabihf/fw-dev/modbus-drive"
export FW_SIM_ELF_DEV_F103="$fw_target/thumbv7m-none-eabi/fw-dev/modbus-drive"

run_pytest fw-sim "$venv" tests/fw_sim "$@"
