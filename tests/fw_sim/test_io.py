"""The firmware's other glue on both images: a limit switch reached by the
emulated axis, through GPIO and EXTI (SPEC §8.7), and the parameter flash
(`--state`): EE-Set runs through the firmware's own flash driver against the
modelled flash controller and a saved value survives a restart (SPEC §9)."""

import re
import subprocess
import time

from conftest import (ACCELERATION, ACTUAL_POSITION, ACTUAL_VELOCITY, CCW_LIMIT, DECELERATION,
                      LIMITS, MODE, PA_BASE, PROFILE_VELOCITY, QUICK_STOP_DECELERATION, ROOT,
                      TICK_NS, Master, e2e_module, hexb, pulse_for, with_crc)

limits = e2e_module("test_limits")

MAX_SPEED_PA12 = PA_BASE + 12
# the step engine's idle entry (src/firmware/calc.rs); a run of alike
# periods in one timer entry lasts at most as long
IDLE_NS = int(re.search(r"pub const IDLE_PERIOD_NS: u32 = ([0-9_]+);",
                        (ROOT / "src" / "firmware" / "calc.rs").read_text())[1].replace("_", ""))
EE_SET = with_crc(hexb("01 10 00 3A 00 01 02 00 01"))  # new format, k = 1


def test_a_ccw_limit_stops_the_axis_with_the_quick_stop_distance(start_fw, board):
    """As tests/e2e/test_limits.py: 45 000 steps/s into a CCW limit at
    10 000 with 0x6085 = 500 (50 r/s²): v²/2a = 2025 steps past the edge,
    within the step tick's rounding."""
    fw = start_fw(board, "--ccw-limit", "10000")
    limits.run_into_the_ccw_limit_at_10000(Master(fw.client()), f"{board}: ")


