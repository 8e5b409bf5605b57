#!/usr/bin/env python3
"""Check a firmware ELF against its chip's memories as the datasheet gives them.

The chip facts below are typed from the datasheets (DS5319 for the
STM32F103C8, DS12589 / RM0440 for the STM32G431CB), not read from the
linker's memory-*.x files: the point is to catch a build that linked with the
wrong map. The parameter pages are the ones the boards' `PARAM_FLASH_START`
reserve (src/firmware/board_*.rs).

Checks, each printed:
  * the vector table sits at the flash origin;
  * every allocated section, every load image (.data's copy in flash) and
    every symbol in flash lies below the parameter pages;
  * every allocated section and symbol in RAM lies inside SRAM;
  * the initial stack pointer (vector table word 0) is `_stack_start`, is
    8-byte aligned, and tops a stack region [_stack_end, _stack_start) inside
    SRAM that no static section overlaps.

Usage: memory_map.py CHIP ELF   (CHIP: stm32f103c8 | stm32g431cb)
Exit status 1 when any check fails.
"""
import struct
import sys

KIB = 1024
CHIPS = {
    # flash origin, flash size, first parameter page, SRAM origin, SRAM size
    "stm32f103c8": dict(flash=0x0800_0000, flash_len=64 * KIB, params=0x0800_F000,
                        sram=0x2000_0000, sram_len=20 * KIB),
    # SRAM1 16 KiB + SRAM2 6 KiB, then the 10 KiB CCM SRAM aliased at
    # 0x2000_5800: 32 KiB contiguous
    "stm32g431cb": dict(flash=0x0800_0000, flash_len=128 * KIB, params=0x0801_F000,
                        sram=0x2000_0000, sram_len=32 * KIB),
}

SHF_ALLOC = 0x2
PT_LOAD = 1
SHT_SYMTAB = 2
SHN_UNDEF = 0


def read_elf(path):
    data = open(path, "rb").read()
    if data[:4] != b"\x7fELF" or data[4] != 1 or data[5] != 1:
        raise SystemExit(f"{path}: not a 32-bit little-endian ELF")
    (e_phoff, e_shoff) = struct.unpack_from("<II", data, 28)
    (e_phentsize, e_phnum, e_shentsize, e_shnum, e_shstrndx) = struct.unpack_from("<HHHHH", data, 42)
    sections = []
    for i in range(e_shnum):
        sh = struct.unpack_from("<IIIIIIIIII", data, e_shoff + i * e_shentsize)
        sections.append(dict(name_off=sh[0], type=sh[1], flags=sh[2], addr=sh[3], offset=sh[4],
                             size=sh[5], link=sh[6]))
    strtab = sections[e_shstrndx]

    def cstr(off):
        end = data.index(b"\0", off)
        return data[off:end].decode()

    for s in sections:
        s["name"] = cstr(strtab["offset"] + s["name_off"])
    segments = []
    for i in range(e_phnum):
        ph = struct.unpack_from("<IIIIIIII", data, e_phoff + i * e_phentsize)
        segments.append(dict(type=ph[0], offset=ph[1], vaddr=ph[2], paddr=ph[3], filesz=ph[4], memsz=ph[5]))
    symbols = {}
    for s in sections:
        if s["type"] != SHT_SYMTAB:
            continue
        names = sections[s["link"]]
        for j in range(s["size"] // 16):
            name_off, value, _size, _info, _other, shndx = struct.unpack_from("<IIIBBH", data, s["offset"] + j * 16)
            if shndx == SHN_UNDEF or name_off == 0:
                continue
            symbols[cstr(names["offset"] + name_off)] = value
    return data, sections, segments, symbols


def main():
    if len(sys.argv) != 3 or sys.argv[1] not in CHIPS:
        raise SystemExit(__doc__)
    chip, path = CHIPS[sys.argv[1]], sys.argv[2]
    data, sections, segments, symbols = read_elf(path)
    flash, params = chip["flash"], chip["params"]
    sram, sram_end = chip["sram"], chip["sram"] + chip["sram_len"]
    failures = []

    def check(ok, what):
        print(f"  {'ok  ' if ok else 'FAIL'} {what}")
        if not ok:
            failures.append(what)

    def in_flash(a):
        return flash <= a < flash + chip["flash_len"]

    def in_ram_space(a):
        return 0x2000_0000 <= a < 0x4000_0000

    print(f"{path} against {sys.argv[1]}: flash 0x{flash:08x}, parameter pages from 0x{params:08x}, "
          f"SRAM 0x{sram:08x}..0x{sram_end:08x}")
    by_name = {s["name"]: s for s in sections}
    vt = by_name.get(".vector_table")
    check(vt is not None and vt["addr"] == flash, f".vector_table at the flash origin 0x{flash:08x}")

    ram_sections = []
    for s in sections:
        if not s["flags"] & SHF_ALLOC or s["size"] == 0:
            continue
        lo, hi = s["addr"], s["addr"] + s["size"]
        if in_flash(lo):
            check(hi <= params, f"{s['name']} 0x{lo:08x}..0x{hi:08x} below the parameter pages")
        elif in_ram_space(lo):
            ram_sections.append((lo, hi))
            check(sram <= lo and hi <= sram_end, f"{s['name']} 0x{lo:08x}..0x{hi:08x} inside SRAM")
        else:
            check(False, f"{s['name']} at 0x{lo:08x} is in neither flash nor SRAM")
    for seg in segments:
        if seg["type"] == PT_LOAD and seg["filesz"]:
            lo, hi = seg["paddr"], seg["paddr"] + seg["filesz"]
            check(flash <= lo and hi <= params,
                  f"load image 0x{lo:08x}..0x{hi:08x} (loaded to 0x{seg['vaddr']:08x}) below the parameter pages")

    # End markers may equal a region's end, so bounds are inclusive here.
    stray = [(n, v) for n, v in symbols.items()
             if (in_flash(v) and v > params) or (in_ram_space(v) and not sram <= v <= sram_end)]
    check(not stray, "every symbol in flash below the parameter pages and every symbol in RAM inside SRAM"
          + "".join(f"\n         {n} = 0x{v:08x}" for n, v in sorted(stray, key=lambda x: x[1])[:10]))

    sp = struct.unpack_from("<I", data, vt["offset"])[0] if vt else None
    top, bottom = symbols.get("_stack_start"), symbols.get("_stack_end")
    check(sp is not None and sp == top, f"initial stack pointer {sp and hex(sp)} is _stack_start {top and hex(top)}")
    if top is not None:
        check(top % 8 == 0, "initial stack pointer 8-byte aligned")
        bottom = sram if bottom is None else bottom
        check(sram <= bottom < top <= sram_end,
              f"stack region 0x{bottom:08x}..0x{top:08x} inside SRAM")
        overlap = [(lo, hi) for lo, hi in ram_sections if lo < top and hi > bottom]
        check(not overlap, "no static section inside the stack region")
    if failures:
        print(f"{path}: {len(failures)} memory-map check(s) FAILED")
        return 1
    print(f"{path}: memory map ok")
    return 0


if __name__ == "__main__":
    sys.exit(main())
