"""The project's accuracy metrics: one definition, used everywhere.

The bench (``bench run`` expectations, summaries, reports), the simulator API
(:func:`sim_fallback.run_scenario`) and the paper reproduction all compute
their figures here, so a name always means the same number.

Why here: this module is public, depends on numpy only (no C library, no
bench code), and ships in the same wheel as ``bench``; the bench imports it
without reaching into private simulator modules, and the simulator does not
depend on the bench.

Every metric is defined once in :data:`METRICS` (signal, statistic, unit,
default window). The table is rendered into the HTML report and docs by
:func:`definitions_markdown` / :func:`definitions_rows`.

Conventions
-----------
* Angles are electrical radians; ``theta_e = pi x / tau`` (tau: pole pitch).
* Rotary-equivalent speed: ``n [r/min] = omega_e / p * 60 / (2 pi)`` with the
  motor's pole pairs p (``r = p tau / pi``).
* A window ``[t0, t1]`` (s) includes both ends. The *default* window of a
  metric is ``[settle_s, end]`` (``"settled"``) or ``[0, end]``
  (``"whole run"``; the settling time is measured from the window start).
* A metric whose signals were not recorded, or whose window holds no sample,
  is NaN.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from protocols.generated.od_names import StartPhase
from protocols.units import m_per_electrical_rad, radps_e_to_rpm

#: Settling band on the averaged position error (rad electrical).
SETTLE_BAND_RAD = 0.05
#: Moving-average length applied to |position error| before the band test (s).
SETTLE_AVG_S = 1e-3
#: Minimum time the averaged error must stay in the band at the window end (s).
SETTLE_HOLD_S = 0.05


@dataclass(frozen=True)
class MetricDef:
    """Definition of one metric.

    Attributes
    ----------
    name : str
        Metric name (unit suffix included).
    signal : str
        The signal the statistic is taken of, as a formula over recorded
        channels.
    statistic : str
        What is computed over the window.
    unit : str
        Unit of the value.
    window : {"settled", "whole run"}
        Default window: ``[settle_s, end]`` or ``[0, end]``.
    channels : tuple of str
        Recorded channels the metric needs (besides ``t_s``).
    """

    name: str
    signal: str
    statistic: str
    unit: str
    window: str
    channels: tuple[str, ...]

    @property
    def needs_truth(self) -> bool:
        """Whether the metric needs the true position or speed (:data:`TRUE_CHANNELS`):
        the simulator's truth, or on a rig a reference sensor. The others judge the
        drive from what it says about itself."""
        return any(c in TRUE_CHANNELS for c in self.channels)


#: the channels of the truth: the true electrical angle and speed
TRUE_CHANNELS: tuple[str, ...] = ("theta_e_rad", "omega_e_radps")

_POS = ("theta_e_rad", "theta_hat_rad")
_EST = ("omega_e_radps", "omega_hat_radps")
_FILT = ("omega_e_radps", "omega_f_radps")
_TRK = ("omega_e_radps", "speed_ref_radps_e")

# the signals, written once for a metric and its twins in other units
_E = ("e = wrap(theta_e - theta_hat): true minus estimated electrical angle, "
      "wrapped to [-pi, pi)")
_E_MM = "e (true minus estimated electrical angle, wrapped) as mover displacement e tau / pi"
_S_EST = ("omega_hat - omega_e: the PLL's speed estimate (the drive reports it as "
          "velocity actual value 0x606C) minus the true speed")
_S_FILT = ("omega_f - omega_e: the low-pass filtered speed estimate the speed loop "
           "regulates on minus the true speed")
_S_TRK = ("omega_e - omega_ref: true speed minus the drive's speed reference "
          "(speed mode; includes the transient after each reference change)")
_S_TRK_EST = ("omega_f - omega_ref: the drive's filtered speed estimate minus its speed "
              "reference (no truth needed: the drive's own view of its tracking)")
_RPM, _MPS, _LIN = "r/min (rotary equivalent)", "m/s", ", as linear speed"
_EST_CH = ("omega_f_radps", "speed_ref_radps_e")

#: The metric definitions (the order is the order of every result dict). A metric with a
#: unit suffix (:data:`UNIT_SUFFIXES`) has twins of the same statistic in other units
#: (``..._rpm`` / ``..._mps``, ``..._rad`` / ``..._mm``), computed by the same code.
METRICS: tuple[MetricDef, ...] = (
    MetricDef("position_error_rms_rad", _E, "RMS of e", "rad (electrical)", "settled", _POS),
    MetricDef("position_error_max_rad", "e as above", "max |e|", "rad (electrical)",
              "settled", _POS),
    MetricDef("position_error_rms_mm", _E_MM, "RMS", "mm", "settled", _POS),
    MetricDef("position_error_mean_rad", "e as above", "mean of e (the bias)",
              "rad (electrical)", "settled", _POS),
    MetricDef("speed_estimate_error_max_rpm", _S_EST, "max |.|", _RPM, "settled", _EST),
    MetricDef("speed_estimate_error_max_mps", _S_EST + _LIN, "max |.|", _MPS, "settled", _EST),
    MetricDef("speed_filtered_estimate_error_max_rpm", _S_FILT, "max |.|", _RPM, "settled",
              _FILT),
    MetricDef("speed_filtered_estimate_error_rms_rpm", "omega_f - omega_e as above",
              "RMS", _RPM, "settled", _FILT),
    MetricDef("speed_tracking_error_max_rpm", _S_TRK, "max |.|", _RPM, "settled", _TRK),
    MetricDef("settling_time_s",
              f"|e| averaged over {SETTLE_AVG_S * 1e3:g} ms (centred moving average)",
              f"time from the window start until it enters {SETTLE_BAND_RAD:g} rad and "
              f"stays there to the window end; NaN if it never does or stays less than "
              f"{SETTLE_HOLD_S * 1e3:g} ms", "s", "whole run", _POS),
    # judged without truth: what the drive says about itself
    MetricDef("speed_tracking_estimate_error_max_rpm", _S_TRK_EST, "max |.|", _RPM,
              "settled", _EST_CH),
    MetricDef("estimate_settling_time_s",
              f"|PLL error| (the drive's own angle-error signal) averaged over "
              f"{SETTLE_AVG_S * 1e3:g} ms",
              f"time from the window start until it enters {SETTLE_BAND_RAD:g} rad and stays "
              f"there to the window end (as settling_time_s, without truth)", "s",
              "whole run", ("pll_err_rad",)),
    MetricDef("current_q_max_A",
              "i_q: the drive's measured thrust current (estimated frame)", "max |i_q|", "A",
              "settled", ("i_dq_hat_A",)),
    # the linear twins of the metrics above (a linear motor is reported in m/s and mm)
    MetricDef("position_error_max_mm", _E_MM, "max |.|", "mm", "settled", _POS),
    MetricDef("position_error_mean_mm", _E_MM, "mean (the bias)", "mm", "settled", _POS),
    MetricDef("speed_filtered_estimate_error_max_mps", _S_FILT + _LIN, "max |.|", _MPS,
              "settled", _FILT),
    MetricDef("speed_filtered_estimate_error_rms_mps", _S_FILT + _LIN, "RMS", _MPS,
              "settled", _FILT),
    MetricDef("speed_tracking_error_max_mps", _S_TRK + _LIN, "max |.|", _MPS, "settled", _TRK),
    MetricDef("speed_tracking_estimate_error_max_mps", _S_TRK_EST + _LIN, "max |.|", _MPS,
              "settled", _EST_CH),
)

#: Metric names in result order.
METRIC_NAMES: tuple[str, ...] = tuple(m.name for m in METRICS)
#: Definitions by name.
METRIC_DEFS: dict[str, MetricDef] = {m.name: m for m in METRICS}

#: The unit suffixes of metric names: a metric is ``<statistic>_<suffix>``; metrics of one
#: statistic in different units (``speed_estimate_error_max_rpm`` / ``_mps``) are twins,
#: computed by the same code (:func:`compute_metrics`) in another unit.
UNIT_SUFFIXES: tuple[str, ...] = ("rad", "mm", "rpm", "mps")
#: Which units a rotary-equivalent and a linear motor are reported in: ``rad`` (electrical)
#: is both's, ``rpm`` only a rotary-equivalent motor's, ``mm`` and ``mps`` a linear one's
#: (the bench shows these; every metric is computed for every run).
SUFFIX_SYSTEM: dict[str, str] = {"rad": "", "mm": "linear", "rpm": "rotary", "mps": "linear"}


def metric_base(name: str) -> tuple[str, str]:
    """``(statistic, unit suffix)`` of a metric name (suffix "" for s, A, ... metrics)."""
    base, _, suffix = name.rpartition("_")
    return (base, suffix) if suffix in UNIT_SUFFIXES else (name, "")


def metric_system(name: str) -> str:
    """"rotary" for a rotary-equivalent-only metric (r/min), "linear" for a linear-only
    one (m/s, mm), "" for a metric both kinds of motor report (rad, s, A)."""
    return SUFFIX_SYSTEM.get(metric_base(name)[1], "")


def metric_twin(name: str, system: str) -> str | None:
    """The metric of the same statistic in the units of ``system`` ("linear" or
    "rotary"): ``speed_estimate_error_max_rpm`` -> ``speed_estimate_error_max_mps`` for
    "linear"; the name itself when it already suits (or has no unit of either kind); None
    when the statistic has no metric in that system's units."""
    if metric_system(name) in ("", system):
        return name
    base, suffix = metric_base(name)
    want = {"linear": {"rpm": "mps", "rad": "mm"}, "rotary": {"mps": "rpm", "mm": "rad"}}
    other = f"{base}_{want.get(system, {}).get(suffix, suffix)}"
    return other if other in METRIC_DEFS else None
