"""The audible-noise metrics (sim_fallback.metrics: thrust_ripple_dBA, phase_current_dBA,
inj_copper_loss_W; docs/audible_noise.md) against analytic references: the IEC 61672
A-weighting's tabulated values, sines of known amplitude, Parseval, a triangle wave's
Fourier series, a square wave's copper loss; then through a campaign run's analysis."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from sim_libs import needs_sim

from sim_fallback import metrics as M

FS = 24000.0  # the control rate (Hz)
N = 7200      # 0.3 s: every test frequency below is on a bin (fs / N = 3.33 Hz)
T = np.arange(N) / FS


def _db(p: float) -> float:
    return 10.0 * math.log10(p)


# IEC 61672-1:2013 Table 3 (A weighting, dB, at the nominal frequencies' exact base-10
# values: 31.5 Hz is 10^1.5 Hz)
IEC_A = {31.5: -39.4, 63.0: -26.2, 100.0: -19.1, 125.0: -16.1, 250.0: -8.6, 500.0: -3.2,
         1000.0: 0.0, 2000.0: 1.2, 4000.0: 1.0, 8000.0: -1.1, 10000.0: -2.5, 16000.0: -6.6,
         20000.0: -9.3}


@pytest.mark.parametrize("f,want", sorted(IEC_A.items()))
def test_a_weighting_is_iec_61672(f: float, want: float) -> None:
    exact = 1000.0 * 10 ** (round(10 * math.log10(f / 1000.0)) / 10)  # the table's base-10 f
    assert float(M.a_weighting_db(exact)) == pytest.approx(want, abs=0.05)


def test_a_sine_at_1_khz_reads_its_rms_and_at_100_hz_19_db_less() -> None:
    a = 2.0
    rms_db = _db(a**2 / 2)  # 3.01 dB re 1
    l1k = M.band_level_db(a * np.sin(2 * np.pi * 1000.0 * T + 0.3), FS)
    l100 = M.band_level_db(a * np.sin(2 * np.pi * 100.0 * T), FS)
    assert l1k == pytest.approx(rms_db, abs=0.01)
    assert l100 - rms_db == pytest.approx(-19.1, abs=0.05)
    # the reference: dB re ref
    assert M.band_level_db(a * np.sin(2 * np.pi * 1000.0 * T), FS, ref=2.0) == pytest.approx(
        rms_db - _db(4.0), abs=0.01)
    # flat (unweighted): the RMS at any frequency in the band
    assert M.band_level_db(a * np.sin(2 * np.pi * 100.0 * T), FS, weighted=False) == \
        pytest.approx(rms_db, abs=0.01)


def test_parseval_on_bins_is_exact() -> None:
    """Tones on bins (Hann window, periodic): the band's power is the sum of a^2 / 2."""
    tones = [(0.7, 500.0), (0.2, 3000.0), (1.3, 7000.0), (0.05, 11000.0)]
    x = sum(a * np.cos(2 * np.pi * f * T + i) for i, (a, f) in enumerate(tones))
    want = _db(sum(a**2 / 2 for a, _ in tones))
    # (to 1e-6 dB: the linear trend removed first is not exactly zero for a tone)
    assert M.band_level_db(x, FS, band_hz=(0.0, FS / 2), weighted=False) == \
        pytest.approx(want, abs=1e-6)
    # weighted: each tone's power times its |A|^2
    want_a = _db(sum(a**2 / 2 * 10 ** (float(M.a_weighting_db(f)) / 10) for a, f in tones))
    # (to 1e-4 dB: the Hann window spreads a tone over three bins, the weighting is read
    # on each)
    assert M.band_level_db(x, FS) == pytest.approx(want_a, abs=1e-4)
    # the band keeps only what lies in it: the two lower tones
    assert M.band_level_db(x, FS, band_hz=(20.0, 4000.0), weighted=False) == \
        pytest.approx(_db(0.7**2 / 2 + 0.2**2 / 2), abs=1e-6)


