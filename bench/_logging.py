"""Per-run logging: raw CAN trace, decoded signals (MF4), metadata, events.

A run folder ``runs/<UTC timestamp>_<sequence>/`` holds::

    can.blf              raw CAN trace (python-can can.Logger, BLF; or .asc)
    signals/part_*.mf4   decoded signals with units, one file per ~1 s chunk
    signals.mf4          all chunks joined (written at the end of a clean run)
    meta.json            drive identity, firmware version, configuration,
                         sequence, seed, bench version, host
    events.jsonl         step/abort/safe-state events, appended and flushed
    report.html, *.png   report (bench._report)

The MF4 files are written by the bench's MF4 writer process (:mod:`bench._mf4writer`;
in this process when it is not available). Crash safety: the CAN trace is flushed and
every signal chunk is written
(atomically, tmp + rename) at least once per ``flush_s`` (default 0.5 s), so
a run killed with SIGKILL loses at most about one second and leaves readable
files. The trace listener is attached to canopen's ``network.notifier``
(python-can allows one Notifier per bus); receive-thread exceptions are
caught by :class:`ErrorListener` and surfaced in the result.
"""

from __future__ import annotations

import copy
import json
import logging
import os
import platform
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import can
import numpy as np

log = logging.getLogger("bench.logging")


def run_dir_for(sequence: str, root: str | Path = "runs") -> Path:
    """A fresh ``runs/<YYYYmmddTHHMMSS_ffffffZ>_<sequence>`` folder (created)."""
    stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%S_%fZ")
    d = Path(root) / f"{stamp}_{sequence}"
    d.mkdir(parents=True, exist_ok=False)
    return d


class ErrorListener(can.Listener):
    """Collects exceptions raised in the notifier's receive thread.

    python-can calls ``on_error`` of every listener when a listener or the bus
    raises inside the receive thread; having one that handles it keeps the
    thread alive, and :attr:`errors` lets the bench report what happened.

    python-can also stores the exception in ``notifier.exception``, and canopen's
    ``Network.send_message`` re-raises it on *every later send*, which would make
    it impossible to disable the drive afterwards. Since the error is handled
    (recorded, reported) and the receive thread keeps running, the stored
    exception is cleared.
    """

    def __init__(self, notifier: can.Notifier | None = None) -> None:
        self.errors: list[str] = []
        self.notifier = notifier

    def on_message_received(self, msg: can.Message) -> None:
        pass

    def on_error(self, exc: Exception) -> None:
        text = f"{type(exc).__name__}: {exc}"
        # one line (the run's result names what it means); the traceback with -v
        log.error("CAN receive thread: %s", text, exc_info=exc if log.isEnabledFor(
            logging.DEBUG) else None)
        if len(self.errors) < 100:
            self.errors.append(text)
        if self.notifier is not None and self.notifier.exception is exc:
            self.notifier.exception = None


class SeqCounter:
    """Counts lost frames from a wrapping sequence number.

    Parameters
    ----------
    modulo : int
        The counter wraps at this value (e.g. 256 for a u8, 65536 for a u16).
    """

    def __init__(self, modulo: int) -> None:
        self.modulo = modulo
        self.last: int | None = None
        self.received = 0
        self.lost = 0

    def update(self, seq: int) -> int:
        """Account for a received sequence number; returns the frames lost before it."""
        self.received += 1
        gap = 0
        if self.last is not None:
            gap = (seq - self.last - 1) % self.modulo
            self.lost += gap
        self.last = seq
        return gap