#: Every channel some metric needs, ``t_s`` first (s, rad, rad/s electrical).
TRUTH_CHANNELS: tuple[str, ...] = ("t_s",) + tuple(dict.fromkeys(
    c for m in METRICS for c in m.channels))


def wrap_pi(x: np.ndarray | float) -> np.ndarray:
    """Wrap angles into [-pi, pi).

    Parameters
    ----------
    x : array_like
        Angles (rad).

    Returns
    -------
    ndarray
        Wrapped angles (rad).
    """
    return (np.asarray(x) + np.pi) % (2.0 * np.pi) - np.pi


#: span of the central difference that turns a reference sensor's position into speed (s)
REF_SPEED_SPAN_S = 2e-3


def truth_from_reference(t_s: np.ndarray, ref_pos_m: np.ndarray, pole_pitch_m: float,
                         span_s: float = REF_SPEED_SPAN_S) -> dict[str, np.ndarray]:
    """The truth channels from a reference position sensor (on a linear rig, a
    quadrature scale read by the drive with its ADC samples, 0x2091).

    ``theta_e_rad = pi x / tau`` (the sensor's position from electrical zero) and
    ``omega_e_radps`` its central difference over about ``span_s`` (the nearest samples
    at least ``span_s / 2`` before and after; one-sided at the ends): a scale of
    resolution r read every T quantises the speed to about r / span_s. Invalid readings
    (NaN: a sensor fault) stay NaN, and so does every speed computed across them.

    Parameters
    ----------
    t_s : ndarray
        Sample times (s).
    ref_pos_m : ndarray
        Reference positions (m), NaN where invalid.
    pole_pitch_m : float
        Pole pitch tau (m).
    span_s : float
        Span of the central difference (s).

    Returns
    -------
    dict
        ``theta_e_rad`` and ``omega_e_radps`` (rad, rad/s electrical).
    """
    t = np.asarray(t_s, dtype=float)
    x = np.asarray(ref_pos_m, dtype=float)
    k = math.pi / pole_pitch_m
    w = np.full(t.shape, np.nan)
    if t.size >= 2:
        hi = np.searchsorted(t, t + 0.5 * span_s, side="left").clip(0, t.size - 1)
        lo = (np.searchsorted(t, t - 0.5 * span_s, side="right") - 1).clip(0, t.size - 1)
        dt = t[hi] - t[lo]
        ok = dt > 0
        w[ok] = k * (x[hi][ok] - x[lo][ok]) / dt[ok]
    return {"theta_e_rad": k * x, "omega_e_radps": w}


