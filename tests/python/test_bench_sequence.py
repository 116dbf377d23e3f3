"""Sequence files: schema validation with file/line/field errors, shipped sequences."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench import METRIC_NAMES, SequenceError, load_sequence, validate_sequence

ROOT = Path(__file__).resolve().parents[2]
SEQ_DIR = ROOT / "sequences"

GOOD = """\
name: t
motor: paper_salient
extractor: sogi_adaptive
seed: 1
steps:
  - enable: {mode: speed}
  - set_speed: {value: 100, unit: r/min}
  - wait: {duration_s: 0.5}
  - load_step: {value: 2.0, unit: N*m}
  - ramp: {quantity: speed, to: -100, unit: r/min, duration_s: 0.2}
  - load_ramp: {to: 0, unit: N, duration_s: 0.1}
  - trace_capture: {name: cap, duration_s: 0.04}
  - expect: {metric: position_error_rms_rad, op: "<=", limit: 0.01, window_s: [0.15, 0.8]}
  - expect: {metric: settling_time_s, value: 0.1, tolerance: 0.05}
  - disable: {}
"""


def _issues(text: str) -> list:
    with pytest.raises(SequenceError) as ei:
        validate_sequence(text, "seq.yaml")
    return ei.value.issues


def test_good_sequence_parses_with_times_and_lines() -> None:
    s = validate_sequence(GOOD, "seq.yaml")
    assert [st.kind for st in s.steps][:3] == ["enable", "set_speed", "wait"]
    assert s.duration_s == pytest.approx(0.8)
    assert s.steps[3].t_start_s == pytest.approx(0.5)  # load step after the 0.5 s wait
    assert s.steps[3].line == 9
    assert len(s.expectations) == 2


@pytest.mark.parametrize("path", sorted(SEQ_DIR.glob("paper_*.yaml")), ids=lambda p: p.stem)
def test_shipped_paper_sequences_are_valid(path: Path) -> None:
    s = load_sequence(path)
    assert s.expectations, "paper sequences carry pass/fail limits"
    for e in s.expectations:
        assert e.params["metric"] in METRIC_NAMES
    assert s.steps[-1].kind == "disable"


def test_paper_claims_are_the_papers_numbers() -> None:
    """Each shipped sequence carries the paper's numbers (method.md section 2) as
    ``paper:``; ``limit:`` is the bench's own regression bound, never tighter
    than the paper's claim would require of a looser metric."""
    ls = load_sequence(SEQ_DIR / "paper_load_step.yaml")
    paper = {(e.params["metric"], tuple(e.params["window_s"])): e.params["paper"]
             for e in ls.expectations if "paper" in e.params}
    assert paper[("position_error_rms_rad", (0.6, 1.0))] == 0.01
    assert paper[("speed_estimate_error_max_rpm", (0.6, 1.0))] == 1.0
    assert all(e.params["limit"] >= e.params["paper"] for e in ls.expectations
               if "paper" in e.params)
    load = next(st for st in ls.steps if st.kind == "load_step")
    assert load.t_start_s == pytest.approx(0.5)
    assert load.params == {"value": 2.0, "unit": "N*m"}
    su = load_sequence(SEQ_DIR / "paper_startup.yaml")
    assert su.x0 == "random"
    assert {e.params["metric"]: e.params["paper"] for e in su.expectations} == {
        "settling_time_s": 0.15, "position_error_max_rad": 0.051}
    rv = load_sequence(SEQ_DIR / "paper_speed_reversal.yaml")
    assert {e.params["paper"] for e in rv.expectations} == {1.0, 0.01}


def test_error_names_file_line_and_field_for_bad_unit() -> None:
    text = GOOD.replace("unit: r/min}", "unit: km/h}", 1)
    (i,) = _issues(text)
    assert (i.file, i.line, i.field) == ("seq.yaml", 7, "steps[1].set_speed.unit")
    assert "km/h" in i.message
    assert str(i).startswith("seq.yaml:7:")


def test_unknown_step_missing_field_and_unknown_field() -> None:
    text = GOOD.replace("  - wait: {duration_s: 0.5}", "  - wiat: {duration_s: 0.5}")
    (i,) = _issues(text)
    assert i.line == 8 and i.field == "steps[2].wiat" and "unknown step" in i.message
    text = GOOD.replace("load_step: {value: 2.0, unit: N*m}", "load_step: {value: 2.0}")
    (i,) = _issues(text)
    assert i.line == 9 and i.field == "steps[3].load_step.unit"
    text = GOOD.replace("seed: 1", "seed: 1\nspeed: 3")
    (i,) = _issues(text)
    assert i.line == 5 and i.field == "speed" and "unknown field" in i.message


def test_all_problems_reported_at_once() -> None:
    text = GOOD.replace("extractor: sogi_adaptive", "extractor: kalman").replace(
        "duration_s: 0.5", "duration_s: -1")
    fields = {i.field for i in _issues(text)}
    assert fields == {"extractor", "steps[2].wait.duration_s"}


