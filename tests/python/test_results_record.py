"""The test record of a run: the device under test as the drive answers (never typed),
operator / station / fixture from the options, the environment or the system, in
summary.json (and its schema), meta.json, junit.xml and the results store.

The drive here is canopen's LocalNode (``sim_fallback.FakeDrive402``) reached as any drive
on a bus is (``--interface virtual``), given a serial number and build id of its own on the
drive side: the record must carry them."""

from __future__ import annotations

import copy
import json
import os
import socket
import sqlite3
import subprocess
import sys
import threading
import uuid
import xml.etree.ElementTree as ET
from pathlib import Path

import can
import jsonschema
import pytest
from sim_libs import needs_sim

from bench import _results as R
from bench.cli import main
from protocols.generated import od_names as od
from sim_fallback import FakeDrive402

ROOT = Path(__file__).resolve().parents[2]
SCHEMA = json.loads((ROOT / "bench" / "schemas" / "summary.schema.json").read_text())
SERIAL, BUILD = 0xCAFE1234, "lab-42"
SEQ = ("name: rec\nmotor: paper_salient\nextractor: sogi\nseed: 0\nsteps:\n"
       "  - enable: {}\n  - wait: {duration_s: 0.3}\n  - disable: {}\n")


def _run_on_fake(tmp: Path, *extra: str, fault_after_s: float | None = None,
                 seq: str = SEQ) -> tuple[int, Path]:
    ch = f"rec-{uuid.uuid4().hex[:8]}"
    fake = FakeDrive402(can.Bus(interface="virtual", channel=ch))
    fake._set(od.IDENTITY_OBJECT__SERIAL_NUMBER, SERIAL)  # the drive's own, not typed
    fake._set(od.BUILD_ID, BUILD)
    (tmp / "rec.yaml").write_text(seq)
    timer = threading.Timer(fault_after_s, fake.raise_fault) if fault_after_s else None
    if timer is not None:
        timer.start()
    try:
        rc = main(["run", str(tmp / "rec.yaml"), "--interface", "virtual", "--channel", ch,
                   "--runs", str(tmp / "runs"), "--no-progress", "--summary-json",
                   str(tmp / "s.json"), "--junit", str(tmp / "j.xml"), *extra])
    finally:
        if timer is not None:
            timer.cancel()
        fake.close()
    return rc, tmp / "s.json"


@pytest.fixture(scope="module")
def fake_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    tmp = tmp_path_factory.mktemp("rec")
    rc, s = _run_on_fake(tmp, "--operator", "Ada Lovelace", "--station", "rig 3",
                         "--fixture", "F-7")
    assert rc == 0
    return tmp, json.loads(s.read_text())


def test_the_identity_is_what_the_drive_answers(fake_run: tuple[Path, dict]) -> None:
    tmp, doc = fake_run
    dut = doc["dut"]
    assert dut["serial"] == SERIAL and dut["build_id"] == BUILD
    assert dut["kind"] == "no_io" == doc["drive"]  # what the stand-in drive says it is
    assert dut["firmware_version"] and dut["device_name"] and dut["product_code"]
    run_dir = Path(doc["run_dir"])
    on_disk = json.loads((run_dir / "summary.json").read_text())
    assert on_disk["dut"] == dut and on_disk["record"] == doc["record"]
    meta = json.loads((run_dir / "meta.json").read_text())
    assert meta["dut"] == dut and meta["drive"]["serial"] == SERIAL
    assert meta["record"]["verdict"] == "passed" and meta["record"]["operator"] == "Ada Lovelace"
    rec = doc["record"]
    assert (rec["operator"], rec["station"], rec["fixture"]) == ("Ada Lovelace", "rig 3", "F-7")
    assert (rec["verdict"], rec["exit_code"]) == ("passed", 0)
    assert rec["started_utc"] <= rec["finished_utc"] and rec["duration_s"] > 0
    assert rec["sequence_file"] == str(tmp / "rec.yaml")
    (row,) = sqlite3.connect(tmp / "runs" / "results.sqlite").execute(
        "SELECT serial, build_id, drive_kind, operator, station, fixture, verdict FROM runs")
    assert row == (SERIAL, BUILD, "no_io", "Ada Lovelace", "rig 3", "F-7", "passed")


def test_the_report_shows_the_record(fake_run: tuple[Path, dict]) -> None:
    """report.html carries the test record: the drive's serial as it answered, who,
    where, on which fixture."""
    import html as h
    import re

    _, doc = fake_run
    text = h.unescape(re.sub(r"<[^>]+>", " ", (Path(doc["run_dir"]) / "report.html")
                             .read_text(encoding="utf-8")))
    sec = " ".join(text[text.index("Test record"):text.index(" Run ")].split())
    assert f"drive serial number (0x1018:4) 0x{SERIAL:08X}" in sec
    assert "operator Ada Lovelace" in sec and "station rig 3" in sec and "fixture F-7" in sec


def test_junit_carries_the_record(fake_run: tuple[Path, dict]) -> None:
    tmp, doc = fake_run
    for path in (tmp / "j.xml", Path(doc["run_dir"]) / "junit.xml"):
        suite = ET.parse(path).getroot().find("testsuite")
        # the suite's own properties: what the drive is (as written by bench._report)
        assert {p.get("name"): p.get("value") for p in suite.find("properties")} == {
            "drive": "no_io", "simulated": "true", "fallback": "false", "board": ""}
        (run,) = [c for c in suite.findall("testcase") if c.get("name") == "run"]
        props = {p.get("name"): p.get("value") for p in run.find("properties")}
        assert props["serial_number"] == str(SERIAL) and props["build_id"] == BUILD
        assert props["product_code"] == f"0x{doc['dut']['product_code']:08X}"
        assert props["operator"] == "Ada Lovelace" and props["station"] == "rig 3"
        assert props["fixture"] == "F-7" and props["device_name"] == doc["dut"]["device_name"]
        assert props["sequence_sha256"] == doc["record"]["sequence_sha256"]
        assert props["started_utc"] == doc["record"]["started_utc"]


