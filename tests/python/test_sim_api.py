"""The simulated drive's Python API: a refused configuration raises and names the
field, its value and the allowed range; setters in m/s and N agree with the
analytic unit conversions (w_e = pi v / tau, K_F = 1.5 (pi/tau) psi_f); motor
files with only a Coulomb friction level load; one DC-link ADC scaling rule."""

import ctypes as C
import math

import numpy as np
import pytest

import sim_fallback as sf
from sim_fallback import _lib


def test_out_of_range_field_raises_with_field_value_and_range():
    with pytest.raises(sf.ConfigError) as ei:
        sf.Firmware("iron_core_linear", R_ohm=-1.0)
    e = ei.value
    assert e.field == "R_ohm" and e.value == -1.0 and e.status == 2
    lo, hi, unit = sf.firmware_field_ranges()["R_ohm"]
    assert e.allowed == (lo, hi)
    msg = str(e)
    assert "R_ohm" in msg and "-1" in msg and f"{lo:g}" in msg and f"{hi:g}" in msg
    assert unit in msg


def test_non_finite_field_raises():
    with pytest.raises(sf.ConfigError) as ei:
        sf.Firmware("paper_salient", L_d_H=float("nan"))
    assert ei.value.field == "L_d_H"


def test_inconsistent_fields_name_the_field_and_the_range_the_others_allow():
    with pytest.raises(sf.ConfigError) as ei:
        sf.Firmware("iron_core_linear", i_trip_A=1.0)   # i_max_A (20 A) >= i_trip_A
    e = ei.value
    assert e.field == "i_max_A" and e.status == 5
    assert e.allowed is not None and e.allowed[1] == pytest.approx(1.0)
    assert "i_max_A = 20" in str(e)


def test_saliency_refusal_explains_itself_and_is_a_result_in_run_scenario():
    with pytest.raises(sf.ConfigError) as ei:
        sf.Firmware("paper_table1")                        # L_q = L_d
    assert ei.value.status == 4 and "saliency" in str(ei.value)
    # the device view: the drive boots refused, the run is invalid with the reason
    fw = sf.Firmware("paper_table1", strict=False)
    assert fw.init_status == 4
    res = sf.run_scenario("paper_table1", t_end=0.05)
    assert not res.valid
    assert res.info["invalid_reason"].startswith("configuration refused: saliency")


def test_unknown_override_is_a_key_error_naming_it():
    with pytest.raises(KeyError, match="R_ohmm"):
        sf.Firmware("paper_salient", R_ohmm=1.0)


def test_sim_raises_on_refused_configuration():
    with pytest.raises(sf.ConfigError, match="psi_f_Wb"):
        sf.Sim("iron_core_linear", fw={"psi_f_Wb": 0.0})


def test_speed_setters_match_the_analytic_conversions():
    mot = sf.load_motor("iron_core_linear")
    fw = sf.Firmware(mot)
    tau, p = fw.cfg.pole_pitch_m, fw.cfg.pole_pairs
    assert fw.set_speed_ref_mps(0.5) == 0
    w = fw.snapshot()["speed_ref_radps_e"]
    assert w == pytest.approx(math.pi * 0.5 / tau, rel=1e-6)
    assert fw.set_speed_ref_rpm(30.0) == 0
    assert fw.snapshot()["speed_ref_radps_e"] == pytest.approx(30.0 * 2 * math.pi * p / 60,
                                                               rel=1e-6)
    # beyond the firmware's limit: clamped (status 2), not silently different. The
    # limit is v_max_mps (CiA 402 0x6080) where that is below speed_max_radps_e ...
    v_max = float(fw.cfg.v_max_mps)
    assert math.pi * v_max / tau < fw.cfg.speed_max_radps_e
    assert fw.set_speed_ref_mps(1.01 * v_max) == 2
    assert fw.snapshot()["speed_ref_radps_e"] == pytest.approx(math.pi * v_max / tau, rel=1e-6)
    assert fw.set_speed_ref_mps(0.99 * v_max) == 0
    # ... and speed_max_radps_e where v_max_mps is above it
    fw = sf.Firmware(mot, v_max_mps=2.0 * fw.cfg.speed_max_radps_e * tau / math.pi)
    v_big = 1.01 * fw.cfg.speed_max_radps_e * tau / math.pi
    assert fw.set_speed_ref_mps(v_big) == 2
    assert fw.snapshot()["speed_ref_radps_e"] == pytest.approx(fw.cfg.speed_max_radps_e)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_references_raise_and_change_nothing(bad):
    fw = sf.Firmware("iron_core_linear")
    fw.set_speed_ref_mps(0.2)
    before = fw.snapshot()["speed_ref_radps_e"]
    for setter in (fw.set_speed_ref_mps, fw.set_speed_ref_rpm, fw.set_force_ref_N,
                   fw.set_iq_ref_A, fw.set_torque_ref_Nm):
        with pytest.raises(sf.RefError, match="finite"):
            setter(bad)
    assert fw.snapshot()["speed_ref_radps_e"] == before


