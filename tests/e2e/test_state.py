"""`--state FILE`: the drive's parameter flash lives in a file, so saved
parameters survive a restart (SPEC §9: EE-Set saves PA0..PA59 and the RW
entries of §5 except 0x607A)."""

import os
import time

from conftest import ACCELERATION, PA_BASE, Master, hexb, with_crc

MAX_SPEED_PA12 = PA_BASE + 12
RESPONSE_DELAY_PA56 = PA_BASE + 56
EE_SET = with_crc(hexb("01 10 00 3A 00 01 02 00 01"))  # new format, k = 1


def test_a_saved_parameter_survives_a_restart(start_drive, tmp_path):
    state = tmp_path / "drive.flash"
    d = start_drive("--no-status", "--state", str(state))
    m = Master(d.client("tcp"))
    assert m.read(MAX_SPEED_PA12) == 3000, "default (SPEC §7)"
    m.write(MAX_SPEED_PA12, 1500)
    m.write(ACCELERATION, 321)
    with d.raw("tcp") as bus:
        assert bus.exchange(EE_SET, timeout=3) == with_crc(hexb("01 10 00 3A 00 01"))
    m.write(MAX_SPEED_PA12, 1400)  # changed after the save: not persisted
    assert d.stop() == 0
    assert state.exists()

    d = start_drive("--no-status", "--state", str(state))
    m = Master(d.client("tcp"))
    assert m.read(MAX_SPEED_PA12) == 1500
    assert m.read(ACCELERATION) == 321


def test_without_a_save_nothing_survives(start_drive, tmp_path):
    state = tmp_path / "drive.flash"
    d = start_drive("--no-status", "--state", str(state))
    m = Master(d.client("tcp"))
    m.write(MAX_SPEED_PA12, 1500)
    assert d.stop() == 0
    d = start_drive("--no-status", "--state", str(state))
    assert Master(d.client("tcp")).read(MAX_SPEED_PA12) == 3000


def test_each_drive_keeps_its_own_saved_parameters(start_drive, tmp_path):
    state = tmp_path / "drives.flash"
    d = start_drive("--no-status", "--state", str(state), "--drives", "1,2")
    c = d.client("tcp")
    Master(c, 1).write(MAX_SPEED_PA12, 1001)
    Master(c, 2).write(MAX_SPEED_PA12, 1002)
    with d.raw("tcp") as bus:
        for addr in (1, 2):
            ee_set = with_crc(bytes([addr]) + EE_SET[1:-2])
            assert bus.exchange(ee_set, timeout=3) == with_crc(ee_set[:6])
    assert d.stop() == 0
    d = start_drive("--no-status", "--state", str(state), "--drives", "1,2")
    c = d.client("tcp")
    assert Master(c, 1).read(MAX_SPEED_PA12) == 1001
    assert Master(c, 2).read(MAX_SPEED_PA12) == 1002


def test_a_failed_flash_answers_exception_4(start_drive, tmp_path):
    """SPEC §5.2 step 10: the state file is the flash; replaced by a
    directory it cannot be written, and EE-Set gets exception 4."""
    state = tmp_path / "drive.flash"
    d = start_drive("--no-status", "--state", str(state))
    os.remove(state)
    os.mkdir(state)
    with d.raw("tcp") as bus:
        assert bus.exchange(EE_SET, timeout=3) == with_crc(hexb("01 90 04"))
    assert "EE operation Save failed" in d.stderr()


def test_requests_during_an_ee_operation_get_exception_6(start_drive, tmp_path):
    """SPEC §5.2 step 9, §9: while an EE operation runs (until its reply has
    left) other requests get exception 6. PA56 = 100 ms holds the reply long
    enough for a second master on another connection to ask."""
    d = start_drive("--no-status", "--state", str(tmp_path / "drive.flash"))
    Master(d.client("tcp")).write(RESPONSE_DELAY_PA56, 100)
    with d.raw("tcp") as a, d.raw("tcp") as b:
        t0 = time.monotonic()
        a.write(EE_SET)
        time.sleep(0.02)
        assert b.exchange(with_crc(hexb("01 03 60 41 00 01"))) == with_crc(hexb("01 83 06"))
        assert a.read_reply(timeout=2) == with_crc(hexb("01 10 00 3A 00 01"))
        assert time.monotonic() - t0 >= 0.1
        # once answered, the drive is no longer busy
        assert b.exchange(with_crc(hexb("01 03 60 41 00 01")))[:3] == hexb("01 03 02")
