"""Campaigns from the outside: every bad input a one-line error naming file:line: field and
what is allowed (never a traceback), results folders that refuse to mix campaigns or lose
runs, crashed runs recorded, the comparison and the replay command."""

from pathlib import Path

import numpy as np
import pytest

from simcampaign._campaign import CampaignError, load_campaign

METRICS = ("position_error_rms_rad", "position_error_max_rad")
OK = """name: t
base: {scenario: load_step, t_end: 0.3}
sampling: {method: grid}
axes:
  seed: {values: [1, 2, 3]}
metrics: [position_error_rms_rad]
"""


def _load(tmp_path: Path, text: str):
    f = tmp_path / "c.yaml"
    f.write_text(text)
    return load_campaign(f, METRICS)


@pytest.mark.parametrize("text,where", [
    # YAML syntax error: with its line (was: "not valid YAML: while parsing a flow mapping")
    ("name: t\nbase: {scenario: load_step\naxes: [1", "c.yaml:3:5: <top>: not valid YAML"),
    # a duplicate key was silently replaced by the last one
    (OK + "axes:\n  seed: {values: [9]}\n", "c.yaml:7:1: axes: duplicate key"),
    (OK.replace("  seed: {values: [1, 2, 3]}", "  seed: {values: [1]}\n  seed: {values: [2]}"),
     "c.yaml:6:3: axes.seed: duplicate key"),
    # unknown top-level key was ignored
    (OK + "colour: red\n", "c.yaml:7: colour: unknown key; known: name, title"),
    # wrong types were internal errors (TypeError tracebacks)
    (OK.replace("base: {scenario: load_step, t_end: 0.3}", "base: 5"),
     "c.yaml:2: base: 5 is not of type 'object'"),
    (OK + "limits: 7\n", "c.yaml:7: limits: need a list of {metric, stat"),
    (OK.replace("metrics: [position_error_rms_rad]", "metrics: [{a: 1}]"),
     "c.yaml:6: metrics[0]: {'a': 1} is not of type 'string'"),
    # a name that is no folder name wrote outside the results root ('../../x') or to 'None'
    (OK.replace("name: t", "name: ../../escape"), "c.yaml:1: name: need a name of letters"),
    (OK.replace("name: t", "name:"), "c.yaml:1: name: need a name of letters"),
    # a boolean seed was taken as 1
    (OK.replace("{method: grid}", "{method: random, n: 3, seed: true}"),
     "c.yaml:3: sampling.seed: need an integer >= 0"),
    (OK.replace("{method: grid}", "{method: lhs, n: 0}"),
     "c.yaml:3: sampling.n: need an integer in [1, 1000000]"),
    (OK.replace("{method: grid}", "{method: lhs}"), "c.yaml:3: sampling.n: missing"),
    # a limit on an unknown metric did not say which
    (OK + "limits:\n  - {metric: bogus, stat: max, max: 1}\n",
     "c.yaml:8: limits[0].metric: 'bogus' is not one of the campaign's metrics "
     "(position_error_rms_rad)"),
    (OK + "limits:\n  - {metric: position_error_rms_rad, stat: max, max: .inf}\n",
     "c.yaml:8: limits[0]: need a finite min and/or max"),
    # out-of-range values were found only by the runs, each recorded as failed
    (OK.replace("seed: {values: [1, 2, 3]}", "noise: {range: [-1, 1]}"),
     "c.yaml:5: axes.noise: -1: noise scales the sensor noise; allowed >= 0"),
    (OK.replace("seed: {values: [1, 2, 3]}", "fw.R_ohm: {range: [0, 1]}"),
     "c.yaml:5: axes.fw.R_ohm: [0, 1]; the firmware allows [0.001, 100] ohm"),
    (OK.replace("seed: {values: [1, 2, 3]}", "fw.R_ohm: {scale: [0.5, 1e9]}"),
     "the firmware allows [0.001, 100] ohm"),
    # plant.<field> and x0_m values were not checked at load: every run failed (negative
    # resistance, zero mass) or ran with a value no motor file may have
    (OK.replace("seed: {values: [1, 2, 3]}", "plant.R_ohm: {values: [1.2, -1.0]}"),
     "c.yaml:5: axes.plant.R_ohm: [-1, 1.2]; the simulator allows [0.001, 100] ohm"),
    (OK.replace("seed: {values: [1, 2, 3]}", "plant.mass_kg: {range: [0, 10]}"),
     "c.yaml:5: axes.plant.mass_kg: [0, 10]; the simulator allows [0.001, 100000] kg"),
    (OK.replace("seed: {values: [1, 2, 3]}", "plant.L_q_H: {scale: [0.5, 100]}"),
     "c.yaml:5: axes.plant.L_q_H: x 0.018 (nominal) gives [0.009, 1.8]; the simulator "
     "allows [1e-05, 1] H"),
    (OK.replace("seed: {values: [1, 2, 3]}", "plant.L_d0_H: {values: [.nan]}"),
     "c.yaml:5: axes.plant.L_d0_H: values must be a non-empty list of finite numbers; "
     "the simulator allows [1e-05, 1] H"),
    (OK.replace("seed: {values: [1, 2, 3]}", "plant.L_d0_H: {values: [0.001]}"),
     "c.yaml:5: axes.plant.L_d0_H: 0.001 with motor paper_salient's other plant parameters: "
     "the simulator refuses dL_sat_H (sim_params_check: dL_sat_H < L_d0_H"),
    (OK.replace("seed: {values: [1, 2, 3]}", "plant.adc_bits: {range: [8, 12]}"),
     "c.yaml:5: axes.plant.adc_bits: [8, 12]: an integer field; need values: [...] of "
     "integers in [8, 16] bit"),
    (OK.replace("seed: {values: [1, 2, 3]}", "plant.adc_offset_counts: {values: [1]}"),
     "c.yaml:5: axes.plant.adc_offset_counts: is one value per phase (3)"),
    (OK.replace("seed: {values: [1, 2, 3]}", "plant.locked: {values: [1]}"),
     "c.yaml:5: axes.plant.locked: has no allowed range (not a motor-file field)"),
    (OK.replace("seed: {values: [1, 2, 3]}", "plant.Rohm: {values: [1]}"),
     "c.yaml:5: axes.plant.Rohm: no plant parameter 'Rohm'"),
    (OK.replace("seed: {values: [1, 2, 3]}", "x0_m: {range: [0, 1e6]}"),
     "c.yaml:5: axes.x0_m: [0, 1e+06]; the simulator allows initial positions "
     "[-1000, 1000] m"),
    (OK.replace("seed: {values: [1, 2, 3]}", "x0_m: {values: [.inf]}"),
     "c.yaml:5: axes.x0_m: values must be a non-empty list of finite numbers; the simulator "
     "allows initial positions [-1000, 1000] m"),
    (OK.replace("  seed: {values: [1, 2, 3]}", "  v:\n    cases:\n      a: {x0_m: -2000}\n"
                "      b: {}"),
     "c.yaml:7: axes.v.cases.a.x0_m: -2000; the simulator allows initial positions "
     "[-1000, 1000] m"),
    (OK.replace("  seed: {values: [1, 2, 3]}", "  v:\n    cases:\n      a: {}\n"
                "      b: {plant.mass_kg: -1}"),
     "c.yaml:8: axes.v.cases.b.plant.mass_kg: -1; the simulator allows [0.001, 100000] kg"),
    (OK.replace("  seed: {values: [1, 2, 3]}", "  k:\n    values: [1, 1000]\n"
                "    set: {plant.R_ohm: plant.R_ohm * x}"),
     "c.yaml:7: axes.k.set.plant.R_ohm: 'plant.R_ohm * x' gives [0.958, 958]; the simulator "
     "allows [0.001, 100] ohm"),
])
def test_bad_files_give_one_line_per_problem(tmp_path, text, where):
    with pytest.raises(CampaignError) as ei:
        _load(tmp_path, text)
    msg = str(ei.value)
    assert where in msg, msg
    assert "Traceback" not in msg and len(msg.splitlines()) == 1, msg


