"""Exit codes: decided in one place (``bench.cli.exit_code_for``), documented in one table
(docs/bench.md), checked here case by case from the outside (the ``bench`` process), and
never decided by what happened to the console (a closed pipe)."""

from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import sys
from pathlib import Path

import can
import pytest
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError
from sim_libs import needs_sim

from bench import cli
from bench._drive import DriveError, DriveFault, DriveLeftState, DriveLost, ParamInputError
from sim_fallback.server import SetupError

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
PASSING = (ROOT / "sequences" / "paper_load_step.yaml")


def bench(*args: str, cwd: Path, **kw: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "bench", *args], cwd=cwd, env=ENV,
                          capture_output=True, text=True, timeout=300, **kw)  # type: ignore


def doc_table() -> dict[int, str]:
    """docs/bench.md's exit-code table: code -> meaning."""
    text = (ROOT / "docs" / "bench.md").read_text(encoding="utf-8")
    sec = text[text.index("### Exit codes"):]
    sec = sec[:sec.index("\n\n", sec.index("| code |"))]
    return {int(m.group(1)): m.group(2) for m in re.finditer(r"^\| (\d+) \| ([^|]+) \|", sec,
                                                             re.M)}


def test_the_documented_table_is_the_codes_the_bench_uses() -> None:
    table = doc_table()
    assert table.keys() == {cli.EXIT_OK, cli.EXIT_FAIL, cli.EXIT_USAGE, cli.EXIT_DRIVE,
                            cli.EXIT_INTERNAL, cli.EXIT_INTERRUPT}
    assert "expectation failed" in table[1] and "invalid input" in table[2]
    assert "drive" in table[3] and "internal error" in table[4]
    assert "interrupted" in table[130]


@pytest.mark.parametrize("exc, code", [
    (cli.UserError("x.yaml:1: bad", cli.EXIT_USAGE), 2),
    (cli.UserError("cannot connect", cli.EXIT_DRIVE), 3),
    (ParamInputError("u_inj_V: allowed range [1, 400] V"), 2),
    (DriveError("drive did not reach OPERATION ENABLED"), 3),
    (DriveFault("drive fault 0xFF07", 0xFF07), 3),
    (DriveLeftState("the drive left OPERATION ENABLED without a fault"), 3),
    (DriveLost("drive node 1 lost"), 3),
    (SdoCommunicationError("No SDO response received"), 3),
    (SdoAbortedError(0x06090030), 3),
    (can.CanOperationError("bus off"), 3),
    (ConnectionRefusedError(111, "Connection refused"), 3),
    (SetupError("state folder x: not a folder", 2), 2),
    (SetupError("state folder x: permission denied", 3), 3),
    (KeyboardInterrupt(), 130),
    (ZeroDivisionError("a bug"), 4),
    (OverflowError("a bug"), 4),
])
def test_each_exception_has_the_documented_code(exc: BaseException, code: int) -> None:
    got, line = cli.exit_code_for(exc)
    assert got == code
    assert line and "\n" not in line


