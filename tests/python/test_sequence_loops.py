"""Sequence parameters (``params:``, ``${name}``, ``bench run --set``) and ``repeat`` loops:
expanded into the flat step list at validation, every error at the file, line and column
of the text as written, expectations named with the loop value, the expanded sequence's
timing checks applied."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from sim_libs import needs_sim

from bench import SequenceError, load_sequence, validate_sequence

ROOT = Path(__file__).resolve().parents[2]
BANNERS = ("bench: using the SIMULATED drive", "bench: no drive hardware found",
           "bench: FALLING BACK TO THE SIMULATED DRIVE")

LOOP = """\
name: loop
motor: paper_salient
extractor: sogi_adaptive
seed: 1
params:
  load: 2.0
  hold: 0.5
steps:
  - enable: {mode: speed}
  - repeat:
      for: v
      in: [100, 200, 400]
      steps:
        - set_speed: {value: "${v}", unit: r/min}
        - wait: {duration_s: "${hold}"}
        - load_step: {value: "${load}", unit: N*m}
        - wait: {duration_s: "${hold}"}
        - expect: {metric: position_error_rms_rad, op: "<=", limit: 0.02, window_s: [0.6, 1.0]}
        - expect: {metric: speed_tracking_error_max_rpm, op: "<=", limit: 6,
                   window_s: [0.8, 1.0], name: trk}
        - load_step: {value: 0, unit: N*m}
  - disable: {}