def test_plant_ranges_are_the_motor_files(tmp_path, monkeypatch):
    """A campaign allows a plant field what a motor file may hold, no more (one table):
    a motor file with the campaign's refused value is refused by load_motor too, and the
    ends of the range a campaign names load."""
    import re

    import sim_fallback
    from sim_fallback import MotorFileError, load_motor
    text = (tmp_path / "m.toml")
    good = (Path(sim_fallback.__file__).parent / "motors" / "paper_salient.toml").read_text()
    with pytest.raises(CampaignError) as ei:
        _load(tmp_path, OK.replace("seed: {values: [1, 2, 3]}", "plant.R_ohm: {values: [200]}"))
    lo, hi = map(float, re.search(r"allows \[([^,]+), ([^\]]+)\] ohm", str(ei.value)).groups())
    for r, ok in ((lo, True), (hi, True), (lo / 2, False), (hi * 2, False)):
        text.write_text(re.sub(r"R_ohm = \S+", f"R_ohm = {r!r}", good))
        if ok:
            assert load_motor(text).plant["R_ohm"] == r
            _load(tmp_path, OK.replace("seed: {values: [1, 2, 3]}",
                                       f"plant.R_ohm: {{values: [{r!r}]}}"))
        else:
            with pytest.raises(MotorFileError, match=r"R_ohm"):
                load_motor(text)


def test_a_bad_plant_value_is_one_line_exit_2(tmp_path):
    f = tmp_path / "a.yaml"
    f.write_text(OK.replace("seed: {values: [1, 2, 3]}", "plant.R_ohm: {values: [1.2, -1.0]}"))
    rc, out, err = _cli(f, "--serial", "--out", tmp_path / "o")
    assert (rc, err.strip()) == (2, f"bench: {f}:5: axes.plant.R_ohm: [-1, 1.2]; the "
                                    "simulator allows [0.001, 100] ohm"), err
    assert not (tmp_path / "o").exists()


