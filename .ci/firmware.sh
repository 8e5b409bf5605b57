#!/usr/bin/env bash
# Firmware stage (issue 6), run by .ci/run: both boards built in profile fw
# (release, opt-level z),
# clippy -D warnings on both, each ELF checked against its chip's memories
# (.ci/memory_map.py), flash / static-RAM budgets checked and printed.
# No board is attached in CI: nothing is flashed or run.
set -euo pipefail
cd "$(dirname "$0")/.."

# flip-link is the linker of the thumb targets (.cargo/config.toml)
command -v flip-link >/dev/null || cargo install flip-link --locked
# llvm-size from the toolchain's own llvm-tools: no cargo-binutils needed
rustup component add llvm-tools
host="$(rustc -vV | sed -n 's/^host: //p')"
llvm_size="$(rustc --print sysroot)/lib/rustlib/$host/bin/llvm-size"

# board chip target feature flash_budget_KiB ram_budget_KiB
check() {
  local board=$1 chip=$2 target=$3 feature=$4 flash_kib=$5 ram_kib=$6
  local elf="target/$target/fw/modbus-drive"
  echo "---- $board ($target, --features $feature)"
  cargo clippy --profile fw --bin modbus-drive --target "$target" --features "$feature" -- -D warnings || return 1
  # the emulator's fault-test build (never released) must not rot either
  cargo clippy --profile fw --bin modbus-drive --target "$target" --features "$feature,fault-test" -- -D warnings || return 1
  cargo build --profile fw --bin modbus-drive --target "$target" --features "$feature" || return 1
  # every section and symbol inside the chip's memories (datasheet figures)
  python3 .ci/memory_map.py "$chip" "$elf" || return 1
  # Flash = every section placed in flash (0x0800_0000..) + the .data image;
  # static RAM = every section placed in RAM (0x2000_0000..): .data, .bss,
  # .uninit (defmt-rtt buffer). The stack is not a section (flip-link puts
  # it below them) and is not counted.
  "$llvm_size" -A -d "$elf" | awk -v board="$board" -v fb="$flash_kib" -v rb="$ram_kib" '
    $3 >= 134217728 && $3 < 135266304 { flash += $2 }
    $3 >= 536870912 && $3 < 537919488 { ram += $2; if ($1 == ".data") flash += $2 }
    END {
      printf "%s: flash %d B (%.1f KiB of %d KiB), static RAM %d B (%.1f KiB of %d KiB)\n",
        board, flash, flash / 1024, fb, ram, ram / 1024, rb
      if (flash > fb * 1024) { print board ": FLASH BUDGET EXCEEDED"; bad = 1 }
      if (ram > rb * 1024) { print board ": RAM BUDGET EXCEEDED"; bad = 1 }
      exit bad
    }'
}

# both boards are checked and printed before the stage fails (set -e does
# not act inside a function called with ||: hence the explicit returns)
bad=0
check STM32G431CB stm32g431cb thumbv7em-none-eabihf board-g431 64 16 || bad=1
# F103 flash: 57 of the 60 KiB below its parameter pages; the fault path,
# watchdog and lock-free RS-485 hand-over took the last KiB of 56
check STM32F103C8 stm32f103c8 thumbv7m-none-eabi board-f103 57 12 || bad=1
exit $bad
