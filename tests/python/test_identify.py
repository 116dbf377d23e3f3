"""Motor identification by the drive (identification/, sim_fallback.SimProbe) against the simulated
plant's truth, with 12-bit ADC noise: shipped motors and a randomized one."""

import functools

import pytest

from sim_fallback import identify, randomized_plant, truth_of
from sim_fallback._motors import load_motor

ELECTRICAL = ("R_ohm", "L_d_H", "L_q_H")


def _random_plant(seed: int) -> dict:
    return randomized_plant(seed)


@pytest.mark.parametrize("name", ["paper_salient", "iron_core_linear"])
def test_shipped_motors_electrical_within_3_percent(name):
    mot = load_motor(name)
    r = identify(mot)
    err = r.rel_error(truth_of(mot))
    for k in ELECTRICAL:
        assert abs(err[k]) <= 0.03, (k, err[k])
    assert abs(err["F_coulomb_N"]) <= 0.10, err["F_coulomb_N"]


def test_randomized_motors_electrical_within_3_percent_or_a_named_fault():
    """Eight motors the drive has never seen, configured from the nominal file: each run
    either stops on a named drive fault (the integrity monitor refusing to work blind
    on a configuration that is too far off) or returns R, L_d, L_q within 3 %. Measured:
    8 of 8 complete (R, L_d, L_q within 1.3 %). Motor 6 used to stop at a standstill start
    (EST_HF_ANGLE: it starts on the alignment's unstable equilibrium, docs/identify.md)
    until the saliency check turned the estimate by the angle it measured and aligned
    again (FW_SAL_RETRIES); before the start-up stopped feeding the PLL's speed forward,
    2 stopped. Before the back-EMF witness waited for the measured R and L, a third
    stopped on EST_BEMF_MISMATCH during the R steps (R 27 % off)."""
    mot = load_motor("iron_core_linear")
    done = 0
    for seed in range(8):
        plant = _random_plant(seed)
        try:
            r = identify(mot, plant=plant)
        except RuntimeError as e:
            assert "drive fault 0xFF" in str(e), e
            continue
        done += 1
        err = r.rel_error(truth_of(mot, plant))
        for k in ELECTRICAL:
            assert abs(err[k]) <= 0.03, (seed, k, err[k])
    assert done == 8, done


def _mechanical_cases():
    mot = load_motor("iron_core_linear")
    cases = [(load_motor(n), None) for n in ("paper_salient", "iron_core_linear")]
    return cases + [(mot, _random_plant(seed)) for seed in range(8)]


@functools.cache
def _mechanical(k: int):
    """Case k of :func:`_mechanical_cases` identified once for the tests below: the
    result, or the drive fault's message."""
    mot, plant = _mechanical_cases()[k]
    try:
        return identify(mot, plant=plant)
    except RuntimeError as e:
        assert plant is not None and "drive fault 0xFF" in str(e), e
        return str(e)


def test_psi_f_mass_and_coulomb_friction():
    """psi_f within 3 %, mass and Coulomb friction within 10 % on the shipped motors and
    on every randomized motor the drive completes (the others stop on a named fault, see
    above). Measured: psi_f within 0.7 %, mass +0.9 ... -7.4 %, Coulomb -0.3 ... +2.6 %
    (from the constant-speed passes; from the profile runs it was -1.0 ... -7.8 %);
    before the matched filtering and the cogging terms: psi_f to -21 %, mass to -40 %."""
    done = 0
    for k, (mot, plant) in enumerate(_mechanical_cases()):
        r = _mechanical(k)
        if isinstance(r, str):
            continue
        done += 1
        err = r.rel_error(truth_of(mot, plant))
        assert abs(err["psi_f_Wb"]) <= 0.03, (mot.name, plant, err["psi_f_Wb"])
        assert abs(err["mass_kg"]) <= 0.10, (mot.name, plant, err["mass_kg"])
        assert abs(err["F_coulomb_N"]) <= 0.10, (mot.name, plant, err["F_coulomb_N"])
        # the stated one-sigma uncertainty must cover the error within 4 sigma
        for k2 in ("psi_f_Wb", "mass_kg", "F_coulomb_N"):
            truth = truth_of(mot, plant)[k2]
            assert abs(r.values[k2] - truth) <= 4.0 * r.sigma[k2] + 0.01 * truth, \
                (k2, r.sigma[k2])
    assert done == len(_mechanical_cases()), done  # all 10 since FW_SAL_RETRIES


