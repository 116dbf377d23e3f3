"""The firmware core alone, callable from Python ("bring your own plant").

Feed sampled phase currents (A) and the DC-link voltage (V) once per PWM
period, get the duty cycles (0..1, to apply over the NEXT period) and the
internal signals. This is the same compiled ``fw_step`` the simulator and the
MCU run; see ``examples/byo_plant.py``.
"""

from __future__ import annotations

import ctypes as C
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from . import _lib

CW_SHUTDOWN, CW_SWITCH_ON, CW_ENABLE_OPERATION, CW_DISABLE_VOLTAGE = 0x06, 0x07, 0x0F, 0x00
CW_FAULT_RESET = 0x80
MODES = {"speed": 0, "force": 1}


class Firmware:
    """An ``fw_ctrl_t`` on the C heap with a thin Pythonic interface.

    Parameters
    ----------
    cfg : FwConfig | str | Path | None
        A ``fw_config_t`` mirror, a motor name/path (config derived with the
        paper's gain rules) or None for ``fw_config_default``.
    extractor : str | int
        Used when ``cfg`` is a motor.
    """

    def __init__(self, cfg: _lib.FwConfig | str | Path | None = None,
                 extractor: int | str = "sogi_adaptive", **overrides: float) -> None:
        self._L = _lib.lib()
        if cfg is None:
            cfg = _lib.FwConfig()
            self._L.fw_config_default(cfg)
        elif not isinstance(cfg, _lib.FwConfig):
            from ._motors import fw_config, load_motor
            cfg = fw_config(load_motor(cfg), extractor)
        for k, v in overrides.items():
            setattr(cfg, k, v)
        self.cfg = cfg
        self.handle = self._L.sim_fw_new()
        if not self.handle:
            raise MemoryError("sim_fw_new failed")
        self.init_status = int(self._L.fw_init(self.handle, C.byref(cfg)))
        self._in = _lib.FwInputs()
        self._adc = _lib.FwAdcInputs()
        self._out = _lib.FwOutputs()
        self._snap = _lib.FwSnapshot()

    def close(self) -> None:
        if getattr(self, "handle", None):
            self._L.sim_fw_free(self.handle)
            self.handle = None

    def __del__(self) -> None:  # pragma: no cover
        try:
            self.close()
        except Exception:
            pass

    # ---- commands ----------------------------------------------------------
    def controlword(self, cw: int) -> int:
        """Apply a CiA 402 controlword; returns the statusword."""
        return int(self._L.fw_controlword(self.handle, cw))

    def enable(self, mode: str = "speed") -> int:
        """Shutdown -> switch on -> enable operation (start-up follows in fw_step)."""
        self._L.fw_set_mode(self.handle, MODES[mode])
        self.controlword(CW_SHUTDOWN)
        self.controlword(CW_SWITCH_ON)
        return self.controlword(CW_ENABLE_OPERATION)

    def set_speed_ref_radps_e(self, w: float) -> int:
        return int(self._L.fw_set_speed_ref(self.handle, w))

    def set_speed_ref_rpm(self, n_rpm: float) -> int:
        return self.set_speed_ref_radps_e(n_rpm * 2.0 * math.pi * self.cfg.pole_pairs / 60.0)

    def set_iq_ref_A(self, i_q: float) -> int:
        return int(self._L.fw_set_iq_ref(self.handle, i_q))

    def set_extractor(self, ex: int | str) -> int:
        from ._motors import extractor_id
        return int(self._L.fw_set_extractor(self.handle, extractor_id(ex)))

    def fault_code(self) -> int:
        return int(self._L.fw_fault_code(self.handle))

    def state(self) -> int:
        return int(self._L.fw_state(self.handle))

    # ---- real time -----------------------------------------------------------
    def step(self, i_abc_A: Sequence[float], u_dc_V: float) -> tuple[np.ndarray, bool]:
        """One PWM period: sampled phase currents (A) and DC link (V) in,
        (duty_abc 0..1, pwm_enable) out. Apply the duties over the next period."""
        self._in.i_abc_A[0], self._in.i_abc_A[1], self._in.i_abc_A[2] = (
            float(i_abc_A[0]), float(i_abc_A[1]), float(i_abc_A[2]))
        self._in.u_dc_V = float(u_dc_V)
        self._L.fw_step(self.handle, C.byref(self._in), C.byref(self._out))
        return np.array(self._out.duty_abc[:], dtype=np.float64), bool(self._out.pwm_enable)

    def step_adc(self, i_abc_counts: Sequence[int], u_dc_counts: int) -> tuple[np.ndarray, bool]:
        """Same as :meth:`step` from raw ADC counts (scaled by cfg.adc_*)."""
        for j in range(3):
            self._adc.i_abc_counts[j] = int(i_abc_counts[j])
        self._adc.u_dc_counts = int(u_dc_counts)
        self._L.fw_step_adc(self.handle, C.byref(self._adc), C.byref(self._out))
        return np.array(self._out.duty_abc[:], dtype=np.float64), bool(self._out.pwm_enable)

    def snapshot(self) -> dict[str, Any]:
        """Internal signals after the last step (``fw_snapshot_t`` as a dict)."""
        self._L.fw_get_snapshot(self.handle, C.byref(self._snap))
        return self._snap.as_dict()
