"""Back-EMF observer and the injection <-> back-EMF handover on iron_core_linear:
standstill to 2 m/s and back, reverse, load steps at low and high speed, judged
from the simulator's truth (docs/bemf.md)."""

import ctypes as C
import math

import numpy as np
import pytest

from sim_fallback import SIM_REF_LOAD, SIM_REF_SPEED, Firmware, Sim, _lib
from sim_fallback._motors import MOTOR_DIR, fw_config, load_motor
from sim_fallback._sim import wrap_pi

T = [0.0, 0.2, 1.2, 1.8, 2.8, 3.6, 4.4, 5.0]
V = [0.0, 0.0, 2.0, 2.0, -2.0, -2.0, 0.0, 0.0]
LOAD = [(0.0, 0.0), (0.5, 20.0), (0.7, 0.0), (1.4, 20.0), (1.6, 0.0), (4.6, 20.0)]


def run_range(seed: int = 1, fw: dict | None = None) -> dict:
    """The whole speed range in 1 ms chunks: truth, estimate and handover state."""
    mot = load_motor("iron_core_linear")
    with Sim(mot, seed=seed, fw=fw) as sim:
        sim.set_schedule(SIM_REF_SPEED, {"t_s": T, "value": V, "ramp": True},
                         mot.mps_to_radps_e(1.0))
        sim.set_schedule(SIM_REF_LOAD, LOAD)
        sim.enable("speed")
        ch = ["t_s", "theta_e_rad", "theta_hat_rad", "v_mps", "omega_f_radps", "fault_code",
              "i_dq_hat_A"]
        parts, active, scale = [], [], []
        for _ in range(int(5.0 / 0.001)):
            parts.append(sim.advance(24, channels=ch))
            s = sim.snapshot()
            active += [s["bemf_active"]] * 24
            scale += [s["inj_scale"]] * 24
        cfg = sim.cfg
    d = {k: np.concatenate([p[k] for p in parts]) for k in ch}
    d["active"], d["inj_scale"] = np.array(active), np.array(scale)
    d["err"] = wrap_pi(d["theta_e_rad"] - d["theta_hat_rad"])
    d["share"] = cfg.bemf_inj_share
    return d


@pytest.fixture(scope="module")
def rng():
    return run_range()


def test_whole_range_tracks_without_fault(rng):
    assert not np.any(rng["fault_code"])
    assert np.max(np.abs(rng["v_mps"])) > 1.95  # really reached 2 m/s, both ways
    assert np.min(rng["v_mps"]) < -1.95
    m = rng["t_s"] >= 0.25
    e = rng["err"][m]
    assert np.sqrt(np.mean(e ** 2)) <= 0.05 and np.max(np.abs(e)) <= 0.25


def test_handover_both_ways_and_reduced_injection(rng):
    sw = np.nonzero(np.diff(rng["active"].astype(int)))[0]
    ups = [k for k in sw if rng["active"][k + 1]]
    downs = [k for k in sw if not rng["active"][k + 1]]
    assert len(ups) >= 2 and len(downs) >= 2, (ups, downs)  # forward and reverse
    on = rng["active"] == 1
    # at speed on the back-EMF the injection is at its reduced share
    steady = on & (np.abs(rng["v_mps"]) > 1.5)
    assert np.allclose(rng["inj_scale"][steady], rng["share"])


def test_no_jump_at_the_handover(rng):
    """Across each switch (+-2 ms) the true position error moves by less than
    0.02 rad el. and the thrust current by less than 0.5 A."""
    sw = np.nonzero(np.diff(rng["active"].astype(int)))[0]
    iq = rng["i_dq_hat_A"][:, 1]
    for k in sw:
        a, b = k - 48, k + 48
        de = abs(rng["err"][b] - rng["err"][a])
        diq = abs(np.median(iq[b - 12:b + 12]) - np.median(iq[a - 12:a + 12]))
        assert de <= 0.02, (k, de)
        assert diq <= 0.5, (k, diq)


def test_back_emf_improves_high_speed_accuracy(rng):
    """At 2 m/s the back-EMF estimate is better than injection alone."""
    inj = run_range(fw={"bemf_v_on_mps": 0.0})
    m = (np.abs(rng["v_mps"]) > 1.9) & (rng["t_s"] > 1.0)
    rms_b = np.sqrt(np.mean(rng["err"][m] ** 2))
    rms_i = np.sqrt(np.mean(inj["err"][m] ** 2))
    assert rms_b < rms_i, (rms_b, rms_i)


