"""CLI: --help everywhere, validation before anything moves, exit codes."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from bench.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[2]

COMMANDS = [[], ["run"], ["validate"], ["live"], ["info"], ["param"], ["param", "get"],
            ["param", "set"], ["param", "list"], ["config"], ["config", "backup"],
            ["config", "restore"], ["faults"]]


@pytest.mark.parametrize("cmd", COMMANDS, ids=lambda c: " ".join(c) or "bench")
def test_help_everywhere(cmd: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as ei:
        main([*cmd, "--help"])
    assert ei.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: bench")


def test_run_help_lists_the_documented_options() -> None:
    p = build_parser()
    sub = next(a for a in p._actions if a.dest == "cmd").choices["run"]
    text = sub.format_help()
    for opt in ("--sim", "--interface", "--channel", "--bitrate", "--serial", "--realtime",
                "--summary-json", "--junit", "--rerun"):
        assert opt in text


def test_console_script_help() -> None:
    r = subprocess.run([sys.executable, "-m", "bench.cli", "--help"], capture_output=True,
                       text=True, cwd=ROOT, timeout=60)
    assert r.returncode == 0 and "run" in r.stdout and "faults" in r.stdout


def test_invalid_sequence_exits_2_before_connecting(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: b\nmotor: paper_salient\nextractor: sogi\nseed: 0\nsteps:\n"
                   "  - enable: {}\n  - set_speed: {value: 1, unit: furlong/fortnight}\n")
    rc = main(["run", str(bad), "--sim", "--runs", str(tmp_path / "runs")])
    assert rc == 2
    err = capsys.readouterr().err
    assert f"{bad}:7:" in err and "steps[1].set_speed.unit" in err
    assert not (tmp_path / "runs").exists()  # nothing ran, nothing logged
