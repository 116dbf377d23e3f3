"""Campaigns: file validation, deterministic sampling, Parquet results that survive
an interruption, recorded failures, Dask and serial runs that agree."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from simcampaign._campaign import (
    CampaignError,
    judge,
    load_campaign,
    load_results,
    parse_campaign,
    run_campaign,
    statistic,
)

ROOT = Path(__file__).resolve().parents[2]
METRICS = ("position_error_rms_rad", "position_error_max_rad")


def _parse(text: str):
    return parse_campaign(yaml.safe_load(text), yaml.compose(text), Path("c.yaml"), METRICS)


TINY = """
name: tiny
base: {scenario: load_step, t_end: 0.3}
sampling: {method: grid}
axes:
  seed: {values: [1, 2, 3]}
metrics: [position_error_rms_rad]
limits:
  - {metric: position_error_rms_rad, stat: max, max: 0.5}
"""


def test_shipped_campaign_is_valid():
    c = load_campaign(ROOT / "campaigns/mismatch_noise.yaml", METRICS)
    assert len(c.runs()) == 64


@pytest.mark.parametrize("text,where", [
    ("name: x\nbase: {}\naxes: {}\nmetrics: [position_error_rms_rad]\n", "c.yaml:3: axes"),
    ("name: x\nbase: {}\naxes:\n  speed: {values: [1]}\nmetrics: [position_error_rms_rad]\n",
     "c.yaml:4: axes.speed"),
    ("name: x\nbase: {}\naxes:\n  plant.R_ohm: {range: [.nan, 1]}\n"
     "metrics: [position_error_rms_rad]\n", "axes.plant.R_ohm: range must be"),
    ("name: x\nbase: {}\nsampling: {method: sobol}\naxes:\n  seed: {values: [1]}\n"
     "metrics: [position_error_rms_rad]\n", "c.yaml:3: sampling.method"),
    ("name: x\nbase: {}\naxes:\n  seed: {values: [1]}\nmetrics: [speed_error]\n",
     "unknown metric 'speed_error'"),
    ("name: x\nbase: {scenario: jog}\naxes:\n  seed: {values: [1]}\n"
     "metrics: [position_error_rms_rad]\n", "c.yaml:2: base.scenario"),
])
def test_errors_name_file_line_field(text, where):
    with pytest.raises(CampaignError) as ei:
        _parse(text)
    assert where in str(ei.value)


def test_lhs_is_stratified_and_deterministic():
    text = TINY.replace("sampling: {method: grid}", "sampling: {method: lhs, n: 50, seed: 3}")
    text = text.replace("seed: {values: [1, 2, 3]}", "plant.R_ohm: {range: [1.0, 2.0]}\n"
                        "  fw.L_q_H: {scale: [0.5, 1.5]}")
    a, b = _parse(text).runs(), _parse(text).runs()
    assert a == b
    for key, lo, hi in (("plant.R_ohm", 1.0, 2.0), ("fw.L_q_H", 0.5, 1.5)):
        u = (np.array([r[key] for r in a]) - lo) / (hi - lo)
        # one sample in each of the 50 strata
        assert sorted(np.floor(u * 50).astype(int)) == list(range(50))


def test_serial_run_resumes_and_records_failures(tmp_path):
    c = _parse(TINY)
    seen = []

    def stop_after_two(done, total, elapsed):
        seen.append(done)
        if done == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_campaign(c, tmp_path, serial=True, batch=1, progress=stop_after_two)
    rdir = tmp_path / "tiny"
    assert sorted(load_results(rdir)["run"]) == [0, 1]  # nothing finished was lost
    run_campaign(c, tmp_path, serial=True, batch=1)
    res = load_results(rdir)
    assert sorted(res["run"]) == [0, 1, 2]  # only the missing run was added
    rms = np.asarray(res["position_error_rms_rad"], dtype=float)
    assert np.all(np.isfinite(rms)) and np.all(rms < 0.1)
    assert all(v["ok"] for v in judge(c, res))
    # a run that cannot be built is recorded with its error, not dropped: each axis's
    # values are accepted alone at load, but L_d0 = 2 mH with dL_sat = 3 mH the simulator
    # refuses (dL_sat_H < L_d0_H)
    bad = _parse(TINY.replace("seed: {values: [1, 2, 3]}", "plant.L_d0_H: {values: [0.012, "
                              "0.002]}\n  plant.dL_sat_H: {values: [0.003]}"))
    run_campaign(bad, tmp_path / "bad", serial=True)
    rb = load_results(tmp_path / "bad" / "tiny")
    assert sorted(rb["run"]) == [0, 1]
    errs = [e for e in rb["error"] if e]
    assert len(errs) == 1 and "dL_sat_H" in errs[0] and "dL_sat_H" in rb["error"][1]
    assert statistic(rb["position_error_rms_rad"], "fail_fraction") == 0.5


def _same_rows(a: dict, b: dict) -> None:
    """Two results hold the same runs with the same values (every column but wall_s)."""
    assert list(a["run"]) == sorted(a["run"]) and list(b["run"]) == sorted(b["run"])
    assert set(a) == set(b)
    for k in a:
        if k == "wall_s":
            continue
        if a[k].dtype == object and any(isinstance(v, str) or v is None for v in a[k]):
            assert list(a[k]) == list(b[k]), k
        else:
            np.testing.assert_array_equal(a[k].astype(float), b[k].astype(float), err_msg=k)


def test_dask_local_cluster_matches_serial(tmp_path):
    """The local cluster's workers write the parts themselves; a remote scheduler's
    send the rows back to the client, which writes them: both give the serial rows."""
    pytest.importorskip("dask.distributed")
    from dask.distributed import Client

    from simcampaign._campaign import _shares_our_files, start_local_cluster
    text = TINY.replace("seed: {values: [1, 2, 3]}", "seed: {values: [1, 2, 3]}\n"
                        "  plant.L_d0_H: {values: [0.012, 0.002]}\n"  # half the runs fail:
                        "  plant.dL_sat_H: {values: [0.003]}")  # dL_sat_H >= L_d0_H
    c = _parse(text)
    run_campaign(c, tmp_path / "s", serial=True)
    cl, client = start_local_cluster(2)
    try:
        assert _shares_our_files(client)
        run_campaign(c, tmp_path / "d", scheduler=client, batch=4)
        with Client(cl.scheduler_address) as remote:  # as --scheduler ADDRESS
            assert not _shares_our_files(remote)
            run_campaign(c, tmp_path / "r", scheduler=remote, batch=4)
        run_campaign(c, tmp_path / "a", scheduler=cl.scheduler_address, batch=4)
    finally:
        client.close()
        cl.close()
    s = load_results(tmp_path / "s" / "tiny")
    assert list(s["run"]) == list(range(6)) and sum(e is not None for e in s["error"]) == 3
    for other in ("d", "r", "a"):
        rdir = tmp_path / other / "tiny"
        assert len(list(rdir.glob("part-*.parquet"))) >= 2  # batches of 4 and the rest
        _same_rows(s, load_results(rdir))


def test_cli_on_the_local_cluster_prints_no_dask_chatter(tmp_path):
    """`bench campaign` on its local cluster: the verdict lines and the progress bar, not
    the ~30 INFO lines per campaign that importing distributed enables (scheduler ports,
    every worker, the close); `-v` keeps them."""
    pytest.importorskip("dask.distributed")
    import os
    import subprocess
    import sys
    f = tmp_path / "tiny.yaml"
    f.write_text(TINY)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for verbose in ((), ("-v",)):
        p = subprocess.run([sys.executable, "-m", "bench", *verbose, "campaign", str(f),
                            "--workers", "1", "--out", str(tmp_path / f"out{len(verbose)}")],
                           capture_output=True, text=True, env=env, timeout=300)
        assert p.returncode == 0, p.stderr[-2000:]
        assert "3 runs in" in p.stdout + p.stderr
        chatter = [ln for ln in p.stderr.replace("\r", "\n").splitlines()
                   if ln.startswith("INFO distributed")]
        assert bool(chatter) == bool(verbose), chatter[:3]


def test_dask_campaign_resumes_after_interruption(tmp_path):
    """Interrupted after its first task, a local-cluster campaign keeps every run its
    workers wrote (whole parts only) and the next call adds exactly the missing ones."""
    pytest.importorskip("dask.distributed")
    c = _parse(TINY.replace("sampling: {method: grid}", "sampling: {method: random, n: 40, "
                            "seed: 5}").replace("t_end: 0.3", "t_end: 0.05").replace(
        "seed: {values: [1, 2, 3]}", "seed: {range: [0, 1000]}"))
    reported = []

    def stop(done, total, elapsed):
        reported.append(done)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_campaign(c, tmp_path / "d", workers=2, batch=3, progress=stop)
    rdir = tmp_path / "d" / c.name
    (rdir / ".part-r00000000-1.tmp").write_bytes(b"torn")  # a writer killed mid-write
    kept = load_results(rdir)["run"]
    assert len(kept) >= reported[0] > 0 and len(set(kept)) == len(kept)
    run_campaign(c, tmp_path / "d", workers=2, batch=3)
    assert not list(rdir.glob(".part-*"))
    run_campaign(c, tmp_path / "s", serial=True)
    _same_rows(load_results(tmp_path / "s" / c.name), load_results(rdir))


def test_results_count_each_run_once_in_run_order(tmp_path):
    """A chunk run again (its worker died) writes its parts again: same names, and a
    run found in two parts still counts once; rows come back in run order."""
    from simcampaign._campaign import _write_part
    rows = [{"run": k, "error": None, "x": float(k)} for k in (5, 3, 4)]
    _write_part(tmp_path, rows)
    _write_part(tmp_path, rows)  # same first run: replaces the part
    _write_part(tmp_path, [{"run": 9, "error": None, "x": 9.0}, rows[1]])
    assert len(list(tmp_path.glob("part-*.parquet"))) == 2
    res = load_results(tmp_path)
    assert list(res["run"]) == [3, 4, 5, 9] and list(res["x"]) == [3.0, 4.0, 5.0, 9.0]


@pytest.mark.parametrize("scenario,extractor,seed,plant,fw,kw,valid", [
    ("load_step", "sogi_adaptive", 3, None, None, {}, True),
    ("speed_reversal", "pseudo", 1, {"adc_noise_counts": 2.0}, None, {}, True),
    ("speed_reversal", "pseudo", 1, None, {"L_q_H": 0.006}, {}, False),  # faults
    ("startup", "sogi", 4, None, None, {"noise": 0.5}, True),
    ("load_step", "sogi_adaptive", 0, None, {"f_inj_Hz": 1e6}, {}, False),  # refused
    ("load_step", "sogi_adaptive", 2, None, None, {"x0_m": 0.004, "record_decimation": 3},
     True),
])
def test_campaign_runs_give_paper_scenario_numbers(scenario, extractor, seed, plant, fw, kw,
                                                   valid):
    """The lean run a campaign makes (``metrics=``: only those metrics and the channels
    they need) gives bit for bit the full run's numbers."""
    from sim_fallback import METRIC_NAMES, paper_scenario
    from simcampaign._campaign import _motor_and_config
    motor, _ = _motor_and_config("paper_salient", extractor)
    kw = {"t_end": 0.3, "record_decimation": 8, **kw}
    r = paper_scenario(scenario, extractor=extractor, motor=motor, seed=seed, plant=plant,
                       fw=fw, **kw)
    for want in (list(METRIC_NAMES), ["position_error_rms_rad"], ["settling_time_s",
                                                                   "no_such_metric"]):
        lean = paper_scenario(scenario, extractor=extractor, motor=motor, seed=seed,
                              plant=plant, fw=fw, metrics=want, **kw)
        assert lean.fault_code == r.fault_code
        known = [m for m in want if m in METRIC_NAMES]
        assert list(lean.metrics) == known
        # only what those metrics need was recorded
        from sim_fallback.metrics import METRIC_DEFS
        need = {"t_s", "fault_code", "start_phase"}.union(
            *(METRIC_DEFS[m].channels for m in known))
        assert set(lean.data) == need
        np.testing.assert_array_equal(np.array([lean.metrics[m] for m in known]),
                                      np.array([r.metrics[m] for m in known]))
    assert r.valid == valid


