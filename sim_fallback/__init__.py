"""Simulated PMLSM drive: C plant + the firmware core in closed loop.

Public API (internals live in private modules)::

    from sim_fallback import run_scenario, paper_scenario, Sim, Firmware, load_motor
    res = run_scenario(motor="paper_salient", extractor="sogi_adaptive",
                       speed_ref=100.0, load=[(0.0, 0.0), (0.5, 2.0)], t_end=1.0)
    res.metrics["position_error_rms_rad"]; res.t_s; res.theta_hat_rad

See docs/simulator.md.
"""

from ._firmware import Firmware
from ._lib import FwConfig, FwSnapshot, SimPlantParams, lib_path
from ._motors import MOTOR_DIR, Motor, MotorFileError, fw_config, load_motor, plant_params
from ._sim import (
    CHANNELS,
    METRIC_NAMES,
    PAPER_SCENARIOS,
    SIM_REF_FORCE,
    SIM_REF_LOAD,
    SIM_REF_SPEED,
    Result,
    Sim,
    compute_metrics,
    paper_scenario,
    run_scenario,
    wrap_pi,
)

__all__ = [
    "CHANNELS", "METRIC_NAMES", "MOTOR_DIR", "PAPER_SCENARIOS", "SIM_REF_FORCE", "SIM_REF_LOAD",
    "SIM_REF_SPEED", "Firmware", "FwConfig", "FwSnapshot", "Motor", "MotorFileError", "Result",
    "Sim", "SimPlantParams", "compute_metrics", "fw_config", "load_motor", "lib_path",
    "paper_scenario", "plant_params", "run_scenario", "wrap_pi",
]
