#!/usr/bin/env bash
# Proves .ci on a clean machine: debootstraps a minimal Debian bookworm
# into DIR (a chroot: no container engine needed) and puts the trap of a
# fresh clone there (libclang-cpp without libclang-dev).
#
# Default: copies the committed tree in, runs `.ci/deps.sh all` inside,
# then checks each package by name, and that libclang.so (what bindgen
# loads) is there. With --build it also installs rustup and builds fw-sim
# (unicorn-engine-sys runs cmake and bindgen: the step a fresh clone
# failed) inside; --build-host-rust builds fw-sim offline with this
# machine's Rust toolchain and crate cache mounted read-only.
#
# --run-ci runs the whole `bash .ci/run` as a fresh clone does. The chroot
# starts with what a new user has before the first command of the README:
# git, curl and ca-certificates (to get rustup and the clone) and the trap;
# every other package of .ci/packages.txt is purged (with what it pulled
# in), and so are an earlier run's toolchain, caches and clone, so the run
# proves .ci's own install steps. Then rustup comes from static.rust-lang.org
# as its installer fetches it, the tree is `git clone`d from a bundle of
# HEAD, and `.ci/run` runs with CI=true; Debian packages, pip and npm
# packages, crates, toolchains, targets, components and cargo tools all come
# from .ci's install steps inside. The log goes to stdout (tee it).
#
# Taken from the host, and why:
# - the kernel and its network (a chroot shares both): tests' ptys come
#   from the host's /dev/pts, their TCP ports are the host's 127.0.0.1;
#   /proc, /sys and a fresh /dev/shm (Chromium) are mounted in;
# - /etc/resolv.conf, to resolve names at all (/etc/hosts is not the
#   host's: the two localhost lines an installed Debian has);
# - the CA certificates of /usr/local/share/ca-certificates: where this
#   machine's egress inspects TLS, the chroot trusts no https server without
#   them (curl: "self-signed certificate in certificate chain"). They join
#   the chroot's own bundle (update-ca-certificates), and the run's
#   environment names that bundle for the clients that ship their own roots
#   (pip's certifi: PIP_CERT; Node: NODE_EXTRA_CA_CERTS), as this machine's
#   does;
# - when the stable toolchain static.rust-lang.org serves here has no
#   rust-std for the thumb targets (this machine's mirror lists them as
#   unavailable for its newest stable): a read-write copy of this machine's
#   stable toolchain (RUSTUP_HOME/toolchains/stable-*, with its thumb
#   targets and components); rustup itself, nightly, crates and cargo tools
#   still come from the network;
# - only when static.rust-lang.org cannot be reached from inside at all: a
#   read-write copy of this machine's RUSTUP_HOME and the rustup/cargo
#   proxies of CARGO_HOME/bin (not its cargo-installed tools nor its crate
#   cache), since .ci/run adds targets, components and nightly itself.
# Not a stage of .ci/run: it downloads a few GB and takes long. Needs root.
#   sudo bash .ci/clean-install.sh /var/tmp/ci-root [--build|--build-host-rust]
#   sudo bash .ci/clean-install.sh /var/tmp/ci-root --run-ci 2>&1 | tee LOG
#   sudo bash .ci/clean-install.sh /var/tmp/ci-root --run-ci-from e2e  # resume
set -euo pipefail
cd "$(dirname "$0")/.."
root=${1:?usage: .ci/clean-install.sh DIR [--build|--build-host-rust|--run-ci]}
mode=${2:-}
case $mode in "" | --build | --build-host-rust | --run-ci | --run-ci-from) ;; *)
  echo "unknown mode $mode" >&2
  exit 2
  ;;
esac
mirror=${DEBIAN_MIRROR:-http://deb.debian.org/debian}

say() { printf '\n---- %s %s\n' "$(date -u +%H:%M:%S)" "$*"; }

if [ ! -x "$root/usr/bin/apt-get" ]; then
  say "debootstrap --variant=minbase bookworm $root"
  debootstrap --variant=minbase bookworm "$root" "$mirror"
fi
mounted=()
cleanup() {
  for ((i = ${#mounted[@]} - 1; i >= 0; i--)); do umount -l "${mounted[i]}" || true; done
}
trap cleanup EXIT
for m in proc sys dev dev/pts dev/shm; do
  mountpoint -q "$root/$m" && continue
  case $m in
    proc) mount -t proc proc "$root/proc" ;;
    sys) mount -t sysfs sysfs "$root/sys" ;;
    dev/shm) mount -t tmpfs -o mode=1777 shm "$root/dev/shm" ;;
    *) mount --bind "/$m" "$root/$m" ;;
  esac
  mounted+=("$root/$m")
