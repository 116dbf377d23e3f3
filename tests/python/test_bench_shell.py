"""`bench shell`: the session's `drive` object (parameters by name with units, tab
completion, set-points, a sequence one step at a time) and the command itself with a piped
stdin."""

from __future__ import annotations

import inspect
import os
import rlcompleter
import subprocess
import sys
from pathlib import Path

import pytest

from bench._drive import ParamError
from bench._sequence import load_sequence
from bench._session import connect
from bench._shell import ident, namespace

REPO = Path(__file__).resolve().parents[2]
SEQ = REPO / "sequences" / "paper_load_step.yaml"


@pytest.fixture
def ns():
    conn = connect(sim=True, realtime=False, say=lambda _m: None)
    names = namespace(conn)
    yield names
    names["drive"].close()


def test_parameter_names_complete_and_show_units(ns):
    drive = ns["drive"]
    comp = rlcompleter.Completer(ns)
    found = {comp.complete("drive.p.u_in", i) for i in range(5)} - {None}
    assert "drive.p.u_inj_V" in found
    assert "Target_velocity" in dir(drive.p)  # objects without a fw_config name too
    v = drive.p.u_inj_V
    assert float(v) == pytest.approx(50.0)  # the motor file's injection amplitude
    assert repr(v).startswith("50.0 V") and "0x2010:1" in repr(v)
    doc = inspect.getdoc(v)
    assert "u_inj_V (0x2010:1" in doc and "range [" in doc
    assert ident("Injection.Amplitude") == "Injection_Amplitude"
    assert ident("Target velocity") == "Target_velocity"
    assert ident("0x2010:1").startswith("p_")


def test_assignment_writes_the_drive_and_is_checked(ns):
    drive, conn = ns["drive"], ns["conn"]
    drive.p.u_inj_V = "30 V"
    assert conn.drive.read_raw(0x2010, 1) == pytest.approx(30.0)
    drive.p.u_inj_V = 35
    assert conn.drive.read_raw(0x2010, 1) == pytest.approx(35.0)
    with pytest.raises(ParamError, match=r"allowed range \[1\.0, 400\.0\]"):
        drive.p.u_inj_V = 5000
    with pytest.raises(ParamError, match="unit"):
        drive.p.u_inj_V = "30 A"
    with pytest.raises(ParamError, match="did you mean: .*u_inj_V"):
        _ = drive.p.u_inj
    assert conn.drive.read_raw(0x2010, 1) == pytest.approx(35.0)  # refused: unchanged


def test_sequence_one_step_at_a_time(ns):
    drive = ns["drive"]
    seq = load_sequence(SEQ)
    steps = drive.stepper(SEQ)
    first = next(steps)
    assert first.index == 0 and first.kind == seq.steps[0].kind
    assert drive.state == "OPERATION ENABLED" or first.kind != "enable"
    done = [first, *steps]
    assert [s.index for s in done] == list(range(len(seq.steps)))
    r = drive.last_result
    assert r is not None and not r.aborted and r.expectations
    assert drive.state == "SWITCH ON DISABLED"  # safe state at the end


def test_closing_a_stepper_is_the_safe_state(ns):
    drive = ns["drive"]
    steps = drive.stepper(SEQ)
    next(steps)  # enable
    next(steps)
    assert drive.state == "OPERATION ENABLED"
    steps.close()
    assert drive.state == "SWITCH ON DISABLED"
    assert drive.last_result.aborted


def _shell(script: str, runs: Path) -> subprocess.CompletedProcess[str]:
    """`bench shell --sim` with ``script`` typed into it (a pipe)."""
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "bench", "shell", "--sim", "--runs",
                           str(runs)], input=script, capture_output=True, text=True,
                          cwd=REPO, env=env, timeout=120)


def test_bench_shell_with_piped_input(tmp_path):
    script = ("print('U=', float(drive.p.u_inj_V))\n"
              "drive.p.u_inj_V = 25\n"
              "print('U2=', float(drive.p.u_inj_V))\n"
              "drive.enable(); drive.speed(0.05)\n"
              "print('STATE=', drive.state)\n"
              "exit\n")
    p = _shell(script, tmp_path)
    assert p.returncode == 0, p.stderr
    assert "U= 50.0" in p.stdout and "U2= 25.0" in p.stdout
    assert "STATE= OPERATION ENABLED" in p.stdout
    assert "Traceback" not in p.stdout + p.stderr


def test_live_in_the_shell_streams_pdo_serial_and_truth_and_detaches(ns, tmp_path):
    """drive.live() is wired like `bench live` (one LiveTap): TPDOs, the serial telemetry
    and the simulated drive's truth reach the recording; live_stop() leaves no decoder on
    the TPDOs, so a second live() does not decode every frame twice."""
    from bench._live import read_rrd

    drive = ns["drive"]
    conn = drive.conn
    maps = [m for m in conn.drive.node.tpdo.values() if m.enabled]
    before = [len(m.callbacks) for m in maps]
    for k in range(2):
        rrd = tmp_path / f"shell{k}.rrd"
        assert str(rrd) in drive.live("save", str(rrd))
        assert [len(m.callbacks) for m in maps] == [n + 1 for n in before]
        drive.enable()
        drive.speed(0.05)
        conn.drive.clock.sleep_until(conn.drive.clock.now() + 0.3)
        drive.disable()
        stats = drive.live_stop()
        assert stats is not None
        assert [len(m.callbacks) for m in maps] == before
        got = read_rrd(rrd)
        # serial telemetry (position/estimate), TPDOs (speed/pdo) and the truth, each
        # over the 0.3 s of drive time at the live view's 50 Hz (15 samples)
        for name in ("position/estimate", "speed/pdo", "truth/position"):
            assert name in got, (name, sorted(got))
            t, _ = got[name]
            assert t.size >= 12 and t[-1] - t[0] > 0.25, (name, t.size)


