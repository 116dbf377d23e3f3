"""Motor files (TOML): loading, validation, linear conversion, fw_config_t.

A motor file has the sections ``[motor]``, ``[electrical]``,
``[mechanical]`` and optional ``[inverter]``, ``[sensing]``, ``[controller]``.
``[mechanical]`` is either rotary-equivalent (``parameterization =
"rotary"``: pole_pairs, pole_pitch_m, inertia_kgm2, N·m friction) or linear
(mass_kg, N friction). Rotary sets are converted on load with the
equivalent radius r = p tau / pi (theta_e = p theta_m = pi x / tau):
m = J / r^2, F = T / r, b_lin = b_rot / r^2.

Every error names the file, the field and the allowed range.
"""

from __future__ import annotations

import ctypes as C
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

try:
    import tomllib
except ImportError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

from protocols import units as U
from protocols.generated.od_names import Extractor

from . import _lib

MOTOR_DIR = Path(__file__).resolve().parent / "motors"


class MotorFileError(ValueError):
    """A motor file is missing a field, has an unknown one or a value out of range.

    ``str()`` is one line: ``file:line: field: message``.

    Attributes
    ----------
    path : Path
        The motor file.
    field : str
        ``section.key`` of the offending field ("" for the whole file).
    line : int
        1-based line of the field in the file (0 if it is not written there).
    message : str
        What is wrong, with the allowed range.
    """

    def __init__(self, path: Path, field: str, message: str, line: int = 0) -> None:
        self.path, self.field, self.line, self.message = Path(path), field, line, message
        where = f"{path}:{line}" if line else str(path)
        super().__init__(f"{where}: {field or '<file>'}: {message}")


class MotorFileErrors(MotorFileError):
    """Several problems in one motor file, all reported at once (as a sequence's are):
    ``str()`` is one line per problem, ``errors`` the single errors. The first problem's
    ``field``, ``line`` and ``message`` are this error's."""

    def __init__(self, errors: list[MotorFileError]) -> None:
        first = errors[0]
        super().__init__(first.path, first.field, first.message, first.line)
        self.errors = errors
        self.args = ("\n".join(str(e) for e in errors),)

    def __str__(self) -> str:
        return str(self.args[0])


_FW_NAMES = {"R_ohm", "L_d_H", "L_q_H", "psi_f_Wb", "pole_pitch_m", "pole_pairs", "f_pwm_Hz",
             "i_max_A", "i_rated_A", "i_trip_A", "u_inj_V", "f_inj_Hz", "bemf_v_on_mps",
             "bemf_v_off_mps", "mon_bemf_min_mps", "dt_comp_s", "dt_comp_band_A",
             "dt_comp_drop_V", "xsat_di_A", *(f"xsat_off{k}_rad" for k in range(1, 7)),
             "sogi_bumpless", "rip_a2_rad", "rip_b2_rad", "rip_a4_rad", "rip_b4_rad",
             "rip6_a0_N", "rip6_b0_N", "rip6_a1_N_per_A", "rip6_b1_N_per_A",
             "bemf_xc_comp", "mon_bemf_i_tol", "bemf_obs_bw"}


def firmware_field_ranges() -> dict[str, tuple[float, float, str]]:
    """The firmware's own configuration table (``fw_config_field()``).

    Returns
    -------
    dict
        fw_config field name -> (min, max, unit), inclusive; empty when the
        simulator library is not available.
    """
    global _FW_RANGES
    if _FW_RANGES is None:
        try:
            L = _lib.lib()
        except OSError:
            return {}
        out = {}
        for i in range(int(L.fw_config_field_count())):
            f = L.fw_config_field(i).contents
            # float32 in C: 7 significant digits give back the written limit (1e-3, not
            # 0.0010000000474974513)
            out[f.name.decode()] = (float(f"{f.min:.7g}"), float(f"{f.max:.7g}"),
                                    f.unit.decode())
        _FW_RANGES = out
    return _FW_RANGES


_FW_RANGES: dict[str, tuple[float, float, str]] | None = None

#: fw_status_t values (firmware_c/include/pmlsm/fw_ctrl.h).
FW_STATUS = {0: "FW_OK", 1: "FW_ERR_NULL", 2: "FW_ERR_RANGE", 3: "FW_ERR_NOT_FINITE",
             4: "FW_ERR_SALIENCY", 5: "FW_ERR_INCONSISTENT", 6: "FW_ERR_STATE"}


def firmware_check(cfg: _lib.FwConfig) -> tuple[int, str]:
    """Run the firmware's ``fw_config_check`` on a configuration.

    Parameters
    ----------
    cfg : FwConfig
        A ``fw_config_t`` mirror (e.g. from :func:`fw_config`).

    Returns
    -------
    status : int
        ``fw_status_t`` (0 = accepted, 4 = saliency too low for injection).
    message : str
        "" when accepted, else which field is refused, its value and range.
    """
    L = _lib.lib()
    issue = _lib.FwConfigIssue()
    st = int(L.fw_config_check(cfg, C.byref(issue)))
    if st == 0:
        return 0, ""
    name = issue.field.decode() if issue.field else "?"
    what = FW_STATUS.get(st, f"fw_status_t {st}")
    if st == 4:
        return st, (f"saliency (L_q - L_d)/L_d = {(cfg.L_q_H - cfg.L_d_H) / cfg.L_d_H:.3g} is "
                    f"below the firmware's saliency_min {cfg.saliency_min:g}: the drive "
                    "refuses HF injection (fault 0xFF03 SALIENCY_TOO_LOW)")
    if st == 5:
        unit = firmware_field_ranges().get(name, (0.0, 0.0, ""))[2]
        return st, (f"{name} = {issue.value:g} is inconsistent with the other fields "
                    f"({what}): allowed [{issue.min:.7g}, {issue.max:.7g}]"
                    + (f" {unit}" if unit else "") + " given them")
    unit = firmware_field_ranges().get(name, (0.0, 0.0, ""))[2]
    return st, f"{name} = {issue.value:g} refused ({what}); allowed range [{issue.min:g}, " \
               f"{issue.max:g}]" + (f" {unit}" if unit else "")


