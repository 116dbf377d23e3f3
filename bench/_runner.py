"""Execute a validated sequence against a drive, evaluate expectations.

Safety: whatever happens inside :meth:`Runner.run` (an expectation evaluated,
a drive error, an exception in the bench, Ctrl-C / SIGINT, SIGTERM), the
``finally`` path removes the load and disables the drive (SWITCH ON
DISABLED, PWM off) before the exception propagates. A second Ctrl-C during
that path is ignored, so it cannot be cut short.
"""

from __future__ import annotations

import contextlib
import logging
import math
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from typing import Any, Protocol

import numpy as np

from bench._drive import DriveFault, DriveLeftState, DriveLost
from bench._evidence import NO_SENSOR
from bench._load import LoadDevice, NoLoad
from bench._sequence import Sequence, Step
from bench._units import MotorUnits
from sim_fallback.metrics import (
    METRIC_DEFS,
    METRIC_NAMES,
    TRUE_CHANNELS,
    compute_metrics,
    default_window,
    run_metrics,
    window_mask,
)

log = logging.getLogger("bench.runner")


class DriveLike(Protocol):
    """What the runner needs from a drive (:class:`bench.Drive` implements it)."""

    clock: Any

    def enable(self, mode: str = "speed") -> None: ...
    def disable(self) -> None: ...
    def set_mode(self, mode: str) -> None: ...
    def set_speed_mps(self, v_mps: float) -> None: ...
    def set_force_N(self, force_N: float) -> None: ...
    def check(self) -> None: ...


class Recorder(Protocol):
    """Where the runner puts events and gets truth data from (see bench._logging)."""

    def event(self, t_s: float, kind: str, detail: dict[str, Any]) -> None: ...
    def truth(self) -> dict[str, np.ndarray] | None: ...
    def trace_window(self, name: str, t0_s: float, t1_s: float, signals: list[str]) -> None: ...


class InterruptGuard:
    """Ctrl-C / SIGTERM while a run is stopping must not stop the stopping.

    Inside the guard the first signal raises ``KeyboardInterrupt`` (the run stops, the
    drive is disabled) and switches to *stopping*; from then on, and from
    :meth:`begin_stop` on (a normal end or an error), further signals are announced
    and ignored until the guard exits, so a second Ctrl-C 10-50 ms after the first
    can neither interrupt disabling the drive nor skip the report and summary.
    Main thread only (elsewhere a no-op). ``kill -9`` still ends the process.
    """

    def __init__(self, say: Callable[[str], None] | None = None, stopping: bool = False
                 ) -> None:
        self.say = say or (lambda m: print(m, file=sys.stderr, flush=True))
        self.stopping = stopping
        self.ignored = 0
        self._old: dict[int, Any] = {}

    def begin_stop(self) -> None:
        self.stopping = True

    def _handler(self, signum: int, frame: Any) -> None:
        if not self.stopping:
            self.stopping = True
            raise KeyboardInterrupt(f"signal {signum}")
        self.ignored += 1
        if self.ignored == 1:
            self.say("bench: already stopping - the drive is being disabled and the run "
                     "saved; please wait (about a second)")

    def __enter__(self) -> InterruptGuard:
        if threading.current_thread() is threading.main_thread():
            self._old = {sig: signal.signal(sig, self._handler)
                         for sig in (signal.SIGINT, signal.SIGTERM)}
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, h in self._old.items():
            signal.signal(sig, h)
        self._old = {}


