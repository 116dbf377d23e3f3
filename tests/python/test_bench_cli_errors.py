"""A user's mistake never shows a traceback: one line naming the file, line and field
(or the parameter and its range) and the documented exit code (2 input, 3 connection)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from sim_libs import needs_sim

ROOT = Path(__file__).resolve().parents[2]
HEAD = "name: x\nmotor: paper_salient\nextractor: sogi\nseed: 0\n"
GOOD_MOTOR = (ROOT / "sim_fallback/motors/paper_salient.toml").read_text()
BANNERS = ("bench: using the SIMULATED drive", "bench: no drive hardware found",
           "bench: FALLING BACK TO THE SIMULATED DRIVE")



def bench(*args: str, cwd: Path) -> tuple[int, list[str]]:
    """Run the CLI; returns (exit code, stderr lines without the simulated-drive banner)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("BENCH_DEBUG", None)
    r = subprocess.run([sys.executable, "-m", "bench.cli", *args], capture_output=True,
                       text=True, cwd=cwd, env=env, timeout=120)
    assert "Traceback" not in r.stderr, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln and not ln.startswith(BANNERS)]
    return r.returncode, lines


def one_line(rc: int, lines: list[str], code: int, *needles: str) -> str:
    assert rc == code, (rc, lines)
    assert len(lines) == 1, lines
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


@pytest.mark.parametrize("body, needles", [
    ("  - enable: {}\n  - wait: {duration_s: .nan}\n",
     ["x.yaml:7:", "steps[1].wait.duration_s", "not a finite number"]),
    ("  - enable: {}\n  - load_step: {value: .nan, unit: N}\n  - wait: {duration_s: 0.1}\n",
     ["x.yaml:7:", "steps[1].load_step.value", "not a finite number"]),
    ("  - enable: {}\n  - set_speed: {value: .inf, unit: r/min}\n",
     ["steps[1].set_speed.value", "not a finite number"]),
    ("  - enable: {}\n  - set_speed: {value: 1.0e6, unit: r/min}\n",
     ["steps[1].set_speed.value", "speed limit; allowed range [-937.5, 937.5] r/min"]),
    ("  - enable: {}\n  - load_step: {value: 500, unit: N*m}\n  - wait: {duration_s: 0.1}\n",
     ["steps[1].load_step.value", "allowed range [-21.92, 21.92] N*m"]),
    ("  - enable: {}\n  - wait: {duration_s: 1.0e9}\n",
     ["steps[1].wait.duration_s", "allowed range (0, 86400] s"]),
    ("  - enable: {}\n  - wait: {duration_s: 1}\n"
     "  - expect: {metric: position_error_rms_rad, op: '<=', limit: .nan}\n",
     ["x.yaml:8:", "steps[2].expect.limit", "not a finite number"]),
    # the drive's trace buffer: 4096 values = 1024 samples of 4 signals = 42.7 ms at 24 kHz
    ("  - enable: {}\n  - trace_capture: {name: a, duration_s: 0.1}\n"
     "  - wait: {duration_s: 0.01}\n  - load_step: {value: 1, unit: N}\n"
     "  - wait: {duration_s: 0.5}\n",
     ["steps[1].trace_capture.duration_s", "trace buffer", "1024 samples of 4 signals"]),
    ("  - enable: {}\n  - trace_capture: {name: a, duration_s: 0.03}\n"
     "  - wait: {duration_s: 0.2}\n  - load_step: {value: 1, unit: N}\n"
     "  - wait: {duration_s: 0.5}\n",
     ["steps[1].trace_capture", "covers [0, 0.03] s", "'load_step'", "at 0.2 s"]),
])
def test_validate_rejects_bad_values(tmp_path: Path, body: str, needles: list[str]) -> None:
    (tmp_path / "x.yaml").write_text(HEAD + "steps:\n" + body)
    one_line(*bench("validate", "x.yaml", cwd=tmp_path), 2, *needles)


@pytest.mark.parametrize("top, needles", [
    ("x0: 1.0e300\n", ["x.yaml:5:", "x0:", "position range [-10000, 10000] m"]),
    ("settle_s: 1.0e6\n", ["x.yaml:5:", "settle_s:", "allowed range [0, 1)"]),
])
def test_validate_rejects_bad_top_level_values(tmp_path: Path, top: str,
                                               needles: list[str]) -> None:
    (tmp_path / "x.yaml").write_text(HEAD + top + "steps:\n  - enable: {}\n"
                                     "  - wait: {duration_s: 1}\n")
    one_line(*bench("validate", "x.yaml", cwd=tmp_path), 2, *needles)


