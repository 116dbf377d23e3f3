"""The 6 theta_e thrust ripple in the observer's model (rip6_*, fw_obs.h; docs/method.md
section 5) against the simulated plant.

The drive's coefficients come from its configuration only (the motor files'
``[controller]`` keys: a datasheet's cogging and a back-EMF test's harmonics). Here they
are checked against two independent references, both from the plant:

1. the closed form of sim_plant.c: cogging F = A sin(k_cog x + phi) with k_cog = 6 pi / tau
   gives a0 = A sin phi, b0 = A cos phi; the back-EMF 5th / 7th harmonics (relative
   amplitudes h5, h7, phases phi5, phi7) give with i_d = 0 the thrust
   K_F i_q (h7 cos(6 theta + phi7) - h5 cos(6 theta + phi5)), K_F = 3/2 (pi / tau) psi_f,
   so a1 = K_F (h7 cos phi7 - h5 cos phi5), b1 = K_F (h5 sin phi5 - h7 sin phi7);
2. the plant's force, measured: the mover released (friction off, so that the force is
   the only cause of motion) at positions over one electrical period with a constant i_q;
   the net force is m dv/dt over a 1 us plant step; its 6 theta_e Fourier coefficients at
   i_q = 0 and i_q = 10 A give (a0, b0) and the slope (a1, b1).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_fallback import Sim, load_motor

MOTORS = ("iron_core_linear", "realistic_linear")
KEYS = ("rip6_a0_N", "rip6_b0_N", "rip6_a1_N_per_A", "rip6_b1_N_per_A")
#: plant overrides for the force measurement: no friction (the mover moves under any
#: force), no measurement noise (the ADC is not read)
FREE = {"F_static_N": 0.0, "F_coulomb_N": 0.0, "b_visc_Ns_per_m": 0.0,
        "adc_noise_counts": 0.0, "udc_noise_V": 0.0}


def configured(motor: str) -> np.ndarray:
    c = load_motor(motor).controller
    return np.array([float(c.get(k, 0.0)) for k in KEYS])


def closed_form(motor: str) -> np.ndarray:
    """(a0, b0, a1, b1) from the plant's parameters (sim_plant.c)."""
    m = load_motor(motor)
    p, r = m.plant, m.realism
    tau = p["tau_m"]
    # cogging at 6 theta_e: its period tau / 3 (the motor files' 0.0053333333 m)
    assert 2.0 * math.pi / p["cog_period_m"] == pytest.approx(6.0 * math.pi / tau, rel=1e-7)
    A, phi = p["cog_amp_N"], p["cog_phase_rad"]
    K_F = 1.5 * math.pi / tau * p["psi_f_Wb"]
    h5, p5 = r.get("emf_h5", 0.0), r.get("emf_h5_phase_rad", 0.0)
    h7, p7 = r.get("emf_h7", 0.0), r.get("emf_h7_phase_rad", 0.0)
    return np.array([A * math.sin(phi), A * math.cos(phi),
                     K_F * (h7 * math.cos(p7) - h5 * math.cos(p5)),
                     K_F * (h5 * math.sin(p5) - h7 * math.sin(p7))])


def _duties(u_a: float, u_b: float, u_dc: float) -> list[float]:
    """Duties whose pole voltages give (u_alpha, u_beta) (amplitude-invariant Clarke)."""
    ua, ub = u_a, -0.5 * u_a + 0.5 * math.sqrt(3.0) * u_b
    uc = -ua - ub
    return [0.5 + u / u_dc for u in (ua, ub, uc)]


def measured_6theta(motor: str, i_q_A: float, n: int = 48) -> np.ndarray:
    """(a, b): 6 theta_e Fourier coefficients of the plant's net force (N) at i_q_A,
    i_d = 0, from m dv/dt over one 1 us step at n positions over one electrical period
    (the mean and the other harmonics drop out of the sums)."""
    with Sim(motor, noise=0.0, plant=FREE) as sim:
        tau, m = sim.params.tau_m, sim.params.mass_kg
        R, u_dc = sim.params.R_ohm, sim.params.u_dc_V
        dt = 1e-6
        F = np.empty(n)
        th = 2.0 * math.pi * (np.arange(n) + 0.25) / n
        for k, t in enumerate(th):
            x = t * tau / math.pi
            sim.set_state(x0_m=x, v0_mps=0.0, i_d_A=0.0, i_q_A=i_q_A)
            # the voltage that holds i_q at standstill (R i_q on q), in the stator frame
            u_q = R * i_q_A
            sim.plant_advance(_duties(-math.sin(t) * u_q, math.cos(t) * u_q, u_dc), True,
                              dt, 1)
            F[k] = m * sim.state()["v_mps"] / dt
    return np.array([2.0 / n * np.sum(F * np.cos(6 * th)), 2.0 / n * np.sum(F * np.sin(6 * th))])


