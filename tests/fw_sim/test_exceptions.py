"""Exception entry and return (ARMv7-M ARM B1.5.6, B1.5.8) where the
firmware's nested interrupts need them exact: a hand-assembled image whose
low-priority handler is preempted by a priority-0 interrupt in the middle
of an IT block (and, on the M4F, with a live FP context). Entry must clear
the IT state for the handler (EPSR.IT = 0) and stack it; return must
restore it, so the rest of the IT block stays conditional; the FP context
must come back as it was. The image stops on a UDF when anything is off,
which fw-sim reports with a non-zero exit."""

import struct
import subprocess

import pytest

from conftest import SIM

FLASH = 0x0800_0000
NOP_W = (0xF3AF, 0x8000)  # stands in for a VMOV on the F103 (no FPU)


def _code(fpu: bool) -> bytes:
    """The image's flash contents (assembled with llvm-mc, encodings below).

    Reset (0x100): IRQ0 at priority 0x80, IRQ1 at 0; both enabled; IRQ0
    pended; after IRQ0 returns, the word at 0x2000_0000 must be 0x600D.
    irq_a (IRQ0): pends IRQ1, then an IT block of four NE-moves with Z set
    (all skipped), placed across the 4 KiB boundary at 0x1000 so that the
    emulator's translation block (and so the point where it takes the
    pending interrupt) ends after the first one: IRQ1 preempts with three
    IT slots left. Then r5 must be 0 (the rest stayed skipped), r7 0x55
    (IRQ1's first instruction ran) and s0 irq_a's value.
    irq_b (IRQ1): r7 = 0x55 with a 32-bit MOV (skipped if it inherited the
    IT state), s0 overwritten, return; UDFs after it catch a skipped BX.
    """
    mem = bytearray(0x1040)
    struct.pack_into("<II", mem, 0, 0x2000_1000, FLASH + 0x101)
    struct.pack_into("<II", mem, 0x40, FLASH + 0xFE9, FLASH + 0x1029)  # IRQ0, IRQ1

    def put(at: int, hws: list[int]):
        struct.pack_into(f"<{len(hws)}H", mem, at, *hws)

    put(0x100, [
        0x4809,          # ldr r0, =0xE000E400 (IPR0)
        0x2180,          # movs r1, #0x80
        0x6001,          # str r1, [r0]
        0x4809,          # ldr r0, =0xE000E100 (ISER0)
        0x2103,          # movs r1, #3
        0x6001,          # str r1, [r0]
        0x4808,          # ldr r0, =0xE000E200 (ISPR0)
        0x2101,          # movs r1, #1
        0x6001,          # str r1, [r0]
        0xE7FF,          # b 0x114 (IRQ0 is taken here)
        0xF04F, 0x5000,  # mov.w r0, #0x20000000
        0x6801,          # ldr r1, [r0]
        0xF246, 0x020D,  # movw r2, #0x600D
        0x4291,          # cmp r1, r2
        0xD100,          # bne 0x124
        0xE7FE,          # b .
        0xDE00,          # udf #0
    ])
    struct.pack_into("<III", mem, 0x128, 0xE000_E400, 0xE000_E100, 0xE000_E200)
    vmov_s0_r6 = [0xEE00, 0x6A10] if fpu else list(NOP_W)
    vmov_r4_s0 = [0xEE10, 0x4A10] if fpu else [0xEA4F, 0x0406]  # mov.w r4, r6
    vmov_s0_r3 = [0xEE00, 0x3A10] if fpu else list(NOP_W)
    put(0xFE8, [
        0x2500,          # movs r5, #0
        0x2700,          # movs r7, #0
        0xF241, 0x2634,  # movw r6, #0x1234
        *vmov_s0_r6,     # vmov s0, r6
        0x480B,          # ldr r0, =0xE000E200 (ISPR0)
        0x2102,          # movs r1, #2
        0x6001,          # str r1, [r0]  (pends IRQ1)
        0x4280,          # cmp r0, r0
        0xBF1F,          # itttt ne
        0x2501,          # movne r5, #1  (0xFFE)
        0x2502,          # movne r5, #2  (0x1000: IRQ1 is taken here)
        0x2503,          # movne r5, #3
        0x2504,          # movne r5, #4
        0x2D00,          # cmp r5, #0
        0xD10B,          # bne 0x1022 (udf #1)
        0x2F55,          # cmp r7, #0x55
        0xD109,          # bne 0x1022
        *vmov_r4_s0,     # vmov r4, s0
        0x42B4,          # cmp r4, r6
        0xD105,          # bne 0x1022
        0xF04F, 0x5000,  # mov.w r0, #0x20000000
        0xF246, 0x010D,  # movw r1, #0x600D
        0x6001,          # str r1, [r0]
        0x4770,          # bx lr
        0xDE01,          # udf #1
    ])
    struct.pack_into("<I", mem, 0x1024, 0xE000_E200)
    assert struct.unpack_from("<H", mem, 0x1022)[0] == 0xDE01
    put(0x1028, [
        0xF04F, 0x0755,  # mov.w r7, #0x55
        0xF244, 0x3321,  # movw r3, #0x4321
        *vmov_s0_r3,     # vmov s0, r3
        0x4770,          # bx lr
        0xDE02, 0xDE02, 0xDE02,  # udf #2
    ])
    return bytes(mem)


def elf(code: bytes) -> bytes:
    """An ELF32 ARM executable of `code` at the flash origin."""
    ehsize, phsize = 52, 32
    off = ehsize + phsize
    eh = b"\x7fELF\x01\x01\x01" + bytes(9) + struct.pack(
        "<HHIIIIIHHHHHH", 2, 40, 1, FLASH + 0x101, ehsize, 0, 0x0500_0200,
        ehsize, phsize, 1, 40, 0, 0)
    ph = struct.pack("<IIIIIIII", 1, off, FLASH, FLASH, len(code), len(code), 5, 4)
    return eh + ph + code


@pytest.mark.parametrize("board", ["f103", "g431"])
def test_preemption_inside_an_it_block(tmp_path, board):
    path = tmp_path / "nested.elf"
    path.write_bytes(elf(_code(fpu=board == "g431")))
    r = subprocess.run([str(SIM), "--board", board, "--elf", str(path), "--run-for", "0.001"],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 0, r.stderr
