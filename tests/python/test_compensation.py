"""The drive's compensations (issue 33, docs/method.md section 6): inverter dead time in
the modulation, the cross-saturation map and the position-ripple correction subtracted
from the observer's HF error, and the identification steps that measure the map on a
clamped mover and the ripple at constant speed without a position sensor (judged here
against the plant's closed forms, which the drive never reads)."""

from __future__ import annotations

import numpy as np
import pytest

from identification import rip_fields, xsat_fields
from sim_fallback import (
    Sim,
    cross_saturation_truth,
    fw_config,
    identify_cross_saturation,
    identify_ripple,
    load_motor,
    run_scenario,
)

COMP_OFF = {"dt_comp_s": 0.0, "dt_comp_drop_V": 0.0, "xsat_di_A": 0.0}
RIP_OFF = {"rip_a2_rad": 0.0, "rip_b2_rad": 0.0}


def _run(fw: dict, load_N: float = 0.0, seed: int = 1):
    r = run_scenario("realistic_linear", speed_ref=0.1, speed_unit="mps",
                     load=[(0.0, 0.0), (0.4, load_N)], load_unit="N", t_end=1.2, fw=fw,
                     seed=seed, channels=["t_s", "theta_e_rad", "theta_hat_rad",
                                          "fault_code"])
    k = r.t_s >= 0.8
    return r, r.position_error_rad[k]


def test_defaults_are_off() -> None:
    cfg = fw_config(load_motor("iron_core_linear"))
    assert cfg.dt_comp_s == 0.0 and cfg.dt_comp_drop_V == 0.0 and cfg.xsat_di_A == 0.0
    assert all(getattr(cfg, f"xsat_off{k}_rad") == 0.0 for k in range(1, 7))
    assert all(getattr(cfg, f"rip_{c}{n}_rad") == 0.0 for n in (2, 4) for c in "ab")
    # realistic_linear carries both in its [controller] section (the drive's knowledge)
    real = fw_config(load_motor("realistic_linear"))
    assert real.dt_comp_s == pytest.approx(1.5e-6) and real.xsat_di_A == 2.0
    assert real.rip_a2_rad != 0.0 and real.rip_b2_rad != 0.0 and real.rip_a4_rad == 0.0


def test_deadtime_compensation_keeps_the_back_emf_witness_quiet() -> None:
    """Without it the 7.2 V dead-time error trips the back-EMF witness at no load; with it
    the drive tracks."""
    r_off, _ = _run({**COMP_OFF})
    assert r_off.fault_code == 0xFF0A
    r_on, e = _run({"xsat_di_A": 0.0})
    assert r_on.fault_code == 0
    assert float(np.sqrt(np.mean(e ** 2))) < 0.1


def test_cross_saturation_map_removes_the_load_dependent_bias() -> None:
    """At half the rated thrust the estimate sits ahead by the HF axis's turn (mean error
    about -0.12 rad) without the map, about on the d axis with it."""
    r0, e0 = _run({"xsat_di_A": 0.0}, load_N=300.0)
    r1, e1 = _run({}, load_N=300.0)
    assert r0.fault_code == 0 and r1.fault_code == 0
    assert float(np.mean(e0)) < -0.09
    assert abs(float(np.mean(e1))) < 0.04
    assert float(np.sqrt(np.mean(e1 ** 2))) < float(np.sqrt(np.mean(e0 ** 2))) - 0.04


def test_identified_map_matches_the_closed_form() -> None:
    """The clamped-mover step (identification.run_cross_saturation) against the plant:
    the axis turn within 0.025 rad of 1/2 atan2(-2 L_dq, L_qq - L_dd) at every point,
    the map within 0.015 rad of the HF error at the true angle."""
    m = load_motor("realistic_linear")
    res = identify_cross_saturation(m, seed=1, fw={"xsat_di_A": 0.0})
    v = res.values
    levels = v["xsat_di_A"] * np.arange(1, 7)
    assert v["xsat_di_A"] == pytest.approx(2.0)
    delta, eps = cross_saturation_truth(m, levels)
    axis = np.array([v[f"xsat_axis{k}_rad"] for k in range(1, 7)])
    off = np.array([v[f"xsat_off{k}_rad"] for k in range(1, 7)])
    assert np.all(np.abs(axis - delta) < 0.025), (axis, delta)
    assert np.all(np.abs(off - eps) < 0.015), (off, eps)
    assert 0.17 < delta[4] < 0.18  # 10.1 deg at the rated 10 A (docs/simulator.md)