# (section, key) -> (required, lo, hi, unit, default); lists are checked per element. lo, hi
# None: a field the firmware configuration shares, whose range is the firmware's (field_range).
_SCHEMA: dict[tuple[str, str], tuple[bool, float | None, float | None, str, Any]] = {
    ("electrical", "R_ohm"): (True, None, None, "ohm", None),
    ("electrical", "L_d_H"): (True, None, None, "H", None),
    ("electrical", "L_q_H"): (True, None, None, "H", None),
    ("electrical", "psi_f_Wb"): (True, None, None, "Wb", None),
    ("electrical", "dL_sat_H"): (False, 0.0, 0.5, "H (< L_d_H)", 0.0),
    ("electrical", "I_sat_A"): (False, 0.01, 1000.0, "A", 5.0),
    # plant realism (docs/simulator.md "Plant realism"), 0 = off: q-axis saturation,
    # cross-saturation, a secondary spatial saliency, back-EMF harmonics
    ("electrical", "dLq_sat_H"): (False, 0.0, 0.5, "H (< L_q_H)", 0.0),
    ("electrical", "Iq_sat_A"): (False, 0.0, 1000.0, "A (> 0 with dLq_sat_H)", 0.0),
    ("electrical", "cross_L_H"): (False, 0.0, 0.5, "H", 0.0),
    ("electrical", "cross_I_A"): (False, 0.0, 1000.0, "A (> 0 with cross_L_H)", 0.0),
    ("electrical", "saliency2_L_H"): (False, 0.0, 0.5, "H", 0.0),
    ("electrical", "saliency2_order"): (False, 1, 12, "(integer)", 4),
    ("electrical", "saliency2_phase_rad"): (False, -10.0, 10.0, "rad", 0.0),
    ("electrical", "emf_h5"): (False, 0.0, 0.5, "(of the fundamental)", 0.0),
    ("electrical", "emf_h5_phase_rad"): (False, -10.0, 10.0, "rad", 0.0),
    ("electrical", "emf_h7"): (False, 0.0, 0.5, "(of the fundamental)", 0.0),
    ("electrical", "emf_h7_phase_rad"): (False, -10.0, 10.0, "rad", 0.0),
    # end effect of the linear machine (outer phases a and c), 0 = off
    ("end_effect", "dL_H"): (False, 0.0, 0.5, "H", 0.0),
    ("end_effect", "psi_frac"): (False, 0.0, 0.9, "", 0.0),
    ("end_effect", "base"): (False, 0.0, 1.0, "", 0.0),
    ("end_effect", "travel_m"): (False, 0.0, 100.0, "m (0: no stator ends)", 0.0),
    ("end_effect", "zone_m"): (False, 0.0, 10.0, "m (> 0 with travel_m)", 0.0),
    # mechanical, both parameterizations
    ("mechanical", "pole_pitch_m"): (True, None, None, "m", None),
    ("mechanical", "pole_pairs"): (False, None, None, "", None),
    # rotary
    ("mechanical", "inertia_kgm2"): (False, 1e-7, 1e3, "kg m^2", None),
    ("mechanical", "viscous_Nms_per_rad"): (False, 0.0, 1e3, "N m s/rad", 0.0),
    ("mechanical", "static_friction_Nm"): (False, 0.0, 1e4, "N m", 0.0),
    ("mechanical", "coulomb_friction_Nm"): (False, 0.0, 1e4, "N m", None),
    ("mechanical", "cogging_Nm"): (False, 0.0, 1e4, "N m", 0.0),
    # linear
    ("mechanical", "mass_kg"): (False, 1e-3, 1e5, "kg", None),
    ("mechanical", "viscous_Ns_per_m"): (False, 0.0, 1e6, "N s/m", 0.0),
    ("mechanical", "static_friction_N"): (False, 0.0, 1e6, "N", 0.0),
    ("mechanical", "coulomb_friction_N"): (False, 0.0, 1e6, "N", None),
    ("mechanical", "cogging_N"): (False, 0.0, 1e6, "N", 0.0),
    # both
    ("mechanical", "cogging_period_m"): (False, 1e-5, 1.0, "m", None),
    ("mechanical", "cogging_phase_rad"): (False, -10.0, 10.0, "rad", 0.0),
    # inverter
    ("inverter", "u_dc_V"): (False, 10.0, 1000.0, "V", 300.0),
    ("inverter", "f_pwm_Hz"): (False, None, None, "Hz", 24000.0),
    ("inverter", "dead_time_s"): (False, 0.0, 5e-6, "s", 0.0),
    ("inverter", "dead_band_A"): (False, 0.0, 10.0, "A", 0.05),
    ("inverter", "n_sub"): (False, 1, 1024, "", 1),
    # inverter nonlinearity (plant realism), 0 = off
    ("inverter", "dead_time_C_F"): (False, 0.0, 1e-7, "F", 0.0),
    ("inverter", "device_drop_V"): (False, 0.0, 10.0, "V", 0.0),
    ("inverter", "device_r_ohm"): (False, 0.0, 10.0, "ohm", 0.0),
    # sensing
    ("sensing", "adc_bits"): (False, 8, 16, "bit", 12),
    ("sensing", "adc_i_fullscale_A"): (False, 0.1, 1000.0, "A", 25.0),
    ("sensing", "adc_noise_counts"): (False, 0.0, 100.0, "counts", 1.0),
    ("sensing", "adc_offset_counts"): (False, -200.0, 200.0, "counts", [1.0, -1.0, 0.5]),
    ("sensing", "adc_gain_err"): (False, -0.2, 0.2, "", [0.0, 0.0, 0.0]),
    ("sensing", "udc_fullscale_V"): (False, 10.0, 2000.0, "V", 500.0),
    ("sensing", "udc_noise_V"): (False, 0.0, 50.0, "V", 0.5),
    # controller (gains are derived; these tune the derivation and limits)
    ("controller", "speed_bw_radps"): (False, 1.0, 1000.0, "rad/s", 35.0),
    ("controller", "i_max_A"): (False, None, None, "A", 20.0),
    ("controller", "i_rated_A"): (False, None, None, "A", 10.0),
    ("controller", "i_trip_A"): (False, None, None, "A", 24.0),
    ("controller", "u_inj_V"): (False, None, None, "V", 50.0),
    ("controller", "f_inj_Hz"): (False, None, None, "Hz", 3000.0),
    # back-EMF handover and witness speeds (docs/bemf.md); not given: the firmware default
    ("controller", "bemf_v_on_mps"): (False, None, None, "m/s", None),
    ("controller", "bemf_v_off_mps"): (False, None, None, "m/s", None),
    ("controller", "mon_bemf_min_mps"): (False, None, None, "m/s", None),
    # the drive's compensations (docs/method.md section 6; not given: off): what the drive
    # is told about its inverter and what identification measured, never the plant's own
    # [inverter] / [electrical] fields, which are the simulated truth
    ("controller", "dt_comp_s"): (False, None, None, "s", None),
    ("controller", "dt_comp_band_A"): (False, None, None, "A", None),
    ("controller", "dt_comp_drop_V"): (False, None, None, "V", None),
    ("controller", "xsat_di_A"): (False, None, None, "A", None),
    **{("controller", f"xsat_off{k}_rad"): (False, None, None, "rad", None)
       for k in range(1, 7)},
    ("controller", "sogi_bumpless"): (False, None, None, "0/1", None),
    **{("controller", f"rip_{c}{n}_rad"): (False, None, None, "rad", None)
       for n in (2, 4) for c in "ab"},
    # the thrust ripple at 6 theta_e in the observer's model (fw_obs.h): cogging (N) and
    # the back-EMF harmonics' thrust ripple per A of i_q, from a datasheet or a test
    **{("controller", f"rip6_{c}0_N"): (False, None, None, "N", None) for c in "ab"},
    **{("controller", f"rip6_{c}1_N_per_A"): (False, None, None, "N/A", None) for c in "ab"},
    ("controller", "bemf_xc_comp"): (False, None, None, "0/1", None),
    ("controller", "mon_bemf_i_tol"): (False, None, None, "", None),
    ("controller", "bemf_obs_bw"): (False, None, None, "", None),
    # the rig's reference position sensor (a quadrature scale), modelled as the true
    # position quantised to its resolution; 0 = no sensor fitted
    ("reference_sensor", "resolution_m"): (False, 0.0, 0.01, "m (0: none)", 1e-6),
    ("reference_sensor", "offset_m"): (False, -1000.0, 1000.0, "m", 0.0),
}
#: ``[controller]`` keys that are fw_config_t fields of the same name, set as given (the
#: back-EMF speeds only when the file gives them: else the firmware's defaults).
_CTRL_FW_FIELDS = ("i_max_A", "i_rated_A", "i_trip_A", "u_inj_V", "f_inj_Hz",
                   "bemf_v_on_mps", "bemf_v_off_mps", "mon_bemf_min_mps",
                   "dt_comp_s", "dt_comp_band_A", "dt_comp_drop_V", "xsat_di_A",
                   *(f"xsat_off{k}_rad" for k in range(1, 7)), "sogi_bumpless",
                   "rip_a2_rad", "rip_b2_rad", "rip_a4_rad", "rip_b4_rad",
                   "rip6_a0_N", "rip6_b0_N", "rip6_a1_N_per_A", "rip6_b1_N_per_A",
                   "bemf_xc_comp", "mon_bemf_i_tol", "bemf_obs_bw")
