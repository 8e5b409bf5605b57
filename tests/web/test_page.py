"""The commissioning page (`--web`) in a real browser: headless Chromium
driven by Selenium, against the release binary, while a pymodbus master
works the same drive over its `--tcp` line.

Run by .ci/web.sh. Environment: MODBUS_DRIVE_BIN (binary), CHROMIUM and
CHROMEDRIVER (paths), WEB_SCREENSHOT (where to save a screenshot of the
page during a move; none if unset)."""

from __future__ import annotations

import os
import re
import select
import signal
import subprocess
import tempfile
import threading
import time
from pathlib import Path

import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient
from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import WebDriverWait

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(os.environ.get("MODBUS_DRIVE_BIN", ROOT / "target" / "release" / "modbus-drive"))
CHROMIUM = os.environ.get("CHROMIUM", "/usr/bin/chromium")
CHROMEDRIVER = os.environ.get("CHROMEDRIVER", "/usr/bin/chromedriver")
WAIT_S = 15

# Dictionary entries (SPEC §5) and PAs (SPEC §7, legacy map 0x0064 + n).
MODE = 0x6060
ACTUAL_POSITION = 0x6064
STATUSWORD = 0x6041
HOME_OFFSET = 0x607C
PA = 0x0064
CW_LIMIT_BIT = 14


class Drive:
    """One run of the release binary with a pty, a TCP line and the page."""

    def __init__(self, workdir: Path):
        self.stderr_path = workdir / "drive.log"
        self._err = open(self.stderr_path, "wb")
        self.proc = subprocess.Popen(
            [str(BIN), "--no-status", "--pty-link", str(workdir / "ttyVD"),
             "--tcp", "127.0.0.1:0", "--web", "127.0.0.1:0"],
            stdout=subprocess.PIPE, stderr=self._err, cwd=workdir)
        r, _, _ = select.select([self.proc.stdout], [], [], 10)
        line = self.proc.stdout.readline() if r else b""
        if line != b"ready\n":
            self.stop()
            raise RuntimeError(f"no `ready`: {line!r}\n{self.log()}")
        log = self.log()
        self.tcp_port = int(re.search(r"tcp: listening on 127\.0\.0\.1:(\d+)", log).group(1))
        self.url = re.search(r"web: page on (http://127\.0\.0\.1:\d+/)", log).group(1)

    def log(self) -> str:
        return self.stderr_path.read_text(errors="replace")

    def stop(self):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self.proc.stdout.close()
        self._err.close()


@pytest.fixture(scope="module")
def drive():
    with tempfile.TemporaryDirectory() as tmp:
        d = Drive(Path(tmp))
        try:
            yield d
        finally:
            d.stop()


@pytest.fixture(scope="module")
def browser(drive):
    with tempfile.TemporaryDirectory() as profile:
        opts = webdriver.ChromeOptions()
        opts.binary_location = CHROMIUM
        for flag in ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                     "--no-first-run", "--disable-background-networking",
                     "--disable-component-update", "--disable-sync",
                     f"--user-data-dir={profile}", "--window-size=1600,1000"]:
            opts.add_argument(flag)
        b = webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
        try:
            b.get(drive.url)
            wait(b, lambda: b.find_element(By.ID, "link").text == "live", "event stream")
            wait(b, lambda: len(b.find_elements(By.CSS_SELECTOR, "#pa tbody tr")) == 60, "PA table")
            yield b
        finally:
            b.quit()


def wait(b, cond, what: str, timeout: float = WAIT_S):
    WebDriverWait(b, timeout, poll_frequency=0.05).until(lambda _: cond(), message=what)


def state(b) -> str:
    return b.find_element(By.ID, "state").text


def position(b) -> int:
    return int(b.find_element(By.ID, "pos-readout").text)


def row(b, index: int):
    return b.find_element(By.CSS_SELECTOR, f'tr[data-index="{index}"]')


