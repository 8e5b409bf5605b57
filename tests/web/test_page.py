"""The commissioning page (`--web`) in a real browser: headless Chromium
driven by Selenium, against the release binary, while pymodbus masters work
the same drive over its `--tcp` line (RTU framing) and its `--modbus-tcp`
port (MBAP framing).

The tests share one drive and one browser and run in file order, each from
where the one before left the drive. Run by .ci/web.sh. Environment:
MODBUS_DRIVE_BIN (binary), CHROMIUM and CHROMEDRIVER (paths), WEB_SCREENSHOT
(where to save a screenshot of the page during a move; none if unset)."""

from __future__ import annotations

import json
import os
import re
import select
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient
from selenium.webdriver.common.action_chains import ActionChains
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
WAIT_S = 15

# Dictionary entries (SPEC §5) and PAs (SPEC §7, legacy map 0x0064 + n).
MODE = 0x6060
ACTUAL_POSITION = 0x6064
STATUSWORD = 0x6041
TARGET_POSITION = 0x607A
HOME_OFFSET = 0x607C
HOMING_METHOD = 0x6098
HOMING_SPEED = 0x6099
HOMING_ACCEL = 0x609A
HOMING_ZERO_SPEED = 0x609B
PA = 0x0064
# Statusword bits (SPEC §8.2).
SW_FAULT, SW_ENABLED, SW_RUNNING, SW_TARGET_REACHED = 3, 2, 9, 10
SW_HOME_SWITCH, SW_HOMING_ATTAINED, SW_CW_LIMIT, SW_CCW_LIMIT = 11, 12, 14, 15
# The simulated axis's home switch: passed by the move, found by homing.
HOME_SWITCH = (200_000, 210_000)
MOVE_TARGET = 250_000


class Drive:
    """One run of the release binary with a pty, both TCP ports and the page."""

    def __init__(self, workdir: Path):
        self.stderr_path = workdir / "drive.log"
        self._err = open(self.stderr_path, "wb")
        self.proc = subprocess.Popen(
            [str(BIN), "--no-status", "--pty-link", str(workdir / "ttyVD"),
             "--tcp", "127.0.0.1:0", "--modbus-tcp", "127.0.0.1:0",
             "--web", "127.0.0.1:0",
             "--home-switch", f"{HOME_SWITCH[0]}:{HOME_SWITCH[1]}"],
            stdout=subprocess.PIPE, stderr=self._err, cwd=workdir)
        r, _, _ = select.select([self.proc.stdout], [], [], 10)
        line = self.proc.stdout.readline() if r else b""
        if line != b"ready\n":
            self.stop()
            raise RuntimeError(f"no `ready`: {line!r}\n{self.log()}")
        log = self.log()
        self.tcp_port = int(re.search(r"tcp: listening on 127\.0\.0\.1:(\d+) \(RTU", log).group(1))
        self.mbap_port = int(re.search(r"modbus-tcp: listening on 127\.0\.0\.1:(\d+)", log).group(1))
        m = re.search(r"web: page on (http://127\.0\.0\.1:(\d+)/)", log)
        self.url, self.web_port = m.group(1), int(m.group(2))

    def log(self) -> str:
        return self.stderr_path.read_text(errors="replace")

    def api_state(self) -> dict:
        with urllib.request.urlopen(self.url + "api/state", timeout=5) as r:
            return json.load(r)["drives"][0]

    def stop(self):
        stop_process(self.proc, self._err)


@pytest.fixture(scope="module")
def drive():
    with tempfile.TemporaryDirectory() as tmp:
        d = Drive(Path(tmp))
        try:
            yield d
        finally:
            d.stop()


@pytest.fixture(scope="module")
def downloads():
    with tempfile.TemporaryDirectory() as d:
        yield Path(d)


@pytest.fixture(scope="module")
def browser(drive, downloads):
    with tempfile.TemporaryDirectory() as profile:
        b = headless_chromium(profile, {
            "download.default_directory": str(downloads),
            "download.prompt_for_download": False,
        })
        try:
            b.execute_cdp_cmd("Browser.setDownloadBehavior",
                              {"behavior": "allow", "downloadPath": str(downloads)})
            b.get(drive.url)
            wait(b, lambda: b.find_element(By.ID, "link").text == "live", "event stream")
            wait(b, lambda: len(b.find_elements(By.CSS_SELECTOR, "#pa tbody tr")) == 60, "PA table")
            yield b
        finally:
            b.quit()


