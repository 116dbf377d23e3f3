"""Metric definitions (sim_fallback.metrics) against independent numpy references.

Every metric is checked, field by field, against a reference computed here
from its written definition; the bench and the simulator API must return the
very same numbers (parity over every field).
"""

import math

import numpy as np
import pytest

from sim_fallback import METRIC_NAMES, load_motor
from sim_fallback import metrics as M

TAU, P = 0.024, 4.0  # paper_salient geometry: pole pitch (m), pole pairs


def _data(err_rad, t_end=1.0, dt=1 / 24000, w=41.9, dw_hat=0.0, dw_f=0.0, dw_ref=0.0):
    t = np.arange(0.0, t_end, dt)
    theta = 5.0 + w * t                                   # unwrapped truth, many turns
    e = err_rad(t) if callable(err_rad) else np.full_like(t, err_rad)
    theta_hat = wrap(theta - e).astype(np.float32).astype(np.float64)
    return {"t_s": t, "theta_e_rad": theta, "theta_hat_rad": theta_hat,
            "omega_e_radps": np.full_like(t, w), "omega_hat_radps": np.full_like(t, w + dw_hat),
            "omega_f_radps": np.full_like(t, w + dw_f),
            "speed_ref_radps_e": np.full_like(t, w + dw_ref)}


def wrap(x):
    return np.angle(np.exp(1j * np.asarray(x)))  # independent of metrics.wrap_pi


