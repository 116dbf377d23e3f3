"""ctypes binding of ``libpmlsm_sim`` (plant + batch loop + firmware core).

The structures below mirror the firmware's (``fw_types.h``, ``fw_snapshot.h``) and
``pmlsm_sim.h`` field by field;
``tests/python/test_sim_layout.py`` proves every offset and size against the
C compiler's answer (``sim_layout_offsetof`` / ``sim_layout_sizeof``).

Library search order: ``$PMLSM_SIM_LIB``, the package directory (wheel
install), ``$PMLSM_BUILD_DIR/sim_fallback``, then any ``build/*/sim_fallback``
(newest first); the first one whose structure layout matches the mirrors below.
"""

from __future__ import annotations

import ctypes as C
import functools
import os
import struct
from pathlib import Path

from protocols.generated import od_names as _od_names

_f = C.c_float
_d = C.c_double
_u8 = C.c_uint8
_u16 = C.c_uint16
_u32 = C.c_uint32

# ---- firmware structures (fw_types.h, fw_snapshot.h) ----------------------

#: fw_config_t's parts in struct order and every field as (flat name, part, ctypes type)
#: in the order of the firmware's field table (fw_config_field(i)); within a part this
#: is the struct's order. Generated from protocols/od.yaml (fw_config_parts:,
#: fw_config:) like the C structs, so the mirror cannot drift from them. Python keeps the
#: flat names: FwConfig has a property per field (``cfg.R_ohm`` is ``cfg.machine.R_ohm``).
FW_CONFIG_PARTS: tuple[str, ...] = _od_names.FW_CONFIG_PARTS
FW_CONFIG_FIELDS: list[tuple[str, str, type]] = [
    (name, part, (C.c_int32 if name in _od_names.FW_CONFIG_SIGNED else _u32) if is_int else _f)
    for name, part, is_int in _od_names.FW_CONFIG_FIELDS]


@functools.cache
def _unpack_plan(cls: type) -> tuple[tuple[tuple[str, int], ...], struct.Struct]:
    """(name, array length or 0) per field of a ctypes structure of scalars and
    arrays of scalars, and the ``struct`` format that reads them all at their
    offsets (native byte order and sizes, padding explicit)."""
    names, parts, pos = [], ["="], 0
    for name, typ in cls._fields_:
        n = typ._length_ if issubclass(typ, C.Array) else 0
        elem = typ._type_ if n else typ
        if struct.calcsize("=" + elem._type_) != C.sizeof(elem):
            raise TypeError(f"{cls.__name__}.{name}: no fixed-size struct code")
        off = getattr(cls, name).offset
        parts.append(f"{off - pos}x{max(n, 1)}{elem._type_}")
        pos = off + C.sizeof(typ)
        names.append((name, n))
    parts.append(f"{C.sizeof(cls) - pos}x")
    return tuple(names), struct.Struct("".join(parts))


def _config_part(part: str) -> type[C.Structure]:
    fields = [(n, t) for n, p, t in FW_CONFIG_FIELDS if p == part]
    return type(f"FwCfg{part.capitalize()}", (C.Structure,),
                {"_fields_": fields, "__doc__": f"Mirror of ``fw_cfg_{part}_t``."})


#: part name -> mirror of fw_cfg_<part>_t
FW_CONFIG_PART_TYPES: dict[str, type[C.Structure]] = {p: _config_part(p) for p in FW_CONFIG_PARTS}


def _config_leaf(part: str, name: str) -> property:
    def get(self):
        return getattr(getattr(self, part), name)

    def put(self, value):
        setattr(getattr(self, part), name, value)

    return property(get, put, doc=f"``fw_config_t.{part}.{name}``")


