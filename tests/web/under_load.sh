#!/usr/bin/env bash
# The browser suite under load (docs/testing.md): `.ci/web.sh` RUNS times in
# a row while BUSY shell loops keep the cores busy, as on a loaded CI
# machine. Prints one line a run and the total; with --out, also writes
# them there (the generated file docs/generated/web-under-load.md).
#   tests/web/under_load.sh                      # 20 runs, 2 busy loops
#   tests/web/under_load.sh --runs 5 --busy 2
#   tests/web/under_load.sh --out docs/generated/web-under-load.md
# The log of every failed run is kept in LOGS (--logs, default
# /tmp/web-under-load). Exit status 0 only if every run passed.
set -euo pipefail
cd "$(dirname "$0")/../.."
runs=20 busy=2 out="" keep=/tmp/web-under-load
while [ $# -gt 0 ]; do
  case $1 in
    --runs) runs=$2; shift 2 ;;
    --busy) busy=$2; shift 2 ;;
    --out) out=$2; shift 2 ;;
    --logs) keep=$2; shift 2 ;;
    *) echo "usage: $0 [--runs N] [--busy N] [--out FILE] [--logs DIR]" >&2; exit 2 ;;
  esac
done

logs=$(mktemp -d)
loops=()
stop_loops() {
  for p in "${loops[@]}"; do kill "$p" 2>/dev/null || true; done
}
trap 'stop_loops; rm -rf "$logs"' EXIT

# the first run builds what the suite needs; the load starts after it so
# that every counted run tests the page, not the compiler
bash .ci/web.sh -q --co >/dev/null

for ((i = 0; i < busy; i++)); do
  bash -c 'while :; do :; done' &
  loops+=($!)
done

report=$(mktemp)
failed_runs=0
{
  echo "commit $(git rev-parse --short HEAD)$(git diff --quiet HEAD || echo ' + local changes'),"\
    "$(nproc) cores, $busy busy loops, $runs runs of .ci/web.sh"
  printf '%-5s %-8s %-6s %-7s %-7s %s\n' run seconds load passed failed "failed tests"
} | tee "$report"
for ((r = 1; r <= runs; r++)); do
  log="$logs/run$r.log"
  start=$(date +%s)
  rc=0
  WEB_SCREENSHOT="$logs/web.png" bash .ci/web.sh >"$log" 2>&1 || rc=$?
  secs=$(($(date +%s) - start))
  passed=$(grep -c ' PASSED' "$log" || true)
  failed=$(grep -c ' FAILED' "$log" || true)
  names=$(grep -o '^FAILED [^ ]*' "$log" | sed 's/^FAILED //' | tr '\n' ' ' || true)
  if [ "$rc" -ne 0 ]; then
    failed_runs=$((failed_runs + 1))
    mkdir -p "$keep"
    cp "$log" "$keep/run$r.log"
    [ -n "$names" ] || names="(stage exited $rc: $(tail -n 1 "$log"))"
  fi
  # the 1-minute load average as the run ends: the busy loops, the suite
  # itself and whatever else this machine was running
  load=$(cut -d' ' -f1 /proc/loadavg)
  printf '%-5s %-8s %-6s %-7s %-7s %s\n' "$r" "$secs" "$load" "$passed" "$failed" "$names" | tee -a "$report"
done
echo "runs failed: $failed_runs of $runs" | tee -a "$report"
[ "$failed_runs" -eq 0 ] || echo "logs of the failed runs: $keep" >&2

if [ -n "$out" ]; then
  {
    echo "# The browser suite under load (generated)"
    echo
    echo "Written by \`tests/web/under_load.sh --runs $runs --busy $busy --out $out\`;"
    echo "do not edit. What it is: [../testing.md](../testing.md)."
    echo
    echo '```text'
    cat "$report"
    echo '```'
  } >"$out"
fi
rm -f "$report"
[ "$failed_runs" -eq 0 ]