def wait(b, cond, what: str, timeout: float = WAIT_S):
    WebDriverWait(b, timeout, poll_frequency=0.05).until(lambda _: cond(), message=what)


def text(b, selector: str) -> str | None:
    """The text of the first element matching `selector`, read in one step
    (the page rebuilds some tables several times a second)."""
    return b.execute_script(
        "const e = document.querySelector(arguments[0]); return e ? e.innerText : null",
        selector)


def state(b) -> str:
    return b.find_element(By.ID, "state").text


def position(b) -> int:
    return int(b.find_element(By.ID, "pos-readout").text)


def bit_set(b, list_id: str, bit: int) -> bool:
    cls = b.execute_script(
        "const e = document.querySelector(arguments[0]); return e ? e.className : ''",
        f'#{list_id} li[data-bit="{bit}"]')
    return "set" in cls.split()


def row(b, index: int):
    return b.find_element(By.CSS_SELECTOR, f'tr[data-index="{index}"]')


def edit(b, index: int, value) -> str:
    """Types `value` into the table row of `index`, writes it and returns
    what the row says of the result."""
    r = row(b, index)
    field = r.find_element(By.TAG_NAME, "input")
    field.clear()
    field.send_keys(str(value))
    result = r.find_element(By.CLASS_NAME, "result")
    b.execute_script("arguments[0].textContent = ''", result)
    r.find_element(By.TAG_NAME, "button").click()
    wait(b, lambda: result.text not in ("", "…"), f"result of writing {value} to 0x{index:04X}")
    return result.text


def click(b, element_id: str):
    b.find_element(By.ID, element_id).click()


def set_field(b, element_id: str, value):
    f = b.find_element(By.ID, element_id)
    f.clear()
    f.send_keys(str(value))


def status_snapshot(b) -> tuple[int, bool]:
    """The status panel's position and running bit, read in one step (both
    rendered from one /api/state snapshot)."""
    pos, cls = b.execute_script(
        "return [document.getElementById('pos-readout').innerText, "
        f"document.querySelector('#sw-bits li[data-bit=\"{SW_RUNNING}\"]').className]")
    return int(pos), "set" in cls.split()


def last_command_ok(b) -> bool:
    return b.find_element(By.ID, "cmd-log").get_attribute("data-ok") == "1"


def counter(b, name: str) -> int:
    return int(text(b, f'[data-counter="{name}"]'))


def newest_exception(b) -> list[str] | None:
    """Port, function and code of the newest row of the last exceptions."""
    cells = b.execute_script(
        "const r = document.querySelector('#exceptions tbody tr');"
        "return r ? [...r.cells].map(c => c.innerText) : null")
    return [cells[1], cells[2], cells[3].split()[0]] if cells else None


class Master(threading.Thread):
    """A pymodbus master reading and writing the drive as long as it runs;
    every reply is checked."""

    def __init__(self, port: int, framer: FramerType):
        super().__init__(daemon=True)
        self.client = ModbusTcpClient("127.0.0.1", port=port, framer=framer,
                                      timeout=1, retries=0)
        assert self.client.connect()
        self.stop_flag = threading.Event()
        self.transactions = 0
        self.positions: list[int] = []
        self.errors: list[str] = []

    def run(self):
        i = 0
        while not self.stop_flag.is_set():
            i += 1
            try:
                r = self.client.read_holding_registers(ACTUAL_POSITION, count=2, device_id=1)
                if r.isError() or len(r.registers) != 2:
                    self.errors.append(f"read 0x6064: {r}")
                else:
                    p = (r.registers[0] << 16) | r.registers[1]
                    self.positions.append(p - (1 << 32) if p >= 1 << 31 else p)
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


# ---- serving -------------------------------------------------------------


def test_the_page_is_served_only_on_the_given_address(drive):
    with socket.create_connection(("127.0.0.1", drive.web_port), timeout=2):
        pass
    # 127.0.0.2 is this machine too: a listener on any address would answer.
    with pytest.raises(OSError):
        socket.create_connection(("127.0.0.2", drive.web_port), timeout=2).close()


