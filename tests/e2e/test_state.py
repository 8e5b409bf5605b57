"""`--state FILE`: the drive's parameter flash lives in a file, so saved
parameters survive a restart (SPEC §9: EE-Set saves PA0..PA59 and the RW
entries of §5 except 0x607A)."""

from conftest import ACCELERATION, NEEDS_EE_FRAMES, PA_BASE, Master, hexb, with_crc

MAX_SPEED_PA12 = PA_BASE + 12
EE_SET = with_crc(hexb("01 10 00 3A 00 01 02 00 01"))  # new format, k = 1


@NEEDS_EE_FRAMES
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


@NEEDS_EE_FRAMES
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