@pytest.mark.parametrize("v0", [2.0, -0.94])
def test_flying_start_never_accelerates_the_mover(v0):
    """Enabled on a coasting mover, the drive catches it on the back-EMF within the
    alignment's motion check (15 ms), never pushes it faster, and brings it to the
    reference without a fault. From 2 m/s the mover brakes to rest and sticks (20 N
    static friction): the speed PI (80 rad/s, integral 1/6 of it) needs some time to
    build the breakaway current, so the run lasts 1.5 s (with the derived observer the
    speed estimate no longer jitters the integrator through the stiction earlier)."""
    mot = load_motor("iron_core_linear")
    target = 0.1 if v0 > 0 else -0.1
    with Sim(mot, seed=4) as sim:
        sim.set_schedule(SIM_REF_SPEED, target, mot.mps_to_radps_e(1.0))
        sim.set_state(x0_m=0.003, v0_mps=v0)
        sim.enable("speed")
        r = sim.advance(int(1.5 / sim.dt_s), channels=["t_s", "v_mps", "fault_code",
                                                       "start_phase", "theta_e_rad",
                                                       "theta_hat_rad"])
        snap = sim.snapshot()
    assert not np.any(r["fault_code"]) and snap["flying_start"] == 1
    k_run = int(np.argmax(r["start_phase"] == 3))
    assert r["t_s"][k_run] <= 0.016  # caught at the motion check
    assert np.max(np.abs(r["v_mps"])) <= abs(v0) + 0.01  # never accelerated
    assert abs(r["v_mps"][-1] - target) < 0.05  # brought to the reference
    e = wrap_pi(r["theta_e_rad"] - r["theta_hat_rad"])[k_run + 1:]  # from the catch on
    assert np.max(np.abs(e)) < 0.3


LEVELS = (("bemf_e_on_V", "bemf_v_on_mps"), ("bemf_e_off_V", "bemf_v_off_mps"),
          ("mon_bemf_min_V", "mon_bemf_min_mps"))


@pytest.mark.parametrize("name", sorted(p.stem for p in MOTOR_DIR.glob("*.toml")))
def test_levels_are_the_back_emf_of_the_configured_speeds(name):
    """The handover and witness levels the drive compares are the back-EMF
    psi_f (pi / tau) v of their configured speeds (analytic, in double), per shipped motor:
    through the Python configuration path (fw_config, and what fw_init stores) and through
    fw_config_default with the motor's psi_f, pole pitch and speeds + the C derivation."""
    mot = load_motor(name)
    k = mot.plant["psi_f_Wb"] * math.pi / mot.tau_m  # V per m/s
    cfg = fw_config(mot)
    fw = Firmware(cfg, strict=False)  # paper_table1 is stored, refused at enable
    L = _lib.lib()
    L.fw_get_config.restype = C.POINTER(_lib.FwConfig)
    L.fw_get_config.argtypes = [C.c_void_p]
    stored = L.fw_get_config(fw.handle).contents
    raw = _lib.FwConfig()
    L.fw_config_default(raw)
    for f in ("psi_f_Wb", "pole_pitch_m", *(v for _, v in LEVELS)):
        setattr(raw, f, getattr(cfg, f))
    L.fw_config_derive(raw)
    for level, speed in LEVELS:
        v = getattr(cfg, speed)
        assert v == pytest.approx(mot.controller.get(speed, getattr(raw, speed)), rel=1e-7)
        assert v > 0.0
        for c in (cfg, stored, raw):
            assert getattr(c, level) == pytest.approx(k * v, rel=1e-6), (name, level)
    fw.close()


def _handover_speeds(plant_scale: float) -> tuple[float, float, object]:
    """iron_core_linear with magnet and configuration scaled by plant_scale, ramped
    0 -> 0.5 -> 0 m/s at 0.5 m/s^2: the true speed when the drive hands over to the
    back-EMF (active) and when it decides to go back (the injection starts rising)."""
    mot = load_motor("iron_core_linear")
    psi = mot.plant["psi_f_Wb"] * plant_scale
    with Sim(mot, seed=2, plant={"psi_f_Wb": psi}, fw={"psi_f_Wb": psi}) as sim:
        sim.set_schedule(SIM_REF_SPEED, {"t_s": [0.0, 0.2, 1.2, 1.5, 2.5, 3.0],
                                         "value": [0.0, 0.0, 0.5, 0.5, 0.0, 0.0],
                                         "ramp": True}, mot.mps_to_radps_e(1.0))
        sim.enable("speed")
        v, act, scale = [], [], []
        for _ in range(3000):
            v.append(float(sim.advance(24, channels=["v_mps"])["v_mps"][-1]))
            s = sim.snapshot()
            act.append(s["bemf_active"])
            scale.append(s["inj_scale"])
            assert s["fault_code"] == 0
        cfg = sim.cfg
    act, scale = np.array(act), np.array(scale)
    k_up = int(np.argmax(act == 1))
    assert act[k_up] == 1
    k_down = k_up + int(np.argmax(np.diff(scale[k_up:]) > 0)) + 1
    assert k_down > k_up + 1 and scale[k_down] > scale[k_down - 1]
    return v[k_up], v[k_down], cfg


