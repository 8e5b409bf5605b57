"""Bus behaviour end to end: exceptions (SPEC §5.2, §3), framing (SPEC §1),
broadcast and several drives on one bus (SPEC §2)."""

import time

import pytest

from conftest import (ACCELERATION, ACTUAL_POSITION, CONTROLWORD, DECELERATION, MODE,
                      MOTOR_RUNNING, PROFILE_VELOCITY, TARGET_POSITION,
                      TARGET_REACHED, Master,
                      hexb, with_crc)

NO_REPLY_WAIT_S = 0.3


def exception(addr: int, function: int, code: int) -> bytes:
    return with_crc(bytes([addr, function | 0x80, code]))


# One request per exception code the bus can produce over a pty or TCP.
# 9 (parity) cannot: neither carries parity bits, so no byte ever has a
# parity error; the slave's unit tests cover it. 4 and 6 come from the parameter
# storage (test_state.py).
EXCEPTIONS = [
    (1, "01 05 00 00 FF 00", "function 0x05 is not supported"),
    (2, "01 03 60 81 00 01", "the range ends inside the 2-word 0x6081"),
    (3, "01 06 60 60 00 02", "mode 2 is not one of 1, 3, 6"),
    (3, "01 03 60 41 00 00", "quantity 0"),
    (5, "01 06 60 41 00 01", "0x6041 is read-only"),
    (7, "01 03 60 40 00 01", "0x6040 is write-only"),
    (8, "01 10 60 83 00 02 02 00 64", "byte count 2 for 2 registers"),
    (8, "01 06 60 81 00 01", "0x06 on a 2-word entry"),
    (11, "01 03 60 42 00 01", "0x6042 does not exist"),
]


@pytest.mark.parametrize("code,body,why", EXCEPTIONS, ids=[f"{c}-{w}" for c, _, w in EXCEPTIONS])
def test_exception_codes(start_drive, transport, code, body, why):
    d = start_drive("--no-status")
    with d.raw(transport) as bus:
        req = with_crc(hexb(body))
        assert bus.exchange(req) == exception(1, req[1], code), why


def test_crc_error_gets_code_10_by_default_and_silence_in_strict_mode(start_drive, transport):
    d = start_drive("--no-status")
    with d.raw(transport) as bus:
        crc_error_gets_code_10_then_silence_with_pa54_0(bus)


def crc_error_gets_code_10_then_silence_with_pa54_0(bus):
    """The test above on any drive's raw line (the firmware under emulation
    runs it too)."""
    bad = bytearray(with_crc(hexb("01 03 60 41 00 01")))
    bad[-1] ^= 0xFF
    assert bus.exchange(bytes(bad)) == exception(1, 0x03, 10)  # SPEC §3, PA54 = 1
    # PA54 = 0 (legacy map 0x0064 + 54): strict Modbus, silent.
    pa54 = with_crc(hexb("01 06 00 9A 00 00"))
    assert bus.exchange(pa54) == pa54
    assert bus.exchange(bytes(bad), timeout=NO_REPLY_WAIT_S) == b""


def test_standard_exception_profile_maps_vendor_codes(start_drive, transport):
    """PA55 = 1: 11 → 2 (SPEC §5.2)."""
    d = start_drive("--no-status")
    with d.raw(transport) as bus:
        pa55 = with_crc(hexb("01 06 00 9B 00 01"))
        assert bus.exchange(pa55) == pa55
        assert bus.exchange(with_crc(hexb("01 03 60 42 00 01"))) == exception(1, 0x03, 2)


def test_frames_for_others_short_frames_and_split_frames(start_drive, transport):
    d = start_drive("--no-status")
    with d.raw(transport) as bus:
        read = hexb("03 60 41 00 01")
        assert bus.exchange(with_crc(b"\x02" + read), timeout=NO_REPLY_WAIT_S) == b""
        assert bus.exchange(with_crc(b"\xF8" + read), timeout=NO_REPLY_WAIT_S) == b""
        assert bus.exchange(hexb("01 03 60"), timeout=NO_REPLY_WAIT_S) == b""
        # Silence >= t3.5 (1750 µs at 115200) ends a frame (SPEC §1): a request
        # written in two parts 20 ms apart is two frames. The first (own
        # address, bad CRC) gets exception 10; the second (address byte 0x00,
        # a broadcast with a bad CRC) is never answered.
        frame = with_crc(b"\x01" + read)
        bus.write(frame[:4])
        time.sleep(0.02)
        bus.write(frame[4:])
        assert bus.read_reply(timeout=NO_REPLY_WAIT_S) == exception(1, 0x03, 10)
        # …and the line recovers for the next frame.
        assert bus.exchange(frame)[:3] == hexb("01 03 02")
    err = d.stderr()
    assert "shorter than 4 bytes" in err and "CRC error" in err


def test_broadcast_reaches_every_drive_and_none_answers(start_drive, transport):
    d = start_drive("--no-status", "--drives", "1,2")
    with d.raw(transport) as bus:
        write = with_crc(hexb("00 06 60 83 00 C8"))  # 0x6083 = 200 to all
        assert bus.exchange(write, timeout=NO_REPLY_WAIT_S) == b""
        write32 = with_crc(hexb("00 10 60 7A 00 02 04 00 01 86 A0"))  # 0x607A = 100000
        assert bus.exchange(write32, timeout=NO_REPLY_WAIT_S) == b""
        # A broadcast read is ignored: no reply.
        assert bus.exchange(with_crc(hexb("00 03 60 83 00 01")), timeout=NO_REPLY_WAIT_S) == b""
        for addr in (1, 2):
            got = bus.exchange(with_crc(bytes([addr]) + hexb("03 60 83 00 01")))
            assert got == with_crc(bytes([addr]) + hexb("03 02 00 C8")), addr
            got = bus.exchange(with_crc(bytes([addr]) + hexb("03 60 7A 00 02")))
            assert got == with_crc(bytes([addr]) + hexb("03 04 00 01 86 A0")), addr


def test_two_drives_on_one_bus_have_their_own_axes(start_drive, transport):
    d = start_drive("--no-status", "--drives", "1,2")
    c = d.client(transport)
    one, two = Master(c, 1), Master(c, 2)
    # seed 000 §7.3's example addresses drive 2
    with d.raw(transport) as bus:
        req = with_crc(hexb("02 06 60 60 00 03"))
        assert bus.exchange(req) == req
    two.enable()
    two.write(MODE, 1)
    two.write32(PROFILE_VELOCITY, 100)
    two.write(ACCELERATION, 1000)
    two.write(DECELERATION, 1000)
    two.write32(TARGET_POSITION, 50000)
    two.write(CONTROLWORD, 0x001F)
    two.wait(lambda s: s & TARGET_REACHED and not s & MOTOR_RUNNING, 5, "drive 2 at target")
    assert two.read32(ACTUAL_POSITION) == 50000
    assert one.read32(ACTUAL_POSITION) == 0, "drive 1 did not move"
    assert one.statusword() & 0x6F == 0x60, "drive 1 still switch on disabled"
