"""Motor files: loading, rotary -> linear conversion, validation errors, fw_config."""

import math

import pytest

from sim_fallback import MotorFileError, _lib, fw_config, load_motor

GOOD = """
[motor]
name = "t"
parameterization = "linear"
[electrical]
R_ohm = 1.0
L_d_H = 0.01
L_q_H = 0.015
psi_f_Wb = 0.1
[mechanical]
pole_pitch_m = 0.02
mass_kg = 5.0
"""


@pytest.mark.parametrize("name", ["paper_table1", "paper_salient", "iron_core_linear"])
def test_shipped_motors_load(name):
    m = load_motor(name)
    assert m.name == name
    assert m.plant["L_d0_H"] > 0 and m.plant["mass_kg"] > 0


def test_paper_table1_is_exactly_table1():
    m = load_motor("paper_table1")
    doc = m.raw
    assert doc["electrical"] == {"R_ohm": 0.958, "L_d_H": 0.012, "L_q_H": 0.012,
                                 "psi_f_Wb": 0.1827, "dL_sat_H": 0.0, "I_sat_A": 5.0}
    mech = doc["mechanical"]
    assert (mech["pole_pairs"], mech["inertia_kgm2"], mech["viscous_Nms_per_rad"],
            mech["static_friction_Nm"]) == (4, 0.03, 0.008, 1.5)


def test_rotary_conversion():
    m = load_motor("paper_salient")
    r = 4 * 0.024 / math.pi
    assert m.radius_m == pytest.approx(r)
    assert m.plant["mass_kg"] == pytest.approx(0.03 / r**2)          # 32.1 kg
    assert m.plant["F_static_N"] == pytest.approx(1.5 / r)            # 49.1 N
    assert m.plant["b_visc_Ns_per_m"] == pytest.approx(0.008 / r**2)
    # thrust constant and torque constant agree through r
    assert m.force_const_N_per_A * r == pytest.approx(1.5 * 4 * 0.1827)
    assert m.plant["L_q_H"] == pytest.approx(1.5 * m.plant["L_d0_H"])
    assert m.plant["dL_sat_H"] == pytest.approx(0.1 * m.plant["L_d0_H"])


def test_iron_core_is_commercial_like():
    m = load_motor("iron_core_linear")
    assert 0.016 <= m.tau_m <= 0.032
    assert 50 <= m.force_const_N_per_A <= 100
    assert 1.2 <= m.plant["L_q_H"] / m.plant["L_d0_H"] <= 1.5
    assert 0.005 <= m.plant["L_d0_H"] <= 0.015


def _write(tmp_path, text, name="bad.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("edit, field, needle", [
    (("R_ohm = 1.0", "R_ohm = -1.0"), "electrical.R_ohm", "[0.001, 100.0]"),
    (("L_d_H = 0.01", "L_d_H = 5.0"), "electrical.L_d_H", "[1e-05, 1.0]"),
    (("mass_kg = 5.0", "mass_kg = 0.0"), "mechanical.mass_kg", "[0.001, 100000.0]"),
    (("mass_kg = 5.0", 'mass_kg = "heavy"'), "mechanical.mass_kg", "not a finite number"),
    (("psi_f_Wb = 0.1\n", ""), "electrical.psi_f_Wb", "missing"),
    (("mass_kg = 5.0", ""), "mechanical.mass_kg", "missing"),
    (("R_ohm = 1.0", "R_ohm = 1.0\nR_ohms = 2.0"), "electrical.R_ohms", "unknown field"),
    (("mass_kg = 5.0", "mass_kg = 5.0\ninertia_kgm2 = 0.1"), "mechanical.inertia_kgm2",
     "rotary field"),
])
def test_bad_file_names_file_field_range(tmp_path, edit, field, needle):
    p = _write(tmp_path, GOOD.replace(*edit))
    with pytest.raises(MotorFileError) as ei:
        load_motor(p)
    msg = str(ei.value)
    assert msg.startswith(f"{p}:") and f": {field}: " in msg and needle in msg, msg
    assert "\n" not in msg
    text = p.read_text().splitlines()
    key = field.split(".")[1]
    written = [n for n, line in enumerate(text, 1) if line.strip().startswith(key + " ")]
    assert ei.value.line == (written[0] if written else 0), msg


@pytest.mark.parametrize("extra, field, needle", [
    # the firmware's own table (fw_config_field) gives u_inj_V >= 1 V: 0.5 V must not
    # silently run on the firmware default
    ("[controller]\nu_inj_V = 0.5\n", "controller.u_inj_V", "[1.0, 400.0] V"),
    ("[controller]\ni_max_A = 20.0\ni_trip_A = 10.0\n", "controller.i_trip_A",
     "must exceed controller.i_max_A"),
    ("[controller]\nf_inj_Hz = 50.0\n", "controller.f_inj_Hz", "[100.0, 20000.0] Hz"),
])
def test_controller_fields_use_the_firmware_limits(tmp_path, extra, field, needle):
    from sim_fallback._motors import firmware_field_ranges

    p = _write(tmp_path, GOOD + "\n" + extra)
    with pytest.raises(MotorFileError) as ei:
        load_motor(p)
    assert f": {field}: " in str(ei.value) and needle in str(ei.value), str(ei.value)
    assert ei.value.line > 0
    if "u_inj_V" in field:  # the limit is the firmware's, read from the C table
        assert firmware_field_ranges()["u_inj_V"][:2] == (1.0, 400.0)


