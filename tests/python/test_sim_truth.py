"""Truth separation: the firmware's outputs depend on the sampled ADC data only."""

import ctypes as C
import re
from pathlib import Path

import numpy as np

from sim_fallback import SIM_REF_SPEED, Firmware, Sim, _lib

ROOT = Path(__file__).resolve().parents[2]


def test_replay_of_adc_inputs_reproduces_duties_exactly():
    """Closed loop, then the same firmware fed only the recorded ADC-derived inputs
    (no plant, no truth at all; converted with the zeros the drive measured at boot)
    produces bit-identical duties: nothing else reaches it."""
    w_ref = 2 * np.pi * 4 * 100 / 60
    with Sim("paper_salient", seed=7, x0_m=0.0071) as sim:
        sim.set_schedule(SIM_REF_SPEED, w_ref)
        sim.enable("speed")
        rec = sim.advance(7200, channels=["i_abc_meas_A", "u_dc_meas_V", "duty_abc",
                                          "theta_hat_rad", "theta_e_rad"])
        cfg = sim.cfg
        # the samples as the drive converted them (its zeros measured at boot)
        i_abc, u_dc = sim.drive_inputs(rec["i_abc_meas_A"], rec["u_dc_meas_V"])
    # it really ran closed loop (the estimate follows the hidden truth)
    assert np.any(~np.isnan(rec["duty_abc"][:, 0]))
    fw = Firmware(cfg)
    fw.enable("speed")
    fw.set_speed_ref_radps_e(w_ref)
    duties = np.empty_like(rec["duty_abc"])
    theta_hat = np.empty(len(duties))
    for k in range(len(duties)):
        d, on = fw.step(i_abc[k], u_dc[k])
        duties[k] = d if on else np.nan
        theta_hat[k] = fw.snapshot()["theta_hat_rad"]
    np.testing.assert_array_equal(duties, rec["duty_abc"])
    np.testing.assert_array_equal(theta_hat, rec["theta_hat_rad"])


def _run_shifted(shift_periods: int, leak: bool = False) -> dict:
    """Closed loop (start-up, 100 r/min, load step) with the mover started
    ``shift_periods`` electrical periods (2 tau each) further along. The
    electromagnetic behaviour is identical, so the sampled currents are too;
    only the truth (x_m) differs. ``leak`` plugs in a controller that reads the
    plant's true position: the comparison below must catch it."""
    tau = 0.024
    x0 = 0.0071 + shift_periods * 2.0 * tau
    with Sim("paper_salient", seed=5, x0_m=x0, plant={"cog_amp_N": 0.0}) as sim:
        sim.set_schedule(SIM_REF_SPEED, 2 * np.pi * 4 * 100 / 60)
        sim.set_schedule(2, [(0.0, 0.0), (0.3, 40.0)])
        sim.enable("speed")
        if leak:
            fw_step = _lib.STEP_FN(C.cast(sim._L.sim_fw_step, C.c_void_p).value)
            ctx = C.c_void_p(sim.firmware.handle)

            def leaky(_ctx, inp, out):
                fw_step(ctx, inp, out)
                x = sim.state()["x_m"]  # truth: what a firmware must never read
                out.contents.duty_abc[0] += 1e-4 * x

            cb = _lib.STEP_FN(leaky)
            port = _lib.SimController()
            port.ctx = ctx.value
            port.step = C.cast(cb, C.c_void_p)
            port.snapshot = C.cast(sim._L.sim_fw_snapshot, C.c_void_p)
            sim.set_controller_port(port, keep=cb)
        rec = sim.advance(12000, channels=["i_abc_meas_A", "duty_abc", "theta_hat_rad",
                                           "omega_hat_radps", "x_m", "start_phase"])
        rec["pos_hat_m"] = np.array([sim.snapshot()["pos_hat_m"]])
    return rec


def test_different_hidden_truth_same_inputs_same_outputs():
    """Two plants whose truth differs (the mover two pole pitches apart, moving,
    through start-up and a load step) but whose samples are identical give
    bit-identical firmware outputs, including the estimated position: nothing
    but the samples reaches the firmware."""
    a, b = _run_shifted(0), _run_shifted(1)
    assert np.all(a["start_phase"][-100:] == 3)  # closed loop reached
    assert np.ptp(a["x_m"]) > 0.05  # the mover really moved
    assert np.allclose(b["x_m"] - a["x_m"], 2 * 0.024, atol=1e-9)  # the truth differs
    assert np.array_equal(a["i_abc_meas_A"], b["i_abc_meas_A"])
    for k in ("duty_abc", "theta_hat_rad", "omega_hat_radps", "pos_hat_m"):
        assert np.array_equal(a[k], b[k], equal_nan=True), k


def test_truth_comparison_catches_a_leak():
    """The comparison above can fail: the same pair of runs with a controller
    that adds a trace of the true position to its duty differs."""
    a, b = _run_shifted(0, leak=True), _run_shifted(1, leak=True)
    assert not np.array_equal(a["duty_abc"], b["duty_abc"], equal_nan=True)


def test_firmware_sources_cannot_see_the_simulator():
    """Structural: no firmware source or header includes or names simulator code."""
    pat = re.compile(r"pmlsm_sim|sim_internal|sim_t\b|sim_plant")
    for p in list((ROOT / "firmware_c" / "src").glob("*.c")) + list(
            (ROOT / "firmware_c" / "include").rglob("*.h")):
        assert not pat.search(p.read_text()), p


def test_adc_counts_mode_runs_closed_loop():
    with Sim("paper_salient", seed=1) as sim:
        sim._L.sim_set_use_adc_counts(sim._h, 1)
        sim.set_schedule(SIM_REF_SPEED, 2 * np.pi * 4 * 100 / 60)
        sim.enable("speed")
        r = sim.advance(12000, channels=["fault_code", "start_phase"])
    assert not np.any(r["fault_code"]) and r["start_phase"][-1] == 3
