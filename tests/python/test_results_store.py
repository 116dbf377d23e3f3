"""The results store across runs (``RUNS/results.sqlite``): written by every run, opened
here independently with ``sqlite3``; two processes writing at once; a store that cannot
be written never changes a run's verdict; ``bench results`` filters, exports and exit
codes; ``--rebuild`` recovers a deleted or corrupt store from the run folders."""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from sim_libs import needs_sim

from bench import _results as R

ROOT = Path(__file__).resolve().parents[2]
BANNERS = ("bench: using the SIMULATED drive", "bench: no drive hardware found",
           "bench: FALLING BACK TO THE SIMULATED DRIVE")
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
ENV.pop("BENCH_DEBUG", None)
for _k in R.STATION_ENV.values():
    ENV.pop(_k, None)

SEQ = """\
name: {name}
motor: paper_salient
extractor: sogi_adaptive
seed: 1
steps:
  - enable: {{mode: speed}}
  - set_speed: {{value: 100, unit: r/min}}
  - wait: {{duration_s: 0.3}}
  - expect: {{metric: speed_tracking_error_max_rpm, op: "<=", limit: {limit}, window_s: [0.2, 0.3]}}
  - disable: {{}}
"""


def bench(*args: str, cwd: Path, env: dict[str, str] | None = None
          ) -> tuple[int, str, list[str]]:
    r = subprocess.run([sys.executable, "-m", "bench", *args], capture_output=True, text=True,
                       cwd=cwd, env=env or ENV, timeout=300)
    assert "Traceback" not in r.stderr, r.stderr
    return r.returncode, r.stdout, [ln for ln in r.stderr.splitlines()
                                    if ln and not ln.startswith(BANNERS)]


def rows(db: Path, sql: str = "SELECT * FROM runs ORDER BY id") -> list[dict]:
    """The store read with sqlite3 alone (not through bench)."""
    con = sqlite3.connect(db)
    con.row_factory = sqlite3.Row
    try:
        return [dict(r) for r in con.execute(sql)]
    finally:
        con.close()


def fake_summary(seq: str = "s", passed: bool = True, aborted: bool = False,
                 serial: int | None = 7, motor: str = "paper_salient",
                 started: str = "2026-03-04T10:00:00.000000Z", n_exp: int = 2) -> dict:
    verdict = "aborted" if aborted else ("passed" if passed else "failed")
    return {
        "sequence": seq, "passed": passed, "aborted": aborted, "error": None,
        "drive": "hardware", "board": "nucleo", "simulated": False, "fallback": False,
        "expectations": [{"name": f"m{i}", "metric": "position_error_rms_rad",
                          "measured": 0.01 * (i + 1), "criterion": "<= 0.02",
                          "window_s": [0.1, 0.5], "passed": passed or i == 0,
                          "status": "pass" if passed or i == 0 else "fail"}
                         for i in range(n_exp)],
        "dut": {"vendor_id": 0x359, "product_code": 0x504D4C53, "revision": 0x300,
                "serial": serial, "firmware_version": "0.3.0", "build_id": "b1",
                "device_name": "PMLSM sensorless drive", "kind": "hardware",
                "board": "nucleo", "error": None},
        "record": {"operator": "ada", "station": "rig-1", "fixture": "F1",
                   "started_utc": started, "finished_utc": started, "duration_s": 1.5,
                   "verdict": verdict, "exit_reason": "x", "exit_code": 0,
                   "sequence_name": seq, "sequence_file": "/x.yaml", "sequence_sha256": "0" * 64,
                   "params": {"v": 1}, "motor": motor},
    }


# ---- the store written by runs ----------------------------------------------------------