def test_xsat_fields_are_clamped_to_the_drive_range() -> None:
    f = xsat_fields(2.0, [0.1, 0.9, -0.9, 0.0, 0.0, 0.0])
    assert f["xsat_off2_rad"] == 0.8 and f["xsat_off3_rad"] == -0.8 and f["xsat_di_A"] == 2.0


def _axis_ripple(motor, i_q: float = 0.0, x0: float = 0.0, n: int = 256) -> np.ndarray:
    """The plant's HF axis offset 1/2 atan2(-2 L_dq, L_qq - L_dd) over one electrical
    period (truth): its (cos, sin) coefficients at 2 and 4 theta."""
    tau = motor.tau_m
    x = x0 + np.arange(n) / n * 2.0 * tau
    th = np.pi * x / tau
    with Sim(motor, seed=0) as sim:
        L = np.array([sim.magnetics(0.0, i_q, xi)["L_dq_H"] for xi in x])
    e = 0.5 * np.arctan2(-2.0 * L[:, 1], L[:, 2] - L[:, 0])
    return np.array([2.0 * np.mean(e * f(k * th)) for k in (2, 4) for f in (np.cos, np.sin)])


def test_ripple_closed_form_is_at_two_theta() -> None:
    """The 4th-order secondary saliency and the end effect's stator-frame saliency both
    move the HF axis at 2 theta in the rotor frame: 0.098 rad at no load on
    realistic_linear, 4 theta about 0.006 rad."""
    c = _axis_ripple(load_motor("realistic_linear"))
    assert np.hypot(c[0], c[1]) == pytest.approx(0.098, abs=0.003)
    assert np.hypot(c[2], c[3]) < 0.008


def test_identified_ripple_matches_the_closed_form() -> None:
    """Step 8 (constant-speed passes, no position sensor) against the plant: the measured
    2 theta axis ripple within 0.008 rad of the closed form per coefficient; the written
    coefficients near the motor file's; the 4 theta terms not written."""
    m = load_motor("realistic_linear")
    res = identify_ripple(m, seed=1, fw=RIP_OFF)
    v = res.values
    truth = _axis_ripple(m)
    assert abs(v["rip_axis_a2_rad"] - truth[0]) < 0.008, (v, truth)
    assert abs(v["rip_axis_b2_rad"] - truth[1]) < 0.008, (v, truth)
    assert 0.9 < v["rip_slope"] < 1.25
    assert v["rip_a4_rad"] == 0.0 and v["rip_b4_rad"] == 0.0
    assert v["rip_a2_rad"] == pytest.approx(m.controller["rip_a2_rad"], abs=0.008)
    assert v["rip_b2_rad"] == pytest.approx(m.controller["rip_b2_rad"], abs=0.008)


def test_ripple_correction_removes_the_position_ripple() -> None:
    """0.1 m/s at no load and at half the rated thrust: the RMS angle error from about
    0.07-0.08 rad without the correction to about 0.015-0.02 with it."""
    for load in (0.0, 300.0):
        r0, e0 = _run(RIP_OFF, load_N=load)
        r1, e1 = _run({}, load_N=load)
        assert r0.fault_code == 0 and r1.fault_code == 0
        rms0, rms1 = (float(np.sqrt(np.mean(e ** 2))) for e in (e0, e1))
        assert rms0 > 0.06 and rms1 < 0.025, (load, rms0, rms1)


def test_rip_fields_are_clamped_to_the_drive_range() -> None:
    f = rip_fields([0.1, -0.9, 0.9, 0.0])
    assert f == {"rip_a2_rad": 0.1, "rip_b2_rad": -0.5, "rip_a4_rad": 0.5, "rip_b4_rad": 0.0}
