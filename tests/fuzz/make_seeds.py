"""Write the seed corpora in tests/fuzz/seeds/ (valid protocol sequences).

    python tests/fuzz/make_seeds.py
"""

from __future__ import annotations

import struct
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from protocols import serial_link as sl  # noqa: E402

HERE = Path(__file__).resolve().parent / "seeds"


def sdo_rec(d: bytes, sel: int = 4, dt: int = 1) -> bytes:
    return bytes([sel, 8]) + d.ljust(8, b"\0") + bytes([dt])


def up(idx: int, sub: int) -> bytes:
    return sdo_rec(struct.pack("<BHB", 0x40, idx, sub))


def dl(idx: int, sub: int, v: int, n: int) -> bytes:
    return sdo_rec(struct.pack("<BHBI", 0x23 | ((4 - n) << 2), idx, sub, v & 0xFFFFFFFF))


def seg_up(t: int) -> bytes:
    return sdo_rec(bytes([0x60 | (t << 4)]))


def main() -> None:
    s = HERE / "fuzz_sdo"
    s.mkdir(parents=True, exist_ok=True)
    (s / "expedited").write_bytes(up(0x1000, 0) + dl(0x6040, 0, 6, 2) + dl(0x6060, 0, 11, 1)
                                  + up(0x1018, 9) + dl(0x2001, 0, 0x3F000000, 4))
    (s / "segmented_upload").write_bytes(up(0x1008, 0) + seg_up(0) + seg_up(1) + seg_up(0)
                                         + seg_up(1) + seg_up(1))
    txt = b"axis-1 left rail"
    seq = sdo_rec(struct.pack("<BHBI", 0x21, 0x2042, 0, len(txt)))
    t = 0
    for i in range(0, len(txt), 7):
        chunk = txt[i:i + 7]
        last = i + 7 >= len(txt)
        seq += sdo_rec(bytes([(t << 4) | ((7 - len(chunk)) << 1) | int(last)]) + chunk)
        t ^= 1
    (s / "segmented_download").write_bytes(seq)
    (s / "nmt_hb").write_bytes(sdo_rec(bytes([1, 0]), sel=0) + dl(0x1016, 1, 0x10032, 4)
                               + sdo_rec(bytes([5]), sel=0x13, dt=200)
                               + sdo_rec(b"", sel=1) + sdo_rec(b"", sel=3, dt=255))
    p = HERE / "fuzz_pdo"
    p.mkdir(parents=True, exist_ok=True)

    def w(idx: int, sub: int, v: int, n: int) -> bytes:
        return bytes([0]) + struct.pack("<HBBI", idx, sub, n, v & 0xFFFFFFFF)

    remap = (w(0x1400, 1, 0x80000207, 4) + w(0x1600, 0, 0, 1) + w(0x1600, 1, 0x60400010, 4)
             + w(0x1600, 2, 0x60710010, 4) + w(0x1600, 0, 2, 1) + w(0x1400, 1, 0x207, 4)
             + bytes([1, 0x20]) + b"\x0f\x00\x10\x00\0\0\0\0" + bytes([2]) + bytes([3, 10, 0])
             + w(0x1803, 1, 0x80000487, 4) + w(0x1A03, 0, 0, 1) + w(0x1A03, 1, 0x60410010, 4)
             + w(0x1A03, 0, 1, 1) + w(0x1803, 2, 1, 1) + w(0x1803, 1, 0x487, 4) + bytes([2]))
    (p / "remap").write_bytes(remap)
    (p / "event").write_bytes(w(0x1800, 3, 5, 2) + bytes([3, 100, 0]) + bytes([3, 200, 3]))
    a = HERE / "fuzz_app"
    a.mkdir(parents=True, exist_ok=True)

    def arec(sel: int, d: bytes, steps: int = 24, cur: int = 0) -> bytes:
        return bytes([sel, len(d)]) + d.ljust(8, b"\0") + bytes([steps, cur])

    walk = arec(0, bytes([1, 0]))
    for cw in (0x06, 0x07, 0x0F):
        walk += arec(2, struct.pack("<Hi", cw, 200000), steps=47, cur=3)
    walk += arec(1, b"") + arec(4, bytes([10]), steps=47, cur=0x85)
    walk += arec(3, struct.pack("<Hh", 0x0F, 500), steps=47, cur=0x7F)
    walk += arec(5, struct.pack("<BHBI", 0x23, 0x2070, 1, 1), steps=10)
    walk += arec(5, struct.pack("<BHBI", 0x23, 0x2070, 1, 2), steps=47)
    walk += arec(2, struct.pack("<Hi", 0x80, 0), steps=4)
    (a / "walk").write_bytes(walk)
    q = HERE / "fuzz_serial"
    q.mkdir(parents=True, exist_ok=True)
    link = sl.Link()
    (q / "telemetry").write_bytes(
        link.send(sl.FrameType.TELEMETRY, sl.telemetry_payload(5, [0, 1], [1.0, 2.0])) * 2)
    (q / "long").write_bytes(link.send(sl.FrameType.TRACE_DATA, bytes(range(240))))
    c = HERE / "fuzz_slcan"
    c.mkdir(parents=True, exist_ok=True)
    # what python-can's slcan interface writes: open (with a bit rate), frames, close
    (c / "python_can").write_bytes(b"C\rS8\r\rO\r" + b"t0000201\r" + b"t60184023402001000000\r"
                                   + b"t0800\r" + b"r6018\rT1ABCDEF82DEADBEEF01020304\r"
                                   + b"R1FFFFFFF0\rC\r")
    (c / "commands").write_bytes(b"V\rN\rF\rZ1\rs031C\rL\rt1232ABCD\rF\rC\rO\r\n"
                                 + b"t7FF8FFFFFFFFFFFFFFFF\r\n" + b"x" * 40 + b"\r")


if __name__ == "__main__":
    main()
