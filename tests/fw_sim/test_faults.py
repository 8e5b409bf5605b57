"""Faults the model must not hide: a tiny hand-assembled image (vector
table, one access, `b .`) per case, run by fw-sim; an access outside the
chip's memories, to an unmodelled peripheral register or a UDF stops the
runner with the address, the program counter named by its symbol and a
non-zero exit. The same access inside the memories runs on."""

import struct
import subprocess

import pytest

from conftest import SIM, elf_image

FLASH = 0x0800_0000
LDR_R0_LIT = 0x4801  # ldr r0, [pc, #4]: the literal at 0x0800_0010
STR_R1_R0 = 0x6001   # str r1, [r0]
LDR_R1_R0 = 0x6801   # ldr r1, [r0]
UDF = 0xDE00
B_SELF = 0xE7FE
NOP = 0xBF00


def image(access: int, addr: int) -> bytes:
    """An ELF32 ARM executable: SP 0x2000_1000, Reset (a FUNC symbol) does
    `access` on `addr` and loops."""
    return elf_image(struct.pack("<4H", LDR_R0_LIT, access, B_SELF, NOP) + struct.pack("<I", addr))


def run(tmp_path, board: str, elf: bytes):
    path = tmp_path / "probe.elf"
    path.write_bytes(elf)
    return subprocess.run([str(SIM), "--board", board, "--elf", str(path), "--run-for", "0.001"],
                          capture_output=True, text=True, timeout=30)


@pytest.mark.parametrize("board,ok", [("f103", False), ("g431", True)])
def test_sram_ends_where_the_chip_says(tmp_path, board, ok):
    """0x2000_5000 is past the F103C8's 20 KiB and inside the G431CB's
    32 KiB (SRAM1 + SRAM2 + CCM alias): the class of bug of an image linked
    with the other chip's map."""
    r = run(tmp_path, board, image(STR_R1_R0, 0x2000_5000))
    if ok:
        assert r.returncode == 0, r.stderr
    else:
        assert r.returncode == 1, r.stderr
        assert "0x20005000" in r.stderr and "outside this chip's memories" in r.stderr
        assert "Reset+0x" in r.stderr, "the program counter named by its symbol"


@pytest.mark.parametrize("board,addr", [("f103", 0x0801_0000), ("g431", 0x0802_0000)])
def test_flash_ends_where_the_chip_says(tmp_path, board, addr):
    r = run(tmp_path, board, image(LDR_R1_R0, addr))
    assert r.returncode == 1, r.stderr
    assert f"{addr:#010x}" in r.stderr, r.stderr


@pytest.mark.parametrize("board", ["f103", "g431"])
def test_an_unmodelled_register_stops_the_runner(tmp_path, board):
    r = run(tmp_path, board, image(LDR_R1_R0, 0x4000_4400))  # USART2
    assert r.returncode == 1, r.stderr
    assert "unmodelled register 0x40004400" in r.stderr
    assert "Reset+0x" in r.stderr


@pytest.mark.parametrize("board", ["f103", "g431"])
def test_udf_stops_the_runner(tmp_path, board):
    r = run(tmp_path, board, image(UDF, 0))
    assert r.returncode == 1, r.stderr
    assert "UDF" in r.stderr and "Reset+0x" in r.stderr
