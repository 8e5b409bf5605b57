"""The parameter store through the firmware's own flash driver on both
images: the legacy map's EEPROM operations in the old frame format (SPEC §9:
`addr 06 00 00 00 0k`, the reply echoes the frame once done), each result
surviving a restart of the runner (`--state`), and the two ways an EE
operation fails with exception 4 (SPEC §5.2 step 10): a flash that refuses
to be written (`--write-protect`, the option bytes' write protection) and a
restore from a backup that was never made.

Every frame goes over one raw connection per runner: the runner hands the
line's replies to every connected master, so a second client would find
these replies in its buffer."""

import shutil
import struct
from pathlib import Path

from conftest import PA_BASE, hexb, with_crc

PA12 = PA_BASE + 12  # max speed, r/min
DEFAULT_PA12 = 3000  # SPEC §7
FIXTURES = Path(__file__).resolve().parent / "fixtures"


def old_ee(k: int) -> bytes:
    """Legacy EE command, old format: 1 Set, 2 rd, 3 bA, 4 rS, 5 dEF."""
    return with_crc(bytes([0x01, 0x06, 0x00, 0x00, 0x00, k]))


class Bus:
    def __init__(self, fw):
        self.raw = fw.raw()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.raw.sock.close()

    def ee(self, k: int) -> bytes:
        return self.raw.exchange(old_ee(k), timeout=3)

    def write(self, reg: int, value: int):
        req = with_crc(struct.pack(">BBHH", 1, 6, reg, value))
        assert self.raw.exchange(req) == req, f"write {reg:#06x}"

    def read(self, reg: int) -> int:
        rep = self.raw.exchange(with_crc(struct.pack(">BBHH", 1, 3, reg, 1)))
        assert rep[:3] == bytes([1, 3, 2]) and with_crc(rep[:-2]) == rep, rep.hex(" ")
        return struct.unpack(">H", rep[3:5])[0]


def test_legacy_ee_operations_survive_restarts(start_fw, board, tmp_path):
    """EE-bA keeps a backup, EE-Set saves the working set; after a restart
    the saved set is loaded and EE-rS brings the backup back and saves it;
    after another restart EE-dEF restores the defaults and saves them; a
    third restart shows the defaults."""
    state = tmp_path / f"{board}.flash"
    fw = start_fw(board, "--state", str(state))
    with Bus(fw) as bus:
        bus.write(PA12, 1500)
        assert bus.ee(3) == old_ee(3), f"{board}: EE-bA, echoed once done"
        bus.write(PA12, 1400)
        assert bus.ee(1) == old_ee(1), f"{board}: EE-Set"
    assert fw.stop() is None

    fw = start_fw(board, "--state", str(state))
    with Bus(fw) as bus:
        assert bus.read(PA12) == 1400, f"{board}: the saved set"
        assert bus.ee(4) == old_ee(4), f"{board}: EE-rS"
        assert bus.read(PA12) == 1500, f"{board}: the backup restored"
    assert fw.stop() is None

    fw = start_fw(board, "--state", str(state))
    with Bus(fw) as bus:
        assert bus.read(PA12) == 1500, f"{board}: EE-rS saved the backup"
        assert bus.ee(5) == old_ee(5), f"{board}: EE-dEF"
        assert bus.read(PA12) == DEFAULT_PA12
    assert fw.stop() is None

    fw = start_fw(board, "--state", str(state))
    with Bus(fw) as bus:
        assert bus.read(PA12) == DEFAULT_PA12, f"{board}: EE-dEF saved the defaults"


def test_a_write_protected_flash_answers_exception_4(start_fw, board, tmp_path):
    """The flash controller refuses every erase and program (WRPERR /
    WRPRTERR): EE-Set gets exception 4 in both formats, the working set
    stays as it was, and nothing reached the flash: after a restart without
    the protection the default is back, and a save then works."""
    state = tmp_path / f"{board}.flash"
    # the development image: it logs the core's events (info)
    fw = start_fw(board, "--state", str(state), "--write-protect", dev=True)
    with Bus(fw) as bus:
        bus.write(PA12, 1500)
        new_set = with_crc(hexb("01 10 00 3A 00 01 02 00 01"))
        assert bus.raw.exchange(new_set, timeout=3) == with_crc(hexb("01 90 04")), board
        assert bus.ee(1) == with_crc(hexb("01 86 04")), f"{board}: old format"
        assert bus.read(PA12) == 1500, f"{board}: the working set kept"
    assert "EeDone { op: Save, error: Some(Storage(Flash(" in fw.stderr(), \
        f"{board}: the firmware logs the flash's failure"
    assert fw.stop() is None

    fw = start_fw(board, "--state", str(state))
    with Bus(fw) as bus:
        assert bus.read(PA12) == DEFAULT_PA12, f"{board}: nothing was saved"
        bus.write(PA12, 1500)
        assert bus.ee(1) == old_ee(1), f"{board}: a save works without the protection"


def test_ee_rs_without_a_backup_answers_exception_4(start_fw, board, tmp_path):
    """A restore with no backup ever made: the device cannot perform it
    (docs/parameters.md), the working set is left as it was."""
    fw = start_fw(board, "--state", str(tmp_path / f"{board}.flash"))
    with Bus(fw) as bus:
        bus.write(PA12, 1500)
        assert bus.ee(4) == with_crc(hexb("01 86 04")), board
        assert bus.read(PA12) == 1500


def test_parameters_saved_by_the_firmware_before_the_journal_are_kept(start_fw, board, tmp_path):
    """A board flashed with the firmware that kept its parameters in a
    sequential-storage map (fixtures/make_old_flash.py: PA12 = 1211 saved
    after twelve saves, 1500 in the backup) boots this image: the saved set
    is loaded, the backup is still there for EE-rS, and what EE-rS saves
    (now in the journal) is what the next restart loads."""
    state = tmp_path / f"{board}.flash"
    shutil.copy(FIXTURES / f"{board}-map.flash", state)
    fw = start_fw(board, "--state", str(state))
    with Bus(fw) as bus:
        assert bus.read(PA12) == 1211, f"{board}: the saved set of the old layout"
        assert bus.ee(4) == old_ee(4), f"{board}: EE-rS from the old layout's backup"
        assert bus.read(PA12) == 1500, f"{board}: the backup"
    assert fw.stop() is None

    fw = start_fw(board, "--state", str(state))
    with Bus(fw) as bus:
        assert bus.read(PA12) == 1500, f"{board}: EE-rS saved the backup"
        bus.write(PA12, 1300)
        assert bus.ee(1) == old_ee(1), f"{board}: EE-Set"
    assert fw.stop() is None

    fw = start_fw(board, "--state", str(state))
    with Bus(fw) as bus:
        assert bus.read(PA12) == 1300, f"{board}: the journal's saved set"
