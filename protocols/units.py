"""The machine geometry of od.yaml's configuration, once for every Python side.

A linear motor's electrical angle follows its position with the pole pitch tau
(``pole_pitch_m``): ``theta_e = pi x / tau``. The paper describes its motor in
rotary-equivalent units (r/min, N m); with the pole-pair count p (``pole_pairs``)
the equivalent radius ``r = p tau / pi`` gives ``theta_e = p theta_m``, ``v = w_m r``
and ``F = T / r``. The firmware's C equivalents are declared in
``firmware_c/include/pmlsm/fw_ctrl.h`` (``fw_units_mps_to_radps_e``,
``fw_units_force_per_A``, ...); the bench, the
simulator, identification and the tools use these functions, never their own
``pi / tau``.
"""

from __future__ import annotations

import math


def electrical_rad_per_m(pole_pitch_m: float) -> float:
    """k_e = pi / tau: electrical angle per metre of travel (theta_e = k_e x)."""
    return math.pi / pole_pitch_m


def m_per_electrical_rad(pole_pitch_m: float) -> float:
    """tau / pi: metres of travel per electrical radian (x = theta_e tau / pi)."""
    return pole_pitch_m / math.pi


def radius_m(pole_pairs: float, pole_pitch_m: float) -> float:
    """Equivalent radius r = p tau / pi (m per mechanical radian)."""
    return pole_pairs * pole_pitch_m / math.pi


def force_constant_N_per_A(psi_f_Wb: float, pole_pitch_m: float) -> float:
    """Thrust per ampere of i_q on a non-salient machine, K_F = 1.5 (pi / tau) psi_f
    (the firmware's ``fw_units_force_per_A`` in float32)."""
    return 1.5 * electrical_rad_per_m(pole_pitch_m) * psi_f_Wb


def rpm_to_radps_e(n_rpm: float, pole_pairs: float) -> float:
    """Rotary-equivalent speed (r/min) to electrical rad/s: w_e = 2 pi p n / 60."""
    return n_rpm * 2.0 * math.pi * pole_pairs / 60.0


def radps_e_to_rpm(w_radps_e: float, pole_pairs: float) -> float:
    """Electrical rad/s to rotary-equivalent r/min: n = 60 w_e / (2 pi p)."""
    return w_radps_e * 60.0 / (2.0 * math.pi * pole_pairs)


def rpm_to_mps(n_rpm: float, pole_pairs: float, pole_pitch_m: float) -> float:
    """Rotary-equivalent speed (r/min) to linear m/s: v = 2 pi n / 60 r."""
    return n_rpm * 2.0 * math.pi / 60.0 * radius_m(pole_pairs, pole_pitch_m)


def mps_to_rpm(v_mps: float, pole_pairs: float, pole_pitch_m: float) -> float:
    """Linear m/s to rotary-equivalent r/min: n = v / r 60 / (2 pi)."""
    return v_mps / radius_m(pole_pairs, pole_pitch_m) * 60.0 / (2.0 * math.pi)