def test_the_page_needs_nothing_from_elsewhere(drive, browser):
    for path in ["", "page.js", "page.css"]:
        with urllib.request.urlopen(drive.url + path, timeout=5) as r:
            body = r.read().decode()
        assert not re.search(r"(https?:)?//[a-z0-9.-]+\.[a-z]{2,}", body, re.I), path
    # Everything the browser loaded came from the drive.
    origins = browser.execute_script(
        "return performance.getEntriesByType('resource').map(e => new URL(e.name).origin)")
    assert origins and set(origins) == {drive.url.rstrip("/")}


def test_a_command_without_the_pages_header_is_refused(drive):
    req = urllib.request.Request(drive.url + "api/cmd?d=0&c=enable", method="POST")
    with pytest.raises(urllib.error.HTTPError) as e:
        urllib.request.urlopen(req, timeout=5)
    assert e.value.code == 403
    time.sleep(0.3)
    assert drive.api_state()["state"] == "SwitchOnDisabled"


# ---- status and scope ------------------------------------------------------


def test_scope_streams_at_least_50_samples_per_second(browser):
    time.sleep(2.2)
    rate = browser.execute_script("return window.scope.rate")
    assert rate >= 50, f"{rate} samples/s"
    n = browser.execute_script("return window.scope.buf[0].length")
    assert n >= 100
    assert state(browser) == "Switch On Disabled"
    # Switch on disabled (SPEC §8.1, §8.2): named bits, bit 6 set.
    assert "switch on disabled" in text(browser, '#sw-bits li[data-bit="6"]')
    assert bit_set(browser, "sw-bits", 6) and not bit_set(browser, "sw-bits", SW_ENABLED)
    assert "generic" in text(browser, '#er-bits li[data-bit="0"]')
    assert "communication" in text(browser, '#er-bits li[data-bit="4"]')
    assert text(browser, "#er-hex") == "0x0000"
    counters = text(browser, "#counters tbody")
    for name in ["bus messages", "bus errors", "exceptions", "slave messages",
                 "no response", "busy", "overruns"]:
        assert name in counters
    # the Modbus TCP server's connection counters (--modbus-tcp is on)
    mt = text(browser, "#modbus-tcp")
    assert re.match(r"Modbus TCP: \d+ connected, \d+ requests, \d+ bad ADUs; closed idle "
                    r"\(60 s\): 0, closed to admit a new client: 0, refused: 0$", mt), mt


def test_enable_move_with_two_masters_at_the_same_time(browser, drive):
    masters = [Master(drive.tcp_port, FramerType.RTU),
               Master(drive.mbap_port, FramerType.SOCKET)]
    for m in masters:
        m.start()
    try:
        click(browser, "enable")
        wait(browser, lambda: state(browser) == "Operation Enabled", "operation enabled")
        assert last_command_ok(browser)
        assert bit_set(browser, "sw-bits", SW_ENABLED)
        for field, value in [("move-target", MOVE_TARGET), ("speed", 100), ("accel", 100)]:
            f = browser.find_element(By.ID, field)
            f.clear()
            f.send_keys(str(value))
        click(browser, "move-go")
        wait(browser, lambda: position(browser) > 1000, "the axis moves")
        assert last_command_ok(browser)
        assert text(browser, "#mode") == "position (1)"
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
        # Each sample is one snapshot: while the velocity is not 0 the
        # running bit is set. (When the test gets here the move may be over
        # on a busy host: its timing is the axis's, not the browser's.)
        moving = [r for r in rows if r[2] != 0]
        assert moving and all(r[4] & (1 << SW_RUNNING) for r in moving), moving[:3]
        # The status panel is one snapshot too: running, or at the target.
        pos, running = status_snapshot(browser)
        assert running or pos == MOVE_TARGET, (pos, running)
        wait(browser, lambda: position(browser) == MOVE_TARGET, "the move ends at its target")
        wait(browser, lambda: bit_set(browser, "sw-bits", SW_TARGET_REACHED), "target reached")
    finally:
        for m in masters:
            m.finish()
    for m in masters:
        assert not m.errors, m.errors[:5]
        assert m.transactions > 50
        # Each master saw the move the page started.
        assert m.positions[0] < 1000 and max(m.positions) == MOVE_TARGET
    # The page's requests count on its own port (3 to enable, 6 to move),
    # the masters' on the bus: neither in the other's counters.
    total = sum(m.transactions for m in masters)
    wait(browser, lambda: counter(browser, "bus-slave_messages") == total,
         f"bus counter at the masters' {total} requests")
    assert counter(browser, "page-slave_messages") == 3 + 6
    assert counter(browser, "bus-exceptions") == 0 and counter(browser, "bus-bus_errors") == 0