def _reference(d, t0, t1, tau=TAU, p=P):
    """Each metric from its written definition, computed independently."""
    t = d["t_s"]
    k = (t >= t0) & (t <= t1)
    e = wrap(d["theta_e_rad"] - d["theta_hat_rad"])
    rpm = 60.0 / (2 * math.pi * p)
    def settling(x):
        """1 ms centred moving average of |x|, the last sample above 0.05 rad."""
        tw, ew = t[k], np.abs(x[k])
        n = int(round(1e-3 / (tw[1] - tw[0])))
        avg = np.array([ew[max(0, i - n // 2):i - n // 2 + n].sum() / n
                        for i in range(tw.size)])
        above = np.flatnonzero(avg > 0.05)
        i0 = 0 if above.size == 0 else above[-1] + 1
        return math.nan if i0 >= tw.size or tw[-1] - tw[i0] < 0.05 - 1e-9 else tw[i0] - t0

    ts = settling(e)
    out_nt = {
        # judged without truth: the drive's own signals
        "speed_tracking_estimate_error_max_rpm":
            np.max(np.abs(d["omega_f_radps"] - d["speed_ref_radps_e"])[k]) * rpm,
        "estimate_settling_time_s": settling(d["pll_err_rad"]) if "pll_err_rad" in d
        else math.nan,
        "current_q_max_A": np.max(np.abs(np.asarray(d["i_dq_hat_A"])[:, 1][k]))
        if "i_dq_hat_A" in d else math.nan,
    }
    return out_nt | {
        "position_error_rms_rad": math.sqrt(np.mean(e[k] ** 2)),
        "position_error_max_rad": np.max(np.abs(e[k])),
        "position_error_mean_rad": np.mean(e[k]),
        "position_error_rms_mm": math.sqrt(np.mean(e[k] ** 2)) * tau / math.pi * 1e3,
        "speed_estimate_error_max_rpm":
            np.max(np.abs(d["omega_hat_radps"] - d["omega_e_radps"])[k]) * rpm,
        "speed_estimate_error_max_mps":
            np.max(np.abs(d["omega_hat_radps"] - d["omega_e_radps"])[k]) * tau / math.pi,
        "speed_filtered_estimate_error_max_rpm":
            np.max(np.abs(d["omega_f_radps"] - d["omega_e_radps"])[k]) * rpm,
        "speed_filtered_estimate_error_rms_rpm":
            math.sqrt(np.mean(((d["omega_f_radps"] - d["omega_e_radps"])[k]) ** 2)) * rpm,
        "speed_tracking_error_max_rpm":
            np.max(np.abs(d["omega_e_radps"] - d["speed_ref_radps_e"])[k]) * rpm,
        "settling_time_s": ts,
        # the linear twins (m/s, mm) of the metrics above
        "position_error_max_mm": np.max(np.abs(e[k])) * tau / math.pi * 1e3,
        "position_error_mean_mm": np.mean(e[k]) * tau / math.pi * 1e3,
        "speed_filtered_estimate_error_max_mps":
            np.max(np.abs(d["omega_f_radps"] - d["omega_e_radps"])[k]) * tau / math.pi,
        "speed_filtered_estimate_error_rms_mps":
            math.sqrt(np.mean(((d["omega_f_radps"] - d["omega_e_radps"])[k]) ** 2))
            * tau / math.pi,
        "speed_tracking_error_max_mps":
            np.max(np.abs(d["omega_e_radps"] - d["speed_ref_radps_e"])[k]) * tau / math.pi,
        "speed_tracking_estimate_error_max_mps":
            np.max(np.abs(d["omega_f_radps"] - d["speed_ref_radps_e"])[k]) * tau / math.pi,
    }


def _noisy(seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(0, 1, 1 / 24000)
    th = 40 * t + 3.0
    e = np.where(t < 0.12, 0.8 * np.exp(-t / 0.03), 0.0) + 0.01 * rng.standard_normal(t.size)
    return {"t_s": t, "theta_e_rad": th, "theta_hat_rad": wrap(th - e),
            "omega_e_radps": 40 + 0.5 * np.sin(30 * t),
            "omega_hat_radps": 40 + rng.standard_normal(t.size),
            "omega_f_radps": 40 + 0.2 * rng.standard_normal(t.size),
            "speed_ref_radps_e": np.where(t < 0.5, 40.0, 38.0),
            "pll_err_rad": e + 0.02 * rng.standard_normal(t.size),
            "i_dq_hat_A": np.column_stack([0.1 * rng.standard_normal(t.size),
                                           2.0 + np.where(t > 0.5, 1.5, 0.0)
                                           + 0.3 * rng.standard_normal(t.size)])}


def test_every_metric_has_one_complete_definition():
    assert METRIC_NAMES == tuple(d.name for d in M.METRICS)
    assert len(set(METRIC_NAMES)) == len(METRIC_NAMES)
    for d in M.METRICS:
        assert d.signal and d.statistic and d.unit and d.window in ("settled", "whole run")
        assert set(d.channels) <= set(M.TRUTH_CHANNELS)
    md = M.definitions_markdown()
    assert all(f"| {n} |" in md for n in METRIC_NAMES)
    # the old ambiguous names are gone
    assert not any(n.startswith("speed_error") for n in METRIC_NAMES)


@pytest.mark.parametrize("window", [(0.15, 1.0), (0.0, 0.5), (0.6, 0.9)])
def test_every_field_matches_the_reference(window):
    d = _noisy()
    got = M.compute_metrics(d, TAU, P, window)
    ref = _reference(d, *window)
    assert tuple(got) == METRIC_NAMES
    for k in METRIC_NAMES:
        if math.isnan(ref[k]):
            assert math.isnan(got[k]), k
        else:
            assert got[k] == pytest.approx(ref[k], rel=1e-9, abs=1e-12), k


def test_wrapped_error_and_units():
    w_rpm = 2 * math.pi * P / 60.0  # 1 r/min in electrical rad/s
    got = M.compute_metrics(_data(0.01, dw_hat=w_rpm, dw_f=2 * w_rpm, dw_ref=-3 * w_rpm),
                            TAU, P, (0.15, 1.0))
    assert got["position_error_rms_rad"] == pytest.approx(0.01, abs=1e-6)
    assert got["position_error_max_rad"] == pytest.approx(0.01, abs=1e-6)
    assert got["position_error_rms_mm"] == pytest.approx(0.01 * 24 / math.pi, rel=1e-4)
    assert got["speed_estimate_error_max_rpm"] == pytest.approx(1.0, rel=1e-9)
    assert got["speed_estimate_error_max_mps"] == pytest.approx(w_rpm * TAU / math.pi, rel=1e-9)
    assert got["speed_filtered_estimate_error_max_rpm"] == pytest.approx(2.0, rel=1e-9)
    assert got["speed_filtered_estimate_error_rms_rpm"] == pytest.approx(2.0, rel=1e-9)
    assert got["position_error_mean_rad"] == pytest.approx(0.01, abs=1e-6)
    assert got["speed_tracking_error_max_rpm"] == pytest.approx(3.0, rel=1e-9)
    assert got["settling_time_s"] == 0.0


def test_settling_time_from_the_window_start():
    d = _data(lambda t: np.where(t < 0.1, 0.5, 0.0))
    got = M.compute_metrics(d, TAU, P, (0.0, 1.0))
    assert got["settling_time_s"] == pytest.approx(0.1 + 0.5e-3, abs=1e-4)
    # measured from the window start
    assert M.compute_metrics(d, TAU, P, (0.05, 1.0))["settling_time_s"] == pytest.approx(
        0.05 + 0.5e-3, abs=1e-4)
    assert math.isnan(M.compute_metrics(_data(0.2), TAU, P)["settling_time_s"])
    # in the band for less than 50 ms at the end of the window: not settled
    late = _data(lambda t: np.where(t < 0.97, 0.5, 0.0))
    assert math.isnan(M.compute_metrics(late, TAU, P, (0.0, 1.0))["settling_time_s"])


def test_missing_channels_and_empty_windows_give_nan():
    d = _data(0.01)
    del d["omega_f_radps"], d["speed_ref_radps_e"]
    got = M.compute_metrics(d, TAU, P, (0.2, 0.4))
    assert math.isnan(got["speed_filtered_estimate_error_max_rpm"])
    assert math.isnan(got["speed_tracking_error_max_rpm"])
    assert got["position_error_rms_rad"] == pytest.approx(0.01, abs=1e-6)
    assert all(math.isnan(v) for v in M.compute_metrics(d, TAU, P, (5.0, 6.0)).values())
    with pytest.raises(KeyError, match="unknown metrics"):
        M.compute_metrics(d, TAU, P, names=("speed_error_max_rpm",))


def test_run_metrics_default_windows():
    d = _noisy(1)
    got, win = M.run_metrics(d, TAU, P, settle_s=0.15, t_end_s=0.9)
    for k in METRIC_NAMES:
        whole = k in ("settling_time_s", "estimate_settling_time_s")
        assert win[k] == ((0.0, 0.9) if whole else (0.15, 0.9))
        ref = _reference(d, *win[k])[k]
        assert got[k] == pytest.approx(ref, rel=1e-9, nan_ok=True), k


def test_bench_and_simulator_share_the_implementation():
    """Parity over every field: one implementation, reached from both packages."""
    import bench
    import sim_fallback

    assert bench.compute_metrics is M.compute_metrics is sim_fallback.compute_metrics
    assert bench.METRIC_NAMES == METRIC_NAMES
    from bench._sequence import SCHEMA

    allowed = SCHEMA["properties"]["steps"]["items"]["properties"]["expect"]["properties"]
    assert tuple(allowed["metric"]["enum"]) == METRIC_NAMES
    m = load_motor("paper_salient")
    assert (m.tau_m, float(m.pole_pairs)) == (TAU, P)


def test_truth_from_a_reference_sensor():
    """A reference scale's quantised position -> the truth channels: the angle is
    pi x / tau exactly; the speed is the central difference over the span (against the
    analytic speed within the quantisation r / span); an invalid reading (NaN: a sensor
    fault) makes NaN of every speed computed across it, never a made-up value."""
    t = np.arange(0.0, 0.2, 1e-3)
    v0, a, res = 0.3, 0.5, 1e-6
    x = 0.01 + v0 * t + 0.5 * a * t ** 2
    xq = np.floor(x / res) * res
    xq[50] = np.nan
    d = M.truth_from_reference(t, xq, TAU, span_s=2e-3)
    k = math.pi / TAU
    np.testing.assert_array_equal(d["theta_e_rad"][:50], k * xq[:50])
    w = d["omega_e_radps"]
    ok = np.isfinite(w)
    assert set(np.flatnonzero(~ok)) == {49, 51}  # the speeds across the invalid reading
    assert np.isnan(d["theta_e_rad"][50])
    inner = ok.copy()
    inner[[0, -1]] = False  # one-sided at the ends: first-order
    exact = k * (v0 + a * t)
    assert np.max(np.abs(w[inner] - exact[inner])) <= k * res / 2e-3 * 1.01
    assert np.max(np.abs(w[[0, -1]] - exact[[0, -1]])) <= k * (res / 1e-3 + a * 1e-3)


def test_the_docs_metric_table_is_the_generated_one() -> None:
    """docs/simulator.md says its metric table is generated from METRICS: it must be
    (it had 8 of the metrics, with older texts)."""
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "docs" / "simulator.md").read_text()
    assert M.definitions_markdown().strip() in text
