"""Every worked frame of seed 000 (chapters 6 and 7), sent raw in the
manual's order over the pty and over TCP, and its reply compared byte for
byte (SPEC §10)."""

import pytest

from conftest import crc16, hexb, with_crc


def echo(frame: str) -> str:
    """0x06 replies echo the request (Modbus application protocol §6.6)."""
    return frame


def ack10(frame: str) -> str:
    """0x10 replies: address, function, start, quantity (SPEC §10)."""
    return with_crc(hexb(frame)[:6]).hex(" ").upper()


def crc_error(frame: str) -> str:
    """SPEC §3 with PA54 = 1 (default): exception 10, function | 0x80."""
    b = hexb(frame)
    return with_crc(bytes([b[0], b[1] | 0x80, 0x0A])).hex(" ").upper()


# (request, expected reply), in the manual's order. Frames SPEC §10 calls
# misprinted are CRC errors on the wire.
SEED_000 = [
    # 6.1 position mode: the 9-register write of the introduction
    ("01 10 60 40 00 09 12 00 0F 00 01 00 00 00 64 00 64 00 64 00 64 00 03 0D 40 40 1C",
     "01 10 60 40 00 09 1F DB"),
    ("01 06 60 83 00 64 67 C9", None),
    ("01 06 60 84 00 64 D6 08", None),
    # 0x607A = 200000 with 0x6000 = 0, and read back (also chapter 7.2)
    ("01 10 60 7A 00 02 04 00 03 0D 40 29 96", "01 10 60 7A 00 02 7E 11"),
    ("01 03 60 7A 00 02 FB D2", "01 03 04 00 03 0D 40 0F 53"),
    # switch to low word first (not a seed frame: the manual only says "if 0x6000 = 1")
    ("01 06 60 00 00 01 " + with_crc(hexb("01 06 60 00 00 01"))[-2:].hex(" "), None),
    ("01 03 60 7A 00 02 FB D2", "01 03 04 0D 40 00 03 B9 4A"),
    ("01 10 60 7A 00 02 04 0D 40 00 03 9F 8F", "01 10 60 7A 00 02 7E 11"),
    ("01 03 60 7A 00 02 FB D2", "01 03 04 0D 40 00 03 B9 4A"),
    ("01 06 60 00 00 00 " + with_crc(hexb("01 06 60 00 00 00"))[-2:].hex(" "), None),
    ("01 03 60 7A 00 02 FB D2", "01 03 04 00 03 0D 40 0F 53"),
    # position mode example program
    ("01 06 60 40 00 01 57 DE", None),
    ("01 06 60 40 00 03 D6 1F", None),
    ("01 06 60 40 00 0F D6 1A", None),
    ("01 06 60 60 00 01 56 14", None),
    ("01 10 60 81 00 02 04 00 00 0A 12 06", "crc"),
    ("01 06 60 83 00 64 67 C9", None),
    ("01 06 60 84 00 64 D6 08", None),
    ("01 10 60 81 00 04 08 00 00 0A 00 64 00 64 10 52", "crc"),
    ("01 10 60 7A 00 02 04 00 03 0D 40 29 96", "01 10 60 7A 00 02 7E 11"),
    ("01 06 60 40 00 1F D7 D6", None),
    ("01 06 60 40 00 0F D6 1A", None),
    ("01 10 60 81 00 02 04 00 00 00 32 13 D4", "ack"),
    ("01 10 60 7A 00 02 04 00 03 0D 40 29 96", "01 10 60 7A 00 02 7E 11"),
    ("01 06 60 40 00 1F D7 D6", None),
    ("01 06 60 40 00 0F D6 1A", None),
    ("01 10 60 81 00 02 04 00 00 00 64 93 EA", "ack"),
    ("01 10 60 7A 00 02 04 00 09 27 C0 17 54", "ack"),
    ("01 06 60 40 00 1F D7 D6", None),
    ("01 06 60 40 02 5F D7 46", None),
    ("01 06 60 40 02 4F D6 8A", None),
    ("01 06 60 40 00 7F D7 FE", None),
    ("01 06 60 40 00 6F D6 32", None),
    ("01 06 60 40 02 7F D6 9E", None),
    # 6.2 velocity mode
    ("01 06 60 60 00 03 D7 D5", None),
    ("01 06 60 40 01 0F D7 8A", None),
    ("01 10 60 81 00 02 04 00 00 0A 64 93 EA", "crc"),
    ("01 06 60 40 00 0F D6 1A", None),
    ("01 06 60 40 01 0F D7 8A", None),
    # 6.3 homing mode
    ("01 06 60 60 00 06 17 D6", None),
    ("01 06 60 98 00 01 D7 E5", None),
    ("01 06 60 9A 03 E8 B7 5B", None),
    ("01 10 60 99 00 02 04 00 00 00 64 93 40", "ack"),
    ("01 10 60 9B 00 02 04 00 00 00 64 12 99", "ack"),
    ("01 10 60 7C 00 02 04 00 00 03 E8 5C 62", "ack"),
    ("01 10 60 7C 00 08 10 00 00 03 E8 00 01 00 00 00 64 03 E8 00 00 00 64 09 42", "ack"),
    ("01 06 60 40 01 1F D6 46", None),
    # 7.4 (reply corrected by SPEC §10) and 7.5
    ("01 10 60 83 00 02 04 00 64 00 64 53 EC", "01 10 60 83 00 02 AE 20"),
    ("01 06 60 90 00 03 D7 E6", "01 86 0B 03 A7"),
]


def expected(req: str, rep):
    if rep is None:
        return hexb(echo(req))
    if rep == "ack":
        return hexb(ack10(req))
    if rep == "crc":
        return hexb(crc_error(req))
    return hexb(rep)


def test_the_table_itself_has_the_crcs_the_spec_says():
    """Guards the test data: exactly the three frames of SPEC §10 are bad."""
    bad = [req for req, _ in SEED_000 if crc16(hexb(req)) != 0]
    assert bad == [
        "01 10 60 81 00 02 04 00 00 0A 12 06",
        "01 10 60 81 00 04 08 00 00 0A 00 64 00 64 10 52",
        "01 10 60 81 00 02 04 00 00 0A 64 93 EA",
    ]
    for req, rep in SEED_000:
        assert crc16(expected(req, rep)) == 0, rep


def test_every_worked_frame_gets_the_manuals_reply(start_drive, transport):
    d = start_drive("--no-status")
    with d.raw(transport) as bus:
        for req, rep in SEED_000:
            got = bus.exchange(hexb(req))
            assert got.hex(" ").upper() == expected(req, rep).hex(" ").upper(), f"request {req}"


@pytest.mark.parametrize("order,frame,reply", [
    (0, "01 10 60 7A 00 02 04 00 03 0D 40 29 96", "01 03 04 00 03 0D 40 0F 53"),
    (1, "01 10 60 7A 00 02 04 0D 40 00 03 9F 8F", "01 03 04 0D 40 00 03 B9 4A"),
])
def test_both_word_orders_store_200000(start_drive, transport, order, frame, reply):
    """SPEC §5.1: both seed frames set 0x607A = 200000."""
    d = start_drive("--no-status")
    with d.raw(transport) as bus:
        if order:
            bus.exchange(with_crc(hexb("01 06 60 00 00 01")))
        assert bus.exchange(hexb(frame)) == hexb("01 10 60 7A 00 02 7E 11")
        assert bus.exchange(hexb("01 03 60 7A 00 02 FB D2")) == hexb(reply)
