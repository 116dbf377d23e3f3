"""Fuzz the serial link's Python side with mutated frames (fixed seeds, bounded iterations).

* Payload parsers (:func:`parse_telemetry`, :class:`TraceAssembler`) get valid
  payloads from the firmware's C code, mutated (bit flips, truncation, extension,
  length fields set to extremes); a reference validator written from the layout
  table in docs/protocols.md says which must be accepted. Every other one must be
  counted and skipped, never raise, never allocate more than the firmware's
  trace buffer; afterwards a pristine upload still assembles.
* The framing (:class:`Receiver`) gets mutated byte streams and must agree with
  the firmware's own stream decoder (ctypes) frame by frame and in every counter.
* :class:`bench._session.TelemetryReader` reads a hostile stream to the end.

No extra test dependency: ``random.Random(seed)`` drives the mutations.
"""

from __future__ import annotations

import ctypes as C
import math
import random
import struct
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from protocols import serial_link as sl
from protocols._od import load
from protocols.clib import load_co

T = sl.FrameType
ROOT = Path(__file__).resolve().parents[2]
N_SIGNALS = len(load().signals)


class Msg(C.Structure):
    _fields_ = [("type", C.c_uint8), ("seq", C.c_uint16), ("len", C.c_uint16),
                ("payload", C.c_uint8 * sl.MAX_PAYLOAD)]


class Decoder(C.Structure):
    """fw_serial_decoder_t (firmware_c/comm/include/pmlsm/fw_serial.h)."""

    _fields_ = [("buf", C.c_uint8 * sl.MAX_ENCODED), ("len", C.c_size_t),
                ("overflow", C.c_uint8), ("have_seq", C.c_uint8), ("next_seq", C.c_uint16),
                ("frames_ok", C.c_uint32), ("frames_bad", C.c_uint32),
                ("frames_lost", C.c_uint32), ("restarts", C.c_uint32)]


C_REASON = {5: "cobs", 6: "short", 7: "crc", 8: "too_long"}


@pytest.fixture(scope="module")
def lib() -> Any:
    try:
        lib = load_co()
    except Exception as e:  # pragma: no cover - no compiler
        pytest.skip(f"cannot build the C library: {e}")
    lib.fw_serial_decoder_push.argtypes = [C.POINTER(Decoder), C.c_uint8, C.POINTER(Msg)]
    lib.fw_serial_encode.argtypes = [C.c_uint8, C.c_uint16, C.c_char_p, C.c_size_t,
                                     C.c_char_p, C.c_size_t, C.POINTER(C.c_size_t)]
    lib.fw_trace_arm.argtypes = [C.c_void_p, C.c_char_p, C.c_uint8, C.c_uint32, C.c_uint8,
                                 C.c_float, C.c_int, C.c_float]
    lib.fw_trace_upload_next.restype = C.c_bool
    lib.fw_serial_telemetry_payload.restype = C.c_size_t
    return lib


def c_upload(lib: Any, ids: list[int], capacity: int, pre: int,
             rng: random.Random) -> list[tuple[int, bytes]]:
    """A trace upload made by the firmware's code: (type, payload) per frame."""
    storage = (C.c_float * capacity)()
    tr = C.create_string_buffer(1024)  # >= sizeof(fw_trace_t)
    snap = C.create_string_buffer(4096)  # >= sizeof(fw_snapshot_t)
    assert lib.fw_trace_init(tr, storage, capacity) == 0
    assert lib.fw_trace_arm(tr, bytes(ids), len(ids), pre, ids[0], C.c_float(0.0), 2,
                            C.c_float(1 / 24000)) == 0
    vals = np.random.default_rng(rng.randrange(2**32)).uniform(
        -1e3, 1e3, (2 * capacity, 63)).astype("<f4")
    base = C.addressof(snap)
    for step in range(2 * capacity):
        struct.pack_into("<I", snap, 0, step)
        C.memmove(base + 4, vals[step].ctypes.data, vals.shape[1] * 4)
        if step == capacity // 2:
            lib.fw_trace_trigger(tr, step)
        lib.fw_trace_sample(tr, snap, False)
    assert lib.fw_trace_upload_start(tr) == 0
    ftype, n = C.c_uint8(), C.c_size_t()
    payload = C.create_string_buffer(sl.MAX_PAYLOAD)
    out = []
    while lib.fw_trace_upload_next(tr, C.byref(ftype), payload, sl.MAX_PAYLOAD, C.byref(n)):
        out.append((ftype.value, payload.raw[: n.value]))
        assert len(out) < 10_000
    return out


