"""The start-up motion check (MOVING_AT_ENABLE, docs/integrity.md): a mover at rest is
never refused, whatever its position and the noise, and a mover that really moves faster
than ``start_speed_max_mps`` is. The drive decides from what it measures (the statistic is
its own, snapshot ``mon_e_bemf_V`` while aligning); the simulator's truth judges.

Until 2026-11 the alignment fed the PLL's convergence speed forward as a back-EMF
(w psi_f on q^, up to 43 V at 212 rad/s el.): the zero-current loop pushed a mover at rest
to 70-136 mm/s and the check then refused it (iron_core_linear seed 7, randomized motors 1
and 3 at seed 2; 9 of 128 and 48 of 128 start positions x seeds)."""

from __future__ import annotations

import numpy as np
import pytest

from sim_fallback import randomized_plant
from sim_fallback._motors import load_motor
from sim_fallback.start_check import FRICTIONLESS, MOVING_AT_ENABLE, motion_check

TAU = load_motor("iron_core_linear").tau_m


def _random_x0(seed: int, tau_m: float) -> float:
    """run_scenario's x0_m="random" for this seed (where the known trips started)."""
    return float(np.random.default_rng([seed, 0x5EED]).uniform(0.0, 2.0 * tau_m))


def _own(seed: int) -> tuple[dict, dict]:
    """A randomized iron-core motor, the drive configured with its own parameters."""
    p = randomized_plant(seed)
    return p, {"R_ohm": p["R_ohm"], "L_d_H": p["L_d0_H"], "L_q_H": p["L_q_H"],
               "psi_f_Wb": p["psi_f_Wb"], "mass_kg": p["mass_kg"], "gains_auto": 1}


def _standstill(motor: str, plant: dict | None, fw: dict | None,
                starts: list[tuple[int, float]]) -> None:
    worst = 0.0
    for seed, x0 in starts:
        r = motion_check(motor, seed, x0, plant=plant, fw=fw)
        where = f"seed {seed}, x0 {x0 * 1e3:.2f} mm"
        # truth: the drive did not push the mover (before: up to 136 mm/s)
        assert r["v_max"] < 0.005, f"{where}: the alignment moved the mover to {r['v_max']} m/s"
        assert r["fault"] != MOVING_AT_ENABLE, f"{where}: refused at rest (ratio {r['ratio']:.2f})"
        worst = max(worst, r["ratio"])
    # measured at most 0.11 of the threshold over 16 positions x 8 seeds on every motor
    # (tools/start_motion_check.py): the margin to the limit is the check's, not luck
    assert worst < 0.25, worst


def test_standstill_shipped_motor_never_refused():
    """iron_core_linear: 16 positions x seeds 1-8 and the known trip (seed 7)."""
    starts = [(s, 2.0 * TAU * k / 16) for s in range(1, 9) for k in range(16)]
    starts.append((7, _random_x0(7, TAU)))
    _standstill("iron_core_linear", None, None, starts)


def test_standstill_paper_motor_never_refused():
    tau = load_motor("paper_salient").tau_m
    starts = [(s, 2.0 * tau * k / 8) for s in (1, 2, 7) for k in range(8)]
    _standstill("paper_salient", None, None, starts)


@pytest.mark.parametrize("motor_seed", [1, 3])
def test_standstill_randomized_motors_never_refused(motor_seed):
    """The motors of docs/identify.md's footnote (seed 2 faulted at every speed), over
    8 positions x 4 seeds and seed 2's own start position."""
    plant, fw = _own(motor_seed)
    starts = [(s, 2.0 * TAU * k / 8) for s in (1, 2, 3, 7) for k in range(8)]
    starts.append((2, _random_x0(2, TAU)))
    _standstill("iron_core_linear", plant, fw, starts)


@pytest.mark.parametrize(("v0", "plant"), [(0.075, FRICTIONLESS), (-0.075, FRICTIONLESS),
                                           (0.12, None)])
def test_slow_real_motion_is_refused(v0, plant):
    """A mover faster than start_speed_max_mps (0.05 m/s) but too slow for a flying start
    (bemf_v_off_mps 0.175 m/s) is refused: coasting without friction at 1.5x the limit,
    and the fault matrix's 0.12 m/s with friction (slowed to 0.044-0.080 m/s at the
    check). Truth: the mover really was over the limit when the drive judged it."""
    for seed in (1, 2):
        for k in range(8):
            x0 = 2.0 * TAU * k / 8
            r = motion_check("iron_core_linear", seed, x0, v0_mps=v0, plant=plant)
            where = f"v0 {v0} m/s, seed {seed}, x0 {x0 * 1e3:.1f} mm"
            assert r["fault"] == MOVING_AT_ENABLE, f"{where}: not refused ({r})"
            assert not r["flying"], where
            assert r["ratio"] > 1.0, where
            if plant is FRICTIONLESS:
                assert r["v_check"] > 0.055, f"{where}: truth {r['v_check']} m/s"


def test_alignment_saddle_is_left_by_turning_the_estimate():
    """The alignment's unstable equilibrium: randomized motor 6 of the identification,
    started 0.5 pole pitch (pi/2 el.) from the estimate's initial 0 with the
    identification's configuration. The PLL's error signal vanishes there too, the
    80 ms alignment ends off the axis, and the standstill saliency check measures the
    angle error from the full HF admittance. It used to be the EST_HF_ANGLE fault at
    the check (the motor could not be identified); the drive now turns the estimate by
    the measured error, aligns and checks again (FW_SAL_RETRIES), and reaches closed
    loop on the right axis. (With the current zeros unknown to the drive, as before the
    boot's calibration, this start needed the second alignment, 0.178 s to closed loop
    against 0.095; with them calibrated, as without the offsets before, the first
    alignment leaves the saddle far enough: 0.095 s, entering the closed loop 0.38-0.45
    rad off and pulling in.)"""
    from identification import IDENT_FW
    from sim_fallback import randomized_plant
    from sim_fallback._motors import load_motor
    from sim_fallback._sim import SIM_REF_FORCE, Sim
    from sim_fallback.metrics import wrap_pi

    mot = load_motor("iron_core_linear")
    t_run = {}
    for x0 in (0.5, 0.13):
        with Sim(mot, extractor="pseudo", seed=1, plant=randomized_plant(6), fw=IDENT_FW,
                 x0_m=x0 * mot.tau_m) as sim:
            sim.set_schedule(SIM_REF_FORCE, 0.0)
            sim.enable("force")
            d = sim.advance(int(0.4 / sim.dt_s), 24, ["t_s", "start_phase", "fault_code",
                                                       "theta_e_rad", "theta_hat_rad"])
        assert not d["fault_code"].any(), hex(int(d["fault_code"].max()))
        run = np.nonzero(d["start_phase"] == 3)[0]
        assert run.size, x0
        t_run[x0] = float(d["t_s"][run[0]])
        err = np.abs(wrap_pi(d["theta_e_rad"] - d["theta_hat_rad"]))[run[0]:]
        # the right axis and polarity (a wrong one is pi/2 or pi off): the closed loop
        # starts within 0.5 rad (the saddle start measured 0.38 with the current zeros
        # calibrated at boot, 0.2 before) and has pulled in 0.1 s later (the
        # identification's slow observer: 0.075 rad at 50 ms)
        assert err.max() < 0.5, (x0, err.max())
        assert err[100:].max() < 0.05, (x0, err[100:].max())  # 1 ms per record
    # both reach the closed loop within the alignment, the check and (at most) one retry
    assert t_run[0.13] < 0.13 and t_run[0.5] < 0.2, t_run