def test_non_utf8_and_bad_toml_name_file_and_line(tmp_path):
    p = tmp_path / "latin1.toml"
    p.write_bytes(GOOD.encode() + b"\n# caf\xe9\n")
    with pytest.raises(MotorFileError, match="not UTF-8"):
        load_motor(p)
    q = _write(tmp_path, GOOD + "\n[broken\n", "broken.toml")
    with pytest.raises(MotorFileError) as ei:
        load_motor(q)
    assert "not valid TOML" in str(ei.value) and ei.value.line > 0


def test_good_file_loads(tmp_path):
    m = load_motor(_write(tmp_path, GOOD, "good.toml"))
    assert m.plant["tau_m"] == 0.02


def test_bad_toml_syntax(tmp_path):
    p = _write(tmp_path, "[motor\nname=")
    with pytest.raises(MotorFileError, match="not valid TOML"):
        load_motor(p)


def test_fw_config_paper_gains():
    m = load_motor("paper_salient")
    cfg = fw_config(m)
    assert cfg.cur_kp_V_per_A == pytest.approx(0.012 * 1100, rel=1e-6)
    assert cfg.cur_ki_V_per_As == pytest.approx(0.958 * 1100, rel=1e-6)
    # 0.1 A/(r/min): 1 r/min = 2 pi p / 60 rad/s electrical
    assert cfg.spd_kp_A_per_radps == pytest.approx(0.1 * 60 / (2 * math.pi * 4), rel=1e-6)
    assert cfg.spd_ki_A_per_rad == pytest.approx(0.6 * 60 / (2 * math.pi * 4), rel=1e-6)
    assert (cfg.pll_kp, cfg.pll_ki) == (pytest.approx(86.6), 5000.0)
    assert cfg.adc_max_count == 4095
    issue = _lib.FwConfigIssue()
    assert _lib.lib().fw_config_check(cfg, issue) == 0


def test_fw_config_table1_saliency_refused():
    cfg = fw_config(load_motor("paper_table1"))
    issue = _lib.FwConfigIssue()
    assert _lib.lib().fw_config_check(cfg, issue) == 4  # FW_ERR_SALIENCY
    assert issue.field == b"L_q_H"


def test_fw_config_all_motors_valid_except_table1():
    for name in ("paper_salient", "iron_core_linear"):
        issue = _lib.FwConfigIssue()
        assert _lib.lib().fw_config_check(fw_config(load_motor(name)), issue) == 0, (
            name, issue.field)


def test_every_problem_of_a_motor_file_is_reported_at_once(tmp_path) -> None:
    """Three mistakes, three lines (each file:line: field: message), as for sequences
    (was: the first one only, then the next after fixing it)."""
    from pathlib import Path

    import pytest

    from sim_fallback import MotorFileError, load_motor

    src = Path(__file__).resolve().parents[2] / "sim_fallback/motors/iron_core_linear.toml"
    lines = src.read_text().splitlines()
    lines = ["R_ohm = -1.0" if ln.startswith("R_ohm =") else
             'mass_kg = "heavy"' if ln.startswith("mass_kg =") else ln for ln in lines]
    f = tmp_path / "bad.toml"
    f.write_text("\n".join(lines + ["bogus = 3"]) + "\n")
    with pytest.raises(MotorFileError) as ei:
        load_motor(f)
    got = str(ei.value).splitlines()
    assert len(got) == 3, got
    r_line = next(i for i, ln in enumerate(lines, 1) if ln.startswith("R_ohm"))
    assert f"bad.toml:{r_line}: electrical.R_ohm: -1.0 outside allowed range" in "\n".join(got)
    assert any("mechanical.mass_kg: 'heavy' is not a finite number" in g for g in got)
    from sim_fallback._motors import _SCHEMA

    allowed = sorted(k for (sec, k) in _SCHEMA if sec == "controller")
    assert {"u_inj_V", "f_inj_Hz", "i_max_A", "speed_bw_radps"} <= set(allowed)
    assert any(g.endswith(f"controller.bogus: unknown field; allowed: {allowed}")
               for g in got), got
    assert all(g.startswith(str(f) + ":") for g in got)


def test_firmware_shared_ranges_are_never_a_copy(monkeypatch) -> None:
    """The motor-file ranges of fields the firmware configuration shares come from the
    firmware's table, or without the simulator library from its source, od.yaml (a copy
    in _motors.py had drifted: u_inj_V [0, 400] V there, [1, 400] V in the drive)."""
    from protocols import _od
    from sim_fallback import _motors as M

    cfg = _od.load().fw_config
    with_lib = {k: M.field_range(s, k) for s, k in M._SCHEMA if k in M._FW_NAMES}
    monkeypatch.setattr(M, "firmware_field_ranges", lambda: {})
    for (s, k), spec in M._SCHEMA.items():
        if k not in M._FW_NAMES:
            continue
        assert spec[1] is None and spec[2] is None, k  # no literal range to drift
        lo, hi, _ = M.field_range(s, k)
        assert (lo, hi) == (float(cfg[k]["min"]), float(cfg[k]["max"])) == with_lib[k][:2]
    assert M.field_range("controller", "u_inj_V") == (1.0, 400.0, "V")