@needs_sim
def test_every_run_is_a_row_and_its_expectations_rows(tmp_path: Path) -> None:
    (tmp_path / "pass.yaml").write_text(SEQ.format(name="p", limit=60))
    (tmp_path / "fail.yaml").write_text(SEQ.format(name="f", limit=1e-9))
    rc, out, err = bench("run", "pass.yaml", "--sim", "--runs", "runs", "--no-progress",
                         "--operator", "ada", "--station", "rig-3", "--fixture", "F7",
                         cwd=tmp_path)
    assert rc == 0 and not err, (out, err)
    rc, out, err = bench("run", "fail.yaml", "--sim", "--runs", "runs", "--no-progress",
                         cwd=tmp_path)
    assert rc == 1 and not err, (out, err)
    db = tmp_path / "runs" / "results.sqlite"
    runs = rows(db)
    assert [(r["sequence"], r["verdict"], r["exit_code"]) for r in runs] == [
        ("p", "passed", 0), ("f", "failed", 1)]
    p, f = runs
    assert (p["operator"], p["station"], p["fixture"]) == ("ada", "rig-3", "F7")
    assert p["drive_kind"] == "simulated" and p["motor"] == "paper_salient"
    assert p["sequence_sha256"] == hashlib.sha256((tmp_path / "pass.yaml").read_bytes()).hexdigest()
    # the identity in the store is what the run's own files say the drive answered
    meta = json.loads((tmp_path / "runs" / p["run_dir"] / "meta.json").read_text())
    assert p["serial"] == meta["drive"]["serial"] and p["build_id"] == meta["drive"]["build_id"]
    assert p["firmware_version"] == meta["drive"]["firmware_version"]
    assert p["started_utc"] < f["started_utc"] and p["duration_s"] > 0
    exps = rows(db, "SELECT * FROM expectations ORDER BY run_id, idx")
    assert [(e["run_id"], e["status"]) for e in exps] == [(p["id"], "pass"), (f["id"], "fail")]
    assert exps[1]["metric"] == "speed_tracking_error_max_rpm" and exps[1]["measured"] > 0
    assert exps[1]["criterion"] == "<= 1e-09"
    assert "1 expectation(s) failed" in f["exit_reason"]
    con = sqlite3.connect(db)
    assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    con.close()