class FwConfig(C.Structure):
    """Mirror of ``fw_config_t`` (nested in parts like the C struct); every field is
    also an attribute under its flat name (``cfg.R_ohm`` = ``cfg.machine.R_ohm``)."""

    _fields_ = [(p, FW_CONFIG_PART_TYPES[p]) for p in FW_CONFIG_PARTS]

    def as_dict(self) -> dict[str, float | int]:
        """Every field by flat name, in field-table order."""
        parts = {p: getattr(self, p) for p in FW_CONFIG_PARTS}
        return {name: getattr(parts[p], name) for name, p, _ in FW_CONFIG_FIELDS}

    @classmethod
    def field_names(cls) -> frozenset[str]:
        return frozenset(name for name, _, _ in FW_CONFIG_FIELDS)

    @classmethod
    def leaves(cls) -> dict[str, tuple[str, int, type]]:
        """Flat name -> (C path ``part.name``, byte offset in fw_config_t, ctypes type),
        in field-table order."""
        return {name: (f"{p}.{name}",
                       getattr(cls, p).offset + getattr(FW_CONFIG_PART_TYPES[p], name).offset, t)
                for name, p, t in FW_CONFIG_FIELDS}


for _name, _part, _ in FW_CONFIG_FIELDS:
    setattr(FwConfig, _name, _config_leaf(_part, _name))
del _name, _part


class FwInputs(C.Structure):
    """Mirror of ``fw_inputs_t`` (phase currents A, DC link V)."""

    _fields_ = [("i_abc_A", _f * 3), ("u_dc_V", _f)]


class FwAdcInputs(C.Structure):
    """Mirror of ``fw_adc_inputs_t`` (raw counts)."""

    _fields_ = [("i_abc_counts", _u16 * 3), ("u_dc_counts", _u16)]


class FwOutputs(C.Structure):
    """Mirror of ``fw_outputs_t`` (duties 0..1, latched next period)."""

    _fields_ = [("duty_abc", _f * 3), ("pwm_enable", _u8)]


class FwSnapshot(C.Structure):
    """Mirror of ``fw_snapshot_t``."""

    _fields_ = [
        ("step_count", _u32), ("statusword", _u16), ("cia402_state", _u8),
        ("start_phase", _u8), ("extractor", _u8), ("mode", _u8),
        ("polarity_flipped", _u8), ("fault_code", _u16),
        ("theta_hat_rad", _f), ("omega_hat_radps", _f), ("omega_f_radps", _f),
        ("pos_hat_m", _f), ("speed_hat_mps", _f), ("pos_hat_mech_rad", _f),
        ("speed_hat_rpm", _f), ("pll_err_rad", _f), ("pll_err_f_rad", _f),
        ("accel_dist_radps2", _f),
        ("hf_amp_A", _f), ("hf_q_A", _f), ("sogi_k_eff", _f), ("pol_dI_pos_A", _f),
        ("pol_dI_neg_A", _f), ("i_dq_A", _f * 2), ("i_dq_ref_A", _f * 2),
        ("u_dq_V", _f * 2), ("u_inj_V", _f), ("i_ab_A", _f * 2), ("i_h_ab_A", _f * 2),
        ("speed_ref_radps_e", _f), ("force_hat_N", _f), ("torque_hat_Nm", _f),
        ("u_dc_V", _f), ("duty_abc", _f * 3),
        ("mon_angle_hf_rad", _f), ("mon_angle_bemf_rad", _f), ("mon_e_bemf_V", _f),
        ("mon_i_sum_A", _f), ("sal_meas", _f), ("L_small_meas_H", _f), ("L_large_meas_H", _f),
        ("bemf_err_rad", _f), ("inj_scale", _f), ("bemf_active", _u8), ("flying_start", _u8),
        ("ref_limited", _u8), ("ref_pos_m", _f),
    ]

    def as_dict(self) -> dict:
        """Every field by name (arrays as lists): the values ``getattr`` gives, read in
        one ``struct.unpack_from`` (a snapshot per run or per SYNC; ~70 getattr took
        19 us)."""
        names, fmt = _unpack_plan(type(self))
        vals = fmt.unpack_from(self)
        out = {}
        i = 0
        for name, n in names:
            if n:
                out[name] = list(vals[i:i + n])
                i += n
            else:
                out[name] = vals[i]
                i += 1
        return out


# ---- simulator structures (pmlsm_sim.h) ----------------------------------


