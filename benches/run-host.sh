#!/usr/bin/env bash
# Host instruction counts (docs/benchmarks.md): the workloads of
# benches/workloads under valgrind's callgrind through gungraun
# (`cargo bench -p host-bench`), then the per-frame / per-step figures and
# the drive-vs-competitor ratios. Needs valgrind and
#   cargo install gungraun-runner --version 0.20.0 --locked
set -euo pipefail
cd "$(dirname "$0")"
export RUSTFLAGS=""
export GUNGRAUN_SAVE_SUMMARY=json
cargo bench -q -p host-bench >/dev/null
# The figures live in one place: the file this script writes (docs/generated/).
out=../docs/generated/bench-host.md
tmp="$(mktemp)"
trap 'rm -f "$tmp"' EXIT
python3 - <<'PY' | tee "$tmp"
import json, glob, os
ir = {}
for f in glob.glob("target/gungraun/host-bench/instructions/*/*/summary.json"):
    d = json.load(open(f))
    name = f'{d["function_name"]}.{d["id"]}'
    ir[name] = d["profiles"][0]["data"]["parts"][0]["metrics"]["Ir"]["values"]["new"]
base = ir["empty_call.call"]
net = {k: v - base for k, v in ir.items()}
print(f"host x86-64, valgrind callgrind (gungraun): instructions per call, empty call ({base}) subtracted")
print(f'{"slave path per frame":<24}{"modbus-drive":>13}{"rmodbus 0.13":>14}{"ratio":>8}   (M4 target <= 40 %, enforced by run-qemu.sh)')
for key, label in (("fc03_read_2", "FC03 read 2 regs"), ("fc03_read_10", "FC03 read 10 regs"),
                   ("fc10_write_9", "FC10 write 9 regs"), ("fc06_write_1", "FC06 write 1 reg")):
    ours, theirs = net[f"slave_drive.{key}"], net[f"slave_rmodbus.{key}"]
    print(f"{label:<24}{ours:>13}{theirs:>14}{100 * ours / theirs:>7.1f} %")
for key, n, label in (("fc03_read_2", 8, "FC03 read 2 (8 B)"), ("fc10_write_9", 27, "FC10 write 9 (27 B)")):
    per_byte = (ir["assembler." + key] - ir["assembler_feed_only." + key]) / n
    print(f'{"frame assembler, " + label:<38}{per_byte:>7.1f} /byte  (M4 target <= 25)')
steps = 2000  # workloads::RAMP_MOVE_STEPS; run-qemu.sh checks each move yields exactly that many
print(f'{"ramp-maker 0.2 trapezoidal, fixed":<38}{net["ramp_maker_fixed.fixed"] / steps:>7.1f} /step')
print(f'{"ramp-maker 0.2 trapezoidal, f32":<38}{net["ramp_maker_f32.f32"] / steps:>7.1f} /step')
print(f'{"Klipper-style step event":<38}{net["klipper_step.step"]:>7.1f} /step')
# inside timed_advance / timed_fill only (callgrind toggle), whole simulated move
isr, planner = ir["drive_move_isr.isr"], ir["drive_move_planner.planner"]
print(f'{"modbus-drive step interrupt side":<38}{isr / steps:>7.1f} /step  (M4 target <= 20)')
print(f'{"modbus-drive planner, amortised":<38}{planner / steps:>7.1f} /step  (M4 target <= 60)')
fixed, f32 = net["ramp_maker_fixed.fixed"] / steps, net["ramp_maker_f32.f32"] / steps
print(f'{"  planner + interrupt vs ramp-maker":<38}{(isr + planner) / steps / fixed:>7.2f} x fixed, {(isr + planner) / steps / f32:.2f} x f32')
PY
{
  echo "# Host instruction counts (generated)"
  echo
  echo "Written by \`benches/run-host.sh\` at $(git rev-parse --short HEAD 2>/dev/null || echo '?')$(git diff --quiet HEAD -- ../src ../benches 2>/dev/null || echo ' + local changes'); do not edit. Method: [../benchmarks.md](../benchmarks.md)."
  echo
  echo '```text'
  cat "$tmp"
  echo '```'
} >"$out"
