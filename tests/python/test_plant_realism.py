"""Plant realism (docs/simulator.md "Plant realism"): every effect against an analytic
case, measured in the simulated plant (fixed duties at a locked or coasting mover, as
test equipment would), compared as numbers within stated tolerances.

The closed forms here are written from the documented equations, independently of the C
code: a sign or factor slip in either shows as a mismatch.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_fallback import Sim, load_motor
from sim_fallback._lib import REALISM_FIELDS
from sim_fallback._motors import MotorFileError

MOTOR = "realistic_linear"
OFF = {k: 0 for k in REALISM_FIELDS}
REAL = load_motor(MOTOR).realism
SQ3 = math.sqrt(3.0)


def _sim(plant: dict, **kw) -> Sim:
    """realistic_linear with the realism fields given (others 0), no ADC noise, ideal
    inverter unless the overrides say otherwise, no cogging."""
    ov = dict(OFF, dead_time_s=0.0, cog_amp_N=0.0) | plant
    return Sim(MOTOR, noise=0.0, plant=ov, **kw)


def _rot(th: float) -> np.ndarray:
    return np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])


def _duties(s: Sim, u_ab: np.ndarray) -> list[float]:
    """Duties that make the average inverter apply u_alpha_beta (ideal inverter)."""
    ua, ub = u_ab
    u_abc = [ua, -0.5 * ua + 0.5 * SQ3 * ub, -0.5 * ua - 0.5 * SQ3 * ub]
    return [0.5 + u / s.params.u_dc_V for u in u_abc]


def _delta_i(s: Sim, x: float, i_dq: np.ndarray, u_ab: np.ndarray, dt: float,
             v: float = 0.0) -> np.ndarray:
    """Rotor-frame current change over dt from state (x, v, i_dq) under u_alpha_beta."""
    s.set_state(x0_m=x, v0_mps=v, i_d_A=float(i_dq[0]), i_q_A=float(i_dq[1]))
    s.plant_advance(_duties(s, u_ab), True, dt, 4)
    st = s.state()
    return np.array([st["i_d_A"], st["i_q_A"]]) - i_dq


def _inductance_ab(s: Sim, x: float, i_dq: np.ndarray, U: float = 2.0) -> np.ndarray:
    """Incremental inductance in the stator frame measured at a locked mover: +-U pulses
    along alpha and beta on top of the holding voltage R i (symmetric differences cancel
    the even-order terms), M = U dt [di(alpha) di(beta)]^-1."""
    th = math.pi * x / s.params.tau_m
    R = _rot(th)
    dt = 1.0 / s.params.f_pwm_Hz
    u0 = R @ (s.params.R_ohm * i_dq)
    cols = []
    for e in (np.array([1.0, 0.0]), np.array([0.0, 1.0])):
        dp = _delta_i(s, x, i_dq, u0 + U * e, dt)
        dm = _delta_i(s, x, i_dq, u0 - U * e, dt)
        cols.append(R @ (0.5 * (dp - dm)))
    return U * dt * np.linalg.inv(np.column_stack(cols))


# ---- off = today's plant -------------------------------------------------------


def test_every_effect_off_is_the_plant_without_realism() -> None:
    """All realism fields 0: the same arrays, bit for bit, as a simulation whose
    realism was never set (the plant's own paths; plant_bitcheck.py compares them with
    the library before the realism was added)."""
    m = load_motor("iron_core_linear")
    out = []
    for plant in (None, OFF):
        with Sim(m, seed=4, plant=plant) as s:
            s.set_schedule(0, 30.0)
            s.set_schedule(2, [(0.0, 0.0), (0.1, 200.0)])
            s.enable()
            out.append(s.advance(int(0.2 / s.dt_s)))
    for k in out[0]:
        assert np.array_equal(out[0][k], out[1][k], equal_nan=True), k


def test_full_model_reduces_to_the_fast_plant() -> None:
    """The full magnetic model (taken when any realism field is set) with its effects
    negligible integrates the same trajectory as the plant's expansion path: fixed duties,
    moving mover, d-axis saturation and cogging, 20 ms; currents within 1e-9 A, position
    within 1e-12 m."""
    res = []
    for plant in ({}, {"emf_h7": 1e-300}):
        with Sim("iron_core_linear", noise=0.0, plant=plant) as s:
            s.set_state(x0_m=0.003, v0_mps=0.2, i_d_A=1.0, i_q_A=3.0)
            s.plant_advance([0.62, 0.45, 0.43], True, 0.02, 480)
            res.append(s.state())
    for k in ("i_d_A", "i_q_A"):
        assert abs(res[0][k] - res[1][k]) < 1e-9, k
    assert abs(res[0]["x_m"] - res[1]["x_m"]) < 1e-12


# ---- magnetics: reciprocity and energy --------------------------------------------


def _points() -> list[tuple[float, float, float]]:
    rng = np.random.default_rng(1)
    pts = [(0.0, 10.0, 0.004), (-5.0, 20.0, 0.2995), (3.0, -12.0, -0.31)]
    pts += [tuple(v) for v in np.column_stack([rng.uniform(-15, 15, 6), rng.uniform(-20, 20, 6),
                                               rng.uniform(-0.4, 0.4, 6)])]
    return pts


def test_flux_maps_are_reciprocal_and_give_the_incremental_inductance() -> None:
    """d psi / d i by central differences (1e-4 A) equals the plant's incremental
    inductance, and d psi_d / d i_q = d psi_q / d i_d, within 1e-8 H (~1e-6 of L)."""
    with _sim(REAL) as s:
        for i_d, i_q, x in _points():
            h = 1e-4
            J = np.zeros((2, 2))
            for k, di in enumerate((np.array([h, 0.0]), np.array([0.0, h]))):
                pp = s.magnetics(i_d + di[0], i_q + di[1], x)["psi_dq_Wb"]
                pm = s.magnetics(i_d - di[0], i_q - di[1], x)["psi_dq_Wb"]
                J[:, k] = (pp - pm) / (2 * h)
            L = s.magnetics(i_d, i_q, x)["L_dq_H"]
            assert abs(J[0, 1] - J[1, 0]) < 1e-8, (i_d, i_q, x, J)
            assert np.allclose(J, [[L[0], L[1]], [L[1], L[2]]], atol=1e-8, rtol=0), (J, L)


def test_no_work_around_a_closed_current_loop() -> None:
    """At a locked position the electrical work around a closed current loop,
    3/2 (loop integral of i . d psi), vanishes (a lossless, reciprocal magnetic model):
    |W| < 1e-6 of the work's absolute integral, on loops through saturation."""
    with _sim(REAL) as s:
        for c_d, c_q, r, x in ((0.0, 8.0, 6.0, 0.01), (-4.0, -10.0, 9.0, 0.305)):
            n = 4000
            ph = np.linspace(0.0, 2 * math.pi, n + 1)
            i = np.column_stack([c_d + r * np.cos(ph), c_q + r * np.sin(ph)])
            th = math.pi * x / s.params.tau_m
            R = _rot(th)
            psi = np.array([R @ s.magnetics(a, b, x)["psi_dq_Wb"] for a, b in i])
            i_ab = i @ R.T
            im = 0.5 * (i_ab[1:] + i_ab[:-1])
            dw = 1.5 * np.sum(im * np.diff(psi, axis=0), axis=1)
            assert abs(dw.sum()) < 1e-6 * np.abs(dw).sum(), (dw.sum(), np.abs(dw).sum())


