"""Closed-loop simulation: the C plant + the firmware core, stepped in C.

``Sim`` owns one ``sim_t`` and one ``fw_ctrl_t``; ``Sim.advance(n)`` runs n
PWM periods in one C call (so a protocol bridge can exchange frames between
chunks); ``run_scenario`` builds a Sim from a motor file, runs a reference
schedule and returns a :class:`Result` with numpy arrays and metrics.
"""

from __future__ import annotations

import ctypes as C
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from protocols.generated.od_names import Extractor, StartPhase

from . import _lib
from ._firmware import Firmware, config_error
from ._motors import (
    SENSING_SCALE_KEYS,
    Motor,
    extractor_id,
    fw_config,
    load_motor,
    plant_params,
    plant_params_refused,
    realism_params,
    split_plant_overrides,
)
from .metrics import METRIC_DEFS, METRIC_NAMES, TRUTH_CHANNELS, run_metrics, wrap_pi

SIM_REF_SPEED, SIM_REF_FORCE, SIM_REF_LOAD = 0, 1, 2
CHANNELS = [name for name, *_ in _lib.RECORD_CHANNELS]

ScheduleLike = float | Sequence[tuple[float, float]] | dict[str, Any] | None


def _schedule(spec: ScheduleLike, scale: float) -> tuple[list[float], list[float], int] | None:
    """Normalise a schedule: constant, [(t_s, value), ...] or {"t_s", "value", "ramp"}.
    Breakpoint times and scaled values as floats (a few of them: plain Python, which
    costs a run ~2 us where numpy arrays cost ~12 us)."""
    if spec is None:
        return None
    ramp = 0
    if isinstance(spec, (int, float)):
        t, v = [0.0], [float(spec)]
    elif isinstance(spec, dict):
        t, v, ramp = list(spec["t_s"]), list(spec["value"]), int(bool(spec.get("ramp", False)))
    else:
        t = [a for a, _ in spec]
        v = [b for _, b in spec]
    t = [float(a) for a in t]
    v = [float(b) * scale for b in v]
    if not t or len(t) != len(v) or any(b < a for a, b in zip(t, t[1:], strict=False)):
        raise ValueError(f"bad schedule {spec!r}: need ascending t_s and matching values")
    return t, v, ramp


class _SimRecordRaw(C.Structure):
    """:class:`_lib.SimRecord` with its pointers as plain addresses (same layout)."""

    _fields_ = [(n, C.c_void_p) for n, _, _, _ in _lib.RECORD_CHANNELS] + [
        ("capacity", C.c_uint32), ("pad_", C.c_uint32)]


assert C.sizeof(_SimRecordRaw) == C.sizeof(_lib.SimRecord)