@pytest.mark.parametrize("plant_scale", [0.77, 1.0, 1.27])
def test_handover_happens_at_the_configured_speed(plant_scale):
    """Up and down happen at bemf_v_on_mps / bemf_v_off_mps of true speed within
    0.015 m/s, whatever psi_f (a motor with a 23 % weaker or 27 % stronger magnet,
    configured with it; with the former volt levels these handed over at 0.325 and
    0.197 m/s). Measured: up at 0.240-0.243 m/s, down at 0.176-0.178 m/s: the up condition
    holds 5 ms (+2.5 mm/s at 0.5 m/s^2), and the speed estimate on injection first crosses
    a threshold on a peak of its noise (0.005 m/s RMS against the truth on this ramp, peaks
    of 0.02 m/s), up to 0.01 m/s above the true speed; down goes on the estimate or the
    measured back-EMF, whichever is first below."""
    v_up, v_down, cfg = _handover_speeds(plant_scale)
    assert abs(v_up - cfg.bemf_v_on_mps) <= 0.015, v_up
    assert abs(v_down - cfg.bemf_v_off_mps) <= 0.015, v_down


def _load_step(v_mps: float, load_N: float, plant: dict | None = None,
               fw: dict | None = None, seed: int = 1):
    from sim_fallback import run_scenario

    return run_scenario(load_motor("iron_core_linear"), speed_ref=v_mps, speed_unit="mps",
                        load=[(0.0, 0.0), (0.5, load_N)], load_unit="N", t_end=1.0, seed=seed,
                        x0_m="random", plant=plant, fw=fw)


def test_load_step_through_the_handover_band_on_unseen_motors():
    """20 % of the rated thrust at 0.3 m/s brakes a 5-8 kg mover to about standstill in
    15-20 ms, through the handover band (docs/bemf.md, "Under a load step"): on the
    randomized motors 0-8 (R, L, psi_f, mass x 0.75-1.3, configured with their true
    values) every run tracks, within 0.02 rad RMS, max 0.054-0.074 rad (target 0.08). Before
    the handover went down on the measured back-EMF, 2 of 9 stopped on EST_BEMF_MISMATCH
    and the others reached 0.077-0.63 rad. The runs are chaotic: at most one over 0.08."""
    from sim_fallback import randomized_plant

    mot = load_motor("iron_core_linear")
    maxima = []
    for s in range(9):
        pl = randomized_plant(s)
        fw = {"R_ohm": pl["R_ohm"], "L_d_H": pl["L_d0_H"], "L_q_H": pl["L_q_H"],
              "psi_f_Wb": pl["psi_f_Wb"], "mass_kg": pl["mass_kg"]}
        load = 0.2 * 10.0 * 1.5 * math.pi / mot.tau_m * pl["psi_f_Wb"]  # i_rated 10 A
        r = _load_step(0.3, load, pl, fw)
        assert r.valid, (s, r.info.get("invalid_reason"))
        assert r.metrics["position_error_rms_rad"] <= 0.02, s
        maxima.append(r.metrics["position_error_max_rad"])
    assert max(maxima) <= 0.1 and sum(m > 0.08 for m in maxima) <= 1, maxima


@pytest.mark.parametrize("v_mps", [0.3, 1.0])
def test_peak_load_step_on_the_back_emf_does_not_oscillate(v_mps):
    """20 % of the *peak* thrust (240 N) on iron_core_linear: with the residual's
    cross-coupling on the speed estimate, the PLL's angle error fed back on itself
    (gain k_p L_q i_q / (w psi_f) > 1 under this load): a ~40 ms oscillation of 0.67-0.72 rad
    at 1.0 m/s, EST_BEMF_MISMATCH at 0.3 m/s. On the frame's own speed: 0.094-0.096 rad at
    1.0 m/s, 0.125-0.152 rad at 0.3 m/s (seeds 1-3; beyond the issue's target load)."""
    for seed in (1, 2, 3):
        r = _load_step(v_mps, 240.0, seed=seed)
        assert r.valid, (seed, r.info.get("invalid_reason"))
        assert r.metrics["position_error_max_rad"] <= 0.2, seed