def test_thrust_is_the_coenergy_derivative() -> None:
    """F = dW'/dx at fixed stator currents, W' = 3/2 int_0^1 psi_ab(s i_ab, x) . i_ab ds
    (20-point Gauss-Legendre), central difference over +-1 um: the plant's thrust
    (sim_force_N at that state: magnetics, saliencies, harmonics, end effect) within
    1e-5 N + 1e-6 |F|."""
    gx, gw = np.polynomial.legendre.leggauss(20)
    sq, wq = 0.5 * (gx + 1.0), 0.5 * gw
    with _sim(REAL) as s:
        k = math.pi / s.params.tau_m

        def coenergy(i_ab: np.ndarray, x: float) -> float:
            R = _rot(k * x)
            i_dq = R.T @ i_ab
            return 1.5 * sum(w * float((R @ s.magnetics(*(si * i_dq), x)["psi_dq_Wb"]) @ i_ab)
                             for si, w in zip(sq, wq, strict=True))

        for i_d, i_q, x in _points():
            i_ab = _rot(k * x) @ np.array([i_d, i_q])
            h = 1e-6
            F_fd = (coenergy(i_ab, x + h) - coenergy(i_ab, x - h)) / (2 * h)
            s.set_state(x0_m=x, i_d_A=i_d, i_q_A=i_q)
            F = s.force_N()
            assert F == pytest.approx(s.magnetics(i_d, i_q, x)["force_N"], abs=0, rel=0)
            assert abs(F - F_fd) < 1e-5 + 1e-6 * abs(F), (i_d, i_q, x, F, F_fd)


