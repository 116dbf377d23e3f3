"""``bench identify --clamped``: step 7, the cross-saturation map, over the wire (CANopen +
serial telemetry, the hardware code path) on a held mover, judged against the simulated
plant's closed forms (never read by the procedure); a mover that is not held stops the
step with one line and exit 1, keeping steps 1-6; ``--clamped`` is refused where the
mover cannot be held."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import sim_fallback
from bench._identify import identify_drive
from bench._session import connect
from bench.cli import main
from identification import XSAT_MAX_SPEED_MPS, Identified, MoverMoved, Probe
from identification._procedure import _HeldGuard
from sim_fallback import cross_saturation_truth, hold_mover, load_motor

#: the map against the HF angle error at the true angle (the closed form with the
#: identified L_d, L_q the step ran with); measured 0.003-0.009 rad over the wire
MAP_TOL_RAD = 0.015
#: the measured axis turn against 1/2 atan2(-2 L_dq, L_qq - L_dd) (test_compensation's)
AXIS_TOL_RAD = 0.025
MAP = ["xsat_di_A", *[f"xsat_off{k}_rad" for k in range(1, 7)]]


def _map_errors(motor, values: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    levels = values["xsat_di_A"] * np.arange(1, 7)
    delta, eps = cross_saturation_truth(motor, levels, L_d_cfg=values["L_d_H"],
                                        L_q_cfg=values["L_q_H"])
    off = np.array([values[f"xsat_off{k}_rad"] for k in range(1, 7)])
    axis = np.array([values[f"xsat_axis{k}_rad"] for k in range(1, 7)])
    return off - eps, axis - delta


def test_clamped_step_measures_the_map_over_the_wire_and_applies_it(tmp_path: Path) -> None:
    conn = connect(sim=True, motor="realistic_linear", seed=1)
    held = []

    def clamp() -> bool:  # the fixture: the simulated plant's lock
        hold_mover(conn.sim)
        held.append(conn.sim.truth_state()["x_m"])
        return True
    try:
        out = identify_drive(conn, runs_root=str(tmp_path), clamped=True, hold=clamp,
                             apply=True)
        after = {k: v["value"] for k, v in conn.drive.backup().items()}
        x_end = conn.sim.truth_state()["x_m"]
        v = out.result.values
        # the axis turn where the mover is held: half the HF axis' difference between
        # +I and -I from the plant's magnetics at that position (the secondary saliency
        # and the end effect shift it with position; the map's closed form is at x = 0)
        levels = v["xsat_di_A"] * np.arange(1, 7) if "xsat_di_A" in v else np.zeros(0)

        def axis(i: float) -> float:
            L = conn.sim.sim.magnetics(0.0, i, x_end)["L_dq_H"]
            return 0.5 * float(np.arctan2(-2.0 * L[1], L[2] - L[0]))

        delta_held = np.array([0.5 * (axis(i) - axis(-i)) for i in levels])
    finally:
        conn.close()
    assert out.error is None, out.error
    assert x_end == held[0]  # the mover did not move while held
    assert v["xsat_di_A"] == pytest.approx(2.0)  # 0.6 i_max / 6
    d_off, _ = _map_errors(load_motor("realistic_linear"), v)
    d_axis = np.array([v[f"xsat_axis{k}_rad"] for k in range(1, 7)]) - delta_held
    assert np.all(np.abs(d_off) < MAP_TOL_RAD), d_off
    assert np.all(np.abs(d_axis) < AXIS_TOL_RAD), d_axis
    # the drive got it (--apply), object 0x2057
    for k in MAP:
        assert after[k] == pytest.approx(v[k], abs=1e-6), k
    # the motor file carries it in [controller] and loads
    m = load_motor(out.run_dir / "motor.toml")
    cfg = sim_fallback.fw_config(m)
    for k in MAP:
        assert getattr(cfg, k) == pytest.approx(v[k], abs=1e-5), k
    doc = json.loads((out.run_dir / "drive_config.json").read_text())
    assert doc["parameters"]["xsat_off6_rad"]["value"] == pytest.approx(v["xsat_off6_rad"])
    s = json.loads((out.run_dir / "summary.json").read_text())
    rows = {r["quantity"]: r for r in s["values"]}
    assert "truth" in rows["xsat_off3_rad"] and s["passed"] is True


def test_a_mover_that_is_not_held_stops_the_step_with_one_line_and_exit_1(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The step forced on a free mover (the fixture's lock left out): the safety check
    stops it, the drive is disabled, steps 1-6 are written, the map is not."""
    monkeypatch.setattr(sim_fallback, "hold_mover", lambda drive, held=True: None)
    rc = main(["identify", "--sim", "--motor", "realistic_linear", "--seed", "1", "--clamped",
               "--runs", str(tmp_path)])
    out = capsys.readouterr()
    assert rc == 1, out.err
    err = [ln for ln in out.err.splitlines() if ln.startswith("bench: identify: the mover")]
    assert len(err) == 1, out.err
    assert "the mover moved during step 7" in err[0] and "not held" in err[0]
    assert "drive disabled" in err[0]
    (run,) = [d for d in tmp_path.iterdir() if d.name.endswith("_identify")]
    s = json.loads((run / "summary.json").read_text())
    assert s["passed"] is False and "mover moved" in s["error"]
    got = {r["quantity"] for r in s["values"]}
    assert {"R_ohm", "L_d_H", "L_q_H", "psi_f_Wb", "mass_kg"} <= got  # nothing lost
    assert not any(k.startswith("xsat_") for k in got)
    text = (run / "motor.toml").read_text()
    assert "cross-saturation map (xsat_*) not measured" in text
    assert "\nxsat_" not in text  # not even the configured motor file's map
    load_motor(run / "motor.toml")