def test_the_scope_pauses_zooms_and_downloads_csv(browser, downloads):
    click(browser, "pause")
    assert browser.find_element(By.ID, "pause").text == "Resume"
    frozen = browser.execute_script("return window.scope.frozen.length")
    frozen_end = browser.execute_script("return window.scope.frozen.at(-1)[0]")
    time.sleep(0.5)
    assert browser.execute_script("return window.scope.frozen.length") == frozen
    # live data keeps coming in behind the copy: newer samples (not more:
    # a buffer holding its full 10 s drops one old sample for each new one)
    wait(browser, lambda: browser.execute_script("return window.scope.buf[0].at(-1)[0]") > frozen_end,
         "live samples behind the frozen copy")
    # The window: buttons, then the wheel (zoom in by 0.8 a notch).
    browser.find_element(By.CSS_SELECTOR, 'button.span[data-span="1"]').click()
    assert browser.execute_script("return window.scope.span") == 1
    browser.execute_script(
        "document.getElementById('scope').dispatchEvent("
        "new WheelEvent('wheel', {deltaY: -100, bubbles: true, cancelable: true}))")
    assert abs(browser.execute_script("return window.scope.span") - 0.8) < 1e-9
    # Paused, a drag pans back in time.
    canvas = browser.find_element(By.ID, "scope")
    ActionChains(browser).move_to_element(canvas).click_and_hold() \
        .move_by_offset(200, 0).release().perform()
    end = browser.execute_script("return window.scope.end")
    last = browser.execute_script("return window.scope.frozen.at(-1)[0]")
    assert end is not None and end < last - 0.05
    # CSV: what the scope holds, as a file.
    click(browser, "csv")
    path = downloads / "scope-drive0.csv"
    wait(browser, lambda: path.exists() and path.stat().st_size > 0, "the CSV download")
    lines = path.read_text().splitlines()
    assert lines[0].startswith("time_s,position_steps,velocity_rpm")
    assert lines[0].endswith(",statusword")
    assert len(lines) - 1 == frozen
    data = [line.split(",") for line in lines[1:]]
    times = [float(r[0]) for r in data]
    assert times == sorted(times) and times[-1] - times[0] <= 10.0
    assert int(data[-1][1]) == MOVE_TARGET and min(int(r[1]) for r in data) < MOVE_TARGET
    click(browser, "pause")
    assert browser.execute_script("return window.scope.frozen") is None
    browser.find_element(By.CSS_SELECTOR, 'button.span[data-span="10"]').click()


# ---- dictionary and parameters -------------------------------------------


def test_the_tables_show_access_type_range_unit_and_value(browser):
    cells = lambda index: [c.text for c in row(browser, index).find_elements(By.TAG_NAME, "td")]
    tp = cells(TARGET_POSITION)
    assert tp[:4] == ["0x607A", "TargetPosition", "RW", "I32"] and tp[5] == "steps"
    assert tp[6] == str(MOVE_TARGET)
    sw = cells(STATUSWORD)
    assert sw[2:4] == ["RO", "U16"]
    assert not row(browser, STATUSWORD).find_elements(By.TAG_NAME, "input")
    pa12 = cells(PA + 12)
    assert pa12[:6] == ["PA12", "maximum speed", "RW", "U16", "1..=6000", "r/min"]
    assert pa12[6] == "3000"
    assert not row(browser, PA + 2).find_elements(By.TAG_NAME, "input")
    assert len(browser.find_elements(By.CSS_SELECTOR, "#pa tbody tr")) == 60


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
    (HOMING_METHOD, 9, 3),  # 0x6098 ∉ 1..=8
], ids=["mode-5", "PA51-300", "homing-method-9"])
def test_a_refused_value_shows_the_masters_exception(browser, index, value, code):
    before = row(browser, index).find_element(By.CLASS_NAME, "value").text
    assert edit(browser, index, value) == f"exception {code} (illegal data value)"
    wait(browser, lambda: newest_exception(browser) == ["web", "0x06", str(code)],
         "the refusal in the last exceptions")
    time.sleep(0.3)
    assert row(browser, index).find_element(By.CLASS_NAME, "value").text == before


