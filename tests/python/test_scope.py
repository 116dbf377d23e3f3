"""The terminal scope (`bench live --tui`): sparklines against a numpy reference, and the
whole command on the simulated drive in a pseudo-terminal (what an ssh user sees) and in a
pipe (what a CI log gets)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from sim_libs import needs_sim

from bench._scope import BARS, sparkline

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")


def test_sparkline_levels_match_a_numpy_reference() -> None:
    rng = np.random.default_rng(3)
    v = rng.normal(size=300)
    v[17] = np.nan
    line = sparkline(v, 300)
    assert len(line) == 300 and line[17] == " "
    ok = np.isfinite(v)
    lo, hi = np.nanmin(v), np.nanmax(v)
    ref = np.minimum((v[ok] - lo) / (hi - lo) * len(BARS), len(BARS) - 1).astype(int)
    got = np.array([BARS.index(c) for c, k in zip(line, ok, strict=True) if k])
    assert np.array_equal(got, ref)
    assert line[int(np.nanargmax(v))] == BARS[-1] and line[int(np.nanargmin(v))] == BARS[0]
    assert sparkline(np.ones(5), 5) == BARS[3] * 5  # flat: the middle
    assert sparkline(np.arange(10.0), 4) == sparkline(np.arange(6.0, 10.0), 4)  # the newest


def _check_frame(text: str) -> None:
    assert "OPERATION ENABLED" in text and "no fault" in text, text
    m = re.search(r"speed estimate\s+([+-][\d.e+-]+)\s+m/s", text)
    assert m and abs(float(m.group(1)) - 0.1) < 0.02, text  # tracking 0.1 m/s
    m = re.search(r"angle err vs ref\s+([+-][\d.e+-]+)\s+rad el", text)
    assert m and abs(float(m.group(1))) < 0.1, text  # the estimate against the scale
    assert any(c in text for c in BARS)


@needs_sim
def test_bench_live_tui_in_a_terminal(tmp_path: Path) -> None:
    """In a pseudo-terminal: frames redrawn in place; the last frame before the disable
    shows the state, the speed tracking 0.1 m/s and the error against the reference
    sensor (the simulated drive's 1 um scale)."""
    import pty

    master, slave = pty.openpty()
    os.set_blocking(master, True)
    p = subprocess.Popen([sys.executable, "-m", "bench", "live", "--sim", "--tui",
                          "--speed", "0.1", "--unit", "m/s", "--duration", "1.5"],
                         cwd=tmp_path, env={**ENV, "COLUMNS": "110", "LINES": "30"},
                         stdin=slave, stdout=slave, stderr=slave, close_fds=True)
    os.close(slave)
    chunks = []
    while True:
        try:
            b = os.read(master, 65536)
        except OSError:  # EIO: the child closed the terminal
            break
        if not b:
            break
        chunks.append(b)
    rc = p.wait(timeout=120)
    os.close(master)
    raw = b"".join(chunks).decode("utf-8", "replace")
    assert rc == 0, raw
    frames = [ANSI.sub("", f) for f in raw.split("\x1b[H\x1b[J")[1:]]
    assert len(frames) >= 10, len(frames)  # redrawn about every 0.1 s of drive time
    enabled = [f for f in frames if "OPERATION ENABLED" in f]
    _check_frame(enabled[-1])


@needs_sim
def test_bench_live_tui_in_a_log(tmp_path: Path) -> None:
    """Not a terminal (a CI log): plain lines, about one a second, no escape codes."""
    r = subprocess.run([sys.executable, "-m", "bench", "live", "--sim", "--tui", "--speed",
                        "0.1", "--unit", "m/s", "--duration", "2.2"], cwd=tmp_path, env=ENV,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "\x1b[" not in r.stdout
    lines = r.stdout.strip().splitlines()
    assert 2 <= len(lines) <= 6, lines
    assert all(ln.startswith("drive time ") for ln in lines)
    m = re.search(r"speed=([\d.e+-]+) m/s", lines[-2])
    assert m and abs(float(m.group(1)) - 0.1) < 0.02, lines


def test_tui_and_rerun_together_is_an_input_error(tmp_path: Path) -> None:
    r = subprocess.run([sys.executable, "-m", "bench", "live", "--sim", "--tui", "--rerun",
                        "save", "x.rrd"], cwd=tmp_path, env=ENV, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2 and "--tui with --rerun" in r.stderr


@pytest.mark.parametrize("width", [60, 140])
def test_frame_fits_the_terminal(width: int) -> None:
    from bench._scope import Trace

    t = Trace("speed estimate", "m/s")
    for k in range(500):
        t.values.append(np.sin(k / 20))
    assert len(t.row(width)) == width
