"""JUnit XML and summary JSON content."""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

from bench import ExpectResult, RunResult, write_junit, write_summary_json

METRICS = {"position_error_rms_rad": 0.008, "position_error_max_rad": 0.03,
           "position_error_rms_mm": 0.06, "speed_estimate_error_max_rpm": 0.9,
           "speed_estimate_error_max_mps": 0.003, "settling_time_s": math.nan}


def _result(passed: bool = True, aborted: bool = False) -> RunResult:
    e1 = ExpectResult("rms", "position_error_rms_rad", (0.15, 1.0), 0.008, True, "<= 0.01",
                      line=20)
    e2 = ExpectResult("speed", "speed_estimate_error_max_rpm", (0.15, 1.0),
                      3.5 if not passed else 0.9,
                      passed, "<= 1", "" if passed else "measured 3.5, required <= 1", line=22)
    return RunResult("paper_load_step", passed=passed and not aborted, expectations=[e1, e2],
                     metrics=dict(METRICS), aborted=aborted,
                     error="KeyboardInterrupt" if aborted else None,
                     safe_state="disabled", duration_s=1.0, wall_s=2.5)


def test_summary_json_has_sequence_passed_metrics(tmp_path: Path) -> None:
    p = tmp_path / "s.json"
    write_summary_json(p, _result(), {"run_dir": "runs/x"})
    doc = json.loads(p.read_text())  # strict JSON: NaN became null
    assert doc["sequence"] == "paper_load_step" and doc["passed"] is True
    assert set(METRICS) <= set(doc["metrics"])
    assert doc["metrics"]["position_error_rms_rad"] == 0.008
    assert doc["metrics"]["settling_time_s"] is None
    assert doc["run_dir"] == "runs/x"


def test_junit_one_testcase_per_expectation_plus_run(tmp_path: Path) -> None:
    p = tmp_path / "j.xml"
    write_junit(p, [_result(passed=False)])
    root = ET.parse(p).getroot()
    (suite,) = root.findall("testsuite")
    assert suite.get("name") == "paper_load_step"
    cases = suite.findall("testcase")
    assert [c.get("name") for c in cases] == ["rms", "speed", "run"]
    assert suite.get("tests") == "3" and suite.get("failures") == "1"
    fail = cases[1].find("failure")
    assert fail is not None and "required <= 1" in fail.text and "line 22" in fail.text
    assert cases[0].find("failure") is None and cases[2].find("error") is None


def test_junit_aborted_run_is_an_error(tmp_path: Path) -> None:
    p = tmp_path / "j.xml"
    write_junit(p, [_result(aborted=True)])
    suite = ET.parse(p).getroot().find("testsuite")
    run = [c for c in suite.findall("testcase") if c.get("name") == "run"][0]
    err = run.find("error")
    assert err is not None and "KeyboardInterrupt" in err.get("message")
    assert suite.get("errors") == "1"


def test_paper_claim_reported_beside_the_limit(tmp_path: Path) -> None:
    """A passing expectation whose paper value is not met says so everywhere."""
    from bench._runner import evaluate

    p = {"metric": "speed_estimate_error_max_rpm", "op": "<=", "limit": 3.5, "paper": 1.0}
    assert evaluate(p, 1.6) and not evaluate({**p, "limit": p["paper"]}, 1.6)
    e = ExpectResult("speed", "speed_estimate_error_max_rpm", (0.6, 1.0), 1.6, True, "<= 3.5",
                     "paper's 1 not reproduced", line=30, paper=1.0, paper_met=False)
    r = RunResult("paper_load_step", passed=True, expectations=[e], metrics=dict(METRICS),
                  safe_state="disabled", duration_s=1.0, wall_s=1.0)
    s = tmp_path / "s.json"
    write_summary_json(s, r)
    (x,) = json.loads(s.read_text())["expectations"]
    assert x["paper"] == 1.0 and x["paper_reproduced"] is False and x["passed"] is True
    j = tmp_path / "j.xml"
    write_junit(j, [r])
    case = ET.parse(j).getroot().find("testsuite").find("testcase")
    props = {p.get("name"): p.get("value") for p in case.find("properties")}
    assert props["paper"] == "1" and props["paper_reproduced"] == "false"
    assert case.find("failure") is None


def test_junit_cases_carry_measured_value_limit_unit_window_and_duration(tmp_path: Path
                                                                         ) -> None:
    p = tmp_path / "j.xml"
    write_junit(p, [_result(passed=False)])
    cases = ET.parse(p).getroot().find("testsuite").findall("testcase")
    for case, (measured, limit, unit) in zip(cases[:2], (("0.008", "0.01", "rad (electrical)"),
                                                         ("3.5", "1", "r/min")), strict=True):
        props = {q.get("name"): q.get("value") for q in case.find("properties")}
        assert float(props["measured"]) == float(measured)
        assert float(props["limit"]) == float(limit) and props["required"].endswith(limit)
        assert props["unit"].startswith(unit)
        assert [float(x) for x in props["window_s"].split()] == [0.15, 1.0]
        assert float(case.get("time")) == 0.85  # the window's duration (s), not "0"