class SimPlantParams(C.Structure):
    """Mirror of ``sim_plant_params_t`` (linear units)."""

    _fields_ = [
        ("R_ohm", _d), ("L_d0_H", _d), ("L_q_H", _d), ("psi_f_Wb", _d),
        ("dL_sat_H", _d), ("I_sat_A", _d), ("tau_m", _d), ("mass_kg", _d),
        ("b_visc_Ns_per_m", _d), ("F_coulomb_N", _d), ("F_static_N", _d),
        ("v_stick_mps", _d), ("cog_amp_N", _d), ("cog_period_m", _d),
        ("cog_phase_rad", _d), ("locked", C.c_int32), ("u_dc_V", _d), ("f_pwm_Hz", _d),
        ("dead_time_s", _d), ("dead_band_A", _d), ("n_sub", _u32), ("adc_bits", _u32),
        ("adc_i_fullscale_A", _d), ("adc_noise_counts", _d),
        ("adc_offset_counts", _d * 3), ("adc_gain_err", _d * 3),
        ("udc_fullscale_V", _d), ("udc_noise_V", _d), ("seed", C.c_uint64),
        ("open_phase_mask", _u32), ("adc_stuck_mask", _u32),
        ("ref_res_m", _d), ("ref_offset_m", _d), ("ref_fault", _u32), ("noise_restart", _u32),
    ]


#: ``sim_realism_t`` fields (plant realism, docs/simulator.md), every one 0 = off.
REALISM_FIELDS: tuple[str, ...] = (
    "dLq_sat_H", "Iq_sat_A", "cross_L_H", "cross_I_A", "sal2_L_H", "sal2_order",
    "sal2_phase_rad", "emf_h5", "emf_h5_phase_rad", "emf_h7", "emf_h7_phase_rad",
    "end_dL_H", "end_psi_frac", "end_base", "end_travel_m", "end_zone_m",
    "dt_C_eq_F", "u_dev_V", "r_dev_ohm")


class SimRealism(C.Structure):
    """Mirror of ``sim_realism_t`` (plant realism; all 0 = off)."""

    _fields_ = [(n, _u32 if n == "sal2_order" else _d) for n in REALISM_FIELDS[:6]] + [
        ("pad_real_", _u32)] + [(n, _d) for n in REALISM_FIELDS[6:]]


class SimMagnetics(C.Structure):
    """Mirror of ``sim_magnetics_t`` (sim_plant_magnetics: flux, incremental inductance,
    speed voltage per velocity, thrust at one operating point)."""

    _fields_ = [("psi_dq_Wb", _d * 2), ("L_dq_H", _d * 3), ("e_dq_V_per_mps", _d * 2),
                ("force_N", _d)]


class SimPlantState(C.Structure):
    """Mirror of ``sim_plant_state_t`` (truth)."""

    _fields_ = [("i_d_A", _d), ("i_q_A", _d), ("x_m", _d), ("v_mps", _d),
                ("stuck", C.c_int32), ("pad_", C.c_int32)]


class SimSched(C.Structure):
    """Mirror of ``sim_sched_t``."""

    _fields_ = [("t_s", C.POINTER(_d)), ("value", C.POINTER(_d)), ("n", _u32),
                ("ramp", _u32)]


STEP_FN = C.CFUNCTYPE(None, C.c_void_p, C.POINTER(FwInputs), C.POINTER(FwOutputs))
STEP_ADC_FN = C.CFUNCTYPE(None, C.c_void_p, C.POINTER(FwAdcInputs), C.POINTER(FwOutputs))
SNAP_FN = C.CFUNCTYPE(None, C.c_void_p, C.POINTER(FwSnapshot))
SETREF_FN = C.CFUNCTYPE(None, C.c_void_p, C.c_int, _d)


class SimController(C.Structure):
    """Mirror of ``sim_controller_t`` (function pointers kept opaque)."""

    _fields_ = [("ctx", C.c_void_p), ("step", C.c_void_p), ("step_adc", C.c_void_p),
                ("snapshot", C.c_void_p), ("set_ref", C.c_void_p),
                ("background", C.c_void_p), ("background_every", C.c_uint32),
                ("sample_ref", C.c_void_p)]


