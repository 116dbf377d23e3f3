"""Fault-injection matrix (issue: the drive must know when it does not know).

Every case runs the real firmware in the simulated drive with one thing wrong
and is judged from the simulator's truth (which the firmware never sees): no
more than 0.5 rad el. of true error for more than 20 ms in closed loop without
a fault, and either tracking within the case's bounds or a named fault with the
PWM off at once (hard faults) or within the braking bound.
"""

import numpy as np
import pytest

from sim_fallback._faults import (BLIND_ERR_RAD, BLIND_TIME_S, CASES, FaultCase, judge,
                                  run_case)

SEEDS = (0, 1)


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_case_holds_the_invariant(case: FaultCase) -> None:
    for seed in SEEDS:
        r = run_case(case, seed)
        assert r["verdict"], f"{case.name} seed {seed}: {r['why']} ({r})"
        assert r["blind_max_s"] <= BLIND_TIME_S


def test_expected_faults_are_the_named_ones() -> None:
    """The cases built to show one witness end in that witness's fault."""
    by_name = {c.name: c for c in CASES}
    for name, code in [("saliency_absent", 0xFF07), ("enable_moving_0.94mps", 0xFF08),
                       ("sensor_offset_a_1.2A_learnt", 0xFF06), ("dc_sag_120V", 0x3220),
                       ("position_limit", 0x8612)]:
        r = run_case(by_name[name], 0)
        assert r["fault"] == code, (name, r)


def test_loss_of_lock_detected_within_budget() -> None:
    """Cases where the estimate is really lost (true error > 0.5 rad) are
    caught within 20 ms of the first blind sample."""
    by_name = {c.name: c for c in CASES}
    for name in ("iron_core_paper_gains", "open_phase_a", "adc_stuck_b"):
        r = run_case(by_name[name], 0)
        assert r["fault"] is not None, (name, r)
        if r["t_first_blind_s"] is not None:
            assert r["t_fault_s"] - r["t_first_blind_s"] <= BLIND_TIME_S + 1e-9, (name, r)


def test_judge_can_fail() -> None:
    """The verdict is not a rubber stamp: blind driving, a late switch-off, a
    wrong fault and poor tracking are each refused."""
    c = FaultCase("x", "synthetic", expect="either", rms_max_rad=0.05, max_max_rad=0.2)
    ok = {"blind_max_s": 0.0, "fault": None, "fault_name": None, "pwm_off_after_s": None,
          "rms_rad": 0.01, "max_rad": 0.05}
    assert judge(c, ok, 0.08)[0]
    assert not judge(c, {**ok, "blind_max_s": 0.03}, 0.08)[0]
    assert not judge(c, {**ok, "rms_rad": 0.2}, 0.08)[0]
    late = {**ok, "fault": 0xFF09, "fault_name": "EST_HF_ANGLE", "pwm_off_after_s": 0.01}
    assert not judge(c, late, 0.08)[0]
    wrong = FaultCase("y", "synthetic", expect="fault", fault=0xFF07)
    assert not judge(wrong, {**late, "pwm_off_after_s": 0.0}, 0.08)[0]
    assert BLIND_ERR_RAD == 0.5


def test_nominal_accuracy_with_the_monitor() -> None:
    """The monitor costs no accuracy on the nominal case (steady RMS well
    inside the noise floor reported in docs/reproduction.md)."""
    r = run_case(CASES[0], 0)
    assert r["fault"] is None and r["rms_rad"] < 0.02 and r["max_rad"] < 0.1, r
    assert np.isfinite(r["rms_rad"])