@pytest.mark.parametrize("motor", MOTORS)
def test_configured_ripple_is_the_plants_closed_form(motor):
    """The motor file's rip6_* equal the closed form of its plant's cogging and back-EMF
    harmonics: within 0.01 N (cogging) and 0.01 N/A (the file states 3 digits)."""
    got, ref = configured(motor), closed_form(motor)
    assert got[:2] == pytest.approx(ref[:2], abs=0.01)
    assert got[2:] == pytest.approx(ref[2:], abs=0.01)
    assert np.any(got != 0.0)  # the motor carries a ripple


@pytest.mark.parametrize("motor", MOTORS)
def test_configured_ripple_matches_the_plants_measured_force(motor):
    """The plant's net force at 6 theta_e, measured at i_q = 0 and 10 A, against the
    configured coefficients: within 2 % of the rated ripple's amplitude plus 0.05 N."""
    c = configured(motor)
    f0 = measured_6theta(motor, 0.0)
    f10 = measured_6theta(motor, 10.0)
    slope = (f10 - f0) / 10.0
    amp10 = math.hypot(c[0] + 10.0 * c[2], c[1] + 10.0 * c[3])
    tol = 0.02 * amp10 + 0.05
    assert f0 == pytest.approx(c[:2], abs=tol)
    assert f10 == pytest.approx(c[:2] + 10.0 * c[2:], abs=tol)
    assert slope == pytest.approx(c[2:], abs=tol / 10.0)


def test_paper_motors_carry_no_ripple():
    """Motors without cogging or harmonics leave the term off (default 0)."""
    for motor in ("paper_salient", "paper_table1"):
        assert not np.any(configured(motor))
        assert not np.any(closed_form(motor))


@pytest.mark.parametrize("field,bad,lo,hi", [("rip6_a0_N", 2e4, -10000, 10000),
                                             ("rip6_b0_N", -2e4, -10000, 10000),
                                             ("rip6_a1_N_per_A", 2e3, -1000, 1000),
                                             ("rip6_b1_N_per_A", -2e3, -1000, 1000)])
def test_fields_are_range_checked(field, bad, lo, hi):
    """The firmware refuses a value outside the field's range, naming field and range
    (the table od.yaml generates)."""
    from sim_fallback import fw_config
    from sim_fallback._motors import firmware_check
    cfg = fw_config(load_motor("iron_core_linear"))
    assert firmware_check(cfg) == (0, "")
    setattr(cfg, field, bad)
    st, msg = firmware_check(cfg)
    assert st == 2 and msg.startswith(f"{field} = ") and f"[{lo}, {hi}]" in msg, msg


def test_identified_cogging_matches_the_closed_form():
    """The drive's own measurement of the cogging coefficients (constant-speed passes
    under the speed loop, no position sensor: identification.run_thrust_ripple) against
    the plant's closed form: within 0.6 N (7.5 % of the 8 N), from a configuration
    without them."""
    from sim_fallback import identify_thrust_ripple
    m = load_motor("iron_core_linear")
    res = identify_thrust_ripple(m, seed=1, fw={"rip6_a0_N": 0.0, "rip6_b0_N": 0.0})
    ref = closed_form("iron_core_linear")
    got = [res.values["rip6_a0_N"], res.values["rip6_b0_N"]]
    assert got == pytest.approx(ref[:2], abs=0.6), res.log
    # without the model the estimate follows a third less of the ripple's motion: the
    # first pass alone is biased, the correction is what brings it in
    assert 0.15 < res.values["rip6_observer_gain_re"] < 0.6
