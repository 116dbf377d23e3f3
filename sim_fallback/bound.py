"""How well *any* injection estimator could know the angle: the information bound.

The drive measures the angle from the HF current its square-wave injection makes on
the estimated q-axis; the phase currents carry the ADC's noise. This module computes,
from a motor file (its plant: inductances, ADC; its drive: injection amplitude and
frequency, PWM rate), how much information those samples carry about the angle error,
and from it the smallest mean-square angle and speed error an estimator can reach in
a scenario (docs/method.md section 5.1). numpy only; the simulator is not run.

The chain, each step with a closed form the tests check independently:

1. **Signal.** Injecting +-u on d^ at an angle error e, the q^ current ramps with the
   slope ``u (1/L_d - 1/L_q) sin 2e / 2 ~ u (1/L_d - 1/L_q) e``: a triangle of the
   injection period, sampled once per PWM period. Its zero-mean part is the
   information (a slowly varying q current is unknown). The energy per sample depends
   on where the samples fall in the triangle: the bound takes the most favourable
   alignment.
2. **Noise.** Three phase currents, each with the ADC's Gaussian noise of
   ``adc_noise_counts`` counts (quantization left out: it only loses information). The
   q^ projection of three independent phase noises (amplitude-invariant Park) has the
   variance 2/3 of one phase's.
3. **Fisher rate** ``J = f_pwm <g^2> / sigma_q^2`` (1/(rad^2 s)), ``<g^2>`` the mean
   squared zero-mean signal per rad per sample. An efficient angle measurement is the
   angle plus white noise of two-sided density ``S0 = 1 / J`` (rad^2 s).
4. **Scenario bound.** The angle follows a double integrator driven by the thrust the
   drive commands (known) and a load it does not know. The Kalman filter of that
   linear model with measurement noise density S0 gives the posterior variance of
   angle and speed: the mean-square error no estimator can beat (for a linear Gaussian
   model the posterior mean is the minimum mean-square error estimator). The bound is
   made favourable to the estimator on purpose: it knows the exact model, the mass,
   the friction before the load step (``known_disturbance``), that the mover starts at
   rest, and *when* the load steps (only its size is unknown).
5. **Detection.** A load step of acceleration a at an unknown time: after tau seconds
   the data under "step" and "no step" differ by the parabola a tau^2 / 2, with the
   Kullback-Leibler divergence ``a^2 tau^5 / (40 S0)``. By the Bretagnolle-Huber
   inequality any estimator misses the angle by half the parabola's height with a
   probability of at least ``exp(-KL) / 4`` under one of the two: the least transient
   error the data allow.

These are bounds on what the injection's samples carry. A model of the fundamental
(the voltage equation's back-EMF) carries more where the model is exact, which on a
real motor its parameter errors and the inverter's voltage error limit; the drive
uses it only as a witness (docs/bemf.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ._motors import Motor, fw_config, load_motor

#: Sampling phases over which the most favourable alignment of the samples in the
#: injection's triangle is searched (per sample interval).
ALIGN_STEPS = 64


@dataclass(frozen=True)
class InjectionInformation:
    """What the injection's samples carry about the angle error (at zero error)."""

    slope_A_per_s_rad: float  #: q^ current slope per rad of angle error, A/s/rad
    samples_per_period: int  #: PWM samples per injection period
    signal_A2_per_rad2: float  #: mean squared zero-mean q^ signal per sample, A^2/rad^2
    sigma_phase_A: float  #: one phase's ADC noise, A (1 sigma)
    sigma_q_A: float  #: the noise of the q^ projection, A
    fisher_rate: float  #: J, 1/(rad^2 s)
    f_pwm_Hz: float

    @property
    def S0(self) -> float:
        """Two-sided noise density of an efficient angle measurement, rad^2 s."""
        return 1.0 / self.fisher_rate