_PD = C.POINTER(_d)
# (name, ctypes pointer type, numpy dtype, columns)
RECORD_CHANNELS: list[tuple[str, type, str, int]] = [
    ("t_s", _PD, "f8", 1), ("theta_e_rad", _PD, "f8", 1), ("omega_e_radps", _PD, "f8", 1),
    ("x_m", _PD, "f8", 1), ("v_mps", _PD, "f8", 1), ("force_N", _PD, "f8", 1),
    ("load_N", _PD, "f8", 1), ("i_d_A", _PD, "f8", 1), ("i_q_A", _PD, "f8", 1),
    ("i_abc_meas_A", _PD, "f8", 3), ("u_dc_meas_V", _PD, "f8", 1),
    ("theta_hat_rad", _PD, "f8", 1), ("omega_hat_radps", _PD, "f8", 1),
    ("omega_f_radps", _PD, "f8", 1),
    ("pll_err_rad", _PD, "f8", 1), ("hf_amp_A", _PD, "f8", 1), ("sogi_k_eff", _PD, "f8", 1),
    ("i_dq_hat_A", _PD, "f8", 2), ("duty_abc", _PD, "f8", 3),
    ("speed_ref_radps_e", _PD, "f8", 1), ("cia402_state", C.POINTER(_u8), "u1", 1),
    ("start_phase", C.POINTER(_u8), "u1", 1), ("fault_code", C.POINTER(_u16), "u2", 1),
]


class SimRecord(C.Structure):
    """Mirror of ``sim_record_t`` (NULL pointer = channel not recorded)."""

    _fields_ = [(n, t) for n, t, _, _ in RECORD_CHANNELS] + [("capacity", _u32),
                                                             ("pad_", _u32)]


class SimCtrlConst(C.Structure):
    """Mirror of ``sim_ctrl_const_t`` (fixed-duty test controller)."""

    _fields_ = [("duty_abc", _f * 3), ("pwm_enable", _u8), ("calls", _u32)]


class FwCanFrame(C.Structure):
    """Mirror of ``fw_can_frame_t`` (fw_port.h): a frame through the drive's port."""

    _fields_ = [("id", _u16), ("dlc", _u8), ("rtr", _u8), ("data", _u8 * 8)]


MIRRORS: dict[str, type[C.Structure]] = {
    "fw_config_t": FwConfig, "fw_inputs_t": FwInputs, "fw_adc_inputs_t": FwAdcInputs,
    "fw_outputs_t": FwOutputs, "fw_snapshot_t": FwSnapshot,
    "sim_plant_params_t": SimPlantParams, "sim_plant_state_t": SimPlantState,
    "sim_sched_t": SimSched, "sim_controller_t": SimController,
    "sim_record_t": SimRecord, "sim_ctrl_const_t": SimCtrlConst,
    "fw_can_frame_t": FwCanFrame,
    "sim_realism_t": SimRealism, "sim_magnetics_t": SimMagnetics,
}


class FwConfigIssue(C.Structure):
    """Mirror of ``fw_config_issue_t``."""

    _fields_ = [("status", C.c_int), ("field", C.c_char_p), ("value", _f),
                ("min", _f), ("max", _f)]


class FwConfigField(C.Structure):
    """Mirror of ``fw_config_field_t``."""

    _fields_ = [("name", C.c_char_p), ("unit", C.c_char_p), ("offset", C.c_size_t),
                ("is_int", _u8), ("is_signed", _u8), ("min", _f), ("max", _f)]


# ---- loading -------------------------------------------------------------

_LIBNAME = "libpmlsm_sim.so"


def _candidates() -> list[tuple[Path, bool]]:
    """(path, explicit) in search order; explicit = named by the user (environment)."""
    here = Path(__file__).resolve().parent
    out: list[tuple[Path, bool]] = []
    env = os.environ.get("PMLSM_SIM_LIB")
    if env:
        out.append((Path(env), True))
    out.append((here / _LIBNAME, False))
    if os.environ.get("PMLSM_BUILD_DIR"):
        out.append((Path(os.environ["PMLSM_BUILD_DIR"]) / "sim_fallback" / _LIBNAME, True))
    root = here.parent
    out += [(p, False) for p in sorted((root / "build").glob(f"*/sim_fallback/{_LIBNAME}"),
                                       key=lambda p: -p.stat().st_mtime)]
    return out


def _mismatch(lib: C.CDLL) -> str | None:
    """Why ``lib`` was not built from this checkout's sources, or None: every mirrored
    structure's size and the configuration field count must be what the mirrors here
    say (a library left in a build directory from an older checkout would otherwise be
    fed structures of another layout, silently)."""
    for name, mirror in MIRRORS.items():
        n = int(lib.sim_layout_sizeof(name.encode()))
        if n != C.sizeof(mirror):
            return f"{name} is {n} B there, {C.sizeof(mirror)} B in this checkout"
    n = int(lib.fw_config_field_count())
    if n != len(FW_CONFIG_FIELDS):
        return f"{n} configuration fields there, {len(FW_CONFIG_FIELDS)} in this checkout"
    return None


