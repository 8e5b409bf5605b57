#!/usr/bin/env bash
# Firmware stage (docs/firmware.md), run by .ci/run: the busy-wait check
# (.ci/busy_waits.py), both boards built in profile fw
# (release, opt-level z), clippy -D warnings on both, each ELF checked against
# its chip's memories (.ci/memory_map.py), then flash / static-RAM budgets
# checked and printed and the size breakdown generated (.ci/size_report.py).
# No board is attached in CI: nothing is flashed or run.
set -euo pipefail
cd "$(dirname "$0")/.."

# flip-link is the linker of the thumb targets (.cargo/config.toml)
command -v flip-link >/dev/null || cargo install flip-link --locked
# llvm-size / llvm-nm from the toolchain's own llvm-tools (.ci/size_report.py):
# no cargo-binutils needed
rustup component add llvm-tools

# board chip target feature
check() {
  local board=$1 chip=$2 target=$3 feature=$4
  local elf="target/$target/fw/modbus-drive"
  echo "---- $board ($target, --features $feature)"
  cargo clippy --profile fw --bin modbus-drive --target "$target" --no-default-features --features "$feature" -- -D warnings || return 1
  # the emulator's fault-test build (never released) must not rot either
  cargo clippy --profile fw --bin modbus-drive --target "$target" --no-default-features --features "$feature,fault-test" -- -D warnings || return 1
  cargo build --profile fw --bin modbus-drive --target "$target" --no-default-features --features "$feature" || return 1
  # every section and symbol inside the chip's memories (datasheet figures)
  python3 .ci/memory_map.py "$chip" "$elf" || return 1
}

# no busy wait over 10 µs (docs/firmware.md, "Busy waits"): every
# asm::delay call site with its bound
python3 .ci/busy_waits.py src

# both boards are checked and printed before the stage fails (set -e does
# not act inside a function called with ||: hence the explicit returns)
bad=0
check STM32G431CB stm32g431cb thumbv7em-none-eabihf board-g431 || bad=1
check STM32F103C8 stm32f103c8 thumbv7m-none-eabi board-f103 || bad=1
[ $bad = 0 ] || exit 1
# the release images log warn and error only (the development image, cargo
# fw-dev, logs info: docs/firmware.md)
python3 .ci/log_levels.py \
  target/thumbv7em-none-eabihf/fw/modbus-drive \
  target/thumbv7m-none-eabi/fw/modbus-drive
# flash / static RAM of both images against their budgets (the budgets and
# what is counted live in the script), with the breakdown per crate and
# per function written to the generated file
python3 .ci/size_report.py docs/generated/firmware-size.md \
  STM32G431CB=target/thumbv7em-none-eabihf/fw/modbus-drive \
  STM32F103C8=target/thumbv7m-none-eabi/fw/modbus-drive