def test_a_huge_grid_is_refused_at_once(tmp_path):
    """A grid over a seed range of 10^12 used to build its run list (hung, then ran out
    of memory) before the 10^7 guard; the guard now counts without building."""
    import time
    t0 = time.perf_counter()
    with pytest.raises(CampaignError) as ei:
        _load(tmp_path, OK.replace("{values: [1, 2, 3]}", "{range: [0, 1000000000000]}"))
    assert time.perf_counter() - t0 < 2.0
    assert "c.yaml:5: axes: a grid of 1000000000000 runs; allowed 1..1000000" in str(ei.value)
    c = _load(tmp_path, OK.replace("{values: [1, 2, 3]}", "{range: [10, 20]}"))
    assert [r["seed"] for r in c.runs()] == [float(x) for x in range(10, 20)]


def test_yaml_12_numbers_and_every_shipped_campaign_load():
    """Campaign files are read like sequence files: 1e-3 is a number (PyYAML's YAML 1.1
    took it for a string); every shipped campaign still loads with the same runs."""
    root = Path(__file__).resolve().parents[2]
    files = sorted((root / "campaigns").rglob("*.yaml"))
    assert len(files) >= 16
    for f in files:
        from sim_fallback.metrics import METRIC_NAMES
        assert load_campaign(f, METRIC_NAMES).runs()


def test_exponent_numbers_are_numbers(tmp_path):
    c = _load(tmp_path, OK.replace("seed: {values: [1, 2, 3]}",
                                   "plant.R_ohm: {values: [1e0, 2e0]}"))
    assert [r["plant.R_ohm"] for r in c.runs()] == [1.0, 2.0]


@pytest.mark.parametrize("local", [True, False])
def test_a_run_that_kills_its_worker_is_recorded(tmp_path, local):
    """Such a run used to make dask give up on its whole chunk (KilledWorker), which
    ended the campaign with an internal error: the run was not recorded and the runs of
    its chunk were lost. Now the chunk is halved until the run is alone, and recorded
    with its error; every other run has the serial loop's numbers."""
    pytest.importorskip("dask.distributed")
    import dask
    from distributed.diagnostics.plugin import WorkerPlugin

    from simcampaign._campaign import load_results, run_campaign, start_local_cluster

    class CrashRun(WorkerPlugin):
        """Installed again on every restarted worker: run ``run`` kills its worker
        process, as a crash in the simulator library would."""

        name = "crash-one-run"

        def __init__(self, run: int) -> None:
            self.run = run

        def setup(self, worker) -> None:
            import os

            import simcampaign._campaign as m
            real, crash_at = m._simulate, self.run

            def simulate(base, params, metrics):
                if int(params["run"]) == crash_at:
                    os._exit(139)
                return real(base, params, metrics)
            m._simulate = simulate

    c = _load(tmp_path, OK.replace("t_end: 0.3", "t_end: 0.05").replace(
        "{values: [1, 2, 3]}", "{range: [0, 10]}"))
    run_campaign(c, tmp_path / "s", serial=True)
    # dask gives up on a task at once (it retries 3 times by default); the local
    # cluster's own settings (LOCAL_CLUSTER_CONFIG) must keep an innocent task queued on
    # the crashing worker from being blamed with it
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        cl, client = start_local_cluster(2)
    try:
        client.register_plugin(CrashRun(6))
        sched = client if local else cl.scheduler_address
        run_campaign(c, tmp_path / "d", scheduler=sched, batch=2)
    finally:
        client.close()
        cl.close()
    s, d = load_results(tmp_path / "s" / "t"), load_results(tmp_path / "d" / "t")
    assert list(d["run"]) == list(range(10))
    assert [k for k, e in enumerate(d["error"]) if e] == [6]
    assert "the worker died running this run (KilledWorker" in d["error"][6]
    rms_s = s["position_error_rms_rad"].astype(float)
    rms_d = d["position_error_rms_rad"].astype(float)
    assert np.isnan(rms_d[6])
    keep = np.arange(10) != 6
    np.testing.assert_array_equal(rms_d[keep], rms_s[keep])


