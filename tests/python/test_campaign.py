"""Campaigns: file validation, deterministic sampling, Parquet results that survive
an interruption, recorded failures, Dask and serial runs that agree."""

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from bench._campaign import (
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
    # a run that cannot be built is recorded with its error, not dropped
    bad = _parse(TINY.replace("seed: {values: [1, 2, 3]}", "plant.R_ohm: {values: [1.0, -1.0]}"))
    run_campaign(bad, tmp_path / "bad", serial=True)
    rb = load_results(tmp_path / "bad" / "tiny")
    assert sorted(rb["run"]) == [0, 1]
    errs = [e for e in rb["error"] if e]
    assert len(errs) == 1 and "R_ohm" in errs[0]
    assert statistic(rb["position_error_rms_rad"], "fail_fraction") == 0.5


def test_dask_local_cluster_matches_serial(tmp_path):
    pytest.importorskip("dask.distributed")
    c = _parse(TINY)
    run_campaign(c, tmp_path / "s", serial=True)
    run_campaign(c, tmp_path / "d", workers=2)
    s, d = load_results(tmp_path / "s" / "tiny"), load_results(tmp_path / "d" / "tiny")
    order_s, order_d = np.argsort(s["run"].astype(int)), np.argsort(d["run"].astype(int))
    np.testing.assert_array_equal(s["position_error_rms_rad"][order_s].astype(float),
                                  d["position_error_rms_rad"][order_d].astype(float))


def test_statistics_against_numpy():
    v = np.array([0.1, 0.2, float("nan"), 0.4])
    assert statistic(v, "p50") == pytest.approx(np.percentile([0.1, 0.2, 0.4], 50))
    assert statistic(v, "max") == 0.4
    assert statistic(v, "fail_fraction") == 0.25
    assert math.isnan(statistic(np.array([float("nan")]), "mean"))


def test_report_shows_limits_worst_runs_and_comparison(tmp_path):
    pytest.importorskip("plotly")
    from bench._campaign_report import write_report
    c = _parse(TINY)
    run_campaign(c, tmp_path / "a", serial=True)
    c2 = _parse(TINY.replace("values: [1, 2, 3]", "values: [4, 5]"))
    run_campaign(c2, tmp_path / "b", serial=True)
    out = write_report(c, tmp_path / "a" / "tiny", other=tmp_path / "b" / "tiny")
    text = out.read_text()
    assert "PASSED: 1 of 1 limits hold" in text
    assert "bench campaign c.yaml --replay 2" in text  # every worst run can be replayed
    assert text.count("Plotly.newPlot") == 2  # one histogram, one scatter per axis
    assert "plotly.js" in text.lower() or "plotly v" in text.lower()  # embedded: offline
    res = load_results(tmp_path / "a" / "tiny")
    worst = max(float(x) for x in res["position_error_rms_rad"])
    assert f"{worst:.4g}" in text