def default_window(name: str, settle_s: float, t_end_s: float) -> tuple[float, float]:
    """Default window of a metric.

    Parameters
    ----------
    name : str
        Metric name (one of :data:`METRIC_NAMES`).
    settle_s : float
        End of the start-up (s).
    t_end_s : float
        End of the record or run (s).

    Returns
    -------
    tuple of float
        ``(t0_s, t1_s)``.
    """
    return (0.0 if METRIC_DEFS[name].window == "whole run" else settle_s), t_end_s


def _settling_time(tw: np.ndarray, ew: np.ndarray, t0_s: float) -> float:
    if tw.size == 0:
        return math.nan
    dt = float(np.median(np.diff(tw))) if tw.size > 1 else 1.0
    n_avg = max(1, int(round(SETTLE_AVG_S / max(dt, 1e-12))))
    ea = np.convolve(np.abs(ew), np.ones(n_avg) / n_avg, mode="same")
    bad = np.nonzero(ea > SETTLE_BAND_RAD)[0]
    first = 0 if bad.size == 0 else int(bad[-1]) + 1
    if first >= tw.size or tw[-1] - tw[first] < SETTLE_HOLD_S - 0.5 * dt:
        return math.nan
    return float(tw[first] - t0_s)


def window_mask(t: np.ndarray, t0_s: float, t1_s: float) -> np.ndarray:
    """The samples of the window ``[t0_s, t1_s]`` (both ends included, to 1 ps: the
    one window convention of every metric)."""
    return (t >= t0_s - 1e-12) & (t <= t1_s + 1e-12)


