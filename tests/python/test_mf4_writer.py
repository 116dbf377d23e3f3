"""The MF4 writer process (bench._mf4writer): files equal to what was queued, the bench
falls back to writing them itself when the child dies, a killed bench still gets every
file it queued, and a file that cannot be written is named."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from bench._logging import read_signals
from bench._mf4writer import Mf4Writer

ROOT = Path(__file__).resolve().parents[2]


def _rows(n: int = 2400) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(7)
    t = np.arange(n) / 24000.0
    return [("sim.theta_e_rad", "rad", t, rng.normal(size=n)),
            ("sim.i_q_A", "A", t, rng.normal(size=n)),
            ("pdo.speed_rpm", "r/min", t[::24], rng.normal(size=t[::24].size))]


def _check(run: Path, rows: list[tuple[str, str, np.ndarray, np.ndarray]]) -> None:
    got = read_signals(run)
    for name, unit, t, v in rows:
        tt, vv, u = got[name]
        assert u == unit
        np.testing.assert_array_equal(tt, t)
        np.testing.assert_array_equal(vv, v)


def test_child_writes_the_queued_files_in_order_and_removes_the_parts(tmp_path: Path) -> None:
    w = Mf4Writer(use_process=True)
    try:
        assert w._proc is not None
        rows = _rows()
        (tmp_path / "signals").mkdir()
        w.write(tmp_path / "signals" / "part_00001.mf4", rows[:1])
        w.write(tmp_path / "signals.mf4", rows, header={"sequence": "s"}, compression=2,
                remove_parts=tmp_path / "signals")
        w.sync(60)
        assert w.failed == [] and w.fallbacks == 0
        assert not (tmp_path / "signals").exists()  # parts removed after the joined file
        _check(tmp_path, rows)
    finally:
        w.shutdown()


def test_a_dead_child_falls_back_to_the_bench(tmp_path: Path) -> None:
    w = Mf4Writer(use_process=True)
    assert w._proc is not None
    w._proc.kill()
    w._proc.wait(10)
    rows = _rows()
    w.write(tmp_path / "signals.mf4", rows)
    w.sync(60)
    assert w.fallbacks == 1
    assert (tmp_path / "signals.mf4").exists()
    _check(tmp_path, rows)
    w.shutdown()


def test_a_file_that_cannot_be_written_is_named(tmp_path: Path) -> None:
    w = Mf4Writer(use_process=True)
    try:
        (tmp_path / "a_file").write_text("not a folder")
        w.write(tmp_path / "a_file" / "signals.mf4", _rows(100))
        w.sync(60)
        assert len(w.failed) == 1 and "signals.mf4" in w.failed[0], w.failed
    finally:
        w.shutdown()


BENCH = textwrap.dedent("""
    import sys, time, numpy as np
    from bench._mf4writer import Mf4Writer
    out = sys.argv[1]
    w = Mf4Writer.shared()
    t = np.arange(50000) / 24000.0
    w.write(out, [("sim.x_m", "m", t, np.sin(t))], compression=2)
    print("queued", w._proc.pid, flush=True)
    time.sleep(60)
""")


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_a_killed_bench_still_gets_every_file_it_queued(tmp_path: Path) -> None:
    out = tmp_path / "signals.mf4"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    p = subprocess.Popen([sys.executable, "-c", BENCH, str(out)], stdout=subprocess.PIPE,
                         env=env, text=True)
    try:
        line = p.stdout.readline().split()
        assert line[0] == "queued"
        child = int(line[1])
        p.send_signal(signal.SIGKILL)  # the bench dies right after queuing
        p.wait(10)
    finally:
        if p.poll() is None:
            p.kill()
    deadline = time.monotonic() + 60
    while not out.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert out.exists(), "the writer process did not finish the queued file"
    t = np.arange(50000) / 24000.0
    got = read_signals(tmp_path)["sim.x_m"]
    np.testing.assert_array_equal(got[0], t)
    np.testing.assert_array_equal(got[1], np.sin(t))
    deadline = time.monotonic() + 20  # and then it exits (its stdin is closed)
    while time.monotonic() < deadline and _alive(child):
        time.sleep(0.05)
    if _alive(child):
        os.kill(child, signal.SIGKILL)
        pytest.fail("the writer process outlived the bench")


def _alive(pid: int) -> bool:
    """Running (an exited orphan may stay a zombie where nothing reaps it)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"