def sampled_triangle_energy(n: int, steps: int = ALIGN_STEPS) -> float:
    """Mean squared zero-mean value per sample of a unit-slope triangle (slope +-1 per
    sample interval, period ``n`` samples, ``n`` even), at the most favourable sampling
    phase. n = 8: 1.5 (samples on the peaks)."""
    if n < 2 or n % 2:
        raise ValueError(f"samples per injection period must be an even integer >= 2, got {n}")
    best = 0.0
    k = np.arange(n, dtype=float)
    for ph in np.arange(steps) / steps:
        x = (k + ph) % n  # position in the period, in sample intervals
        tri = np.where(x < n / 2, x, n - x)  # up over n/2 intervals, down over n/2
        z = tri - tri.mean()
        best = max(best, float(np.mean(z * z)))
    return best


def injection_information(motor: Motor | str, **plant: Any) -> InjectionInformation:
    """The injection's information about the angle for a motor file (its plant's
    inductances and ADC, the drive's injection and PWM from :func:`fw_config`); keyword
    arguments override plant fields (``adc_noise_counts``, ``L_d0_H``, ...)."""
    m = motor if isinstance(motor, Motor) else load_motor(motor)
    p = {**m.plant, **plant}
    cfg = fw_config(m)
    u, f_inj, f_pwm = float(cfg.u_inj_V), float(cfg.f_inj_Hz), float(cfg.f_pwm_Hz)
    n = int(round(f_pwm / f_inj))
    L_d, L_q = float(p["L_d0_H"]), float(p["L_q_H"])
    slope = u * (1.0 / L_d - 1.0 / L_q)
    step = slope / f_pwm  # A per rad per sample interval
    signal = sampled_triangle_energy(n) * step * step
    lsb = 2.0 * float(p["adc_i_fullscale_A"]) / 2.0 ** float(p["adc_bits"])
    sig_ph = float(p["adc_noise_counts"]) * lsb
    sig_q = math.sqrt(2.0 / 3.0) * sig_ph
    if not sig_q > 0.0:
        raise ValueError("adc_noise_counts must be > 0 for a finite bound")
    return InjectionInformation(abs(slope), n, signal, sig_ph, sig_q,
                                f_pwm * signal / sig_q**2, f_pwm)


def kalman_bound(S0: float, t_end: float, window: tuple[float, float],
                 step_s: float | None = None, *, known_disturbance: bool = True,
                 start_at_rest: bool = True, dt: float = 2e-4) -> dict[str, float]:
    """Posterior RMS of angle (el. rad) and speed (el. rad/s) over ``window`` (mean of
    the posterior variances at the window's samples, then the root) of the Kalman
    filter for ``[angle, speed, unknown acceleration]`` observed in white noise of
    two-sided density ``S0`` from t = 0 to ``t_end``, the acceleration stepping by an
    unknown amount at ``step_s`` (a diffuse prior). The position at t = 0 is unknown
    (diffuse); ``start_at_rest``: the speed at t = 0 is known; ``known_disturbance``:
    the acceleration before the step is known (exact friction model), else diffuse."""
    t, _, var = _kalman_gains(S0, t_end, step_s, known_disturbance, start_at_rest, dt)
    inw = (t >= window[0] - 1e-12) & (t <= window[1] + 1e-12)
    if window[0] > window[1] or not inw.any():
        raise ValueError(f"window {window} holds no sample of 0..{t_end} s")
    return {"theta_rms_rad": math.sqrt(float(np.mean(var[inw, 0]))),
            "omega_rms_radps": math.sqrt(float(np.mean(var[inw, 1])))}


def _transition(dt: float) -> np.ndarray:
    """[angle, speed, acceleration] over dt: a double integrator of a held acceleration."""
    return np.array([[1.0, dt, 0.5 * dt * dt], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])