#: the compensation keys of ``[controller]`` (docs/method.md section 6); the back-EMF
#: observer's saliency term and bandwidth and the witness's current tolerance are not
#: compensations
COMPENSATION_KEYS = _CTRL_FW_FIELDS[8:-3]
_TEXT_FIELDS = {("motor", "name"), ("motor", "description"), ("motor", "parameterization")}


@dataclass
class Motor:
    """A validated motor: plant parameters in linear SI units plus rotary equivalents.

    Attributes
    ----------
    plant : dict
        ``sim_plant_params_t`` fields (linear units: m, kg, N).
    pole_pairs : float
        Rotary-equivalent pole pairs p (theta_e = p theta_m), used for r/min.
    radius_m : float
        Equivalent radius r = p tau / pi (m per mechanical rad).
    controller : dict
        ``[controller]`` section values (with defaults; the back-EMF handover and witness
        speeds only when the file gives them).
    realism : dict
        ``sim_realism_t`` fields (plant realism, :data:`REALISM_FIELD_SOURCES`; all 0 = off).
    """

    name: str
    path: Path
    description: str
    parameterization: str
    plant: dict[str, Any]
    pole_pairs: float
    radius_m: float
    controller: dict[str, float]
    raw: dict[str, Any] = field(repr=False, default_factory=dict)
    realism: dict[str, Any] = field(default_factory=dict)

    @property
    def tau_m(self) -> float:
        return float(self.plant["tau_m"])

    @property
    def force_const_N_per_A(self) -> float:
        """K_f = 1.5 (pi / tau) psi_f (:func:`protocols.units.force_constant_N_per_A`)."""
        return U.force_constant_N_per_A(float(self.plant["psi_f_Wb"]), self.tau_m)

    # unit helpers (rotary equivalent: n[r/min] = 60 w_e / (2 pi p))
    def rpm_to_radps_e(self, n_rpm: float) -> float:
        return U.rpm_to_radps_e(n_rpm, self.pole_pairs)

    def radps_e_to_rpm(self, w: float):
        return U.radps_e_to_rpm(w, self.pole_pairs)

    def mps_to_radps_e(self, v_mps: float):
        return v_mps * U.electrical_rad_per_m(self.tau_m)

    def nm_to_N(self, torque_Nm: float) -> float:
        return torque_Nm / self.radius_m


