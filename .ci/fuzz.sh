#!/usr/bin/env bash
# Fuzz stage of .ci/run (docs/testing.md): every cargo-fuzz target
# for FUZZ_SECONDS (default 60) each, seeded with fuzz/regressions/<target>/.
# An input that breaks an invariant is copied to fuzz/regressions/<target>/
# (commit it: `cargo test` replays it from then on) and the stage fails.
#   FUZZ_SECONDS=600 .ci/fuzz.sh            # the ≥ 10-minute local runs
#   FUZZ_SECONDS=60 .ci/fuzz.sh dispatcher  # one target
set -euo pipefail
cd "$(dirname "$0")/../fuzz"
seconds="${FUZZ_SECONDS:-60}"

rustup toolchain list | grep -q '^nightly' || rustup toolchain install nightly --profile minimal
# a debug build of the tool installs in a fraction of the time and runs as well
command -v cargo-fuzz >/dev/null || cargo install cargo-fuzz --locked --debug

targets=("$@")
[ ${#targets[@]} -gt 0 ] || mapfile -t targets < <(cargo +nightly fuzz list)
# debug assertions on: an arithmetic overflow on bus input is a finding too
cargo +nightly fuzz build -O --debug-assertions

status=0
for t in "${targets[@]}"; do
  echo "-- fuzz target $t, ${seconds} s"
  mkdir -p "corpus/$t" "artifacts/$t"
  if ! cargo +nightly fuzz run -O --debug-assertions "$t" "corpus/$t" "regressions/$t" -- \
      -max_total_time="$seconds" -print_final_stats=1 -print_pcs=0 2>"artifacts/$t.log"; then
    status=1
    for f in artifacts/"$t"/crash-* artifacts/"$t"/oom-* artifacts/"$t"/timeout-*; do
      [ -e "$f" ] && cp "$f" "regressions/$t/" && echo "kept $f as regressions/$t/$(basename "$f")"
    done
  fi
  grep -E "^(#[0-9]+ +DONE|stat::number_of_executed_units|stat::peak_rss_mb|==.*ERROR|SUMMARY)" "artifacts/$t.log" || true
  tail -n 40 "artifacts/$t.log" | grep -E "panicked|assertion|Done [0-9]+ runs" || true
  grep -oE "cov: [0-9]+ ft: [0-9]+ corp: [0-9]+/[0-9]+[a-zA-Z]*" "artifacts/$t.log" | tail -1 || true
done
exit $status