def test_yaml_12_floats_are_numbers(tmp_path: Path) -> None:
    (tmp_path / "x.yaml").write_text(HEAD + "steps:\n  - enable: {}\n"
                                     "  - wait: {duration_s: 1.0e-1}\n"
                                     "  - wait: {duration_s: 2e-1}\n")
    r = subprocess.run([sys.executable, "-m", "bench.cli", "validate", "x.yaml"],
                       capture_output=True, text=True, cwd=tmp_path, timeout=120,
                       env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert r.returncode == 0, r.stderr
    assert "0.3 s" in r.stdout


@pytest.mark.parametrize("content, needles", [
    (b"name: x\n# caf\xe9\n", ["x.yaml:2:", "not UTF-8"]),
    (b"a: &a [x, x, x, x, x, x, x, x, x]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a]\n"
     b"c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b]\nd: [*c, *c, *c, *c, *c, *c, *c, *c, *c]\n",
     ["x.yaml:2:", "alias '*a' not allowed"]),
    (b"x: " + b"[" * 5000 + b"]" * 5000 + b"\n", ["x.yaml:1:", "nested deeper than 32"]),
    (HEAD.replace("paper_salient", "no_such_motor").encode() + b"steps:\n  - enable: {}\n",
     ["x.yaml:2:", "motor:", "'no_such_motor' not found (known:"]),
])
def test_validate_bad_files_one_line(tmp_path: Path, content: bytes, needles: list[str]) -> None:
    (tmp_path / "x.yaml").write_bytes(content)
    one_line(*bench("validate", "x.yaml", cwd=tmp_path), 2, *needles)


@needs_sim
@pytest.mark.parametrize("args, code, needles", [
    (["info", "--sim", "--motor", "no_such_motor"], 2, ["--motor no_such_motor", "not found"]),
    (["info", "--sim", "--motor", "paper_table1"], 2,
     ["paper_table1", "saliency", "0xFF03", "cannot run this motor"]),
    (["live", "--sim", "--motor", "paper_table1", "--duration", "0.1"], 2, ["saliency"]),
    (["info", "--sim", "--serial", "/dev/ttyUSB9"], 2, ["--serial /dev/ttyUSB9", "--sim"]),
    (["live", "--sim", "--speed", "nan"], 2, ["--speed nan", "not a finite number"]),
    (["live", "--sim", "--speed", "1e9"], 2, ["allowed range [-937.5, 937.5] r/min"]),
    (["param", "set", "Telemetry.Decimation", "nan", "--sim"], 2,
     ["Telemetry.Decimation (0x2060:1)", "not a finite number", "allowed range [0, 65535]"]),
    (["param", "set", "Telemetry.Decimation", "inf", "--sim"], 2, ["not a finite number"]),
    (["param", "set", "no_such_param", "1", "--sim"], 2, ["unknown parameter"]),
    (["param", "set", "u_inj_V", "1e6", "--sim"], 3, ["0x06090031", "allowed range"]),
])
def test_cli_input_errors_one_line(tmp_path: Path, args: list[str], code: int,
                                   needles: list[str]) -> None:
    one_line(*bench(*args, cwd=tmp_path), code, *needles)


@needs_sim
@pytest.mark.parametrize("edit, needles", [
    ((r"^R_ohm = .*$", "R_ohm = -1.0"), ["electrical.R_ohm", "[0.001, 100.0] ohm"]),
    ((None, "\n[controller]\nu_inj_V = 0.5\n"), ["controller.u_inj_V", "[1.0, 400.0] V"]),
    ((None, "\n[controller]\ni_max_A = 20.0\ni_trip_A = 10.0\n"),
     ["controller.i_trip_A", "must exceed controller.i_max_A"]),
])
def test_bad_motor_file_is_input_error_not_connection_error(tmp_path: Path, edit: tuple,
                                                            needles: list[str]) -> None:
    text = re.sub(edit[0], edit[1], GOOD_MOTOR, flags=re.M) if edit[0] else GOOD_MOTOR + edit[1]
    assert text != GOOD_MOTOR
    (tmp_path / "m.toml").write_text(text)
    line = one_line(*bench("info", "--sim", "--motor", "m.toml", cwd=tmp_path), 2, *needles)
    n = int(line.split("m.toml:")[1].split(":")[0])  # the line of the field in the file
    assert text.splitlines()[n - 1].startswith(needles[0].split(".")[1])


@needs_sim
def test_run_with_a_bad_motor_never_moves(tmp_path: Path) -> None:
    (tmp_path / "m.toml").write_text(GOOD_MOTOR + "\n[controller]\nu_inj_V = 0.5\n")
    (tmp_path / "x.yaml").write_text(HEAD.replace("paper_salient", "m.toml") +
                                     "steps:\n  - enable: {}\n  - wait: {duration_s: 0.1}\n")
    rc, lines = bench("run", "x.yaml", "--sim", "--runs", "runs", "--no-progress", cwd=tmp_path)
    one_line(rc, lines, 2, "x.yaml:2:", "motor", "controller.u_inj_V", "[1.0, 400.0] V")
    assert not (tmp_path / "runs").exists()


@needs_sim
def test_config_restore_checks_everything_first(tmp_path: Path) -> None:
    rc, lines = bench("config", "backup", "b.json", "--sim", cwd=tmp_path)
    assert rc == 0, lines
    doc = json.loads((tmp_path / "b.json").read_text())
    n = len(doc["parameters"])
    assert n > 10
    # a backup whose u_inj_V was edited: restore refuses, names the field and range,
    # writes nothing (the drive's u_inj_V is checked below: unchanged)
    bad = json.loads(json.dumps(doc))
    bad["parameters"]["u_inj_V"]["value"] = 5000.0
    bad["parameters"]["i_max_A"]["value"] = 30.0  # valid: must NOT be written either
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    rc, lines = bench("config", "restore", "bad.json", "--sim", cwd=tmp_path)
    assert rc == 2 and lines[-1] == "bench: nothing written", lines
    assert any("bad.json: parameters.u_inj_V" in ln and "allowed range [1.0, 400.0]" in ln
               for ln in lines), lines
    # another product / firmware version
    other = json.loads(json.dumps(doc))
    other["drive"]["product_code"] += 1
    other["drive"]["firmware_version"] = "9.9.9"
    (tmp_path / "other.json").write_text(json.dumps(other))
    rc, lines = bench("config", "restore", "other.json", "--sim", cwd=tmp_path)
    assert rc == 2 and any("drive.product_code" in ln for ln in lines), lines
    assert any("drive.firmware_version: backup has '9.9.9'" in ln for ln in lines), lines
    for content, needle in (("null", "not a bench configuration backup"),
                            ("[1, 2]", "not a bench configuration backup"),
                            ("{\"parameters\": ", "x.json:1:16: not valid JSON")):
        (tmp_path / "x.json").write_text(content)
        rc, lines = bench("config", "restore", "x.json", "--sim", cwd=tmp_path)
        assert rc == 2 and any(needle in ln for ln in lines), (content, lines)
    # the good backup restores everything
    rc, lines = bench("config", "restore", "b.json", "--sim", cwd=tmp_path)
    assert rc == 0, lines


def test_unexpected_error_is_one_line_with_the_traceback_saved(tmp_path: Path) -> None:
    """The last-resort handler: one line naming where the traceback is (a bug, exit 4)."""
    from bench import cli

    def boom(args: object) -> int:
        raise ZeroDivisionError("deliberate")

    import contextlib
    import io

    err = io.StringIO()
    orig = cli.cmd_validate
    cli.cmd_validate = boom  # type: ignore[assignment]
    try:
        with contextlib.redirect_stderr(err):
            os.environ.pop("BENCH_DEBUG", None)
            old = Path.cwd()
            os.chdir(tmp_path)
            try:
                rc = cli.main(["validate", "x.yaml"])
            finally:
                os.chdir(old)
    finally:
        cli.cmd_validate = orig  # type: ignore[assignment]
    lines = err.getvalue().splitlines()
    assert rc == cli.EXIT_INTERNAL == 4 and len(lines) == 1, lines
    assert "ZeroDivisionError: deliberate" in lines[0] and "BENCH_DEBUG=1" in lines[0]
    saved = list((tmp_path / "runs").glob("bench_error_*.txt"))
    assert saved and "Traceback" in saved[0].read_text()


def test_exit_codes_are_documented() -> None:
    r = subprocess.run([sys.executable, "-m", "bench.cli", "--help"], capture_output=True,
                       text=True, cwd=ROOT, timeout=60, env={**os.environ, "PYTHONPATH": str(ROOT)})
    text = " ".join(r.stdout.split())
    for code in ("0 ok", "1 expectation failed", "2 invalid input", "3 drive/connection",
                 "4 internal error", "130 interrupted"):
        assert code in text, code