done
cp /etc/resolv.conf "$root/etc/resolv.conf"
# debootstrap writes no /etc/hosts (an installed Debian has one): without it
# `localhost` does not resolve, and Selenium reaches chromedriver by that name
[ -s "$root/etc/hosts" ] || printf '127.0.0.1\tlocalhost\n::1\tlocalhost ip6-localhost ip6-loopback\n' >"$root/etc/hosts"
mkdir -p "$root/usr/local/share/ca-certificates"
cp /usr/local/share/ca-certificates/*.crt "$root/usr/local/share/ca-certificates/" 2>/dev/null || true
bundle=/etc/ssl/certs/ca-certificates.crt
in_root() {
  chroot "$root" env -i HOME=/root USER=root LANG=C.UTF-8 TERM=dumb \
    PATH=/root/.cargo/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
    DEBIAN_FRONTEND=noninteractive SSL_CERT_FILE=$bundle CURL_CA_BUNDLE=$bundle \
    PIP_CERT=$bundle REQUESTS_CA_BUNDLE=$bundle NODE_EXTRA_CA_CERTS=$bundle \
    ${CI_ENV:-} bash -c "$1"
}

if [ "$mode" = --run-ci-from ]; then
  # after a stage failed: that stage and the later ones of .ci/run's list,
  # in the same chroot and clone, nothing purged
  from=${3:?usage: .ci/clean-install.sh DIR --run-ci-from STAGE}
  stages=$(sed -n 's/^for stage in \(.*\); do$/\1/p' "$root/src/.ci/run")
  [[ " $stages " == *" $from "* ]] || { echo "no stage $from in: $stages" >&2; exit 2; }
  say "stages of .ci/run from $from on, in $root/src ($(git -C "$root/src" rev-parse --short HEAD))"
  start=$(date +%s)
  rc=0
  CI_ENV="CI=true" in_root "cd /src && set -e && go=0 && for s in $stages; do
    [ \$s = $from ] && go=1; [ \$go = 1 ] && [ -f .ci/\$s.sh ] || continue
    printf '\n==== %s ====\n' \$s; bash .ci/\$s.sh; done" || rc=$?
  say "stages from $from: exit status $rc after $((($(date +%s) - start) / 60)) min"
  exit $rc
fi

say "the trap: libclang-cpp14 without libclang-dev"
if [ "$mode" = --run-ci ]; then
  # every package .ci installs goes, but what a new user has to have to
  # fetch rustup and clone (and what the trap is); autoremove by default
  # keeps what an installed package merely suggests (gcc was left so)
  mapfile -t ci_pkgs < <(sed -n 's/^[a-z0-9-]*:\(.*\)/\1/p' .ci/packages.txt | tr ' ' '\n' |
    grep -vxE 'curl|ca-certificates|' | sort -u)
  in_root "apt-get purge -y -qq ${ci_pkgs[*]} libclang-14-dev >/dev/null 2>&1 || true"
  in_root "apt-get update -qq && apt-get install -y -qq --no-install-recommends \
    git curl ca-certificates libclang-cpp14 >/dev/null"
  in_root "apt-mark manual git curl ca-certificates libclang-cpp14 >/dev/null &&
    apt-get autoremove --purge -y -qq -o APT::AutoRemove::SuggestsImportant=false \
    -o APT::AutoRemove::RecommendsImportant=false >/dev/null && apt-get clean"
  in_root "rm -rf /root/.cargo /root/.rustup /root/.cache /root/.npm /root/.config /src /tmp/* /tmp/.[!.]*"
else
  # a root reused from an earlier run has libclang-dev: take it away again
  in_root "apt-get purge -y -qq libclang-dev libclang-14-dev >/dev/null 2>&1 || true"
  in_root "apt-get update -qq && apt-get install -y -qq --no-install-recommends libclang-cpp14 >/dev/null"
fi
in_root "update-ca-certificates >/dev/null 2>&1 || true"
in_root "dpkg-query -W -f='\${Package} \${db:Status-Status}\n' libclang-cpp14 libclang-dev 2>&1 || true"
if in_root "ldconfig -p | grep -q libclang"; then
  echo "ldconfig -p | grep libclang matches (the old guess would skip libclang-dev)"
fi

if [ "$mode" = --run-ci ]; then
  say "what .ci/packages.txt asks for and this machine lacks (expected: all but curl ca-certificates)"
  cp .ci/packages.txt .ci/deps.sh "$root/tmp/"
  in_root "mkdir -p /tmp/d/.ci && mv /tmp/packages.txt /tmp/deps.sh /tmp/d/.ci/ &&
    bash /tmp/d/.ci/deps.sh --check all; rm -rf /tmp/d" || true
  in_root "for c in cc cmake python3 node chromium qemu-system-arm valgrind mbpoll socat rustup cargo; do
    command -v \$c >/dev/null && echo \"present: \$c\"; done; echo 'commands checked'"

  say "rustup, as its installer fetches it (static.rust-lang.org)"
  if in_root "curl -sSfo /tmp/rustup-init \
    https://static.rust-lang.org/rustup/dist/x86_64-unknown-linux-gnu/rustup-init &&
    chmod +x /tmp/rustup-init && /tmp/rustup-init -y --no-modify-path && rm /tmp/rustup-init"; then
    echo "rustup from static.rust-lang.org"
  else
    say "static.rust-lang.org unreachable from the chroot: a copy of this machine's rustup"
    home=${RUSTUP_HOME:-$HOME/.rustup}
    cargo_home=${CARGO_HOME:-$HOME/.cargo}
    cp -a "$home" "$root/root/.rustup"
    mkdir -p "$root/root/.cargo/bin"
    for b in "$cargo_home"/bin/*; do
      # rustup's proxies are links to (or copies of) rustup itself
      if [ "$(readlink -f "$b")" = "$(readlink -f "$cargo_home/bin/rustup")" ] ||
        cmp -s "$b" "$cargo_home/bin/rustup"; then
        cp -a "$b" "$root/root/.cargo/bin/"
      fi
    done
  fi
  # .ci/run needs stable's thumb targets; where the network's stable lacks
  # them (a mirror that carries only some targets' rust-std), the stable
  # toolchain, and that one only, is this machine's
  if ! in_root "rustup target add --toolchain stable thumbv7em-none-eabihf thumbv7m-none-eabi"; then
    say "stable from static.rust-lang.org lacks the thumb targets: this machine's stable toolchain"
    home=${RUSTUP_HOME:-$HOME/.rustup}
    t=stable-x86_64-unknown-linux-gnu
    rm -rf "$root/root/.rustup/toolchains/$t"
    cp -a "$(readlink -f "$home/toolchains/$t")" "$root/root/.rustup/toolchains/$t"
    cp "$home/update-hashes/$t" "$root/root/.rustup/update-hashes/$t"
  fi
  in_root "rustup --version && rustup toolchain list && rustc +stable --version &&
    rustup +stable target list --installed && rustup +stable component list --installed"

  say "git clone of the committed tree ($(git rev-parse HEAD))"
  git bundle create "$root/tmp/tree.bundle" HEAD 2>/dev/null
  in_root "git -c advice.detachedHead=false clone -q /tmp/tree.bundle /src && rm /tmp/tree.bundle &&
    git -C /src log --oneline -1"

  say "bash .ci/run (CI=true)"
  start=$(date +%s)
  rc=0
  CI_ENV="CI=true" in_root "cd /src && bash .ci/run" || rc=$?
  say ".ci/run exit status $rc after $((($(date +%s) - start) / 60)) min"
  exit $rc
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

if [ "$mode" = --build ]; then
  say "rustup and the fw-sim build (unicorn-engine-sys: cmake + bindgen)"
  # rustup-init itself (what sh.rustup.rs fetches)
  in_root "command -v rustup >/dev/null || { curl -sSfo /tmp/rustup-init \
    https://static.rust-lang.org/rustup/dist/x86_64-unknown-linux-gnu/rustup-init &&
    chmod +x /tmp/rustup-init && /tmp/rustup-init -y --profile minimal --default-toolchain none; }"
  in_root "cd /src && rustup show active-toolchain && cd fw-sim && cargo build --release 2>&1 | tail -n 40"
  in_root "cd /src/fw-sim && ls -l target/release/fw-sim"
fi
if [ "$mode" = --build-host-rust ]; then
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
