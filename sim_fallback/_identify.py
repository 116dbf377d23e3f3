"""The simulated drive's probe for the identification (``identification``): the firmware
core stepped directly on the simulated plant, and the simulator-side helpers of its tests
and tools (randomized motors, the truth in the identified names).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

import numpy as np

from identification import (
    IDENT_FW,
    IDENT_RESTORED,
    START_WINDOWS,
    Identified,
    Probe,
    ident_overrides,
    run_cross_saturation,
    run_identification,
    run_ripple,
    run_thrust_ripple,
)
from protocols.generated.od_names import StartPhase

from ._firmware import CW_DISABLE_VOLTAGE
from ._motors import Motor, fw_config
from ._sim import SIM_REF_FORCE, SIM_REF_SPEED, Sim


class SimProbe(Probe):
    """:class:`Probe` on the simulator, in-process (the firmware snapshot at 1 kHz); each
    standstill start is a fresh simulation at another position."""

    def __init__(self, motor: Motor, fw: dict[str, float], plant: dict[str, Any] | None,
                 seed: int) -> None:
        self.motor, self.fw, self.plant, self.seed = motor, fw, plant, seed
        self.sim: Sim | None = None

    def __enter__(self) -> SimProbe:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.sim is not None:
            self.sim.close()
            self.sim = None

    def _snaps(self, seconds: float) -> list[dict[str, Any]]:
        sim = self.sim
        assert sim is not None
        out = []
        for _ in range(max(1, int(round(seconds / 0.001)))):
            sim.advance(int(round(0.001 / sim.dt_s)), channels=["fault_code"])
            out.append(sim.snapshot())
        if out[-1]["fault_code"]:
            raise RuntimeError(f"drive fault 0x{out[-1]['fault_code']:04X} during identification")
        return out

    def standstill_start(self, k: int) -> tuple[float, float]:
        m = self.motor
        with Sim(m, extractor="pseudo", seed=self.seed * 100 + k, plant=self.plant, fw=self.fw,
                 x0_m=(0.13 + 0.37 * k) * m.tau_m) as sim:
            self.sim = sim
            try:
                s = self._start()
            finally:
                self.sim = None
        return s["L_small_meas_H"], s["L_large_meas_H"]

    def _start(self) -> dict[str, Any]:
        sim = self.sim
        assert sim is not None
        sim.set_schedule(SIM_REF_FORCE, 0.0)
        sim.enable("force")
        # about 0.1 s; twice that when the saliency check turned the estimate and
        # aligned again (FW_SAL_RETRIES)
        for _ in range(START_WINDOWS):
            self._snaps(0.15)
            s = sim.snapshot()
            if s["start_phase"] == StartPhase.RUN:
                return s
        raise RuntimeError(f"start-up did not reach closed loop in {0.15 * START_WINDOWS:.2f} s")

    def start(self) -> None:
        if self.sim is None:
            self.sim = Sim(self.motor, extractor="pseudo", seed=self.seed * 100 + 99,
                           plant=self.plant, fw=self.fw)
        self._start()

    def run(self, seconds: float) -> dict[str, np.ndarray]:
        snaps = self._snaps(seconds)
        pick = {"i_d_A": ("i_dq_A", 0), "i_q_A": ("i_dq_A", 1), "u_d_V": ("u_dq_V", 0),
                "u_q_V": ("u_dq_V", 1), "hf_amp_A": ("hf_amp_A", None),
                "pos_hat_m": ("pos_hat_m", None), "speed_hat_mps": ("speed_hat_mps", None)}
        return {k: np.array([q[key][j] if j is not None else q[key] for q in snaps])
                for k, (key, j) in pick.items()}

    def set_id(self, amps: float) -> None:
        assert self.sim is not None
        self.sim._L.fw_set_id_ref(self.sim.firmware.handle, float(amps))

    def set_iq(self, amps: float) -> None:
        assert self.sim is not None
        self.sim._L.fw_set_iq_ref(self.sim.firmware.handle, float(amps))

    def reconfigure(self, fields: dict[str, float]) -> None:
        import ctypes as C

        from . import _lib

        sim = self.sim
        assert sim is not None
        L, h = sim._L, sim.firmware.handle
        L.fw_controlword(h, CW_DISABLE_VOLTAGE)
        self._snaps(0.01)
        cfg = _lib.FwConfig.from_buffer_copy(bytes(sim.cfg))
        for k, v in fields.items():
            setattr(cfg, k, type(getattr(cfg, k))(v))  # int fields (gains_auto) as ints
        issue = _lib.FwConfigIssue()
        if L.fw_set_config(h, C.byref(cfg), C.byref(issue)) != 0:
            raise RuntimeError("the drive refused the identified electrical parameters")
        sim.set_schedule(SIM_REF_FORCE, 0.0)
        sim.enable("force")
        self._snaps(0.15)

    def follow_speed(self, t_s: np.ndarray, v_mps: np.ndarray) -> dict[str, np.ndarray]:
        sim = self.sim
        assert sim is not None
        sim._L.fw_set_mode(sim.firmware.handle, 0)
        t0 = sim.t_s
        sim.set_schedule(SIM_REF_SPEED, {"t_s": list(t0 + t_s), "value": list(v_mps),
                                         "ramp": True}, self.motor.mps_to_radps_e(1.0))
        return self.run(float(t_s[-1]))

    def ramp_speed(self, v_from: float, v_to: float, seconds: float) -> None:
        sim = self.sim
        assert sim is not None
        sim.set_schedule(SIM_REF_SPEED, {"t_s": [sim.t_s, sim.t_s + seconds],
                                         "value": [v_from, v_to], "ramp": True},
                         self.motor.mps_to_radps_e(1.0))


def identify(motor: Motor, seed: int = 0, travel_m: float = 0.3, n_starts: int = 4,
             plant: dict[str, Any] | None = None, guess: dict[str, float] | None = None
             ) -> Identified:
    """Identify a motor on the simulated drive, in-process (:class:`SimProbe`).

    ``guess`` holds the configuration the user starts from (fw_config_t fields,
    e.g. a datasheet's values); by default the motor file's own. ``plant``
    overrides what the simulated motor *is* (the truth to be found).
    """
    fw = dict(IDENT_FW)
    fw.update(guess or {})
    cfg0 = fw_config(motor, "pseudo", **fw)
    if motor.parameterization == "linear" and "spd_kp_A_per_radps" not in fw:
        # a conservative speed loop while the motor is unknown (IDENT_SPEED_BW)
        o = ident_overrides(cfg0)
        fw["spd_kp_A_per_radps"] = o["spd_kp_A_per_radps"]
        fw["spd_ki_A_per_rad"] = o["spd_ki_A_per_rad"]
        cfg0 = fw_config(motor, "pseudo", **fw)
    user = fw_config(motor, "pseudo", **(guess or {}))
    restore = {k: float(getattr(user, k)) for k in IDENT_RESTORED}
    with SimProbe(motor, fw, plant, seed) as probe:
        return run_identification(probe, cfg0, motor.tau_m, travel_m, n_starts, restore)


def identify_cross_saturation(motor: Motor, seed: int = 0, plant: dict[str, Any] | None = None,
                              fw: dict[str, float] | None = None, x0_m: float = 0.0,
                              passes: int = 3) -> Identified:
    """Step 7 of the identification (:func:`identification.run_cross_saturation`) on the
    simulated drive: the plant's mover locked (``locked`` = 1, the rig's clamp) at
    ``x0_m``; the drive runs the motor file's configuration (``fw`` over it) with its
    compensation map replaced by the one being measured."""
    pl = {**(plant or {}), "locked": 1}
    return _optional_step(motor, seed, pl, fw, x0_m, 98, lambda probe, cfg0:
                          run_cross_saturation(probe, cfg0, motor.tau_m, passes))


def _optional_step(motor: Motor, seed: int, plant: dict[str, Any] | None,
                   fw: dict[str, float] | None, x0_m: float, salt: int,
                   step: Callable[[SimProbe, Any], Identified]) -> Identified:
    """An optional step (7, 8, 9) on the simulated drive: the motor file's configuration
    (``fw`` over it), a started probe whose simulator starts at ``x0_m`` with the noise
    seed ``seed * 100 + salt`` (one per step), ``step(probe, cfg0)``."""
    fw = dict(fw or {})
    cfg0 = fw_config(motor, "sogi_adaptive", **fw)
    with SimProbe(motor, fw, plant, seed) as probe:
        probe.sim = Sim(motor, seed=seed * 100 + salt, plant=plant, fw=fw, x0_m=x0_m)
        probe._start()
        return step(probe, cfg0)


def identify_ripple(motor: Motor, seed: int = 0, plant: dict[str, Any] | None = None,
                    fw: dict[str, float] | None = None, x0_m: float = 0.0,
                    travel_m: float = 0.3, passes: int = 3) -> Identified:
    """Step 8 of the identification (:func:`identification.run_ripple`) on the simulated
    drive: a free mover from ``x0_m``, the motor file's configuration (``fw`` over it)
    with its ripple correction replaced by the one being measured."""
    return _optional_step(motor, seed, plant, fw, x0_m, 97, lambda probe, cfg0:
                          run_ripple(probe, cfg0, motor.tau_m, travel_m, passes))


def identify_thrust_ripple(motor: Motor, seed: int = 0, plant: dict[str, Any] | None = None,
                           fw: dict[str, float] | None = None, x0_m: float = 0.0,
                           travel_m: float = 0.3) -> Identified:
    """The cogging thrust at 6 theta_e (:func:`identification.run_thrust_ripple`) on the
    simulated drive: a free mover from ``x0_m``, the motor file's configuration (``fw``
    over it) with its cogging coefficients replaced by the ones being measured."""
    return _optional_step(motor, seed, plant, fw, x0_m, 96, lambda probe, cfg0:
                          run_thrust_ripple(probe, cfg0, motor.tau_m, travel_m))


def hold_mover(drive: Any, held: bool = True) -> None:
    """The rig's clamp on the simulated drive (``bench identify --clamped --sim``): the
    plant's mover stopped and held (``locked`` = 1) or released, from the next control
    period on.
    ``drive``: the bench's in-process :class:`SimDrive` (``conn.sim``); the change is made
    under its stepping lock, between two chunks. A fixture's action on the plant (truth
    side), never a measurement: the drive only feels that its mover does not move."""
    sim = drive.sim
    with drive._lock:
        if held:  # the clamp stops what is left of a coast (the lock keeps the speed)
            st = sim.state()
            sim.set_state(x0_m=float(st["x_m"]), v0_mps=0.0, i_d_A=float(st["i_d_A"]),
                          i_q_A=float(st["i_q_A"]))
        sim.set_plant(locked=1 if held else 0)


def seed_range(text: str) -> range:
    """Seeds from a command line: ``"a-b"`` (both included) or ``"a"``; an argparse
    ``type`` (a malformed value is its one-line error)."""
    a, _, b = text.partition("-")
    try:
        return range(int(a), int(b or a) + 1)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected seeds 'a-b' or 'a', "
                                         "non-negative integers") from None


def randomized_plant(seed: int, base: str = "iron_core_linear") -> dict[str, float]:
    """A motor the drive has never seen: ``base`` with R, L, psi_f and mass scaled by
    random factors in [0.75, 1.3] (the saliency kept above the threshold); plant
    overrides for :class:`Sim` / ``run_scenario``."""
    from ._motors import load_motor

    rng = np.random.default_rng(seed)
    m = load_motor(base).plant
    f = rng.uniform(0.75, 1.3, 5)
    return {"R_ohm": m["R_ohm"] * f[0], "L_d0_H": m["L_d0_H"] * f[1],
            "L_q_H": m["L_q_H"] * f[1] * f[2] ** 0.2, "psi_f_Wb": m["psi_f_Wb"] * f[3],
            "mass_kg": m["mass_kg"] * f[4]}


def truth_of(motor: Motor, plant: dict[str, Any] | None = None) -> dict[str, float]:
    """The simulated motor's parameters in the identified names (test verdicts only)."""
    pl = dict(motor.plant)
    pl.update(plant or {})
    return {"R_ohm": pl["R_ohm"], "L_d_H": pl["L_d0_H"], "L_q_H": pl["L_q_H"],
            "psi_f_Wb": pl["psi_f_Wb"], "mass_kg": pl["mass_kg"],
            "b_visc_Ns_per_m": pl["b_visc_Ns_per_m"], "F_coulomb_N": pl["F_coulomb_N"],
            "dL_sat_H": pl["dL_sat_H"], "I_sat_A": pl["I_sat_A"]}