def test_the_shell_says_once_when_another_master_switched_the_drive_off(ns, capsys):
    """The shell's commands go through the bench's one watch (Drive.check): a drive
    switched off by a second master is said on stderr, once, naming the statusword."""
    import can

    drive, conn = ns["drive"], ns["conn"]
    drive.enable()
    bus2 = can.Bus(interface="virtual", channel=conn.info["channel"])
    try:  # an SDO download of controlword 0 from another master
        bus2.send(can.Message(arbitration_id=0x601, is_extended_id=False,
                              data=[0x2B, 0x40, 0x60, 0, 0, 0, 0, 0]))
    finally:
        bus2.shutdown()
    # the simulated drive answers the intruder while the bench has no SDO of its own
    # pending (two SDO clients on one SDO channel would race: a real bus's problem too)
    clock = conn.drive.clock
    clock.sleep_until(clock.now() + 0.02)
    err = ""
    for _ in range(100):
        drive.actual()
        err += capsys.readouterr().err
        if "left OPERATION ENABLED" in err:
            break
    assert "bench: the drive left OPERATION ENABLED without a fault: statusword 0x" in err
    for _ in range(5):
        drive.actual()
    err += capsys.readouterr().err
    assert err.count("left OPERATION ENABLED") == 1
    assert drive.state == "SWITCH ON DISABLED"


def test_user_mistakes_in_the_shell_are_one_line(tmp_path):
    """The issue's cases, typed into `bench shell`: a value with a wrong unit, a NaN speed,
    a refused write while enabled: one `bench:` line each, no traceback through canopen;
    a speed echoes its unit."""
    script = ("drive.p.u_inj_V = '5000 V'\n"
              "drive.speed(float('nan'))\n"
              "print('SPD=', repr(drive.speed(100, 'r/min')))\n"
              "drive.enable()\n"
              "drive.p.pole_pitch_m = 0.03\n"
              "print('STILL=', drive.state)\n"
              "exit\n")
    p = _shell(script, tmp_path)
    out = p.stdout + p.stderr
    assert p.returncode == 0, out
    assert "Traceback" not in out and "canopen" not in out, out
    lines = [ln for ln in p.stderr.splitlines() if ln.startswith("bench: ")]
    assert any("u_inj_V" in ln and "allowed range [1" in ln for ln in lines), lines
    assert any("drive.speed(nan): not a finite number" in ln for ln in lines), lines
    assert any("pole_pitch_m" in ln and "disable the drive first" in ln for ln in lines), lines
    assert "SPD= 0.32 m/s" in p.stdout
    assert "STILL= OPERATION ENABLED" in p.stdout
    assert p.stderr.rstrip().endswith("bench: drive disabled")  # exit confirms it


def test_scope_in_the_shell(tmp_path):
    """drive.scope(s): the terminal scope while the shell's drive runs (here in a pipe:
    plain lines); it returns the state line."""
    script = ("drive.enable(); drive.speed(0.1)\n"
              "print('END=', drive.scope(1.5))\n"
              "exit\n")
    p = _shell(script, tmp_path)
    assert p.returncode == 0, p.stderr
    lines = [ln for ln in p.stdout.splitlines() if "drive time" in ln and "speed=" in ln]
    assert lines, p.stdout
    assert "speed_ref=0.1 m/s" in lines[-1]
    assert "END= drive time" in p.stdout and "OPERATION ENABLED" in p.stdout


def test_parameter_help_and_table_show_text_and_values(ns):
    """`drive.p.u_inj_V?` shows the parameter's documentation (od.yaml's fw_config text
    when the object has none) and `table()` the drive's present values."""
    import re

    drive = ns["drive"]
    doc = type(drive.p.u_inj_V).__doc__
    assert "range [1.0, 400.0]" in doc and "square-wave amplitude" in doc
    drive.p.u_inj_V = 31
    row = next(r for r in drive.p.table("inj").splitlines() if r.startswith("u_inj_V "))
    m = re.search(r"0x2010:1\s+([\d.]+) V\s+rw\s+\[1\.0, 400\.0\]", row)
    assert m and float(m.group(1)) == 31.0, row


def test_load_control_in_the_shell(ns):
    """drive.load(F) puts F on the simulated plant: the drive holding speed 0 needs a
    thrust current against it (the plant's truth), and none once it is removed; NaN is a
    one-line error."""
    drive, conn = ns["drive"], ns["conn"]
    clock = conn.drive.clock
    drive.enable()
    drive.speed(0.0)
    clock.sleep_until(clock.now() + 0.2)
    i0 = abs(conn.sim.truth_state()["i_q_A"])
    assert drive.load(200).startswith("load 200 N")  # beyond the static friction
    clock.sleep_until(clock.now() + 0.3)
    i1 = abs(conn.sim.truth_state()["i_q_A"])
    assert i1 > i0 + 2.0, (i0, i1)
    with pytest.raises(ValueError, match=r"drive.load\(nan\): not a finite number"):
        drive.load(float("nan"))
    drive.load(0)
    clock.sleep_until(clock.now() + 0.3)
    assert abs(conn.sim.truth_state()["i_q_A"]) < i1 / 2
