"""Per-run analyses of a simulated paper scenario, beyond the headline metrics.

A campaign (bench/_campaign.py) computes these in the worker, from the run's
full-rate record, and keeps only the numbers (and, if asked, a decimated trace)
in its Parquet results; the paper reproduction (bench/_reproduction.py) renders
its tables and figures from those results alone.

Names, as a campaign lists them under ``metrics:``:

* ``<window>.<m>`` with a window of ``base.windows`` (``name: [t0, t1]``, s, both
  ends included, as every metric of :mod:`sim_fallback.metrics`) and ``m`` one of
  :data:`WINDOW_METRICS`; the first five are short names of that module's metrics
  (:data:`WINDOW_ALIASES`), computed by it;
* :data:`EVENT_METRICS` (recovery after the event at ``base.event_s``);
* :data:`STARTUP_METRICS` (closed-loop start and error after settling);
* :data:`RUN_METRICS` (what the drive did: valid, faulted when, reached RUN).

Window, event and start-up metrics are NaN for a run that is not *valid* (the
drive refused or faulted, or never closed the loop: the simulator's own rule);
run metrics describe every run, refused ones included.

Angles are electrical radians; speeds rotary-equivalent r/min; the speed error
is the drive's filtered estimate ``omega_f`` minus the true speed.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from protocols.generated.od_names import StartPhase
from sim_fallback.metrics import compute_metrics, window_mask

#: Statistics over a window: position error (el. rad) RMS / max |.| / mean, speed
#: error (r/min) max |.| / RMS, RMS of the true d / q current minus its mean over one
#: injection period (A, the HF ripple), and the position error RMS over the samples in
#: the window in which the drive was in closed loop (RUN; for refused or faulted runs).
WINDOW_METRICS = ("pos_rms", "pos_max", "pos_mean", "spd_max", "spd_rms", "ripple_d",
                  "ripple_q", "run_err_rms")
#: Campaign short names of :mod:`sim_fallback.metrics` metrics (one definition each).
WINDOW_ALIASES = {"pos_rms": "position_error_rms_rad", "pos_max": "position_error_max_rad",
                  "pos_mean": "position_error_mean_rad",
                  "spd_max": "speed_filtered_estimate_error_max_rpm",
                  "spd_rms": "speed_filtered_estimate_error_rms_rpm"}
#: Times (s) from the event to the first return into a band after the disturbance's peak.
EVENT_METRICS = ("t_speed_back_s", "t_est_back_s", "t_pos_back_s")
#: Start of the closed loop (s) and max |position error| after ``settling_time_s``.
STARTUP_METRICS = ("t_run_s", "pos_max_after_settle")
#: 1/0 flags, the firmware's init status, the first fault sample (s) and max |error| in RUN.
RUN_METRICS = ("valid", "reached_run", "pwm_on", "init_status", "t_fault_s", "run_err_max_rad")
#: Signals a campaign may keep as decimated traces (columns ``trace.<signal>``).
TRACE_SIGNALS = ("t_s", "theta_e_rad", "theta_hat_rad", "position_error_rad", "speed_rpm",
                 "speed_estimate_rpm", "speed_error_rpm", "sogi_k_eff")

# band definitions for the event timings (docs/reproduction.md states them)
SPEED_BAND_RPM = 5.0        # true speed back within +-5 r/min of the reference
EST_BAND_RPM = 1.0          # speed estimation error back within the paper's +-1 r/min
POS_BAND_RAD = 0.02         # position error (10 ms moving RMS) back within 0.02 el. rad
AVG_S = 0.010               # moving-average window for the event timings
SPEED_PEAK_S = 0.3          # the speed deviation's peak is looked for in [event, event + 0.3 s]
EST_PEAK_S = 0.2            # the estimation and position errors' in [event, event + 0.2 s]

#: Channels the analyses read (the run records them at full rate).
CHANNELS = ("t_s", "theta_e_rad", "theta_hat_rad", "omega_e_radps", "omega_f_radps",
            "omega_hat_radps", "speed_ref_radps_e", "i_d_A", "i_q_A", "fault_code",
            "start_phase", "sogi_k_eff")


def is_window_metric(name: str, windows: Iterable[str]) -> bool:
    w, _, m = name.partition(".")
    return w in windows and m in WINDOW_METRICS


def needs_analysis(metrics: Iterable[str], windows: Iterable[str]) -> bool:
    ws = list(windows)
    return any(is_window_metric(m, ws) or m in EVENT_METRICS + STARTUP_METRICS + RUN_METRICS
               for m in metrics)


def _movavg(x: np.ndarray, n: int) -> np.ndarray:
    n = max(1, int(n))
    if x.size < n:
        return x.copy()
    return np.convolve(x, np.ones(n) / n, mode="same")


def _rpm(res: Any) -> float:
    return float(res.motor.radps_e_to_rpm(1.0))


def speed_error_rpm(res: Any) -> np.ndarray:
    """Reported (filtered) speed estimate minus true speed, r/min (rotary equivalent)."""
    return (res.data["omega_f_radps"] - res.data["omega_e_radps"]) * _rpm(res)


def window_metrics(res: Any, t0: float, t1: float) -> dict[str, float]:
    """Position error (el. rad) and speed error (r/min) statistics over [t0, t1], by
    their campaign short names (:data:`WINDOW_ALIASES`)."""
    m = res.motor
    got = compute_metrics(res.data, m.tau_m, float(m.pole_pairs), (t0, t1),
                          names=tuple(WINDOW_ALIASES.values()))
    return {short: got[name] for short, name in WINDOW_ALIASES.items()}


def hf_ripple(res: Any, t0: float, t1: float, n_inj: int) -> tuple[float, float]:
    """RMS of the HF current ripple (true d and q current minus its mean over one
    injection period of ``n_inj`` samples) over [t0, t1], A."""
    k = window_mask(res.data["t_s"], t0, t1)
    out = []
    for ch in ("i_d_A", "i_q_A"):
        x = res.data[ch][k]
        m = np.convolve(x, np.ones(n_inj) / n_inj, mode="valid")
        h = x[n_inj // 2: n_inj // 2 + m.size] - m
        out.append(float(np.sqrt(np.mean(h**2))))
    return out[0], out[1]


def _back_after_peak(t: np.ndarray, y: np.ndarray, t_ev: float, band: float,
                     t_peak_end: float) -> float:
    """Time from t_ev until y first returns within band after its peak in
    [t_ev, t_peak_end]; 0 if it never left; NaN if it never returns."""
    k = np.nonzero(t >= t_ev)[0]
    if k.size == 0:
        return float("nan")
    kp = k[t[k] <= t_peak_end]
    ip = kp[np.argmax(y[kp])]
    if y[ip] <= band:
        return 0.0
    back = np.nonzero((t > t[ip]) & (y <= band))[0]
    return float(t[back[0]] - t_ev) if back.size else float("nan")


def event_metrics(res: Any, t_ev: float) -> dict[str, float]:
    """Recovery times (s) after the event at ``t_ev``: the true speed's 10 ms average
    back within +-5 r/min of the reference, the 10 ms average of the speed estimation
    error back within +-1 r/min, the 10 ms moving RMS of the position error back
    within 0.02 el. rad."""
    d = res.data
    t = d["t_s"]
    n = max(1, int(round(AVG_S / (t[1] - t[0]))))
    n_true = d["omega_e_radps"] * _rpm(res)
    n_ref = d["speed_ref_radps_e"] * _rpm(res)
    dev = np.abs(_movavg(n_true - n_ref, n))
    est = np.abs(_movavg(speed_error_rpm(res), n))
    prms = np.sqrt(_movavg(res.position_error_rad**2, n))
    return {"t_speed_back_s": _back_after_peak(t, dev, t_ev, SPEED_BAND_RPM,
                                               t_ev + SPEED_PEAK_S),
            "t_est_back_s": _back_after_peak(t, est, t_ev, EST_BAND_RPM, t_ev + EST_PEAK_S),
            "t_pos_back_s": _back_after_peak(t, prms, t_ev, POS_BAND_RAD, t_ev + EST_PEAK_S)}


def startup_metrics(res: Any) -> dict[str, float]:
    """Closed-loop start (first RUN sample, s) and max |error| from the settling time on."""
    d = res.data
    t = d["t_s"]
    run = np.nonzero(d["start_phase"] == StartPhase.RUN)[0]
    ts = res.metrics["settling_time_s"]
    e = np.abs(res.position_error_rad)
    return {"t_run_s": float(t[run[0]]) if run.size else float("nan"),
            "pos_max_after_settle": (float(np.max(e[t >= ts])) if np.isfinite(ts)
                                     else float("nan"))}


def run_metrics(res: Any) -> dict[str, float]:
    """What the drive did, for every run (refused and faulted ones included)."""
    d = res.data
    t = d["t_s"]
    nz = np.nonzero(d["fault_code"])[0]
    run = d["start_phase"] == StartPhase.RUN
    return {"valid": float(res.valid), "reached_run": float(np.any(run)),
            "pwm_on": float(np.any(d["start_phase"] != StartPhase.IDLE)),
            "init_status": float(res.info.get("fw_init_status", -1)),
            "t_fault_s": float(t[nz[0]]) if nz.size else float("nan"),
            "run_err_max_rad": (float(np.max(np.abs(res.position_error_rad[run])))
                                if np.any(run) else float("nan"))}


def trace(res: Any, signals: Iterable[str], decimation: int) -> dict[str, list[float]]:
    """Decimated signals (every ``decimation``-th sample), as plain lists."""
    d = res.data
    rpm = _rpm(res)
    make = {"t_s": lambda: d["t_s"], "theta_e_rad": lambda: d["theta_e_rad"],
            "theta_hat_rad": lambda: d["theta_hat_rad"],
            "position_error_rad": lambda: res.position_error_rad,
            "speed_rpm": lambda: d["omega_e_radps"] * rpm,
            "speed_estimate_rpm": lambda: d["omega_f_radps"] * rpm,
            "speed_error_rpm": lambda: speed_error_rpm(res),
            "sogi_k_eff": lambda: d["sogi_k_eff"]}
    return {f"trace.{s}": np.asarray(make[s](), dtype=float)[::decimation].tolist()
            for s in signals}


def analyse(res: Any, metrics: Iterable[str], windows: Mapping[str, list[float]],
            event_s: float | None, n_inj: int) -> dict[str, float]:
    """The requested analysis metrics of one run (see the module docstring)."""
    want = list(metrics)
    out: dict[str, float] = {}
    if any(m in RUN_METRICS for m in want):
        rm = run_metrics(res)
        out.update({m: rm[m] for m in want if m in rm})
    cache: dict[str, dict[str, float]] = {}
    for m in want:
        if not is_window_metric(m, windows):
            continue
        w, _, name = m.partition(".")
        t0, t1 = windows[w]
        if name == "run_err_rms":
            k = window_mask(res.data["t_s"], t0, t1) & (res.data["start_phase"] == StartPhase.RUN)
            out[m] = (float(np.sqrt(np.mean(res.position_error_rad[k] ** 2))) if np.any(k)
                      else float("nan"))
        elif not res.valid:
            out[m] = float("nan")
        elif name in ("ripple_d", "ripple_q"):
            rd, rq = hf_ripple(res, t0, t1, n_inj)
            out[m] = rd if name == "ripple_d" else rq
        else:
            if w not in cache:
                cache[w] = window_metrics(res, t0, t1)
            out[m] = cache[w][name]
    if any(m in EVENT_METRICS for m in want):
        ev = (event_metrics(res, float(event_s)) if res.valid and event_s is not None
              else dict.fromkeys(EVENT_METRICS, math.nan))
        out.update({m: ev[m] for m in want if m in ev})
    if any(m in STARTUP_METRICS for m in want):
        sm = startup_metrics(res) if res.valid else dict.fromkeys(STARTUP_METRICS, math.nan)
        out.update({m: sm[m] for m in want if m in sm})
    return out
