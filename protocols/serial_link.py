"""Serial telemetry link: COBS framing, CRC-16/CCITT-FALSE, sequence numbers.

Mirror of firmware_c/comm/src/fw_serial.c; byte layouts in docs/protocols.md.
One frame on the wire::

    COBS( type:u8 | seq:u16le | payload[0..240] | crc16:u16le ) 0x00

Use :class:`Receiver` on a byte stream (e.g. a ``serial.Serial``'s reads):
it returns decoded :class:`Frame` objects, rejects corrupt or truncated
frames with a reason, and counts lost frames from gaps in ``seq``.
:class:`TraceAssembler` rebuilds a trace-buffer upload into a numpy array.
"""

from __future__ import annotations

import struct
from collections import Counter
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

MAX_PAYLOAD = 240
MAX_RAW = 3 + MAX_PAYLOAD + 2
MAX_ENCODED = MAX_RAW + MAX_RAW // 254 + 2


class FrameType(IntEnum):
    """Frame types (first byte of a decoded frame)."""

    TELEMETRY = 0x01
    TRACE_HEADER = 0x10
    TRACE_DATA = 0x11
    TRACE_END = 0x12


class FrameError(ValueError):
    """A frame was rejected. ``reason`` is one of cobs, short, crc, too_long."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF (``b"123456789"`` -> 0x29B1)."""
    crc = 0xFFFF
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def cobs_encode(data: bytes) -> bytes:
    """COBS-encode (no delimiter); a full 254-byte block at the end gets no trailing code."""
    out = bytearray([0])
    code_pos, code = 0, 1
    for i, b in enumerate(data):
        if b == 0:
            out[code_pos] = code
            code_pos, code = len(out), 1
            out.append(0)
        else:
            out.append(b)
            code += 1
            if code == 0xFF:
                out[code_pos] = code
                if i + 1 == len(data):
                    return bytes(out)
                code_pos, code = len(out), 1
                out.append(0)
    out[code_pos] = code
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """COBS-decode (input without the delimiter); raises :class:`FrameError` ("cobs")."""
    if not data:
        raise FrameError("cobs", "empty frame")
    out = bytearray()
    i = 0
    n = len(data)
    while i < n:
        code = data[i]
        i += 1
        if code == 0:
            raise FrameError("cobs", f"zero code byte at {i - 1}")
        end = i + code - 1
        if end > n:
            raise FrameError("cobs", "truncated block")
        block = data[i:end]
        if 0 in block:
            raise FrameError("cobs", "zero inside a block")
        out += block
        i = end
        if code != 0xFF and i < n:
            out.append(0)
    return bytes(out)


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
    raw += struct.pack("<H", crc16(raw))
    return cobs_encode(raw) + b"\x00"


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
    if crc16(raw[:-2]) != crc:
        raise FrameError("crc", f"0x{crc:04X} != 0x{crc16(raw[:-2]):04X}")
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

    def feed(self, data: bytes) -> list[Frame]:
        out: list[Frame] = []
        for b in data:
            if b != 0:
                if len(self._buf) >= MAX_ENCODED:
                    self._overflow = True
                    self._buf.clear()
                if not self._overflow:
                    self._buf.append(b)
                continue
            if self._overflow:
                self._overflow = False
                self._buf.clear()
                self._reject("too_long")
                continue
            if not self._buf:
                continue
            chunk = bytes(self._buf)
            self._buf.clear()
            try:
                fr = decode_frame(chunk)
            except FrameError as e:
                self._reject(e.reason)
                continue
            if self._next_seq is not None and fr.seq != self._next_seq:
                gap = (fr.seq - self._next_seq) & 0xFFFF
                if gap > 0x8000:
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
    """``step:u32 | n:u8 | ids[n] | f32[n]``."""
    if len(payload) < 5:
        raise FrameError("short", "telemetry payload")
    step, n = struct.unpack_from("<IB", payload, 0)
    if len(payload) != 5 + 5 * n:
        raise FrameError("short", f"telemetry with n={n} has {len(payload)} bytes")
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


class TraceAssembler:
    """Collect TRACE_HEADER / TRACE_DATA / TRACE_END frames into a :class:`Trace`."""

    def __init__(self) -> None:
        self._hdr: dict | None = None
        self._rows: dict[int, np.ndarray] = {}

    def feed(self, frame: Frame) -> Trace | None:
        """Returns the trace when its END frame arrives, else None."""
        p = frame.payload
        if frame.type == FrameType.TRACE_HEADER:
            cid, n = struct.unpack_from("<HB", p, 0)
            ids = tuple(p[3:3 + n])
            total, pre, trig, dt = struct.unpack_from("<IIIf", p, 3 + n)
            self._hdr = {"id": cid, "ids": ids, "total": total, "pre": pre,
                         "trig": trig, "dt": float(dt)}
            self._rows = {}
        elif frame.type == FrameType.TRACE_DATA and self._hdr is not None:
            cid, first, cnt = struct.unpack_from("<HIB", p, 0)
            if cid != self._hdr["id"]:
                return None
            n = len(self._hdr["ids"])
            vals = np.frombuffer(p, dtype="<f4", count=cnt * n, offset=7).reshape(cnt, n)
            self._rows[first] = vals
        elif frame.type == FrameType.TRACE_END and self._hdr is not None:
            cid, total = struct.unpack_from("<HI", p, 0)
            h = self._hdr
            n = len(h["ids"])
            samples = np.full((total, n), np.nan, dtype=np.float32)
            have = np.zeros(total, dtype=bool)
            for first, vals in self._rows.items():
                end = min(first + vals.shape[0], total)
                samples[first:end] = vals[: end - first]
                have[first:end] = True
            missing: list[tuple[int, int]] = []
            k = 0
            while k < total:
                if not have[k]:
                    j = k
                    while j < total and not have[j]:
                        j += 1
                    missing.append((k, j - k))
                    k = j
                else:
                    k += 1
            self._hdr = None
            return Trace(cid, h["ids"], samples, h["pre"], h["trig"], h["dt"], missing)
        return None


def signal_names() -> list[str]:
    """Signal names by id, from protocols/od.yaml (same table as the firmware)."""
    from ._od import load

    return [s["name"] for s in load().signals]