def c_telemetry(lib: Any, rng: random.Random) -> bytes:
    snap = C.create_string_buffer(4096)
    for off in range(0, 256, 4):
        struct.pack_into("<f", snap, off, rng.uniform(-1e3, 1e3))
    n = rng.randrange(0, sl.MAX_SIGNALS + 1)
    ids = bytes(rng.randrange(N_SIGNALS) for _ in range(n))
    out = C.create_string_buffer(sl.MAX_PAYLOAD)
    k = lib.fw_serial_telemetry_payload(snap, ids, n, out, sl.MAX_PAYLOAD)
    assert k == 5 + 5 * n
    return out.raw[:k]


def mutate(p: bytes, rng: random.Random) -> bytes:
    """One random mutation, biased to the length and count fields."""
    b = bytearray(p)
    op = rng.randrange(7)
    if op == 0 and b:  # bit flip
        i = rng.randrange(len(b))
        b[i] ^= 1 << rng.randrange(8)
    elif op == 1:  # truncate
        del b[rng.randrange(len(b) + 1):]
    elif op == 2:  # extend
        b += bytes(rng.randrange(256) for _ in range(rng.randrange(1, 9)))
    elif op == 3 and b:  # one byte to an extreme
        b[rng.randrange(len(b))] = rng.choice([0, 1, 8, 9, 0x7F, 0x80, 0xFF])
    elif op == 4 and len(b) >= 7:  # a u32 field to an extreme (samples, first, pre)
        i = rng.randrange(len(b) - 3)
        b[i:i + 4] = struct.pack("<I", rng.choice([0, 1, 2**27, 2**31, 2**32 - 1,
                                                   sl.TRACE_FLOATS, sl.TRACE_FLOATS + 1]))
    elif op == 5:  # random bytes
        b = bytearray(rng.randrange(256) for _ in range(rng.randrange(0, 64)))
    else:  # duplicate a slice
        i = rng.randrange(len(b) + 1)
        b[i:i] = b[: rng.randrange(0, 16)]
    return bytes(b[: sl.MAX_PAYLOAD])


# ---- reference validators, from the layout table in docs/protocols.md ------------------


def ref_telemetry_ok(p: bytes) -> bool:
    # step:u32 | n:u8 | ids[n]:u8 | values[n]:f32, n <= 8 signals
    return len(p) >= 5 and p[4] <= 8 and len(p) == 5 + p[4] * (1 + 4)


def ref_header(p: bytes) -> dict[str, Any] | None:
    # capture:u16 | n:u8 | ids[n]:u8 | samples:u32 | pre_trigger:u32 | trigger_step:u32 | dt:f32
    if len(p) < 3 or not 1 <= p[2] <= 8 or len(p) != 3 + p[2] + 16:
        return None
    n = p[2]
    samples, pre, trig = (int.from_bytes(p[3 + n + 4 * k:7 + n + 4 * k], "little")
                          for k in range(3))
    (dt,) = struct.unpack("<f", p[15 + n:19 + n])
    if samples * n > sl.TRACE_FLOATS or pre > samples or not math.isfinite(dt):
        return None
    return {"cid": int.from_bytes(p[0:2], "little"), "n": n, "samples": samples}


def ref_data_ok(p: bytes, hdr: dict[str, Any] | None) -> str:
    # capture:u16 | first:u32 | count:u8 | count x n x f32
    if len(p) < 7:
        return "payload"
    if hdr is None or int.from_bytes(p[0:2], "little") != hdr["cid"]:
        return "orphan"
    first, count = int.from_bytes(p[2:6], "little"), p[6]
    if len(p) != 7 + 4 * hdr["n"] * count or first + count > hdr["samples"]:
        return "payload"
    return "ok"


def ref_end_ok(p: bytes, hdr: dict[str, Any] | None) -> str:
    # capture:u16 | samples:u32
    if len(p) != 6:
        return "payload"
    if hdr is None or int.from_bytes(p[0:2], "little") != hdr["cid"]:
        return "orphan"
    return "ok" if int.from_bytes(p[2:6], "little") == hdr["samples"] else "payload"


# ---- payload parsers --------------------------------------------------------------------


