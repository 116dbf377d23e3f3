"""Closed loop: refusal of the non-salient machine, chunking, determinism, the
paper's scenarios for all extractors, and the accuracy targets of issue 3 item 7.

The accuracy tests use the issue's tolerances (not tuned to a seed); their
measured values are printed (pytest -s) for the reports.
"""

import math

import numpy as np
import pytest

from sim_fallback import (
    METRIC_NAMES,
    PAPER_SCENARIOS,
    SIM_REF_SPEED,
    Sim,
    fw_config,
    load_motor,
    paper_scenario,
    run_scenario,
    wrap_pi,
)

EXTRACTORS = ("pseudo", "sogi", "sogi_adaptive")


def test_paper_table1_refuses_no_fake_tracking():
    r = paper_scenario("load_step", motor="paper_table1")
    assert r.fault_code == 0xFF03  # FW_FAULT_SALIENCY_TOO_LOW
    assert not r.valid and all(np.isnan(r.metrics[k]) for k in METRIC_NAMES)
    assert np.all(np.isnan(r.duty_abc))          # PWM never enabled
    assert np.all(r.i_d_A == 0) and np.all(r.i_q_A == 0)
    assert np.all(r.start_phase != 3)            # never claimed closed loop


def test_metric_names_exact():
    r = run_scenario(t_end=0.3)
    assert tuple(r.metrics) == METRIC_NAMES
    assert r.valid


def test_chunked_advance_equals_one_call():
    def make():
        s = Sim("paper_salient", seed=5)
        s.set_schedule(SIM_REF_SPEED, 40.0)
        s.enable()
        return s

    a = make().advance(4800, decimation=3)
    s = make()
    parts = [s.advance(n, decimation=3) for n in (1000, 7, 1393, 2400)]
    for k, v in a.items():
        np.testing.assert_array_equal(np.concatenate([p[k] for p in parts]), v, err_msg=k)


def test_seed_reproducible():
    a = run_scenario(t_end=0.2, seed=11)
    b = run_scenario(t_end=0.2, seed=11)
    c = run_scenario(t_end=0.2, seed=12)
    assert np.array_equal(a.theta_hat_rad, b.theta_hat_rad)
    assert not np.array_equal(a.theta_hat_rad, c.theta_hat_rad)


def test_force_mode_runs():
    r = run_scenario(force_ref=[(0.0, 0.0), (0.2, 100.0)], t_end=0.4)
    assert r.fault_code == 0 and r.info["mode"] == "force"
    assert r.v_mps[-1] > 0.0  # 100 N > 49 N static friction: it moves forward


@pytest.mark.parametrize("scenario", PAPER_SCENARIOS)
@pytest.mark.parametrize("extractor", EXTRACTORS)
def test_paper_scenarios_run(scenario, extractor):
    r = paper_scenario(scenario, extractor, seed=1)
    print(f"\n{scenario:15s} {extractor:14s} " +
          " ".join(f"{k}={v:.4g}" for k, v in r.metrics.items()))
    assert r.valid, r.info["invalid_reason"]
    # loose sanity bound (locked on the right angle); the targets are below
    assert r.metrics["position_error_rms_rad"] < 0.2


# ---- issue 3 item 7 accuracy targets --------------------------------------------

TARGET_SEEDS = (0, 1, 2, 3)


@pytest.fixture(scope="module")
def target_runs():
    """paper_salient, 12-bit ADC, default noise, 100 r/min from a random position."""
    return [run_scenario("paper_salient", "sogi_adaptive", speed_ref=100.0, t_end=1.0,
                         seed=seed, x0_m="random") for seed in TARGET_SEEDS]


def test_target_adaptive_sogi_position_accuracy(target_runs):
    """Issue 3 item 7: position error <= 0.01 rad el. RMS after 0.15 s.

    Judged on the RMS over four seeds (measured 0.0074-0.0089 per seed); a
    single seed may not exceed 0.012 rad.
    """
    rms = np.array([r.metrics["position_error_rms_rad"] for r in target_runs])
    print("\nposition_error_rms_rad per seed:", np.round(rms, 4))
    assert all(r.valid for r in target_runs)
    assert float(np.sqrt(np.mean(rms ** 2))) <= 0.01
    assert float(rms.max()) <= 0.012


def test_speed_error_achieved_bound(target_runs):
    """What the estimator achieves today at the default 1-count ADC noise:
    |estimated - true speed| <= 8 r/min after 0.15 s (measured 4.1-5.8, all of it
    while the mover accelerates from standstill; steady state stays within
    +-1 r/min, see test_steady_state_speed_band)."""
    sp = np.array([r.metrics["speed_filtered_estimate_error_max_rpm"] for r in target_runs])
    print("\nspeed_filtered_estimate_error_max_rpm per seed:", np.round(sp, 2))
    assert float(sp.max()) <= 8.0


@pytest.mark.xfail(strict=True, reason=(
    "issue 3 target +-1 r/min from 0.15 s is not met: until the observer has learnt the "
    "friction (about 0.3 s from start) the speed estimate lags the accelerating mover by "
    "4-6 r/min; see docs/reproduction.md"))
def test_target_speed_error_within_1rpm(target_runs):
    assert max(r.metrics["speed_filtered_estimate_error_max_rpm"] for r in target_runs) <= 1.0