def test_tasks_cover_every_run_once_large_first():
    from simcampaign._campaign import _chunks
    todos = [[{"run": k} for k in range(1000)], [], [{"run": k} for k in range(37)]]
    for largest in (128, 1024):
        tasks = _chunks(todos, 2, largest)
        for i, todo in enumerate(todos):
            assert [r for j, rs in tasks if j == i for r in rs] == todo
        sizes = [len(rs) for _, rs in tasks]
        assert max(sizes) <= largest and sizes[0] == min(largest, 260) and len(tasks) < 30
        assert sizes[-2] <= 8  # short tasks at the end: no worker waits on a long one
    assert len(_chunks(todos, 2, 1024)) < len(_chunks(todos, 2, 128))


def test_statistics_against_numpy():
    v = np.array([0.1, 0.2, float("nan"), 0.4])
    assert statistic(v, "p50") == pytest.approx(np.percentile([0.1, 0.2, 0.4], 50))
    assert statistic(v, "max") == 0.4
    assert statistic(v, "fail_fraction") == 0.25
    assert math.isnan(statistic(np.array([float("nan")]), "mean"))


def test_report_shows_limits_worst_runs_and_comparison(tmp_path):
    pytest.importorskip("plotly")
    from simcampaign._report import write_report
    c = _parse(TINY)
    run_campaign(c, tmp_path / "a", serial=True)
    c2 = _parse(TINY.replace("values: [1, 2, 3]", "values: [4, 5]"))
    run_campaign(c2, tmp_path / "b", serial=True)
    out = write_report(c, tmp_path / "a" / "tiny", other=tmp_path / "b" / "tiny")
    text = out.read_text()
    assert "PASSED: 1 of 1 limits hold" in text
    # every worst run can be replayed, from any directory (the file's absolute path)
    assert f"bench campaign {Path('c.yaml').resolve()} --replay 2" in text
    assert text.count("Plotly.newPlot") == 2  # one histogram, one scatter per axis
    assert "plotly.js" in text.lower() or "plotly v" in text.lower()  # embedded: offline
    res = load_results(tmp_path / "a" / "tiny")
    worst = max(float(x) for x in res["position_error_rms_rad"])
    assert f"{worst:.4g}" in text


