"""The hardware path, end to end through the bench: the firmware image on the emulated
board (`bench emu start`, QEMU), reached with --emu exactly as a rig is, judged on its
modelled reference scale - and its twin, the host simulated drive, with the same seed.

Checked from outside, through the `bench` command as a user runs it:
- the main job's sequence passes on the emulated board; every result says EMULATED
  (console, summary.json, JUnit), from what the drive says (0x2090:1), judged on the
  reference sensor over the serial link;
- `bench compare` of that run and the host simulated drive's: the same fault codes
  (none), position-error RMS within 10 % (and every other metric within its tolerance);
- a rig without a reference sensor: "no reference sensor: estimate metrics not judged"
  once, those expectations NOT JUDGED, the run's verdict from what needs no truth;
- QEMU killed mid-run: the bench ends within a second with one line naming the lost
  drive and exit 3, its run folder readable, never a hang.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SEQ = REPO / "sequences" / "paper_load_step.yaml"

pytestmark = pytest.mark.skipif(
    (shutil.which("qemu-system-arm") is None or shutil.which("arm-none-eabi-gcc") is None)
    and os.environ.get("CI") != "true",
    reason="qemu-system-arm / arm-none-eabi-gcc not installed; CI installs them")


def bench(*args: str, env: dict[str, str], timeout: float = 300) -> tuple[int, str, str]:
    p = subprocess.run([sys.executable, "-m", "bench", *args], cwd=REPO, env=env,
                       capture_output=True, text=True, timeout=timeout)
    return p.returncode, p.stdout, p.stderr


def _env(folder: Path) -> dict[str, str]:
    e = dict(os.environ)
    e["BENCH_SIM_DIR"] = str(folder)
    e["PYTHONPATH"] = str(REPO) + os.pathsep + e.get("PYTHONPATH", "")
    for k in ("CAN_INTERFACE", "CAN_CHANNEL", "CAN_CONFIG"):
        e.pop(k, None)
    return e


@pytest.fixture(scope="module")
def emu(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, str]]:
    env = _env(tmp_path_factory.mktemp("emustate"))
    rc, out, err = bench("emu", "start", "--seed", "1", env=env)
    assert rc == 0, out + err
    assert "connect: --emu" in out and "127.0.0.1" in out
    yield env
    bench("emu", "stop", env=env)


def _summary(run_dir: str) -> dict:
    return json.loads((Path(run_dir) / "summary.json").read_text())


def _run_dir(out: str) -> str:
    return next(line.split(": ", 1)[1] for line in out.splitlines()
                if line.strip().startswith("run folder:"))


def test_main_job_on_the_emulated_board_and_its_twin(emu: dict[str, str],
                                                     tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    junit = tmp_path / "emu.xml"
    rc, out, err = bench("run", str(SEQ), "--emu", "--runs", str(runs), "--no-progress",
                         "--junit", str(junit), env=emu)
    assert rc == 0, out + err
    assert "connected to the EMULATED drive mps2_an386" in err
    assert "[EMULATED drive]" in out and "HARDWARE" not in out + err
    emu_dir = _run_dir(out)
    s = _summary(emu_dir)
    assert s["drive"] == "emulated" and s["simulated"] is True and s["board"] == "mps2_an386"
    assert s["evidence"]["source"] == "reference sensor"
    assert s["evidence"]["path"] == "serial telemetry"
    assert all(e["judged"] for e in s["expectations"])
    props = {p.get("name"): p.get("value") for p in
             ET.parse(junit).getroot().find("testsuite").find("properties")}
    assert props["drive"] == "emulated" and props["simulated"] == "true"
    html = (Path(emu_dir) / "report.html").read_text()
    assert "EMULATED BOARD" in html
    meta = json.loads((Path(emu_dir) / "meta.json").read_text())
    assert meta["clock"].startswith("the drive's own clock")
    # the twin: the host simulated drive, the same seed
    rc, out, err = bench("run", str(SEQ), "--sim", "--seed", "1", "--runs", str(runs),
                         "--no-progress", env=emu)
    assert rc == 0, out + err
    sim_dir = _run_dir(out)
    assert _summary(sim_dir)["drive"] == "simulated"
    rc, out, err = bench("compare", sim_dir, emu_dir, env=emu)
    assert rc == 0, out + err
    line = next(x for x in out.splitlines() if x.startswith("position_error_rms_rad"))
    a, b = (float(v) for v in line.split()[1:3])
    assert abs(b - a) <= 0.10 * a, line
    assert "faults: A none, B none: the same" in out
    assert Path(out.strip().splitlines()[-1].split("page: ", 1)[1]).is_file()


def test_a_rig_without_a_reference_sensor_says_what_it_cannot_judge(tmp_path: Path) -> None:
    env = _env(tmp_path / "state")
    rc, out, err = bench("emu", "start", "--no-ref-sensor", env=env)
    assert rc == 0, out + err
    try:
        rc, out, err = bench("run", str(SEQ), "--emu", "--runs", str(tmp_path / "runs"),
                             "--no-progress", env=env)
    finally:
        bench("emu", "stop", env=env)
    assert rc == 0, out + err  # what could be judged passed
    assert err.count("no reference sensor: estimate metrics not judged") == 1
    s = _summary(_run_dir(out))
    assert s["evidence"]["source"] == "none"
    assert s["evidence"]["note"] == "no reference sensor: estimate metrics not judged"
    nj = [e for e in s["expectations"] if not e["judged"]]
    assert nj and all(e["status"] == "not judged" and e["measured"] is None for e in nj)
    assert s["metrics"]["position_error_rms_rad"] is None  # never a number without truth
    assert s["metrics"]["speed_tracking_estimate_error_max_rpm"] is not None
    assert "[NOT JUDGED]" in out


def test_killed_emulator_ends_the_run_within_a_second(tmp_path: Path) -> None:
    env = _env(tmp_path / "state")
    rc, out, err = bench("emu", "start", env=env)
    assert rc == 0, out + err
    st = json.loads((tmp_path / "state" / "emu.json").read_text())
    seq = tmp_path / "long.yaml"
    seq.write_text("name: long\nmotor: paper_salient\nextractor: sogi_adaptive\nseed: 0\n"
                   "steps:\n  - enable: {}\n"
                   "  - set_speed: {value: 100, unit: r/min}\n  - wait: {duration_s: 30}\n"
                   "  - disable: {}\n")
    p = subprocess.Popen([sys.executable, "-m", "bench", "run", str(seq), "--emu", "--runs",
                          str(tmp_path / "runs"), "--no-progress"], cwd=REPO, env=env,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60

        def waiting() -> bool:  # the drive is enabled, at speed, in the long wait
            ev = list((tmp_path / "runs").glob("*/events.jsonl"))
            return bool(ev) and '"step": "wait"' in ev[0].read_text()

        while not waiting():
            assert p.poll() is None and time.monotonic() < deadline, p.communicate()
            time.sleep(0.1)
        time.sleep(0.5)
        os.kill(st["pid"], signal.SIGKILL)
        t_kill = time.monotonic()
        out, err = p.communicate(timeout=20)
        dt = time.monotonic() - t_kill
    finally:
        if p.poll() is None:
            p.kill()
        bench("emu", "stop", env=env)
    assert p.returncode == 3, out + err
    assert dt < 2.5, f"the bench took {dt:.2f} s to end after QEMU died"  # 1 s + startup
    assert "Traceback" not in err
    last = [x for x in err.strip().splitlines() if x.startswith("bench: run aborted")]
    assert len(last) == 1 and "lost" in last[0], err
    s = _summary(_run_dir(out))
    assert s["aborted"] and "DriveLost" in s["error"]
    assert s["safe_state"].startswith("SAFE STATE NOT CONFIRMED")


def test_two_concurrent_starts_leave_one_board(tmp_path: Path) -> None:
    """Two `bench emu start` at once on one state folder: one board, the other start is
    refused (exit 2, one line); `bench emu stop` stops it; status then says none (exit 3)."""
    env = _env(tmp_path / "state")
    ps = [subprocess.Popen([sys.executable, "-m", "bench", "emu", "start"], cwd=REPO, env=env,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
          for _ in range(2)]
    res = [(p.wait(timeout=120), *p.communicate()) for p in ps]
    try:
        rcs = sorted(r[0] for r in res)
        assert rcs == [0, 2], res
        refused = next(r for r in res if r[0] == 2)
        assert "already running" in refused[2] and refused[2].count("\n") == 1
        st = json.loads((tmp_path / "state" / "emu.json").read_text())
        qemus = subprocess.run(["pgrep", "-f", str(tmp_path / "state" / "emu_boot.bin")],
                               capture_output=True, text=True).stdout.split()
        assert qemus == [str(st["pid"])]
    finally:
        assert bench("emu", "stop", env=env)[0] == 0
    rc, _, err = bench("emu", "status", env=env)
    assert rc == 3 and "no emulated board running" in err
