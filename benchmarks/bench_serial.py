"""Serial link decode cost per frame: pure Python (before) vs library (after), one run.

*Before* is the pure-Python code the data path used until the switch (kept here,
verbatim in behaviour, as the baseline): bitwise CRC-16/CCITT-FALSE, a Python
COBS loop and a per-byte stream loop. *After* is ``protocols.serial_link`` as
it is: ``binascii.crc_hqx``, the ``cobs`` package's C codec and a stream split
on the delimiters. Both sides are first checked to give the same frames.

Printed per frame (median over ``--repeat`` runs of ``--frames`` frames each):
CRC over a full raw frame, COBS decode, ``decode_frame``, and the stream
receiver (``Receiver.feed`` on the concatenated wire bytes), for a full trace
frame (240-byte payload, 245 raw bytes) and a telemetry frame of 4 signals.

Usage::

    python benchmarks/bench_serial.py [--frames 2000] [--repeat 7]
"""

from __future__ import annotations

import argparse
import random
import statistics
import struct
import sys
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from protocols import serial_link as sl  # noqa: E402

# ---- before: the pure-Python implementation ---------------------------------------------


def py_crc16(data: bytes) -> int:
    crc = 0xFFFF
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def py_cobs_decode(data: bytes) -> bytes:
    if not data:
        raise sl.FrameError("cobs", "empty frame")
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        code = data[i]
        i += 1
        if code == 0:
            raise sl.FrameError("cobs", "zero code byte")
        end = i + code - 1
        if end > n:
            raise sl.FrameError("cobs", "truncated block")
        block = data[i:end]
        if 0 in block:
            raise sl.FrameError("cobs", "zero inside a block")
        out += block
        i = end
        if code != 0xFF and i < n:
            out.append(0)
    return bytes(out)


def py_decode_frame(frame: bytes) -> sl.Frame:
    if len(frame) > sl.MAX_ENCODED:
        raise sl.FrameError("too_long")
    raw = py_cobs_decode(frame)
    if len(raw) < 5:
        raise sl.FrameError("short")
    if len(raw) > sl.MAX_RAW:
        raise sl.FrameError("too_long")
    (crc,) = struct.unpack_from("<H", raw, len(raw) - 2)
    if py_crc16(raw[:-2]) != crc:
        raise sl.FrameError("crc")
    ftype, seq = struct.unpack_from("<BH", raw, 0)
    return sl.Frame(ftype, seq, bytes(raw[3:-2]))


def py_receive(data: bytes) -> list[sl.Frame]:
    """The per-byte stream loop (sequence counting left out: same on both sides)."""
    out: list[sl.Frame] = []
    buf = bytearray()
    overflow = False
    for b in data:
        if b != 0:
            if len(buf) >= sl.MAX_ENCODED:
                overflow = True
                buf.clear()
            if not overflow:
                buf.append(b)
            continue
        if overflow:
            overflow = False
            buf.clear()
            continue
        if not buf:
            continue
        chunk = bytes(buf)
        buf.clear()
        try:
            out.append(py_decode_frame(chunk))
        except sl.FrameError:
            continue
    return out


# ---- measurement ------------------------------------------------------------------------


def per_item_us(fn: Callable[[], object], items: int, repeat: int) -> float:
    """Median over ``repeat`` runs of one call of ``fn`` (handling ``items``), us per item."""
    fn()  # warm up
    runs = []
    for _ in range(repeat):
        t0 = time.perf_counter_ns()
        fn()
        runs.append((time.perf_counter_ns() - t0) / 1e3 / items)
    return statistics.median(runs)


def frames_for(payload_len: int, n: int, rng: random.Random) -> list[bytes]:
    link = sl.Link()
    return [link.send(sl.FrameType.TRACE_DATA,
                      bytes(rng.choice([0, rng.randrange(256)]) for _ in range(payload_len)))
            for _ in range(n)]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=2000, help="frames per run")
    ap.add_argument("--repeat", type=int, default=7, help="runs; the median is printed")
    args = ap.parse_args()
    rng = random.Random(1)
    print(f"serial link decode cost per frame, median of {args.repeat} runs x "
          f"{args.frames} frames (us)")
    print(f"{'frame':<28}{'step':<16}{'pure Python':>12}{'library':>10}{'ratio':>9}")
    for label, plen in (("trace data (240 B payload)", sl.MAX_PAYLOAD),
                        ("telemetry, 4 signals", 25)):
        wires = frames_for(plen, args.frames, rng)
        bodies = [w[:-1] for w in wires]
        raws = [sl.cobs_decode(b) for b in bodies]
        stream = b"".join(wires)
        # both sides must give the same frames before their cost means anything
        ref = [py_decode_frame(b) for b in bodies]
        assert ref == [sl.decode_frame(b) for b in bodies] == py_receive(stream)
        assert ref == sl.Receiver().feed(stream)
        assert all(py_crc16(r[:-2]) == sl.crc16(r[:-2]) for r in raws[:50])
        steps: list[tuple[str, Callable[[], object], Callable[[], object]]] = [
            (f"crc16 ({len(raws[0]) - 2} B)", lambda r=raws: [py_crc16(x[:-2]) for x in r],
             lambda r=raws: [sl.crc16(x[:-2]) for x in r]),
            ("cobs decode", lambda b=bodies: [py_cobs_decode(x) for x in b],
             lambda b=bodies: [sl.cobs_decode(x) for x in b]),
            ("decode_frame", lambda b=bodies: [py_decode_frame(x) for x in b],
             lambda b=bodies: [sl.decode_frame(x) for x in b]),
            ("stream receiver", lambda s=stream: py_receive(s),
             lambda s=stream: sl.Receiver().feed(s)),
        ]
        for name, before, after in steps:
            t_py = per_item_us(before, len(wires), args.repeat)
            t_lib = per_item_us(after, len(wires), args.repeat)
            print(f"{label:<28}{name:<16}{t_py:>12.2f}{t_lib:>10.2f}{t_py / t_lib:>8.0f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
