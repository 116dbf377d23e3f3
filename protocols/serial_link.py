"""Serial telemetry link: COBS framing, CRC-16/CCITT-FALSE, sequence numbers.

Mirror of firmware_c/comm/src/fw_serial.c; byte layouts in docs/protocols.md.
One frame on the wire::

    COBS( type:u8 | seq:u16le | payload[0..240] | crc16:u16le ) 0x00

Use :class:`Receiver` on a byte stream (e.g. a ``serial.Serial``'s reads):
it returns decoded :class:`Frame` objects, rejects corrupt or truncated
frames with a reason, and counts lost frames from gaps in ``seq``.
:class:`TraceAssembler` rebuilds a trace-buffer upload into a numpy array.

The data path uses the standard library's CRC-CCITT (``binascii.crc_hqx``,
the same CRC-16/CCITT-FALSE with init 0xFFFF) and the ``cobs`` package's C
codec; ``benchmarks/bench_serial.py`` compares them with the pure-Python
versions they replaced, and ``tests/python/test_protocol_serial.py`` checks
both against the firmware's C code.

Payload parsers never trust a length field further than the firmware can
send: :data:`MAX_SIGNALS` signals per frame or capture and :data:`TRACE_FLOATS`
samples x signals per capture (the firmware's constants; a test fails when
they drift). A malformed payload raises :class:`FrameError` (reason
``payload``) from :func:`parse_telemetry`; :class:`TraceAssembler` counts and
skips it.
"""

from __future__ import annotations

import binascii
import math
import struct
from collections import Counter
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
from cobs import cobs as _cobs

#: Payload bytes per frame (FW_SERIAL_MAX_PAYLOAD in fw_serial.h).
MAX_PAYLOAD = 240
MAX_RAW = 3 + MAX_PAYLOAD + 2
MAX_ENCODED = MAX_RAW + MAX_RAW // 254 + 2
#: Signals per telemetry frame or trace capture (FW_SERIAL_MAX_SIGNALS in fw_serial.h).
MAX_SIGNALS = 8
#: Largest sequence gap (mod 2^16) counted as loss; a larger one is a sender restart
#: (FW_SERIAL_RESTART_GAP in fw_serial.h).
RESTART_GAP = 0x8000
#: Floats in the drive's trace buffer (FW_APP_TRACE_FLOATS in
#: firmware_c/comm/include/pmlsm/fw_app.h): a capture of n signals holds at most
#: ``TRACE_FLOATS // n`` samples. Use this constant instead of repeating the number.
TRACE_FLOATS = 4096


class FrameType(IntEnum):
    """Frame types (first byte of a decoded frame)."""

    TELEMETRY = 0x01
    TRACE_HEADER = 0x10
    TRACE_DATA = 0x11
    TRACE_END = 0x12


class FrameError(ValueError):
    """A frame was rejected.

    ``reason`` is one of cobs, short, crc, too_long (framing) or payload (a frame
    with a valid CRC whose payload does not match its type's layout or bounds).
    """

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason


def crc16(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF (``b"123456789"`` -> 0x29B1)."""
    return binascii.crc_hqx(data, 0xFFFF)


def cobs_encode(data: bytes | bytearray | memoryview) -> bytes:
    """COBS-encode (no delimiter); a full 254-byte block at the end gets no trailing code."""
    return _cobs.encode(data)


def cobs_decode(data: bytes | bytearray | memoryview) -> bytes:
    """COBS-decode (input without the delimiter); raises :class:`FrameError` ("cobs")."""
    if not data:
        raise FrameError("cobs", "empty frame")
    try:
        return _cobs.decode(data)
    except _cobs.DecodeError as e:
        raise FrameError("cobs", str(e)) from None


@dataclass(frozen=True)
class Frame:
    """One decoded frame."""

    type: int
    seq: int
    payload: bytes


def encode_frame(ftype: int, seq: int, payload: bytes = b"") -> bytes:
    """Wire bytes of one frame, delimiter included."""
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload of {len(payload)} bytes > {MAX_PAYLOAD}")
    raw = struct.pack("<BH", ftype & 0xFF, seq & 0xFFFF) + bytes(payload)
    raw += struct.pack("<H", binascii.crc_hqx(raw, 0xFFFF))
    return _cobs.encode(raw) + b"\x00"


def decode_frame(frame: bytes) -> Frame:
    """Decode the bytes between two delimiters; raises :class:`FrameError`."""
    if len(frame) > MAX_ENCODED:
        raise FrameError("too_long", f"{len(frame)} bytes")
    raw = cobs_decode(frame)
    if len(raw) < 5:
        raise FrameError("short", f"{len(raw)} bytes decoded")
    if len(raw) > MAX_RAW:
        raise FrameError("too_long", f"{len(raw)} bytes decoded")
    (crc,) = struct.unpack_from("<H", raw, len(raw) - 2)
    calc = binascii.crc_hqx(memoryview(raw)[:-2], 0xFFFF)
    if calc != crc:
        raise FrameError("crc", f"0x{crc:04X} != 0x{calc:04X}")
    ftype, seq = struct.unpack_from("<BH", raw, 0)
    return Frame(ftype, seq, bytes(raw[3:-2]))


class Link:
    """Encoder with a sequence number (the firmware's side, for tests and tools)."""

    def __init__(self) -> None:
        self.seq = 0

    def send(self, ftype: int, payload: bytes = b"") -> bytes:
        out = encode_frame(ftype, self.seq, payload)
        self.seq = (self.seq + 1) & 0xFFFF
        return out


@dataclass
class Receiver:
    """Stream decoder. ``feed(bytes)`` returns the valid frames it completed.

    Attributes
    ----------
    frames_ok, frames_bad, frames_lost : int
        Valid frames, rejected frames, and frames missing from the sequence
        (a rejected frame also shows up as lost when the next one arrives).
    restarts : int
        Sequence jumps *backwards* (modulo 2^16, a gap of more than 32768):
        the sender restarted (drive reset) and counts from 0 again. They are not
        counted as lost frames.
    errors : Counter
        Rejections by reason (cobs, short, crc, too_long).
    """

    frames_ok: int = 0
    frames_bad: int = 0
    frames_lost: int = 0
    restarts: int = 0
    errors: Counter = field(default_factory=Counter)
    _buf: bytearray = field(default_factory=bytearray)
    _overflow: bool = False
    _next_seq: int | None = None

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        out: list[Frame] = []
        parts = bytes(data).split(b"\x00")
        last = len(parts) - 1
        for k, part in enumerate(parts):
            if self._overflow or len(self._buf) + len(part) > MAX_ENCODED:
                # no delimiter within MAX_ENCODED bytes: discard up to the next one
                self._buf.clear()
                self._overflow = k == last
                if k != last:
                    self._reject("too_long")
                continue
            if k == last:  # not terminated yet
                self._buf += part
                break
            if self._buf:
                self._buf += part
                chunk = bytes(self._buf)
                self._buf.clear()
            elif part:
                chunk = part
            else:
                continue  # idle delimiters
            try:
                fr = decode_frame(chunk)
            except FrameError as e:
                self._reject(e.reason)
                continue
            if self._next_seq is not None and fr.seq != self._next_seq:
                gap = (fr.seq - self._next_seq) & 0xFFFF
                if gap > RESTART_GAP:
                    self.restarts += 1  # behind the expected number: sender restarted
                else:
                    self.frames_lost += gap
            self._next_seq = (fr.seq + 1) & 0xFFFF
            self.frames_ok += 1
            out.append(fr)
        return out

    def _reject(self, reason: str) -> None:
        self.frames_bad += 1
        self.errors[reason] += 1


# ---- payloads -----------------------------------------------------------------


@dataclass(frozen=True)
class Telemetry:
    """A telemetry frame: control step, signal ids and float32 values."""

    step: int
    ids: tuple[int, ...]
    values: tuple[float, ...]


def parse_telemetry(payload: bytes) -> Telemetry:
    """``step:u32 | n:u8 | ids[n] | f32[n]`` with n <= :data:`MAX_SIGNALS`.

    Raises :class:`FrameError` (reason ``payload``) when the payload does not
    have exactly that layout.
    """
    if len(payload) < 5:
        raise FrameError("payload", f"telemetry of {len(payload)} bytes")
    step, n = struct.unpack_from("<IB", payload, 0)
    if n > MAX_SIGNALS:
        raise FrameError("payload", f"telemetry with {n} > {MAX_SIGNALS} signals")
    if len(payload) != 5 + 5 * n:
        raise FrameError("payload", f"telemetry with n={n} has {len(payload)} bytes")
    ids = tuple(payload[5:5 + n])
    values = struct.unpack_from(f"<{n}f", payload, 5 + n)
    return Telemetry(step, ids, tuple(float(v) for v in values))


def telemetry_payload(step: int, ids: list[int], values: list[float]) -> bytes:
    """Build a telemetry payload (tests, simulators)."""
    return struct.pack(f"<IB{len(ids)}B{len(ids)}f", step, len(ids), *ids, *values)


@dataclass
class Trace:
    """A completed trace-buffer upload.

    Attributes
    ----------
    capture_id : int
    ids : tuple of signal ids (columns of ``samples``)
    samples : ndarray, shape (n_samples, n_signals), float32, oldest first
    pre_trigger : int
        Samples recorded before the trigger (row ``pre_trigger`` is the trigger step).
    trigger_step : int
        Control step of the trigger.
    dt_s : float
        Sample period (the control period).
    missing : list of (first, count) chunks that never arrived
    """

    capture_id: int
    ids: tuple[int, ...]
    samples: np.ndarray
    pre_trigger: int
    trigger_step: int
    dt_s: float
    missing: list[tuple[int, int]]

    @property
    def complete(self) -> bool:
        return not self.missing

    def time_s(self) -> np.ndarray:
        """Time of each row relative to the trigger."""
        return (np.arange(self.samples.shape[0]) - self.pre_trigger) * self.dt_s


_TRACE_HEADER = struct.Struct("<IIIf")  # samples, pre_trigger, trigger_step, dt_s
_TRACE_DATA = struct.Struct("<HIB")  # capture, first, count
_TRACE_END = struct.Struct("<HI")  # capture, samples


@dataclass
class _Capture:
    """The upload in progress (after its TRACE_HEADER)."""

    cid: int
    ids: tuple[int, ...]
    pre: int
    trig: int
    dt: float
    samples: np.ndarray
    have: np.ndarray


class TraceAssembler:
    """Collect TRACE_HEADER / TRACE_DATA / TRACE_END frames into a :class:`Trace`.

    :meth:`feed` never raises on what comes off the wire: a trace frame whose
    payload does not match its layout or the firmware's bounds (at most
    :data:`MAX_SIGNALS` signals and ``max_floats // n`` samples, chunks inside
    the capture, END repeating the header's sample count) is counted in
    ``errors["payload"]`` and skipped; DATA or END without a header of the same
    capture (header lost, reader started mid-upload) in ``errors["orphan"]``.
    Memory is bounded by ``max_floats`` (allocated at the header). Other frame
    types are ignored.

    Parameters
    ----------
    max_floats : int
        Samples x signals the drive can capture (default :data:`TRACE_FLOATS`).
    """

    def __init__(self, max_floats: int = TRACE_FLOATS) -> None:
        self.max_floats = int(max_floats)
        self.frames_bad = 0
        self.errors: Counter[str] = Counter()
        self._cap: _Capture | None = None

    def feed(self, frame: Frame) -> Trace | None:
        """Returns the trace when its END frame arrives, else None."""
        try:
            if frame.type == FrameType.TRACE_HEADER:
                self._cap = None
                self._cap = self._header(frame.payload)
            elif frame.type == FrameType.TRACE_DATA:
                self._data(frame.payload)
            elif frame.type == FrameType.TRACE_END:
                return self._end(frame.payload)
        except FrameError as e:
            self.frames_bad += 1
            self.errors[e.reason] += 1
        return None

    def _header(self, p: bytes) -> _Capture:
        # capture:u16 | n:u8 | ids[n] | samples:u32 | pre:u32 | trigger_step:u32 | dt:f32
        if len(p) < 3:
            raise FrameError("payload", f"trace header of {len(p)} bytes")
        cid, n = struct.unpack_from("<HB", p, 0)
        if not 1 <= n <= MAX_SIGNALS or len(p) != 3 + n + _TRACE_HEADER.size:
            raise FrameError("payload", f"trace header with n={n} has {len(p)} bytes")
        total, pre, trig, dt = _TRACE_HEADER.unpack_from(p, 3 + n)
        if total > self.max_floats // n:
            raise FrameError("payload", f"trace of {total} samples x {n} signals > "
                             f"{self.max_floats} floats")
        if pre > total or not math.isfinite(dt):
            raise FrameError("payload", f"trace header pre={pre} of {total}, dt={dt}")
        return _Capture(cid, tuple(p[3:3 + n]), pre, trig, float(dt),
                        np.full((total, n), np.nan, dtype=np.float32),
                        np.zeros(total, dtype=bool))

    def _data(self, p: bytes) -> None:
        # capture:u16 | first:u32 | count:u8 | count x n x f32
        if len(p) < _TRACE_DATA.size:
            raise FrameError("payload", f"trace data of {len(p)} bytes")
        cid, first, cnt = _TRACE_DATA.unpack_from(p, 0)
        cap = self._cap
        if cap is None or cid != cap.cid:
            raise FrameError("orphan", f"trace data of capture {cid}")
        n = len(cap.ids)
        if len(p) != _TRACE_DATA.size + 4 * n * cnt or first + cnt > cap.have.size:
            raise FrameError("payload", f"trace data {first}+{cnt} of {cap.have.size} "
                             f"samples in {len(p)} bytes")
        vals = np.frombuffer(p, dtype="<f4", count=cnt * n, offset=_TRACE_DATA.size)
        cap.samples[first:first + cnt] = vals.reshape(cnt, n)
        cap.have[first:first + cnt] = True

    def _end(self, p: bytes) -> Trace:
        # capture:u16 | samples:u32
        if len(p) != _TRACE_END.size:
            raise FrameError("payload", f"trace end of {len(p)} bytes")
        cid, total = _TRACE_END.unpack_from(p, 0)
        cap = self._cap
        if cap is None or cid != cap.cid:
            raise FrameError("orphan", f"trace end of capture {cid}")
        self._cap = None
        if total != cap.have.size:
            raise FrameError("payload", f"trace end says {total} samples, header "
                             f"{cap.have.size}")
        edges = np.diff(np.concatenate(([0], (~cap.have).view(np.int8), [0])))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        missing = [(int(a), int(b - a)) for a, b in zip(starts, ends, strict=True)]
        return Trace(cid, cap.ids, cap.samples, cap.pre, cap.trig, cap.dt, missing)


def signal_names() -> list[str]:
    """Signal names by id, from protocols/od.yaml (same table as the firmware)."""
    from ._od import load

    return [s["name"] for s in load().signals]
