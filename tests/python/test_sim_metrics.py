"""Metric definitions on synthetic data (wrap handling, units, settling)."""

import math

import numpy as np
import pytest

from sim_fallback import METRIC_NAMES, compute_metrics, load_motor, wrap_pi


def _data(err_rad, t_end=1.0, dt=1 / 24000, w=41.9, dw=0.0):
    t = np.arange(0.0, t_end, dt)
    theta = 5.0 + w * t                                   # unwrapped truth, many turns
    e = err_rad(t) if callable(err_rad) else np.full_like(t, err_rad)
    theta_hat = wrap_pi(theta - e).astype(np.float32).astype(np.float64)
    return {"t_s": t, "theta_e_rad": theta, "theta_hat_rad": theta_hat,
            "omega_e_radps": np.full_like(t, w), "omega_hat_radps": np.full_like(t, w + dw),
            "omega_f_radps": np.full_like(t, w + dw)}


def test_wrapped_error_and_units():
    m = load_motor("paper_salient")
    met = compute_metrics(_data(0.01, dw=m.rpm_to_radps_e(1.0)), m)
    assert tuple(met) == METRIC_NAMES
    assert met["position_error_rms_rad"] == pytest.approx(0.01, abs=1e-6)
    assert met["position_error_max_rad"] == pytest.approx(0.01, abs=1e-6)
    assert met["position_error_rms_mm"] == pytest.approx(0.01 * 0.024 / math.pi * 1e3, rel=1e-4)
    assert met["speed_error_max_rpm"] == pytest.approx(1.0, rel=1e-9)
    assert met["speed_error_max_mps"] == pytest.approx(
        m.rpm_to_radps_e(1.0) * 0.024 / math.pi, rel=1e-9)
    assert met["settling_time_s"] == 0.0


def test_settle_window_and_settling_time():
    m = load_motor("paper_salient")
    met = compute_metrics(_data(lambda t: np.where(t < 0.1, 0.5, 0.0)), m, settle_s=0.15)
    assert met["position_error_max_rad"] < 1e-6          # error before 0.15 s ignored
    assert met["settling_time_s"] == pytest.approx(0.1 + 0.5e-3, abs=1e-4)
    never = compute_metrics(_data(0.2), m)
    assert math.isnan(never["settling_time_s"])