def test_expect_needs_op_limit_or_value_tolerance() -> None:
    text = GOOD.replace('op: "<=", limit: 0.01', 'op: "<=", limit: 0.01, tolerance: 1')
    (i,) = _issues(text)
    assert i.field == "steps[7].expect" and i.line == 13


def test_expect_window_must_lie_in_the_past() -> None:
    text = GOOD.replace("window_s: [0.15, 0.8]", "window_s: [0.15, 2.0]")
    (i,) = _issues(text)
    assert i.field == "steps[7].expect.window_s" and "evaluated at" in i.message


def test_reference_before_enable_is_refused() -> None:
    text = GOOD.replace("  - enable: {mode: speed}\n", "").replace(
        "  - disable: {}", "  - enable: {}\n  - disable: {}")
    issues = _issues(text)
    assert issues[0].field == "steps[0].set_speed" and "before 'enable'" in issues[0].message


def test_yaml_syntax_error_has_a_line(tmp_path: Path) -> None:
    p = tmp_path / "broken.yaml"
    p.write_text("name: x\nsteps: [\n")
    with pytest.raises(SequenceError) as ei:
        load_sequence(p)
    (i,) = ei.value.issues
    assert i.file == str(p) and i.line >= 2 and "YAML" in i.message


def test_trace_signals_must_exist_in_the_object_dictionary() -> None:
    text = GOOD.replace("trace_capture: {name: cap, duration_s: 0.04}",
                        "trace_capture: {name: cap, duration_s: 0.04, signals: [pll_err_rad, "
                        "theta_true]}")
    (i,) = _issues(text)
    assert i.field == "steps[6].trace_capture.signals[1]" and "theta_true" in i.message
    assert i.line == 12


def test_each_missing_top_level_key_named_once(tmp_path) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text("name: bad\nsteps:\n  - wait: {duration_s: 0.1}\n")
    with pytest.raises(SequenceError) as ei:
        load_sequence(p)
    fields = sorted(i.field for i in ei.value.issues)
    assert fields == ["extractor", "motor", "seed"]


def test_a_relative_motor_file_is_beside_the_sequence(tmp_path: Path) -> None:
    """`cd /tmp && bench validate /path/seq/s.yaml` with `motor: my_lin.toml` beside the
    sequence (before: "No such file or directory: 'my_lin.toml'", the current directory's)."""
    import os
    import shutil
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[2]
    seqdir, elsewhere = tmp_path / "seq", tmp_path / "elsewhere"
    (seqdir / "motors").mkdir(parents=True)
    elsewhere.mkdir()
    src = root / "sim_fallback" / "motors" / "iron_core_linear.toml"
    shutil.copy(src, seqdir / "my_lin.toml")
    shutil.copy(src, seqdir / "motors" / "lin2.toml")
    body = ("extractor: sogi_adaptive\nseed: 0\nsteps:\n  - enable: {}\n"
            "  - set_speed: {value: 0.1, unit: m/s}\n  - wait: {duration_s: 0.2}\n"
            "  - disable: {}\n")
    (seqdir / "a.yaml").write_text("name: a\nmotor: my_lin.toml\n" + body)
    (seqdir / "b.yaml").write_text("name: b\nmotor: motors/lin2.toml\n" + body)
    (seqdir / "c.yaml").write_text("name: c\nmotor: missing.toml\n" + body)
    env = {**os.environ, "PYTHONPATH": str(root)}
    r = subprocess.run([sys.executable, "-m", "bench", "validate", str(seqdir / "a.yaml"),
                        str(seqdir / "b.yaml")], cwd=elsewhere, env=env, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    r = subprocess.run([sys.executable, "-m", "bench", "validate", str(seqdir / "c.yaml")],
                       cwd=elsewhere, env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert str(seqdir / "missing.toml") in r.stderr  # says where it looked
    seq = load_sequence(seqdir / "a.yaml")
    assert Path(seq.motor) == seqdir / "my_lin.toml"
    assert validate_sequence("name: t\nmotor: paper_salient\n" + body).motor == "paper_salient"


def test_a_file_without_params_or_repeat_is_as_written() -> None:
    """Parameters and loops change nothing for a plain file: no parameters, no loop
    values, steps and positions as written, the file's hash recorded."""
    import hashlib

    s = validate_sequence(GOOD, "seq.yaml")
    assert s.params == {} and s.overrides == {}
    assert all(st.loop == {} for st in s.steps)
    assert [st.index for st in s.steps] == list(range(len(s.steps)))
    assert s.expectations[0].params == {"metric": "position_error_rms_rad", "op": "<=",
                                        "limit": 0.01, "window_s": [0.15, 0.8]}
    assert s.sha256 == hashlib.sha256(GOOD.encode()).hexdigest()
    with pytest.raises(SequenceError, match=r"--set x: no such parameter; defined: none"):
        validate_sequence(GOOD, "seq.yaml", overrides={"x": 1})