def _err(path: Path, key: str, msg: str) -> MotorFileError:
    return MotorFileError(path, key, msg)


def _line_of(text: str, field: str) -> int:
    """1-based line of ``section.key`` (or of ``[section]``) in TOML text, 0 if absent."""
    sec, _, key = field.partition(".")
    in_sec = False
    for n, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if s.startswith("["):
            in_sec = s.strip("[] ") == sec
            if in_sec and not key:
                return n
        elif in_sec and key and re.match(rf"{re.escape(key)}\s*=", s):
            return n
    return 0


def field_range(sec: str, key: str) -> tuple[float, float, str]:
    """A motor-file field's allowed range ``(lo, hi, unit)``, inclusive: :data:`_SCHEMA`'s,
    or for a field the firmware configuration shares (``None`` there: never a copy), the
    firmware's own (:func:`firmware_field_ranges`, its ``fw_config_field()`` table), else,
    without the simulator library, the same table's source, od.yaml's ``fw_config``."""
    _, lo, hi, unit, _ = _SCHEMA[(sec, key)]
    if key in _FW_NAMES:
        fw = firmware_field_ranges()
        if key in fw:
            lo, hi, fw_unit = fw[key]  # the firmware's own limits
        else:
            from protocols import load_od

            c = load_od().fw_config[key]
            lo, hi, fw_unit = float(c["min"]), float(c["max"]), str(c.get("unit") or "")
        unit = fw_unit or unit
    return lo, hi, unit


#: ``sim_plant_params_t`` fields a motor file sets, by the motor-file field (linear
#: parameterization: the same units) whose range they have (:func:`plant_field_range`).
#: The others have no range of their own: v_stick_mps and locked are the simulator's,
#: seed and the fault-injection masks are set by the run (``seed``, ``Sim.set_plant``).
PLANT_FIELD_SOURCES: dict[str, tuple[str, str]] = {
    "R_ohm": ("electrical", "R_ohm"), "L_d0_H": ("electrical", "L_d_H"),
    "L_q_H": ("electrical", "L_q_H"), "psi_f_Wb": ("electrical", "psi_f_Wb"),
    "dL_sat_H": ("electrical", "dL_sat_H"), "I_sat_A": ("electrical", "I_sat_A"),
    "tau_m": ("mechanical", "pole_pitch_m"), "mass_kg": ("mechanical", "mass_kg"),
    "b_visc_Ns_per_m": ("mechanical", "viscous_Ns_per_m"),
    "F_coulomb_N": ("mechanical", "coulomb_friction_N"),
    "F_static_N": ("mechanical", "static_friction_N"),
    "cog_amp_N": ("mechanical", "cogging_N"), "cog_period_m": ("mechanical", "cogging_period_m"),
    "cog_phase_rad": ("mechanical", "cogging_phase_rad"),
    "u_dc_V": ("inverter", "u_dc_V"), "f_pwm_Hz": ("inverter", "f_pwm_Hz"),
    "dead_time_s": ("inverter", "dead_time_s"), "dead_band_A": ("inverter", "dead_band_A"),
    "n_sub": ("inverter", "n_sub"), "adc_bits": ("sensing", "adc_bits"),
    "adc_i_fullscale_A": ("sensing", "adc_i_fullscale_A"),
    "adc_noise_counts": ("sensing", "adc_noise_counts"),
    "adc_offset_counts": ("sensing", "adc_offset_counts"),
    "adc_gain_err": ("sensing", "adc_gain_err"),
    "udc_fullscale_V": ("sensing", "udc_fullscale_V"), "udc_noise_V": ("sensing", "udc_noise_V"),
    "ref_res_m": ("reference_sensor", "resolution_m"),
    "ref_offset_m": ("reference_sensor", "offset_m"),
}


