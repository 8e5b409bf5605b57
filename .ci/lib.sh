# Shared by the pytest stages (e2e, fw-sim, web): sourced, not run.

# A venv at $1 with the requirements file $2 installed.
pytest_venv() {
  [ -x "$1/bin/python" ] || python3 -m venv "$1"
  "$1/bin/pip" install --quiet --disable-pip-version-check -r "$2"
}

# Builds the virtual drive and exports MODBUS_DRIVE_BIN where cargo put it:
# CARGO_TARGET_DIR or .cargo/config.toml may move the target directory away
# from ./target. $1 names the stage in the error.
release_binary() {
  cargo build --release --bin modbus-drive
  if [ -z "${MODBUS_DRIVE_BIN:-}" ]; then
    local target_dir
    target_dir=$(cargo metadata --format-version 1 --no-deps |
      python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')
    export MODBUS_DRIVE_BIN="$target_dir/release/modbus-drive"
  fi
  [ -x "$MODBUS_DRIVE_BIN" ] || { echo "$1: no binary at $MODBUS_DRIVE_BIN" >&2; exit 1; }
}

# pytest from venv $2 named for stage $1, with the rest as its arguments;
# exits with pytest's status, and fails when no test ran ("no tests
# collected" means the harness is broken, not green).
run_pytest() {
  local stage=$1 venv=$2 rc
  shift 2
  set +e
  "$venv/bin/python" -m pytest -p no:cacheprovider -v "$@"
  rc=$?
  set -e
  if [ "$rc" -eq 5 ]; then
    echo "$stage: no tests ran" >&2
    exit 1
  fi
  exit "$rc"
}

# The target directory of the workspace (or of --manifest-path "$1").
target_of() {
  cargo metadata --format-version 1 --no-deps "$@" |
    python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])'
}

# Builds both boards' release images and fw-sim, and exports FW_SIM_BIN,
# FW_SIM_ELF_G431 and FW_SIM_ELF_F103 where cargo put them.
fw_sim_images() {
  cargo fw
  cargo fw-f103
  ( cd fw-sim && cargo build --release )
  local fw_target
  fw_target=$(target_of)
  export FW_SIM_ELF_G431="$fw_target/thumbv7em-none-eabihf/fw/modbus-drive"
  export FW_SIM_ELF_F103="$fw_target/thumbv7m-none-eabi/fw/modbus-drive"
  export FW_SIM_BIN="$(target_of --manifest-path fw-sim/Cargo.toml)/release/fw-sim"
}