def compute_metrics(data: Mapping[str, np.ndarray], pole_pitch_m: float, pole_pairs: float,
                    window_s: tuple[float, float] | None = None,
                    names: tuple[str, ...] | list[str] = METRIC_NAMES) -> dict[str, float]:
    """Metrics of ``data`` over one window.

    Parameters
    ----------
    data : mapping of str to ndarray
        Recorded channels: ``t_s`` (s) and the channels of :data:`TRUTH_CHANNELS`
        (rad, rad/s electrical). Missing channels make the metrics that need
        them NaN.
    pole_pitch_m : float
        Pole pitch tau (m).
    pole_pairs : float
        Rotary-equivalent pole pairs p.
    window_s : tuple of float, optional
        ``(t0_s, t1_s)``, both included; the whole record if None.
    names : sequence of str
        Which metrics to compute (default: all, in :data:`METRIC_NAMES` order).

    Returns
    -------
    dict
        Metric name -> value in the unit of its definition.
    """
    unknown = [n for n in names if n not in METRIC_DEFS]
    if unknown:
        raise KeyError(f"unknown metrics {unknown}; known: {', '.join(METRIC_NAMES)}")
    t = np.asarray(data["t_s"], dtype=float) if "t_s" in data else np.zeros(0)
    if window_s is None:
        t0, t1 = (float(t[0]), float(t[-1])) if t.size else (0.0, 0.0)
    else:
        t0, t1 = float(window_s[0]), float(window_s[1])
    m = window_mask(t, t0, t1)
    tw = t[m]
    # the unit of each suffix, from electrical rad (rad/s): the twins differ only by it
    rpm_per_radps = radps_e_to_rpm(1.0, pole_pairs)
    mps_per_radps = m_per_electrical_rad(pole_pitch_m)

    def in_unit(v: float, suffix: str) -> float:
        if suffix == "rpm":
            return v * rpm_per_radps
        if suffix == "mps":
            return v * mps_per_radps
        if suffix == "mm":
            return v * mps_per_radps * 1e3
        return v

    def sig(a: str, b: str) -> np.ndarray:
        return np.asarray(data[a], dtype=float)[m] - np.asarray(data[b], dtype=float)[m]

    def absmax(x: np.ndarray) -> float:
        return float(np.max(np.abs(x)))

    def rms(x: np.ndarray) -> float:
        return float(np.sqrt(np.mean(x**2)))

    out: dict[str, float] = {}
    e: np.ndarray | None = None
    for name in names:
        d = METRIC_DEFS[name]
        if tw.size == 0 or any(c not in data for c in d.channels):
            out[name] = math.nan
            continue
        if d.channels == _POS and e is None:
            e = wrap_pi(sig("theta_e_rad", "theta_hat_rad"))
        base, suffix = metric_base(name)
        if base == "position_error_rms":
            v = rms(e)
        elif base == "position_error_max":
            v = absmax(e)
        elif base == "position_error_mean":
            v = float(np.mean(e))
        elif base == "speed_estimate_error_max":
            v = absmax(sig("omega_hat_radps", "omega_e_radps"))
        elif base == "speed_filtered_estimate_error_max":
            v = absmax(sig("omega_f_radps", "omega_e_radps"))
        elif base == "speed_filtered_estimate_error_rms":
            v = rms(sig("omega_f_radps", "omega_e_radps"))
        elif base == "speed_tracking_error_max":
            v = absmax(sig("omega_e_radps", "speed_ref_radps_e"))
        elif base == "speed_tracking_estimate_error_max":
            v = absmax(sig("omega_f_radps", "speed_ref_radps_e"))
        elif name == "estimate_settling_time_s":
            v = _settling_time(tw, np.asarray(data["pll_err_rad"], dtype=float)[m], t0)
        elif name == "current_q_max_A":
            iq = np.asarray(data["i_dq_hat_A"], dtype=float)
            iq = iq[:, 1] if iq.ndim == 2 else iq
            v = absmax(iq[m])
        else:  # settling_time_s
            v = _settling_time(tw, e, t0)
        out[name] = in_unit(v, suffix)
    return out


def run_metrics(data: Mapping[str, np.ndarray], pole_pitch_m: float, pole_pairs: float,
                settle_s: float, t_end_s: float | None = None,
                names: tuple[str, ...] | list[str] = METRIC_NAMES
                ) -> tuple[dict[str, float], dict[str, tuple[float, float]]]:
    """Every metric over its default window (the headline figures of a run).

    Parameters
    ----------
    data : mapping of str to ndarray
        As for :func:`compute_metrics`.
    pole_pitch_m, pole_pairs : float
        Geometry (m, dimensionless).
    settle_s : float
        End of the start-up (s).
    t_end_s : float, optional
        End of the run (s); the last sample if None.
    names : sequence of str
        Which metrics (default: all, in :data:`METRIC_NAMES` order).

    Returns
    -------
    metrics : dict
        Metric name -> value.
    windows : dict
        Metric name -> the window it was computed over (s).
    """
    t = np.asarray(data.get("t_s", np.zeros(0)))
    end = float(t_end_s) if t_end_s is not None else (float(t[-1]) if t.size else 0.0)
    out: dict[str, float] = {}
    windows: dict[str, tuple[float, float]] = {}
    for name in names:
        w = default_window(name, settle_s, end)
        windows[name] = w
        out.update(compute_metrics(data, pole_pitch_m, pole_pairs, w, (name,)))
    return out, windows


def definitions_rows() -> list[dict[str, str]]:
    """The definitions as rows (name, signal, statistic, unit, default window).

    Returns
    -------
    list of dict
        One dict per metric, in :data:`METRIC_NAMES` order.
    """
    win = {"settled": "[settle_s, end]", "whole run": "[0, end]"}
    return [{"metric": d.name, "signal": d.signal, "statistic": d.statistic, "unit": d.unit,
             "default window (s)": win[d.window]} for d in METRICS]