def test_force_setter_uses_the_analytic_thrust_constant():
    fw = sf.Firmware("iron_core_linear")
    k_f = 1.5 * math.pi / fw.cfg.pole_pitch_m * fw.cfg.psi_f_Wb   # numpy-free reference
    assert fw.force_per_A == pytest.approx(k_f, rel=1e-6)
    # the Python copy (motor files, identification, the bench's rated force) agrees
    from protocols.units import force_constant_N_per_A
    assert force_constant_N_per_A(fw.cfg.psi_f_Wb, fw.cfg.pole_pitch_m) == pytest.approx(
        k_f, rel=1e-12)
    assert sf.load_motor("iron_core_linear").force_const_N_per_A == pytest.approx(
        fw.force_per_A, rel=1e-6)
    i_max = fw.cfg.i_max_A
    # the clamp sits exactly at F = K_F i_max: +-0.1 % around it tells K_F to 0.1 %
    assert fw.set_force_ref_N(0.999 * k_f * i_max) == 0
    assert fw.set_force_ref_N(1.001 * k_f * i_max) == 2
    r = fw.cfg.pole_pairs * fw.cfg.pole_pitch_m / math.pi
    assert fw.set_torque_ref_Nm(0.999 * k_f * i_max * r) == 0
    assert fw.set_torque_ref_Nm(1.001 * k_f * i_max * r) == 2


def test_force_mode_run_produces_the_commanded_thrust():
    # simulator truth: a locked-in force-mode run's mean plant thrust ~ the command
    res = sf.run_scenario("iron_core_linear", force_ref=[(0.0, 0.0), (0.2, 30.0)], t_end=0.3,
                          noise=0.0, channels=["force_N"])
    t, f = res.data["t_s"], res.data["force_N"]
    late = (t > 0.25)
    assert res.fault_code == 0
    assert np.mean(f[late]) == pytest.approx(30.0, rel=0.05)


def _motor_file(tmp_path, mech: str):
    src = (sf.MOTOR_DIR / "iron_core_linear.toml").read_text()
    lines, out, skip = src.splitlines(), [], False
    for ln in lines:
        if ln.strip().startswith("["):
            skip = ln.strip() == "[mechanical]"
            if skip:
                out.append("[mechanical]")
                out.extend(mech.strip().splitlines())
                continue
        if not skip:
            out.append(ln)
    p = tmp_path / "m.toml"
    p.write_text("\n".join(out) + "\n")
    return p


def test_motor_file_with_only_coulomb_friction_loads(tmp_path):
    p = _motor_file(tmp_path, 'pole_pitch_m = 0.016\nmass_kg = 5.0\ncoulomb_friction_N = 7.5\n')
    mot = sf.load_motor(p)
    assert mot.plant["F_coulomb_N"] == 7.5 and mot.plant["F_static_N"] == 7.5


def test_coulomb_above_static_names_the_real_key(tmp_path):
    p = _motor_file(tmp_path, 'pole_pitch_m = 0.016\nmass_kg = 5.0\n'
                              'static_friction_N = 2.0\ncoulomb_friction_N = 7.5\n')
    with pytest.raises(sf.MotorFileError) as ei:
        sf.load_motor(p)
    msg = str(ei.value)
    assert "mechanical.coulomb_friction_N" in msg and "static_friction_N = 2" in msg