# ---- the HF admittance's angle offset -----------------------------------------------


def _hf_axis_angle(s: Sim, x: float, i_q: float, U: float = 2.0) -> float:
    """Angle (rotor frame) of the direction gamma where a square-wave voltage along gamma
    produces no HF current across it (what an injection estimator locks onto), found by
    bisection; the response is the +-U symmetric difference over one PWM period."""
    th = math.pi * x / s.params.tau_m
    R = _rot(th)
    dt = 1.0 / s.params.f_pwm_Hz
    i0 = np.array([0.0, i_q])
    u0 = R @ (s.params.R_ohm * i0)

    def cross(g: float) -> float:
        n = np.array([math.cos(g), math.sin(g)])
        d = 0.5 * (_delta_i(s, x, i0, u0 + U * (R @ n), dt) -
                   _delta_i(s, x, i0, u0 - U * (R @ n), dt))
        return float(d @ np.array([-n[1], n[0]]))

    lo, hi = -0.6, 0.6
    f_lo = cross(lo)
    assert f_lo * cross(hi) < 0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        f = cross(mid)
        if (f < 0) == (f_lo < 0):
            lo, f_lo = mid, f
        else:
            hi = mid
    return 0.5 * (lo + hi)


def test_hf_angle_offset_from_cross_saturation_matches_closed_form() -> None:
    """Cross- and q-saturation only, locked mover, i_d = 0: the measured HF axis angle
    over i_q against theta_err = 1/2 atan2(-2 L_dq, L_qq - L_dd) with L_dd = L_d0,
    L_dq = -L_x tanh(i_q/I_x), L_qq = L_q - dLq tanh^2(i_q/Iq): within 1e-4 rad; 10.1 el.
    deg at the rated 10 A."""
    m = load_motor(MOTOR)
    p = {k: REAL[k] for k in ("dLq_sat_H", "Iq_sat_A", "cross_L_H", "cross_I_A")}
    L_d0, L_q = m.plant["L_d0_H"], m.plant["L_q_H"]
    with _sim(p | {"locked": 1}) as s:
        for i_q in (-20.0, -10.0, -5.0, 0.0, 2.0, 5.0, 10.0, 15.0, 20.0):
            L_dq = -p["cross_L_H"] * math.tanh(i_q / p["cross_I_A"])
            L_qq = L_q - p["dLq_sat_H"] * math.tanh(i_q / p["Iq_sat_A"]) ** 2
            want = 0.5 * math.atan2(-2.0 * L_dq, L_qq - L_d0)
            got = _hf_axis_angle(s, 0.004, i_q)
            assert abs(got - want) < 1e-4, (i_q, got, want)
            if i_q == 10.0:
                assert math.degrees(want) == pytest.approx(10.10, abs=0.01)