"""


def _issues(text: str, **kw: object) -> list:
    with pytest.raises(SequenceError) as ei:
        validate_sequence(text, "s.yaml", **kw)
    return ei.value.issues


def _line_col(text: str, needle: str, nth: int = 0) -> tuple[int, int]:
    """1-based line and column of the ``nth`` occurrence of ``needle`` in ``text``."""
    pos = -1
    for _ in range(nth + 1):
        pos = text.index(needle, pos + 1)
    line = text.count("\n", 0, pos) + 1
    return line, pos - (text.rfind("\n", 0, pos) + 1) + 1


def test_a_repeat_expands_into_the_flat_step_list() -> None:
    s = validate_sequence(LOOP, "s.yaml")
    kinds = [st.kind for st in s.steps]
    assert kinds == ["enable"] + ["set_speed", "wait", "load_step", "wait", "expect", "expect",
                                  "load_step"] * 3 + ["disable"]
    assert s.duration_s == pytest.approx(3.0)
    speeds = [st.params["value"] for st in s.steps if st.kind == "set_speed"]
    assert speeds == [100, 200, 400]  # ${v}: the number, not its text
    assert all(st.params["value"] == 2.0 for st in s.steps if st.kind == "load_step"
               and st.params["value"])
    # each repetition starts where the previous ended; its windows move with it
    starts = [st.t_start_s for st in s.steps if st.kind == "set_speed"]
    assert starts == pytest.approx([0.0, 1.0, 2.0])
    ex = s.expectations
    assert [e.params["name"] for e in ex] == [
        "position_error_rms_rad@v=100", "trk@v=100", "position_error_rms_rad@v=200",
        "trk@v=200", "position_error_rms_rad@v=400", "trk@v=400"]
    assert [e.params["window_s"] for e in ex[::2]] == [[0.6, 1.0], [1.6, 2.0], [2.6, 3.0]]
    assert [e.loop for e in ex[::2]] == [{"v": 100}, {"v": 200}, {"v": 400}]
    # every expanded step keeps the line of the text as written
    set_line = _line_col(LOOP, "- set_speed")[0]
    assert {st.line for st in s.steps if st.kind == "set_speed"} == {set_line}
    assert s.params == {"load": 2.0, "hold": 0.5} and s.overrides == {}
    assert s.raw["steps"][1]["repeat"]["in"] == [100, 200, 400]  # the file as written


def test_set_overrides_a_default_and_unknown_or_bad_values_are_named() -> None:
    s = validate_sequence(LOOP, "s.yaml", overrides={"load": 3.5})
    assert {st.params["value"] for st in s.steps if st.kind == "load_step"} == {3.5, 0}
    assert s.params["load"] == 3.5 and s.overrides == {"load": 3.5}
    (i,) = _issues(LOOP, overrides={"lod": 3})
    assert "--set lod: no such parameter; defined: load, hold" in i.message
    assert (i.line, i.field) == (6, "params")
    (i,) = _issues(LOOP, overrides={"load": "x"})
    assert "--set load='x': not a finite number" in i.message
    # a value beyond the drive's thrust is refused where it is used, saying where it came from
    (i,) = _issues(LOOP, overrides={"load": 30})
    assert (i.line, i.column) == _line_col(LOOP, '"${load}"')
    assert i.field == "steps[1].repeat.steps[2].load_step.value (v=100)"
    assert "30 N*m load exceeds the thrust" in i.message and "(${load} = 30 from --set)" in \
        i.message


def test_errors_in_a_repeat_are_at_the_text_as_written() -> None:
    # a mistake the same in every repetition: once, at its place in the file
    text = LOOP.replace('unit: r/min}', 'unit: km/h}')
    (i,) = _issues(text)
    assert (i.line, i.column) == _line_col(text, "km/h")
    assert i.field == "steps[1].repeat.steps[0].set_speed.unit (v=100)"
    assert str(i).startswith(f"s.yaml:{i.line}:{i.column}: ")
    # a value that depends on the loop: once per value that is wrong, with the value
    text = LOOP.replace("[100, 200, 400]", "[100, 2000, 3000]")
    issues = _issues(text)
    assert [i.field for i in issues] == [
        "steps[1].repeat.steps[0].set_speed.value (v=2000)",
        "steps[1].repeat.steps[0].set_speed.value (v=3000)"]
    assert {(i.line, i.column) for i in issues} == {_line_col(text, '"${v}"')}
    assert "2000 r/min exceeds the drive's speed limit" in issues[0].message
    # an unknown reference: its place, what is defined
    text = LOOP.replace('"${load}"', '"${lod}"')
    (i,) = _issues(text)
    assert (i.line, i.column) == _line_col(text, '"${lod}"')
    assert "unknown parameter 'lod'" in i.message and "defined: load, hold" in i.message
    assert "loop variable here: v" in i.message
    # unquoted in a flow mapping: YAML's error, with what to do
    text = LOOP.replace('value: "${v}"', "value: ${v}")
    (i,) = _issues(text)
    assert i.line == _line_col(text, "value: ${v}")[0]
    assert "not valid YAML" in i.message and 'must be quoted' in i.message


def test_repeat_form_errors() -> None:
    head = LOOP.split("steps:\n")[0] + "steps:\n  - enable: {}\n"
    cases = {
        "  - repeat: {for: v, in: [1, 1], steps: [{wait: {duration_s: 0.1}}]}\n":
            ("steps[1].repeat.in[1]", "listed twice"),
        "  - repeat: {for: load, in: [1], steps: [{wait: {duration_s: 0.1}}]}\n":
            ("steps[1].repeat.for", "'load' is already a parameter"),
        "  - repeat: {for: 3v, in: [1], steps: [{wait: {duration_s: 0.1}}]}\n":
            ("steps[1].repeat.for", "a name is letters, digits and _"),
        "  - repeat: {for: v, in: [], steps: [{wait: {duration_s: 0.1}}]}\n":
            ("steps[1].repeat.in", "should be non-empty"),
        "  - repeat: {for: v, in: [a], steps: [{wait: {duration_s: 0.1}}]}\n":
            ("steps[1].repeat.in[0]", "is not of type 'number'"),
        "  - repeat: {for: v, in: [1], stepz: [{wait: {duration_s: 0.1}}]}\n":
            ("steps[1].repeat.stepz", "unknown field; allowed: for, in, steps"),
        "  - repeat: [1, 2]\n": ("steps[1].repeat", "a repeat is a mapping"),
        "  - repeat: {for: v, in: [1], steps: [{repeat: {for: v, in: [2], steps: "
        "[{wait: {duration_s: 0.1}}]}}]}\n":
            ("steps[1].repeat.steps[0].repeat.for (v=1)", "enclosing repeat"),
        "  - repeat: {for: v, in: [1], steps: [{wait: {duration_s: 0.1}}, {expect: {metric: "
        "position_error_rms_rad, op: '<=', limit: 1}}, {expect: {metric: "
        "position_error_rms_rad, op: '<=', limit: 2}}]}\n":
            ("steps[1].repeat.steps[2].expect (v=1)", "give each a 'name:' or a 'window_s:'"),
    }
    for body, (field, msg) in cases.items():
        issues = _issues(head + body)
        assert any(i.field == field and msg in i.message for i in issues), (body, issues)
        assert all(i.line > 0 for i in issues), issues


def test_the_expanded_sequence_keeps_the_timing_checks() -> None:
    head = LOOP.split("steps:\n")[0] + "steps:\n  - enable: {}\n"
    # 30 repetitions of an hour: 30 h, beyond the 24 h a sequence may last
    text = head + ("  - repeat: {for: h, in: [" + ", ".join(str(i) for i in range(30))
                   + "], steps: [{wait: {duration_s: 3600}}]}\n")
    (i,) = _issues(text)
    assert i.field == "steps" and "lasts 108000 s; allowed up to 86400 s" in i.message
    # a window is from the start of its repetition: one ending after it is evaluated
    text = LOOP.replace("window_s: [0.6, 1.0]}", "window_s: [0.6, 1.2]}")
    (i,) = _issues(text)
    assert (i.line, i.column) == _line_col(text, "[0.6, 1.2]")
    assert "window ends 1.2 s after the start of the repetition" in i.message
    assert "evaluated 1 s after it" in i.message
    # a reference after a disable in the repetition: the drive would ignore it
    text = LOOP.replace("        - load_step: {value: 0, unit: N*m}\n",
                        "        - load_step: {value: 0, unit: N*m}\n        - disable: {}\n")
    issues = _issues(text)
    assert issues[0].field == "steps[1].repeat.steps[0].set_speed (v=200)"
    assert "before 'enable'" in issues[0].message
    # a trace capture checked against the action it precedes in the expanded list
    text = LOOP.replace("        - load_step: {value: \"${load}\", unit: N*m}\n",
                        "        - trace_capture: {name: c, duration_s: 0.02}\n"
                        "        - wait: {duration_s: 0.1}\n"
                        "        - load_step: {value: \"${load}\", unit: N*m}\n")
    issues = _issues(text)
    assert issues[0].field.startswith("steps[1].repeat.steps[2].trace_capture (v=100)")
    assert "'load_step' it precedes (steps[1].repeat.steps[4] (v=100))" in issues[0].message


def test_nested_repeats_and_the_step_limit() -> None:
    head = LOOP.split("steps:\n")[0] + "steps:\n  - enable: {}\n"
    text = head + ("  - repeat:\n      for: a\n      in: [1, 2]\n      steps:\n"
                   "        - repeat:\n            for: b\n            in: [5, 6]\n"
                   "            steps:\n              - wait: {duration_s: 0.5}\n"
                   "              - expect: {metric: position_error_rms_rad, op: '<=', "
                   "limit: 0.5, name: 'e${a}'}\n  - disable: {}\n")
    s = validate_sequence(text, "s.yaml")
    assert [e.params["name"] for e in s.expectations] == [
        "e1@a=1,b=5", "e1@a=1,b=6", "e2@a=2,b=5", "e2@a=2,b=6"]
    # without window_s: [settle_s, evaluation] from the start of the repetition
    assert [e.params["window_s"] for e in s.expectations] == [
        [0.15, 0.5], [0.65, 1.0], [1.15, 1.5], [1.65, 2.0]]
    many = ", ".join(str(i) for i in range(30))
    bomb = head + (f"  - repeat: {{for: a, in: [{many}], steps: [{{repeat: {{for: b, in: "
                   f"[{many}], steps: [{{repeat: {{for: c, in: [{many}], steps: "
                   "[{wait: {duration_s: 0.001}}]}}]}}]}\n")
    (i,) = _issues(bomb)
    assert "more than 10000 steps" in i.message and i.line == bomb.count("\n")


def test_shipped_speed_sweep() -> None:
    p = ROOT / "sequences" / "speed_sweep.yaml"
    s = load_sequence(p)
    assert s.sha256 == hashlib.sha256(p.read_bytes()).hexdigest()
    speeds = [st.params["value"] for st in s.steps if st.kind == "set_speed"]
    assert len(speeds) == 5 and len(set(speeds)) == 5
    assert all(0 < v <= 937.5 for v in speeds)  # paper_salient's speed limit (3 m/s)
    names = [e.params["name"] for e in s.expectations]
    assert "position_error_rms_rad@speed=400" in names
    assert len(names) == len(set(names)) == 4 * 5
    # the same load-step test as paper_load_step.yaml at every speed
    loads = [st.params["value"] for st in s.steps if st.kind == "load_step"]
    assert loads == [2.0, 0] * 5


def _bench(*args: str, cwd: Path) -> tuple[int, str, list[str]]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("BENCH_DEBUG", None)
    r = subprocess.run([sys.executable, "-m", "bench", *args], capture_output=True, text=True,
                       cwd=cwd, env=env, timeout=300)
    assert "Traceback" not in r.stderr, r.stderr
    return r.returncode, r.stdout, [ln for ln in r.stderr.splitlines()
                                    if ln and not ln.startswith(BANNERS)]


SHORT = """\
name: short_loop
motor: paper_salient
extractor: sogi_adaptive
seed: 1
params: {top: 200}
steps:
  - enable: {mode: speed}
  - repeat:
      for: v
      in: [100, "${top}"]
      steps:
        - set_speed: {value: "${v}", unit: r/min}
        - wait: {duration_s: 0.3}
        - expect: {metric: speed_tracking_error_max_rpm, op: "<=", limit: 60, window_s: [0.2, 0.3]}
  - disable: {}
