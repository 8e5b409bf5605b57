"""The RS-485 driver enable lead and tail, PA57 / PA58 (docs/firmware.md,
"RS-485 driver enable"), measured on the emulated DE pin of both images
(`--trace-line`): DE rises at least the lead before a reply's first start
bit and falls at least the tail after its last stop bit, at the default (one
bit time: the G431's DEAT / DEDT) and beyond what DEAT / DEDT can time
(three bit times: a GPIO on both boards); a change takes effect after the
reply to the write that made it; a write out of range gets exception 3.

Times are compared in bit times of the line as the trace shows it (the
spacing of the reply's back-to-back characters, 10 bits each at 8N1), the
unit PA57 / PA58 are given in."""

import csv
import time

from conftest import PA_BASE, STATUSWORD, Master

PA57, PA58 = PA_BASE + 57, PA_BASE + 58
# slack for the time between the firmware's decision and the pin: a reply
# whose DE is held this much longer than asked fails
SLACK_BITS = 5


def replies(path):
    """(DE rise, first start bit, end of last stop bit, DE fall, bit time)
    of each reply, in ns."""
    rows = list(csv.DictReader(open(path)))
    edges = sorted((int(r["time_ns"]), int(r["value"])) for r in rows if r["event"] == "de")
    tx = sorted(int(r["time_ns"]) for r in rows if r["event"] == "tx")
    assert [v for _, v in edges] == [1, 0] * (len(edges) // 2), f"DE edges {edges}"
    out = []
    for (rise, _), (fall, _) in zip(edges[0::2], edges[1::2]):
        chars = [t for t in tx if rise <= t <= fall]
        assert len(chars) >= 2, f"a reply inside DE {rise}..{fall}"
        char_ns = (chars[-1] - chars[0]) / (len(chars) - 1)
        out.append((rise, chars[0], chars[-1] + char_ns, fall, char_ns / 10))
    return out


def test_de_lead_and_tail_at_least_as_configured(start_fw, board, tmp_path):
    line = tmp_path / "line.csv"
    fw = start_fw(board, "--trace-line", str(line))
    m = Master(fw.client())
    # (lead, tail) in force for each reply, in bit times
    want = []
    assert (m.read(PA57), m.read(PA58)) == (1, 1)
    want += [(1, 1), (1, 1)]
    # out of range: exception 3 (its 5-byte reply is measured too), nothing
    # stored
    for reg, v in ((PA57, 21), (PA58, 0xFFFF)):
        r = m.c.write_register(reg, v, device_id=1)
        assert r.isError() and r.exception_code == 3, f"{board}: PA{reg - PA_BASE} = {v}: {r}"
        want.append((1, 1))
    assert (m.read(PA57), m.read(PA58)) == (1, 1)
    want += [(1, 1), (1, 1)]
    m.write(PA57, 3)  # its reply still at (1, 1)
    want.append((1, 1))
    m.write(PA58, 3)  # lead 3 in force, tail not yet
    want.append((3, 1))
    for _ in range(2):
        m.read(STATUSWORD)
        want.append((3, 3))
    assert (m.read(PA57), m.read(PA58)) == (3, 3)
    want += [(3, 3), (3, 3)]
    time.sleep(0.2)  # the last DE fall is written once emulated time reaches it
    fw.alive()
    got = replies(line)
    assert len(got) == len(want), f"{board}: {len(got)} replies on DE, {len(want)} sent"
    for i, ((rise, first, end, fall, bit), (lead, tail)) in enumerate(zip(got, want)):
        lead_bits, tail_bits = (first - rise) / bit, (fall - end) / bit
        print(f"{board} reply {i}: PA57 {lead} PA58 {tail}: "
              f"lead {lead_bits:.2f} bits, tail {tail_bits:.2f} bits")
        # the trace rounds each time to the ns
        assert first - rise >= lead * bit - 2, f"{board} reply {i}: lead {lead_bits:.2f} bits"
        assert fall - end >= tail * bit - 2, f"{board} reply {i}: tail {tail_bits:.2f} bits"
        assert lead_bits < lead + SLACK_BITS and tail_bits < tail + SLACK_BITS, \
            f"{board} reply {i}: DE held too long"