def test_steady_state_speed_band(target_runs):
    """Once at speed (0.5-1.0 s): speed error RMS <= 0.8 r/min and max <= 2.5 r/min
    (the paper's band is "about +-1 r/min"), position error <= 0.01 rad RMS.
    The max over 0.5 s of a noisy estimate depends on the noise realisation:
    over 8 seeds and start-up timings shifted by +-3 ms (the standstill saliency
    check adds 2.7 ms) it measured 0.86-2.12 r/min, RMS 0.29-0.74."""
    for r in target_runs:
        m = r.t_s >= 0.5
        w_err = r.motor.radps_e_to_rpm(r.omega_f_radps[m] - r.omega_e_radps[m])
        e = wrap_pi(r.theta_e_rad[m] - r.theta_hat_rad[m])
        print(f"\nsteady: speed err max {np.abs(w_err).max():.2f} r/min, "
              f"rms {np.sqrt(np.mean(w_err ** 2)):.2f}, "
              f"pos err rms {np.sqrt(np.mean(e ** 2)):.4f} rad")
        assert np.sqrt(np.mean(w_err ** 2)) <= 0.8
        assert np.abs(w_err).max() <= 2.5
        assert np.sqrt(np.mean(e ** 2)) <= 0.01


def test_target_startup_16_random_positions_converge_not_pi_shifted():
    """From 16 random initial positions the estimate converges to the true angle
    (never theta + pi) within 0.2 s."""
    bad = []
    for seed in range(16):
        r = paper_scenario("startup", "sogi_adaptive", seed=seed, t_end=0.4)
        e = wrap_pi(r.theta_e_rad - r.theta_hat_rad)
        late = r.t_s >= 0.2
        pi_shift = np.mean(np.abs(e[late]) > np.pi / 2)
        ts = r.metrics["settling_time_s"]
        print(f"\nseed {seed:2d} x0 {r.info['x0_m'] * 1e3:6.2f} mm settle {ts:.3f} s "
              f"pi-shifted fraction {pi_shift:.3f}")
        if not r.valid or pi_shift > 0 or not ts <= 0.2:
            bad.append((seed, ts, pi_shift, r.info["invalid_reason"]))
    assert not bad, bad


def test_ramp_schedule_applied_in_c():
    r = run_scenario(speed_ref={"t_s": [0.0, 0.2, 0.4], "value": [0.0, 100.0, 100.0],
                                "ramp": True}, t_end=0.4, record_decimation=24)
    w100 = r.motor.rpm_to_radps_e(100.0)
    expect = np.interp(r.t_s, [0.0, 0.2, 0.4], [0.0, w100, w100])
    np.testing.assert_allclose(r.speed_ref_radps_e, expect, atol=1e-4 * w100)


def test_iron_core_linear_closed_loop():
    r = run_scenario("iron_core_linear", speed_ref=0.3, speed_unit="mps",
                     load=[(0.0, 0.0), (0.5, 30.0)], load_unit="N", t_end=1.2, seed=2)
    print("\niron_core_linear " + " ".join(f"{k}={v:.4g}" for k, v in r.metrics.items()))
    assert r.valid, r.info["invalid_reason"]
    assert r.metrics["position_error_rms_rad"] < 0.2
    assert abs(np.mean(r.v_mps[r.t_s > 1.0]) - 0.3) < 0.05


@pytest.mark.parametrize("v_mps", [0.1, 0.3, 1.0])
def test_iron_core_load_step_with_the_derived_observer(v_mps):
    """The drive derives its observer from mass and peak thrust (fw_config_derive): a
    60 N load step (5 % of K_F i_max) on the 6 kg iron-core mover keeps the issue's
    accuracy from 0.15 s on, in the injection region, at the handover speed and on the
    back-EMF observer. With the paper's observer it faulted at 0.3 m/s and reached
    0.075 / 0.35 rad at 1 m/s (docs/tuning.md). Measured: 0.012/0.04, 0.012/0.04,
    0.004/0.03 rad (RMS / max)."""
    r = run_scenario("iron_core_linear", speed_ref=v_mps, speed_unit="mps",
                     load=[(0.0, 0.0), (0.5, 60.0)], load_unit="N", t_end=1.0, seed=1,
                     x0_m="random")
    assert r.valid, r.info["invalid_reason"]
    assert r.metrics["position_error_rms_rad"] <= 0.02
    assert r.metrics["position_error_max_rad"] <= 0.08


@pytest.mark.parametrize("v_mps", [0.1, 0.3, 1.0, 2.0])
def test_iron_core_rated_load_step(v_mps):
    """The issue's accuracy target on iron_core_linear: a load step of 20 % of the rated
    thrust (K_F i_rated = 60 N/A x 10 A: 120 N) at 0.5 s, position error from 0.15 s on
    <= 0.02 rad RMS and <= 0.08 rad max, in the injection region, just above the
    back-EMF handover and on the back-EMF observer, and the speed back near the
    reference. With the file's former 20 rad/s speed loop the step pushed the mover
    through the handover band (0.028/0.34 rad at 0.3 m/s, and EST_BEMF_MISMATCH for
    another seed); at 80 rad/s, measured (seed 1 / 2): 0.015/0.062, 0.008/0.060,
    0.005/0.052, 0.005/0.051 rad."""
    mot = load_motor("iron_core_linear")
    cfg = fw_config(mot)
    K_F = 1.5 * math.pi / mot.tau_m * mot.plant["psi_f_Wb"]  # N/A, from the motor file
    F = 0.2 * float(cfg.i_rated_A) * K_F
    assert abs(F - 120.0) < 0.5
    r = run_scenario("iron_core_linear", speed_ref=v_mps, speed_unit="mps",
                     load=[(0.0, 0.0), (0.5, F)], load_unit="N", t_end=1.0, seed=1,
                     x0_m="random")
    assert r.valid, r.info["invalid_reason"]
    assert r.metrics["position_error_rms_rad"] <= 0.02
    assert r.metrics["position_error_max_rad"] <= 0.08
    assert abs(np.mean(r.v_mps[r.t_s > 0.9]) - v_mps) < 0.1 * v_mps + 0.02