def test_dc_link_scaling_is_one_rule():
    """fw_config_default and fw_config() scale the DC-link ADC alike (FS / 2^bits)."""
    default = _lib.FwConfig()
    _lib.lib().fw_config_default(default)
    cfg = sf.fw_config(sf.load_motor("paper_salient"))
    pl = sf.load_motor("paper_salient").plant
    assert pl["adc_bits"] == 12 and pl["udc_fullscale_V"] == 500.0
    assert cfg.adc_V_per_count == pytest.approx(500.0 / 4096.0, rel=1e-7)
    assert default.adc_V_per_count == pytest.approx(cfg.adc_V_per_count, rel=1e-7)
    assert default.adc_A_per_count == pytest.approx(cfg.adc_A_per_count, rel=1e-7)


@pytest.mark.parametrize("motor", ["paper_salient", "iron_core_linear"])
def test_python_units_are_the_firmwares(motor):
    """protocols.units (the bench's, the simulator's and the tools' one copy of the
    machine geometry) against the firmware's fw_units_* in float32, and against the
    rotary-equivalent definitions written out here (r = p tau / pi)."""
    from protocols import units as U
    fw = sf.Firmware(motor)
    L, cfg = _lib.lib(), C.byref(fw.cfg)
    p, tau = fw.cfg.pole_pairs, fw.cfg.pole_pitch_m
    rel = 2e-7  # float32 against float64
    for n in (-3000.0, -1.0, 0.5, 100.0, 2500.0):
        assert U.rpm_to_radps_e(n, p) == pytest.approx(L.fw_units_rpm_to_radps_e(cfg, n),
                                                       rel=rel)
        assert U.radps_e_to_rpm(U.rpm_to_radps_e(n, p), p) == pytest.approx(n, rel=1e-12)
        v = U.rpm_to_mps(n, p, tau)
        assert v == pytest.approx(n / 60.0 * 2.0 * p * tau, rel=1e-12)  # 2 p tau per rev
        assert U.mps_to_rpm(v, p, tau) == pytest.approx(n, rel=1e-12)
    for v in (-2.0, 0.01, 1.5):
        assert v * U.electrical_rad_per_m(tau) == pytest.approx(
            L.fw_units_mps_to_radps_e(cfg, v), rel=rel)
        w = L.fw_units_mps_to_radps_e(cfg, v)
        assert w * U.m_per_electrical_rad(tau) == pytest.approx(
            L.fw_units_radps_e_to_mps(cfg, w), rel=rel)
    assert U.radius_m(p, tau) == pytest.approx(p * tau / math.pi, rel=1e-15)
    # the bench's sequence units are these
    from bench._units import MotorUnits
    mu = MotorUnits(pole_pitch_m=tau, pole_pairs=p)
    assert mu.speed_to_mps(100.0, "r/min") == U.rpm_to_mps(100.0, p, tau)
    assert mu.force_to_N(2.0, "N*m") == 2.0 / U.radius_m(p, tau)
    assert mu.theta_e_rad(tau) == pytest.approx(math.pi, rel=1e-15)


def test_target_beyond_v_max_runs_at_v_max_without_a_trip():
    """0x6080 (v_max_mps) limits the speed target: a 2.5 m/s target with v_max 2.0
    m/s runs the simulated mover at 2.0 m/s (truth), with statusword bit 11 and no
    fault; the speed loop's overshoot stays inside the trip's margin (x 1.2)."""
    mot = sf.load_motor("iron_core_linear")
    k = math.pi / mot.tau_m  # m/s -> el. rad/s
    with sf.Sim(mot, "sogi_adaptive", seed=0, fw={"v_max_mps": 2.0}) as s:
        s.set_schedule(sf.SIM_REF_SPEED, [(0.0, 0.2 * k), (0.3, 2.5 * k)])
        s.enable()
        d = s.advance(int(round(1.0 / s.dt_s)), 24, ["v_mps", "fault_code", "t_s"])
        sw = int(s.snapshot()["statusword"])
        margin = float(s.cfg.overspeed_margin)
    assert int(d["fault_code"].max()) == 0
    late = d["v_mps"][d["t_s"] > 0.6]
    assert late == pytest.approx(2.0, rel=0.01), (late.min(), late.max())
    assert d["v_mps"].max() < 2.0 * margin
    assert sw & 0x0800, hex(sw)