def test_results_of_another_campaign_are_not_mixed(tmp_path):
    """A changed file (same name) resumed into the old folder: its run k is not the old
    run k, yet the old runs were kept and only the 'missing' ones added (3 runs reported
    for a 2-run campaign). Now it is refused and the folder left as it was."""
    from simcampaign._campaign import ResultsError, load_results, run_campaign
    a = _load(tmp_path, OK)
    run_campaign(a, tmp_path / "out", serial=True)
    before = load_results(tmp_path / "out" / "t")
    b = _load(tmp_path, OK.replace("[1, 2, 3]", "[1, 2, 3, 4]"))
    with pytest.raises(ResultsError, match="holds results of a different campaign "
                                           r"\(axes differ"):
        run_campaign(b, tmp_path / "out", serial=True)
    c = _load(tmp_path, OK.replace("t_end: 0.3", "t_end: 0.2"))
    with pytest.raises(ResultsError, match=r"\(base differ"):
        run_campaign(c, tmp_path / "out", serial=True)
    after = load_results(tmp_path / "out" / "t")
    np.testing.assert_array_equal(after["position_error_rms_rad"].astype(float),
                                  before["position_error_rms_rad"].astype(float))
    import json
    assert json.loads((tmp_path / "out/t/campaign.json").read_text())["axes"] == [
        ["seed", "values", [1.0, 2.0, 3.0]]]  # not overwritten by the refused campaigns
    # a title or the file's place may change: same runs
    d = _load(tmp_path, OK + "title: the same runs\n")
    run_campaign(d, tmp_path / "out", serial=True)
    assert list(load_results(tmp_path / "out" / "t")["run"]) == [0, 1, 2]


def test_a_damaged_part_is_moved_aside_and_its_runs_run_again(tmp_path):
    """A part damaged after it was written was deleted without a word on resume; now it
    is kept as part-*.parquet.corrupt, said, and the results equal a clean run's."""
    from simcampaign._campaign import ResultsError, load_results, run_campaign
    c = _load(tmp_path, OK)
    run_campaign(c, tmp_path / "clean", serial=True)
    run_campaign(c, tmp_path / "out", serial=True, batch=2)
    part = tmp_path / "out/t/part-r00000000.parquet"
    part.write_bytes(part.read_bytes()[:100])
    with pytest.raises(ResultsError, match=r"part-r00000000.parquet: unreadable Parquet"):
        load_results(tmp_path / "out" / "t")  # was pyarrow's ArrowInvalid traceback
    run_campaign(c, tmp_path / "out", serial=True, batch=2)
    assert (tmp_path / "out/t/part-r00000000.parquet.corrupt").stat().st_size == 100
    a, b = load_results(tmp_path / "out" / "t"), load_results(tmp_path / "clean" / "t")
    assert list(a["run"]) == [0, 1, 2]
    np.testing.assert_array_equal(a["position_error_rms_rad"].astype(float),
                                  b["position_error_rms_rad"].astype(float))


def _cli(*args, cwd=None):
    import os
    import subprocess
    import sys
    root = Path(__file__).resolve().parents[2]
    p = subprocess.run([sys.executable, "-m", "bench", "campaign", *map(str, args)],
                       capture_output=True, text=True, timeout=120, cwd=cwd,
                       env={**os.environ, "PYTHONPATH": str(root)})
    return p.returncode, p.stdout, p.stderr


def test_cli_folder_compare_and_scheduler_errors_are_one_line(tmp_path):
    """Each was a traceback (ArrowInvalid, ValueError: 'internal error', exit 4) or a
    wrong exit code (an unreachable scheduler exited 3, 'folder not writable')."""
    f, g = tmp_path / "a.yaml", tmp_path / "b.yaml"
    f.write_text(OK)
    g.write_text(OK.replace("[1, 2, 3]", "[1, 2]"))
    assert _cli(f, "--serial", "--out", tmp_path / "out")[0] == 0
    rc, out, err = _cli(g, "--serial", "--out", tmp_path / "out")
    assert (rc, err.strip().count("\n")) == (3, 0), err
    assert "holds results of a different campaign (axes differ" in err
    part = tmp_path / "out/t/part-r00000000.parquet"
    part.write_bytes(b"PAR1 not really")
    rc, out, err = _cli(g, "--serial", "--out", tmp_path / "o2", "--compare",
                        tmp_path / "out/t")
    assert (rc, err.strip().count("\n")) == (2, 0), err
    assert "--compare" in err and "part-r00000000.parquet: unreadable Parquet" in err
    rc, out, err = _cli(g, "--out", tmp_path / "o3", "--scheduler", "nonsense")
    assert (rc, err.strip()) == (2, "bench: --scheduler nonsense: cannot connect: "
                                    "missing port number in address 'nonsense'"), err


def test_an_unreachable_scheduler_is_one_line_at_once(tmp_path):
    """A closed port was refused only after dask's 30 s connect timeout, as 'Timed out
    trying to connect'; now the port is probed first and the error says why at once."""
    import socket
    f = tmp_path / "a.yaml"
    f.write_text(OK)
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    try:
        socket.create_connection(("127.0.0.1", port), timeout=5).close()
        pytest.skip("something listens on the port just freed")
    except OSError as e:
        why = e.strerror
    rc, out, err = _cli(f, "--out", tmp_path / "o", "--scheduler", f"tcp://127.0.0.1:{port}")
    assert (rc, err.strip()) == (2, f"bench: --scheduler tcp://127.0.0.1:{port}: cannot "
                                    f"connect: {why}"), err