def test_without_clamped_the_motor_file_says_the_map_was_not_measured() -> None:
    res = Identified(values={"R_ohm": 1.0, "L_d_H": 1e-3, "L_q_H": 2e-3, "psi_f_Wb": 0.1,
                             "dL_sat_H": 0.0, "I_sat_A": 1.0, "mass_kg": 2.0,
                             "b_visc_Ns_per_m": 1.0, "F_coulomb_N": 1.0},
                     sigma={k: 0.0 for k in ("R_ohm", "L_d_H", "L_q_H", "psi_f_Wb",
                                             "mass_kg")})
    text = res.motor_file("x", 0.016, 1, "test", {"speed_bw_radps": 80.0, "xsat_di_A": 2.0,
                                                   "xsat_off1_rad": 0.03})
    assert "not measured" in text and "bench identify --clamped" in text
    assert "xsat_di_A =" not in text and "speed_bw_radps = 80.0" in text


@pytest.mark.parametrize("flag", ["--sim-server", "--emu"])
def test_clamped_is_refused_where_the_mover_cannot_be_held(
        flag: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["identify", flag, "--clamped", "--runs", str(tmp_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and "--clamped" in err[0] and "cannot be held" in err[0], err
    assert not any(tmp_path.iterdir())


def test_clamped_on_a_drive_needs_an_operator_at_a_terminal(
        monkeypatch: pytest.MonkeyPatch) -> None:
    from bench import cli

    monkeypatch.setattr("sys.stdin", SimpleNamespace(isatty=lambda: False))
    with pytest.raises(cli.UserError, match="operator at the terminal"):
        cli._clamp_fixture(SimpleNamespace(), SimpleNamespace(sim=None))


class _Free(Probe):
    """A probe whose mover runs away at 0.5 m/s (the speed estimate only, no drift yet)."""

    def __init__(self) -> None:
        self.iq = []

    def set_iq(self, amps: float) -> None:
        self.iq.append(amps)

    def run(self, seconds: float) -> dict[str, np.ndarray]:
        return {"pos_hat_m": np.zeros(1), "speed_hat_mps": np.array([0.0, 0.5])}


def test_the_guard_trips_on_the_speed_estimate_and_zeroes_the_thrust() -> None:
    p = _Free()
    g = _HeldGuard(p, k_e=196.0)
    with pytest.raises(MoverMoved, match=r"speed estimate \+0\.500 m/s") as e:
        g.run(0.001)
    assert "\n" not in str(e.value)
    assert p.iq == [0.0]
    assert XSAT_MAX_SPEED_MPS < 0.5