#: ``sim_realism_t`` fields (plant realism) by the motor-file field that sets them.
REALISM_FIELD_SOURCES: dict[str, tuple[str, str]] = {
    "dLq_sat_H": ("electrical", "dLq_sat_H"), "Iq_sat_A": ("electrical", "Iq_sat_A"),
    "cross_L_H": ("electrical", "cross_L_H"), "cross_I_A": ("electrical", "cross_I_A"),
    "sal2_L_H": ("electrical", "saliency2_L_H"), "sal2_order": ("electrical", "saliency2_order"),
    "sal2_phase_rad": ("electrical", "saliency2_phase_rad"),
    "emf_h5": ("electrical", "emf_h5"), "emf_h5_phase_rad": ("electrical", "emf_h5_phase_rad"),
    "emf_h7": ("electrical", "emf_h7"), "emf_h7_phase_rad": ("electrical", "emf_h7_phase_rad"),
    "end_dL_H": ("end_effect", "dL_H"), "end_psi_frac": ("end_effect", "psi_frac"),
    "end_base": ("end_effect", "base"), "end_travel_m": ("end_effect", "travel_m"),
    "end_zone_m": ("end_effect", "zone_m"),
    "dt_C_eq_F": ("inverter", "dead_time_C_F"), "u_dev_V": ("inverter", "device_drop_V"),
    "r_dev_ohm": ("inverter", "device_r_ohm"),
}


def plant_field_range(name: str) -> tuple[float, float, str] | None:
    """A plant field's allowed range ``(lo, hi, unit)``, inclusive: its motor-file field's
    (:data:`PLANT_FIELD_SOURCES`, :data:`REALISM_FIELD_SOURCES`, :func:`field_range`);
    None for a field without one."""
    src = PLANT_FIELD_SOURCES.get(name) or REALISM_FIELD_SOURCES.get(name)
    return field_range(*src) if src else None


def plant_params_refused(p: _lib.SimPlantParams) -> str | None:
    """The field the simulator's own check (``sim_params_check``: signs, finiteness and
    the relations dL_sat < L_d0, F_static >= F_coulomb, udc_fullscale > u_dc, dead time
    below 20 % of a PWM period) refuses in ``p``; None when it accepts them."""
    bad = C.c_char_p()
    if _lib.lib().sim_params_check(p, C.byref(bad)) != 0:
        return bad.value.decode() if bad.value else "?"
    return None


def _get(path: Path, doc: dict, sec: str, key: str) -> Any:
    req, _, _, _, default = _SCHEMA[(sec, key)]
    lo, hi, unit = field_range(sec, key)
    name = f"{sec}.{key}"
    if key not in doc.get(sec, {}):
        if req:
            raise _err(path, name, f"missing; required, allowed range [{lo}, {hi}] {unit}")
        return default
    val = doc[sec][key]
    vals = val if isinstance(val, list) else [val]
    if isinstance(default, list) and (not isinstance(val, list) or len(val) != len(default)):
        raise _err(path, name, f"must be a list of {len(default)} numbers in [{lo}, {hi}] {unit}")
    for v in vals:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise _err(path, name,
                       f"{v!r} is not a finite number; allowed range [{lo}, {hi}] {unit}")
        if not lo <= v <= hi:
            raise _err(path, name, f"{v!r} outside allowed range [{lo}, {hi}] {unit}")
    return [float(v) for v in vals] if isinstance(val, list) else val


def resolve_motor_path(motor: str | Path) -> Path:
    """A motor name from ``sim_fallback/motors`` or a path to a TOML file."""
    p = Path(motor)
    if p.suffix == ".toml" or p.exists():
        return p
    cand = MOTOR_DIR / f"{motor}.toml"
    if not cand.exists():
        known = ", ".join(sorted(q.stem for q in MOTOR_DIR.glob("*.toml")))
        raise FileNotFoundError(f"motor '{motor}' not found (known: {known})")
    return cand


#: Plant fields that describe the machine (what ``--sim-plant`` swaps in); the others
#: (converter, sensing, integration: f_pwm_Hz, u_dc_V, dead time, ADC, n_sub, seed) belong
#: to the drive and stay.
MACHINE_FIELDS = ("R_ohm", "L_d0_H", "L_q_H", "dL_sat_H", "I_sat_A", "psi_f_Wb", "tau_m",
                  "mass_kg", "b_visc_Ns_per_m", "F_coulomb_N", "F_static_N", "v_stick_mps",
                  "cog_amp_N", "cog_period_m", "cog_phase_rad")


def realism_params(motor: Motor, **overrides: Any) -> _lib.SimRealism:
    """``sim_realism_t`` for a motor (plant realism), with field overrides."""
    vals = dict(motor.realism)
    for k, v in overrides.items():
        if k not in _lib.REALISM_FIELDS:
            raise KeyError(f"unknown plant realism parameter '{k}'")
        vals[k] = v
    r = _lib.SimRealism()
    for k, v in vals.items():
        setattr(r, k, int(v) if k == "sal2_order" else float(v))
    return r


def split_plant_overrides(plant: dict[str, Any] | None
                          ) -> tuple[dict[str, Any], dict[str, Any]]:
    """Plant overrides split into ``sim_plant_params_t`` and ``sim_realism_t`` fields."""
    ov = dict(plant or {})
    real = {k: ov.pop(k) for k in list(ov) if k in _lib.REALISM_FIELDS}
    return ov, real


def realism_refused(p: _lib.SimPlantParams, r: _lib.SimRealism) -> str | None:
    """The realism field the simulator's own check (``sim_realism_check``: signs, ranges,
    the incremental inductance positive definite) refuses with plant ``p``; None if none."""
    bad = C.c_char_p()
    if _lib.lib().sim_realism_check(p, r, C.byref(bad)) != 0:
        return bad.value.decode() if bad.value else "?"
    return None


def machine_params(motor: Motor) -> dict[str, Any]:
    """The machine part of a motor's plant (:data:`MACHINE_FIELDS`): plant overrides that
    make the simulated drive drive *this* motor whatever its configuration says."""
    return {k: motor.plant[k] for k in MACHINE_FIELDS if k in motor.plant}


