"""Serial link: the Python codec against the C implementation (ctypes on the
firmware sources), both directions, corrupt/truncated frames, loss counting,
telemetry and trace upload."""

from __future__ import annotations

import ctypes as C
import random
import struct

import numpy as np
import pytest

from protocols import serial_link as sl
from protocols._od import load
from protocols.clib import load_co

MAX_ENC = sl.MAX_ENCODED


class Msg(C.Structure):
    _fields_ = [("type", C.c_uint8), ("seq", C.c_uint16), ("len", C.c_uint16),
                ("payload", C.c_uint8 * sl.MAX_PAYLOAD)]


class Signal(C.Structure):
    _fields_ = [("name", C.c_char_p), ("unit", C.c_char_p), ("offset", C.c_size_t),
                ("type", C.c_uint8)]


STATUS = {0: "ok", 1: "incomplete", 5: "cobs", 6: "short", 7: "crc", 8: "too_long"}


@pytest.fixture(scope="module")
def lib():
    try:
        lib = load_co()
    except Exception as e:  # pragma: no cover - no compiler
        pytest.skip(f"cannot build the C library: {e}")
    lib.fw_serial_crc16.restype = C.c_uint16
    lib.fw_serial_encode.argtypes = [C.c_uint8, C.c_uint16, C.c_char_p, C.c_size_t,
                                     C.c_char_p, C.c_size_t, C.POINTER(C.c_size_t)]
    lib.fw_serial_decode.argtypes = [C.c_char_p, C.c_size_t, C.POINTER(Msg)]
    lib.fw_serial_cobs_encode.argtypes = [C.c_char_p, C.c_size_t, C.c_char_p, C.c_size_t]
    lib.fw_serial_cobs_encode.restype = C.c_size_t
    lib.fw_trace_arm.argtypes = [C.c_void_p, C.c_char_p, C.c_uint8, C.c_uint32, C.c_uint8,
                                 C.c_float, C.c_int, C.c_float]
    lib.fw_trace_upload_next.restype = C.c_bool
    return lib


def c_encode(lib, ftype: int, seq: int, payload: bytes) -> bytes:
    out = C.create_string_buffer(MAX_ENC)
    n = C.c_size_t()
    assert lib.fw_serial_encode(ftype, seq, payload, len(payload), out, MAX_ENC, C.byref(n)) == 0
    return out.raw[: n.value]


def c_decode(lib, wire: bytes) -> tuple[str, sl.Frame | None]:
    m = Msg()
    body = wire[:-1] if wire.endswith(b"\x00") else wire
    st = lib.fw_serial_decode(body, len(body), C.byref(m))
    if st != 0:
        return STATUS.get(st, str(st)), None
    return "ok", sl.Frame(m.type, m.seq, bytes(m.payload[: m.len]))


def test_crc_and_cobs_vectors(lib):
    assert sl.crc16(b"123456789") == 0x29B1 == lib.fw_serial_crc16(b"123456789", 9)
    vectors = {
        b"\x00": b"\x01\x01",
        b"\x00\x00": b"\x01\x01\x01",
        b"\x11\x22\x00\x33": b"\x03\x11\x22\x02\x33",
        b"\x11\x00\x00\x00": b"\x02\x11\x01\x01\x01",
        bytes(range(1, 255)): b"\xff" + bytes(range(1, 255)),
        bytes(range(1, 256)): b"\xff" + bytes(range(1, 255)) + b"\x02\xff",
    }
    for raw, enc in vectors.items():
        assert sl.cobs_encode(raw) == enc
        assert sl.cobs_decode(enc) == raw
        out = C.create_string_buffer(600)
        n = lib.fw_serial_cobs_encode(raw, len(raw), out, 600)
        assert out.raw[:n] == enc


def test_random_frames_both_directions(lib):
    rng = random.Random(1234)
    for _ in range(300):
        n = rng.choice([0, 1, 2, 7, 50, 239, 240, rng.randrange(0, 241)])
        payload = bytes(rng.choice([0, 0, rng.randrange(256)]) for _ in range(n))
        ftype, seq = rng.randrange(256), rng.randrange(65536)
        wire_c = c_encode(lib, ftype, seq, payload)
        wire_py = sl.encode_frame(ftype, seq, payload)
        assert wire_c == wire_py
        assert sl.decode_frame(wire_c[:-1]) == sl.Frame(ftype, seq, payload)
        assert c_decode(lib, wire_py) == ("ok", sl.Frame(ftype, seq, payload))


def test_corrupt_and_truncated_frames_are_rejected_with_a_reason(lib):
    rng = random.Random(7)
    wire = sl.encode_frame(sl.FrameType.TELEMETRY, 42, bytes(range(30)))
    body = wire[:-1]
    for i in range(len(body)):
        bad = bytearray(body)
        bad[i] ^= 1 << rng.randrange(8)
        if bad[i] == 0:
            bad[i] = 0x5A
        with pytest.raises(sl.FrameError) as ei:
            sl.decode_frame(bytes(bad))
        reason_c, fr = c_decode(lib, bytes(bad))
        assert fr is None
        assert ei.value.reason == reason_c
    for k in range(1, len(body)):
        with pytest.raises(sl.FrameError) as ei:
            sl.decode_frame(body[:k])
        assert ei.value.reason in ("cobs", "short", "crc")
        assert c_decode(lib, body[:k])[0] == ei.value.reason
    with pytest.raises(sl.FrameError, match="too_long"):
        sl.decode_frame(b"\x01" * (MAX_ENC + 1))