# ---- named axes, string axes, windows, traces (the paper reproduction's campaigns) ----

def test_every_reproduction_campaign_is_valid():
    files = sorted((ROOT / "campaigns/reproduction").glob("*.yaml"))
    assert len(files) == 15
    from sim_fallback.metrics import METRIC_NAMES
    names = {load_campaign(f, METRIC_NAMES).name for f in files}
    assert len(names) == len(files)  # each its own results folder


BAD = "name: x\nbase: {scenario: load_step%s}\naxes:\n%s\nmetrics: [%s]\n"


@pytest.mark.parametrize("base,axes,metrics,where", [
    ("", "  extractor: {values: [pseudo, sogi_fast]}", "position_error_rms_rad",
     "c.yaml:4: axes.extractor: need values: [...] of pseudo, sogi, sogi_adaptive; "
     "'sogi_fast' is not one"),
    ("", "  motor: {values: [no_such_motor]}", "position_error_rms_rad",
     "c.yaml:4: axes.motor: need values: [...] of motor names ("),
    ("", "  k:\n    values: [1, 2]\n    set: {fw.pll_kp: 86.6 * y}", "position_error_rms_rad",
     "c.yaml:6: axes.k.set.fw.pll_kp: '86.6 * y': need a product of numbers, x, x^N"),
    ("", "  k:\n    values: [1, 2]\n    set: {fw.pll_kp: plant.L_x * x}",
     "position_error_rms_rad", "c.yaml:6: axes.k.set.fw.pll_kp: no plant parameter 'L_x'"),
    ("", "  k:\n    values: [1, 2]\n    set: {fw.no_field: x}", "position_error_rms_rad",
     "c.yaml:6: axes.k.set.fw.no_field: no drive configuration field 'no_field'"),
    ("", "  plant.R_ohms: {values: [1.0]}", "position_error_rms_rad",
     "c.yaml:4: axes.plant.R_ohms: no plant parameter 'R_ohms'"),
    ("", "  v:\n    cases:\n      a: {extractor: sogi, speed: 3}", "position_error_rms_rad",
     "c.yaml:6: axes.v.cases.a.speed: target must be extractor, noise, x0_m"),
    ("", "  k:\n    values: [1]\n    set: {fw.L_q_H: plant.L_q_H * x}\n"
     "  fw.L_q_H: {values: [0.01]}", "position_error_rms_rad",
     "axes.fw.L_q_H: sets fw.L_q_H, which axis k sets too"),
    (", windows: {steady: [0.7, 0.2]}", "  seed: {values: [0]}", "steady.pos_rms",
     "c.yaml:2: base.windows.steady: [0.7, 0.2]: need [t0, t1] with 0 <= t0 < t1"),
    (", windows: {steady: [0.7, 1.0]}", "  seed: {values: [0]}", "tail.pos_rms",
     "unknown metric 'tail.pos_rms'"),
    ("", "  seed: {values: [0]}", "t_speed_back_s",
     "c.yaml:5: metrics: t_speed_back_s needs base.event_s"),
    (", trace: {signals: [omega]}", "  seed: {values: [0]}", "position_error_rms_rad",
     "c.yaml:2: base.trace: need {signals"),
    (", extractor: sogi2", "  seed: {values: [0]}", "position_error_rms_rad",
     "c.yaml:2: base.extractor: 'sogi2' not one of"),
    (", tend: 1", "  seed: {values: [0]}", "position_error_rms_rad",
     "c.yaml:2: base.tend: unknown; known: scenario"),
])
def test_extension_errors_name_file_line_field(base, axes, metrics, where):
    with pytest.raises(CampaignError) as ei:
        _parse(BAD % (base, axes, metrics))
    assert where in str(ei.value)