def load_motor(motor: str | Path) -> Motor:
    """Load and validate a motor file.

    Ranges of the fields the firmware configuration shares (R, L, psi_f, pole
    pitch, PWM frequency, currents, injection) are the firmware's own table
    (:func:`firmware_field_ranges`), and the derived firmware configuration
    must pass the firmware's ``fw_config_check`` (a saliency below the
    firmware's minimum is allowed: the drive refuses injection at run time,
    which the ``paper_table1`` motor shows).

    Parameters
    ----------
    motor : str or Path
        Name in ``sim_fallback/motors`` or a TOML path.

    Returns
    -------
    Motor

    Raises
    ------
    FileNotFoundError
        No such motor (the message lists the known names).
    MotorFileError
        One line ``file:line: field: message`` naming the allowed range.
    """
    path = resolve_motor_path(motor)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as e:
        raise MotorFileError(path, "", f"not UTF-8 text (byte {e.object[e.start]:#04x} at "
                                       f"offset {e.start})") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        m = re.search(r"line (\d+)", str(e))
        raise MotorFileError(path, "", f"not valid TOML: {e}",
                             int(m.group(1)) if m else 0) from None
    try:
        mot = _build(path, doc)
        st, msg = firmware_check(fw_config(mot)) if firmware_field_ranges() else (0, "")
        if st not in (0, 4):
            name = msg.partition(" ")[0]
            sec = next((s for s, k in _SCHEMA if k == name), None)
            raise MotorFileError(path, f"{sec}.{name}" if sec else f"(derived) {name}",
                                 "the firmware refuses the configuration derived from this "
                                 f"file: {msg}")
        if firmware_field_ranges():  # the simulator library is there: its own checks
            bad = realism_refused(plant_params(mot), realism_params(mot))
            if bad is not None:
                sec, key = REALISM_FIELD_SOURCES.get(bad, ("electrical", bad))
                lo, hi, unit = field_range(sec, key)
                raise MotorFileError(path, f"{sec}.{key}", (
                    f"{mot.raw.get(sec, {}).get(key, 0.0)!r} refused by the simulator with the "
                    f"other fields: allowed range [{lo}, {hi}] {unit}, and the incremental "
                    "inductance must stay positive definite (>= 10 % of the smaller "
                    "unsaturated one) over twice the current ADC's range"))
        return mot
    except MotorFileErrors as e:
        raise MotorFileErrors([x if x.line or not x.field else
                               MotorFileError(path, x.field, x.message, _line_of(text, x.field))
                               for x in e.errors]) from None
    except MotorFileError as e:
        if e.line or not e.field:
            raise
        raise MotorFileError(path, e.field, e.message, _line_of(text, e.field)) from None