@dataclass
class ExpectResult:
    """Outcome of one ``expect`` step.

    Attributes
    ----------
    name : str
        ``<metric>@[t0,t1]`` unless the step names itself.
    metric : str
    window_s : tuple of float
        Evaluation window in sequence time (s).
    measured : float
        Metric value (NaN if unavailable).
    passed : bool
    criterion : str
        E.g. ``<= 0.01`` or ``== 1 ± 0.1``.
    message : str
        Explanation when failed.
    line : int
        Line of the expect step in the sequence file.
    paper : float or None
        The value the reference paper claims for this metric (``paper:`` in the
        step), judged with the same operator; reported beside the bench's own
        limit so a claim that is not reproduced stays visible.
    paper_met : bool or None
        Whether the measurement also meets the paper's value.
    """

    name: str
    metric: str
    window_s: tuple[float, float]
    measured: float
    passed: bool
    criterion: str
    message: str = ""
    line: int = 0
    paper: float | None = None
    paper_met: bool | None = None
    doc: str = ""
    judged: bool = True

    @property
    def status(self) -> str:
        """``PASS``, ``FAIL`` or ``NOT JUDGED`` (the metric needs what the run did not
        have: a reference sensor, a signal the link does not carry; ``message`` says)."""
        return "NOT JUDGED" if not self.judged else ("PASS" if self.passed else "FAIL")


@dataclass
class RunResult:
    """Outcome of a run.

    Attributes
    ----------
    sequence : str
    passed : bool
        Every expectation passed and nothing went wrong.
    expectations : list of ExpectResult
    metrics : dict
        Every metric over its default window (:mod:`sim_fallback.metrics`:
        ``[settle_s, end]``, the settling time ``[0, end]``); NaN when the
        truth is unavailable.
    metric_windows : dict
        Metric name -> the window ``(t0_s, t1_s)`` its headline value covers.
    error : str or None
        Exception text if the run was aborted.
    aborted : bool
        Interrupted (Ctrl-C / signal) or failed with an exception.
    safe_state : str
        What the safe-state path reported (``disabled`` or an error text).
    duration_s : float
        Sequence time at the end (s).
    wall_s : float
        Wall time of the run (s).
    events : list of dict
    """

    sequence: str
    passed: bool = False
    expectations: list[ExpectResult] = field(default_factory=list)
    metrics: dict[str, float] = field(default_factory=dict)
    metric_windows: dict[str, tuple[float, float]] = field(default_factory=dict)
    error: str | None = None
    aborted: bool = False
    safe_state: str = ""
    duration_s: float = 0.0
    wall_s: float = 0.0
    events: list[dict[str, Any]] = field(default_factory=list)
    #: what the run was judged on (bench._evidence.Evidence.to_dict())
    evidence: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class _NullRecorder:
    def __init__(self) -> None:
        self.events: list[dict[str, Any]] = []

    def event(self, t_s: float, kind: str, detail: dict[str, Any]) -> None:
        self.events.append({"t_s": t_s, "kind": kind, **detail})

    def truth(self) -> dict[str, np.ndarray] | None:
        return None

    def evidence_channels(self, until_s: float | None = None) -> dict[str, np.ndarray] | None:
        return None

    def trace_window(self, name: str, t0_s: float, t1_s: float, signals: list[str]) -> None:
        pass


def _criterion(p: dict[str, Any]) -> str:
    if "op" in p:
        return f"{p['op']} {p['limit']:g}"
    return f"== {p['value']:g} ± {p['tolerance']:g}"


def evaluate(p: dict[str, Any], measured: float) -> bool:
    """Whether ``measured`` meets an expect step's criterion (NaN never does)."""
    if measured is None or not math.isfinite(measured):
        return False
    if "op" in p:
        lim = float(p["limit"])
        return {"<": measured < lim, "<=": measured <= lim, ">": measured > lim,
                ">=": measured >= lim}[p["op"]]
    return abs(measured - float(p["value"])) <= float(p["tolerance"])


