"""Bring your own plant: the firmware step alone, and the documented example."""

import importlib.util
from pathlib import Path

import numpy as np

from sim_fallback import Firmware

ROOT = Path(__file__).resolve().parents[2]


def test_firmware_step_alone():
    fw = Firmware("paper_salient")
    assert fw.init_status == 0
    d, on = fw.step([0.0, 0.0, 0.0], 300.0)
    assert not on                              # not enabled yet: PWM off
    fw.enable("speed")
    d, on = fw.step([0.01, -0.005, -0.005], 300.0)
    assert on and np.all((d >= 0) & (d <= 1))
    snap = fw.snapshot()
    assert snap["cia402_state"] == 4 and snap["start_phase"] == 1  # OPERATION ENABLED, ALIGN
    assert fw.fault_code() == 0


def test_firmware_rejects_nan_input():
    fw = Firmware("paper_salient")
    fw.enable("speed")
    fw.step([float("nan"), 0.0, 0.0], 300.0)
    assert fw.fault_code() == 0x5210           # FW_FAULT_INPUT_INVALID


def test_byo_example_tracks():
    spec = importlib.util.spec_from_file_location("byo_plant", ROOT / "examples" / "byo_plant.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = mod.main(t_end=0.5)
    assert out["fault_code"] == 0
    assert out["position_error_rms_rad"] < 0.1
    assert abs(out["speed_rpm"] - 100.0) < 20.0
    # commanded in m/s (0.32 m/s = 100 r/min on this motor); 65 N load from 0.35 s
    assert abs(out["speed_mps"] - 0.32) < 0.064