def test_parseval_for_noise_and_the_psd() -> None:
    x = np.random.default_rng(1).normal(0.0, 0.5, N)
    f, S = M.psd(x, FS)
    assert f[0] == 0.0 and f[-1] == FS / 2 and f.size == N // 2 + 1
    # the window-corrected power of white noise is its variance (within its scatter)
    assert np.sum(S) * FS / N == pytest.approx(np.var(x), rel=0.05)
    assert M.band_level_db(x, FS, band_hz=(0.0, FS / 2), weighted=False) == \
        pytest.approx(_db(np.var(x)), abs=0.2)


def test_the_mean_the_trend_and_what_lies_below_20_hz_do_not_count() -> None:
    tone = 0.1 * np.sin(2 * np.pi * 1000.0 * T)
    slow = 50.0 + 30.0 * T + 5.0 * np.sin(2 * np.pi * 6.67 * T)  # thrust, motion, fundamental
    assert M.band_level_db(tone + slow, FS) == pytest.approx(M.band_level_db(tone, FS),
                                                             abs=0.01)
    assert M.band_level_db(slow, FS) < M.band_level_db(tone, FS) - 40.0


def _triangle(n_per: int) -> np.ndarray:
    """Unit triangle wave with its corners on samples (period n_per samples)."""
    k = np.arange(N) % n_per
    q = n_per // 4
    return np.where(k < q, k / q, np.where(k < 3 * q, 2.0 - k / q, k / q - 4.0))


@pytest.mark.parametrize("n_per", [4, 8, 24])
def test_linear_hold_reproduces_a_triangle_waves_fourier_series(n_per: int) -> None:
    """A square-wave voltage held over control periods drives a triangle current with its
    corners on the samples: read as the straight lines through them (hold linear) its
    in-band power is the Fourier series' (odd harmonics 8 / (pi^2 k^2)) up to 20 kHz,
    beyond the record's Nyquist frequency."""
    f0 = FS / n_per
    ks = [k for k in range(1, 40, 2) if k * f0 <= 20000.0]  # 6 kHz: 1 and 3 (18 kHz)
    x = _triangle(n_per)
    want = _db(sum((8 / (math.pi**2 * k**2)) ** 2 / 2 for k in ks))
    assert M.band_level_db(x, FS, weighted=False, hold="linear") == pytest.approx(want,
                                                                                  abs=1e-6)
    want_a = _db(sum((8 / (math.pi**2 * k**2)) ** 2 / 2
                     * 10 ** (float(M.a_weighting_db(k * f0)) / 10) for k in ks))
    assert M.band_level_db(x, FS, hold="linear") == pytest.approx(want_a, abs=1e-4)
    # the samples alone overstate the fundamental by 1 / sinc^2(f0 / fs)
    if n_per == 4:
        assert M.band_level_db(x, FS, weighted=False) == pytest.approx(_db(0.5), abs=1e-9)


def test_hold_must_be_known() -> None:
    with pytest.raises(ValueError, match="hold"):
        M.band_level_db(np.ones(10), FS, hold="cubic")


def test_short_or_broken_records_are_nan() -> None:
    assert math.isnan(M.band_level_db(np.ones(3), FS))
    assert math.isnan(M.band_level_db(np.array([1.0, np.nan, 2.0, 3.0, 4.0]), FS))
    assert M.band_level_db(np.zeros(100), FS) == -math.inf


