"""The stack's headroom under emulation (docs/firmware.md, "Sizes"). Both
images put the stack below the statics (flip-link), so an overflow faults
rather than corrupting them, but a fault is still a reset: fw-sim paints
the stack region at power-on (fw-sim/src/stack.rs) and `--stats` reports
the bytes at its far end never written since. After a boot, an EE-Set
and a run at the board's step rate limit into a limit with the master
polling (the boot's `install_device` and the store's save are the
deepest calls, the limit brake's refill the deepest interrupt nesting),
at least HEADROOM bytes were never reached: room for an interrupt's
frames on top of the deepest call."""

from __future__ import annotations

import time

from conftest import LIMITS, Master, hexb, with_crc
from test_io import EE_SET, run_into_the_ccw_limit

HEADROOM = 1024


def untouched(stats) -> int:
    """`stack_untouched` of a `--stats` file, rewritten once more first."""
    time.sleep(0.2)  # fw-sim rewrites the file every 50 ms of wall time
    fields = dict(line.split() for line in stats.read_text().splitlines())
    return int(fields["stack_untouched"])


def test_the_stack_keeps_headroom(start_fw, board, tmp_path):
    rate = LIMITS[board]
    edge = rate * rate // 2_000_000 + 20_000  # up to speed, then a cruise
    stats = tmp_path / "stats"
    fw = start_fw(board, "--ccw-limit", str(edge), "--stats", str(stats))
    m = Master(fw.client())
    booted = untouched(stats)
    assert booted >= HEADROOM, f"{board}: {booted} B of stack never reached after the boot"
    run_into_the_ccw_limit(m, board, rate)
    # the save last: the flash erase it starts stalls the core (the USART
    # loses what arrives meanwhile)
    m.c.close()
    with fw.raw() as bus:
        assert bus.exchange(EE_SET, timeout=3) == with_crc(hexb("01 10 00 3A 00 01"))
    time.sleep(0.5)
    fw.alive()
    left = untouched(stats)
    print(f"{board}: {left} B of stack never reached ({booted} after the boot)")
    assert left >= HEADROOM, f"{board}: {left} B of stack never reached"
