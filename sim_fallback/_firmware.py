"""The firmware core alone, callable from Python ("bring your own plant").

Feed sampled phase currents (A) and the DC-link voltage (V) once per PWM
period, get the duty cycles (0..1, to apply over the NEXT period) and the
internal signals. This is the same compiled ``fw_step`` the simulator and the
MCU run; see ``examples/byo_plant.py``.
"""

from __future__ import annotations

import ctypes as C
from collections.abc import Sequence
from typing import Any

import numpy as np

from protocols import units as U
from protocols.generated.od_names import Mode

from . import _lib


class ConfigError(ValueError):
    """The firmware refused a configuration (``fw_init``/``fw_config_check``).

    Attributes: ``field`` (fw_config_t field name), ``value``, ``allowed``
    ((min, max) or None when the field is inconsistent with others), ``status``
    (fw_status_t).
    """

    def __init__(self, message: str, field: str, value: float,
                 allowed: tuple[float, float] | None, status: int) -> None:
        super().__init__(message)
        self.field, self.value, self.allowed, self.status = field, value, allowed, status


class RefError(ValueError):
    """A reference the firmware refused (non-finite) or clamped (out of range)."""


def config_error(cfg: _lib.FwConfig) -> ConfigError | None:
    """``ConfigError`` describing why the firmware refuses ``cfg``, or None."""
    from ._motors import firmware_check
    L = _lib.lib()
    issue = _lib.FwConfigIssue()
    st = int(L.fw_config_check(cfg, C.byref(issue)))
    if st == 0:
        return None
    _, msg = firmware_check(cfg)
    field = issue.field.decode() if issue.field else "?"
    # float32 limits: 7 significant digits give back the written value (1e-3)
    allowed = ((float(f"{issue.min:.7g}"), float(f"{issue.max:.7g}")) if st in (2, 3, 5)
               else None)
    return ConfigError(msg, field, float(issue.value), allowed, st)


CW_SHUTDOWN, CW_SWITCH_ON, CW_ENABLE_OPERATION, CW_DISABLE_VOLTAGE = 0x06, 0x07, 0x0F, 0x00
CW_FAULT_RESET = 0x80
#: mode name -> fw_mode_t value (protocols/od.yaml enums:)
MODES = {m.key: int(m) for m in Mode}