def test_receiver_counts_lost_and_bad_frames(lib):
    stream = bytearray()
    dropped = {3, 4, 10}
    corrupted = {6}
    for seq in range(20):
        w = bytearray(c_encode(lib, 1, (seq + 65530) & 0xFFFF, bytes([seq]) * 8))
        if seq in dropped:
            continue
        if seq in corrupted:
            w[3] ^= 0x10
        stream += w
    stream += b"\x13\x37\x00"  # garbage
    rx = sl.Receiver()
    frames = []
    for i in range(0, len(stream), 5):  # arbitrary chunking
        frames += rx.feed(bytes(stream[i:i + 5]))
    assert [f.payload[0] for f in frames] == [s for s in range(20)
                                               if s not in dropped | corrupted]
    assert rx.frames_ok == 16
    assert rx.frames_bad == 2
    assert rx.frames_lost == 4  # across the 16-bit wrap
    assert rx.errors["crc"] + rx.errors["cobs"] + rx.errors["short"] == 2


def test_telemetry_payload_round_trip():
    p = sl.telemetry_payload(123456, [0, 11, 27], [1.5, -2.25, 567.0])
    t = sl.parse_telemetry(p)
    assert t.step == 123456 and t.ids == (0, 11, 27) and t.values == (1.5, -2.25, 567.0)
    with pytest.raises(sl.FrameError):
        sl.parse_telemetry(p[:-1])


def test_trace_upload_from_c_decoded_in_python(lib):
    od = load()
    names = [s["name"] for s in od.signals]
    sigs = (Signal * len(names)).in_dll(lib, "fw_serial_signals")
    assert [s.name.decode() for s in sigs] == names
    off = {s.name.decode(): s.offset for s in sigs}
    iq, om = names.index("i_q_A"), names.index("omega_hat_radps")
    storage = (C.c_float * 300)()
    tr = C.create_string_buffer(1024)
    snap = C.create_string_buffer(4096)
    assert lib.fw_trace_init(tr, storage, 300) == 0
    ids = bytes([iq, om])
    assert lib.fw_trace_arm(tr, ids, 2, 40, iq, C.c_float(2.0), 0, C.c_float(1 / 24000)) == 0
    for step in range(400):
        struct.pack_into("<I", snap, 0, step)
        struct.pack_into("<f", snap, off["i_q_A"], 0.01 * step)
        struct.pack_into("<f", snap, off["omega_hat_radps"], float(step))
        lib.fw_trace_sample(tr, snap, False)
    assert lib.fw_trace_upload_start(tr) == 0
    ftype = C.c_uint8()
    payload = C.create_string_buffer(sl.MAX_PAYLOAD)
    n = C.c_size_t()
    rx, asm = sl.Receiver(), sl.TraceAssembler()
    trace = None
    seq = 0
    while lib.fw_trace_upload_next(tr, C.byref(ftype), payload, sl.MAX_PAYLOAD, C.byref(n)):
        wire = c_encode(lib, ftype.value, seq, payload.raw[: n.value])
        seq += 1
        for fr in rx.feed(wire):
            trace = asm.feed(fr) or trace
    assert trace is not None and trace.complete
    assert trace.ids == (iq, om)
    assert trace.samples.shape == (150, 2)
    assert trace.pre_trigger == 40
    k_trig = trace.trigger_step
    assert 199 <= k_trig <= 201  # 0.01 * step crosses 2.0
    np.testing.assert_array_equal(trace.samples[:, 1],
                                  np.arange(k_trig - 40, k_trig + 110, dtype=np.float32))
    assert trace.time_s()[40] == 0.0


class Decoder(C.Structure):
    """fw_serial_decoder_t (firmware_c/comm/include/pmlsm/fw_serial.h)."""

    _fields_ = [("buf", C.c_uint8 * sl.MAX_ENCODED), ("len", C.c_size_t),
                ("overflow", C.c_uint8), ("have_seq", C.c_uint8), ("next_seq", C.c_uint16),
                ("frames_ok", C.c_uint32), ("frames_bad", C.c_uint32),
                ("frames_lost", C.c_uint32), ("restarts", C.c_uint32)]


#: (sequence numbers, restarts, lost): the vectors of test_decoder_restart in
#: tests/c/test_serial.c
RESTART_VECTORS = [
    ((100, 101, 102, 0, 1, 3), 1, 1),  # drive reset: one restart, then seq 2 lost
    ((65534, 65535, 2), 0, 2),  # forward across the 16-bit wrap: 0 and 1 lost
    ((0, 0x8001), 0, 0x8000),  # a gap of exactly 0x8000 is loss
    ((0, 0x8002), 1, 0),  # one more is a restart
    ((7, 7), 1, 0),  # a repeated frame is behind the expected number
]


@pytest.mark.parametrize(("seqs", "restarts", "lost"), RESTART_VECTORS)
def test_receiver_sender_restart_is_not_loss(lib, seqs, restarts, lost):
    """A drive reset restarts the sequence at 0: counted as a restart, not as
    ~65000 lost frames; a forward gap across the 16-bit wrap is still loss. The
    firmware's decoder counts the same."""
    stream = b"".join(sl.encode_frame(sl.FrameType.TELEMETRY, s, b"x") for s in seqs)
    rx = sl.Receiver()
    assert [f.seq for f in rx.feed(stream)] == list(seqs)
    assert (rx.restarts, rx.frames_lost) == (restarts, lost)
    dec, msg = Decoder(), Msg()
    lib.fw_serial_decoder_init(C.byref(dec))
    for b in stream:
        lib.fw_serial_decoder_push(C.byref(dec), C.c_uint8(b), C.byref(msg))
    assert (dec.frames_ok, dec.frames_bad) == (len(seqs), 0)
    assert (dec.restarts, dec.frames_lost) == (restarts, lost)