def test_set_expressions_evaluate_like_python():
    from simcampaign._campaign import eval_expr, parse_expr
    plant = {"L_d0_H": 0.012, "R_ohm": 0.958}
    for x in (0.8, 0.9, 1.1, 1.2):  # bit for bit what a hand-written loop computes
        assert eval_expr("1100 * plant.L_d0_H * x", x, plant) == 1100.0 * 0.012 * x
        assert eval_expr("5000 * x^2", x, plant) == 5000.0 * x**2
        assert eval_expr("1e5 * x^3", x, plant) == 1.0e5 * x**3
    assert parse_expr("2 * * x") is None and parse_expr("x + 1") is None


def test_named_and_case_axes_run_what_they_say(tmp_path):
    """A named axis sets its targets and a case its values: each run equals the direct
    simulator call with those arguments (the reference)."""
    import sim_fallback as sf
    c = _parse("""
name: named
base: {scenario: load_step, t_end: 0.3}
sampling: {method: grid}
axes:
  mm: {values: [0.9, 1.1], set: {fw.L_q_H: plant.L_q_H * x}}
  sensing:
    cases:
      ideal: {noise: 0.0, plant.adc_bits: 16, extractor: sogi}
      default: {}
metrics: [position_error_rms_rad]
""")
    runs = c.runs()
    assert [(r["mm"], r["sensing"]) for r in runs] == [
        (0.9, "ideal"), (0.9, "default"), (1.1, "ideal"), (1.1, "default")]
    res = load_results(run_campaign(c, tmp_path, serial=True))
    got = dict(zip(res["run"].astype(int), res["position_error_rms_rad"].astype(float),
                   strict=True))
    mot = sf.load_motor("paper_salient")
    for r in runs:
        kw = ({"noise": 0.0, "plant": {"adc_bits": 16}, "extractor": "sogi"}
              if r["sensing"] == "ideal" else {})
        ex = kw.pop("extractor", "sogi_adaptive")
        ref = sf.paper_scenario("load_step", ex, seed=int(r["seed"]), t_end=0.3,
                                record_decimation=8, channels=[],
                                fw={"L_q_H": mot.plant["L_q_H"] * r["mm"]}, **kw)
        assert got[r["run"]] == ref.metrics["position_error_rms_rad"], r