class TraceListener(can.Listener):
    """Wraps a python-can writer (``can.Logger``) with a lock and periodic flush."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.writer = can.Logger(str(path))
        self.lock = threading.Lock()
        self.count = 0      # frames received from the bus
        self.tx_count = 0   # frames the bench sent (logged too)
        self.id_counts: dict[int, int] = {}
        self._channel_ints: dict[str, int | None] = {}  # channel2int is a regex

    def on_message_received(self, msg: can.Message) -> None:
        if isinstance(msg.channel, str):
            # BLF stores the channel as u16, derived from the name's trailing digits:
            # "pmlsm-sim-12345678" would overflow it and kill the receive thread
            c = self._channel_ints.get(msg.channel, -1)
            if c == -1:
                c = self._channel_ints[msg.channel] = can.util.channel2int(msg.channel)
            if c is not None and not 0 <= c <= 0xFFFF:
                msg = copy.copy(msg)
                msg.channel = None
        with self.lock:
            self.writer.on_message_received(msg)
            if not msg.is_rx:  # sent by the bench (see RunLogger._hook_sends)
                self.tx_count += 1
                return
            self.count += 1
            i = msg.arbitration_id
            self.id_counts[i] = self.id_counts.get(i, 0) + 1

    def flush(self) -> None:
        """Push buffered frames to disk (BLF: close the current container)."""
        with self.lock:
            w = self.writer
            f = getattr(w, "file", None)
            if hasattr(w, "_flush") and getattr(w, "_buffer_size", 0):
                w._flush()  # BLF: compress and write the pending container
                if getattr(w, "start_timestamp", None) is not None and f.seekable():
                    # rewrite the header now (python-can does it only at stop()), so a
                    # killed run keeps absolute timestamps and the object count
                    end = f.tell()
                    f.seek(0)
                    w._write_header(end)
                    f.seek(end)
            if f is not None and not f.closed:
                f.flush()
                os.fsync(f.fileno())

    def stop(self) -> None:
        with self.lock:
            self.writer.stop()


@dataclass
class _Channel:
    unit: str
    t: list[np.ndarray]
    v: list[np.ndarray]
    flushed: int = 0  # number of list items already written to a part file


def _compact(ch: _Channel) -> None:
    """Join a channel's pieces (many small per-frame arrays) into at most two: the part
    already written to a part file and the rest, so that reading a channel again (the
    runner's expectations read the truth at every check) costs one copy of what arrived
    since, not a concatenation of every piece since the start. Call under the lock."""
    n, f = len(ch.t), ch.flushed
    if n <= 2:
        return
    if 0 < f < n:
        ch.t[:] = [np.concatenate(ch.t[:f]), np.concatenate(ch.t[f:])]
        ch.v[:] = [np.concatenate(ch.v[:f]), np.concatenate(ch.v[f:])]
        ch.flushed = 1
    else:
        ch.t[:] = [np.concatenate(ch.t)]
        ch.v[:] = [np.concatenate(ch.v)]
        ch.flushed = 1 if f else 0


class RunLogger:
    """Everything a run writes. Thread-safe ``append``; a flusher thread.

    Parameters
    ----------
    run_dir : Path
        Folder of the run (see :func:`run_dir_for`).
    network : canopen.Network or None
        Its ``notifier`` gets the CAN trace listener and the error listener.
    trace_format : {"blf", "asc"}
    flush_s : float
        Flush period of the CAN trace and the signal chunks (s).
    mf4_process : bool or None
        Write the MF4 files in the bench's MF4 writer process
        (:meth:`bench._mf4writer.Mf4Writer.shared`), so that asammdf's import and the
        compression run beside the run on another core. None (default): when asammdf
        is not imported here yet, or the writer process is already running.
    """

    def __init__(self, run_dir: Path, network: Any = None, trace_format: str = "blf",
                 flush_s: float = 0.5, mf4_process: bool | None = None) -> None:
        import sys

        from bench._mf4writer import Mf4Writer

        self.dir = Path(run_dir)
        self.dir.mkdir(parents=True, exist_ok=True)
        (self.dir / "signals").mkdir(exist_ok=True)
        self._lock = threading.RLock()
        self._channels: dict[str, _Channel] = {}
        self._part = 0
        self._events = open(self.dir / "events.jsonl", "a", encoding="utf-8")  # noqa: SIM115
        self.events: list[dict[str, Any]] = []
        self.windows: list[dict[str, Any]] = []
        self.t_origin_s = 0.0
        self.errors = ErrorListener(getattr(network, "notifier", None))
        self.trace: TraceListener | None = None
        self.network = network
        self.counters: dict[str, SeqCounter] = {}
        self.meta: dict[str, Any] = {}
        self._send_hooked: Any = None
        if network is not None and getattr(network, "notifier", None) is not None:
            self.trace = TraceListener(self.dir / f"can.{trace_format}")
            network.notifier.add_listener(self.errors)
            network.notifier.add_listener(self.trace)
            self._hook_sends(network)
        self.flush_s = flush_s
        if mf4_process is None:
            mf4_process = "asammdf" not in sys.modules or Mf4Writer.running()
        self._mf4 = Mf4Writer.shared() if mf4_process else Mf4Writer(use_process=False)
        self._mf4_before = (len(self._mf4.failed), self._mf4.fallbacks)  # shared: counts
        self._stop = threading.Event()
        self._flusher = threading.Thread(target=self._flush_loop, name="bench-log-flush",
                                         daemon=True)
        self._flusher.start()

    # ---- metadata and events ---------------------------------------------------------
    def write_meta(self, meta: dict[str, Any]) -> None:
        """Write (or rewrite) ``meta.json`` atomically."""
        self.meta.update(meta)
        base = {"bench_version": _bench_version(), "host": platform.node(),
                "python": platform.python_version(),
                "created_utc": datetime.now(timezone.utc).isoformat()}
        self.meta = {**base, **self.meta}
        doc = self.meta
        _atomic_write(self.dir / "meta.json", json.dumps(doc, indent=2, default=_json_default))

    def mark_start(self, t0_s: float) -> None:
        """Origin of sequence time on the drive clock (s)."""
        self.t_origin_s = t0_s
        self.meta["time_origin_s"] = float(t0_s)  # drive clock at sequence time 0

    def event(self, t_s: float, kind: str, detail: dict[str, Any]) -> None:
        ev = {"t_s": round(float(t_s), 6), "kind": kind, **detail}
        with self._lock:
            self.events.append(ev)
            self._events.write(json.dumps(ev, default=_json_default) + "\n")
            self._events.flush()

    def trace_window(self, name: str, t0_s: float, t1_s: float, signals: list[str]) -> None:
        """Remember a trace-capture window (plotted at full rate in the report)."""
        self.windows.append({"name": name, "t0_s": t0_s, "t1_s": t1_s, "signals": signals})
        self.event(t0_s, "trace_capture", {"name": name, "t1_s": t1_s})

    # ---- signals ----------------------------------------------------------------------
    def append(self, t_s: np.ndarray, values: dict[str, np.ndarray],
               units: dict[str, str], prefix: str = "") -> None:
        """Append samples of several channels sharing one time vector.

        Parameters
        ----------
        t_s : ndarray
            Timestamps on the drive clock (s).
        values : dict of ndarray
            Channel name -> samples (same length as ``t_s``).
        units : dict of str
            Channel name -> unit.
        prefix : str
            Prepended to the channel names (e.g. ``"truth."``).
        """
        t = np.asarray(t_s, dtype=np.float64)
        with self._lock:
            for k, v in values.items():
                name = prefix + k
                ch = self._channels.get(name)
                if ch is None:
                    unit = units.get(k) or (_signal_units().get(k, "")
                                            if prefix.startswith(("tel.", "trace.")) else "")
                    ch = self._channels[name] = _Channel(unit, [], [])
                ch.t.append(t)
                ch.v.append(np.asarray(v))

    def channel(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """All samples of one channel: (t on the drive clock (s), values)."""
        with self._lock:
            ch = self._channels.get(name)
            if ch is None or not ch.t:
                return np.empty(0), np.empty(0)
            _compact(ch)
            if len(ch.t) == 1:
                return ch.t[0], ch.v[0]
            return np.concatenate(ch.t), np.concatenate(ch.v)

    def channels(self) -> dict[str, str]:
        """Channel name -> unit."""
        with self._lock:
            return {k: c.unit for k, c in self._channels.items()}

    def evidence_channels(self, until_s: float | None = None) -> dict[str, np.ndarray] | None:
        """The channels the run's metrics are computed from, in sequence time
        (:class:`bench._evidence.Evidence`: the simulator's record, a reference sensor
        with the drive's signals, or the drive's signals alone); ``until_s``: wait
        briefly for a link's latency to cover that sequence time."""
        ev = getattr(self, "evidence", None)
        if ev is None:
            return self.truth()
        return ev.collect(self, self.t_origin_s, until_s)

    def truth(self) -> dict[str, np.ndarray] | None:
        """Truth + estimate channels in sequence time (None if no true angle recorded).

        Channels of :data:`sim_fallback.metrics.TRUTH_CHANNELS` that were not
        recorded are left out (the metrics that need them are then NaN).
        """
        from sim_fallback.metrics import TRUTH_CHANNELS

        out: dict[str, np.ndarray] = {}
        t_ref = None
        with self._lock:  # one consistent snapshot while the simulation keeps appending
            for c in TRUTH_CHANNELS[1:]:
                t, v = self.channel("sim." + c)
                if t.size == 0:
                    continue
                out[c] = v
                t_ref = t
        if t_ref is None or "theta_e_rad" not in out:
            return None
        out["t_s"] = t_ref - self.t_origin_s
        return out

    def counter(self, name: str, modulo: int) -> SeqCounter:
        """A named :class:`SeqCounter` reported in the summary."""
        c = self.counters.get(name)
        if c is None:
            c = self.counters[name] = SeqCounter(modulo)
        return c

    # ---- flushing ---------------------------------------------------------------------
    def _flush_loop(self) -> None:
        while not self._stop.wait(self.flush_s):
            try:
                self.flush()
            except Exception as e:  # noqa: BLE001 - never kill the run for a flush
                log.error("log flush failed: %s", e)

    def flush(self, signals: bool = True) -> None:
        """Flush the CAN trace and write new signal samples as a new MF4 part."""
        if self.trace is not None:
            self.trace.flush()
        if not signals:
            return
        with self._lock:
            new: list[tuple[str, str, np.ndarray, np.ndarray]] = []
            for name, ch in self._channels.items():
                if ch.flushed < len(ch.t):
                    t = np.concatenate(ch.t[ch.flushed:])
                    v = np.concatenate(ch.v[ch.flushed:])
                    ch.flushed = len(ch.t)
                    new.append((name, ch.unit, t, v))
            if not new:
                return
            self._part += 1
            part = self._part
        self._mf4.write(self.dir / "signals" / f"part_{part:05d}.mf4", new)

    def _hook_sends(self, network: Any) -> None:
        """Log what the bench sends too (SDO requests, NMT, SYNC, heartbeat, RPDOs):
        a bus does not receive its own frames, so the notifier alone records one
        direction. Every frame given to ``bus.send`` is written to the trace as a
        transmitted frame (``is_rx=False``) with its send time."""
        bus = getattr(network, "bus", None)
        if bus is None or self.trace is None:
            return
        trace = self.trace
        orig = bus.send

        def send(msg: can.Message, timeout: float | None = None) -> None:
            orig(msg, timeout)
            try:
                m = copy.copy(msg)
                m.is_rx = False
                m.timestamp = time.time()
                trace.on_message_received(m)
            except Exception as e:  # noqa: BLE001 - logging must never stop a send
                log.error("could not log a sent frame: %s", e)

        had_own = "send" in vars(bus)
        bus.send = send  # instance attribute: python-can's periodic tasks call it too
        self._send_hooked = (bus, orig if had_own else None)

    def close(self, join_mf4: bool = True, sync: bool = True) -> dict[str, Any]:
        """Stop the flusher, flush, detach listeners, join the MF4 parts.

        ``sync=False`` returns while the MF4 writer process may still be writing: call
        :meth:`sync_files` with the returned dict before relying on the files.

        Returns
        -------
        dict
            ``{"frames_logged", "receive_errors", "lost_frames", "mf4", "can_trace"}``.
        """
        self._stop.set()
        self._flusher.join(timeout=5)
        # no last part when the joined file follows: it holds everything (and if the
        # writer process fails, the bench writes it itself)
        self.flush(signals=not join_mf4)
        if self._send_hooked is not None:
            bus, own = self._send_hooked
            if own is not None:
                bus.send = own
            else:
                try:
                    del bus.send  # back to the class's method
                except AttributeError:
                    pass
            self._send_hooked = None
        if self.trace is not None and self.network is not None and self.network.notifier:
            for lst in (self.trace, self.errors):
                try:
                    self.network.notifier.remove_listener(lst)
                except ValueError:
                    pass
            self.trace.stop()
        self._events.close()
        out: dict[str, Any] = {
            "frames_logged": self.trace.count if self.trace else 0,
            "frames_sent_logged": self.trace.tx_count if self.trace else 0,
            "frames_by_id": dict(self.trace.id_counts) if self.trace else {},
            "receive_errors": list(self.errors.errors),
            "lost_frames": {k: c.lost for k, c in self.counters.items()},
            "can_trace": str(self.trace.path.name) if self.trace else None,
            "mf4": None, "mf4_errors": [], "mf4_written_in_bench": 0,
        }
        if join_mf4:
            out["mf4"] = self.join_mf4()
        if sync:
            self.sync_files(out)
        return out

    def sync_files(self, stats: dict[str, Any]) -> None:
        """Wait until the MF4 files are written; record the outcome in ``stats`` (the
        dict :meth:`close` returned): ``mf4`` (None if it could not be written),
        ``mf4_errors``, ``mf4_written_in_bench`` (files the writer process did not
        write, written here instead)."""
        self._mf4.sync()
        stats["mf4_errors"] = list(self._mf4.failed[self._mf4_before[0]:])
        if stats.get("mf4") and not (self.dir / stats["mf4"]).exists():
            stats["mf4"] = None
        stats["mf4_written_in_bench"] = self._mf4.fallbacks - self._mf4_before[1]

    def join_mf4(self) -> str | None:
        """Join everything into one compressed ``signals.mf4`` with the run's metadata in
        its header and a unit and comment on every channel; the crash-safety parts
        (``signals/part_*.mf4``) are removed once it is written, so the data is stored
        once."""
        names = self.channels()
        if not names:
            return None
        rows = []
        for name, unit in names.items():
            t, v = self.channel(name)
            rows.append((name, unit, t, v))
        path = self.dir / "signals.mf4"
        self._mf4.write(path, rows, header=self._mf4_header(), compression=2,
                        remove_parts=self.dir / "signals")
        return path.name

    def _mf4_header(self) -> dict[str, str]:
        """What makes the MF4 self-describing (also in meta.json)."""
        m = self.meta
        seq = m.get("sequence", {}) or {}
        drv = m.get("drive", {}) or {}
        info = m.get("connection_info", {}) or {}
        return {
            "sequence": str(seq.get("name", "")), "sequence_file": str(seq.get("file", "")),
            "seed": str(seq.get("seed", "")), "motor": str(seq.get("motor", "")),
            "extractor": str(seq.get("extractor", "")),
            "drive": str(info.get("kind", "unknown")),  # what the drive said it is (0x2090:1)
            "connection": str(m.get("connection", "")),
            "firmware_version": str(drv.get("firmware_version", "")),
            "firmware_build": str(drv.get("build_id", "")),
            "bench_version": _bench_version(),
            "time_origin_s": f"{self.t_origin_s:.9f}",
            "time_base": "drive clock (s); sequence time = t - time_origin_s",
            "created_utc": str(m.get("created_utc", "")),
        }


_SIGNAL_UNITS: dict[str, str] | None = None


def _signal_units() -> dict[str, str]:
    """Units of the drive's serial/trace signals (od.yaml ``signals:``)."""
    global _SIGNAL_UNITS
    if _SIGNAL_UNITS is None:
        from protocols import load_od

        _SIGNAL_UNITS = {s["name"]: str(s.get("unit", "")) for s in load_od().signals}
    return _SIGNAL_UNITS


def channel_comment(name: str) -> str:
    """Where a channel comes from, for the MF4 channel comment."""
    src, _, sig = name.partition(".")
    if src == "pdo":
        return f"received over CAN: TPDO signal {sig} (decoded to SI by the bench)"
    if src == "tel":
        return f"received over the serial link: telemetry signal {sig} (fw_snapshot_t)"
    if src == "trace":
        cap, _, s2 = sig.partition(".")
        return (f"drive trace buffer, capture '{cap}', signal {s2}, full control rate "
                "(uploaded over the serial link)")
    if src == "sim":
        return (f"simulated drive record: {sig} (plant truth or firmware internals; "
                "not available on hardware)")
    return name


def _mf4_header_xml(header: dict[str, str]) -> str:
    from xml.sax.saxutils import escape

    props = "".join(f'<e name="{escape(k)}">{escape(v)}</e>' for k, v in header.items())
    return ("<HDcomment><TX>pmlsm bench run: decoded drive signals</TX>"
            f"<common_properties>{props}</common_properties></HDcomment>")


def _write_mf4(path: Path, rows: Iterable[tuple[str, str, np.ndarray, np.ndarray]],
               header: dict[str, str] | None = None, compression: int = 0) -> None:
    """Write channels to an MF4 file atomically; one group per time base. ``header``
    goes into the file header's common properties; ``compression`` is asammdf's
    (0 none for the crash-safety parts, 2 transposed deflate for the final file)."""
    from asammdf import MDF, Signal

    groups: dict[int, list[Any]] = {}
    bases: dict[int, np.ndarray] = {}
    for name, unit, t, v in rows:
        key = None
        for k, tb in bases.items():
            if tb.shape == t.shape and np.array_equal(tb, t):
                key = k
                break
        if key is None:
            key = len(bases)
            bases[key] = t
            groups[key] = []
        v = np.asarray(v)
        com = channel_comment(name)
        if v.ndim > 1:
            for j in range(v.shape[1]):
                groups[key].append(Signal(v[:, j], t, name=f"{name}[{j}]", unit=unit,
                                          comment=f"{com}, component {j}"))
        else:
            groups[key].append(Signal(v, t, name=name, unit=unit, comment=com))
    mdf = MDF(version="4.10")
    if header:
        mdf.header.comment = _mf4_header_xml(header)
    for sigs in groups.values():
        mdf.append(sigs, comment="pmlsm bench")
    # written beside it, then renamed: a reader never sees a half-written file. The name
    # keeps the .mf4 suffix: asammdf puts its own suffix on another (a ".tmp" became
    # the final name itself, written in place while readers could open it)
    tmp = path.with_name(f".{path.stem}.writing.mf4")
    saved = mdf.save(tmp, overwrite=True, compression=compression)
    mdf.close()
    os.replace(saved if saved and Path(saved).exists() else tmp, path)


def read_signals(run_dir: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray, str]]:
    """Read a run's signals back: the joined file, else every part (crash case).

    Returns
    -------
    dict
        Channel -> (t (s), values, unit).
    """
    from asammdf import MDF

    d = Path(run_dir)
    files = [d / "signals.mf4"] if (d / "signals.mf4").exists() else sorted(
        (d / "signals").glob("part_*.mf4"))
    acc: dict[str, tuple[list[np.ndarray], list[np.ndarray], str]] = {}
    for f in files:
        with MDF(f) as mdf:
            for name in mdf.channels_db:
                if name.startswith("time") or name == "t":
                    continue
                s = mdf.get(name)
                e = acc.setdefault(name, ([], [], s.unit))
                e[0].append(s.timestamps)
                e[1].append(s.samples)
    return {k: (np.concatenate(t), np.concatenate(v), u) for k, (t, v, u) in acc.items()}


def _atomic_write(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", encoding="utf-8") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _json_default(o: Any) -> Any:
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    return str(o)


def _bench_version() -> str:
    from bench import __version__

    return __version__


def wall_time() -> float:
    """Wall-clock time (s since the epoch)."""
    return time.time()
