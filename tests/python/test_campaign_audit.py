"""Campaigns from the outside: every bad input a one-line error naming file:line: field and
what is allowed (never a traceback), results folders that refuse to mix campaigns or lose
runs, crashed runs recorded, the comparison and the replay command."""

from pathlib import Path

import pytest

from bench._campaign import CampaignError, load_campaign

METRICS = ("position_error_rms_rad", "position_error_max_rad")
OK = """name: t
base: {scenario: load_step, t_end: 0.3}
sampling: {method: grid}
axes:
  seed: {values: [1, 2, 3]}
metrics: [position_error_rms_rad]
"""


def _load(tmp_path: Path, text: str):
    f = tmp_path / "c.yaml"
    f.write_text(text)
    return load_campaign(f, METRICS)


@pytest.mark.parametrize("text,where", [
    # YAML syntax error: with its line (was: "not valid YAML: while parsing a flow mapping")
    ("name: t\nbase: {scenario: load_step\naxes: [1", "c.yaml:3:5: <top>: not valid YAML"),
    # a duplicate key was silently replaced by the last one
    (OK + "axes:\n  seed: {values: [9]}\n", "c.yaml:7:1: axes: duplicate key"),
    (OK.replace("  seed: {values: [1, 2, 3]}", "  seed: {values: [1]}\n  seed: {values: [2]}"),
     "c.yaml:6:3: axes.seed: duplicate key"),
    # unknown top-level key was ignored
    (OK + "colour: red\n", "c.yaml:7: colour: unknown key; known: name, title"),
    # wrong types were internal errors (TypeError tracebacks)
    (OK.replace("base: {scenario: load_step, t_end: 0.3}", "base: 5"),
     "c.yaml:2: base: 5 is not of type 'object'"),
    (OK + "limits: 7\n", "c.yaml:7: limits: need a list of {metric, stat"),
    (OK.replace("metrics: [position_error_rms_rad]", "metrics: [{a: 1}]"),
     "c.yaml:6: metrics[0]: {'a': 1} is not of type 'string'"),
    # a name that is no folder name wrote outside the results root ('../../x') or to 'None'
    (OK.replace("name: t", "name: ../../escape"), "c.yaml:1: name: need a name of letters"),
    (OK.replace("name: t", "name:"), "c.yaml:1: name: need a name of letters"),
    # a boolean seed was taken as 1
    (OK.replace("{method: grid}", "{method: random, n: 3, seed: true}"),
     "c.yaml:3: sampling.seed: need an integer >= 0"),
    (OK.replace("{method: grid}", "{method: lhs, n: 0}"),
     "c.yaml:3: sampling.n: need an integer in [1, 1000000]"),
    (OK.replace("{method: grid}", "{method: lhs}"), "c.yaml:3: sampling.n: missing"),
    # a limit on an unknown metric did not say which
    (OK + "limits:\n  - {metric: bogus, stat: max, max: 1}\n",
     "c.yaml:8: limits[0].metric: 'bogus' is not one of the campaign's metrics "
     "(position_error_rms_rad)"),
    (OK + "limits:\n  - {metric: position_error_rms_rad, stat: max, max: .inf}\n",
     "c.yaml:8: limits[0]: need a finite min and/or max"),
    # out-of-range values were found only by the runs, each recorded as failed
    (OK.replace("seed: {values: [1, 2, 3]}", "noise: {range: [-1, 1]}"),
     "c.yaml:5: axes.noise: -1: noise scales the sensor noise; allowed >= 0"),
    (OK.replace("seed: {values: [1, 2, 3]}", "fw.R_ohm: {range: [0, 1]}"),
     "c.yaml:5: axes.fw.R_ohm: [0, 1]; the firmware allows [0.001, 100] ohm"),
    (OK.replace("seed: {values: [1, 2, 3]}", "fw.R_ohm: {scale: [0.5, 1e9]}"),
     "the firmware allows [0.001, 100] ohm"),
])
def test_bad_files_give_one_line_per_problem(tmp_path, text, where):
    with pytest.raises(CampaignError) as ei:
        _load(tmp_path, text)
    msg = str(ei.value)
    assert where in msg, msg
    assert "Traceback" not in msg and len(msg.splitlines()) == 1, msg


def test_a_huge_grid_is_refused_at_once(tmp_path):
    """A grid over a seed range of 10^12 used to build its run list (hung, then ran out
    of memory) before the 10^7 guard; the guard now counts without building."""
    import time
    t0 = time.perf_counter()
    with pytest.raises(CampaignError) as ei:
        _load(tmp_path, OK.replace("{values: [1, 2, 3]}", "{range: [0, 1000000000000]}"))
    assert time.perf_counter() - t0 < 2.0
    assert "c.yaml:5: axes: a grid of 1000000000000 runs; allowed 1..1000000" in str(ei.value)
    c = _load(tmp_path, OK.replace("{values: [1, 2, 3]}", "{range: [10, 20]}"))
    assert [r["seed"] for r in c.runs()] == [float(x) for x in range(10, 20)]


def test_yaml_12_numbers_and_every_shipped_campaign_load():
    """Campaign files are read like sequence files: 1e-3 is a number (PyYAML's YAML 1.1
    took it for a string); every shipped campaign still loads with the same runs."""
    root = Path(__file__).resolve().parents[2]
    files = sorted((root / "campaigns").rglob("*.yaml"))
    assert len(files) >= 16
    for f in files:
        from sim_fallback.metrics import METRIC_NAMES
        assert load_campaign(f, METRIC_NAMES).runs()


def test_exponent_numbers_are_numbers(tmp_path):
    c = _load(tmp_path, OK.replace("seed: {values: [1, 2, 3]}",
                                   "plant.R_ohm: {values: [1e0, 2e0]}"))
    assert [r["plant.R_ohm"] for r in c.runs()] == [1.0, 2.0]