def run_into_the_ccw_limit(m: Master, board: str, rate: int):
    """Velocity mode at `rate` steps/s (PA12 at 6000 r/min, PA15 short
    enough), every ramp and 0x6085 at 2 000 000 steps/s², until the CCW
    limit has stopped the motor."""
    m.write(MAX_SPEED_PA12, 6000)
    m.write(PA_BASE + 15, pulse_for(rate))
    m.enable()
    m.write(MODE, 3)
    m.write(ACCELERATION, 2000)
    m.write(DECELERATION, 2000)
    m.write(QUICK_STOP_DECELERATION, 2000)
    m.write32(PROFILE_VELOCITY, rate // 1000)
    m.wait(lambda s: s & CCW_LIMIT, 20, f"{board}: the CCW limit")
    deadline = time.monotonic() + 20
    while m.read32(ACTUAL_VELOCITY) != 0:
        assert time.monotonic() < deadline, f"{board}: still moving"
        time.sleep(0.02)


def test_a_limit_at_the_top_rate_brakes_from_the_step_the_pin_is_at(start_fw, board):
    """The board's step rate limit into a CCW limit, 0x6085 = 2000
    (2 000 000 steps/s²): v²/2a past the edge, plus the steps the timer
    had been handed. At constant speed the engine writes runs of alike
    periods ahead of the timer; at the edge it cuts all but the two runs
    next to the DMA (and the one playing and the one loaded) and the
    newest (the time of the refill that starts the brake) to one step
    each, so at most five runs and a step for each other entry of the
    buffer go out before the brake, not sixteen runs."""
    rate = LIMITS[board]
    brake = rate * rate // (2 * 2_000_000)
    edge = 2 * brake + 20_000  # up to speed first (0x6083 alike), then a cruise
    fw = start_fw(board, "--ccw-limit", str(edge))
    m = Master(fw.client())
    run_into_the_ccw_limit(m, board, rate)
    fw.alive()
    over = m.read32(ACTUAL_POSITION) - edge
    period_ticks = 1e9 / rate / TICK_NS[board]
    run = int(IDLE_NS / TICK_NS[board] // period_ticks)
    ahead = 5 * run + 11
    print(f"{board}: {over} steps past the edge at {rate} steps/s ({brake} to brake, "
          f"runs of {run}, at most {ahead} ahead)")
    assert brake - 4 <= over <= brake + ahead + 4, f"{board}: {over}"
    assert m.statusword() & CCW_LIMIT
    # the brake kept ahead of the timer, and the bus was served throughout
    assert "came a buffer half late" not in fw.stderr(), fw.stderr()
    assert "Overrun" not in fw.stderr(), fw.stderr()


def test_a_saved_parameter_survives_a_restart(start_fw, board, tmp_path):
    state = tmp_path / f"{board}.flash"
    fw = start_fw(board, "--state", str(state))
    m = Master(fw.client())
    assert m.read(MAX_SPEED_PA12) == 3000, "default (SPEC §7)"
    m.write(MAX_SPEED_PA12, 1500)
    m.write(ACCELERATION, 321)
    with fw.raw() as bus:
        assert bus.exchange(EE_SET, timeout=3) == with_crc(hexb("01 10 00 3A 00 01"))
    m.write(MAX_SPEED_PA12, 1400)  # changed after the save: not persisted
    assert fw.stop() is None
    assert state.stat().st_size == 4096
    fw = start_fw(board, "--state", str(state))
    m = Master(fw.client())
    assert m.read(MAX_SPEED_PA12) == 1500
    assert m.read(ACCELERATION) == 321


def test_mbpoll_over_the_pseudo_terminal(start_fw, board, tmp_path):
    """The --pty-link path, driven by mbpoll as a field engineer would:
    0x6041 reads 0x0060 (switch on disabled, SPEC §8.1) at power-up."""
    link = tmp_path / "ttyFW"
    fw = start_fw(board, "--pty-link", str(link))
    out = subprocess.run(["mbpoll", "-m", "rtu", "-a", "1", "-0", "-r", str(0x6041), "-c", "1",
                          "-b", "115200", "-P", "none", "-1", str(link)],
                         capture_output=True, text=True, timeout=20)
    fw.alive()
    assert out.returncode == 0, out.stdout + out.stderr
    assert re.search(r"\[24641\]:\s+96\b", out.stdout), out.stdout


def test_a_power_cut_during_a_save_keeps_the_old_or_the_new_set(start_fw, board, tmp_path):
    """`--power-cut N`: the supply fails as the N-th flash program or erase
    starts and the chip restarts from the flash file, as the host power-cut
    tests do on the core's store, here through the firmware's own flash
    driver. Whatever N, the drive comes back with the old or the new value,
    and a save afterwards works and survives a restart. The cuts fall on the
    page erase, inside the entry and on the page header, which the journal
    writes last (docs/parameters.md)."""
    for n in (1, 3, 8, last_flash_operation_of_a_first_save(start_fw, board, tmp_path)):
        state = tmp_path / f"{board}-{n}.flash"
        fw = start_fw(board, "--state", str(state), "--power-cut", str(n))
        m = Master(fw.client())
        m.write(MAX_SPEED_PA12, 1500)
        with fw.raw() as bus:
            bus.exchange(EE_SET, timeout=0.3)  # the reply may never come
        deadline = time.monotonic() + 5
        while "power cut" not in fw.stderr():
            assert time.monotonic() < deadline, f"{board}: no power cut at operation {n}"
            time.sleep(0.05)
        time.sleep(0.3)  # the restart
        c = fw.client()
        m = Master(c)
        assert m.read(MAX_SPEED_PA12) in (3000, 1500), f"{board}, cut at {n}"
        m.write(MAX_SPEED_PA12, 1200)
        with fw.raw() as bus:
            assert bus.exchange(EE_SET, timeout=3) == with_crc(hexb("01 10 00 3A 00 01"))
        fw.stop()
        fw = start_fw(board, "--state", str(state))
        assert Master(fw.client()).read(MAX_SPEED_PA12) == 1200, f"{board}, cut at {n}"
        fw.stop()


def last_flash_operation_of_a_first_save(start_fw, board, tmp_path) -> int:
    """A first EE-Set on blank pages is one erase and one program per
    written word (G431 double words, F103 half-words); the words it leaves
    not erased are the entry and the page header, so the count of those plus
    the erase is the number of the header's last operation."""
    state = tmp_path / f"{board}-count.flash"
    fw = start_fw(board, "--state", str(state))
    m = Master(fw.client())
    m.write(MAX_SPEED_PA12, 1500)
    with fw.raw() as bus:
        assert bus.exchange(EE_SET, timeout=3) == with_crc(hexb("01 10 00 3A 00 01"))
    fw.stop()
    image = state.read_bytes()
    word = {"g431": 8, "f103": 2}[board]
    words = [image[i:i + word] for i in range(0, len(image), word)]
    return 1 + sum(1 for w in words if w != b"\xff" * word)
