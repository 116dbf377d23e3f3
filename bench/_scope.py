"""A terminal scope: the everyday live view where there is no display (a lab PC over ssh,
a CI log).

``bench live --tui`` (and ``drive.scope()`` in the shell) draw, a few times a second, the
drive's state and fault and a few signals scrolling as one-line sparklines with their
present value, minimum and maximum: the speed estimate against its reference, the
estimated position, the thrust, and, when the drive has a reference position sensor
(0x2091), the sensor's position and the estimate's electrical-angle error against it.
Everything comes from the drive's TPDOs as canopen already keeps them
(``BaseNode402.tpdo_values``): no extra bus traffic, and the same on hardware, the
emulated board and the simulated drive.

On a terminal each frame redraws in place (ANSI cursor home); anywhere else (a pipe, a
CI log) one plain line per second, so a log stays readable.
"""

from __future__ import annotations

import math
import sys
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, TextIO

import numpy as np

from bench._units import wire_to_si
from protocols.generated import od_names as od

#: sparkline levels, lowest to highest
BARS = "▁▂▃▄▅▆▇█"
#: the raw count a reference sensor without a valid reading sends (INTEGER32 min)
NO_READING = -2**31


def sparkline(values: np.ndarray, width: int, lo: float | None = None,
              hi: float | None = None) -> str:
    """The last ``width`` values as one line of :data:`BARS` (NaN: a space), scaled to
    ``[lo, hi]`` (default: their own range; a flat signal sits at the middle)."""
    if width <= 0:
        return ""
    v = np.asarray(values, dtype=float)[-width:]
    ok = np.isfinite(v)
    if not ok.any():
        return " " * len(v)
    lo = float(np.min(v[ok])) if lo is None else lo
    hi = float(np.max(v[ok])) if hi is None else hi
    if not hi > lo:
        idx = np.full(len(v), len(BARS) // 2 - 1)
    else:
        idx = np.clip(np.floor((v - lo) / (hi - lo) * len(BARS)), 0, len(BARS) - 1)
    return "".join(BARS[int(i)] if k else " " for i, k in zip(idx, ok, strict=True))


@dataclass
class Trace:
    """One scrolling signal."""

    label: str
    unit: str
    scale: float = 1.0  # shown value = SI value * scale
    digits: int = 4

    def __post_init__(self) -> None:
        self.values: deque[float] = deque(maxlen=400)

    def row(self, width: int) -> str:
        v = np.array(self.values, dtype=float)
        ok = v[np.isfinite(v)]
        now = f"{v[-1]:+.{self.digits}g}" if v.size and math.isfinite(v[-1]) else "--"
        rng = (f"[{ok.min():+.3g}, {ok.max():+.3g}]" if ok.size else "[--]")
        head = f"{self.label:<16.16s} {now:>10s} {self.unit:<7s} {rng:<22s} "
        if width - len(head) < 10:  # a narrow terminal: the range gives way to the line
            head = f"{self.label:<16.16s} {now:>10s} {self.unit:<7s} "
        return (head + sparkline(v, max(0, width - len(head))))[:width].ljust(width)


class TerminalScope:
    """The scope over a connected drive (see the module documentation).

    Parameters
    ----------
    drive : bench.Drive
        Set up (its TPDOs mapped); read without bus traffic except the reference
        sensor's resolution and zero, once.
    pole_pitch_m : float
        For the electrical-angle error against the reference sensor.
    stream : text file
        Where frames go (default stdout).
    width : int
        Characters per row (default: the terminal's, else 100).
    tty : bool, optional
        Redraw in place; default: whether ``stream`` is a terminal.
    """

    def __init__(self, drive: Any, pole_pitch_m: float, stream: TextIO | None = None,
                 width: int | None = None, tty: bool | None = None) -> None:
        import shutil

        self.drive = drive
        self.tau = float(pole_pitch_m)
        self.out = stream or sys.stdout
        self.tty = self.out.isatty() if tty is None else tty
        self.width = width or shutil.get_terminal_size((100, 24)).columns
        self.speed_ref_mps = 0.0
        self.traces = {
            "speed_ref": Trace("speed reference", "m/s"),
            "speed": Trace("speed estimate", "m/s"),
            "pos": Trace("position est.", "mm", 1e3),
            "force": Trace("thrust est.", "N"),
        }
        self.ref_res_m = self.ref_zero_m = 0.0
        try:
            if int(drive.read(od.REFERENCE_SENSOR__STATUS)) != int(od.RefStatus.NONE):
                self.ref_res_m = float(drive.read(od.REFERENCE_SENSOR__RESOLUTION))
                self.ref_zero_m = float(drive.read(od.REFERENCE_SENSOR__ELECTRICAL_ZERO))
        except Exception:  # noqa: BLE001 - a firmware without 0x2091: no reference sensor
            pass
        if self.ref_res_m > 0:
            self.traces["ref"] = Trace("ref. sensor pos.", "mm", 1e3)
            self.traces["err"] = Trace("angle err vs ref", "rad el")
        self.t_drive = float("nan")
        self.frames = 0
        self._last_line = -math.inf

    # ---- sampling ----------------------------------------------------------------------
    def _tpdo(self, e: od.Entry) -> int | None:
        v = self.drive.node.tpdo_values.get(e.index)
        return None if v is None else int(v)

    def sample(self, t_drive_s: float | None = None) -> None:
        """Take the drive's latest TPDO values as one sample of every trace."""
        if t_drive_s is not None:
            self.t_drive = float(t_drive_s)

        def si(e: od.Entry) -> float:
            raw = self._tpdo(e)
            return float("nan") if raw is None else wire_to_si(e, raw)

        speed = si(od.VELOCITY_ACTUAL_VALUE)
        pos = si(od.POSITION_ACTUAL_VALUE)
        try:
            force = si(od.TORQUE_ACTUAL_VALUE) * float(self.drive.force_rated_N)
        except Exception:  # noqa: BLE001 - the rating not readable: the force unknown
            force = float("nan")
        got = {"speed_ref": self.speed_ref_mps, "speed": speed, "pos": pos, "force": force}
        if "ref" in self.traces:
            c = self._tpdo(od.REFERENCE_SENSOR__COUNT)
            x = (float("nan") if c is None or c == NO_READING
                 else c * self.ref_res_m - self.ref_zero_m)
            got["ref"] = x
            # the estimate's electrical angle against the sensor's, wrapped to [-pi, pi)
            e = math.pi / self.tau * (pos - x)
            got["err"] = (e + math.pi) % (2 * math.pi) - math.pi if math.isfinite(e) else e
        for k, v in got.items():
            self.traces[k].values.append(v * self.traces[k].scale)

    # ---- drawing -----------------------------------------------------------------------
    def status(self) -> str:
        from bench._drive import fault_text, state_of

        sw = self._tpdo(od.STATUSWORD)
        state = state_of(sw) if sw is not None else "no statusword yet"
        code = self._tpdo(od.ERROR_CODE) or 0
        fault = fault_text(code) if code else "no fault"
        t = f"{self.t_drive:.2f} s" if math.isfinite(self.t_drive) else "--"
        return f"drive time {t} | {state} | {fault}"

    def frame(self) -> str:
        """The present frame as text (what a terminal shows)."""
        rows = [self.status()[: self.width], "-" * min(self.width, 100)]
        rows += [t.row(self.width) for t in self.traces.values()]
        if "ref" not in self.traces:
            rows.append("(no reference sensor: the estimate is not judged here)")
        return "\n".join(rows)

    def line(self) -> str:
        """One plain line (logs): time, state, the latest value of every trace."""
        vals = " ".join(f"{k}={t.values[-1]:.4g} {t.unit}"
                        for k, t in self.traces.items() if t.values)
        return f"{self.status()} | {vals}"

    def draw(self) -> None:
        """Redraw (a terminal) or, once a second, print a line (anything else)."""
        self.frames += 1
        if self.tty:
            self.out.write("\x1b[H\x1b[J" + self.frame() + "\n")
        else:
            now = time.monotonic()
            if now - self._last_line < 1.0:
                return
            self._last_line = now
            self.out.write(self.line() + "\n")
        self.out.flush()

    def start(self) -> None:
        if self.tty:
            self.out.write("\x1b[2J")

    def close(self) -> None:
        """The last frame stays on screen; one final line for a log."""
        if not self.tty:
            self.out.write(self.line() + "\n")
        self.out.flush()