def test_something_else_than_a_scheduler_at_the_address_is_one_line(tmp_path):
    """A server that answers with something else (here an HTTP error, as a proxy would)
    made dask read a huge frame length: an internal error (MemoryError, exit 4)."""
    import socket
    import threading
    f = tmp_path / "a.yaml"
    f.write_text(OK)
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen()
    port = srv.getsockname()[1]

    def answer() -> None:
        while True:
            try:
                conn, _ = srv.accept()
            except OSError:
                return
            with conn:
                conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n" * 8)

    threading.Thread(target=answer, daemon=True).start()
    try:
        rc, out, err = _cli(f, "--out", tmp_path / "o", "--scheduler",
                            f"tcp://127.0.0.1:{port}")
    finally:
        srv.close()
    assert (rc, err.count("\n")) == (2, 1), err
    assert err.startswith(f"bench: --scheduler tcp://127.0.0.1:{port}: cannot connect: "
                          "no Dask scheduler answered"), err


def test_a_silent_scheduler_address_is_given_a_short_timeout(tmp_path, monkeypatch):
    """A port that accepts but never answers as a scheduler: the Client is asked to give
    up well before dask's default connect timeout (30 s), and its timeout is one line."""
    import socket

    import dask
    import dask.distributed
    from dask.utils import parse_timedelta

    from simcampaign._campaign import SchedulerError, run_campaign
    seen = {}

    class Client:
        def __init__(self, address, **kw):
            seen.update(kw, address=address)
            raise TimeoutError(f"Timed out trying to connect to {address}")

    monkeypatch.setattr(dask.distributed, "Client", Client)
    c = _load(tmp_path, OK)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        addr = f"tcp://127.0.0.1:{s.getsockname()[1]}"
        with pytest.raises(SchedulerError) as ei:
            run_campaign(c, tmp_path / "o", scheduler=addr)
    default = parse_timedelta(dask.config.get("distributed.comm.timeouts.connect"))
    assert seen["address"] == addr
    assert 0 < parse_timedelta(seen["timeout"]) <= 10 < default
    assert str(ei.value) == (f"--scheduler {addr}: cannot connect: no Dask scheduler "
                             f"answered within {parse_timedelta(seen['timeout']):g} s")


CORNERS = """name: corners
base: {scenario: load_step, t_end: 0.3}
sampling: {method: lhs, n: 8, seed: 4}
axes:
  fw.L_q_H: {scale: [0.85, 1.15]}
  plant.adc_noise_counts: {range: [0.5, 3.0]}
  plant.L_d0_H: {values: [0.012, 0.002, 0.012, 0.012]}
  plant.dL_sat_H: {values: [0.003]}
metrics: [position_error_rms_rad, position_error_max_rad]
limits:
  - {metric: position_error_max_rad, stat: max, max: 0.05}
  - {metric: position_error_rms_rad, stat: fail_fraction, max: 0.0}
"""


def test_report_highlights_failing_corners_with_replay_commands(tmp_path):
    """The report showed the failed limits and the worst runs per metric, but not which
    runs break them: no highlight, a fault without its code. Now a 'Failing corners'
    table lists exactly the runs beyond a limit (value above a max, or no value for a
    fail_fraction limit), each with its replay command, and the plots mark them; a
    comparison says which metrics the other campaign lacks."""
    pytest.importorskip("plotly")
    import re

    from simcampaign._campaign import load_results, run_campaign
    from simcampaign._report import write_report
    c = _load(tmp_path, CORNERS)
    run_campaign(c, tmp_path / "out", serial=True)
    res = load_results(tmp_path / "out" / "corners")
    mx = res["position_error_max_rad"].astype(float)
    rms = res["position_error_rms_rad"].astype(float)
    expect = sorted(int(r) for r, a, b in zip(res["run"], mx, rms, strict=True)
                    if a > 0.05 or not np.isfinite(b))
    assert expect and len(expect) < 8  # some runs pass, some fail
    other = _load(tmp_path, OK)
    run_campaign(other, tmp_path / "other", serial=True)
    text = write_report(c, tmp_path / "out" / "corners", tmp_path / "other" / "t").read_text()
    corners = text.split("Failing corners:")[1].split("</table>")[0]
    assert f"{len(expect)} of 8 runs beyond a limit" in corners
    listed = [int(x) for x in re.findall(r"--replay (\d+)", corners)]
    assert listed == expect
    assert corners.count("<tr class='beyond'>") == len(expect)
    for k in expect:
        if np.isfinite(mx[k]) and mx[k] > 0.05:
            assert f"position_error_max_rad {mx[k]:.4g} &gt; 0.05" in corners
    assert "has no position_error_max_rad: compared on the other metrics only" in text
    # a drive fault shows its code where a run error would be
    for k in np.flatnonzero(res["fault"].astype(int)):
        assert f"drive fault 0x{int(res['fault'][k]):04X}" in text