class Runner:
    """Runs sequences on a drive.

    Parameters
    ----------
    drive : DriveLike
        The drive under test (its ``clock`` is the run's time base).
    units : MotorUnits
        For r/min and N·m conversions.
    load : LoadDevice
        Load machine (hardware) or plant load (sim); :class:`NoLoad` if None.
    recorder : Recorder
        Event log and truth source; a null recorder if None.
    progress : callable(t_s, total_s), optional
        Called while waiting, with the sequence time (s).
    ramp_step_s : float
        Update period of stepwise ramps (s).
    f_pwm_Hz : float, optional
        Control rate of the drive; enables the drive's trace buffer for
        ``trace_capture`` steps (else only the recorded window is marked).
    """

    def __init__(self, drive: DriveLike, units: MotorUnits, load: LoadDevice | None = None,
                 recorder: Recorder | None = None,
                 progress: Callable[[float, float], None] | None = None,
                 ramp_step_s: float = 0.005, f_pwm_Hz: float | None = None) -> None:
        self.drive = drive
        self.units = units
        self.load: LoadDevice = load or NoLoad()
        self.rec: Recorder = recorder or _NullRecorder()
        self.progress = progress
        self.ramp_step_s = ramp_step_s
        self.f_pwm_Hz = f_pwm_Hz
        #: drive trace captures armed during the run (uploaded by the session afterwards)
        self.traces: list[dict[str, Any]] = []
        self.clock = drive.clock
        self._t0 = 0.0
        #: set by run_sequence: its InterruptGuard, so stopping is never interrupted
        self.guard: InterruptGuard | None = None
        self._speed_mps = 0.0
        self._force_N = 0.0
        self._load_N = 0.0
        #: why the drive was lost mid-run (bench._drive.DriveLost), None while it answers
        self.drive_lost: str | None = None
        self._last_now = 0.0  # the last sequence time read (kept for a lost drive)

    # ---- time -------------------------------------------------------------------------
    def now(self) -> float:
        """Sequence time (s)."""
        t = self.clock.now() - self._t0
        self._last_now = t
        return t

    def _now_or_last(self) -> float:
        """Sequence time, or the last one read when the drive (its clock) is lost."""
        try:
            return self.now()
        except Exception:  # noqa: BLE001 - DriveLost: the clock stopped with the drive
            return self._last_now

    def _check_drive(self) -> None:
        """Stop the sequence when the drive is no longer doing what the run asked
        (:meth:`bench.Drive.check`, the bench's one watch): a fault (EMCY or statusword),
        the drive leaving OPERATION ENABLED without one (another master), its time
        stopped. What follows would run on a drive that has switched its power stage off,
        and every figure after it would measure a coasting mover, not the estimator."""
        check = getattr(self.drive, "check", None)
        if check is None:
            return
        try:
            check()
        except (DriveFault, DriveLeftState) as e:
            at = f" at t = {self._now_or_last():.3f} s"
            if isinstance(e, DriveFault):
                raise DriveFault(f"{e}{at}", e.code) from None
            raise DriveLeftState(f"{e}{at}") from None

    def _sleep_until(self, t_seq: float, total: float) -> None:
        """Sleep in slices so progress updates, Ctrl-C and a drive fault stay responsive."""
        while True:
            now = self.now()
            if self.progress:
                self.progress(min(now, total), total)
            self._check_drive()
            if now >= t_seq - 1e-9:  # clocks advance in steps; avoid float ties
                return
            # slices of the clock's choice (10 ms on hardware): a fault stops the
            # sequence within one slice of its EMCY
            self.clock.sleep_until(self._t0 + min(t_seq, now + getattr(
                self.clock, "slice_s", 0.01)))

    # ---- steps ------------------------------------------------------------------------
    def _speed(self, p: dict[str, Any], key: str = "value") -> float:
        return self.units.speed_to_mps(float(p[key]), p["unit"])

    def _force(self, p: dict[str, Any], key: str = "value") -> float:
        return self.units.force_to_N(float(p[key]), p["unit"])

    def _ramp(self, setter: Callable[[float], None], start: float, end: float,
              duration: float, t_start: float, total: float, step: float) -> None:
        n = max(1, int(math.ceil(duration / step)))
        for k in range(1, n + 1):
            setter(start + (end - start) * k / n)
            self._sleep_until(t_start + duration * k / n, total)

    def _do(self, step: Step, seq: Sequence, result: RunResult) -> None:
        p = step.params
        kind = step.kind
        d = self.drive
        total = seq.duration_s
        if kind == "enable":
            self.load.enable()
            d.enable(p.get("mode", "speed"))
        elif kind == "disable":
            if self._t_disable is None:
                self._t_disable = self.now()  # the headline metrics end here
            self._set_load(0.0)
            d.disable()
        elif kind == "set_mode":
            d.set_mode(p["mode"])
        elif kind == "set_speed":
            self._speed_mps = self._speed(p)
            d.set_speed_mps(self._speed_mps)
        elif kind == "set_force":
            self._force_N = self._force(p)
            d.set_force_N(self._force_N)
        elif kind == "ramp":
            step_s = float(p.get("step_s", self.ramp_step_s))
            if p["quantity"] == "speed":
                target = self._speed(p, "to")

                def setter(v: float) -> None:
                    self._speed_mps = v
                    d.set_speed_mps(v)
                start = self._speed_mps
            else:
                target = self._force(p, "to")

                def setter(v: float) -> None:
                    self._force_N = v
                    d.set_force_N(v)
                start = self._force_N
            self._ramp(setter, start, target, float(p["duration_s"]), step.t_start_s, total,
                       step_s)
        elif kind == "load_step":
            self._set_load(self._force(p))
        elif kind == "load_ramp":
            target = self._force(p, "to")
            dur = float(p["duration_s"])
            if self.load.ramp_force_N(target, dur):
                self._load_N = target
                self._sleep_until(step.t_start_s + dur, total)
            else:
                self._ramp(self._set_load, self._load_N, target, dur, step.t_start_s, total,
                           self.ramp_step_s)
        elif kind == "wait":
            self._sleep_until(step.t_start_s + float(p["duration_s"]), total)
        elif kind == "trace_capture":
            t = self.now()
            pre = float(p.get("pre_s", 0.0))
            signals = list(p.get("signals", [])) or ["theta_hat_rad", "pll_err_rad",
                                                     "i_q_A", "omega_hat_radps"]
            self.rec.trace_window(p["name"], max(0.0, t - pre), t + float(p["duration_s"]),
                                  signals)
            arm = getattr(self.drive, "trace_capture", None)
            if arm is not None and self.f_pwm_Hz:
                try:  # the drive's own scope at the full control rate (uploaded at the end)
                    cfg = arm(signals, pre, self.f_pwm_Hz)
                    self.traces.append({"name": p["name"], "t_s": t, **cfg,
                                        "signals": signals})
                except Exception as e:  # noqa: BLE001 - a measurement, not a safety matter
                    log.warning("drive trace capture '%s' failed: %s", p["name"], e)
                    self.rec.event(t, "trace_failed", {"name": p["name"], "error": str(e)})
        elif kind == "expect":
            result.expectations.append(self._expect(step, seq))
        else:  # pragma: no cover - the schema forbids it
            raise ValueError(f"unknown step {kind}")

    def _set_load(self, force_N: float) -> None:
        self._load_N = force_N
        self.load.set_force_N(force_N)

    def _expect(self, step: Step, seq: Sequence) -> ExpectResult:
        p = step.params
        now = self.now()
        t0, t1 = (float(v) for v in p.get("window_s",
                                            default_window(p["metric"], seq.settle_s, now)))
        name = p.get("name") or f"{p['metric']}@[{t0:g},{t1:g}]s"
        data = self._evidence(until_s=t1)
        why = self._not_judged(p["metric"], data, (t0, t1))
        if why:
            return ExpectResult(name, p["metric"], (t0, t1), float("nan"), False, _criterion(p),
                                why, step.line, p.get("paper"), None, str(p.get("doc", "")),
                                judged=False)
        m = compute_metrics(data, self.units.pole_pitch_m, self.units.pole_pairs, (t0, t1),
                            (p["metric"],))[p["metric"]]
        ok = evaluate(p, m)
        msg = "" if ok else f"measured {m:.6g}, required {_criterion(p)}"
        paper = p.get("paper")
        paper_met = None
        if paper is not None:
            paper_met = evaluate({**p, "limit": paper} if "op" in p else
                                 {**p, "value": paper}, m)
            if not paper_met:
                msg = (msg + "; " if msg else "") + f"paper's {paper:g} not reproduced"
        return ExpectResult(name, p["metric"], (t0, t1), m, ok, _criterion(p), msg, step.line,
                            paper, paper_met, str(p.get("doc", "")))

    def _evidence(self, until_s: float | None = None) -> dict[str, np.ndarray] | None:
        get = getattr(self.rec, "evidence_channels", None)
        return get(until_s) if get is not None else self.rec.truth()

    def _not_judged(self, metric: str, data: dict[str, np.ndarray] | None,
                    window: tuple[float, float]) -> str:
        """Why ``metric`` cannot be judged on this run's evidence ("" when it can)."""
        ev = getattr(self.rec, "evidence", None)
        d = METRIC_DEFS[metric]
        if d.needs_truth and ev is not None and not ev.has_truth:
            return ev.note or NO_SENSOR
        if data is None:
            return ("metric unavailable: nothing recorded to judge it on (no truth, no "
                    "signals from the drive)")
        missing = [c for c in d.channels if c not in data]
        if missing:
            via = f" over {ev.path}" if ev is not None else ""
            return (f"not judged: {', '.join(missing)} not recorded{via}"
                    + (" (the drive publishes it on the serial link: give --serial)"
                       if ev is not None and ev.path == "TPDO" else ""))
        if d.needs_truth:
            t = np.asarray(data["t_s"])
            w = window_mask(t, *window)
            bad = [c for c in d.channels if c in TRUE_CHANNELS
                   and np.any(~np.isfinite(np.asarray(data[c], dtype=float)[w]))]
            if bad:
                i = int(np.argmax(~np.isfinite(np.asarray(data[bad[0]], dtype=float)[w])))
                return (f"not judged: the reference sensor had no valid reading at t = "
                        f"{float(t[w][i]):.3f} s in the window (a sensor fault)")
        return ""

    # ---- safe state -------------------------------------------------------------------
    def safe_state(self) -> str:
        """Remove the load and disable the drive; never raises. Returns a status text.
        A lost drive (its time stopped, its bus failed) is not waited for: nothing the
        bench sends reaches it; its own supervision switches it off."""
        if self.drive_lost is not None:
            with contextlib.suppress(Exception):
                self.load.disable()
            return (f"SAFE STATE NOT CONFIRMED: {self.drive_lost}; the drive's heartbeat "
                    "consumer (0x1016) switches its PWM off without the bench's heartbeat")
        in_main = threading.current_thread() is threading.main_thread()
        old = signal.signal(signal.SIGINT, signal.SIG_IGN) if in_main else None
        try:
            msgs = []
            for what, fn in (("load", self._load_off), ("drive", self.drive.disable)):
                for attempt in range(3):
                    try:
                        fn()
                        break
                    except Exception as e:  # noqa: BLE001 - we must keep trying
                        log.error("safe state: %s disable attempt %d failed: %s", what,
                                  attempt + 1, e)
                        if attempt == 2:
                            msgs.append(f"{what}: {e}")
                        time.sleep(0.05)
            return "disabled" if not msgs else "SAFE STATE FAILED: " + "; ".join(msgs)
        finally:
            if in_main and old is not None:
                signal.signal(signal.SIGINT, old)

    def _load_off(self) -> None:
        try:
            self.load.set_force_N(0.0)
        finally:
            self.load.disable()

    # ---- run --------------------------------------------------------------------------
    def run(self, seq: Sequence) -> RunResult:
        """Execute ``seq``; the drive is disabled on every exit path.

        Exceptions (including KeyboardInterrupt) propagate after the safe
        state; the partial :class:`RunResult` is available as
        ``self.result``.
        """
        for _ in self.iter_steps(seq):
            pass
        return self.result

    def iter_steps(self, seq: Sequence) -> Iterator[Step]:
        """Execute ``seq`` one step per ``next()`` (``bench shell``); yields each step
        after doing it. When the generator ends, is closed (``.close()``) or collected,
        the drive goes to the safe state and ``self.result`` holds the verdict of what
        ran (a closed one is aborted). Sequence time keeps running between steps: on a
        drive paced to the wall clock, a ``wait`` that is already past returns at once.
        """
        result = RunResult(sequence=seq.name)
        self.result = result
        self._t_disable: float | None = None
        wall0 = time.monotonic()
        self._t0 = 0.0
        try:
            self._t0 = self.clock.now()  # a drive lost before the first step: aborted too
            mark = getattr(self.rec, "mark_start", None)
            if mark is not None:
                mark(self._t0)
            self.rec.event(0.0, "start", {"sequence": seq.name})
            for step in seq.steps:
                if step.kind != "enable":  # a fault before enable is enable's to report
                    self._check_drive()
                self.rec.event(self.now(), "step", {"index": step.index, "step": step.kind,
                                                    "params": step.params})
                self._do(step, seq, result)
                yield step
            result.duration_s = self.now()
        except BaseException as e:
            if isinstance(e, DriveLost):
                self.drive_lost = str(e)
            result.aborted = True
            result.error = f"{type(e).__name__}: {e}" if str(e) else type(e).__name__
            self.rec.event(self._now_or_last(), "abort", {"error": result.error})
            raise
        finally:
            if self.guard is not None:  # run_sequence's guard spans the saving too
                self.guard.begin_stop()
                self._finish(seq, result, wall0)
            else:
                with InterruptGuard(stopping=True):
                    self._finish(seq, result, wall0)
        return result

    def _finish(self, seq: Sequence, result: RunResult, wall0: float) -> None:
        """Safe state, metrics and verdict (runs with interrupts deferred)."""
        result.safe_state = self.safe_state()
        now = self._now_or_last()
        self.rec.event(now, "safe_state", {"status": result.safe_state})
        result.duration_s = result.duration_s or now
        ev = getattr(self.rec, "evidence", None)
        if ev is not None:
            result.evidence = ev.to_dict()
        try:
            truth = self._evidence()
        except Exception as e:  # noqa: BLE001 - never mask the original exception
            log.error("truth data unavailable: %s", e)
            truth = None
        if truth is not None and len(truth.get("t_s", ())) > 0:
            # default windows end just before the drive was disabled (not at the end of
            # the record: the sample at the disable instant already has the reference at
            # 0, which made the main job's tracking error read 99 r/min)
            t_end = min(result.duration_s, seq.duration_s)
            if self._t_disable is not None and self._t_disable > seq.settle_s:
                t_end = min(t_end, self._t_disable - 1e-9)
            result.metrics, result.metric_windows = run_metrics(
                truth, self.units.pole_pitch_m, self.units.pole_pairs, seq.settle_s, t_end)
            if ev is not None and not ev.has_truth:  # never a number without its truth
                for k in METRIC_NAMES:
                    if METRIC_DEFS[k].needs_truth:
                        result.metrics[k] = float("nan")
        else:
            result.metrics = dict.fromkeys(METRIC_NAMES, float("nan"))
        result.passed = (not result.aborted and result.safe_state == "disabled"
                         and all(x.passed for x in result.expectations if x.judged))
        result.wall_s = time.monotonic() - wall0
        if isinstance(self.rec, _NullRecorder):
            result.events = self.rec.events
