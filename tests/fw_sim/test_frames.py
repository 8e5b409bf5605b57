"""Both firmware images on the bus: every worked frame of seed 000 byte for
byte (SPEC §10), the exception codes of SPEC §5.2 / §3 and addressing
(SPEC §2), on the emulated USART at 115200 baud."""


from conftest import NO_REPLY_WAIT_S, e2e_module, hexb, with_crc

seed = e2e_module("test_seed_frames")
bus_tests = e2e_module("test_bus")


def exception(addr: int, function: int, code: int) -> bytes:
    return with_crc(bytes([addr, function | 0x80, code]))


def test_every_worked_frame_gets_the_manuals_reply(start_fw, board):
    fw = start_fw(board)
    with fw.raw() as bus:
        for req, rep in seed.SEED_000:
            got = bus.exchange(hexb(req))
            want = seed.expected(req, rep)
            assert got.hex(" ").upper() == want.hex(" ").upper(), f"{board}: request {req}"


def test_exception_codes(start_fw, board):
    fw = start_fw(board)
    with fw.raw() as bus:
        for code, body, why in bus_tests.EXCEPTIONS:
            req = with_crc(hexb(body))
            assert bus.exchange(req) == exception(1, req[1], code), f"{board}: {why}"


def test_bad_crc_gets_exception_10(start_fw, board):
    fw = start_fw(board)
    with fw.raw() as bus:
        bus_tests.crc_error_gets_code_10_then_silence_with_pa54_0(bus)


def test_other_addresses_and_broadcast_get_no_reply(start_fw, board):
    fw = start_fw(board)
    with fw.raw() as bus:
        read = hexb("03 60 83 00 01")
        assert bus.exchange(with_crc(b"\x02" + read), timeout=NO_REPLY_WAIT_S) == b""
        assert bus.exchange(with_crc(b"\xF8" + read), timeout=NO_REPLY_WAIT_S) == b""
        # a broadcast write is done and not answered (SPEC §2)
        assert bus.exchange(with_crc(hexb("00 06 60 83 00 C8")), timeout=NO_REPLY_WAIT_S) == b""
        assert bus.exchange(with_crc(b"\x01" + read)) == with_crc(hexb("01 03 02 00 C8"))


def test_line_faults_reach_the_firmware_through_the_usart_flags(start_fw, board):
    """`--noise`: a parity error on a character of a request for us gets
    exception 9 (SPEC §3, line 8E1 by PA53 = 1); a framing error or a break
    breaks the frame: no reply; the next clean frame is answered. Characters
    are counted from the first one the master sends."""
    read = with_crc(hexb("01 03 60 41 00 01"))  # 8 characters
    pa53 = with_crc(hexb("01 06 00 99 00 01"))  # 8E1, after this reply
    fw = start_fw(board, "--noise", "parity@12,framing@20,break@36")
    with fw.raw() as bus:
        assert bus.exchange(pa53) == pa53                      # characters 1..8
        assert bus.exchange(read) == exception(1, 0x03, 9)     # 9..16, parity on 12
        assert bus.exchange(read, timeout=NO_REPLY_WAIT_S) == b""  # 17..24, framing on 20
        assert bus.exchange(read)[:3] == hexb("01 03 02")      # 25..32
        assert bus.exchange(read, timeout=NO_REPLY_WAIT_S) == b""  # 33..40, break on 36
        assert bus.exchange(read)[:3] == hexb("01 03 02")      # 41..48