def test_replay_command_reproduces_the_recorded_run(tmp_path):
    """The command printed for a failing corner gives that run's recorded numbers."""
    import json
    import re

    from simcampaign._campaign import load_results, replay_command, run_campaign
    f = tmp_path / "c.yaml"
    f.write_text(CORNERS)
    c = load_campaign(f, METRICS)
    run_campaign(c, tmp_path / "out", serial=True)
    res = load_results(tmp_path / "out" / "corners")
    k = int(np.nanargmax(res["position_error_max_rad"].astype(float)))
    cmd = replay_command(c, k)
    assert re.fullmatch(r"bench campaign \S+ --replay \d+", cmd)
    rc, out, err = _cli(*cmd.split()[2:])
    row = json.loads(out)
    assert (rc, row["run"], row["error"]) == (0, k, None), err
    for m in METRICS:
        assert row[m] == float(res[m][k])


def test_replay_command_works_from_another_directory(tmp_path, monkeypatch):
    """The command named the campaign file as given: a relative path (here with a
    space, which the shell split) that another directory does not have. Now it is the
    absolute path, shell-quoted, and gives the recorded numbers from elsewhere."""
    import json
    import shlex

    from simcampaign._campaign import load_results, replay_command, run_campaign
    (tmp_path / "my dir").mkdir()
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "my dir" / "c.yaml").write_text(OK)
    monkeypatch.chdir(tmp_path)
    c = load_campaign(Path("my dir") / "c.yaml", METRICS)
    run_campaign(c, tmp_path / "out", serial=True)
    res = load_results(tmp_path / "out" / "t")
    args = shlex.split(replay_command(c, 1))
    assert args[:2] == ["bench", "campaign"] and args[3:] == ["--replay", "1"]
    assert args[2] == str(tmp_path / "my dir" / "c.yaml")
    rc, out, err = _cli(*args[2:], cwd=tmp_path / "elsewhere")
    row = json.loads(out)
    assert (rc, row["run"], row["error"]) == (0, 1, None), err
    assert row["position_error_rms_rad"] == float(res["position_error_rms_rad"][1])


def test_reproduction_renderer_reads_results_as_campaigns_do(tmp_path, capsys):
    """tools/reproduce_paper.py --render-only over a damaged part ended in pyarrow's
    ArrowInvalid traceback (its renderer read the Parquet parts itself); it now reads
    them through load_results (each run once, in run order) and exits 3 with one line."""
    import importlib.util

    from simcampaign._campaign import ResultsError, load_results, run_campaign
    from simcampaign._reproduction import read_results
    c = _load(tmp_path, OK)
    run_campaign(c, tmp_path / "out", serial=True, batch=2)
    meta, rows = read_results(tmp_path / "out" / "t")
    res = load_results(tmp_path / "out" / "t")
    assert meta["name"] == "t" and [r["run"] for r in rows] == [0, 1, 2]
    assert [r["position_error_rms_rad"] for r in rows] == list(res["position_error_rms_rad"])
    assert rows[1]["p"]["seed"] == 2.0
    root = Path(__file__).resolve().parents[2]
    spec = importlib.util.spec_from_file_location("reproduce_paper",
                                                  root / "tools/reproduce_paper.py")
    rp = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(rp)
    results = tmp_path / "results"
    for f in sorted((root / "campaigns/reproduction").glob("*.yaml")):
        d = results / load_campaign(f).name
        d.mkdir(parents=True)
        (d / "campaign.json").write_text("{}")
        (d / "part-r00000000.parquet").write_bytes(b"PAR1 torn")
    with pytest.raises(ResultsError, match="unreadable Parquet"):
        read_results(d)
    assert rp.main(["--render-only", "--results", str(results), "--out",
                    str(tmp_path / "doc")]) == 3
    err = capsys.readouterr().err
    assert err.startswith("reproduce_paper: ") and err.count("\n") == 1
    assert "part-r00000000.parquet: unreadable Parquet" in err


def test_one_process_writes_a_results_folder(tmp_path):
    """Two campaign processes on the same folder each deleted the other's temporary
    parts (a resume cleans up after a killed writer) and ran the same runs; now the
    second is refused while the first holds the folder's lock, which a kill releases."""
    from simcampaign._campaign import ResultsError, _locked, load_results, run_campaign
    c = _load(tmp_path, OK)
    rdir = tmp_path / "out" / "t"
    rdir.mkdir(parents=True)
    with _locked(rdir):
        with pytest.raises(ResultsError, match="another campaign process is writing"):
            run_campaign(c, tmp_path / "out", serial=True)
    assert not list(rdir.glob("part-*"))
    run_campaign(c, tmp_path / "out", serial=True)  # the lock is gone with its holder
    assert list(load_results(rdir)["run"]) == [0, 1, 2]


def test_replay_prints_strict_json(tmp_path):
    """A metric a run does not have was printed as NaN, which is not JSON (jq refuses)."""
    import json
    f = tmp_path / "c.yaml"
    f.write_text(OK.replace("t_end: 0.3", "t_end: 0.1"))  # too short: no position error
    rc, out, err = _cli(f, "--replay", "1")

    def refuse(x):
        raise ValueError(x)
    row = json.loads(out, parse_constant=refuse)
    assert (rc, row["run"], row["position_error_rms_rad"]) == (0, 1, None), err