def test_hf_angle_ripple_from_the_secondary_saliency_matches_closed_form() -> None:
    """Secondary saliency only, no current: the HF axis angle over one electrical period
    against 1/2 arg((L_q - L_d)/2 - L_n e^{j(a - 2 theta)}), a = n theta + phase: within
    1e-4 rad (a +-2.9 el. deg ripple for realistic_linear)."""
    m = load_motor(MOTOR)
    p = {"sal2_L_H": REAL["sal2_L_H"], "sal2_order": REAL["sal2_order"],
         "sal2_phase_rad": 0.3}
    dL = 0.5 * (m.plant["L_q_H"] - m.plant["L_d0_H"])
    tau = m.plant["tau_m"]
    worst = 0.0
    with _sim(p | {"locked": 1}) as s:
        for x in np.linspace(0.0, 2 * tau, 9)[:-1] + 0.0007:
            th = math.pi * x / tau
            a = p["sal2_order"] * th + p["sal2_phase_rad"]
            want = 0.5 * np.angle(dL - p["sal2_L_H"] * np.exp(1j * (a - 2 * th)))
            got = _hf_axis_angle(s, x, 0.0)
            assert abs(got - want) < 1e-4, (x, got, want)
            worst = max(worst, abs(got))
    # the ripple's peak, 1/2 asin(L_n / ((L_q - L_d)/2)) = 2.87 el. deg, bounds the samples
    peak = math.degrees(0.5 * math.asin(p["sal2_L_H"] / dL))
    assert peak == pytest.approx(2.87, abs=0.01)
    assert 2.0 < math.degrees(worst) <= peak + 0.01


# ---- back-EMF harmonics ------------------------------------------------------------


def test_back_emf_harmonics_by_fft_of_the_open_circuit_phase_voltage() -> None:
    """Coasting mover (0.5 m/s), zero current: the phase-a voltage that the winding's
    flux induces, measured from the current's response to a short zero-voltage probe
    (2 us) at 256 positions over one electrical period; its FFT gives the 5th and 7th
    harmonics relative to the fundamental as configured (amplitude within 1e-4, phase
    within 5 mrad), nothing else above 1e-4."""
    p = {"emf_h5": 0.03, "emf_h5_phase_rad": 2.0, "emf_h7": 0.015, "emf_h7_phase_rad": -0.7}
    n, v, dt = 256, 0.5, 2e-6
    with _sim(p | {"F_coulomb_N": 0.0, "F_static_N": 0.0, "b_visc_Ns_per_m": 0.0,
                   "mass_kg": 1e5}) as s:
        tau = s.params.tau_m
        M = np.diag([s.params.L_d0_H, s.params.L_q_H])
        e_a = []
        for k in range(n):
            x = 2 * tau * k / n - 0.5 * v * dt  # the probe's mid-point at theta = 2 pi k / n
            di = _delta_i(s, x, np.zeros(2), np.zeros(2), dt, v=v)
            e_dq = -(M @ di) / dt  # M di/dt = -e (R i = 0 at i = 0)
            e_a.append((_rot(2 * math.pi * k / n) @ e_dq)[0])
    c = np.fft.rfft(np.array(e_a)) / n
    # e_a = -omega psi_f (sin th + h5 sin(5 th + phi5) + h7 sin(7 th + phi7))
    for h, amp, ph in ((5, p["emf_h5"], p["emf_h5_phase_rad"]),
                       (7, p["emf_h7"], p["emf_h7_phase_rad"])):
        r = c[h] / c[1]
        assert abs(abs(r) - amp) < 1e-4, (h, abs(r))
        assert abs(np.angle(r * np.exp(-1j * ph))) < 5e-3, (h, np.angle(r))
    others = [abs(c[h] / c[1]) for h in range(2, 40) if h not in (5, 7)]
    assert max(others) < 1e-4


# ---- end effect -----------------------------------------------------------------


def _exposure(x: float, r: dict) -> float:
    edge = 0.0
    if r["end_travel_m"] > 0:
        h, z = 0.5 * r["end_travel_m"], r["end_zone_m"]
        edge = 0.5 * (1 + math.tanh((x - h) / z)) + 0.5 * (1 - math.tanh((x + h) / z))
    return r["end_base"] + (1 - r["end_base"]) * edge