def _build(path: Path, doc: dict[str, Any]) -> Motor:
    # unknown sections / fields (typos) are errors
    known_secs = {s for s, _ in _SCHEMA} | {"motor"}
    errs: list[MotorFileError] = []  # every field's problem at once, as for sequences
    for sec, body in doc.items():
        if sec not in known_secs or not isinstance(body, dict):
            errs.append(_err(path, sec, f"unknown section; allowed: {sorted(known_secs)}"))
            continue
        for key in body:
            if (sec, key) not in _SCHEMA and (sec, key) not in _TEXT_FIELDS:
                allowed = sorted(k for s, k in list(_SCHEMA) + list(_TEXT_FIELDS) if s == sec)
                errs.append(_err(path, f"{sec}.{key}", f"unknown field; allowed: {allowed}"))
    m = doc.get("motor", {})
    param = m.get("parameterization", "linear") if isinstance(m, dict) else "linear"
    if param not in ("linear", "rotary"):
        errs.append(_err(path, "motor.parameterization",
                         f"{param!r}; allowed: 'linear', 'rotary'"))
    g: dict[str, Any] = {}
    for s, k in _SCHEMA:
        if not isinstance(doc.get(s, {}), dict):
            continue  # a section that is not a table: reported above
        try:
            g[k] = _get(path, doc, s, k)
        except MotorFileError as e:
            errs.append(e)
    if len(errs) == 1:
        raise errs[0]
    if errs:
        raise MotorFileErrors(errs)

    tau = float(g["pole_pitch_m"])
    L_d, L_q = float(g["L_d_H"]), float(g["L_q_H"])
    if g["dL_sat_H"] >= L_d:
        raise _err(path, "electrical.dL_sat_H", f"{g['dL_sat_H']} must be < L_d_H = {L_d}")
    if g["dLq_sat_H"] >= L_q:
        raise _err(path, "electrical.dLq_sat_H", f"{g['dLq_sat_H']} must be < L_q_H = {L_q}")
    for k_on, k_scale in (("dLq_sat_H", "Iq_sat_A"), ("cross_L_H", "cross_I_A")):
        if g[k_on] > 0.0 and not g[k_scale] > 0.0:
            raise _err(path, f"electrical.{k_scale}", f"{g[k_scale]} must be > 0 when "
                       f"electrical.{k_on} > 0; allowed range (0, 1000.0] A")
    if g["travel_m"] > 0.0 and not g["zone_m"] > 0.0:
        raise _err(path, "end_effect.zone_m", f"{g['zone_m']} must be > 0 when "
                   "end_effect.travel_m > 0; allowed range (0, 10.0] m")
    if int(g["saliency2_order"]) != g["saliency2_order"]:
        raise _err(path, "electrical.saliency2_order",
                   f"{g['saliency2_order']!r} is not an integer; allowed range [1, 12]")
    if param == "rotary":
        for k in ("pole_pairs", "inertia_kgm2"):
            if k not in doc["mechanical"]:
                lo, hi, unit = _SCHEMA[("mechanical", k)][1:4]
                raise _err(path, f"mechanical.{k}",
                           f"missing; required for rotary files, allowed range [{lo}, {hi}] {unit}")
        for k in ("mass_kg", "viscous_Ns_per_m", "static_friction_N", "coulomb_friction_N",
                  "cogging_N"):
            if k in doc["mechanical"]:
                raise _err(path, f"mechanical.{k}", "linear field in a rotary file")
        p = float(g["pole_pairs"])
        r = U.radius_m(p, tau)
        mass = float(g["inertia_kgm2"]) / r**2
        b = float(g["viscous_Nms_per_rad"]) / r**2
        F_s = float(g["static_friction_Nm"]) / r
        tc = g["coulomb_friction_Nm"]
        F_c = F_s if tc is None else float(tc) / r
        if "static_friction_Nm" not in doc["mechanical"]:
            F_s = F_c  # only the Coulomb (kinetic) level given: no extra breakaway
        fric_keys = ("static_friction_Nm", "coulomb_friction_Nm", r)
        cog = float(g["cogging_Nm"]) / r
    else:
        if "mass_kg" not in doc["mechanical"]:
            lo, hi, unit = _SCHEMA[("mechanical", "mass_kg")][1:4]
            raise _err(path, "mechanical.mass_kg",
                       f"missing; required for linear files, allowed range [{lo}, {hi}] {unit}")
        for k in ("inertia_kgm2", "viscous_Nms_per_rad", "static_friction_Nm",
                  "coulomb_friction_Nm", "cogging_Nm"):
            if k in doc["mechanical"]:
                raise _err(path, f"mechanical.{k}", "rotary field in a linear file")
        p = float(g["pole_pairs"] or 1.0)
        r = U.radius_m(p, tau)
        mass = float(g["mass_kg"])
        b = float(g["viscous_Ns_per_m"])
        F_s = float(g["static_friction_N"])
        F_c = F_s if g["coulomb_friction_N"] is None else float(g["coulomb_friction_N"])
        if "static_friction_N" not in doc["mechanical"]:
            F_s = F_c  # only the Coulomb (kinetic) level given: no extra breakaway
        fric_keys = ("static_friction_N", "coulomb_friction_N", 1.0)
        cog = float(g["cogging_N"])
    if g["i_rated_A"] > g["i_max_A"]:
        raise _err(path, "controller.i_rated_A", f"{g['i_rated_A']} A must not exceed "
                   f"controller.i_max_A = {g['i_max_A']} A (the continuous rating is at most "
                   "the peak)")
    if g["i_trip_A"] <= g["i_max_A"]:
        raise _err(path, "controller.i_trip_A", f"{g['i_trip_A']} A must exceed "
                   f"controller.i_max_A = {g['i_max_A']} A (the trip level is above the limit)")
    if F_c > F_s:
        k_s, k_c, scale = fric_keys
        raise _err(path, f"mechanical.{k_c}",
                   f"{F_c * scale:g} must be <= mechanical.{k_s} = {F_s * scale:g} (kinetic "
                   "friction cannot exceed the breakaway level)")
    if g["udc_fullscale_V"] <= g["u_dc_V"]:
        raise _err(path, "sensing.udc_fullscale_V",
                   f"{g['udc_fullscale_V']} must exceed inverter.u_dc_V = {g['u_dc_V']}")
    plant = dict(
        R_ohm=float(g["R_ohm"]), L_d0_H=L_d, L_q_H=L_q, psi_f_Wb=float(g["psi_f_Wb"]),
        dL_sat_H=float(g["dL_sat_H"]), I_sat_A=float(g["I_sat_A"]), tau_m=tau,
        mass_kg=mass, b_visc_Ns_per_m=b, F_coulomb_N=F_c, F_static_N=F_s,
        v_stick_mps=1e-6, cog_amp_N=cog,
        cog_period_m=float(g["cogging_period_m"] or tau / 3.0),
        cog_phase_rad=float(g["cogging_phase_rad"]), locked=0,
        u_dc_V=float(g["u_dc_V"]), f_pwm_Hz=float(g["f_pwm_Hz"]),
        dead_time_s=float(g["dead_time_s"]), dead_band_A=float(g["dead_band_A"]),
        n_sub=int(g["n_sub"]), adc_bits=int(g["adc_bits"]),
        adc_i_fullscale_A=float(g["adc_i_fullscale_A"]),
        adc_noise_counts=float(g["adc_noise_counts"]),
        adc_offset_counts=list(g["adc_offset_counts"]), adc_gain_err=list(g["adc_gain_err"]),
        udc_fullscale_V=float(g["udc_fullscale_V"]), udc_noise_V=float(g["udc_noise_V"]),
        seed=0, ref_res_m=float(g["resolution_m"]), ref_offset_m=float(g["offset_m"]),
        ref_fault=0, noise_restart=0,
    )
    ctrl = {k: float(g[k]) for (s, k) in _SCHEMA if s == "controller" and g[k] is not None}
    realism = {name: (int(g[k]) if name == "sal2_order" else float(g[k]))
               for name, (_, k) in REALISM_FIELD_SOURCES.items()}
    return Motor(name=str(m.get("name", path.stem)), path=path,
                 description=str(m.get("description", "")), parameterization=param,
                 plant=plant, pole_pairs=p, radius_m=r, controller=ctrl, raw=doc,
                 realism=realism)