def edit(b, index: int, value) -> str:
    """Types `value` into the table row of `index`, writes it and returns
    what the row says of the result."""
    r = row(b, index)
    field = r.find_element(By.TAG_NAME, "input")
    field.clear()
    field.send_keys(str(value))
    r.find_element(By.TAG_NAME, "button").click()
    result = r.find_element(By.CLASS_NAME, "result")
    wait(b, lambda: result.text not in ("", "…"), f"result of writing {value} to 0x{index:04X}")
    return result.text


def click(b, element_id: str):
    b.find_element(By.ID, element_id).click()


def last_command_ok(b) -> bool:
    log = b.find_element(By.ID, "cmd-log")
    return log.get_attribute("data-ok") == "1"


class Master(threading.Thread):
    """A pymodbus master reading and writing the drive over TCP (RTU
    framing) as long as it runs; every reply is checked."""

    def __init__(self, port: int):
        super().__init__(daemon=True)
        self.client = ModbusTcpClient("127.0.0.1", port=port, framer=FramerType.RTU,
                                      timeout=1, retries=0)
        assert self.client.connect()
        self.stop_flag = threading.Event()
        self.transactions = 0
        self.errors: list[str] = []

    def run(self):
        i = 0
        while not self.stop_flag.is_set():
            i += 1
            try:
                r = self.client.read_holding_registers(ACTUAL_POSITION, count=2, device_id=1)
                if r.isError() or len(r.registers) != 2:
                    self.errors.append(f"read 0x6064: {r}")
                r = self.client.write_registers(HOME_OFFSET, [0, i % 1000], device_id=1)
                if r.isError():
                    self.errors.append(f"write 0x607C: {r}")
                r = self.client.read_holding_registers(STATUSWORD, count=1, device_id=1)
                if r.isError():
                    self.errors.append(f"read 0x6041: {r}")
                self.transactions += 3
            except Exception as e:  # a timeout or a garbled reply
                self.errors.append(repr(e))
            time.sleep(0.005)

    def finish(self):
        self.stop_flag.set()
        self.join(5)
        self.client.close()


def test_scope_streams_at_least_50_samples_per_second(browser):
    time.sleep(2.2)
    rate = browser.execute_script("return window.scope.rate")
    assert rate >= 50, f"{rate} samples/s"
    n = browser.execute_script("return window.scope.buf[0].length")
    assert n >= 100
    assert state(browser) == "Switch On Disabled"


def test_enable_move_and_a_master_at_the_same_time(browser, drive):
    master = Master(drive.tcp_port)
    master.start()
    try:
        click(browser, "enable")
        wait(browser, lambda: state(browser) == "Operation Enabled", "operation enabled")
        assert last_command_ok(browser)
        for field, value in [("move-target", 250000), ("speed", 100), ("accel", 100)]:
            f = browser.find_element(By.ID, field)
            f.clear()
            f.send_keys(str(value))
        t0 = browser.execute_script("return performance.now()")
        click(browser, "move-go")
        wait(browser, lambda: position(browser) > 1000, "the axis moves")
        assert last_command_ok(browser)
        drawn = browser.execute_script("return window.scope.drawn")
        time.sleep(1.0)
        shot = os.environ.get("WEB_SCREENSHOT")
        if shot:
            browser.save_screenshot(shot)
        # The scope shows the move: rising position, a non-zero velocity.
        rows = browser.execute_script(
            "return window.scope.buf[0].filter(r => r[0] >= window.scope.buf[0].at(-1)[0] - 1.5)")
        assert max(r[2] for r in rows) > 0, "no velocity on the scope"
        assert rows[-1][1] > rows[0][1], "position not rising on the scope"
        assert browser.execute_script("return window.scope.drawn") > drawn + 20
        wait(browser, lambda: position(browser) == 250000, "the move ends at its target")
        assert browser.execute_script("return performance.now()") - t0 < WAIT_S * 1000
        csv = browser.execute_script("return window.scopeCsv()").splitlines()
        assert csv[0].startswith("time_s,position_steps,velocity_rpm")
        positions = [int(line.split(",")[1]) for line in csv[1:]]
        assert positions[-1] == 250000 and min(positions) < 250000
    finally:
        master.finish()
    assert not master.errors, master.errors[:5]
    assert master.transactions > 50
    # The page's requests count on its own port (3 to enable, 6 to move),
    # the master's on the bus: neither in the other's counters.
    def counter(name):
        return int(browser.find_element(By.CSS_SELECTOR, f'[data-counter="{name}"]').text)
    wait(browser, lambda: counter("bus-slave_messages") == master.transactions,
         f"bus counter at the master's {master.transactions} requests")
    assert counter("page-slave_messages") == 3 + 6
    assert counter("bus-exceptions") == 0 and counter("bus-bus_errors") == 0


