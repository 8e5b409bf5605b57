#!/usr/bin/env bash
# The system packages of CI stages, asked for by package name (dpkg), never
# guessed from a command or a library being around: `ldconfig -p | grep
# libclang` also matches libclang-cpp, which many machines have without the
# libclang.so bindgen loads. The lists live in .ci/packages.txt.
#   bash .ci/deps.sh fw-sim e2e     # install what these stages lack
#   bash .ci/deps.sh --check all    # list what is missing, install nothing
set -euo pipefail
cd "$(dirname "$0")/.."

check_only=0
if [ "${1:-}" = "--check" ]; then
  check_only=1
  shift
fi
[ $# -gt 0 ] || { echo "usage: .ci/deps.sh [--check] STAGE…|all" >&2; exit 2; }

stages=("$@")
if [ "${stages[0]}" = all ]; then
  mapfile -t stages < <(sed -n 's/^\([a-z0-9-]*\):.*/\1/p' .ci/packages.txt)
fi

wanted=()
for s in "${stages[@]}"; do
  line=$(grep -E "^$s:" .ci/packages.txt || true)
  [ -n "$line" ] || continue # a stage without system packages
  read -ra pkgs <<<"${line#*:}"
  wanted+=("${pkgs[@]}")
done
[ ${#wanted[@]} -gt 0 ] || exit 0

if ! command -v dpkg-query >/dev/null; then
  echo "deps: not a Debian system; install the equivalents of: ${wanted[*]}" >&2
  [ $check_only = 0 ] || exit 1
  exit 0
fi

# Installed packages and the virtual ones they provide (nodesource's nodejs
# provides npm, and conflicts with Debian's).
scan() {
  have=" $(dpkg-query -W -f='${db:Status-Status}\t${Package}, ${Provides}\n' |
    awk -F'\t' '$1 == "installed" { print $2 }' |
    tr ',' '\n' | sed -E 's/^ *//; s/ *\(.*//; s/:.*//' | sort -u | tr '\n' ' ')"
}
scan
installed() {
  [[ "$have" == *" $1 "* ]]
}

missing=()
for p in "${wanted[@]}"; do
  installed "$p" || [[ " ${missing[*]} " == *" $p "* ]] || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "deps (${stages[*]}): ${#wanted[@]} packages installed"
  exit 0
fi
echo "deps (${stages[*]}): missing ${missing[*]}"
[ $check_only = 0 ] || exit 1

sudo=""
[ "$(id -u)" -ne 0 ] && sudo="sudo"
$sudo apt-get update -qq
$sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}"
# what apt said it did is checked, not trusted
scan
for p in "${missing[@]}"; do
  installed "$p" || { echo "deps: $p is still not installed" >&2; exit 1; }
done