def test_windows_events_and_traces_are_columns(tmp_path):
    c = _parse("""
name: win
base:
  scenario: load_step
  t_end: 0.7
  record_decimation: 1
  windows: {steady: [0.55, 0.7]}
  event_s: 0.5
  trace: {signals: [t_s, position_error_rad], decimation: 24, seeds: [0]}
sampling: {method: grid}
axes:
  extractor: {values: [pseudo, sogi]}
  seed: {values: [0, 1]}
metrics: [valid, steady.pos_rms, steady.ripple_d, t_est_back_s]
""")
    res = load_results(run_campaign(c, tmp_path, serial=True))
    for k in range(4):
        params = json.loads(res["params"][k])
        tr = res["trace.position_error_rad"][k]
        if params["seed"] == 0:  # kept for seed 0 only, every 24th sample (1 ms)
            assert len(tr) == len(res["trace.t_s"][k]) == 700
            e = np.asarray(tr)[550:]  # t >= 0.55 s
            assert float(np.sqrt(np.mean(e**2))) == pytest.approx(
                float(res["steady.pos_rms"][k]), rel=0.3)  # 1 ms samples of the same error
        else:
            assert tr is None
        assert res["valid"][k] == 1.0
        assert 0.0 < float(res["t_est_back_s"][k]) < 0.2
        assert 0.1 < float(res["steady.ripple_d"][k]) < 0.5  # 50 V / 3 kHz on 12 mH: ~0.2 A