def test_ok_invalid_input_and_no_drive(tmp_path: Path) -> None:
    r = bench("validate", str(PASSING), cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    (tmp_path / "bad.yaml").write_text("name: x\nsteps: [{wait: {duration_s: .nan}}]\n")
    r = bench("validate", "bad.yaml", cwd=tmp_path)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    r = bench("info", "--interface", "socketcand", "--channel", "can0", "--host", "127.0.0.1",
              "--port", str(port), cwd=tmp_path)
    assert r.returncode == 3, (r.returncode, r.stderr)
    assert len(r.stderr.strip().splitlines()) == 1 and "cannot connect" in r.stderr


@needs_sim
def test_expectation_failed_is_1(tmp_path: Path) -> None:
    (tmp_path / "f.yaml").write_text(
        "name: f\nmotor: paper_salient\nextractor: sogi_adaptive\nseed: 0\nsteps:\n"
        "  - enable: {}\n  - wait: {duration_s: 0.2}\n"
        "  - expect: {metric: position_error_rms_rad, op: '<', limit: 1.0e-9, "
        "window_s: [0.1, 0.2]}\n  - disable: {}\n")
    r = bench("run", "f.yaml", "--sim", "--no-progress", "--runs", "runs", cwd=tmp_path)
    assert r.returncode == 1, r.stderr
    assert "FAILED" in r.stdout and "Traceback" not in r.stderr


@needs_sim
def test_a_closed_pipe_decides_nothing(tmp_path: Path) -> None:
    """`bench run ... 2>&1 | head -1`: the reader goes after the first line. The run
    still ends with its own exit code (0: the shipped sequence passes) and writes its
    report and summary (before: exit 1, a run folder without report or summary)."""
    p = subprocess.Popen([sys.executable, "-m", "bench", "run", str(PASSING), "--sim",
                          "--runs", "runs"], cwd=tmp_path, env=ENV,
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert p.stdout is not None
    first = p.stdout.readline()
    p.stdout.close()  # as `head -1` exits
    rc = p.wait(timeout=300)
    assert first.startswith("bench:"), first
    assert rc == 0
    (run_dir,) = [d for d in (tmp_path / "runs").iterdir() if d.is_dir()]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["passed"] is True
    assert (run_dir / "report.html").stat().st_size > 0


def test_campaign_overflowing_expression_is_input_error(tmp_path: Path) -> None:
    (tmp_path / "c.yaml").write_text(
        "name: pow\nbase: {scenario: load_step, t_end: 0.2}\nsampling: {method: grid}\n"
        "axes:\n  g: {values: [10.0, 3.0], set: {fw.pll_kp: x^400}}\n"
        "metrics: [position_error_rms_rad]\n")
    r = bench("campaign", "c.yaml", "--out", "out", cwd=tmp_path)
    assert r.returncode == 2, r.stderr  # before: 4 (OverflowError)
    assert "c.yaml:5: axes.g.set.fw.pll_kp: 'x^400' gives a non-finite value" in r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "out").exists()


@needs_sim
def test_a_huge_campaign_says_its_size_and_waits_for_yes(tmp_path: Path) -> None:
    (tmp_path / "big.yaml").write_text(
        "name: big\nbase: {scenario: load_step, t_end: 3600}\n"
        "sampling: {method: random, n: 1000000, seed: 1}\n"
        "axes:\n  seed: {values: [0, 1]}\nmetrics: [position_error_rms_rad]\n")
    r = bench("campaign", "big.yaml", "--out", "out", cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    m = re.search(r"campaign big: 1000000 runs x 3600 s = 3\.6e\+09 s of drive time; about "
                  r"([\d.]+) (days|h) on \d+ local workers \(measured ([\d.]+) wall s per "
                  r"drive s", r.stderr)
    assert m, r.stderr
    assert float(m.group(3)) > 0
    assert "give --yes to start it" in r.stderr
    assert not (tmp_path / "out").exists()  # nothing started


@needs_sim
def test_live_with_its_output_gone_still_disables_and_says_so(tmp_path: Path) -> None:
    """`bench live --sim | tee log`, then Ctrl-C (tee dies with it): the drive is
    disabled and that is what the bench records, exit 130 (before: "SAFE STATE FAILED:
    [Errno 32] Broken pipe" although the drive was already disabled)."""
    import signal
    import time

    err = tmp_path / "stderr.txt"
    with err.open("w") as ef:
        p = subprocess.Popen([sys.executable, "-m", "bench", "live", "--sim", "--speed", "50",
                              "--rerun", "save", str(tmp_path / "t.rrd")],
                             cwd=tmp_path, env=ENV, stdout=subprocess.PIPE, stderr=ef,
                             text=True)
        assert p.stdout is not None
        deadline = time.monotonic() + 120
        while ("bench: live;" not in err.read_text() and p.poll() is None
               and time.monotonic() < deadline):
            time.sleep(0.1)
        p.stdout.close()  # the reader is gone
        time.sleep(0.5)
        p.send_signal(signal.SIGINT)
        rc = p.wait(timeout=120)
    text = err.read_text()
    assert rc == 130, text
    assert "bench: drive disabled" in text and "SAFE STATE FAILED" not in text, text
    assert "Traceback" not in text, text


@pytest.mark.parametrize("action", ["status", "stop", "start"])
def test_an_unusable_state_folder_is_one_line_for_the_emulated_board_too(
        tmp_path: Path, action: str) -> None:
    """`BENCH_SIM_DIR` under a regular file: `bench emu` said "internal error" (exit 4)
    where `bench sim` says the folder and exits 2."""
    (tmp_path / "afile").write_text("")
    r = subprocess.run([sys.executable, "-m", "bench", "emu", action], cwd=tmp_path,
                       env={**ENV, "BENCH_SIM_DIR": str(tmp_path / "afile" / "x")},
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    (line,) = r.stderr.strip().splitlines()
    assert "afile is not a folder" in line and "internal error" not in line


@pytest.mark.parametrize("option", ["--sim-server", "--emu"])
def test_an_unusable_state_folder_is_input_error_when_connecting_too(
        tmp_path: Path, option: str) -> None:
    """`bench run --sim-server|--emu` with `BENCH_SIM_DIR` under a regular file: the
    connection mapped every server error to 3 ("no drive"), and the emulated board's
    called the unreadable folder a stale state file; now the folder's own error, exit 2."""
    (tmp_path / "afile").write_text("")
    r = subprocess.run([sys.executable, "-m", "bench", "run", str(PASSING), option],
                       cwd=tmp_path, env={**ENV, "BENCH_SIM_DIR": str(tmp_path / "afile" / "x")},
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    (line,) = r.stderr.strip().splitlines()
    assert "afile is not a folder" in line and "stale" not in line