def test_fuzz_parse_telemetry(lib: Any) -> None:
    rng = random.Random(20261121)
    accepted = rejected = 0
    for _ in range(3000):
        good = c_telemetry(lib, rng)
        p = mutate(good, rng) if rng.random() < 0.9 else good
        if ref_telemetry_ok(p):
            tel = sl.parse_telemetry(p)
            n = p[4]
            assert tel.step == int.from_bytes(p[:4], "little")
            assert tel.ids == tuple(p[5:5 + n])
            np.testing.assert_array_equal(np.array(tel.values, dtype=np.float32),
                                          np.frombuffer(p[5 + n:], dtype="<f4"))
            accepted += 1
        else:
            with pytest.raises(sl.FrameError) as ei:
                sl.parse_telemetry(p)
            assert ei.value.reason == "payload"
            rejected += 1
    assert accepted > 300 and rejected > 300  # both branches exercised


def test_fuzz_trace_assembler(lib: Any) -> None:
    """Mutated trace frames between pristine ones: each one is accepted exactly when
    the reference says so, else counted once under the reference's reason."""
    rng = random.Random(4242)
    checked = {"ok": 0, "payload": 0, "orphan": 0}
    for it in range(60):
        n_sig = rng.randrange(1, sl.MAX_SIGNALS + 1)
        ids = [rng.randrange(N_SIGNALS) for _ in range(n_sig)]
        capacity = rng.randrange(2 * n_sig, sl.TRACE_FLOATS // 8)
        frames = c_upload(lib, ids, capacity, rng.randrange(capacity // n_sig), rng)
        asm = sl.TraceAssembler()
        hdr: dict[str, Any] | None = None
        for ftype, good in frames:
            for _ in range(rng.randrange(0, 4)):
                bad_type = rng.choice([ftype, ftype, T.TRACE_HEADER, T.TRACE_DATA, T.TRACE_END,
                                       T.TELEMETRY, rng.randrange(256)])
                bad = mutate(good, rng)
                if bad_type == T.TRACE_HEADER:
                    if ref_header(bad) is not None:
                        continue  # a valid new header would restart the capture
                    hdr = None  # a broken header drops the capture in progress
                    expect = "payload"
                elif bad_type == T.TRACE_DATA:
                    expect = ref_data_ok(bad, hdr)
                    if expect == "ok":
                        continue  # valid data with other values: not a fault to count
                elif bad_type == T.TRACE_END:
                    expect = ref_end_ok(bad, hdr)
                    if expect == "ok":
                        continue
                    if expect == "payload" and len(bad) == 6:
                        hdr = None  # END of this capture with a wrong count ends it
                else:
                    expect = "ignored"
                before = dict(asm.errors)
                assert asm.feed(sl.Frame(bad_type, 0, bad)) is None
                diff = {k: v - before.get(k, 0) for k, v in asm.errors.items()
                        if v != before.get(k, 0)}
                assert diff == ({} if expect == "ignored" else {expect: 1}), (it, bad_type, bad)
                if expect in checked:
                    checked[expect] += 1
                assert asm.frames_bad == sum(asm.errors.values())
            # the pristine frame
            if ftype == T.TRACE_HEADER:
                hdr = ref_header(good)
                assert hdr is not None
            orphans = asm.errors["orphan"]
            bad_before = asm.frames_bad
            got = asm.feed(sl.Frame(ftype, 0, good))
            if hdr is None:  # its header was broken: the rest of the upload is orphaned
                assert got is None and asm.errors["orphan"] == orphans + 1
            elif ftype == T.TRACE_END:
                assert got is not None and got.samples.size <= sl.TRACE_FLOATS
                assert got.samples.shape == (hdr["samples"], n_sig)
                assert got.ids == tuple(ids)
                hdr = None
            else:
                assert got is None and asm.frames_bad == bad_before
                checked["ok"] += 1
        # the firmware's upload, untouched, still assembles after all that
        asm2 = sl.TraceAssembler()
        tr = [asm2.feed(sl.Frame(t, 0, p)) for t, p in frames][-1]
        assert tr is not None and tr.complete and asm2.frames_bad == 0
        data = [p for t, p in frames if t == T.TRACE_DATA]
        ref = np.concatenate([np.frombuffer(p[7:], dtype="<f4") for p in data])
        np.testing.assert_array_equal(tr.samples.ravel(), ref)
    assert min(checked.values()) > 50, checked


def test_trace_bounds_and_missing_ranges() -> None:
    """The frames that used to stop or stall the reader, one by one."""
    asm = sl.TraceAssembler()
    hdr = struct.pack("<HB2BIIIf", 7, 2, 0, 1, 2**27, 0, 0, 1e-3)  # 2^27 samples claimed
    assert asm.feed(sl.Frame(T.TRACE_HEADER, 0, hdr)) is None
    assert asm.feed(sl.Frame(T.TRACE_END, 0, struct.pack("<HI", 7, 2**27))) is None
    assert asm.errors == {"payload": 1, "orphan": 1}
    assert asm.feed(sl.Frame(T.TRACE_DATA, 0, b"\x07\x00")) is None  # short, valid CRC
    assert asm.errors["payload"] == 2
    # the largest capture the firmware can send, with chunks 1 and 3 lost
    n = 3
    total = sl.TRACE_FLOATS // n
    hdr = struct.pack("<HB3BIIIf", 8, n, 0, 1, 2, total, 5, 99, 1e-3)
    assert asm.feed(sl.Frame(T.TRACE_HEADER, 0, hdr)) is None
    vals = np.arange(total * n, dtype="<f4").reshape(total, n)
    firsts = list(range(0, total, 19))
    for k, first in enumerate(firsts):
        if k in (1, 3):
            continue
        cnt = min(19, total - first)
        asm.feed(sl.Frame(T.TRACE_DATA, 0, struct.pack("<HIB", 8, first, cnt)
                          + vals[first:first + cnt].tobytes()))
    tr = asm.feed(sl.Frame(T.TRACE_END, 0, struct.pack("<HI", 8, total)))
    assert tr is not None and asm.frames_bad == 3
    assert tr.missing == [(19, 19), (57, 19)]
    have = np.ones(total, dtype=bool)
    have[19:38] = have[57:76] = False
    np.testing.assert_array_equal(tr.samples[have], vals[have])
    assert np.isnan(tr.samples[~have]).all()
    # one sample more than the buffer holds is refused
    hdr = struct.pack("<HB3BIIIf", 9, n, 0, 1, 2, total + 1, 0, 0, 1e-3)
    asm.feed(sl.Frame(T.TRACE_HEADER, 0, hdr))
    assert asm.errors["payload"] == 3


def test_trace_bound_is_the_firmware_constant() -> None:
    """TRACE_FLOATS, MAX_SIGNALS, MAX_PAYLOAD and RESTART_GAP are the firmware's numbers."""
    app_h = (ROOT / "firmware_c/comm/include/pmlsm/fw_app.h").read_text()
    ser_h = (ROOT / "firmware_c/comm/include/pmlsm/fw_serial.h").read_text()

    def define(text: str, name: str) -> int:
        import re

        m = re.search(rf"#define\s+{name}\s+(0x[0-9A-Fa-f]+|\d+)u?\b", text)
        assert m, f"{name} not found"
        return int(m.group(1), 0)

    assert define(app_h, "FW_APP_TRACE_FLOATS") == sl.TRACE_FLOATS
    assert define(ser_h, "FW_SERIAL_MAX_SIGNALS") == sl.MAX_SIGNALS
    assert define(ser_h, "FW_SERIAL_MAX_PAYLOAD") == sl.MAX_PAYLOAD
    assert define(ser_h, "FW_SERIAL_RESTART_GAP") == sl.RESTART_GAP


# ---- framing against the firmware's decoder ---------------------------------------------


def c_stream(lib: Any, data: bytes) -> tuple[list[sl.Frame], dict[str, int], Decoder]:
    dec, msg = Decoder(), Msg()
    lib.fw_serial_decoder_init(C.byref(dec))
    frames: list[sl.Frame] = []
    reasons: dict[str, int] = {}
    for b in data:
        st = lib.fw_serial_decoder_push(C.byref(dec), b, C.byref(msg))
        if st == 0:
            frames.append(sl.Frame(msg.type, msg.seq, bytes(msg.payload[: msg.len])))
        elif st != 1:
            reasons[C_REASON[st]] = reasons.get(C_REASON[st], 0) + 1
    return frames, reasons, dec


def test_fuzz_receiver_matches_the_firmware_decoder(lib: Any) -> None:
    rng = random.Random(99)
    for _ in range(150):
        link = sl.Link()
        link.seq = rng.randrange(65536)
        stream = bytearray()
        for _ in range(rng.randrange(1, 12)):
            n = rng.choice([0, 5, 40, 239, 240, rng.randrange(241)])
            wire = bytearray(link.send(rng.choice(list(T)),
                                       bytes(rng.choice([0, rng.randrange(256)])
                                             for _ in range(n))))
            r = rng.random()
            if r < 0.15:
                continue  # lost
            if r < 0.3:
                wire[rng.randrange(len(wire))] ^= 1 << rng.randrange(8)
            elif r < 0.35:
                wire = wire[: rng.randrange(len(wire))]  # cut: merges with the next frame
            elif r < 0.4:
                link.seq = rng.randrange(65536)  # restart or jump
            elif r < 0.45:
                wire = bytearray(rng.randrange(1, 256) for _ in range(rng.randrange(300)))
            stream += wire
        c_frames, c_reasons, dec = c_stream(lib, bytes(stream))
        rx = sl.Receiver()
        py_frames: list[sl.Frame] = []
        i = 0
        while i < len(stream):  # arbitrary chunking
            k = rng.randrange(1, 300)
            py_frames += rx.feed(bytes(stream[i:i + k]))
            i += k
        assert py_frames == c_frames
        assert dict(rx.errors) == c_reasons
        assert (rx.frames_ok, rx.frames_bad, rx.frames_lost, rx.restarts) == (
            dec.frames_ok, dec.frames_bad, dec.frames_lost, dec.restarts)


# ---- the bench's reader -------------------------------------------------------------------


class FakePort:
    """A serial port that hands out ``data`` in chunks, then reports closed."""

    def __init__(self, data: bytes, chunk: int = 97) -> None:
        self.data, self.chunk, self.pos, self.closed = data, chunk, 0, False

    def read(self, n: int) -> bytes:
        out = self.data[self.pos:self.pos + min(n, self.chunk)]
        self.pos += len(out)
        if not out:
            self.closed = True
        return out


class FakeLogger:
    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.rows: dict[str, list[float]] = {}

    def append(self, t: np.ndarray, values: dict[str, np.ndarray], units: dict[str, str],
               prefix: str = "") -> None:
        with self.lock:
            for k, v in values.items():
                self.rows.setdefault(prefix + k, []).extend(np.asarray(v).tolist())


def test_telemetry_reader_survives_a_hostile_stream(lib: Any) -> None:
    from bench._session import TelemetryReader

    rng = random.Random(5)
    names = sl.signal_names()
    link = sl.Link()
    link.seq = 100
    s = bytearray()
    s += link.send(T.TELEMETRY, sl.telemetry_payload(24, [0, 1], [1.0, 2.0]))
    s += link.send(T.TRACE_HEADER, b"\x01\x00")  # valid CRC, short trace payload
    s += link.send(T.TRACE_HEADER, struct.pack("<HB2BIIIf", 3, 2, 0, 1, 2**27, 0, 0, 1e-3))
    s += link.send(T.TRACE_END, struct.pack("<HI", 3, 2**27))
    s += link.send(T.TELEMETRY, bytes([0, 0, 0, 0, 200]) + bytes(40))  # n = 200
    s += link.send(0x7E, b"future frame type")
    link.seq = 0  # the drive was reset
    s += link.send(T.TELEMETRY, sl.telemetry_payload(48, [0, 1], [3.0, 4.0]))
    upload = c_upload(lib, [0, 1], 64, 4, rng)
    for ftype, p in upload:
        s += link.send(ftype, p)
    s += link.send(T.TELEMETRY, sl.telemetry_payload(72, [0, 1], [5.0, 6.0]))
    logger = FakeLogger()
    rd = TelemetryReader(FakePort(bytes(s)), logger, 24000.0)  # type: ignore[arg-type]
    rd.start()
    rd.join(timeout=30)  # used to raise TypeError: 'Event' object is not callable
    assert not rd.is_alive() and rd.error is None
    assert logger.rows[f"tel.{names[0]}"] == [1.0, 3.0, 5.0]
    assert logger.rows[f"tel.{names[1]}"] == [2.0, 4.0, 6.0]
    assert len(rd.traces) == 1 and rd.traces[0].complete
    assert rd.traces[0].samples.shape == (32, 2)
    assert rd.payload_errors == {"payload": 1, "type": 1}
    assert dict(rd.asm.errors) == {"payload": 2, "orphan": 1}
    assert rd.stats == {"frames_ok": 8 + len(upload), "frames_bad": 0, "frames_lost": 0,
                        "restarts": 1, "payload_bad": 5}
    rd.stop()  # stop() and join() on a finished reader
    rd.join()