def test_viscous_friction_target():
    """Viscous friction within 10 % (the issue's target) on the same motors, from the
    constant-speed passes at two speeds in each direction (docs/identify.md, step 6).
    Measured: paper_salient +4.9 %, iron_core_linear -1.3 %, the randomized motors
    -3.7 ... +3.9 % (before the wider observer on the back-EMF, bemf_obs_bw: -8.0 %,
    -2.0 %, -1.1 ... -5.6 %); from the profile runs alone (0.08-0.3 m/s) it was +8 ...
    +91 %. The stated one-sigma (with its systematic 2 %) covers the error within 4 sigma."""
    done = 0
    for k, (mot, plant) in enumerate(_mechanical_cases()):
        r = _mechanical(k)
        if isinstance(r, str):
            continue
        done += 1
        truth = truth_of(mot, plant)["b_visc_Ns_per_m"]
        err = r.rel_error(truth_of(mot, plant))["b_visc_Ns_per_m"]
        assert abs(err) <= 0.10, (mot.name, plant, err)
        assert abs(r.values["b_visc_Ns_per_m"] - truth) <= 4.0 * r.sigma["b_visc_Ns_per_m"], \
            (mot.name, plant, err, r.sigma["b_visc_Ns_per_m"] / truth)
    assert done == len(_mechanical_cases()), done  # all 10 since FW_SAL_RETRIES


def test_motor_file_round_trip(tmp_path):
    """The identified values make a motor file the loader accepts."""
    from sim_fallback._motors import load_motor as load

    mot = load_motor("paper_salient")
    r = identify(mot)
    f = tmp_path / "identified.toml"
    f.write_text(r.motor_toml("identified", mot))
    m2 = load(f)
    assert abs(m2.plant["R_ohm"] - r.values["R_ohm"]) < 1e-6 * r.values["R_ohm"] + 1e-9


def test_an_inverter_with_dead_time_does_not_pass_for_back_emf():
    """realistic_linear (1.5 us dead time, 0.9 V device drops, the drive's dead-time
    compensation on): the inverter's voltage error left after the compensation has one
    sign per direction; with one mean speed per direction it passed for back-EMF (psi_f
    -23.5 %, mass -25.7 %, Coulomb -23.8 %, and step 6 stopped on a fault). The profile
    runs at two mean speeds separate it: psi_f within 8 %, mass and Coulomb friction
    within 12 % (measured -5.5 %, -8.3 %, -3.2 %), every step completed. On
    iron_core_linear (an ideal inverter) the term is not resolved and not fitted."""
    mot = load_motor("realistic_linear")
    r = identify(mot, seed=1)
    err = r.rel_error(truth_of(mot))
    assert abs(err["psi_f_Wb"]) <= 0.08, err
    assert abs(err["mass_kg"]) <= 0.12, err
    assert abs(err["F_coulomb_N"]) <= 0.12, err
    assert not any("stopped" in ln for ln in r.log), r.log
    (psi_line,) = [ln for ln in r.log if ln.startswith("psi_f ")]
    assert "inverter voltage error" in psi_line and "V against i_q's sign" in psi_line
    ideal = _mechanical(1)  # iron_core_linear, identified above
    (psi_line,) = [ln for ln in ideal.log if ln.startswith("psi_f ")]
    assert "no inverter voltage error resolved" in psi_line, psi_line
