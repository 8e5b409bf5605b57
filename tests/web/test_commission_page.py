"""The commissioning page of `modbus-drive commission` (the page over a
Modbus master) in headless Chromium, against a drive on a pseudo-terminal:
the virtual drive, and both firmware images under fw-sim (the real serial
path). The page enables the drive, moves it 10 000 steps and shows target
reached; Restore defaults runs only once confirmed; the runner stops mid-session and the page says the drive is gone,
then finds it again when the runner is back. Run by .ci/web.sh, which
builds fw-sim and the images (FW_SIM_BIN, FW_SIM_ELF_G431/F103)."""

from __future__ import annotations

import importlib.util
import os
import select
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import WebDriverWait

from browser import headless_chromium

ROOT = Path(__file__).resolve().parents[2]
# the process helpers shared with tests/e2e
_E2E = ROOT / "tests" / "e2e"
if str(_E2E) not in sys.path:
    sys.path.append(str(_E2E))
from processes import stop_process  # noqa: E402

BIN = Path(os.environ.get("MODBUS_DRIVE_BIN", ROOT / "target" / "release" / "modbus-drive"))
SIM = Path(os.environ.get("FW_SIM_BIN") or ROOT / "fw-sim" / "target" / "release" / "fw-sim")
ELF = {
    "g431": Path(os.environ.get("FW_SIM_ELF_G431")
                 or ROOT / "target" / "thumbv7em-none-eabihf" / "fw" / "modbus-drive"),
    "f103": Path(os.environ.get("FW_SIM_ELF_F103")
                 or ROOT / "target" / "thumbv7m-none-eabi" / "fw" / "modbus-drive"),
}
WAIT_S = 30
SW_TARGET_REACHED = 10

_spec = importlib.util.spec_from_file_location("commission", ROOT / "tests" / "e2e" / "commission.py")
commission = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(commission)


class Runner:
    """The drive (`virtual`, or fw-sim running `g431` / `f103`) on a pty."""

    def __init__(self, tmp: Path, kind: str):
        self.tmp, self.kind = tmp, kind
        self.link = tmp / f"tty-{kind}"
        self.proc = None
        self.start()

    def start(self):
        flash = self.tmp / "flash.bin"
        if self.kind == "virtual":
            cmd = [str(BIN), "--no-status", "--pty-link", str(self.link), "--state", str(flash)]
        else:
            assert SIM.exists() and ELF[self.kind].exists(), \
                "fw-sim and the firmware images are built by .ci/web.sh"
            cmd = [str(SIM), "--board", self.kind, "--elf", str(ELF[self.kind]),
                   "--pty-link", str(self.link), "--state", str(flash)]
        self.log = open(self.tmp / f"{self.kind}-{time.monotonic_ns()}.log", "wb")
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=self.log)
        deadline = time.monotonic() + 30
        got = b""
        while b"ready\n" not in got and time.monotonic() < deadline:
            r, _, _ = select.select([self.proc.stdout], [], [], 0.1)
            if r:
                got += os.read(self.proc.stdout.fileno(), 64)
            assert self.proc.poll() is None, f"{self.kind} exited"
        assert b"ready\n" in got, f"{self.kind}: no ready"

    def stop(self):
        stop_process(self.proc, self.log)


@pytest.fixture(scope="module")
def browser():
    with tempfile.TemporaryDirectory() as profile:
        b = headless_chromium(profile)
        try:
            yield b
        finally:
            b.quit()


def wait(b, cond, what: str, timeout: float = WAIT_S):
    WebDriverWait(b, timeout, poll_frequency=0.1).until(lambda _: cond(), message=what)


def text(b, element_id: str) -> str:
    return b.execute_script(
        "const e = document.getElementById(arguments[0]); return e ? e.innerText : ''",
        element_id)


def bit_set(b, list_id: str, bit: int) -> bool:
    cls = b.execute_script(
        "const e = document.querySelector(arguments[0]); return e ? e.className : ''",
        f'#{list_id} li[data-bit="{bit}"]')
    return "set" in cls.split()


@pytest.mark.parametrize("kind", ["virtual", "g431", "f103"])
def test_the_page_moves_a_drive_and_follows_its_line_away_and_back(browser, kind, tmp_path):
    runner = Runner(tmp_path, kind)
    page = None
    try:
        page = commission.Commission(BIN, tmp_path, "--serial", runner.link)
        b = browser
        b.get(page.url)
        wait(b, lambda: text(b, "link") == "live", "the page is live")
        wait(b, lambda: "samples/s" in text(b, "remote") and text(b, "state") == "Switch On Disabled",
             "the drive's state read over the line")
        wait(b, lambda: len(b.find_elements(By.CSS_SELECTOR, "#pa tbody tr")) == 60, "PA table")
        # the §6 table's page column: the master's requests sent, not "—"
        sent = lambda: b.execute_script(
            "const e = document.querySelector('[data-counter=\"page-bus_messages\"]');"
            " return e ? e.innerText : ''")
        wait(b, lambda: sent().isdigit() and int(sent()) > 0, "the master's count shown")
        # the force buttons of the simulated axis have no meaning here
        assert text(b, "switches-title") == "Switch inputs (DP-In)"
        b.find_element(By.ID, "enable").click()
        wait(b, lambda: text(b, "state") == "Operation Enabled", "enabled")
        target = b.find_element(By.ID, "move-target")
        target.clear()
        target.send_keys("10000")
        b.find_element(By.ID, "move-go").click()
        wait(b, lambda: bit_set(b, "sw-bits", SW_TARGET_REACHED) and text(b, "pos-readout") == "10000",
             "target reached at 10000")
        assert "done" in text(b, "cmd-log"), text(b, "cmd-log")
        # EE-dEF asks first: dismissed, nothing is sent; accepted, it runs
        before = text(b, "cmd-log")
        b.find_element(By.ID, "defaults").click()
        b.switch_to.alert.dismiss()
        time.sleep(0.5)
        assert text(b, "cmd-log") == before
        b.find_element(By.ID, "defaults").click()
        b.switch_to.alert.accept()
        wait(b, lambda: "EE-dEF (restore defaults, and save them): ok" in text(b, "cmd-log"),
             "EE-dEF answered")
        # the line pulled away: the runner stops
        runner.stop()
        wait(b, lambda: text(b, "link") == "drive not answering", "the page says the drive is gone")
        assert "not answering" in text(b, "remote")
        runner.start()
        wait(b, lambda: text(b, "link") == "live" and text(b, "state") != "Not Answering",
             "the page finds the drive again")
    finally:
        if page:
            page.stop()
        runner.stop()