def test_seeds_are_integers_as_the_runs_use_them(tmp_path) -> None:
    """A seed axis over a range gave 96707.0 / 9.671e+04 in the outputs; a run used
    int(seed): the run list now holds that integer."""
    from simcampaign._campaign import load_campaign

    f = tmp_path / "c.yaml"
    f.write_text("name: s\nbase: {scenario: load_step, t_end: 0.3}\n"
                 "sampling: {method: lhs, n: 4, seed: 3}\naxes:\n"
                 "  seed: {range: [0, 100000]}\nmetrics: [position_error_rms_rad]\n")
    runs = load_campaign(f).runs()
    assert all(type(r["seed"]) is int for r in runs)
    assert len({r["seed"] for r in runs}) == 4 and all(0 <= r["seed"] < 100000 for r in runs)


# ---- the linear-units scenario (linear_load_step) ----------------------------------

LINEAR = """
name: lin
base: {scenario: linear_load_step, motor: realistic_linear, speed_mps: 0.1, event_s: 0.2,
       t_end: 0.35, x0_m: random}
sampling: {method: grid}
axes:
  load:
    cases:
      none: {}
      half: {load_rated: 0.5}
      newtons: {load_N: 120.0, speed_mps: -0.1}
  fw.obs_mode: {values: [1, 2]}
  seed: {values: [3]}
metrics: [position_error_rms_rad, position_error_max_rad]
"""


def test_linear_load_step_runs_what_it_says(tmp_path):
    """Each run of a linear_load_step campaign equals the direct simulator call in m/s and
    N (run_scenario with speed_unit="mps", load_unit="N"); load_rated is a fraction of
    K_f i_rated (600 N on realistic_linear); an integer configuration field (obs_mode)
    from an axis; the base's x0_m: random."""
    import sim_fallback as sf
    c = _parse(LINEAR)
    runs = c.runs()
    assert len(runs) == 6
    res = load_results(run_campaign(c, tmp_path, serial=True))
    assert not any(res["error"])
    got = dict(zip(res["run"].astype(int), res["position_error_rms_rad"].astype(float),
                   strict=True))
    assert sf.rated_thrust_N("realistic_linear") == pytest.approx(600.0, rel=1e-4)
    valid = 0
    for r in runs:
        load, speed = {"none": (0.0, 0.1), "half": (0.5 * sf.rated_thrust_N(
            "realistic_linear"), 0.1), "newtons": (120.0, -0.1)}[r["load"]]
        ref = sf.run_scenario("realistic_linear", "sogi_adaptive", speed_ref=speed,
                              speed_unit="mps", load=[(0.0, 0.0), (0.2, load)],
                              load_unit="N", t_end=0.35, seed=3, x0_m="random",
                              record_decimation=8, fw={"obs_mode": int(r["fw.obs_mode"])},
                              metrics=["position_error_rms_rad", "position_error_max_rad"])
        want = ref.metrics["position_error_rms_rad"]
        assert got[r["run"]] == want or (math.isnan(want) and math.isnan(got[r["run"]])), r
        valid += ref.valid
    assert valid >= 4  # most track (a fault is a result: NaN in both)