def test_end_effect_phase_inductances_over_the_travel() -> None:
    """Locked mover at positions across the travel: the phase-aligned inductances
    L_j = n_j^T M_ab n_j (M_ab measured from alpha/beta voltage pulses) with the end
    effect minus without it, against -2/3 dL e(x) (5/4, 1/2, 5/4) for phases a, b, c
    (outer phases a and c lose their self-inductance): within 1e-7 H."""
    keys = ("end_dL_H", "end_psi_frac", "end_base", "end_travel_m", "end_zone_m")
    r = {k: REAL[k] for k in keys}
    n = [np.array([1.0, 0.0]), np.array([-0.5, 0.5 * SQ3]), np.array([-0.5, -0.5 * SQ3])]
    xs = (0.0013, 0.2, 0.29, 0.3, 0.312, 0.45, -0.3)
    with _sim(r | {"locked": 1}) as s_on, _sim({"locked": 1}) as s_off:
        for x in xs:
            M_on, M_off = (_inductance_ab(s, x, np.zeros(2)) for s in (s_on, s_off))
            dL = [float(nj @ (M_on - M_off) @ nj) for nj in n]
            want = -2 / 3 * r["end_dL_H"] * _exposure(x, r) * np.array([1.25, 0.5, 1.25])
            assert np.allclose(dL, want, atol=1e-7, rtol=0), (x, dL, want)


# ---- inverter -------------------------------------------------------------------


def _pole_error(i: float, r: dict, p) -> float:
    """The documented pole-voltage error (dead time with capacitive commutation, device
    drops) for phase current i."""
    a, td, C, u = abs(i), p.dead_time_s, r["dt_C_eq_F"], p.u_dc_V
    m = td * td * a / (2 * C) if a * td <= C * u else u * td - C * u * u / (2 * a)
    band = p.dead_band_A
    return (p.f_pwm_Hz * math.copysign(m, i) if i != 0 else 0.0) + \
        r["u_dev_V"] * max(-1.0, min(1.0, i / band)) + r["r_dev_ohm"] * i


def test_dead_time_voltage_error_with_zero_current_clamp() -> None:
    """Locked mover at theta = 0, current along phase a (i_a = I, i_b = i_c = -I/2):
    the alpha-axis voltage lost to the inverter (pulse response with the realistic
    inverter minus the ideal one) against the Clarke transform of the documented
    per-phase error, over I in [-3, 3] A: within 1e-3 relative. The error is linear through
    zero current (clamp, |I| < i_c = C u_dc / t_d = 0.2 A) and approaches u_dc t_d f_pwm
    (7.2 V) minus the device drops' share at large current. (Tolerance 1e-3 relative
    + 10 uV: the inverter's current sign is taken at each sub-step start, so inside the
    clamp, an 18 ohm slope, the error lags the current by a sub-step.)"""
    m = load_motor(MOTOR)
    keys = ("dt_C_eq_F", "u_dev_V", "r_dev_ohm")
    r = {k: REAL[k] for k in keys}
    dt_s = m.plant["dead_time_s"]
    with _sim(r | {"locked": 1, "dead_time_s": dt_s}) as s_on, \
            _sim({"locked": 1, "dead_time_s": 0.0}) as s_off:
        dt = 1e-7
        for i_a in np.linspace(-3.0, 3.0, 61):
            i = np.array([i_a, 0.0])
            L = s_on.magnetics(i_a, 0.0, 0.0)["L_dq_H"]
            M = np.array([[L[0], L[1]], [L[1], L[2]]])
            # a constant voltage difference du drives di = (M/dt + R/2)^-1 du + O(dt^2)
            du = (M / dt + 0.5 * s_on.params.R_ohm * np.eye(2)) @ (
                _delta_i(s_on, 0.0, i, np.zeros(2), dt) - _delta_i(s_off, 0.0, i, np.zeros(2), dt))
            e = [_pole_error(ij, r, s_on.params) for ij in (i_a, -0.5 * i_a, -0.5 * i_a)]
            want = -(2 / 3) * (e[0] - 0.5 * e[1] - 0.5 * e[2])
            assert abs(du[0] - want) < 1e-5 + 1e-3 * abs(want), (i_a, du, want)
            assert abs(du[1]) < 1e-9
    # the formula's shape: continuous at i_c, odd, 7.2 V asymptote of the dead-time part
    p = s_on.params
    i_c = r["dt_C_eq_F"] * p.u_dc_V / dt_s
    r0 = dict(r, u_dev_V=0.0, r_dev_ohm=0.0)
    assert _pole_error(i_c * (1 - 1e-9), r0, p) == pytest.approx(_pole_error(i_c * (1 + 1e-9),
                                                                            r0, p), rel=1e-6)
    assert _pole_error(1e3, r0, p) == pytest.approx(p.u_dc_V * dt_s * p.f_pwm_Hz, rel=1e-3)


