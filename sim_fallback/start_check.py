"""The start-up motion check (MOVING_AT_ENABLE) measured on the simulated drive: its
statistic over the check window against its threshold, and the simulator's truth beside it
(for verdicts only; tools/start_motion_check.py, tests/python/test_start_motion.py)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from protocols.generated.od_names import FAULT_CODES, StartPhase

from ._sim import SIM_REF_SPEED, Sim

CHECK_FROM_S = 0.015  #: FW_MOTION_CHECK_S
MOVING_AT_ENABLE = FAULT_CODES["MOVING_AT_ENABLE"]
#: plant overrides: no friction or cogging (a mover that keeps its speed)
FRICTIONLESS = {"F_coulomb_N": 0.0, "F_static_N": 0.0, "b_visc_Ns_per_m": 0.0,
                "cog_amp_N": 0.0}


def motion_check(motor: str, seed: int, x0_m: float, v0_mps: float = 0.0,
                 plant: dict[str, Any] | None = None,
                 fw: dict[str, float] | None = None) -> dict[str, float]:
    """Enable at x0_m (true speed v0_mps) and run the alignment. Returns the largest
    statistic / threshold over the check window, the fault code, the largest true |v|
    during the alignment and the true |v| at the first check."""
    sim = Sim(motor, seed=seed, x0_m=x0_m, plant=plant, fw=fw)
    try:
        if v0_mps:
            sim.set_state(x0_m=x0_m, v0_mps=v0_mps)
        sim.set_schedule(SIM_REF_SPEED, 0.0)
        cfg = sim.cfg
        thr = sim.firmware.bemf_V(cfg.start_speed_max_mps)  # the drive's own threshold
        sim.enable("speed")
        stat, v_max, v_check, stat_check = 0.0, 0.0, float("nan"), float("nan")
        while sim.t_s < 0.3:
            d = sim.advance(8, channels=["t_s", "v_mps", "start_phase", "fault_code"])
            aligning = d["start_phase"] == StartPhase.ALIGN
            if not aligning.any():
                break
            v_max = max(v_max, float(np.max(np.abs(d["v_mps"][aligning]))))
            if d["t_s"][-1] >= CHECK_FROM_S:
                e = float(sim.snapshot()["mon_e_bemf_V"])
                if math.isnan(v_check):
                    v_check, stat_check = abs(float(d["v_mps"][-1])), e
                stat = max(stat, e)
            if d["fault_code"][-1]:
                break
        # the statistic at the first check against the true back-EMF there
        e_true = sim.firmware.bemf_V(v_check)
        return {"ratio": stat / thr, "fault": int(sim.firmware.fault_code()),
                "v_max": v_max, "v_check": v_check, "v_limit": cfg.start_speed_max_mps,
                "accuracy": stat_check / e_true if e_true > 0.0 else float("nan"),
                "flying": int(sim.snapshot()["flying_start"])}
    finally:
        sim.close()
