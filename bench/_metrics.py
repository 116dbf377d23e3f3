"""Metrics over a time window, with the project-wide names (issue 3).

Definitions follow ``sim_fallback._sim.compute_metrics`` so numbers agree with
the simulator's own scenario runs:

* ``position_error_rms_rad`` / ``position_error_max_rad``: wrapped electrical
  angle error ``theta_e - theta_hat`` (rad), RMS / max of the absolute value.
* ``position_error_rms_mm``: the RMS error as mover displacement (mm).
* ``speed_error_max_rpm`` / ``speed_error_max_mps``: max ``|omega_hat - omega|``
  (estimate vs truth) in rotary-equivalent r/min and in m/s.
* ``settling_time_s``: time from the window start after which ``|error|``,
  averaged over ``settle_avg_s``, stays within ``settle_band_rad`` until the
  window end (NaN if never).

They need the true angle, which only the simulated drive (or a reference
encoder) provides.
"""

from __future__ import annotations

import math

import numpy as np

from bench._units import MotorUnits

#: Channels a metric computation needs (s, rad, rad/s electrical).
TRUTH_CHANNELS = ("t_s", "theta_e_rad", "theta_hat_rad", "omega_e_radps", "omega_hat_radps")


def wrap_pi(x: np.ndarray) -> np.ndarray:
    """Wrap angles (rad) into [-pi, pi)."""
    return (np.asarray(x) + np.pi) % (2.0 * np.pi) - np.pi


def compute_metrics(data: dict[str, np.ndarray], units: MotorUnits, t0_s: float, t1_s: float,
                    settle_band_rad: float = 0.05, settle_avg_s: float = 1e-3
                    ) -> dict[str, float]:
    """Metrics of ``data`` restricted to ``t0_s <= t <= t1_s``.

    Parameters
    ----------
    data : dict of ndarray
        At least :data:`TRUTH_CHANNELS`; ``t_s`` in sequence time (s).
    units : MotorUnits
        Pole pitch and pole pairs for the mm and r/min conversions.
    t0_s, t1_s : float
        Window (s).
    settle_band_rad, settle_avg_s : float
        Settling band (rad electrical) and averaging length (s).

    Returns
    -------
    dict
        Metric name -> value (NaN when the window holds no samples).
    """
    missing = [c for c in TRUTH_CHANNELS if c not in data]
    if missing:
        raise KeyError(f"metrics need channels {missing} (true angle: simulated drive only)")
    t = np.asarray(data["t_s"])
    m = (t >= t0_s - 1e-12) & (t <= t1_s + 1e-12)
    nan = float("nan")
    if not np.any(m):
        return dict.fromkeys(("position_error_rms_rad", "position_error_max_rad",
                              "position_error_rms_mm", "speed_error_max_rpm",
                              "speed_error_max_mps", "settling_time_s"), nan)
    tw = t[m]
    e = wrap_pi(np.asarray(data["theta_e_rad"])[m] - np.asarray(data["theta_hat_rad"])[m])
    w_err = np.asarray(data["omega_hat_radps"])[m] - np.asarray(data["omega_e_radps"])[m]
    rms = float(np.sqrt(np.mean(e**2)))
    mx = float(np.max(np.abs(e)))
    sp = float(np.max(np.abs(w_err)))
    dt = float(np.median(np.diff(tw))) if tw.size > 1 else 1.0
    n_avg = max(1, int(round(settle_avg_s / max(dt, 1e-12))))
    ea = np.convolve(np.abs(e), np.ones(n_avg) / n_avg, mode="same")
    bad = np.nonzero(ea > settle_band_rad)[0]
    if bad.size == 0:
        ts = 0.0
    elif bad[-1] + 1 >= tw.size:
        ts = nan
    else:
        ts = float(tw[bad[-1] + 1] - t0_s)
    v_err = sp * units.pole_pitch_m / math.pi
    return {
        "position_error_rms_rad": rms,
        "position_error_max_rad": mx,
        "position_error_rms_mm": units.rad_e_to_mm(rms),
        "speed_error_max_rpm": units.mps_to_rpm(v_err),
        "speed_error_max_mps": v_err,
        "settling_time_s": ts,
    }