@needs_sim
def test_two_bench_processes_running_at_once_both_recorded(tmp_path: Path) -> None:
    for n in ("a", "b"):
        (tmp_path / f"{n}.yaml").write_text(SEQ.format(name=n, limit=60))
    procs = [subprocess.Popen([sys.executable, "-m", "bench", "run", f"{n}.yaml", "--sim",
                               "--runs", "runs", "--no-progress"], cwd=tmp_path, env=ENV,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for n in ("a", "b")]
    for p in procs:
        out, err = p.communicate(timeout=300)
        assert p.returncode == 0, (out, err)
        assert "results store" not in err, err
    got = rows(tmp_path / "runs" / "results.sqlite")
    assert sorted(r["sequence"] for r in got) == ["a", "b"]
    assert len(rows(tmp_path / "runs" / "results.sqlite", "SELECT * FROM expectations")) == 2


WRITER = textwrap.dedent("""\
    import sys, time, pathlib
    from bench import _results as R
    root, tag, n, go = sys.argv[1], sys.argv[2], int(sys.argv[3]), pathlib.Path(sys.argv[4])
    while not go.exists():
        time.sleep(0.001)
    for i in range(n):
        doc = {"sequence": f"{tag}{i}", "passed": True, "aborted": False,
               "drive": "simulated",
               "expectations": [{"name": f"e{k}", "metric": "position_error_rms_rad",
                                 "measured": k, "criterion": "<= 1", "window_s": [0, 1],
                                 "passed": True, "status": "pass"} for k in range(5)],
               "record": {"started_utc": f"2026-01-01T00:00:{i:02d}.000000Z",
                          "verdict": "passed"}}
        R.record_run(root, f"{root}/{tag}_{i:03d}", doc)
""")


def test_two_processes_writing_the_store_at_once(tmp_path: Path) -> None:
    """Two writers released together onto a store that does not exist yet (both create
    it, both switch it to WAL): every run and every expectation lands, none twice, and
    the file is intact. Without the write lock taken first (BEGIN IMMEDIATE) and the
    retries, one of them fails with 'database is locked'."""
    (tmp_path / "w.py").write_text(WRITER)
    go = tmp_path / "go"
    n = 60
    procs = [subprocess.Popen([sys.executable, str(tmp_path / "w.py"), str(tmp_path), tag,
                               str(n), str(go)], env=ENV, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for tag in ("x", "y")]
    go.touch()
    for p in procs:
        out, err = p.communicate(timeout=300)
        assert p.returncode == 0, err
    db = tmp_path / "results.sqlite"
    got = rows(db)
    assert len(got) == 2 * n
    assert {r["run_dir"] for r in got} == {f"{t}_{i:03d}" for t in "xy" for i in range(n)}
    ex = rows(db, "SELECT run_id, COUNT(*) AS k FROM expectations GROUP BY run_id")
    assert len(ex) == 2 * n and {e["k"] for e in ex} == {5}
    con = sqlite3.connect(db)
    assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    con.close()


@needs_sim
@pytest.mark.parametrize("limit, code", [(60, 0), (1e-9, 1)])
@pytest.mark.parametrize("broken", ["garbage", "directory"])
def test_a_store_that_cannot_be_written_never_changes_the_run(tmp_path: Path, limit: float,
                                                              code: int, broken: str) -> None:
    (tmp_path / "s.yaml").write_text(SEQ.format(name="s", limit=limit))
    store = tmp_path / "runs" / "results.sqlite"
    store.parent.mkdir()
    if broken == "garbage":
        store.write_bytes(b"this is not a database\n" * 100)
    else:
        store.mkdir()
    rc, out, err = bench("run", "s.yaml", "--sim", "--runs", "runs", "--no-progress",
                         "--summary-json", "s.json", cwd=tmp_path)
    assert rc == code, (out, err)
    assert len(err) == 1 and err[0].startswith("bench: warning: results store"), err
    assert "not updated" in err[0] and "--rebuild" in err[0]
    doc = json.loads((tmp_path / "s.json").read_text())
    assert doc["record"]["verdict"] == ("passed" if code == 0 else "failed")
    assert (tmp_path / doc["run_dir"] / "summary.json").is_file()
    if broken == "garbage":  # the store was left as it was
        assert store.read_bytes() == b"this is not a database\n" * 100


# ---- bench results ----------------------------------------------------------------------


@pytest.fixture()
def store(tmp_path: Path) -> Path:
    """A runs folder with five runs recorded (folders with summary.json, like real ones)."""
    root = tmp_path / "runs"
    specs = [("a", True, False, 7, "paper_salient", "2026-03-01T08:00:00.000000Z"),
             ("a", False, False, 7, "paper_salient", "2026-03-02T09:00:00.000000Z"),
             ("b", True, False, 8, "iron_core_linear", "2026-03-03T10:00:00.000000Z"),
             ("b", False, True, 0xCAFE, "iron_core_linear", "2026-03-04T11:00:00.000000Z"),
             ("a", True, False, 8, "paper_salient", "2026-03-05T12:00:00.000000Z")]
    for i, (seq, ok, ab, serial, motor, t) in enumerate(specs):
        d = root / f"2026030{i + 1}T000000_000000Z_{seq}"
        d.mkdir(parents=True)
        doc = fake_summary(seq, ok, ab, serial, motor, t)
        (d / "summary.json").write_text(json.dumps(doc))
        R.record_run(root, d, doc)
    return root


def _json(store: Path, *args: str) -> list[dict]:
    rc, out, err = bench("results", "--runs", str(store), "--json", *args, cwd=store.parent)
    assert rc == 0 and not err, err
    return json.loads(out)


def test_results_table_newest_first(store: Path) -> None:
    rc, out, err = bench("results", "--runs", str(store), cwd=store.parent)
    assert rc == 0 and not err
    lines = out.splitlines()
    assert lines[0].split()[:4] == ["STARTED", "(UTC)", "VERDICT", "SEQUENCE"]
    assert [ln.split()[:3] for ln in lines[1:6]] == [
        ["2026-03-05", "12:00:00", "PASSED"], ["2026-03-04", "11:00:00", "ABORTED"],
        ["2026-03-03", "10:00:00", "PASSED"], ["2026-03-02", "09:00:00", "FAILED"],
        ["2026-03-01", "08:00:00", "PASSED"]]
    assert "51966" in lines[2] and "ada" in lines[2] and "rig-1" in lines[2]
    assert lines[-1] == "5 runs: 3 passed, 1 failed, 1 aborted"


def test_results_filters(store: Path) -> None:
    def seqs(*args: str) -> list[tuple[str, str]]:
        return [(r["sequence"], r["started_utc"][:10]) for r in _json(store, *args)]

    assert seqs("--motor", "iron_core_linear") == [("b", "2026-03-04"), ("b", "2026-03-03")]
    assert seqs("--serial", "8") == [("a", "2026-03-05"), ("b", "2026-03-03")]
    assert seqs("--serial", "0xcafe") == [("b", "2026-03-04")]
    assert seqs("--sequence", "a", "--verdict", "passed") == [("a", "2026-03-05"),
                                                             ("a", "2026-03-01")]
    assert seqs("--verdict", "aborted") == [("b", "2026-03-04")]
    # a day given to --until is the whole day; times are UTC unless an offset is given
    assert seqs("--since", "2026-03-02", "--until", "2026-03-03") == [("b", "2026-03-03"),
                                                                      ("a", "2026-03-02")]
    assert seqs("--since", "2026-03-04T11:00") == [("a", "2026-03-05"), ("b", "2026-03-04")]
    assert seqs("--since", "2026-03-04T12:30+02:00", "--until", "2026-03-04T11:00Z") == [
        ("b", "2026-03-04")]
    assert seqs("--limit", "2") == [("a", "2026-03-05"), ("b", "2026-03-04")]
    assert seqs("--motor", "nope") == []
    rc, out, err = bench("results", "--runs", str(store), "--motor", "nope", cwd=store.parent)
    assert rc == 0 and "no runs" in out and "match" in out


def test_results_json_and_csv_exports(store: Path, tmp_path: Path) -> None:
    runs = _json(store, "--serial", "7")
    assert [r["verdict"] for r in runs] == ["failed", "passed"]
    r = runs[0]
    assert r["params"] == {"v": 1} and r["vendor_id"] == 0x359 and r["fixture"] == "F1"
    assert [(e["name"], e["status"]) for e in r["expectations"]] == [("m0", "pass"),
                                                                     ("m1", "fail")]
    assert r["expectations"][1]["measured"] == pytest.approx(0.02)
    out_csv = tmp_path / "out.csv"
    rc, out, err = bench("results", "--runs", str(store), "--csv", str(out_csv),
                         cwd=tmp_path)
    assert rc == 0 and not err and "5 run(s)" in out
    table = list(csv.DictReader(io.StringIO(out_csv.read_text())))
    assert len(table) == 5 and table[0]["started_utc"].startswith("2026-03-05")
    assert {c for c, _ in R.RUN_COLUMNS} <= set(table[0])
    assert table[1]["serial"] == str(0xCAFE) and table[1]["verdict"] == "aborted"
    rc, out, err = bench("results", "--runs", str(store), "--csv", "-", "--verdict", "failed",
                         cwd=tmp_path)
    assert rc == 0 and len(list(csv.DictReader(io.StringIO(out)))) == 1


@pytest.mark.parametrize("args, needle", [
    (["--since", "yesterday"], "--since 'yesterday': not a date"),
    (["--until", "2026-02-30"], "--until '2026-02-30': not a date"),
    (["--since", "2026-03-05", "--until", "2026-03-01"], "is after --until"),
    (["--verdict", "ok"], "--verdict 'ok': allowed: passed, failed, aborted"),
    (["--serial", "abc"], "--serial 'abc': not a serial number"),
    (["--serial", "0x1FFFFFFFF"], "outside 0..0xFFFFFFFF"),
    (["--limit", "0"], "--limit '0'"),
])
def test_bad_filters_are_one_line_exit_2(store: Path, args: list[str], needle: str) -> None:
    rc, out, err = bench("results", "--runs", str(store), *args, cwd=store.parent)
    assert rc == 2 and out == "", out
    assert len(err) == 1 and err[0].startswith("bench: ") and needle in err[0], err


def test_missing_corrupt_or_foreign_store_is_one_line_exit_3(tmp_path: Path) -> None:
    rc, out, err = bench("results", "--runs", str(tmp_path / "none"), cwd=tmp_path)
    assert rc == 3 and len(err) == 1 and "no results store" in err[0] and "--rebuild" in err[0]
    assert not (tmp_path / "none").exists()  # a query creates nothing
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "results.sqlite").write_bytes(b"\x00garbage" * 512)
    rc, out, err = bench("results", "--runs", str(bad), cwd=tmp_path)
    assert rc == 3 and len(err) == 1, err
    assert "cannot be read as a results store" in err[0] and "--rebuild" in err[0]
    other = tmp_path / "other"
    other.mkdir()
    con = sqlite3.connect(other / "results.sqlite")
    con.execute("CREATE TABLE runs (x TEXT)")
    con.commit()
    con.close()
    rc, out, err = bench("results", "--runs", str(other), cwd=tmp_path)
    assert rc == 3 and len(err) == 1 and "not a results store" in err[0], err
    con = sqlite3.connect(other / "results.sqlite")  # a query left the file as it was
    assert con.execute("PRAGMA journal_mode").fetchone()[0] == "delete"
    con.close()


def test_rebuild_recovers_a_deleted_or_corrupt_store(store: Path) -> None:
    db = store / "results.sqlite"
    cols = "run_dir, sequence, serial, motor, verdict, started_utc, operator, station, fixture"
    before = rows(db, f"SELECT {cols} FROM runs ORDER BY run_dir")
    before_exp = rows(db, "SELECT r.run_dir, e.idx, e.name, e.measured, e.status FROM "
                          "expectations e JOIN runs r ON r.id = e.run_id ORDER BY 1, 2")
    assert len(before) == 5
    for suffix in ("", "-wal", "-shm"):
        Path(str(db) + suffix).unlink(missing_ok=True)
    rc, out, err = bench("results", "--runs", str(store), cwd=store.parent)
    assert rc == 3
    rc, out, err = bench("results", "--runs", str(store), "--rebuild", cwd=store.parent)
    assert rc == 0 and err == [f"bench: rebuilt {db}: 5 run(s) from the run folders"], err
    assert out.splitlines()[-1] == "5 runs: 3 passed, 1 failed, 1 aborted"
    assert rows(db, f"SELECT {cols} FROM runs ORDER BY run_dir") == before
    assert rows(db, "SELECT r.run_dir, e.idx, e.name, e.measured, e.status FROM expectations e "
                    "JOIN runs r ON r.id = e.run_id ORDER BY 1, 2") == before_exp
    # corrupt: moved aside (said), rebuilt; a folder whose summary is unreadable is named
    db.write_bytes(b"garbage" * 1000)
    (store / "20260309T000000_000000Z_x").mkdir()
    (store / "20260309T000000_000000Z_x" / "summary.json").write_text("{not json")
    rc, out, err = bench("results", "--runs", str(store), "--rebuild", "--json",
                         cwd=store.parent)
    assert rc == 0, err
    assert len(json.loads(out)) == 5
    assert any("unreadable store was moved to" in ln for ln in err)
    assert any("skipped 20260309T000000_000000Z_x" in ln for ln in err)
    assert list(store.glob("results.sqlite.unreadable-*"))
    assert rows(db, f"SELECT {cols} FROM runs ORDER BY run_dir") == before
    rc, out, err = bench("results", "--runs", str(store.parent / "nowhere"), "--rebuild",
                         cwd=store.parent)
    assert rc == 2 and len(err) == 1 and "no such folder" in err[0]


def test_rebuild_reads_runs_from_before_the_record(tmp_path: Path) -> None:
    """A run folder written before summary.json had ``dut`` / ``record``: its identity
    from meta.json, its start from the folder name, its verdict from passed/aborted."""
    d = tmp_path / "runs" / "20250102T030405_123456Z_old"
    d.mkdir(parents=True)
    doc = fake_summary("old", passed=False)
    del doc["dut"], doc["record"]
    (d / "summary.json").write_text(json.dumps(doc))
    (d / "meta.json").write_text(json.dumps({
        "drive": {"serial": 4711, "vendor_id": 1, "product_code": 2, "revision": 3,
                  "firmware_version": "0.2.0", "build_id": "old", "device_name": "d"},
        "sequence": {"motor": "paper_salient", "file": "/s/old.yaml"}}))
    n, skipped, moved = R.rebuild(tmp_path / "runs")
    assert (n, skipped, moved) == (1, [], None)
    (r,) = rows(tmp_path / "runs" / "results.sqlite")
    assert (r["serial"], r["firmware_version"], r["motor"], r["verdict"]) == (
        4711, "0.2.0", "paper_salient", "failed")
    assert r["started_utc"] == "2025-01-02T03:04:05.123456Z"
    assert r["sequence_file"] == "/s/old.yaml" and r["operator"] is None
