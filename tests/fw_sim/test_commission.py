"""The master tools against both firmware images under fw-sim, over its
pseudo-terminal: the real serial path of a field engineer's adapter
(bodies in tests/e2e/commission.py, shared with the virtual drive's and
the browser's tests)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from conftest import Firmware, Master, e2e_module, free_port

commission = e2e_module("commission")
ROOT = Path(__file__).resolve().parents[2]
BIN = Path(os.environ.get("MODBUS_DRIVE_BIN") or ROOT / "target" / "release" / "modbus-drive")


class Runner:
    """fw-sim running `board`'s image with a pty and a flash file."""

    def __init__(self, tmp: Path, board: str, flags: tuple[str, ...] = ()):
        self.tmp, self.board, self.flags = tmp, board, list(flags)
        self.link = tmp / f"tty-{board}"
        self.fw: Firmware | None = None
        self.start()

    def start(self):
        self.fw = Firmware(self.tmp, self.board, ["--pty-link", str(self.link),
                                                  "--state", str(self.tmp / "flash.bin"),
                                                  *self.flags])

    def stop(self):
        rc = self.fw.stop()
        assert rc is None, f"fw-sim {self.board} exited with {rc}:\n{self.fw.stderr()}"

    def master(self, address: int = 1) -> Master:
        self.fw.alive()
        return Master(self.fw.client(), address)


@pytest.fixture
def runner(tmp_path, board):
    r = Runner(tmp_path, board)
    try:
        yield r
    finally:
        r.stop()


def test_scan_finds_the_firmware_at_address_17_19200_8e1(runner):
    commission.scan_finds_the_drive_at_its_address_and_line(runner, BIN)


def test_params_save_change_restore_survives_a_restart(runner, tmp_path):
    commission.params_round_trip_survives_a_restart(runner, BIN, tmp_path, "toml")


def test_a_restore_follows_the_firmware_to_its_new_address_and_line(runner, tmp_path):
    commission.a_restore_follows_the_drive_to_its_new_address_and_line(runner, BIN, tmp_path)


def test_an_out_of_range_restore_writes_nothing_and_names_the_pa(runner, tmp_path):
    commission.an_out_of_range_restore_writes_nothing(runner, BIN, tmp_path)


def test_the_page_says_the_firmware_is_gone_and_finds_it_again(runner, tmp_path):
    commission.the_page_follows_the_line_away_and_back(runner, BIN, tmp_path)


def test_the_page_enables_and_moves_the_firmware(runner, tmp_path):
    commission.the_page_moves_the_drive(runner, BIN, tmp_path)


def test_the_page_jogs_the_firmware_both_ways(runner, tmp_path):
    commission.the_page_jogs_the_drive(runner, BIN, tmp_path)


def test_the_page_homes_the_firmware_to_its_home_switch(tmp_path, board):
    r = Runner(tmp_path, board, ("--home-switch", commission.HOME_WINDOW))
    try:
        commission.the_page_homes_the_drive(r, BIN, tmp_path)
    finally:
        r.stop()


def test_the_pages_fault_reset_clears_the_firmwares_comm_loss_fault(runner, tmp_path):
    commission.the_page_resets_a_comm_loss_fault(runner, BIN, tmp_path)


def test_the_page_through_the_runners_modbus_tcp_gateway(start_fw, board, tmp_path):
    """`--modbus-tcp-master` to fw-sim's gateway: the page reads the
    firmware and writes a PA; a unit that is not on the line gets the
    gateway's exception 0x0B, which the page shows as the drive gone."""
    port = free_port()
    fw = start_fw(board, "--modbus-tcp", f"127.0.0.1:{port}")
    page = commission.Commission(BIN, tmp_path, "--modbus-tcp-master", f"127.0.0.1:{port}")
    try:
        s = page.wait(lambda s: s["link"]["ok"] and s["pa"][2]["value"] is not None,
                      "the page reads the firmware through the gateway")
        assert s["state"] == "SwitchOnDisabled"
        r = page.cmd(c="write", index=0x0064 + 12, value=1234)
        assert r["ok"], r
        page.wait(lambda s: s["pa"][12]["value"] == 1234, "PA12 read back")
    finally:
        page.stop()
    fw.alive()
    # the gateway waits 1 s of emulated time, which a loaded machine
    # stretches: the master waits longer still
    page = commission.Commission(BIN, tmp_path, "--modbus-tcp-master", f"127.0.0.1:{port}",
                                 "--address", "9", "--timeout", "8000")
    try:
        s = page.wait(lambda s: "exception 11" in (s["link"]["error"] or ""),
                      "unit 9 is absent: the gateway's 0x0B", timeout=40)
        assert not s["link"]["ok"] and s["state"] == "NotAnswering", s["link"]
    finally:
        page.stop()
