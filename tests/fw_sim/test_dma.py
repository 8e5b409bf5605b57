"""The DMA model sees the CPU's memory and the CPU sees the DMA's writes
(fw-sim/src/mem.rs: SRAM is one buffer for both). A hand-assembled image
stores a word in SRAM, lets DMA1 channel 1 copy it memory to memory, loads
the copy and reads the address it names: 0x4000_4400 (USART2, not
modelled), so the runner stops naming exactly that address only if the
word went CPU → SRAM → DMA → SRAM → CPU. Without the copy the load finds 0
and the fault names address 0 instead. Timer-driven DMA (requests, bursts,
HT/TC) is covered by the runner's unit tests (`cd fw-sim && cargo test`).
"""

import struct
import subprocess

import pytest

from conftest import FLASH, SIM, elf_image

# above the image's initial stack pointer: the stack region below it is
# painted at power-on (fw-sim/src/stack.rs), the rest of SRAM reads 0
SRC, DST = 0x2000_1200, 0x2000_1300
MARKER = 0x4000_4400
DMA1_CCR1 = 0x4002_0008
# EN | DIR (memory → "peripheral") | PSIZE = MSIZE = 32 bits | MEM2MEM
CCR = 1 | (1 << 4) | (2 << 8) | (2 << 10) | (1 << 14)


def program(copies: int) -> bytes:
    """Thumb code: each step loads its literals PC-relative, then stores or
    loads; `copies` = 0 leaves the channel's count at 0 (nothing moves)."""
    lits: list[int] = []
    code: list[tuple[str, int, int]] = []  # (op, rt, literal index | rn)

    def lit(rt: int, value: int):
        lits.append(value)
        code.append(("ldr_lit", rt, len(lits) - 1))

    lit(0, SRC)
    lit(1, MARKER)
    code.append(("str", 1, 0))                 # [SRC] = MARKER
    lit(0, DMA1_CCR1)
    lit(1, copies)
    code.append(("str_off", 1, 1))             # CNDTR1
    lit(1, DST)
    code.append(("str_off", 1, 2))             # CPAR1
    lit(1, SRC)
    code.append(("str_off", 1, 3))             # CMAR1
    lit(1, CCR)
    code.append(("str", 1, 0))                 # CCR1: go
    lit(0, DST)
    code.append(("ldr", 1, 0))                 # r1 = [DST]
    code.append(("ldr", 2, 1))                 # r2 = [r1]: the fault
    code.append(("b_self", 0, 0))
    n = len(code) + (len(code) % 2)            # literals word-aligned
    base = FLASH + 8
    pool = base + 2 * n
    out = b""
    for i, (op, rt, x) in enumerate(code):
        pc = base + 2 * i
        if op == "ldr_lit":
            imm = (pool + 4 * x - ((pc + 4) & ~3)) // 4
            out += struct.pack("<H", 0x4800 | (rt << 8) | imm)
        elif op == "str":
            out += struct.pack("<H", 0x6000 | (x << 3) | rt)
        elif op == "str_off":                  # str rt, [r0, #4 * x]
            out += struct.pack("<H", 0x6000 | (x << 6) | rt)
        elif op == "ldr":
            out += struct.pack("<H", 0x6800 | (x << 3) | rt)
        else:
            out += struct.pack("<H", 0xE7FE)
    out += b"\x00\xbf" * (n - len(code))
    return out + b"".join(struct.pack("<I", v) for v in lits)


@pytest.mark.parametrize("board", ["f103", "g431"])
def test_a_memory_to_memory_copy_moves_what_the_cpu_wrote(tmp_path, board):
    path = tmp_path / "dma.elf"
    for copies, named in ((1, MARKER), (0, 0)):
        path.write_bytes(elf_image(program(copies)))
        r = subprocess.run([str(SIM), "--board", board, "--elf", str(path), "--run-for", "0.001"],
                           capture_output=True, text=True, timeout=30)
        assert r.returncode == 1, r.stderr
        assert f"{named:#010x}" in r.stderr, (copies, r.stderr)