def test_a_parameter_edit_reaches_the_drive(browser, drive):
    assert edit(browser, PA + 12, 1500) == "✓ written"
    value = row(browser, PA + 12).find_element(By.CLASS_NAME, "value")
    wait(browser, lambda: value.text == "1500", "PA12 shows 1500")
    c = ModbusTcpClient("127.0.0.1", port=drive.tcp_port, framer=FramerType.RTU, timeout=1)
    assert c.connect()
    try:
        r = c.read_holding_registers(PA + 12, count=1, device_id=1)
        assert not r.isError() and r.registers == [1500]
    finally:
        c.close()


@pytest.mark.parametrize("index,value,code", [
    (MODE, 5, 3),          # SPEC §5.2 step 8: 0x6060 ∉ {1, 3, 6}
    (PA + 51, 300, 3),     # PA51 ∉ 1..=247
    (PA + 2, 1, 5),        # PA2 is read-only ... typed through the raw box below
])
def test_a_refused_value_shows_the_masters_exception(browser, index, value, code):
    if index == PA + 2:
        # Read-only rows have no input: send the write as a typed request.
        field = browser.find_element(By.ID, "raw-pdu")
        field.clear()
        field.send_keys(f"06 00 66 00 {value:02X}")
        click(browser, "raw-send")
        log = browser.find_element(By.ID, "raw-log")
        wait(browser, lambda: "exception" in log.text, "answer to the typed request")
        text = log.text
    else:
        text = edit(browser, index, value)
    assert f"exception {code} " in text, text
    def newest():
        rows = browser.find_elements(By.CSS_SELECTOR, "#exceptions tbody tr")
        return rows[0].text.split()[1:4] if rows else None
    fn = "0x06"
    wait(browser, lambda: newest() == ["web", fn, str(code)], "the refusal in the last exceptions")


def test_a_forced_limit_switch_reaches_the_statusword(browser):
    r = browser.find_element(By.CSS_SELECTOR, 'tr[data-switch="cw"]')
    r.find_element(By.CSS_SELECTOR, 'button[data-state="on"]').click()
    bit = browser.find_element(By.CSS_SELECTOR, f'#sw-bits li[data-bit="{CW_LIMIT_BIT}"]')
    wait(browser, lambda: "set" in bit.get_attribute("class").split(), "statusword bit 14")
    r.find_element(By.CSS_SELECTOR, 'button[data-state="auto"]').click()
    wait(browser, lambda: "set" not in bit.get_attribute("class").split(), "bit 14 released")


def test_jog_runs_while_held_and_stops_on_release(browser):
    from selenium.webdriver.common.action_chains import ActionChains
    start = position(browser)
    jog = browser.find_element(By.ID, "jog-neg")
    ActionChains(browser).click_and_hold(jog).perform()
    wait(browser, lambda: position(browser) < start - 1000, "jog moves the axis")
    ActionChains(browser).release(jog).perform()
    wait(browser, lambda: "set" not in browser.find_element(
        By.CSS_SELECTOR, '#sw-bits li[data-bit="9"]').get_attribute("class").split(),
        "the motor stops after release")
