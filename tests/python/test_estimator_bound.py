"""The injection's information bound (sim_fallback.bound, docs/method.md section 5.1)
against independent references: closed forms of least-squares fits, a Monte Carlo
maximum-likelihood estimate from synthetic phase currents, numerical integrals; and the
simulated drive, which must not beat it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_fallback import bound as B
from sim_fallback import fw_config, load_motor, paper_scenario
from sim_fallback.metrics import window_metrics


def test_sampled_triangle_energy_closed_forms():
    # n = 4 on the peaks: 0 1 2 1 -> zero mean -1 0 1 0: 0.5 per sample
    assert B.sampled_triangle_energy(4) == pytest.approx(0.5, rel=1e-12)
    # n = 8: -2 -1 0 1 2 1 0 -1: 12 / 8
    assert B.sampled_triangle_energy(8) == pytest.approx(1.5, rel=1e-12)
    # many samples: the continuous triangle's peak^2 / 3 (peak n/4 intervals)
    assert B.sampled_triangle_energy(64) == pytest.approx((64 / 4) ** 2 / 3, rel=0.01)
    with pytest.raises(ValueError, match="even integer"):
        B.sampled_triangle_energy(7)


def _ml_angle_estimates(info: B.InjectionInformation, L_d: float, u: float, periods: int,
                        trials: int, seed: int) -> np.ndarray:
    """Least-squares (= maximum-likelihood, Gaussian noise) angle-error estimates from
    synthetic noisy phase currents: the d^ and q^ HF response of a square wave +-u on d^
    sampled on the peaks, a constant fundamental current (unknown), the three phases'
    independent noise; the error e is a regressor's coefficient."""
    n = info.samples_per_period
    f_pwm = info.f_pwm_Hz
    k = np.arange(n * periods)
    x = k % n
    tri = np.where(x < n / 2, x, n - x) / f_pwm  # unit-slope triangle, s
    tri = tri - tri.mean()
    rng = np.random.default_rng(seed)
    th = rng.uniform(0.0, 2 * math.pi)  # the estimated frame's angle (fixed: slow motion)
    e_true = 0.0
    g_q = info.slope_A_per_s_rad * tri  # q^ current per rad of error
    g_d = (u / L_d) * tri  # d^ response (a nuisance: its amplitude is taken as unknown)
    ph = th - 2 * math.pi * np.arange(3) / 3
    cos_p, sin_p = np.cos(ph), -np.sin(ph)

    def abc(i_d: np.ndarray, i_q: np.ndarray) -> np.ndarray:  # inverse Park, (samples, 3)
        return np.outer(i_d, cos_p) + np.outer(i_q, sin_p)

    ones = np.ones(k.size)
    # regressors, stacked over the three phases: e, d^ amplitude, fundamental d, q
    X = np.column_stack([abc(np.zeros(k.size), g_q).ravel(), abc(g_d, 0 * g_d).ravel(),
                         abc(ones, 0 * ones).ravel(), abc(0 * ones, ones).ravel()])
    clean = abc(g_d + 1.0, e_true * g_q + 3.0).ravel()
    noise = rng.normal(0.0, info.sigma_phase_A, (trials, clean.size))
    coef, *_ = np.linalg.lstsq(X, (clean + noise).T, rcond=None)
    return coef[0]


@pytest.mark.parametrize("motor", ["paper_salient", "iron_core_linear"])
def test_fisher_rate_against_monte_carlo_ml(motor):
    """The Fisher rate's 1/(J T) is the variance of the maximum-likelihood angle error
    from T seconds of three noisy phase currents (numpy least squares): within 10 %
    (2,000 draws: the variance's own standard error is 3 %)."""
    info = B.injection_information(motor)
    m = load_motor(motor)
    periods, trials = 6, 2000
    est = _ml_angle_estimates(info, m.plant["L_d0_H"], float(fw_config(m).u_inj_V), periods,
                              trials, seed=3)
    T = periods * info.samples_per_period / info.f_pwm_Hz
    assert float(np.var(est)) == pytest.approx(1.0 / (info.fisher_rate * T), rel=0.10)