def definitions_markdown() -> str:
    """The definitions as a Markdown table (docs and reports).

    Returns
    -------
    str
        Markdown table.
    """
    rows = definitions_rows()
    cols = list(rows[0])
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(r[c].replace("|", "\\|") for c in cols) + " |" for r in rows]
    return "\n".join(lines)


# ---- scenario analyses (campaigns and the paper reproduction) -------------------------
#
# Per-run analyses of a simulated paper scenario, beyond the headline metrics.
#
# A campaign (simcampaign/_campaign.py) computes these in the worker, from the run's
# full-rate record, and keeps only the numbers (and, if asked, a decimated trace)
# in its Parquet results; the paper reproduction (simcampaign/_reproduction.py) renders
# its tables and figures from those results alone.
#
# Names, as a campaign lists them under ``metrics:``:
#
# * ``<window>.<m>`` with a window of ``base.windows`` (``name: [t0, t1]``, s, both
#   ends included, as every metric of :mod:`sim_fallback.metrics`) and ``m`` one of
#   :data:`WINDOW_METRICS`; the first five are short names of that module's metrics
#   (:data:`WINDOW_ALIASES`), computed by it;
# * :data:`EVENT_METRICS` (recovery after the event at ``base.event_s``);
# * :data:`STARTUP_METRICS` (closed-loop start and error after settling);
# * :data:`RUN_METRICS` (what the drive did: valid, faulted when, reached RUN).
#
# Window, event and start-up metrics are NaN for a run that is not *valid* (the
# drive refused or faulted, or never closed the loop: the simulator's own rule);
# run metrics describe every run, refused ones included.
#
# Angles are electrical radians; speeds rotary-equivalent r/min; the speed error
# is the drive's filtered estimate ``omega_f`` minus the true speed.




#: What the injection costs in audible noise and heat (docs/audible_noise.md), over a
#: window: the A-weighted level of the thrust ripple (dB(A) re 1 N) and of the phase
#: currents (dB(A) re 1 A) in the audible band, and the copper loss of the HF current (W).
#: Defined in :data:`AUDIBLE_DEFS`; a campaign that asks for them records every sample
#: (``base.record_decimation: 1``: the band reaches the record's Nyquist frequency).
AUDIBLE_METRICS = ("thrust_ripple_dBA", "phase_current_dBA", "inj_copper_loss_W")
#: Statistics over a window: position error (el. rad) RMS / max |.| / mean, speed
#: error (r/min) max |.| / RMS, RMS of the true d / q current minus its mean over one
#: injection period (A, the HF ripple), the position error RMS over the samples in
#: the window in which the drive was in closed loop (RUN; for refused or faulted runs),
#: and the :data:`AUDIBLE_METRICS`.
WINDOW_METRICS = ("pos_rms", "pos_max", "pos_mean", "spd_max", "spd_rms", "ripple_d",
                  "ripple_q", "run_err_rms") + AUDIBLE_METRICS
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
SCENARIO_CHANNELS = ("t_s", "theta_e_rad", "theta_hat_rad", "omega_e_radps", "omega_f_radps",
            "omega_hat_radps", "speed_ref_radps_e", "i_d_A", "i_q_A", "fault_code",
            "start_phase", "sogi_k_eff", "force_N")


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