def _declare(lib: C.CDLL) -> None:
    P, V = C.POINTER, C.c_void_p
    sig = {
        "sim_params_check": (C.c_int, [P(SimPlantParams), P(C.c_char_p)]),
        "sim_new": (V, [P(SimPlantParams)]),
        "sim_set_params": (C.c_int, [V, P(SimPlantParams), P(C.c_char_p)]),
        "sim_free": (None, [V]),
        "sim_set_controller": (None, [V, P(SimController)]),
        "sim_set_use_adc_counts": (None, [V, C.c_int]),
        "sim_set_schedule": (C.c_int, [V, C.c_int, P(_d), P(_d), _u32, _u32]),
        "sim_set_state": (None, [V, P(SimPlantState)]),
        "sim_get_state": (None, [V, P(SimPlantState)]),
        "sim_set_latched_duty": (None, [V, P(_d), C.c_int]),
        "sim_time_s": (_d, [V]),
        "sim_step_count": (C.c_uint64, [V]),
        "sim_sched_value": (_d, [V, C.c_int]),
        "sim_run": (C.c_int64, [V, C.c_uint64, _u32, P(SimRecord)]),
        "sim_boot": (C.c_int64, [V, C.c_uint64, C.c_int]),
        "sim_plant_advance": (None, [V, P(_d), C.c_int, _d, _u32]),
        "sim_sample": (None, [V, P(FwInputs), P(FwAdcInputs)]),
        "sim_force_N": (_d, [V]),
        "sim_realism_check": (C.c_int, [P(SimPlantParams), P(SimRealism), P(C.c_char_p)]),
        "sim_set_realism": (C.c_int, [V, P(SimRealism), P(C.c_char_p)]),
        "sim_plant_magnetics": (None, [V, _d, _d, _d, P(SimMagnetics)]),
        "sim_ctrl_const_port": (None, [P(SimCtrlConst), P(SimController)]),
        "sim_fw_port": (None, [V, P(SimController)]),
        "sim_fw_new": (V, []),
        "sim_fw_free": (None, [V]),
        "sim_layout_sizeof": (C.c_size_t, [C.c_char_p]),
        "sim_layout_offsetof": (C.c_int64, [C.c_char_p, C.c_char_p]),
        # firmware core (whole archive linked into the sim library)
        "fw_config_default": (None, [P(FwConfig)]),
        "fw_config_check": (C.c_int, [P(FwConfig), P(FwConfigIssue)]),
        "fw_config_derive": (None, [P(FwConfig)]),
        "fw_config_field_count": (C.c_size_t, []),
        "fw_config_field": (P(FwConfigField), [C.c_size_t]),
        "fw_init": (C.c_int, [V, P(FwConfig)]),
        "fw_set_config": (C.c_int, [V, P(FwConfig), P(FwConfigIssue)]),
        "fw_controlword": (_u16, [V, _u16]),
        "fw_statusword": (_u16, [V]),
        "fw_state": (C.c_int, [V]),
        "fw_set_mode": (C.c_int, [V, C.c_int]),
        "fw_set_speed_ref": (C.c_int, [V, _f]),
        "fw_set_iq_ref": (C.c_int, [V, _f]),
        "fw_set_id_ref": (C.c_int, [V, _f]),
        "fw_set_force_ref": (C.c_int, [V, _f]),
        "fw_units_mps_to_radps_e": (_f, [P(FwConfig), _f]),
        "fw_units_radps_e_to_mps": (_f, [P(FwConfig), _f]),
        "fw_units_rpm_to_radps_e": (_f, [P(FwConfig), _f]),
        "fw_units_force_per_A": (_f, [P(FwConfig)]),
        "fw_units_bemf_V": (_f, [P(FwConfig), _f]),
        "fw_set_extractor": (C.c_int, [V, C.c_int]),
        "fw_fault_code": (C.c_int, [V]),
        "fw_raise_fault": (None, [V, C.c_int]),
        "fw_step": (None, [V, P(FwInputs), P(FwOutputs)]),
        "fw_step_adc": (None, [V, P(FwAdcInputs), P(FwOutputs)]),
        "fw_current_zero_counts": (C.c_float, [V, C.c_uint]),
        "fw_current_zero_external": (None, [V]),
        "fw_adc_convert": (C.c_bool, [P(FwConfig), P(_f * 3), P(FwAdcInputs), P(FwInputs)]),
        "fw_get_snapshot": (None, [V, P(FwSnapshot)]),
        "fw_ctrl_sizeof": (C.c_size_t, []),
        # the whole drive application behind the simulator's port (sim_port.c)
        "sim_app_new": (V, [P(FwConfig), _u8, C.c_char_p, P(C.c_int)]),
        "sim_app_free": (None, [V]),
        "sim_app_controller": (None, [V, _u32, P(SimController)]),
        "sim_app_can_rx": (C.c_bool, [V, P(FwCanFrame)]),
        "sim_app_can_pop": (C.c_bool, [V, P(FwCanFrame)]),
        "sim_app_uart_read": (C.c_size_t, [V, C.c_char_p, C.c_size_t]),
        "sim_app_background_now": (None, [V]),
        "sim_app_fw_app": (V, [V]),
        "sim_app_config": (None, [V, P(FwConfig)]),
        "sim_app_nvm_state": (C.c_int, [V]),
        "sim_app_crit_unbalanced": (_u32, [V]),
    }
    for name, (res, args) in sig.items():
        fn = getattr(lib, name)
        fn.restype = res
        fn.argtypes = args