def test_copper_loss_of_a_square_wave() -> None:
    """A +-a square wave of one injection period on i_d: 3/2 R a^2 from its samples,
    whatever the d and q currents' steady and slow parts."""
    a, R, n_inj = 0.25, 0.958, 8
    sq = np.where(np.arange(N) % n_inj < n_inj // 2, a, -a)
    i_q = 3.0 + 0.0 * T
    assert M.injection_copper_loss_W(sq, i_q, n_inj, R) == pytest.approx(1.5 * R * a**2,
                                                                         rel=1e-12)
    assert M.injection_copper_loss_W(sq + 0.7, i_q - 0.2, n_inj, R) == pytest.approx(
        1.5 * R * a**2, rel=1e-12)
    # on the q axis as on the d axis; both add
    assert M.injection_copper_loss_W(sq, sq, n_inj, R) == pytest.approx(3 * R * a**2,
                                                                        rel=1e-12)
    # a fundamental of a few Hz is (nearly) no HF loss
    slow = 2.0 * np.sin(2 * np.pi * 6.67 * T)
    assert M.injection_copper_loss_W(sq + slow, i_q, n_inj, R) == pytest.approx(
        1.5 * R * a**2, rel=1e-4)
    # and it matches the HF ripple RMS (the reproduction's ripple_d / ripple_q)
    h = M.hf_part(sq + slow, n_inj)
    assert h.size == N - n_inj + 1
    assert np.sqrt(np.mean(h**2)) == pytest.approx(a, rel=1e-4)
    # read as straight lines between the samples, two of every n_inj intervals cross
    # from +a to -a (mean square a^2 / 3): a^2 (1 - 4 / (3 n_inj))
    assert M.injection_copper_loss_W(sq, i_q, n_inj, R, hold="linear") == pytest.approx(
        1.5 * R * a**2 * (1 - 4 / (3 * n_inj)), rel=1e-3)


@pytest.mark.parametrize("n_inj", [4, 8, 24])
def test_copper_loss_of_the_triangle_current_a_square_voltage_drives(n_inj: int) -> None:
    """The injection's current: a triangle of peak A with its corners on the samples;
    its copper loss is 3/2 R A^2 / 3 (its RMS A / sqrt(3)), which the straight lines
    give exactly and the samples overstate (by 3/2 at 4 samples per period)."""
    A, R = 0.3, 2.0
    tri = A * _triangle(n_inj)
    zero = 0.0 * T
    exact = 1.5 * R * A**2 / 3
    assert M.injection_copper_loss_W(tri, zero, n_inj, R, hold="linear") == pytest.approx(
        exact, rel=2e-3)
    sampled = M.injection_copper_loss_W(tri, zero, n_inj, R)
    assert sampled > exact * 1.001
    if n_inj == 4:
        assert sampled == pytest.approx(1.5 * exact, rel=2e-3)
    assert M.mean_square(np.array([0.0, 1.0])) == 0.5
    assert M.mean_square(np.array([0.0, 1.0]), "linear") == pytest.approx(1 / 3)


def test_phase_current_level() -> None:
    """An HF current a sin(2 pi f t) on the d axis of a rotating frame: each phase carries
    it times cos(theta - k 120 deg), on average over the phases half its power; the
    fundamental (i_q at 6.67 Hz) is below the band."""
    a, f = 0.3, 3000.0
    theta = 2 * np.pi * 6.67 * T + 0.4
    i_d = a * np.sin(2 * np.pi * f * T)
    i_q = 3.0 + 0.0 * T
    iabc = M.phase_currents(i_d, i_q, theta)
    assert np.allclose(iabc.sum(axis=1), 0.0, atol=1e-12)
    assert np.allclose(iabc[:, 0], i_d * np.cos(theta) - i_q * np.sin(theta))
    # (hold linear: the straight lines through the samples, sinc^4(f / fs) less power)
    want = _db(a**2 / 2 / 2) + float(M.a_weighting_db(f)) + _db(np.sinc(f / FS) ** 4)
    assert M.phase_current_level_db(i_d, i_q, theta, FS) == pytest.approx(want, abs=0.05)
    assert M.phase_current_level_db(0 * i_d, i_q, theta, FS) < want - 50.0


def test_the_definitions_are_one_each_and_documented() -> None:
    assert tuple(M.AUDIBLE_DEFS) == M.AUDIBLE_METRICS
    assert set(M.AUDIBLE_METRICS) <= set(M.WINDOW_METRICS)
    md = M.audible_definitions_markdown()
    for name, d in M.AUDIBLE_DEFS.items():
        assert f"`<window>.{name}`" in md and d.unit in md
        assert set(d.channels) <= set(M.SCENARIO_CHANNELS)
    assert M.AUDIBLE_DEFS["thrust_ripple_dBA"].unit == "dB(A) re 1 N"
    assert M.AUDIBLE_DEFS["phase_current_dBA"].unit == "dB(A) re 1 A"
    assert M.AUDIBLE_DEFS["inj_copper_loss_W"].unit == "W"


def _fake_run() -> SimpleNamespace:
    t = np.arange(int(1.0 * FS)) / FS
    n_inj = 8
    sq = np.where(np.arange(t.size) % n_inj < n_inj // 2, 0.2, -0.2)
    data = {"t_s": t, "i_d_A": sq, "i_q_A": 2.0 + 0 * t, "theta_e_rad": 41.9 * t,
            "force_N": 100.0 + np.where(t >= 0.5, 0.5, 0.05) * np.sin(2 * np.pi * 1000 * t)}
    return SimpleNamespace(data=data, valid=True, motor=SimpleNamespace(plant={"R_ohm": 2.0}))


def test_analyse_computes_them_over_a_campaign_window() -> None:
    res = _fake_run()
    windows = {"before": [0.2, 0.5 - 1 / FS], "after": [0.7, 1.0]}
    names = [f"{w}.{m}" for w in windows for m in M.AUDIBLE_METRICS]
    assert M.needs_analysis(names, windows)
    out = M.analyse(res, names, windows, None, 8)
    l1k = float(M.a_weighting_db(1000.0)) + 10 * math.log10(float(np.sinc(1000 / FS)) ** 4)
    assert out["before.thrust_ripple_dBA"] == pytest.approx(_db(0.05**2 / 2) + l1k, abs=0.02)
    assert out["after.thrust_ripple_dBA"] == pytest.approx(_db(0.5**2 / 2) + l1k, abs=0.02)
    sq_loss = 1.5 * 0.2**2 * (1 - 4 / (3 * 8))  # per ohm, straight lines (test above)
    assert out["after.inj_copper_loss_W"] == pytest.approx(2.0 * sq_loss, rel=1e-3)
    # the run's plant resistance (a campaign's plant.R_ohm) over the motor file's
    out2 = M.analyse(res, ["after.inj_copper_loss_W"], windows, None, 8, R_ohm=1.0)
    assert out2["after.inj_copper_loss_W"] == pytest.approx(1.0 * sq_loss, rel=1e-3)
    # a run that is not valid has none; a channel not recorded gives NaN
    res.valid = False
    assert math.isnan(M.analyse(res, names, windows, None, 8)["after.thrust_ripple_dBA"])
    res.valid = True
    del res.data["force_N"]
    assert math.isnan(M.analyse(res, names, windows, None, 8)["after.thrust_ripple_dBA"])


@needs_sim
def test_on_the_simulated_drive_the_levels_follow_the_injection() -> None:
    """The paper's load step: halving u_inj halves the HF current and the thrust ripple it
    causes (-6 dB, within 1.5 dB: other ripple is there too), quarters the copper loss;
    the copper loss is 3/2 R (ripple_d^2 + ripple_q^2) of the same window, the samples'
    mean square a little above the straight lines' (8 samples per period: 9/8 for a
    triangle)."""
    from sim_fallback import load_motor, paper_scenario
    mot = load_motor("paper_salient")
    out = {}
    for u in (50.0, 25.0):
        r = paper_scenario("load_step", fw={"u_inj_V": u}, channels=list(M.SCENARIO_CHANNELS))
        assert r.valid
        out[u] = M.analyse(r, ["steady." + m for m in M.AUDIBLE_METRICS] + ["steady.ripple_d",
                                                                           "steady.ripple_q"],
                           {"steady": [0.7, 1.0]}, None, 8)
    hi, lo = out[50.0], out[25.0]
    assert lo["steady.thrust_ripple_dBA"] - hi["steady.thrust_ripple_dBA"] == pytest.approx(
        -6.0, abs=1.5)
    assert lo["steady.phase_current_dBA"] - hi["steady.phase_current_dBA"] == pytest.approx(
        -6.0, abs=0.5)
    assert lo["steady.inj_copper_loss_W"] / hi["steady.inj_copper_loss_W"] == pytest.approx(
        0.25, rel=0.1)
    R = float(mot.plant["R_ohm"])
    sampled = 1.5 * R * (hi["steady.ripple_d"] ** 2 + hi["steady.ripple_q"] ** 2)
    assert hi["steady.inj_copper_loss_W"] == pytest.approx(sampled / (9 / 8), rel=0.03)