def hf_part(x: np.ndarray, n_inj: int) -> np.ndarray:
    """The HF part of a signal sampled at the control rate: ``x`` minus its moving mean
    over one injection period of ``n_inj`` samples (centred; the ``n_inj - 1`` samples
    whose period does not fit in ``x`` are left out). The moving mean is an exact notch
    at the injection frequency and its harmonics, so the injection's whole response is
    in the HF part and the fundamental (a few Hz) is not."""
    x = np.asarray(x, dtype=float)
    m = np.convolve(x, np.ones(n_inj) / n_inj, mode="valid")
    return x[n_inj // 2: n_inj // 2 + m.size] - m


def hf_ripple(res: Any, t0: float, t1: float, n_inj: int) -> tuple[float, float]:
    """RMS of the HF current ripple (true d and q current minus its mean over one
    injection period of ``n_inj`` samples, :func:`hf_part`) over [t0, t1], A."""
    k = window_mask(res.data["t_s"], t0, t1)
    out = []
    for ch in ("i_d_A", "i_q_A"):
        h = hf_part(res.data[ch][k], n_inj)
        out.append(float(np.sqrt(np.mean(h**2))))
    return out[0], out[1]


# ---- audible noise ------------------------------------------------------------------
#
# docs/audible_noise.md. A linear motor's audible emission is driven by its force
# ripple (the mover, the secondary and the frame vibrate under it; magnetostriction, the
# other source, is not modelled). How loud that is depends on the mechanics (the
# structure's transfer from force to surface velocity, radiation, the listener), which
# the simulator does not model: the levels below are *relative* figures for comparing
# drive settings on one machine, in dB(A) re 1 N (thrust) and re 1 A (phase current),
# not sound pressure levels.

#: The audible band (Hz). The record (one sample per control period) is read as the
#: straight-line signal through its samples (:data:`AUDIBLE_HOLD`), which reaches it whole.
AUDIBLE_BAND_HZ = (20.0, 20000.0)
#: Reference of the thrust ripple level (N): 0 dB(A) is an A-weighted RMS of 1 N.
THRUST_REF_N = 1.0
#: Reference of the phase current level (A): 0 dB(A) is an A-weighted RMS of 1 A.
CURRENT_REF_A = 1.0

#: The audible metrics' definitions (:data:`AUDIBLE_METRICS`; the window is the
#: campaign's ``<window>``, as for every window metric). Rendered by
#: :func:`audible_definitions_markdown` into docs/audible_noise.md.
AUDIBLE_DEFS: dict[str, MetricDef] = {d.name: d for d in (
    MetricDef("thrust_ripple_dBA",
              "the thrust ripple: the true electromagnetic thrust force_N minus its mean and "
              "linear trend over the window (the steady thrust and the slow motion), Hann "
              "window",
              "A-weighted power in the audible band, 20 Hz to 20 kHz, of the straight-line "
              "signal through the control-rate samples (band_level_db, hold linear: the "
              "samples' PSD times sinc^4 at each image), as 10 log10(P_A / (1 N)^2)",
              "dB(A) re 1 N", "<window>", ("force_N",)),
    MetricDef("phase_current_dBA",
              "the true phase currents i_a, i_b, i_c (from i_d, i_q and theta_e, "
              "amplitude-invariant), each minus its mean and linear trend, Hann window",
              "A-weighted power in the audible band as above, averaged over the three "
              "phases, as 10 log10(P_A / (1 A)^2); the fundamental (a few Hz) lies below "
              "the band",
              "dB(A) re 1 A", "<window>", ("i_d_A", "i_q_A", "theta_e_rad")),
    MetricDef("inj_copper_loss_W",
              "the HF part of the true d and q currents (hf_part: minus the moving mean over "
              "one injection period)",
              "3/2 R mean(i_d_hf^2 + i_q_hf^2), the mean square of the straight-line signal "
              "through the samples (mean_square, hold linear), R the plant's phase "
              "resistance (the run's plant.R_ohm, else the motor file's)", "W", "<window>",
              ("i_d_A", "i_q_A")),
)}


def a_weighting_db(f_hz: np.ndarray | float) -> np.ndarray:
    """The A weighting of IEC 61672-1 (dB), the standard's analytic form:
    ``20 log10 R_A(f) + 2.00`` with ``R_A(f) = f_4^2 f^4 / ((f^2 + f_1^2)
    sqrt((f^2 + f_2^2)(f^2 + f_3^2)) (f^2 + f_4^2))``, f_1 = 20.6, f_2 = 107.7,
    f_3 = 737.9, f_4 = 12194 Hz (0.0 dB at 1 kHz, -19.1 dB at 100 Hz, +1.2 dB at 2.5 kHz).

    Parameters
    ----------
    f_hz : array_like
        Frequencies (Hz), > 0.

    Returns
    -------
    ndarray
        Weighting (dB); -inf at 0 Hz.
    """
    f2 = np.asarray(f_hz, dtype=float) ** 2
    f1, fb, fc, f4 = 20.598997, 107.65265, 737.86223, 12194.217
    with np.errstate(divide="ignore"):
        ra = (f4**2 * f2**2) / ((f2 + f1**2) * np.sqrt((f2 + fb**2) * (f2 + fc**2))
                                * (f2 + f4**2))
        return 20.0 * np.log10(ra) + 2.0


def _detrend(x: np.ndarray) -> np.ndarray:
    n = np.arange(x.size, dtype=float)
    if x.size < 2:
        return x - np.mean(x)
    return x - np.polyval(np.polyfit(n, x, 1), n)


def psd(x: np.ndarray, fs_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """One-sided power spectral density of ``x`` minus its mean and linear trend, Hann
    window: ``(f, S)`` with ``sum(S) * fs / N`` the window-corrected mean power (exactly
    ``a^2 / 2`` for a sine of amplitude a on a frequency bin; Parseval).

    Parameters
    ----------
    x : ndarray
        Samples at ``fs_hz``.
    fs_hz : float
        Sample rate (Hz).

    Returns
    -------
    f : ndarray
        Bin frequencies (Hz), 0 to fs/2.
    S : ndarray
        PSD (unit^2 / Hz).
    """
    x = _detrend(np.asarray(x, dtype=float))
    n = x.size
    w = 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(n) / n)  # periodic Hann
    X = np.fft.rfft(w * x)
    S = np.abs(X) ** 2 / (fs_hz * np.sum(w**2))
    S[1: (n + 1) // 2] *= 2.0  # one-sided: every bin but DC (and Nyquist, n even)
    return np.fft.rfftfreq(n, 1.0 / fs_hz), S


def band_weights(f_hz: np.ndarray, fs_hz: float, band_hz: tuple[float, float] = AUDIBLE_BAND_HZ,
                 weighted: bool = True, hold: str = "none") -> np.ndarray:
    """Power gain of each bin of a sampled signal's one-sided PSD (bins 0..fs/2) into the
    (A-weighted) band.

    ``hold="none"``: the samples alone, ``|A(f)|^2`` on the bins inside ``band_hz``
    (the band cut at fs/2). ``hold="linear"``: the continuous signal that joins the
    samples by straight lines (what a current driven by a voltage held over each control
    period is, to within its time constant), whose spectrum is the samples' times
    ``sinc^2(f / fs)`` at every image ``m fs +- f``: a bin's gain is the sum of
    ``|A|^2 sinc^4`` over its images inside the band (up to 20 kHz, so beyond fs/2).
    A triangle wave sampled at its corners is reproduced exactly (fundamental 8/pi^2,
    third harmonic 1/9 of it).
    """
    f = np.asarray(f_hz, dtype=float)
    lo, hi = band_hz

    def gain(fi: np.ndarray) -> np.ndarray:
        inside = (fi >= lo) & (fi <= hi)
        g = 10.0 ** (a_weighting_db(np.where(inside, fi, 1e3)) / 10.0) if weighted else 1.0
        return np.where(inside, g, 0.0)

    if hold == "none":
        return gain(f) * (f <= 0.5 * fs_hz)
    if hold != "linear":
        raise ValueError(f"hold {hold!r}: 'none' or 'linear'")
    out = np.zeros_like(f)
    distinct = (f > 0.0) & (f < 0.5 * fs_hz)  # +f and -f images coincide at 0 and fs/2
    for m in range(int(hi // fs_hz) + 2):
        fi = m * fs_hz + f
        out += gain(fi) * np.sinc(fi / fs_hz) ** 4
        if m >= 1:
            fi = m * fs_hz - f
            out += np.where(distinct, gain(fi) * np.sinc(fi / fs_hz) ** 4, 0.0)
    return out


def band_level_db(x: np.ndarray, fs_hz: float, ref: float = 1.0,
                  band_hz: tuple[float, float] = AUDIBLE_BAND_HZ,
                  weighted: bool = True, hold: str = "none") -> float:
    """The (A-weighted) level of ``x`` in a band: ``10 log10(P / ref^2)`` with ``P`` the
    sum over the bins of the PSD (:func:`psd`) times the bin width times the bin's gain
    into the band (:func:`band_weights`: ``|A(f)|^2`` (:func:`a_weighting_db`, unless
    ``weighted`` is False) inside ``band_hz``, both ends included; with ``hold="linear"``
    of the straight-line continuous signal through the samples). A sine of amplitude a
    at 1 kHz gives ``20 log10(a / sqrt(2) / ref)`` (``hold="none"``); at 100 Hz 19.1 dB
    less.

    Parameters
    ----------
    x : ndarray
        Samples at ``fs_hz``.
    fs_hz : float
        Sample rate (Hz).
    ref : float
        Reference RMS of 0 dB (the signal's unit).
    band_hz : tuple of float
        ``(f_lo, f_hi)`` (Hz).
    weighted : bool
        A-weighted (default) or flat.
    hold : {"none", "linear"}
        The samples alone, or the straight-line signal through them.

    Returns
    -------
    float
        Level (dB re ``ref``); -inf for no power; NaN for fewer than 4 samples or a
        non-finite one.
    """
    x = np.asarray(x, dtype=float)
    if x.size < 4 or not np.all(np.isfinite(x)):
        return math.nan
    f, S = psd(x, fs_hz)
    p = float(np.sum(S * band_weights(f, fs_hz, band_hz, weighted, hold))) * fs_hz / x.size
    with np.errstate(divide="ignore"):
        return float(10.0 * np.log10(p / ref**2))


#: How the audible metrics read the control-rate record: as the straight-line signal
#: through the samples (:func:`band_weights`, :func:`mean_square`). The plant holds the
#: inverter's voltage over each control period (average model), so its current, and the
#: thrust made of it, runs nearly straight between samples (L / R = 12.5 ms against a
#: 42 us period, paper_salient); the samples alone would overstate a 6 kHz triangle's
#: fundamental by 1.8 dB and its mean square by 1.8 dB too.
AUDIBLE_HOLD = "linear"


def phase_currents(i_d: np.ndarray, i_q: np.ndarray, theta_e: np.ndarray) -> np.ndarray:
    """The phase currents (n x 3, A) from the d/q currents and the electrical angle
    (amplitude-invariant: ``i_a = i_d cos(theta) - i_q sin(theta)``, b and c 120 deg
    later)."""
    th = np.asarray(theta_e, dtype=float)[:, None] - np.array([0.0, 2.0, -2.0]) * np.pi / 3
    return (np.asarray(i_d, dtype=float)[:, None] * np.cos(th)
            - np.asarray(i_q, dtype=float)[:, None] * np.sin(th))


def phase_current_level_db(i_d: np.ndarray, i_q: np.ndarray, theta_e: np.ndarray,
                           fs_hz: float, band_hz: tuple[float, float] = AUDIBLE_BAND_HZ
                           ) -> float:
    """``phase_current_dBA``: the A-weighted audible-band power of the three phase
    currents (:func:`phase_currents`), averaged over the phases, dB re 1 A."""
    iabc = phase_currents(i_d, i_q, theta_e)
    p = [10.0 ** (band_level_db(iabc[:, j], fs_hz, CURRENT_REF_A, band_hz,
                                hold=AUDIBLE_HOLD) / 10.0) for j in range(3)]
    with np.errstate(divide="ignore"):
        return float(10.0 * np.log10(np.mean(p)))


def mean_square(x: np.ndarray, hold: str = "none") -> float:
    """Mean square of a sampled signal: of the samples (``hold="none"``) or of the
    straight lines through them (``"linear"``: each interval's ``(a^2 + a b + b^2) / 3``;
    a triangle wave with its corners on samples gives its a^2 / 3 exactly, where its
    samples at 4 per period give a^2 / 2)."""
    x = np.asarray(x, dtype=float)
    if hold == "none" or x.size < 2:
        return float(np.mean(x**2)) if x.size else math.nan
    if hold != "linear":
        raise ValueError(f"hold {hold!r}: 'none' or 'linear'")
    a, b = x[:-1], x[1:]
    return float(np.mean(a * a + a * b + b * b) / 3.0)


def injection_copper_loss_W(i_d: np.ndarray, i_q: np.ndarray, n_inj: int, R_ohm: float,
                            hold: str = "none") -> float:
    """``inj_copper_loss_W``: ``3/2 R mean(i_d_hf^2 + i_q_hf^2)`` with the HF parts of
    :func:`hf_part` (W; amplitude-invariant d/q currents, as the plant's), the mean
    square of the samples or of the straight lines through them (:func:`mean_square`)."""
    hd, hq = hf_part(i_d, n_inj), hf_part(i_q, n_inj)
    if hd.size == 0:
        return math.nan
    return float(1.5 * R_ohm * (mean_square(hd, hold) + mean_square(hq, hold)))


def audible_metrics(data: Mapping[str, np.ndarray], t0: float, t1: float, n_inj: int,
                    R_ohm: float, names: Iterable[str] = AUDIBLE_METRICS
                    ) -> dict[str, float]:
    """The :data:`AUDIBLE_METRICS` of a record over [t0, t1] (its sample rate from
    ``t_s``); a metric whose channels were not recorded is NaN."""
    k = window_mask(np.asarray(data["t_s"]), t0, t1)
    t = np.asarray(data["t_s"], dtype=float)[k]
    fs = 1.0 / float(np.median(np.diff(t))) if t.size > 1 else math.nan
    out: dict[str, float] = {}
    for name in names:
        d = AUDIBLE_DEFS[name]
        if t.size < 4 or any(c not in data for c in d.channels):
            out[name] = math.nan
        elif name == "thrust_ripple_dBA":
            out[name] = band_level_db(np.asarray(data["force_N"])[k], fs, THRUST_REF_N,
                                      hold=AUDIBLE_HOLD)
        elif name == "phase_current_dBA":
            out[name] = phase_current_level_db(np.asarray(data["i_d_A"])[k],
                                               np.asarray(data["i_q_A"])[k],
                                               np.asarray(data["theta_e_rad"])[k], fs)
        else:
            out[name] = injection_copper_loss_W(np.asarray(data["i_d_A"])[k],
                                                np.asarray(data["i_q_A"])[k], n_inj, R_ohm,
                                                AUDIBLE_HOLD)
    return out


def audible_definitions_markdown() -> str:
    """The :data:`AUDIBLE_DEFS` as a Markdown table (docs/audible_noise.md)."""
    lines = ["| metric | signal | statistic | unit |", "|---|---|---|---|"]
    lines += [f"| `<window>.{d.name}` | {d.signal} | {d.statistic} | {d.unit} |"
              for d in AUDIBLE_DEFS.values()]
    return "\n".join(lines)


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


def run_state_metrics(res: Any) -> dict[str, float]:
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
            event_s: float | None, n_inj: int, R_ohm: float | None = None
            ) -> dict[str, float]:
    """The requested analysis metrics of one run (see the module docstring); ``R_ohm``:
    the plant's phase resistance for ``inj_copper_loss_W`` (default: the motor file's)."""
    want = list(metrics)
    out: dict[str, float] = {}
    if any(m in RUN_METRICS for m in want):
        rm = run_state_metrics(res)
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
        elif name in AUDIBLE_METRICS:
            r_ohm = float(res.motor.plant["R_ohm"]) if R_ohm is None else float(R_ohm)
            out[m] = audible_metrics(res.data, t0, t1, n_inj, r_ohm, (name,))[name]
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
