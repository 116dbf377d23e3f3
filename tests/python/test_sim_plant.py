"""Plant against analytic cases, RK4 convergence order, ADC, dead time, friction."""

import math

import numpy as np
import pytest

from sim_fallback import SIM_REF_LOAD, Sim

T_PWM = 1.0 / 24000.0
IDEAL = dict(adc_noise_counts=0.0, udc_noise_V=0.0, adc_offset_counts=[0.0, 0.0, 0.0],
             dL_sat_H=0.0, F_static_N=0.0, F_coulomb_N=0.0, b_visc_Ns_per_m=0.0,
             cog_amp_N=0.0)


def make(**kw):
    ov = dict(IDEAL)
    ov.update(kw)
    return Sim("paper_salient", noise=0.0, plant=ov)


def alpha_duties(U_V, u_dc_V=300.0):
    """Duties giving u_alpha = U, u_beta = 0 (u_alpha = u_dc * delta)."""
    d = U_V / u_dc_V
    return [0.5 + d, 0.5 - d / 2, 0.5 - d / 2]


@pytest.mark.parametrize("axis", ["d", "q"])
def test_locked_rl_step(axis):
    """Locked mover: i(t) = U/R (1 - exp(-t R / L)) on the axis the voltage points along."""
    tau = 0.024
    x0 = 0.0 if axis == "d" else tau / 2  # theta_e = 0 or pi/2
    s = make(locked=1)
    s.set_state(x0_m=x0)
    U, R = 10.0, 0.958
    L = 0.012 if axis == "d" else 0.018
    duty = alpha_duties(U)
    worst = 0.0
    for k in range(1, 1201):  # 50 ms = 4 L/R (d axis)
        s.plant_advance(duty, True, T_PWM, 4)
        st = s.state()
        t = k * T_PWM
        i_ref = U / R * (1 - math.exp(-t * R / L))
        i = st["i_d_A"] if axis == "d" else -st["i_q_A"]  # u_q = -U at theta = pi/2
        other = st["i_q_A"] if axis == "d" else st["i_d_A"]
        worst = max(worst, abs(i - i_ref))
        assert abs(other) < 1e-12
    assert worst < 1e-9 * U / R
    assert s.state()["x_m"] == x0


def test_one_sample_update_delay():
    """Duties returned at step k act over [t_k+1, t_k+2): the current starts one period late."""
    s = make(locked=1)
    U, R, L = 10.0, 0.958, 0.012
    duty = np.float32(alpha_duties(U))  # fw_outputs_t carries float32 duties
    s.use_fixed_duties(duty, True)
    da, db, dc = (float(d) for d in duty)
    U = 300.0 * 2 / 3 * (da - 0.5 * db - 0.5 * dc)
    rec = s.advance(480)
    t = rec["t_s"]
    ref = np.where(t >= T_PWM, U / R * (1 - np.exp(-(t - T_PWM) * R / L)), 0.0)
    assert rec["i_d_A"][1] == 0.0 and rec["i_d_A"][2] > 0.0
    np.testing.assert_allclose(rec["i_d_A"], ref, atol=1e-9)


def _d_axis_reference(U, t_end, dL, I_sat, L0=0.012, R=0.958, n=20000):
    """numpy RK4 of di/dt = (U - R i) / L_dd(i) with a fine step."""
    h = t_end / n
    i = 0.0

    def f(i):
        return (U - R * i) / (L0 - dL * math.tanh(i / I_sat))

    for _ in range(n):
        k1 = f(i)
        k2 = f(i + h / 2 * k1)
        k3 = f(i + h / 2 * k2)
        k4 = f(i + h * k3)
        i += h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return i


def test_d_axis_saturation_polarity():
    """+i_d (along the magnet) sees the lower inductance: it rises faster than -i_d."""
    dL, I_sat = 0.0012, 5.0
    out = {}
    for sign in (+1, -1):
        s = make(locked=1, dL_sat_H=dL, I_sat_A=I_sat)
        for _ in range(480):  # 20 ms
            s.plant_advance(alpha_duties(sign * 60.0), True, T_PWM, 4)
        out[sign] = s.state()["i_d_A"]
        ref = _d_axis_reference(sign * 60.0, 480 * T_PWM, dL, I_sat)
        assert out[sign] == pytest.approx(ref, rel=1e-8)
    assert out[+1] > -out[-1] > 0