def test_summaries_with_the_record_follow_the_schema(fake_run: tuple[Path, dict]) -> None:
    _, doc = fake_run
    jsonschema.validate(doc, SCHEMA)

    def refused(change) -> None:
        bad = copy.deepcopy(doc)
        change(bad)
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(bad, SCHEMA)

    refused(lambda d: d.pop("dut"))
    refused(lambda d: d.pop("record"))
    refused(lambda d: d["record"].update(verdict="failed"))         # not the run's verdict
    refused(lambda d: d["record"].update(verdict="maybe"))
    refused(lambda d: d.update(aborted=True, passed=False))         # aborted, record: passed
    refused(lambda d: d["dut"].update(kind="hardware"))             # not what the drive said
    refused(lambda d: d["dut"].update(serial=-1))
    refused(lambda d: d["dut"].update(serial=2 ** 32))
    refused(lambda d: d["dut"].pop("serial"))
    refused(lambda d: d["record"].update(operator="a\nb"))
    refused(lambda d: d["record"].update(station="x" * 101))
    refused(lambda d: d["record"].update(started_utc="2026-01-01 10:00"))
    refused(lambda d: d["record"].update(sequence_sha256="abc"))
    refused(lambda d: d["record"]["params"].update(v="fast"))


def test_an_aborted_run_is_recorded_as_aborted(tmp_path: Path) -> None:
    seq = SEQ.replace("duration_s: 0.3", "duration_s: 5")
    rc, s = _run_on_fake(tmp_path, fault_after_s=0.5, seq=seq)
    assert rc == 3
    doc = json.loads(s.read_text())
    assert doc["aborted"] and doc["record"]["verdict"] == "aborted"
    assert doc["record"]["exit_code"] == 3 and "EST_PLL_ERROR" in doc["record"]["exit_reason"]
    jsonschema.validate(doc, SCHEMA)
    (row,) = sqlite3.connect(tmp_path / "runs" / "results.sqlite").execute(
        "SELECT verdict, exit_code, exit_reason, serial FROM runs")
    assert row[:2] == ("aborted", 3) and "EST_PLL_ERROR" in row[2] and row[3] == SERIAL


# ---- operator, station, fixture ---------------------------------------------------------


def _env(**kw: str) -> dict[str, str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for k in (*R.STATION_ENV.values(), "BENCH_DEBUG"):
        env.pop(k, None)
    env.update(kw)
    return env


def test_station_fields_precedence() -> None:
    env = {"BENCH_OPERATOR": " eve ", "BENCH_STATION": "st-9", "BENCH_FIXTURE": "fx"}
    assert R.station_fields(environ=env) == {"operator": "eve", "station": "st-9",
                                             "fixture": "fx"}
    assert R.station_fields("bob", None, "", environ=env) == {"operator": "bob",
                                                              "station": "st-9", "fixture": ""}
    got = R.station_fields(environ={})
    assert got["station"] == socket.gethostname()[:100] and got["fixture"] == ""


@pytest.mark.parametrize("args, env, needle", [
    (["--operator", "a\tb"], {}, "--operator: 'a\\tb': character 2 (U+0009) is not printable"),
    (["--fixture", "x\x1b[31m"], {}, "--fixture: "),
    (["--station", "s" * 101], {}, "--station: 101 characters; at most 100"),
    ([], {"BENCH_OPERATOR": "line1\nline2"}, "--operator (from BENCH_OPERATOR): "),
    ([], {"BENCH_STATION": "x" * 300}, "--station (from BENCH_STATION): 300 characters"),
])
def test_bad_operator_station_fixture_is_one_line_exit_2(tmp_path: Path, args: list[str],
                                                         env: dict[str, str],
                                                         needle: str) -> None:
    (tmp_path / "rec.yaml").write_text(SEQ)
    r = subprocess.run([sys.executable, "-m", "bench", "run", "rec.yaml", "--sim", "--runs",
                        "runs", "--no-progress", *args], cwd=tmp_path, env=_env(**env),
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("bench: ") and needle in lines[0], lines
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "runs").exists()  # nothing ran


@needs_sim
def test_defaults_from_the_environment_then_the_system(tmp_path: Path) -> None:
    """One run with the variables set, one without (the login name from LOGNAME, the
    host name); an option beats its variable. In a subprocess, as a lab's CI runs it."""
    (tmp_path / "rec.yaml").write_text(SEQ)

    def run(*args: str, **env: str) -> dict:
        r = subprocess.run([sys.executable, "-m", "bench", "run", "rec.yaml", "--sim",
                            "--runs", "runs", "--no-progress", "--summary-json", "s.json",
                            *args], cwd=tmp_path, env=_env(**env), capture_output=True,
                           text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        return json.loads((tmp_path / "s.json").read_text())["record"]

    rec = run("--fixture", "opt-fx", BENCH_OPERATOR="env-op", BENCH_STATION="env-st",
              BENCH_FIXTURE="env-fx")
    assert (rec["operator"], rec["station"], rec["fixture"]) == ("env-op", "env-st", "opt-fx")
    rec = run(LOGNAME="lab-user", USER="lab-user")
    assert (rec["operator"], rec["station"], rec["fixture"]) == (
        "lab-user", socket.gethostname(), "")