def test_linear_load_step_replays_as_a_sequence_in_m_per_s_and_newtons():
    """--replay N --full maps a linear_load_step run to a bench sequence: set_speed in
    m/s, the load step in N at event_s, the run's start position."""
    from bench import validate_sequence
    from simcampaign._campaign import linear_args, resolve_run
    from simcampaign._replay import sequence_text
    c = _parse(LINEAR)
    run = c.runs()[2]  # half rated thrust, obs_mode 1
    rr = resolve_run(c.run_base(), run)
    lin = linear_args(c.run_base(), rr.rest, rr.motor)
    assert lin == {"speed_mps": 0.1, "load_N": pytest.approx(300.0, rel=1e-4),
                   "event_s": 0.2, "t_end": 0.35}
    text = sequence_text("lin_run2", "linear_load_step", rr.motor_name, rr.extractor,
                         rr.seed, 0.35, "random", lin)
    assert "set_speed: {value: 0.1, unit: m/s}" in text
    assert f"load_step: {{value: {lin['load_N']!r}, unit: 'N'}}" in text
    assert "wait: {duration_s: 0.2}" in text and "x0: random" in text
    seq = validate_sequence(text, "<lin>")
    assert seq.x0 == "random"


@pytest.mark.parametrize("base,axes,where", [
    ("scenario: linear_load_step, motor: realistic_linear, event_s: 0.2",
     "  seed: {values: [0]}", "c.yaml:2: base.speed_mps: missing: linear_load_step needs"),
    ("scenario: linear_load_step, motor: realistic_linear, speed_mps: 0.1",
     "  seed: {values: [0]}", "c.yaml:2: base.event_s: missing: linear_load_step steps"),
    ("scenario: load_step, load_N: 100",
     "  seed: {values: [0]}", "c.yaml:2: base.load_N: a linear-units scenario's argument"),
    ("scenario: load_step",
     "  speed_mps: {values: [0.1]}", "c.yaml:4: axes.speed_mps: a linear-units scenario's"),
    ("scenario: linear_load_step, motor: realistic_linear, speed_mps: 50, event_s: 0.2",
     "  seed: {values: [0]}", "c.yaml:2: base.speed_mps: 50: allowed [-20, 20] m/s"),
    ("scenario: linear_load_step, motor: realistic_linear, speed_mps: 0.1, event_s: 0.2, "
     "load_N: 10", "  load_rated: {values: [0.5]}", "base.load_N: give the load as load_N"),
    ("scenario: linear_load_step, motor: realistic_linear, speed_mps: 0.1, event_s: 0.2",
     "  load_rated: {range: [0, 20]}", "c.yaml:4: axes.load_rated: [0, 20]: allowed [-10, 10]"),
    ("scenario: load_step",
     "  v:\n    cases:\n      a: {load_N: 3}",
     "c.yaml:6: axes.v.cases.a.load_N: a linear-units scenario's argument"),
    ("scenario: load_step, x0_m: far", "  seed: {values: [0]}",
     "c.yaml:2: base.x0_m: 'far': need random or an initial position"),
    ("scenario: load_step", "  fw.obs_mode: {values: [1, 1.5]}",
     "c.yaml:4: axes.fw.obs_mode: [1, 1.5]: an integer field; need values: [...] of integers"),
    ("scenario: load_step, motor: realistic_linear", "  plant.emf_h5: {values: [0.9]}",
     "c.yaml:4: axes.plant.emf_h5: 0.9; the simulator allows [0, 0.5]"),
])
def test_linear_scenario_errors_name_file_line_field(base, axes, where):
    text = f"name: x\nbase: {{{base}}}\naxes:\n{axes}\nmetrics: [position_error_rms_rad]\n"
    with pytest.raises(CampaignError) as ei:
        _parse(text)
    assert where in str(ei.value)
    assert all(ln.startswith("c.yaml:") for ln in str(ei.value).splitlines())


def test_plant_realism_fields_are_axis_targets():
    """The plant realism (sim_realism_t: emf_h5, cross_L_H, ...) is a plant.<field> target
    like sim_plant_params_t's, scaled by the motor's nominal value."""
    from simcampaign._campaign import resolve_run
    c = _parse("name: r\nbase: {scenario: load_step, motor: realistic_linear}\n"
               "axes:\n  plant.emf_h5: {scale: [0.5, 1.5]}\n  plant.cross_L_H: {values: [0]}\n"
               "metrics: [position_error_rms_rad]\n")
    rr = resolve_run(c.run_base(), c.runs()[0])
    assert rr.plant == {"emf_h5": pytest.approx(0.015), "cross_L_H": 0.0}
