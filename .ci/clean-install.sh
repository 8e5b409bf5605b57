#!/usr/bin/env bash
# Proves .ci's install steps on a clean machine: debootstraps a minimal
# Debian bookworm into DIR (a chroot: no container engine needed), puts the
# trap of a fresh clone there (libclang-cpp without libclang-dev), copies
# the committed tree in and runs `.ci/deps.sh all` inside, then checks each
# package by name, and that libclang.so (what bindgen loads) is there.
# With --build it also installs rustup and builds fw-sim (unicorn-engine-sys
# runs cmake and bindgen: the step a fresh clone failed) inside. Where the
# chroot cannot reach static.rust-lang.org and crates.io, --build-host-rust
# builds fw-sim offline with this machine's Rust toolchain and crate cache
# mounted read-only: the C build and bindgen still see only the chroot's
# Debian packages.
# Not a stage of .ci/run: it downloads ~1 GB and takes long. Needs root.
#   sudo bash .ci/clean-install.sh /var/tmp/ci-root [--build|--build-host-rust]
set -euo pipefail
cd "$(dirname "$0")/.."
root=${1:?usage: .ci/clean-install.sh DIR [--build]}
build=0
[ "${2:-}" = --build ] && build=1
host_rust=0
[ "${2:-}" = --build-host-rust ] && host_rust=1
mirror=${DEBIAN_MIRROR:-http://deb.debian.org/debian}

say() { printf '\n---- %s\n' "$*"; }

if [ ! -x "$root/usr/bin/apt-get" ]; then
  say "debootstrap --variant=minbase bookworm $root"
  debootstrap --variant=minbase bookworm "$root" "$mirror"
fi
mounted=()
cleanup() {
  for ((i = ${#mounted[@]} - 1; i >= 0; i--)); do umount -l "${mounted[i]}" || true; done
}
trap cleanup EXIT
for m in proc dev dev/pts; do
  mountpoint -q "$root/$m" && continue
  case $m in
    proc) mount -t proc proc "$root/proc" ;;
    *) mount --bind "/$m" "$root/$m" ;;
  esac
  mounted+=("$root/$m")
done
cp /etc/resolv.conf "$root/etc/resolv.conf"
in_root() { chroot "$root" env -i HOME=/root PATH=/root/.cargo/bin:/usr/sbin:/usr/bin:/sbin:/bin \
  DEBIAN_FRONTEND=noninteractive bash -c "$1"; }

say "the trap: libclang-cpp14 without libclang-dev"
# a root reused from an earlier run has libclang-dev: take it away again
in_root "apt-get purge -y -qq libclang-dev libclang-14-dev >/dev/null 2>&1 || true"
in_root "apt-get update -qq && apt-get install -y -qq --no-install-recommends libclang-cpp14 >/dev/null"
in_root "dpkg-query -W -f='\${Package} \${db:Status-Status}\n' libclang-cpp14 libclang-dev 2>&1 || true"
if in_root "ldconfig -p | grep -q libclang"; then
  echo "ldconfig -p | grep libclang matches (the old guess would skip libclang-dev)"
fi

say "the committed tree ($(git rev-parse --short HEAD)) into $root/src"
rm -rf "$root/src"
mkdir -p "$root/src"
git archive HEAD | tar -x -C "$root/src"

say "every stage's install step: .ci/deps.sh all"
in_root "cd /src && bash .ci/deps.sh all"
say "checked by package name: .ci/deps.sh --check all"
in_root "cd /src && bash .ci/deps.sh --check all"
say "libclang.so for bindgen"
in_root "ls /usr/lib/llvm-*/lib/libclang.so"

if [ $build = 1 ]; then
  say "rustup and the fw-sim build (unicorn-engine-sys: cmake + bindgen)"
  # rustup-init itself (what sh.rustup.rs fetches)
  in_root "command -v rustup >/dev/null || { curl -sSfo /tmp/rustup-init \
    https://static.rust-lang.org/rustup/dist/x86_64-unknown-linux-gnu/rustup-init &&
    chmod +x /tmp/rustup-init && /tmp/rustup-init -y --profile minimal --default-toolchain none; }"
  in_root "cd /src && rustup show active-toolchain && cd fw-sim && cargo build --release 2>&1 | tail -n 40"
  in_root "cd /src/fw-sim && ls -l target/release/fw-sim"
fi
if [ $host_rust = 1 ]; then
  say "fw-sim built offline with the host's toolchain (unicorn-engine-sys: cmake + bindgen)"
  home=${RUSTUP_HOME:-$HOME/.rustup}
  cargo_home=${CARGO_HOME:-$HOME/.cargo}
  mkdir -p "$root/root/.rustup" "$root/root/.cargo/bin" "$root/root/.cargo/registry"
  for m in "$home:/root/.rustup" "$cargo_home/bin:/root/.cargo/bin" \
    "$cargo_home/registry:/root/.cargo/registry"; do
    mountpoint -q "$root${m#*:}" || {
      mount --bind "${m%%:*}" "$root${m#*:}" && mount -o remount,bind,ro "$root${m#*:}"
      mounted+=("$root${m#*:}")
    }
  done
  in_root "cd /src/fw-sim && rm -rf target && cargo build --offline --release 2>&1 | tail -n 40"
  in_root "cd /src/fw-sim && ls -l target/release/fw-sim"
fi
say "clean install: OK"