_LIB: C.CDLL | None = None


def lib() -> C.CDLL:
    """Load (once) and return the simulator library: the first candidate built from
    these sources. A stale one named by $PMLSM_SIM_LIB or $PMLSM_BUILD_DIR is an error;
    a stale one found under build/ is passed over (both say why)."""
    global _LIB
    if _LIB is None:
        tried = []
        for path, explicit in _candidates():
            if not path.is_file():
                tried.append(f"{path} (missing)")
                continue
            cand = C.CDLL(str(path))
            try:
                _declare(cand)
                why = _mismatch(cand)
            except AttributeError as e:  # a symbol this checkout needs is not there
                why = f"no {str(e).split(':')[-1].strip()}"
            if why is None:
                _LIB = cand
                break
            if explicit:
                raise OSError(f"{path}: built from other sources ({why}); rebuild it "
                              "(cmake --build <build dir>) or unset PMLSM_SIM_LIB/PMLSM_BUILD_DIR")
            tried.append(f"{path} (stale: {why})")
        else:
            raise OSError(
                "libpmlsm_sim.so not found; build it with `cmake -S . -B build/sim -G Ninja "
                "&& cmake --build build/sim --target pmlsm_sim` or set PMLSM_SIM_LIB. Tried: "
                + ", ".join(tried))
    return _LIB


_COMM: C.CDLL | None = None


def comm_lib() -> C.CDLL:
    """Load (once) the drive application alone, without a plant (``libpmlsm_comm``: the
    core, the CANopen node and the serial link, ``fw_app_*``; enough for NMT, SDO, PDO,
    heartbeat and EMCY against zero currents), declared with this module's mirrors."""
    global _COMM
    if _COMM is None:
        from protocols.clib import load_app

        cand = load_app()
        P, V = C.POINTER, C.c_void_p
        for name, (res, args) in {
            "fw_app_sizeof": (C.c_size_t, []),
            "fw_app_init": (C.c_int, [V, P(FwConfig), _u8]),
            "fw_app_can_rx": (C.c_bool, [V, P(FwCanFrame)]),
            "fw_app_can_tx_pop": (C.c_bool, [V, P(FwCanFrame)]),
            "fw_app_step": (None, [V, P(FwInputs), P(FwOutputs)]),
            "fw_app_uart_read": (C.c_size_t, [V, C.c_char_p, C.c_size_t]),
            "fw_config_default": (None, [P(FwConfig)]),
        }.items():
            fn = getattr(cand, name)
            fn.restype = res
            fn.argtypes = args
        _COMM = cand
    return _COMM


def lib_path() -> str:
    """Path of the loaded library."""
    return lib()._name  # type: ignore[attr-defined]