def _kalman_gains(S0: float, t_end: float, step_s: float | None, known_disturbance: bool,
                  start_at_rest: bool, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The filter's gains and posterior variances (they do not depend on the data)."""
    if not (S0 > 0.0 and t_end > 0.0 and dt > 0.0):
        raise ValueError("the bound needs S0 > 0, t_end > 0 and dt > 0")
    big = 1e8  # diffuse: far beyond any angle, speed, acceleration of the scenario
    F = _transition(dt)
    P = np.diag([big, 0.0 if start_at_rest else big, 0.0 if known_disturbance else big])
    R = S0 / dt
    n = int(round(t_end / dt)) + 1
    k_step = None if step_s is None else int(round(step_s / dt))
    gains = np.empty((n, 3))
    var = np.empty((n, 2))
    for k in range(n):
        if k == k_step:
            P[2, 2] += big
        # measurement update of the angle (Joseph form: P stays symmetric, >= 0)
        K = P[:, 0] / (P[0, 0] + R)
        A = np.eye(3)
        A[:, 0] -= K
        P = A @ P @ A.T + R * np.outer(K, K)
        gains[k] = K
        var[k] = P[0, 0], P[1, 1]
        P = F @ P @ F.T
    return np.arange(n) * dt, gains, var


def kalman_error_max(S0: float, t_end: float, window: tuple[float, float],
                     step_s: float | None = None, *, known_disturbance: bool = True,
                     start_at_rest: bool = True, dt: float = 2e-4, trials: int = 400,
                     seed: int = 0) -> dict[str, np.ndarray]:
    """Per noise draw, the largest angle (el. rad) and speed (el. rad/s) error and the
    angle error's RMS over ``window`` of the
    filter of :func:`kalman_bound` run on ``trials`` noise draws (a reference, not a
    bound: another estimator may trade mean-square error for a smaller maximum). The
    filter's error does not depend on the true trajectory (a linear filter: the error
    follows the noise alone once the diffuse priors are updated), so it is simulated
    directly."""
    t, gains, _ = _kalman_gains(S0, t_end, step_s, known_disturbance, start_at_rest, dt)
    rng = np.random.default_rng(seed)
    F = _transition(dt)
    # err = x_hat - x. The diffuse priors: whatever the error before the first update
    # (the angle's gain is ~1 there) and at the step (the acceleration's), the update
    # leaves a remainder of order 1/prior variance; start from zero and step by 1.
    err = np.zeros((trials, 3))
    sd = math.sqrt(S0 / dt)
    inw = (t >= window[0] - 1e-12) & (t <= window[1] + 1e-12)
    m_th = np.zeros(trials)
    m_w = np.zeros(trials)
    sq = np.zeros(trials)
    k_step = None if step_s is None else int(round(step_s / dt))
    for k in range(t.size):
        if k == k_step:
            err[:, 2] -= 1.0  # the true acceleration steps; the estimate does not yet
        # update: x_hat += K (z - x_hat[0]), z = x[0] + v  =>  err += K (v - err[0])
        err = err + np.outer(rng.normal(0.0, sd, trials) - err[:, 0], gains[k])
        if inw[k]:
            m_th = np.maximum(m_th, np.abs(err[:, 0]))
            m_w = np.maximum(m_w, np.abs(err[:, 1]))
            sq += err[:, 0] ** 2
        err = err @ F.T
    return {"theta_max_rad": m_th, "omega_max_radps": m_w,
            "theta_rms_rad": np.sqrt(sq / max(int(inw.sum()), 1))}


def step_kl(S0: float, accel: float, tau: float) -> float:
    """Kullback-Leibler divergence between the angle data with and without an
    acceleration step ``accel`` (el. rad/s^2) tau seconds ago, white noise of
    two-sided density S0: the integral of (accel t^2 / 2)^2 / (2 S0) over 0..tau."""
    return accel * accel * tau**5 / (40.0 * S0)


def transient_bound(S0: float, accel: float, p_miss: float = 0.05) -> dict[str, float]:
    """The least transient angle error a load step of ``accel`` (el. rad/s^2) allows:
    until the step is told from no step, an estimator errs by half the parabola
    accel tau^2 / 2 under one of the two with probability >= exp(-KL(tau)) / 4
    (Bretagnolle-Huber). Returns the latest ``tau_s`` at which that probability is
    still ``p_miss`` and the error ``err_rad`` = accel tau^2 / 4 then: with probability
    at least p_miss, some error reaches err_rad."""
    if not 0.0 < p_miss < 0.25:
        raise ValueError(f"p_miss must be in (0, 0.25), got {p_miss}")
    kl = math.log(1.0 / (4.0 * p_miss))
    tau = (40.0 * S0 * kl / (accel * accel)) ** 0.2
    return {"tau_s": tau, "err_rad": 0.25 * accel * tau * tau, "kl": kl}