def plant_params(motor: Motor, **overrides: Any) -> _lib.SimPlantParams:
    """``sim_plant_params_t`` for a motor, with field overrides."""
    vals = dict(motor.plant)
    for k, v in overrides.items():
        if k not in vals:
            raise KeyError(f"unknown plant parameter '{k}'")
        vals[k] = v
    p = _lib.SimPlantParams()
    for k, v in vals.items():
        if isinstance(v, list):
            getattr(p, k)[:] = v
        else:
            setattr(p, k, v)
    return p


#: The drive's own sensing chain: ADC resolution and full scales. They are the drive
#: board's design, which its firmware is built for, so the drive's ADC scaling follows
#: the simulated board's (a plant override of them is a different board, configured
#: accordingly); its offsets, gains errors and noise stay unknown to the drive.
SENSING_SCALE_KEYS = ("adc_bits", "adc_i_fullscale_A", "udc_fullscale_V")


def fw_config(motor: Motor, extractor: int | str = "sogi_adaptive",
              sensing: dict[str, float] | None = None, **overrides: float) -> _lib.FwConfig:
    """``fw_config_t`` for a motor: nominal parameters and the paper's gain rules.

    Current PI: kp = L_d 1100 V/A, ki = R 1100 V/(A s). Speed PI (rotary files):
    the paper's 0.1 A/(r/min) and 0.6 A/(r/min s), converted to electrical rad/s
    with 1 r/min = 2 pi p / 60 rad/s; linear files: kp = m w_bw / K_f (A per m/s),
    ki = kp w_bw / 6, converted with v = w_e tau / pi. PLL 86.6 / 5000. ADC
    scaling matches the plant's ADC (the drive knows its nominal scaling, not
    the offset or gain errors): the motor file's, or ``sensing``
    (:data:`SENSING_SCALE_KEYS`) when the simulated board differs from it. The back-EMF
    handover and witness speeds (``bemf_v_on_mps``, ``bemf_v_off_mps``,
    ``mon_bemf_min_mps``) from ``[controller]`` when given, else the firmware's defaults;
    the drive derives their back-EMF levels.
    """
    L = _lib.lib()
    cfg = _lib.FwConfig()
    L.fw_config_default(cfg)
    pl = motor.plant
    p = motor.pole_pairs
    cfg.f_pwm_Hz = pl["f_pwm_Hz"]
    cfg.R_ohm = pl["R_ohm"]
    cfg.L_d_H = pl["L_d0_H"]
    cfg.L_q_H = pl["L_q_H"]
    cfg.psi_f_Wb = pl["psi_f_Wb"]
    cfg.pole_pairs = p
    cfg.pole_pitch_m = pl["tau_m"]
    # the physical description; the drive derives the gains from it (fw_config_derive,
    # one implementation in C for the simulator, this API and a drive set up over CANopen)
    cfg.mass_kg = pl["mass_kg"]
    cfg.visc_Ns_per_m = pl["b_visc_Ns_per_m"]
    cfg.coulomb_N = pl["F_coulomb_N"]
    cfg.cur_bw_radps = 1100.0  # the paper's current-loop rule: k_P = L_d 1100, k_I = R 1100
    cfg.gains_auto = 1
    c = motor.controller
    for k in _CTRL_FW_FIELDS:
        if k in c:
            setattr(cfg, k, type(getattr(cfg, k))(c[k]))  # sogi_bumpless: uint32_t
    if motor.parameterization == "rotary":
        # the paper's speed PI, 0.1 A/(r/min) and 0.6 A/(r/min s), and its PLL, kept
        L.fw_config_derive(cfg)
        cfg.gains_auto = 0
        cfg.spd_kp_A_per_radps = 0.1 * 60.0 / (2.0 * math.pi * p)
        cfg.spd_ki_A_per_rad = 0.6 * 60.0 / (2.0 * math.pi * p)
        cfg.pll_kp = 86.6
        cfg.pll_ki = 5000.0
        cfg.pll_kd = 1.0e5
    else:
        # linear motors: every gain from the physical description, in the drive
        # (fw_config_derive: current and speed PI, observer incl. its bandwidth)
        cfg.spd_bw_radps = motor.controller["speed_bw_radps"]
        L.fw_config_derive(cfg)
    sens = {k: pl[k] for k in SENSING_SCALE_KEYS} | dict(sensing or {})
    full = 2.0 ** sens["adc_bits"]
    cfg.adc_A_per_count = 2.0 * sens["adc_i_fullscale_A"] / full
    cfg.adc_offset_counts = full / 2.0
    cfg.adc_V_per_count = sens["udc_fullscale_V"] / full
    cfg.adc_max_count = int(full - 1)
    cfg.extractor = extractor_id(extractor)
    for k, v in overrides.items():
        if not hasattr(cfg, k):
            raise KeyError(f"unknown fw_config_t field '{k}'")
        setattr(cfg, k, v)
    # derived again over the overrides, as fw_init will (the back-EMF levels of the
    # handover speeds; the gains when still automatic): the configuration the drive runs
    L.fw_config_derive(cfg)
    return cfg


#: extractor name -> fw_extractor_t value (protocols/od.yaml enums:)
EXTRACTORS = {e.key: int(e) for e in Extractor}


def extractor_id(ex: int | str) -> int:
    if isinstance(ex, str):
        if ex not in EXTRACTORS:
            raise ValueError(f"extractor '{ex}' unknown; choose from {list(EXTRACTORS)}")
        return EXTRACTORS[ex]
    if int(ex) not in EXTRACTORS.values():
        raise ValueError(f"extractor {ex} unknown")
    return int(ex)