def test_free_acceleration_constant_force():
    """No friction, no current: x = a t^2 / 2 with a = F / m (load < 0 pushes +x)."""
    s = make()
    m = s.params.mass_kg
    F = 20.0
    s.set_schedule(SIM_REF_LOAD, -F)
    s.use_fixed_duties([0.5, 0.5, 0.5], False)
    rec = s.advance(2400)
    t = rec["t_s"]
    a = F / m
    np.testing.assert_allclose(rec["v_mps"], a * t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(rec["x_m"], 0.5 * a * t**2, rtol=0, atol=1e-12)
    assert np.all(rec["i_d_A"] == 0) and np.all(rec["i_q_A"] == 0)


def _sched_value(t_s, value, ramp, t):
    """sched_eval of sim_loop.c, operation for operation (Python floats are IEEE doubles)."""
    if t < t_s[0]:
        return value[0]
    i = max(j for j in range(len(t_s)) if t_s[j] <= t)
    if not ramp or i + 1 >= len(t_s):
        return value[i]
    a = (t - t_s[i]) / (t_s[i + 1] - t_s[i])
    return value[i] + a * (value[i + 1] - value[i])


@pytest.mark.parametrize("ramp", [False, True])
def test_schedules_applied_every_period(ramp):
    """sim_run re-evaluates the schedules only when one may have moved (the next
    breakpoint, every period inside a ramp): the load it applies is the schedule's value
    at every period all the same, bit for bit, across chunks, a schedule replaced in the
    middle of a run and breakpoints between periods or before the first one; and with a
    controller that takes no references (the fixed-duty one) a speed schedule next to it
    does not hold the load back."""
    s = make()
    s.use_fixed_duties([0.5, 0.5, 0.5], False)
    s.set_schedule(0, 100.0)  # speed: nothing takes it
    t1, v1 = [0.002, 0.0041, 0.0041, 0.01], [3.0, -2.0, 7.5, 1.0]
    s.set_schedule(SIM_REF_LOAD, {"t_s": t1, "value": v1, "ramp": ramp})
    got = [s.advance(150), s.advance(200)]
    t2, v2 = [0.0151, 0.02], [-4.0, 6.0]
    s.set_schedule(SIM_REF_LOAD, {"t_s": t2, "value": v2, "ramp": ramp})
    got.append(s.advance(300))
    for rec, (ts, vs) in zip(got, [(t1, v1), (t1, v1), (t2, v2)], strict=True):
        want = [_sched_value(ts, vs, ramp, t) for t in rec["t_s"]]
        assert rec["load_N"].tolist() == want
    assert got[2]["t_s"][0] < t2[0] < got[2]["t_s"][-1]


def test_static_friction_holds_without_creep_then_breaks_away():
    s = make(F_static_N=50.0, F_coulomb_N=40.0)
    m = s.params.mass_kg
    s.set_state(x0_m=0.01)
    s.set_schedule(SIM_REF_LOAD, [(0.0, 45.0), (0.5, 55.0)])
    s.use_fixed_duties([0.5, 0.5, 0.5], False)
    rec = s.advance(24000)
    t, x = rec["t_s"], rec["x_m"]
    held = t < 0.5
    assert np.all(x[held] == 0.01) and np.all(rec["v_mps"][held] == 0.0)  # no creep at all
    late = t > 0.6
    a = -(55.0 - 40.0) / m
    np.testing.assert_allclose(x[late], 0.01 + 0.5 * a * (t[late] - 0.5) ** 2, atol=1e-6)


def test_coulomb_friction_stops_and_stays():
    """v0 = 0.1 m/s decelerates at F_c / m, stops exactly and stays stopped."""
    s = make(F_static_N=12.0, F_coulomb_N=10.0, mass_kg=5.0)
    m = s.params.mass_kg
    s.set_state(x0_m=0.0, v0_mps=0.1)
    s.use_fixed_duties([0.5, 0.5, 0.5], False)
    rec = s.advance(4800)
    a = 10.0 / m
    t_stop = 0.1 / a
    after = rec["t_s"] > t_stop + 2 * T_PWM
    assert np.all(rec["v_mps"][after] == 0.0)
    assert np.ptp(rec["x_m"][after]) == 0.0
    assert rec["x_m"][-1] == pytest.approx(0.1**2 / (2 * a), abs=1e-7)


def test_cogging_force_initial_acceleration():
    s = make(cog_amp_N=8.0, cog_period_m=0.008, cog_phase_rad=0.3)
    m = s.params.mass_kg
    x0 = 0.001
    s.set_state(x0_m=x0)
    s.plant_advance([0.5] * 3, False, 1e-5, 8)
    F = 8.0 * math.sin(2 * math.pi * x0 / 0.008 + 0.3)
    assert s.state()["v_mps"] == pytest.approx(F / m * 1e-5, rel=1e-4)


def test_rk4_convergence_order():
    """Error against a fine reference falls ~2^4 per halving of the sub-step."""
    def run(n_sub):
        s = make(dL_sat_H=0.0024, I_sat_A=2.0, cog_amp_N=30.0, cog_period_m=0.008,
                 mass_kg=1.0, b_visc_Ns_per_m=5.0)
        s.set_state(x0_m=0.003, v0_mps=0.5, i_d_A=0.5, i_q_A=1.0)
        for _ in range(10):  # 10 periods of 1 ms: h = 1 ms / n_sub
            s.plant_advance([0.62, 0.41, 0.47], True, 1e-3, n_sub)
        st = s.state()
        return np.array([st["i_d_A"], st["i_q_A"], st["x_m"] * 1e3, st["v_mps"]])

    ref = run(256)
    errs = [np.max(np.abs(run(n) - ref)) for n in (1, 2, 4, 8)]
    orders = [math.log2(errs[i] / errs[i + 1]) for i in range(3)]
    assert all(3.5 < o < 4.6 for o in orders), (errs, orders)


def test_adc_quantisation_without_noise():
    s = make(locked=1)
    s.set_state(i_d_A=1.2345, i_q_A=-0.6789, x0_m=0.005)
    i, u, cnt, ucnt = s.sample()
    lsb = 50.0 / 4096
    th = math.pi * 0.005 / 0.024
    ia = math.cos(th) * 1.2345 + math.sin(th) * 0.6789
    assert cnt[0] == round(2048 + ia / lsb)
    assert i[0] == pytest.approx((cnt[0] - 2048) * lsb, abs=1e-6)
    assert abs(i[0] - ia) <= lsb / 2 + 1e-6
    assert sum(cnt) - 3 * 2048 in (-1, 0, 1)
    assert u == pytest.approx(round(300 / (500 / 4096)) * 500 / 4096, abs=1e-4)


def test_adc_noise_offset_reproducible():
    def samples(seed, noise=2.0, offs=(3.0, 0.0, 0.0)):
        s = Sim("paper_salient", noise=0.0, seed=seed,
                plant=dict(adc_noise_counts=noise, adc_offset_counts=list(offs),
                           udc_noise_V=1.0))
        return np.array([s.sample()[2] for _ in range(20000)], dtype=float)

    a, b, c = samples(1), samples(1), samples(2)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert a[:, 0].mean() == pytest.approx(2048 + 3.0, abs=0.05)
    assert a[:, 1].std() == pytest.approx(math.sqrt(4 + 1 / 12), rel=0.04)


def test_dead_time_voltage_error():
    """Phase a carries +I, b and c -I/2: u_alpha loses (4/3) u_dc t_d f_pwm."""
    t_d = 1e-6
    s = make(locked=1, dead_time_s=t_d, dead_band_A=0.01)
    U, R = 20.0, 0.958
    for _ in range(24000 // 4):  # 0.25 s = 20 L/R
        s.plant_advance(alpha_duties(U), True, T_PWM, 4)
    u_dt = 300.0 * t_d * 24000
    assert s.state()["i_d_A"] == pytest.approx((U - 4 / 3 * u_dt) / R, rel=1e-6)


def test_python_controller_port():
    """Any controller with the fw_step signature plugs in (here a Python callback)."""
    import ctypes as C

    from sim_fallback import _lib

    duty = np.float32(alpha_duties(10.0))
    seen = []

    def step(ctx, inp, out):
        seen.append(inp.contents.u_dc_V)
        for j in range(3):
            out.contents.duty_abc[j] = float(duty[j])
        out.contents.pwm_enable = 1

    cb = _lib.STEP_FN(step)
    port = _lib.SimController()
    port.step = C.cast(cb, C.c_void_p)
    a = make(locked=1)
    a.set_controller_port(port, keep=cb)
    ra = a.advance(100)
    b = make(locked=1)
    b.use_fixed_duties(duty, True)
    rb = b.advance(100)
    assert len(seen) == 100 and seen[0] == pytest.approx(300.0, abs=0.2)
    np.testing.assert_array_equal(ra["i_d_A"], rb["i_d_A"])


def test_pwm_off_current_freewheels_to_zero_and_stays():
    """Switches off with 5 A flowing: the diodes return the energy to the DC link,
    the current reaches zero within ~L I / (2/3 u_dc) and stays exactly zero."""
    s = make(locked=1)
    s.set_state(i_d_A=5.0, i_q_A=0.0)
    s.use_fixed_duties([0.5, 0.5, 0.5], False)
    rec = s.advance(240)  # 10 ms
    t_ext = 0.012 * 5.0 / (2 / 3 * 300.0)
    i = np.hypot(rec["i_d_A"], rec["i_q_A"])
    assert np.all(np.diff(i) <= 0)                     # monotonic decay, no ringing
    assert np.all(i[rec["t_s"] > 2 * t_ext] == 0.0)


# ---- integration accuracy of the default sub-step count --------------------------
#
# Criterion for the default n_sub (= 1, one RK4 step per PWM period): against a
# fine-step reference (n_sub = 64) the plant error must stay negligible next to
# what the controller can see, i.e. far below one ADC count (LSB = 12.2 mA):
#   currents: max |error| <= 1e-6 LSB, and the error's component at the
#             injection frequency <= 1e-7 of the injected HF current;
#   position: max |error| <= 1e-9 rad electrical.
# Measured (paper_salient, 100 r/min, 3.4 A, 50 V / 3 kHz d-axis injection):
# 6e-10 A (5e-8 LSB) and 4e-12 m; n_sub = 2 / 4: 16 / 256 times smaller.

LSB_A = 50.0 / 4096


def _voltage_duties(th, u_d, u_q):
    ua = u_d * math.cos(th) - u_q * math.sin(th)
    ub = u_d * math.sin(th) + u_q * math.cos(th)
    return [0.5 + ua / 300.0, 0.5 + (-0.5 * ua + 0.5 * math.sqrt(3) * ub) / 300.0,
            0.5 + (-0.5 * ua - 0.5 * math.sqrt(3) * ub) / 300.0]


def _injection_run(n_sub, n_periods=2400, f_inj=3000.0, u_inj=50.0):
    """Moving mover at 100 r/min carrying 3.4 A of i_q, sinusoidal d-axis voltage
    injection (the firmware's defaults), duties from the true state each period."""
    s = Sim("paper_salient", noise=0.0)
    tau, psi, R, Lq, iq = 0.024, 0.1827, 0.958, 0.018, 3.4
    s.set_state(x0_m=0.003, v0_mps=0.32, i_d_A=0.0, i_q_A=iq)
    out = []
    for k in range(n_periods):
        st = s.state()
        th, w = math.pi * st["x_m"] / tau, math.pi * st["v_mps"] / tau
        u_d = -w * Lq * iq + u_inj * math.cos(2 * math.pi * f_inj * k * T_PWM)
        u_q = R * iq + w * psi
        s.plant_advance(_voltage_duties(th, u_d, u_q), True, T_PWM, n_sub)
        st = s.state()
        out.append([st["i_d_A"], st["i_q_A"], st["x_m"], st["v_mps"]])
    return np.array(out)


def test_default_n_sub_error_at_injection_frequency():
    n_default = Sim("paper_salient").params.n_sub
    assert n_default == 1
    ref = _injection_run(64)
    got = _injection_run(n_default)
    err = got - ref
    assert np.max(np.abs(err[:, :2])) <= 1e-6 * LSB_A
    assert np.max(np.abs(err[:, 2])) * math.pi / 0.024 <= 1e-9
    k = np.arange(len(ref))
    ph = np.exp(-2j * math.pi * 3000.0 * k * T_PWM)
    hf_ref = abs(np.sum((ref[:, 0] - ref[:, 0].mean()) * ph))
    hf_err = abs(np.sum(err[:, 0] * ph))
    assert 2.0 * hf_ref / len(k) > 0.1  # the injected HF current is really there (~0.2 A)
    assert hf_err <= 1e-7 * hf_ref
    # the error is RK4 truncation: order 4 in the sub-step
    e2 = np.max(np.abs(_injection_run(2)[:, :2] - ref[:, :2]))
    assert 8.0 < np.max(np.abs(err[:, :2])) / e2 < 32.0


def _friction_event_run(n_sub, k_off=1900, n_periods=3800):
    """From standstill: a q-axis voltage ramps the thrust through F_static
    (break-away inside a period), then reverses: the mover decelerates through
    v = 0 (Coulomb sign flip) and, with the voltage removed, stops and sticks."""
    s = Sim("paper_salient", noise=0.0)
    s.set_state(x0_m=0.0)
    out = []
    for k in range(n_periods):
        st = s.state()
        th = math.pi * st["x_m"] / 0.024
        u_q = 12.0 if k < 1200 else (-12.0 if k < k_off else 0.0)
        s.plant_advance(_voltage_duties(th, 0.0, u_q), True, T_PWM, n_sub)
        st = s.state()
        out.append([st["i_d_A"], st["i_q_A"], st["x_m"], st["v_mps"], st["stuck"]])
    return np.array(out)


def test_friction_events_located_inside_the_period():
    """Break-away, velocity reversal and sticking are located inside the sub-step
    (regula falsi on the drive force / velocity), so one sub-step per period is
    as accurate across the events as a fine step."""
    ref = _friction_event_run(64)
    stuck = ref[:, 4]
    assert stuck[0] == 1 and np.any(stuck == 0) and stuck[-1] == 1  # all events happen
    assert np.any(ref[:, 3] > 0) and np.any(ref[:, 3] < 0)           # reversal
    got = _friction_event_run(1)
    err = np.abs(got - ref).max(axis=0)
    assert err[0] <= 1e-7 * LSB_A and err[1] <= 1e-7 * LSB_A
    assert err[2] <= 1e-12 and err[3] <= 1e-10
    assert np.array_equal(got[:, 4], stuck)


@pytest.mark.parametrize("i_d", [-7.3, -1.2, 0.0, 0.061, 0.4, 2.49, 6.0, 13.7])
def test_flux_expansion_matches_closed_form(i_d):
    """Thrust from the expanded psi_d (grid point nearest i_d, Taylor order 8)
    equals the closed form with libm to round-off."""
    dL, I_sat = 0.0012, 5.0
    s = make(locked=1, dL_sat_H=dL, I_sat_A=I_sat)
    s.set_state(x0_m=0.001, i_d_A=i_d, i_q_A=2.0)
    s.plant_advance([0.5, 0.5, 0.5], True, 1e-12, 1)  # sets the expansion point
    st = s.state()
    idd, iq = st["i_d_A"], st["i_q_A"]
    psi = 0.1827 + 0.012 * idd - dL * I_sat * math.log(math.cosh(idd / I_sat))
    F = 1.5 * math.pi / 0.024 * (psi * iq - 0.018 * iq * idd)
    assert s.force_N() == pytest.approx(F, rel=1e-13, abs=1e-12)


def test_a_flux_parameter_changed_mid_run_takes_effect():
    """set_plant(psi_f_Wb=...) on the saturating motor: the plant then integrates
    exactly as one built with that psi_f from the same state (the flux expansion
    coefficients cached per grid point are recomputed, not reused)."""
    from sim_fallback import Sim
    s0 = dict(x0_m=0.01, v0_mps=0.2, i_d_A=1.5, i_q_A=2.0)
    duty, n = (0.62, 0.41, 0.47), 200

    def run(sim):
        sim.set_state(**s0)
        for _ in range(n):
            sim.plant_advance(duty, True, sim.dt_s, 1)
        return sim.state()

    a = Sim("paper_salient", noise=0.0)
    psi = a.params.psi_f_Wb
    run(a)  # fills the cached coefficients with the old psi_f
    a.set_plant(psi_f_Wb=0.8 * psi)
    b = Sim("paper_salient", noise=0.0, plant={"psi_f_Wb": 0.8 * psi})
    sa, sb = run(a), run(b)
    assert sa == sb
    c = Sim("paper_salient", noise=0.0)  # and the change is visible at all
    assert run(c)["i_d_A"] != sb["i_d_A"]