def test_kill_9_mid_campaign_then_resume_equals_an_uninterrupted_run(tmp_path):
    """`bench campaign` on its local cluster killed with SIGKILL mid-run (its workers
    with it: they notice their parent is gone), then run again: every run once, the
    numbers of an uninterrupted serial run."""
    pytest.importorskip("dask.distributed")
    import os
    import signal
    import subprocess
    import sys
    import time

    import pyarrow.parquet as pq

    from simcampaign._campaign import load_results, run_campaign
    text = OK.replace("{method: grid}", "{method: random, n: 240, seed: 2}").replace(
        "{values: [1, 2, 3]}", "{range: [0, 100000]}").replace("t_end: 0.3", "t_end: 1.0")
    f = tmp_path / "c.yaml"
    f.write_text(text)
    root = Path(__file__).resolve().parents[2]
    p = subprocess.Popen([sys.executable, "-m", "bench", "campaign", str(f), "--workers", "2",
                          "--out", str(tmp_path / "out")], env={**os.environ,
                                                                "PYTHONPATH": str(root)},
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    rdir = tmp_path / "out" / "t"
    deadline = time.monotonic() + 120
    while not list(rdir.glob("part-*.parquet")) and time.monotonic() < deadline:
        time.sleep(0.02)
    children = [int(x) for x in subprocess.run(["pgrep", "-P", str(p.pid)],
                                               capture_output=True, text=True).stdout.split()]
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    for pid in children:  # the workers end by themselves
        while time.monotonic() < deadline and Path(f"/proc/{pid}").exists() and \
                "Z" not in Path(f"/proc/{pid}/stat").read_text().split()[2]:
            time.sleep(0.05)
    kept = load_results(rdir)["run"]
    assert 0 < len(kept) < 240, len(kept)  # killed mid-run, finished runs kept
    c = load_campaign(f, METRICS)
    run_campaign(c, tmp_path / "out", serial=True)
    run_campaign(c, tmp_path / "clean", serial=True)
    rows = sum(pq.read_metadata(x).num_rows for x in rdir.glob("part-*.parquet"))
    a, b = load_results(rdir), load_results(tmp_path / "clean" / "t")
    assert rows == 240 and list(a["run"]) == list(range(240))  # each run exactly once
    for k in ("position_error_rms_rad", "fault"):
        np.testing.assert_array_equal(a[k].astype(float), b[k].astype(float))
    assert list(a["params"]) == list(b["params"])


def test_sigterm_keeps_the_finished_runs(tmp_path):
    """`kill PID` (SIGTERM) ended a serial campaign at once: the finished runs not yet
    in a part (up to 63) were lost. Now it is handled as Ctrl-C: they are written, exit
    130, and the same command resumes to the numbers of an uninterrupted run."""
    import os
    import signal
    import subprocess
    import sys

    from simcampaign._campaign import load_results, run_campaign
    text = OK.replace("{method: grid}", "{method: random, n: 200, seed: 2}").replace(
        "{values: [1, 2, 3]}", "{range: [0, 100000]}").replace("t_end: 0.3", "t_end: 1.0")
    f = tmp_path / "c.yaml"
    f.write_text(text)
    root = Path(__file__).resolve().parents[2]
    p = subprocess.Popen([sys.executable, "-m", "bench", "campaign", str(f), "--serial",
                          "--out", str(tmp_path / "out")], stderr=subprocess.PIPE,
                         stdout=subprocess.DEVNULL, env={**os.environ,
                                                         "PYTHONPATH": str(root)})
    seen = b""
    while b"/200" not in seen:  # the progress bar: runs are finishing
        ch = p.stderr.read(1)
        assert ch, seen
        seen += ch
    os.kill(p.pid, signal.SIGTERM)
    err = seen + p.stderr.read()
    assert p.wait(timeout=60) == 130, err[-500:]
    assert b"interrupted; run the same command again to resume" in err
    rdir = tmp_path / "out" / "t"
    kept = load_results(rdir)["run"]
    assert 0 < len(kept) < 200
    c = load_campaign(f, METRICS)
    run_campaign(c, tmp_path / "out", serial=True)
    run_campaign(c, tmp_path / "clean", serial=True)
    a, b = load_results(rdir), load_results(tmp_path / "clean" / "t")
    assert list(a["run"]) == list(range(200))
    np.testing.assert_array_equal(a["position_error_rms_rad"].astype(float),
                                  b["position_error_rms_rad"].astype(float))


def test_a_broken_motor_file_is_named_with_its_error(tmp_path, monkeypatch):
    """A motor file that exists but does not load was reported as 'need one of motor
    names (..., the same name, ...)', hiding the file's own error."""
    import sim_fallback._motors as motors
    from simcampaign import _campaign
    motor_dir = tmp_path / "motors"
    motor_dir.mkdir()
    for f in Path(motors.MOTOR_DIR).glob("*.toml"):
        (motor_dir / f.name).write_text(f.read_text())
    good = (motor_dir / "paper_salient.toml").read_text()
    (motor_dir / "broken.toml").write_text(good.replace("R_ohm", "R_ohm = -5\n#", 1))
    monkeypatch.setattr(motors, "MOTOR_DIR", motor_dir)
    monkeypatch.setattr(_campaign, "_motor_loaded", _campaign._motor_loaded.__wrapped__)
    with pytest.raises(CampaignError) as ei:
        _load(tmp_path, OK.replace("t_end: 0.3", "t_end: 0.3, motor: broken"))
    msg = str(ei.value)
    assert "c.yaml:2: base.motor: 'broken': its motor file cannot be loaded: " in msg, msg
    assert "R_ohm" in msg and len(msg.splitlines()) == 1
    with pytest.raises(CampaignError, match="base.motor: 'nonesuch': need one of motor"):
        _load(tmp_path, OK.replace("t_end: 0.3", "t_end: 0.3, motor: nonesuch"))


def test_workers_outside_what_the_machine_can_run_is_one_line(tmp_path):
    """--workers 0, or more local worker processes than 4 per core (each a CPU-bound
    ~150 MiB process: 1024 on 2 cores was accepted and forked), is refused before
    anything starts: one line naming the allowed range, exit 2, no results folder."""
    import os

    from simcampaign._campaign import WORKERS_PER_CORE
    f = tmp_path / "a.yaml"
    f.write_text(OK)
    top = WORKERS_PER_CORE * (os.cpu_count() or 1)
    for bad in (0, -3, top + 1, 1024):
        rc, out, err = _cli(f, "--workers", bad, "--out", tmp_path / "out")
        assert (rc, err.strip()) == (2, f"bench: --workers {bad}: allowed 1..{top} "
                                        f"({WORKERS_PER_CORE} per core of this machine's "
                                        f"{os.cpu_count() or 1})"), err
    assert not (tmp_path / "out").exists()


REPLAY = """name: rp
base: {scenario: load_step, t_end: 0.8}
sampling: {method: grid}
axes:
  fw.spd_filter_Hz: {values: [150.0]}
  plant.adc_noise_counts: {values: [1.5]}
  seed: {values: [7, 8]}
metrics: [position_error_rms_rad, position_error_max_rad]
"""


def test_replay_full_is_a_bench_run_of_the_same_case(tmp_path):
    """`--replay N --full`: the row as strict JSON with its parameters as an object (was a
    JSON string inside JSON), then the same case as a bench run on the simulated drive
    (report, CAN log, summary, the campaign's parameters beside them), with the full run's
    metrics beside the campaign's. The two paths differ (references over the bus at the
    bench's times vs at exact times in-process); measured 5-20 % apart on the position
    error, so within 50 % here, and the same seed and settings by construction."""
    import json

    f = tmp_path / "c.yaml"
    f.write_text(REPLAY)
    rc, out, err = _cli(f, "--replay", "1", "--full", "--runs", tmp_path / "runs",
                        cwd=tmp_path)
    assert rc == 0, err
    row = json.loads(out)
    assert row["params"] == {"fw.spd_filter_Hz": 150.0, "plant.adc_noise_counts": 1.5,
                             "seed": 8, "run": 1}
    assert '"seed": 8,' in out  # an integer, not 8.0
    (run_dir,) = [d for d in (tmp_path / "runs").iterdir() if d.is_dir()]
    for name in ("report.html", "summary.json", "can.blf", "campaign_run.json"):
        assert (run_dir / name).stat().st_size > 0, name
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["simulated"] is True
    assert json.loads((run_dir / "campaign_run.json").read_text())["params"]["seed"] == 8
    cmp = {ln.split()[0]: ln.split()[1:] for ln in err.splitlines()
           if ln.startswith("position_error")}
    for m in ("position_error_rms_rad", "position_error_max_rad"):
        camp, full = (float(x) for x in cmp[m])
        assert camp == pytest.approx(row[m], rel=1e-4)
        assert full == pytest.approx(summary["metrics"][m], rel=1e-4)
        assert abs(full / camp - 1) < 0.5, (m, camp, full)
    assert f"replayed as a bench run (PASSED): {run_dir}" in err


def test_replay_full_of_a_fault_case_says_why_not(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("name: fm\nbase: {scenario: fault_case}\nsampling: {method: grid}\n"
                 "axes:\n  case: {values: all}\n  seed: {values: [0]}\n"
                 "metrics: [blind_max_s, verdict_ok]\n")
    rc, out, err = _cli(f, "--replay", "0", "--full", cwd=tmp_path)
    assert rc == 2 and "a fault case injects faults inside the simulation" in err
    assert err.count("\n") == 1
