"""The drive's own clock, as the bench sees it over a bus.

A drive's time base is its count of control periods (the PWM is its clock, in
simulation as on the MCU). It publishes the count of the period its values show in
0x2090:3 (TPDO4, every SYNC). :class:`DriveClock` turns those observations into the
run's time base: sequence steps, PDO and telemetry samples are all placed in *drive*
time. On a rig that is the wall clock (to the crystal's ppm); on the emulated board,
which runs paced by its own virtual clock at a fraction of real time, it is the only
time that means anything: a load step "at 0.5 s" happens 0.5 s of the drive's time
after the enable, however long that takes on this machine.

Between observations the clock extrapolates with the rate measured over the last
second (drive seconds per host second), never runs backwards, and raises
:class:`bench._drive.DriveLost` when no observation came for ``lost_s`` of host time
or when the bus failed (:meth:`fail`): a dead drive stops a run within a slice, it
is never mistaken for a slow one.
"""

from __future__ import annotations

import threading
import time
from collections import deque

from bench._drive import DriveLost

#: the period counter is an UNSIGNED32 (0x2090:3)
_WRAP = 1 << 32


class DriveClock:
    """Drive time (s) from the drive's period count.

    Parameters
    ----------
    f_pwm_Hz : float
        The drive's control rate: seconds = periods / f_pwm_Hz.
    lost_s : float
        Host seconds without an observation after which the drive counts as lost.
    what : str
        How errors name the drive (e.g. ``"drive node 1"``).
    """

    #: sleep slices (host s): a fault or a lost drive is noticed within one
    slice_s = 0.01
    #: not the simulated drive's exact step clock (see bench._session._collect_trace)
    exact_steps = False

    def __init__(self, f_pwm_Hz: float, lost_s: float = 0.5, what: str = "the drive") -> None:
        if not f_pwm_Hz > 0:
            raise ValueError(f"control rate {f_pwm_Hz!r} Hz: must be > 0")
        self.f_pwm_Hz = float(f_pwm_Hz)
        self.lost_s = float(lost_s)
        self.what = what
        self._lock = threading.Lock()
        self._obs: deque[tuple[float, float]] = deque(maxlen=512)  # (host t, drive t)
        self._last_raw: int | None = None
        self._wraps = 0
        self._last_ret = float("-inf")
        self._failed: str | None = None
        self._first = threading.Event()
        self.observations = 0

    # ---- feeding ----------------------------------------------------------------------
    def observe(self, periods: int, host_t: float | None = None) -> None:
        """One observation: the drive's period count ``periods`` (UNSIGNED32, unwrapped
        here) seen at host time ``host_t`` (``time.time()``; a frame's timestamp)."""
        h = time.time() if host_t is None else float(host_t)
        p = int(periods) & (_WRAP - 1)
        with self._lock:
            if self._last_raw is not None:
                back = (self._last_raw - p) & (_WRAP - 1)
                if 0 < back < _WRAP // 2:
                    return  # an older period (reordered frame): keep the newest
                if p < self._last_raw:
                    self._wraps += 1
            self._last_raw = p
            d = (self._wraps * _WRAP + p) / self.f_pwm_Hz
            if self._obs and h < self._obs[-1][0]:
                h = self._obs[-1][0]  # host timestamps from two threads: keep them ordered
            self._obs.append((h, d))
            self.observations += 1
        self._first.set()

    def fail(self, why: str) -> None:
        """The bus under the drive failed: every later :meth:`now` raises."""
        with self._lock:
            if self._failed is None:
                self._failed = why
        self._first.set()

    def wait_first(self, timeout_s: float) -> bool:
        """Whether an observation arrived within ``timeout_s`` (host s)."""
        return self._first.wait(timeout_s) and self._failed is None

    # ---- reading ----------------------------------------------------------------------
    def _rate(self) -> float:
        """Drive seconds per host second over the last second of observations."""
        h1, d1 = self._obs[-1]
        h0, d0 = h1, d1
        for h, d in reversed(self._obs):
            h0, d0 = h, d
            if h1 - h <= 1.0:
                continue
            break
        if h1 - h0 < 0.05:
            return 1.0
        return min(100.0, max(1e-3, (d1 - d0) / (h1 - h0)))

    def rate(self) -> float:
        """Drive seconds per host second (1.0 until a tenth of a second was observed)."""
        with self._lock:
            return self._rate() if self._obs else 1.0

    def _check(self, h: float) -> tuple[float, float]:
        if self._failed is not None:
            raise DriveLost(f"{self.what} lost: {self._failed}")
        if not self._obs:
            raise DriveLost(f"{self.what} publishes no time (0x2090:3 in a TPDO): is it "
                            "OPERATIONAL and is SYNC produced?")
        hl, dl = self._obs[-1]
        if h - hl > self.lost_s:
            raise DriveLost(f"{self.what} lost: no time from it for {h - hl:.2f} s (its bus "
                            "or its process is gone)")
        return hl, dl

    def lost(self) -> str | None:
        """Why the drive counts as lost now (None while it answers); never raises."""
        try:
            with self._lock:
                self._check(time.time())
        except DriveLost as e:
            return str(e)
        return None

    def now(self) -> float:
        """Drive time (s); raises :class:`DriveLost` for a lost drive."""
        h = time.time()
        with self._lock:
            hl, dl = self._check(h)
            t = max(dl + (h - hl) * self._rate(), self._last_ret)
            self._last_ret = t
            return t

    def of_host(self, host_t: float) -> float:
        """Drive time at a host time (a frame's timestamp), from the observation
        nearest before it and the present rate; NaN before the first observation."""
        with self._lock:
            if not self._obs:
                return float("nan")
            rate = self._rate()
            for h, d in reversed(self._obs):
                if h <= host_t:
                    return d + (host_t - h) * rate
            h, d = self._obs[0]
            return d + (host_t - h) * rate

    def sleep_until(self, t_s: float) -> None:
        """Block until :meth:`now` >= ``t_s`` (in slices; raises :class:`DriveLost`)."""
        while True:
            n = self.now()
            if n >= t_s:
                return
            wait = (t_s - n) / self.rate()
            time.sleep(min(max(wait, 0.0005), self.slice_s))