def test_kalman_bound_closed_forms():
    """Posterior variance of the angle at the end of T seconds of white noise of density
    S0, no step: a constant (speed known 0, acceleration known): S0 / T; a line (speed
    unknown): 4 S0 / T; a parabola (acceleration unknown too): 9 S0 / T (the end-point
    variance of continuous least-squares polynomial fits, (n + 1)^2 S0 / T)."""
    S0, T = 1e-6, 0.5
    for rest, known, c in ((True, True, 1.0), (False, True, 4.0), (False, False, 9.0)):
        r = B.kalman_bound(S0, T, (T, T), None, start_at_rest=rest, known_disturbance=known)
        assert r["theta_rms_rad"] ** 2 == pytest.approx(c * S0 / T, rel=0.01), (rest, known)


def test_kalman_bound_after_a_step_closed_form():
    """Long before the step (angle and speed known well), an acceleration step of
    unknown size: at tau after it the angle's variance is that of a / 2 tau^2 with a
    fitted to the parabola a t^2 / 2: (tau^2 / 2)^2 20 S0 / tau^5 = 5 S0 / tau."""
    S0, t_step, tau = 1e-8, 20.0, 0.2
    r = B.kalman_bound(S0, t_step + tau, (t_step + tau, t_step + tau), t_step, dt=1e-3)
    assert r["theta_rms_rad"] ** 2 == pytest.approx(5.0 * S0 / tau, rel=0.03)


def test_kalman_error_simulation_matches_the_bound():
    """The simulated filter's mean-square error over the window equals the posterior
    variance the bound computes (400 draws: within 6 %)."""
    S0 = 8e-7
    kb = B.kalman_bound(S0, 1.0, (0.7, 1.0), 0.5)
    mc = B.kalman_error_max(S0, 1.0, (0.7, 1.0), 0.5, trials=400, seed=1)
    assert float(np.mean(mc["theta_rms_rad"] ** 2)) == pytest.approx(
        kb["theta_rms_rad"] ** 2, rel=0.06)
    assert np.all(mc["theta_max_rad"] >= mc["theta_rms_rad"])


def test_step_kl_and_transient_bound():
    S0, a, tau = 9e-7, 267.0, 0.017
    t = np.linspace(0.0, tau, 20001)
    kl_num = float(np.trapezoid((0.5 * a * t * t) ** 2 / (2.0 * S0), t))
    assert B.step_kl(S0, a, tau) == pytest.approx(kl_num, rel=1e-6)
    tb = B.transient_bound(S0, a, 0.05)
    assert math.exp(-B.step_kl(S0, a, tb["tau_s"])) / 4.0 == pytest.approx(0.05, rel=1e-9)
    assert tb["err_rad"] == pytest.approx(0.25 * a * tb["tau_s"] ** 2, rel=1e-12)
    with pytest.raises(ValueError, match="p_miss"):
        B.transient_bound(S0, a, 0.3)
    with pytest.raises(ValueError, match="window"):
        B.kalman_bound(S0, 1.0, (2.0, 3.0))


def test_the_simulated_drive_does_not_beat_the_bound():
    """The paper's load step (adaptive SOGI, both observer laws, 4 seeds): the drive's
    mean-square steady error (0.7-1.0 s) is at least the bound, which assumes an
    estimator that knows the step's time and the exact model. A bound computed too high
    (a wrong noise projection or signal energy) fails here."""
    info = B.injection_information("paper_salient")
    bound = B.kalman_bound(info.S0, 1.0, (0.7, 1.0), 0.5)["theta_rms_rad"]
    for mode in (1, 2):
        ms = [window_metrics(paper_scenario("load_step", "sogi_adaptive", seed=s,
                                            fw={"obs_mode": mode}), 0.7, 1.0)["pos_rms"] ** 2
              for s in range(4)]
        assert float(np.mean(ms)) >= bound**2, (mode, math.sqrt(float(np.mean(ms))), bound)


def test_generated_doc_is_current():
    """docs/estimator_bound.json holds what tools/estimator_bound.py computes now (bounds
    and the drive's medians, within 1e-6 relative): regenerate it when the drive or a
    motor file changes."""
    import json
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    sys.path.insert(0, str(root / "tools"))
    import estimator_bound as eb

    old = json.loads(eb.DATA.read_text())
    diffs = eb._compare(eb.compute(int(old["seeds"])), old)
    assert not diffs, ("docs/estimator_bound.json is stale (python tools/estimator_bound.py): "
                       + "; ".join(diffs[:5]))
    assert eb.DOC.read_text() == eb.render(old)
