"""Simulated PMLSM drive: C plant + the firmware core in closed loop.

Public API (internals live in private modules)::

    from sim_fallback import run_scenario, paper_scenario, Sim, Firmware, load_motor
    res = run_scenario(motor="paper_salient", extractor="sogi_adaptive",
                       speed_ref=100.0, load=[(0.0, 0.0), (0.5, 2.0)], t_end=1.0)
    res.metrics["position_error_rms_rad"]; res.t_s; res.theta_hat_rad

The simulated drive as a CAN node (the firmware's whole drive application on a
python-can bus; python-can is imported on first use)::

    from sim_fallback import SimDrive, DriveBridge

The drive worlds beside it, as public modules: :mod:`sim_fallback.server` (the simulated
drive server, ``bench sim``), :mod:`sim_fallback.emu` (the firmware image on the emulated
board in QEMU, ``bench emu``), :mod:`sim_fallback.standin` (``FakeDrive402``: a CiA 402
stand-in node without a plant, for protocol tests).

Metrics (one definition for the simulator, the bench and the reports):
``sim_fallback.metrics`` (public, numpy only). See docs/simulator.md. What any estimator
of the injection could reach, from a motor file: ``sim_fallback.bound`` (numpy only;
docs/method.md section 5.1, docs/estimator_bound.md).
"""

from ._emu_blob import EMU_BLOB_ADDR, emu_boot_blob, write_emu_boot_blob
from ._firmware import ConfigError, Firmware, RefError, config_error
from ._identify import (
    SimProbe,
    cross_saturation_truth,
    hold_mover,
    identify,
    identify_cross_saturation,
    identify_ripple,
    identify_thrust_ripple,
    randomized_plant,
    seed_range,
    truth_of,
)
from ._lib import FwConfig, FwSnapshot, SimPlantParams, lib_path
from ._motors import (
    MOTOR_DIR,
    PLANT_FIELD_SOURCES,
    Motor,
    MotorFileError,
    extractor_id,
    firmware_check,
    firmware_field_ranges,
    fw_config,
    load_motor,
    machine_params,
    plant_field_range,
    plant_params,
    plant_params_refused,
    realism_params,
    realism_refused,
    split_plant_overrides,
)
from ._sim import (
    CHANNELS,
    LINEAR_SCENARIOS,
    PAPER_SCENARIO_ARGS,
    PAPER_SCENARIOS,
    SIM_REF_FORCE,
    SIM_REF_LOAD,
    SIM_REF_SPEED,
    X0_MAX_M,
    Result,
    Sim,
    drive_params,
    linear_scenario,
    linear_scenario_args,
    paper_scenario,
    rated_thrust_N,
    run_scenario,
)
from .metrics import METRIC_DEFS, METRIC_NAMES, METRICS, compute_metrics, run_metrics, wrap_pi

#: Names of the CAN-node modules, imported on first use (they import python-can).
_LAZY = {"DriveBridge": "_app", "SimDrive": "_candrive", "SimLoad": "_candrive",
         "SimClock": "_candrive", "FwCanFrame": "_lib", "FakeDrive402": "standin"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "DriveBridge", "SimDrive", "SimLoad", "SimClock", "FwCanFrame", "FakeDrive402",
    "SimProbe", "cross_saturation_truth", "hold_mover", "identify", "identify_cross_saturation",
    "identify_ripple", "identify_thrust_ripple", "randomized_plant", "seed_range", "truth_of",
    "PLANT_FIELD_SOURCES", "extractor_id", "machine_params", "plant_field_range",
    "plant_params_refused", "realism_params", "realism_refused", "split_plant_overrides",
    "X0_MAX_M",
    "CHANNELS", "ConfigError", "EMU_BLOB_ADDR", "drive_params", "emu_boot_blob",
    "write_emu_boot_blob", "RefError", "config_error", "METRIC_DEFS", "METRIC_NAMES",
    "METRICS", "MOTOR_DIR", "PAPER_SCENARIO_ARGS", "PAPER_SCENARIOS", "LINEAR_SCENARIOS",
    "linear_scenario", "linear_scenario_args", "rated_thrust_N",
    "SIM_REF_FORCE", "SIM_REF_LOAD", "SIM_REF_SPEED", "Firmware", "FwConfig", "FwSnapshot",
    "Motor", "MotorFileError", "Result", "Sim", "SimPlantParams", "compute_metrics",
    "firmware_check", "firmware_field_ranges", "fw_config", "load_motor", "lib_path",
    "paper_scenario", "plant_params", "run_metrics", "run_scenario", "wrap_pi",
]