# ---- parameters -------------------------------------------------------------------


def test_realistic_linear_loads_with_every_effect_on() -> None:
    m = load_motor(MOTOR)
    assert all(m.realism[k] != 0 for k in REALISM_FIELDS if not k.endswith("phase_rad")), \
        m.realism
    # without the fields: every effect off (the order only matters with an amplitude)
    off = load_motor("iron_core_linear").realism
    assert all(v == 0 for k, v in off.items() if k != "sal2_order"), off


@pytest.mark.parametrize("section,text,field", [
    ("electrical", "cross_L_H = 0.001\n", "electrical.cross_I_A"),
    ("electrical", "saliency2_order = 2.5\n", "electrical.saliency2_order"),
    ("electrical", "emf_h5 = 0.7\n", "electrical.emf_h5"),
    ("end_effect", "travel_m = 0.5\n", "end_effect.zone_m"),
    ("end_effect", "length_m = 0.5\n", "end_effect.length_m"),
    ("inverter", "device_drop_V = -1\n", "inverter.device_drop_V"),
    ("electrical", "cross_L_H = 0.2\ncross_I_A = 1.0\n", "electrical.cross_L_H"),
])
def test_bad_realism_fields_are_one_line_errors(tmp_path, section, text, field) -> None:
    src = (load_motor("iron_core_linear").path).read_text()
    if f"[{section}]" not in src:
        src += f"\n[{section}]\n"
    src = src.replace(f"[{section}]\n", f"[{section}]\n{text}", 1)
    f = tmp_path / "m.toml"
    f.write_text(src)
    with pytest.raises(MotorFileError) as e:
        load_motor(f)
    assert e.value.field == field, str(e.value)
    assert "\n" not in str(e.value) and ("allowed" in str(e.value)), str(e.value)


def test_realism_changes_mid_run_and_refusal_names_the_field() -> None:
    with _sim({}) as s:
        s.set_plant(cross_L_H=5e-4, cross_I_A=10.0)
        s.set_state(i_q_A=10.0)
        assert s.magnetics(0.0, 10.0, 0.0)["L_dq_H"][1] == pytest.approx(-5e-4 * math.tanh(1.0))
        with pytest.raises(ValueError, match="cross_I_A"):
            s.set_plant(cross_I_A=0.0)


def test_the_emulated_board_refuses_a_plant_it_cannot_simulate() -> None:
    """The emulated board's boot block has no realism block: a motor that sets one is
    refused in one line naming its fields, not run as a simpler plant."""
    from sim_fallback import emu_boot_blob

    with pytest.raises(ValueError, match=r"realistic_linear: .*cross_L_H.*--sim"):
        emu_boot_blob(motor="realistic_linear")
    with pytest.raises(ValueError, match=r"emf_h5"):
        emu_boot_blob(motor="iron_core_linear", plant={"emf_h5": 0.02})
    assert len(emu_boot_blob(motor="iron_core_linear", plant={"emf_h5": 0.0})) > 0