"""


@pytest.mark.parametrize("args, needles", [
    (["--set", "nope=1"], ["s.yaml:5:", "params", "--set nope: no such parameter; defined: top"]),
    (["--set", "top=fast"], ["bench: --set top=fast: not a number"]),
    (["--set", "top"], ["bench: --set top: give NAME=VALUE"]),
    (["--set", "top=1", "--set", "top=2"], ["bench: --set top: given twice"]),
    (["--set", "top=.nan"], ["bench: --set top=.nan: not a number"]),
    (["--set", "top=5000"], ["s.yaml:12:", "steps[1].repeat.steps[0].set_speed.value (v=5000)",
                             "speed limit", "(${v} = ${top} = 5000 from --set)"]),
])
def test_bad_set_is_one_line_and_nothing_runs(tmp_path: Path, args: list[str],
                                              needles: list[str]) -> None:
    (tmp_path / "s.yaml").write_text(SHORT)
    rc, out, lines = _bench("run", "s.yaml", "--sim", "--runs", "runs", "--no-progress", *args,
                            cwd=tmp_path)
    assert rc == 2, (out, lines)
    assert len(lines) == 1, lines
    for n in needles:
        assert n in lines[0], (n, lines[0])
    assert not (tmp_path / "runs").exists()  # nothing ran


@needs_sim
def test_a_loop_with_set_runs_on_the_simulated_drive(tmp_path: Path) -> None:
    (tmp_path / "s.yaml").write_text(SHORT)
    rc, out, lines = _bench("run", "s.yaml", "--sim", "--runs", "runs", "--no-progress",
                            "--set", "top=300", "--summary-json", "s.json", cwd=tmp_path)
    assert rc == 0, (out, lines)
    assert "[PASS] speed_tracking_error_max_rpm@v=100" in out
    assert "[PASS] speed_tracking_error_max_rpm@v=300" in out
    doc = json.loads((tmp_path / "s.json").read_text())
    exps = {e["name"]: e for e in doc["expectations"]}
    assert exps["speed_tracking_error_max_rpm@v=100"]["window_s"] == [0.2, 0.3]
    assert exps["speed_tracking_error_max_rpm@v=300"]["window_s"] == pytest.approx([0.5, 0.6])
    assert doc["record"]["params"] == {"top": 300} and doc["record"]["overrides"] == {"top": 300}
    assert doc["record"]["sequence_sha256"] == hashlib.sha256(SHORT.encode()).hexdigest()
    run_dir = tmp_path / doc["run_dir"]
    meta = json.loads((run_dir / "meta.json").read_text())
    assert meta["sequence"]["params"] == {"top": 300}
    assert meta["sequence"]["document"]["steps"][1]["repeat"]["for"] == "v"  # as written
    # the drive was really told both speeds (events.jsonl: what the runner did)
    events = [json.loads(ln) for ln in
              (run_dir / "events.jsonl").read_text().splitlines()]
    told = [e["params"]["value"] for e in events if e.get("kind") == "step"
            and e["step"] == "set_speed"]
    assert told == [100, 300]


def test_validate_takes_the_values_run_would(tmp_path: Path) -> None:
    """`bench validate --set`: the sequence checked with the values `bench run --set`
    would use (a load the drive cannot take is refused, naming --set), before a rig."""
    seq = ROOT / "sequences" / "speed_sweep.yaml"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}

    def validate(*extra: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "bench", "validate", str(seq), *extra],
                              cwd=tmp_path, env=env, capture_output=True, text=True,
                              timeout=120)

    ok = validate("--set", "load=1")
    assert ok.returncode == 0 and "ok (speed_sweep" in ok.stdout, ok.stderr
    bad = validate("--set", "load=30")
    assert bad.returncode == 2
    assert "(${load} = 30 from --set)" in bad.stderr and "allowed range" in bad.stderr
    assert validate("--set", "nope").returncode == 2