@functools.lru_cache(maxsize=64)
def _record_layout(want: tuple[str, ...], n_rec: int
                   ) -> tuple[list[tuple[str, np.dtype, int, int, int]], int]:
    """(name, dtype, columns, bytes, offset) of each recorded channel in one buffer
    (64-byte aligned), and the buffer's size."""
    out = []
    off = 0
    for name, _, dtype, cols in _lib.RECORD_CHANNELS:
        if name in want:
            dt = np.dtype(dtype)
            nbytes = n_rec * cols * dt.itemsize
            out.append((name, dt, cols, nbytes, off))
            off += -(-nbytes // 64) * 64
    return out, off


#: The largest initial position |x0| (m) the simulator takes: x is unwrapped and
#: theta_e = pi x / tau in float64, which keeps the angle to 1e-9 rad up to ~3 km at the
#: shortest pole pitch a motor file allows (1 mm); the firmware never sees x.
X0_MAX_M = 1000.0


def drive_params(motor: str | Path | Motor = "paper_salient",
                 extractor: int | str = "sogi_adaptive", seed: int = 0, noise: float = 1.0,
                 plant: dict[str, Any] | None = None, fw: dict[str, float] | None = None
                 ) -> tuple[_lib.SimPlantParams, _lib.FwConfig]:
    """The simulated drive's two halves for a motor: the plant it drives
    (``sim_plant_params_t``: the motor file's values, ADC noise and offsets scaled by
    ``noise``, the noise ``seed``, ``plant`` overrides) and the drive's configuration
    (``fw_config_t``: :func:`fw_config` with the board's ADC scaling, ``fw`` overrides).
    One definition for every simulated drive: :class:`Sim`, the bench's simulated drive
    and the emulated board's boot block (:func:`sim_fallback.emu_boot_blob`).

    Raises ValueError naming a plant parameter the simulator refuses.
    """
    m = motor if isinstance(motor, Motor) else load_motor(motor)
    ov = dict(plant or {})
    mp = m.plant
    ov.setdefault("adc_noise_counts", mp["adc_noise_counts"] * noise)
    ov.setdefault("udc_noise_V", mp["udc_noise_V"] * noise)
    ov.setdefault("adc_offset_counts", [o * noise for o in mp["adc_offset_counts"]])
    ov.setdefault("seed", int(seed) & 0xFFFFFFFFFFFFFFFF)
    params = plant_params(m, **ov)
    bad = plant_params_refused(params)
    if bad is not None:
        raise ValueError(f"plant parameter '{bad}' invalid")
    cfg = fw_config(m, extractor,  # the drive knows its own board's ADC
                    sensing={k: getattr(params, k) for k in SENSING_SCALE_KEYS}, **(fw or {}))
    return params, cfg


class Sim:
    """One simulated drive: plant (truth) + firmware core, stepped in C.

    Parameters
    ----------
    motor : str | Path | Motor
        Motor name in ``sim_fallback/motors`` or a TOML path.
    extractor : {"pseudo", "sogi", "sogi_adaptive"}
    seed : int
        Seeds the ADC noise RNG (and nothing else).
    noise : float
        Scale of the motor file's ADC noise and offsets (1 = default, 0 = ideal).
    x0_m : float
        Initial mover position (true; the firmware does not know it).
    plant : dict
        ``sim_plant_params_t`` overrides (linear units), and ``sim_realism_t`` ones (plant
        realism: ``cross_L_H``, ``emf_h5``, ...; applied with ``sim_set_realism``).
    fw : dict
        ``fw_config_t`` overrides.
    strict : bool
        True: a configuration the firmware refuses raises
        :class:`~sim_fallback.ConfigError` (field, value, allowed range).
        False: the simulated drive boots refused, in FAULT, like a real drive.
    """

    def __init__(self, motor: str | Path | Motor = "paper_salient",
                 extractor: int | str = "sogi_adaptive", seed: int = 0, noise: float = 1.0,
                 x0_m: float = 0.0, plant: dict[str, Any] | None = None,
                 fw: dict[str, float] | None = None, strict: bool = True) -> None:
        self._L = _lib.lib()
        self._rec_raw = _SimRecordRaw()  # advance()'s record, reused
        self._rec = _lib.SimRecord.from_buffer(self._rec_raw)
        self.motor = motor if isinstance(motor, Motor) else load_motor(motor)
        plant_ov, real_ov = split_plant_overrides(plant)
        self.params, self.cfg = drive_params(self.motor, extractor, seed, noise, plant_ov, fw)
        self.realism = realism_params(self.motor, **real_ov)
        self._h = self._L.sim_new(self.params)
        if not self._h:
            raise MemoryError("sim_new failed")
        bad = C.c_char_p()
        if self._L.sim_set_realism(self._h, self.realism, C.byref(bad)) != 0:
            self._L.sim_free(self._h)
            self._h = None
            raise ValueError(f"plant parameter '{bad.value.decode()}' invalid")
        self.dt_s = 1.0 / self.params.f_pwm_Hz
        self.firmware = Firmware(self.cfg, strict=strict, calibrate=True)
        self._port = _lib.SimController()
        self._L.sim_fw_port(self.firmware.handle, C.byref(self._port))
        self._L.sim_set_controller(self._h, C.byref(self._port))
        self.boot()
        self.set_state(x0_m=x0_m)
        self._keep: list[np.ndarray] = []

    # ---- life cycle ------------------------------------------------------
    def close(self) -> None:
        if getattr(self, "_h", None):
            self._L.sim_free(self._h)
            self._h = None
        if getattr(self, "firmware", None) is not None:
            self.firmware.close()

    def __del__(self) -> None:  # pragma: no cover - GC order
        try:
            self.close()
        except Exception:
            pass

    def __enter__(self) -> Sim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def boot(self, advance_time: bool = False) -> int:
        """The drive's boot (the controller in place): the firmware measures its
        current zeros on the plant's ADC samples with the PWM off (CiA 402 NOT READY
        TO SWITCH ON, fw_cal.h). ``advance_time`` False: before t = 0, neither the
        plant nor the time advance (the core alone: scenarios start at the enable);
        True: the simulator's time runs with the drive's clock (the drive
        application). Returns the periods it took (``boot_steps``); a drive that does
        not leave NOT READY TO SWITCH ON within 1 s raises RuntimeError."""
        n = int(self._L.sim_boot(self._h, int(round(1.0 / self.dt_s)), int(advance_time)))
        if n < 0:
            raise RuntimeError("sim_boot: the drive did not leave NOT READY TO SWITCH ON "
                               "within 1 s with the PWM off")
        self.boot_steps = n
        return n

    # ---- configuration ---------------------------------------------------
    def set_state(self, x0_m: float = 0.0, v0_mps: float = 0.0, i_d_A: float = 0.0,
                  i_q_A: float = 0.0) -> None:
        """Set the true plant state (truth only: the firmware never sees it). ``x0_m``
        finite with |x0_m| <= :data:`X0_MAX_M` (else ValueError)."""
        if not (math.isfinite(x0_m) and abs(x0_m) <= X0_MAX_M):
            raise ValueError(f"x0_m = {x0_m!r} outside the allowed range [-{X0_MAX_M:g}, "
                             f"{X0_MAX_M:g}] m")
        st = _lib.SimPlantState(i_d_A, i_q_A, x0_m, v0_mps, 1 if v0_mps == 0.0 else 0, 0)
        self._L.sim_set_state(self._h, C.byref(st))

    def state(self) -> dict[str, float]:
        st = _lib.SimPlantState()
        self._L.sim_get_state(self._h, C.byref(st))
        return {k: getattr(st, k) for k, _ in st._fields_ if k != "pad_"}

    def set_plant(self, **changes: Any) -> None:
        """Change plant parameters mid-run (fault injection: DC-link sag, sensor
        gain/offset errors, ``open_phase_mask``, ``adc_stuck_mask``); state and
        time are kept. Truth only: the firmware sees the effect, never the value."""
        changes, real = split_plant_overrides(changes)
        for k, v in real.items():
            setattr(self.realism, k, v)
        for k, v in changes.items():
            if not hasattr(self.params, k):
                raise ValueError(f"unknown plant parameter '{k}'")
            cur = getattr(self.params, k)
            if isinstance(cur, C.Array):
                for j, x in enumerate(v):
                    cur[j] = x
            else:
                setattr(self.params, k, v)
        bad = C.c_char_p()
        if self._L.sim_set_params(self._h, self.params, C.byref(bad)) != 0:
            raise ValueError(f"plant parameter '{bad.value.decode()}' invalid")
        if real and self._L.sim_set_realism(self._h, self.realism, C.byref(bad)) != 0:
            raise ValueError(f"plant parameter '{bad.value.decode()}' invalid")

    def set_schedule(self, kind: int, spec: ScheduleLike, scale: float = 1.0) -> None:
        """Schedule SIM_REF_SPEED (rad/s el.), SIM_REF_FORCE (N) or SIM_REF_LOAD (N)."""
        s = _schedule(spec, scale)
        if s is None:
            rc = self._L.sim_set_schedule(self._h, kind, None, None, 0, 0)
        else:
            t, v, ramp = s
            arr = C.c_double * len(t)
            rc = self._L.sim_set_schedule(self._h, kind, arr(*t), arr(*v), len(t), ramp)
        if rc != 0:
            raise ValueError(f"sim_set_schedule rejected {spec!r}")

    def enable(self, mode: str = "speed") -> int:
        """CiA 402 walk to OPERATION ENABLED; returns the statusword."""
        return self.firmware.enable(mode)

    @property
    def t_s(self) -> float:
        return float(self._L.sim_time_s(self._h))

    @property
    def step_count(self) -> int:
        return int(self._L.sim_step_count(self._h))

    # ---- stepping --------------------------------------------------------
    def advance(self, n_steps: int, decimation: int = 1,
                channels: Sequence[str] | None = None) -> dict[str, np.ndarray]:
        """Run n_steps PWM periods in one C call; return the recorded channels.

        Entries are recorded every ``decimation`` periods counted from t = 0,
        so consecutive chunks join without gaps or duplicates.
        """
        if n_steps < 0 or decimation < 1:
            raise ValueError("n_steps >= 0 and decimation >= 1 required")
        k0 = self.step_count
        first = -(-k0 // decimation) * decimation
        n_rec = 0 if first >= k0 + n_steps else (k0 + n_steps - 1 - first) // decimation + 1
        if n_rec >= 2**32:
            raise ValueError("too many records for one call; use chunks")
        layout, total = _record_layout(tuple(CHANNELS if channels is None else channels),
                                       n_rec)
        # One allocation for all channels (64-byte aligned views): a long
        # recording is then large enough for numpy to back it with huge pages,
        # which removes most of the page faults taken while the C loop writes
        # it (~2.5 us per 4 KiB fault in a VM, i.e. ~0.1 us per recorded
        # period). The views keep the shared buffer alive. The record's pointers
        # are set as plain addresses: the simulated drive calls this once per SYNC
        # (1,000 times per simulated second), and typed pointer casts made it
        # 84 us per call instead of 22 us (20 channels, one control period).
        buf = np.empty(total + 64, dtype=np.uint8)
        base = buf.ctypes.data
        off0 = -base % 64
        raw = self._rec_raw
        C.memset(C.addressof(raw), 0, C.sizeof(raw))
        raw.capacity = n_rec
        out: dict[str, np.ndarray] = {}
        for name, dtype, cols, nbytes, off in layout:
            a = buf[off0 + off:off0 + off + nbytes].view(dtype)
            out[name] = a.reshape((n_rec, cols)) if cols > 1 else a
            setattr(raw, name, base + off0 + off)
        rec = self._rec
        got = self._L.sim_run(self._h, n_steps, decimation, C.byref(rec))
        if got < 0:
            raise RuntimeError("sim_run failed")
        assert got == n_rec, (got, n_rec)
        return out

    def snapshot(self) -> dict[str, Any]:
        return self.firmware.snapshot()

    def drive_inputs(self, i_abc_meas_A: np.ndarray, u_dc_meas_V: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
        """The physical inputs the drive computed from recorded samples (the channels
        ``i_abc_meas_A`` (n, 3) and ``u_dc_meas_V`` (n,) of this simulator): the raw
        counts back from the simulated ADC's scaling, then the firmware's own conversion
        (``fw_adc_convert``) with the current zeros it measured at boot. What a replay
        in physical units (``Firmware.step``, fw_step) must be fed to see what the
        closed loop saw. -> (i_abc_A (n, 3), u_dc_V (n,)), float32."""
        p = self.params
        full = float(2 ** int(p.adc_bits))
        lsb, mid, u_lsb = 2.0 * p.adc_i_fullscale_A / full, 0.5 * full, p.udc_fullscale_V / full
        counts = np.rint(np.asarray(i_abc_meas_A, float) / lsb + mid).astype(np.uint16)
        u_counts = np.rint(np.asarray(u_dc_meas_V, float) / u_lsb).astype(np.uint16)
        zeros = (C.c_float * 3)(*self.firmware.current_zero_counts())
        adc, x = _lib.FwAdcInputs(), _lib.FwInputs()
        i_out = np.empty(counts.shape, np.float32)
        u_out = np.empty(len(u_counts), np.float32)
        for k in range(len(u_counts)):
            adc.i_abc_counts[0], adc.i_abc_counts[1], adc.i_abc_counts[2] = (
                int(counts[k, 0]), int(counts[k, 1]), int(counts[k, 2]))
            adc.u_dc_counts = int(u_counts[k])
            self._L.fw_adc_convert(self.cfg, zeros, adc, x)
            i_out[k] = x.i_abc_A[:]
            u_out[k] = x.u_dc_V
        return i_out, u_out

    def set_controller_port(self, port: _lib.SimController, keep: Any = None) -> None:
        """Plug another controller with the fw_step signature (e.g. a CANopen
        application wrapping fw_ctrl_t): ``port`` holds ctx and C function pointers
        (``sim_controller_t``); ``keep`` is held to keep ctx / callbacks alive."""
        self._port = port
        self._port_keep = keep
        self._L.sim_set_controller(self._h, C.byref(self._port))

    # ---- test equipment -----------------------------------------------------
    def use_fixed_duties(self, duty_abc: Sequence[float], pwm_enable: bool = True) -> None:
        """Replace the firmware by the fixed-duty controller (plant tests)."""
        self._const = _lib.SimCtrlConst()
        self._const.duty_abc[:] = [float(d) for d in duty_abc]
        self._const.pwm_enable = int(bool(pwm_enable))
        port = _lib.SimController()
        self._L.sim_ctrl_const_port(C.byref(self._const), C.byref(port))
        self._port = port
        self._L.sim_set_controller(self._h, C.byref(self._port))

    def plant_advance(self, duty_abc: Sequence[float], pwm_enable: bool, dt_s: float,
                      n_sub: int) -> None:
        """Integrate the plant alone for dt_s with fixed duties (n_sub RK4 steps)."""
        d = (C.c_double * 3)(*[float(x) for x in duty_abc])
        self._L.sim_plant_advance(self._h, d, int(bool(pwm_enable)), dt_s, n_sub)

    def sample(self) -> tuple[np.ndarray, float, np.ndarray, int]:
        """Sample the ADC now: (i_abc_A, u_dc_V, i_abc_counts, u_dc_counts)."""
        i, a = _lib.FwInputs(), _lib.FwAdcInputs()
        self._L.sim_sample(self._h, C.byref(i), C.byref(a))
        return (np.array(i.i_abc_A[:]), float(i.u_dc_V), np.array(a.i_abc_counts[:]),
                int(a.u_dc_counts))

    def force_N(self) -> float:
        """True electromagnetic thrust at the present state."""
        return float(self._L.sim_force_N(self._h))

    def magnetics(self, i_d_A: float, i_q_A: float, x_m: float) -> dict[str, Any]:
        """The plant's magnetics at currents (true rotor frame) and position
        (``sim_plant_magnetics``): ``psi_dq_Wb`` (2), ``L_dq_H`` (dd, dq, qq),
        ``e_dq_V_per_mps`` (speed voltage per velocity), ``force_N`` (thrust, no cogging)."""
        m = _lib.SimMagnetics()
        self._L.sim_plant_magnetics(self._h, float(i_d_A), float(i_q_A), float(x_m),
                                    C.byref(m))
        return {"psi_dq_Wb": np.array(m.psi_dq_Wb[:]), "L_dq_H": np.array(m.L_dq_H[:]),
                "e_dq_V_per_mps": np.array(m.e_dq_V_per_mps[:]), "force_N": m.force_N}


# ---- results ---------------------------------------------------------------


@dataclass
class Result:
    """Time series (numpy arrays keyed by channel name) and metrics."""

    data: dict[str, np.ndarray]
    metrics: dict[str, float]
    motor: Motor
    extractor: str
    seed: int
    settle_s: float
    fault_code: int
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def valid(self) -> bool:
        """False when the drive refused, faulted or never closed the loop (metrics NaN)."""
        return self.info.get("invalid_reason") is None

    def __getattr__(self, name: str) -> np.ndarray:
        data = self.__dict__.get("data", {})
        if name in data:
            return data[name]
        raise AttributeError(name)

    @property
    def position_error_rad(self) -> np.ndarray:
        """Wrapped electrical angle error theta - theta_hat (rad)."""
        return wrap_pi(self.data["theta_e_rad"] - self.data["theta_hat_rad"])


def run_scenario(motor: str | Path | Motor = "paper_salient",
                 extractor: int | str = "sogi_adaptive",
                 speed_ref: ScheduleLike = 100.0, load: ScheduleLike = None,
                 force_ref: ScheduleLike = None, t_end: float = 1.0, seed: int = 0,
                 noise: float = 1.0, record_decimation: int = 1,
                 x0_m: float | str = 0.0, settle_s: float = 0.15,
                 speed_unit: str = "rpm", load_unit: str = "Nm",
                 plant: dict[str, Any] | None = None, fw: dict[str, float] | None = None,
                 channels: Sequence[str] | None = None,
                 metrics: Sequence[str] | None = None) -> Result:
    """Run one closed-loop scenario and return time series and metrics.

    Schedules are a constant, a list of ``(t_s, value)`` breakpoints
    (piecewise constant) or ``{"t_s": [...], "value": [...], "ramp": True}``.

    Parameters
    ----------
    speed_ref : schedule in ``speed_unit`` ("rpm" rotary-equivalent, "mps",
        "radps_e"). Ignored when ``force_ref`` is given (force mode).
    load : external load schedule in ``load_unit`` ("Nm" rotary-equivalent, "N");
        positive opposes positive motion.
    force_ref : thrust schedule in N (force mode, the firmware converts to i_q).
    x0_m : initial true position in m, or "random" (uniform over one electrical
        period 2 tau, drawn from ``seed``).
    channels : what to record (default: everything); the metrics' channels always.
    metrics : which metrics to compute (default: all of :data:`METRIC_NAMES`; unknown
        names are left out). Given without ``channels``, only the channels those metrics
        need are recorded: the lean run of a campaign, with the same numbers.
    """
    mot = motor if isinstance(motor, Motor) else load_motor(motor)
    if x0_m == "random":
        x0 = float(np.random.default_rng([int(seed), 0x5EED]).uniform(0.0, 2.0 * mot.tau_m))
    else:
        x0 = float(x0_m)
    ex_name = Extractor(extractor_id(extractor)).key
    # strict=False: a refused configuration is a result (the drive boots in
    # FAULT), reported in info["invalid_reason"] with the field and its range.
    sim = Sim(mot, extractor=extractor, seed=seed, noise=noise, x0_m=x0, plant=plant, fw=fw,
              strict=False)
    refused = config_error(sim.cfg)
    try:
        sp_scale = {"rpm": mot.rpm_to_radps_e(1.0), "mps": mot.mps_to_radps_e(1.0),
                    "radps_e": 1.0}[speed_unit]
        ld_scale = {"Nm": 1.0 / mot.radius_m, "N": 1.0}[load_unit]
        if force_ref is not None:
            sim.set_schedule(SIM_REF_FORCE, force_ref)
            mode = "force"
        else:
            sim.set_schedule(SIM_REF_SPEED, speed_ref, sp_scale)
            mode = "speed"
        sim.set_schedule(SIM_REF_LOAD, load, ld_scale)
        status = sim.enable(mode)
        n = int(round(t_end / sim.dt_s))
        names = METRIC_NAMES if metrics is None else tuple(
            m for m in metrics if m in METRIC_DEFS)
        if metrics is None:
            need = {*TRUTH_CHANNELS, "fault_code", "start_phase"}
        else:
            need = {"t_s", "fault_code", "start_phase"}.union(
                *(METRIC_DEFS[m].channels for m in names))
        ch = (None if channels is None and metrics is None else
              sorted(set(channels or ()) | need))
        data = sim.advance(n, record_decimation, ch)
        fault = int(sim.firmware.fault_code())
        info = {"statusword_after_enable": status, "x0_m": x0, "dt_s": sim.dt_s,
                "n_steps": n, "snapshot": sim.snapshot(), "mode": mode,
                "fw_init_status": sim.firmware.init_status}
        # No fake tracking: a run in which the drive refused or faulted, or
        # never reached closed loop, has no accuracy figures.
        fc = data["fault_code"]
        reason = None
        if refused is not None:
            reason = f"configuration refused: {refused}"
        elif fault or (fc.size and np.any(fc != 0)):
            reason = f"fault 0x{(fault or int(fc[fc != 0][0])):04X}"
        elif "start_phase" in data and not np.any(data["start_phase"] == StartPhase.RUN):
            reason = "never reached closed loop (start_phase RUN)"
        # the project's metric definitions (sim_fallback.metrics), default windows
        vals, windows = run_metrics(data, mot.tau_m, float(mot.pole_pairs), settle_s,
                                    names=names)
        if reason is not None:
            vals = {k: float("nan") for k in names}
        info["metric_windows_s"] = windows
        info["invalid_reason"] = reason
        return Result(data=data, metrics=vals, motor=mot, extractor=ex_name, seed=seed,
                      settle_s=settle_s, fault_code=fault, info=info)
    finally:
        sim.close()


# ---- the paper's scenarios (method.md section 2) -----------------------------

PAPER_SCENARIOS = ("load_step", "speed_reversal", "startup")
#: Their arguments of :func:`run_scenario`.
PAPER_SCENARIO_ARGS: dict[str, dict[str, Any]] = {
    "load_step": {"speed_ref": 100.0, "load": [(0.0, 0.0), (0.5, 2.0)], "t_end": 1.0},
    "speed_reversal": {"speed_ref": [(0.0, 100.0), (0.5, -100.0)], "t_end": 1.0},
    "startup": {"speed_ref": 100.0, "t_end": 0.5, "x0_m": "random"},
}


def paper_scenario(name: str, extractor: int | str = "sogi_adaptive",
                   motor: str | Path | Motor = "paper_salient", seed: int = 0,
                   **kw: Any) -> Result:
    """load_step: 100 r/min, 2 N m at 0.5 s; speed_reversal: 100 -> -100 r/min at
    0.5 s; startup: 100 r/min from a random initial position (from ``seed``)."""
    if name not in PAPER_SCENARIO_ARGS:
        raise ValueError(f"unknown scenario '{name}'; choose from {PAPER_SCENARIOS}")
    args = dict(PAPER_SCENARIO_ARGS[name])
    args.update(kw)
    return run_scenario(motor=motor, extractor=extractor, seed=seed, **args)


# ---- linear-units scenarios (campaigns on the linear motors) ------------------

LINEAR_SCENARIOS = ("linear_load_step",)


def rated_thrust_N(motor: str | Path | Motor) -> float:
    """The motor's rated thrust K_f i_rated (N): the unsaturated force constant
    (:attr:`Motor.force_const_N_per_A`) times ``[controller] i_rated_A``."""
    m = motor if isinstance(motor, Motor) else load_motor(motor)
    return float(m.force_const_N_per_A * float(m.controller["i_rated_A"]))


def linear_scenario_args(name: str, speed_mps: float, event_s: float, t_end: float,
                         load_N: float = 0.0) -> dict[str, Any]:
    """:func:`run_scenario` arguments of a linear-units scenario. ``linear_load_step``:
    the speed loop holds ``speed_mps`` (m/s) from the enable, an external load of
    ``load_N`` (N, opposing positive motion) steps on at ``event_s``, the run lasts
    ``t_end`` (s)."""
    if name not in LINEAR_SCENARIOS:
        raise ValueError(f"unknown linear scenario '{name}'; choose from {LINEAR_SCENARIOS}")
    return {"speed_ref": float(speed_mps), "speed_unit": "mps",
            "load": [(0.0, 0.0), (float(event_s), float(load_N))], "load_unit": "N",
            "t_end": float(t_end)}


def linear_scenario(name: str, extractor: int | str = "sogi_adaptive",
                    motor: str | Path | Motor = "realistic_linear", seed: int = 0, *,
                    speed_mps: float, event_s: float, t_end: float, load_N: float = 0.0,
                    **kw: Any) -> Result:
    """Run a linear-units scenario (:func:`linear_scenario_args`); ``kw`` as for
    :func:`run_scenario` (``x0_m``, ``plant``, ``fw``, ``metrics``, ...)."""
    args = linear_scenario_args(name, speed_mps, event_s, t_end, load_N)
    args.update(kw)
    return run_scenario(motor=motor, extractor=extractor, seed=seed, **args)
