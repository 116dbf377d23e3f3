"""The motor is not the one configured (``--sim-plant``): the drive must stop safely and
the bench must say so at once; and ``bench identify`` finds the motor actually there."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bench._identify import identify_drive
from bench._logging import read_signals
from bench._session import connect
from bench.cli import main
from sim_fallback import randomized_plant, truth_of
from sim_fallback._motors import load_motor, machine_params
from sim_fallback.faults import BLIND_ERR_RAD, BLIND_TIME_S

ROOT = Path(__file__).resolve().parents[2]


def test_wrong_motor_faults_and_the_run_stops_within_one_wait_slice(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Configured for paper_salient, driving iron_core_linear: the drive's integrity
    monitor faults; the bench stops the sequence at the EMCY (exit 3, the fault named),
    instead of running the rest of it on a coasting mover and failing expectations."""
    rc = main(["run", str(ROOT / "sequences" / "paper_load_step.yaml"), "--sim",
               "--sim-plant", "iron_core_linear", "--runs", str(tmp_path), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 3, err
    line = [x for x in err.splitlines() if "run aborted" in x]
    assert len(line) == 1 and "DriveFault: drive fault 0xFF" in line[0], err
    assert "Traceback" not in err
    (run,) = [d for d in tmp_path.iterdir() if d.is_dir()]
    s = json.loads((run / "summary.json").read_text())
    assert s["passed"] is False and "drive fault 0xFF" in s["error"]
    # when: the fault as the drive reported it (TPDO 0x603F) vs the bench's abort event
    meta = json.loads((run / "meta.json").read_text())
    t0 = meta["time_origin_s"]
    sig = read_signals(run)
    t, code, _ = sig["pdo.error_code"]
    k = np.nonzero(code)[0]
    assert k.size, "the drive never reported the fault"
    t_fault = float(t[k[0]] - t0)
    ev = [json.loads(x) for x in (run / "events.jsonl").read_text().splitlines()]
    t_abort = next(e["t_s"] for e in ev if e["kind"] == "abort")
    # within one wait slice of the simulated clock (50 ms; 10 ms on hardware) + 2 ms
    assert 0.0 <= t_abort - t_fault <= 0.052, (t_fault, t_abort)
    # the project's invariant (the fault-injection matrix's): never more than
    # BLIND_TIME_S with the estimate off by more than BLIND_ERR_RAD before the fault
    # (measured: 6 ms beyond 0.5 rad; below 0.1 rad 12 ms before the fault)
    tt = sig["sim.theta_e_rad"][0] - t0
    err_ang = np.abs(np.angle(np.exp(1j * (sig["sim.theta_e_rad"][1]
                                           - sig["sim.theta_hat_rad"][1]))))
    blind = np.nonzero((err_ang > BLIND_ERR_RAD) & (tt > 0.02))[0]
    assert blind.size and t_fault - tt[blind[0]] <= BLIND_TIME_S, (tt[blind[0]], t_fault)


@pytest.mark.parametrize("argv, text", [
    (["--sim", "--sim-plant", "no_such_motor"], "--sim-plant no_such_motor"),
    (["--sim-plant", "iron_core_linear", "--interface", "virtual", "--channel", "x",
      "--require-hardware"], "--sim-plant iron_core_linear: only with --sim")])
def test_sim_plant_input_errors_are_one_line(argv: list[str], text: str, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["info", *argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2, err
    assert len(err) == 1 and text in err[0], err


def test_identify_finds_the_motor_actually_there(tmp_path: Path) -> None:
    """Configured from the iron_core_linear file, driving randomized variants (R, L,
    psi_f, mass scaled by 0.75-1.3): identification over the wire measures the variant,
    or stops on a named drive fault (never a wrong answer). Measured on seeds 0-7: 7
    identified (R, L, psi_f within 0.7 %, mass -1.8..+8.5 %, Coulomb -6.9..+0.2 %), seed 0
    stopped on EST_BEMF_MISMATCH in the motion runs."""
    mot = load_motor("iron_core_linear")
    done = 0
    for seed in (0, 1, 2, 3):
        plant = randomized_plant(seed)
        conn = connect(sim=True, motor="iron_core_linear", seed=2, sim_plant=plant,
                       say=lambda s: None)
        try:
            out = identify_drive(conn, runs_root=str(tmp_path))
        finally:
            conn.close()
        if out.result is None:
            assert out.error is not None and "drive fault 0xFF" in out.error, out.error
            continue
        done += 1
        truth = truth_of(mot, plant)
        assert out.truth == truth
        for k in ("R_ohm", "L_d_H", "L_q_H", "psi_f_Wb"):
            assert abs(out.result.values[k] / truth[k] - 1) <= 0.03, (seed, k)
        for k in ("mass_kg", "F_coulomb_N"):
            assert abs(out.result.values[k] / truth[k] - 1) <= 0.10, (seed, k)
    assert done >= 3, done


def test_machine_params_are_the_machine_only() -> None:
    m = machine_params(load_motor("iron_core_linear"))
    assert {"R_ohm", "L_q_H", "psi_f_Wb", "tau_m", "mass_kg"} <= set(m)
    assert not {"f_pwm_Hz", "adc_bits", "u_dc_V", "seed", "n_sub"} & set(m)