class Firmware:
    """An ``fw_ctrl_t`` on the C heap with a thin Pythonic interface.

    Parameters
    ----------
    cfg : FwConfig | Motor | str | Path | None
        A ``fw_config_t`` mirror, a :class:`Motor` or a motor name/path (config
        from :func:`fw_config`, gains derived by the firmware) or None for
        ``fw_config_default``.
    extractor : str | int
        Used when ``cfg`` is a motor.
    strict : bool
        True (default): a configuration the firmware refuses raises
        :class:`ConfigError` naming the field, its value and the allowed range.
        False: keep the refused drive (it stays in FAULT with the refusal's
        fault code, as a real drive would boot); ``init_status`` tells why.
    calibrate : bool
        False (default): stepped in physical units (:meth:`step`), the caller owns the
        current zero (``fw_current_zero_external``): ready to enable at once. True: the
        drive boots as on a board, measuring its current zeros on the first raw samples
        (:meth:`step_adc`, or the simulator's port) with the PWM off, in NOT READY TO
        SWITCH ON until they are measured (fw_cal.h).
    **overrides
        ``fw_config_t`` fields to set (an unknown name raises ``KeyError``).

    Raises
    ------
    ConfigError
        When ``strict`` and the firmware refuses the configuration.
    """

    def __init__(self, cfg: Any = None,
                 extractor: int | str = "sogi_adaptive", strict: bool = True,
                 calibrate: bool = False, **overrides: float) -> None:
        self._L = _lib.lib()
        if cfg is None:
            cfg = _lib.FwConfig()
            self._L.fw_config_default(cfg)
        elif not isinstance(cfg, _lib.FwConfig):
            from ._motors import Motor, fw_config, load_motor
            cfg = fw_config(cfg if isinstance(cfg, Motor) else load_motor(cfg), extractor)
        for k, v in overrides.items():
            if k not in _lib.FwConfig.field_names():
                raise KeyError(f"unknown fw_config_t field '{k}'")
            setattr(cfg, k, v)
        if strict:
            err = config_error(cfg)
            if err is not None:
                raise err
        self.cfg = cfg
        self.handle = self._L.sim_fw_new()
        if not self.handle:
            raise MemoryError("sim_fw_new failed")
        self.init_status = int(self._L.fw_init(self.handle, C.byref(cfg)))
        if not calibrate:
            self._L.fw_current_zero_external(self.handle)
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

    @staticmethod
    def _ref(status: int, name: str, value: float, unit: str) -> int:
        if status == 3:  # FW_ERR_NOT_FINITE: nothing applied
            raise RefError(f"{name} = {value!r} {unit} refused: must be a finite number")
        return status

    def set_speed_ref_radps_e(self, w: float) -> int:
        """Speed mode: electrical rad/s. Returns 0, or 2 (FW_ERR_RANGE) when the
        firmware clamped it to the smaller of +-speed_max_radps_e and
        +-v_max_mps (0x6080); raises :class:`RefError`
        for NaN/inf (nothing applied)."""
        return self._ref(int(self._L.fw_set_speed_ref(self.handle, w)), "speed reference", w,
                         "rad/s el.")

    def set_speed_ref_rpm(self, n_rpm: float) -> int:
        """Speed mode: rotary-equivalent r/min (see :meth:`set_speed_ref_radps_e`)."""
        return self.set_speed_ref_radps_e(
            self._L.fw_units_rpm_to_radps_e(C.byref(self.cfg), n_rpm))

    def set_speed_ref_mps(self, v_mps: float) -> int:
        """Speed mode: linear speed in m/s (w_e = pi v / tau)."""
        return self.set_speed_ref_radps_e(
            self._L.fw_units_mps_to_radps_e(C.byref(self.cfg), v_mps))

    def set_iq_ref_A(self, i_q: float) -> int:
        """Force mode: q-axis current reference in A (clamped to +-i_max_A: 2)."""
        return self._ref(int(self._L.fw_set_iq_ref(self.handle, i_q)), "i_q reference", i_q,
                         "A")

    def set_force_ref_N(self, force_N: float) -> int:
        """Force mode: thrust in N, i_q = F / K_F with the firmware's
        ``fw_units_force_per_A`` (K_F = 1.5 (pi/tau) psi_f)."""
        return self._ref(int(self._L.fw_set_force_ref(self.handle, force_N)),
                         "force reference", force_N, "N")

    def set_torque_ref_Nm(self, torque_Nm: float) -> int:
        """Force mode, rotary equivalent: T = F r with r = p tau / pi."""
        r = U.radius_m(self.cfg.pole_pairs, self.cfg.pole_pitch_m)
        return self.set_force_ref_N(torque_Nm / r)

    def bemf_V(self, v_mps: float) -> float:
        """Back-EMF magnitude w psi_f (V) of a mover at v_mps with this configuration: the
        firmware's ``fw_units_bemf_V`` (its handover, witness and motion-check levels)."""
        return float(self._L.fw_units_bemf_V(C.byref(self.cfg), v_mps))

    @property
    def force_per_A(self) -> float:
        """K_F in N/A (the firmware's nominal thrust constant)."""
        return float(self._L.fw_units_force_per_A(C.byref(self.cfg)))

    def set_extractor(self, ex: int | str) -> int:
        from ._motors import extractor_id
        return int(self._L.fw_set_extractor(self.handle, extractor_id(ex)))

    def fault_code(self) -> int:
        return int(self._L.fw_fault_code(self.handle))

    def current_zero_counts(self) -> list[float]:
        """Per-phase current zero (ADC counts) the conversion uses: measured with
        the PWM off at boot (fw_cal.h), the nominal ``adc_offset_counts`` until then
        or when stepped in physical units."""
        return [float(self._L.fw_current_zero_counts(self.handle, k)) for k in range(3)]

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