def cross_saturation_truth(motor: Motor, i_q_A: Any, plant: dict[str, Any] | None = None,
                           L_d_cfg: float | None = None, L_q_cfg: float | None = None
                           ) -> tuple[np.ndarray, np.ndarray]:
    """The simulated motor's cross-saturation at i_d = 0 (test verdicts and tools only):
    the HF axis turn delta = 1/2 atan2(-2 L_dq, L_qq - L_dd) (docs/simulator.md) and the
    HF angle error the drive sees at the true angle, eps = -L_dq / L_qq x L_q / (L_q -
    L_d) with the drive's configured L_d, L_q (default: the motor file's): what its map
    must subtract."""
    r = dict(motor.realism)
    pl = dict(motor.plant)
    for k, v in (plant or {}).items():
        (r if k in r else pl)[k] = v
    i = np.asarray(i_q_A, dtype=float)
    Lx, Ix = float(r["cross_L_H"]), float(r["cross_I_A"]) or 1.0
    dLq, Iq = float(r["dLq_sat_H"]), float(r["Iq_sat_A"]) or 1.0
    L_dq = -Lx * np.tanh(i / Ix)
    L_qq = pl["L_q_H"] - dLq * np.tanh(i / Iq) ** 2
    L_dd = pl["L_d0_H"] + 0.0 * i
    delta = 0.5 * np.arctan2(-2.0 * L_dq, L_qq - L_dd)
    Ld = float(L_d_cfg if L_d_cfg is not None else motor.plant["L_d0_H"])
    Lq = float(L_q_cfg if L_q_cfg is not None else motor.plant["L_q_H"])
    eps = -L_dq / L_qq * Lq / (Lq - Ld)
    return delta, eps
