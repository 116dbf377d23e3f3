"""Self-describing run files: summary.json against its JSON Schema, one compressed MF4
with header metadata, units and comments on every channel and no duplicate part files,
and a CAN trace with both directions (the bench's own requests too)."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import can
import jsonschema
import pytest

from bench.cli import main

ROOT = Path(__file__).resolve().parents[2]
SCHEMA = json.loads((ROOT / "bench" / "schemas" / "summary.schema.json").read_text())


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    tmp = tmp_path_factory.mktemp("files")
    s = tmp / "summary.json"
    rc = main(["run", str(ROOT / "sequences" / "paper_load_step.yaml"), "--sim",
               "--summary-json", str(s), "--runs", str(tmp / "runs"), "--no-progress"])
    assert rc == 0
    return s, Path(json.loads(s.read_text())["run_dir"])


def test_summaries_follow_the_schema(run: tuple[Path, Path]) -> None:
    jsonschema.Draft202012Validator.check_schema(SCHEMA)
    s, run_dir = run
    for doc in (json.loads(s.read_text()), json.loads((run_dir / "summary.json").read_text())):
        jsonschema.validate(doc, SCHEMA)
    # the schema can fail: a hardware run claiming a fallback, a string metric
    bad = json.loads(s.read_text()) | {"drive": "hardware", "simulated": False,
                                       "fallback": True}
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, SCHEMA)
    # ... an emulated or simulated drive that claims not to be simulated, an old label
    for drive in ("emulated", "simulated", "unknown"):
        bad = json.loads(s.read_text()) | {"drive": drive, "simulated": False,
                                           "fallback": False}
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(bad, SCHEMA)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(json.loads(s.read_text()) | {"drive": "SIMULATED"}, SCHEMA)
    bad = json.loads(s.read_text())
    bad["metrics"]["position_error_rms_rad"] = "0.01"
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, SCHEMA)


def test_one_compressed_mf4_with_header_units_and_comments(run: tuple[Path, Path]) -> None:
    from asammdf import MDF

    _, run_dir = run
    assert not (run_dir / "signals").exists(), "crash-safety parts kept beside the MF4"
    meta = json.loads((run_dir / "meta.json").read_text())
    with MDF(run_dir / "signals.mf4") as mdf:
        root = ET.fromstring(mdf.header.comment if mdf.header.comment.startswith("<")
                             else f"<x>{mdf.header.comment}</x>")
        props = {e.get("name"): e.text or "" for e in root.iter("e")}
        assert props["sequence"] == "paper_load_step" and props["seed"] == "1"
        assert props["motor"] == "paper_salient" and props["drive"] == "simulated"
        assert props["firmware_version"] == meta["drive"]["firmware_version"]
        assert props["bench_version"] == meta["bench_version"]
        assert float(props["time_origin_s"]) == pytest.approx(meta["time_origin_s"], abs=1e-9)
        names = [n for n in mdf.channels_db if not n.startswith("time") and n != "t"]
        assert any(n.startswith("tel.") for n in names)
        assert any(n.startswith("trace.") for n in names)
        import yaml

        od_units = {x["name"]: x.get("unit", "") for x in
                    yaml.safe_load((ROOT / "protocols" / "od.yaml").read_text())["signals"]}
        checked = 0
        for n in names:
            sig = mdf.get(n)
            assert sig.comment, f"{n}: no comment"
            if n.startswith(("tel.", "trace.")):
                base = n.rsplit(".", 1)[-1]
                assert sig.unit == od_units[base], (n, sig.unit, od_units[base])
                checked += bool(od_units[base])
        assert checked >= 4  # rad, A, rad/s ... on the serial channels
    # compressed: well below the raw float64 payload of its samples
    from bench import read_signals

    raw = sum(v.nbytes + t.nbytes for t, v, _ in read_signals(run_dir).values())
    assert (run_dir / "signals.mf4").stat().st_size < 0.6 * raw


def test_can_trace_holds_both_directions(run: tuple[Path, Path]) -> None:
    _, run_dir = run
    frames = list(can.BLFReader(str(run_dir / "can.blf")))
    rx = {f.arbitration_id for f in frames if f.is_rx}
    tx = {f.arbitration_id for f in frames if not f.is_rx}
    assert 0x581 in rx and 0x181 in rx             # SDO responses, TPDO1 from the drive
    assert 0x601 in tx                             # the bench's SDO requests
    # every SDO request of the bench has its response in the same trace
    n_req = sum(1 for f in frames if not f.is_rx and f.arbitration_id == 0x601)
    n_resp = sum(1 for f in frames if f.is_rx and f.arbitration_id == 0x581)
    assert n_req > 10 and abs(n_req - n_resp) <= 2, (n_req, n_resp)
    meta = json.loads((run_dir / "meta.json").read_text())
    assert meta["logging"]["frames_sent_logged"] == sum(1 for f in frames if not f.is_rx)
    assert meta["logging"]["frames_logged"] == sum(1 for f in frames if f.is_rx)