@pytest.mark.parametrize("pdu,function,code", [
    ("06 00 66 1B 9C", "0x06", 5),   # PA2 is read-only
    ("03 60 40 00 01", "0x03", 7),   # 0x6040 is write-only
    ("06 60 90 00 03", "0x06", 11),  # 0x6090 does not exist
], ids=["write-PA2", "read-0x6040", "write-0x6090"])
def test_a_typed_request_shows_the_masters_exception(browser, pdu, function, code):
    field = browser.find_element(By.ID, "raw-pdu")
    field.clear()
    field.send_keys(pdu)
    log = browser.find_element(By.ID, "raw-log")
    browser.execute_script("arguments[0].textContent = ''", log)
    click(browser, "raw-send")
    wait(browser, lambda: "exception" in log.text, "answer to the typed request")
    assert f"exception {code} " in log.text, log.text
    wait(browser, lambda: newest_exception(browser) == ["web", function, str(code)],
         "the refusal in the last exceptions")


def test_a_masters_refusal_shows_with_its_port(browser, drive):
    c = ModbusTcpClient("127.0.0.1", port=drive.mbap_port, framer=FramerType.SOCKET, timeout=1)
    assert c.connect()
    try:
        r = c.write_register(MODE, 2, device_id=1)
        assert r.isError() and r.exception_code == 3
    finally:
        c.close()
    wait(browser, lambda: (newest_exception(browser) or [""])[0].startswith("modbus-tcp 127.0.0.1:")
         and newest_exception(browser)[1:] == ["0x06", "3"], "the master's refusal")
    assert counter(browser, "bus-exceptions") == 1


# ---- driving the axis ----------------------------------------------------


def test_a_forced_limit_switch_reaches_the_statusword(browser):
    r = browser.find_element(By.CSS_SELECTOR, 'tr[data-switch="cw"]')
    r.find_element(By.CSS_SELECTOR, 'button[data-state="on"]').click()
    wait(browser, lambda: bit_set(browser, "sw-bits", SW_CW_LIMIT), "statusword bit 14")
    r.find_element(By.CSS_SELECTOR, 'button[data-state="auto"]').click()
    wait(browser, lambda: not bit_set(browser, "sw-bits", SW_CW_LIMIT), "bit 14 released")


@pytest.mark.parametrize("button,sign", [("jog-neg", -1), ("jog-pos", 1)], ids=["neg", "pos"])
def test_jog_runs_while_held_and_stops_on_release(browser, button, sign):
    start = position(browser)
    jog = browser.find_element(By.ID, button)
    ActionChains(browser).click_and_hold(jog).perform()
    wait(browser, lambda: sign * (position(browser) - start) > 1000, f"{button} moves the axis")
    assert text(browser, "#mode") == "velocity (3)"
    ActionChains(browser).release(jog).perform()
    wait(browser, lambda: not bit_set(browser, "sw-bits", SW_RUNNING),
         "the motor stops after release")
    stopped = position(browser)
    time.sleep(0.3)
    assert position(browser) == stopped


def test_homing_from_the_page_finds_the_home_switch(browser):
    for index, value in [(HOMING_METHOD, 3), (HOMING_SPEED, 50), (HOMING_ZERO_SPEED, 10),
                         (HOMING_ACCEL, 200), (HOME_OFFSET, 0)]:
        assert edit(browser, index, value) == "✓ written", hex(index)
    # Method 3 starts right of the switch: go there first (how far the
    # jogs before went depends on how fast the browser let go)
    set_field(browser, "move-target", MOVE_TARGET)
    click(browser, "move-go")
    wait(browser, lambda: status_snapshot(browser) == (MOVE_TARGET, False), "back at the move's target")
    assert position(browser) > HOME_SWITCH[1]
    click(browser, "home")
    wait(browser, lambda: text(browser, "#mode") == "homing (6)", "homing mode")
    assert last_command_ok(browser)
    # Method 3 runs left onto the switch; its edge becomes the origin.
    wait(browser, lambda: bit_set(browser, "sw-bits", SW_HOMING_ATTAINED)
         and bit_set(browser, "sw-bits", SW_TARGET_REACHED), "homing attained")
    assert "homing attained" in text(browser, f'#sw-bits li[data-bit="{SW_HOMING_ATTAINED}"]')
    wait(browser, lambda: position(browser) == 0, "the position is 0 at the origin")


def test_both_limits_fault_and_a_reset_from_the_page(browser):
    for switch in ["cw", "ccw"]:
        browser.find_element(
            By.CSS_SELECTOR, f'tr[data-switch="{switch}"] button[data-state="on"]').click()
    wait(browser, lambda: state(browser) == "Fault", "the fault")
    assert bit_set(browser, "sw-bits", SW_FAULT)
    wait(browser, lambda: bit_set(browser, "er-bits", 0), "0x1001 bit 0 (generic)")
    assert text(browser, "#er-hex") == "0x0001"
    # Enable is refused while in fault, with the reason.
    click(browser, "enable")
    log = browser.find_element(By.ID, "cmd-log")
    wait(browser, lambda: "reset the fault first" in log.text, "enable refused")
    assert not last_command_ok(browser)
    # Still both limits: the fault stays after a reset.
    for switch in ["cw", "ccw"]:
        browser.find_element(
            By.CSS_SELECTOR, f'tr[data-switch="{switch}"] button[data-state="auto"]').click()
    click(browser, "reset")
    wait(browser, lambda: state(browser) == "Switch On Disabled", "the fault reset")
    wait(browser, lambda: not bit_set(browser, "er-bits", 0), "0x1001 cleared")
    click(browser, "enable")
    wait(browser, lambda: state(browser) == "Operation Enabled", "enabled again")
    click(browser, "disable")
    wait(browser, lambda: state(browser) == "Ready To Switch On", "disabled")
    assert last_command_ok(browser)


def test_a_relative_move_a_save_refused_while_moving_and_a_quick_stop(browser):
    click(browser, "enable")
    wait(browser, lambda: state(browser) == "Operation Enabled", "enabled")
    start = position(browser)
    # slow enough (10,000 steps/s: 100 s for the move) that the quick stop
    # below comes first however slowly the browser acts
    set_field(browser, "speed", 10)
    set_field(browser, "move-target", 1_000_000)
    browser.find_element(By.ID, "move-relative").click()
    click(browser, "move-go")
    wait(browser, lambda: position(browser) > start + 5000, "the relative move runs")
    # EE operations under a moving axis are refused with 6 (busy).
    log = browser.find_element(By.ID, "cmd-log")
    browser.execute_script("arguments[0].textContent = ''", log)
    click(browser, "save")
    wait(browser, lambda: log.text.startswith("save:"), "the save's answer")
    assert "exception 6 (busy)" in log.text and not last_command_ok(browser)
    click(browser, "quickstop")
    wait(browser, lambda: state(browser) == "Quick Stop Active", "quick stop")
    wait(browser, lambda: not bit_set(browser, "sw-bits", SW_RUNNING), "stopped")
    assert position(browser) < start + 1_000_000
    browser.find_element(By.ID, "move-relative").click()
    click(browser, "disable")
    wait(browser, lambda: state(browser) == "Ready To Switch On", "disabled")
    # At rest the save runs (on the drive's flash) and answers normally.
    browser.execute_script("arguments[0].textContent = ''", log)
    click(browser, "save")
    wait(browser, lambda: log.text.startswith("save:"), "the save's answer")
    assert last_command_ok(browser), log.text
    assert "EE-Set (save parameters): ok" in log.text


def test_a_page_opened_later_gets_the_last_10_s_of_scope(browser, drive):
    # By now the drive has run for more than 10 s.
    browser.get(drive.url)
    wait(browser, lambda: browser.find_element(By.ID, "link").text == "live", "event stream")
    # At once: 9 s of history within 5 s of going live (live samples alone
    # would span less). Counted by time, not by samples: a drive process
    # starved of CPU samples less often than every 10 ms, and the samples
    # say when they were taken (the stream test asks >= 50 a second).
    span = "const b = window.scope.buf[0] || []; return b.length ? b.at(-1)[0] - b[0][0] : 0"
    wait(browser, lambda: browser.execute_script(span) >= 9.0, "the kept samples", timeout=5)
    assert 9.0 <= browser.execute_script(span) <= 10.0
    assert browser.execute_script("return window.scope.buf[0].length") >= 450
