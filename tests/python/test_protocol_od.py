"""Object dictionary: generated files match od.yaml, the EDS loads cleanly in
canopen and every attribute survives the round trip."""

from __future__ import annotations

import configparser
import logging
import struct
import warnings
from pathlib import Path

import canopen
import pytest
import yaml

from protocols import generate
from protocols._od import OdError, load

EDS = Path(generate.ROOT) / "protocols" / "generated" / "pmlsm_drive.eds"
NODE_ID = 5


def _f32(v: float) -> float:
    return struct.unpack("<f", struct.pack("<f", v))[0]


@pytest.fixture(scope="module")
def od():
    return load()


def test_generated_files_match_a_fresh_generation(od):
    drifted = generate.drifted(od)
    assert drifted == [], (
        f"generated files drifted from protocols/od.yaml: {drifted}; "
        "run `python -m protocols.generate`"
    )


def test_check_mode_exit_code():
    assert generate.main(["--check"]) == 0


def test_eds_loads_without_warnings(caplog):
    caplog.set_level(logging.DEBUG)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        cod = canopen.import_od(str(EDS), NODE_ID)
    bad = [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert bad == [], [r.getMessage() for r in bad]
    assert [str(x.message) for x in w] == []
    assert 0x6040 in cod and 0x1A03 in cod


def test_every_object_round_trips_through_canopen(od):
    cod = canopen.import_od(str(EDS), NODE_ID)
    n = 0
    for e in od.entries:
        var = cod[e.index] if e.kind == "var" else cod[e.index][e.sub]
        assert var.index == e.index and var.subindex == e.sub
        assert var.name == e.name
        assert var.data_type == e.type_code, e.c_ident
        assert var.access_type == e.access, e.c_ident
        assert var.pdo_mappable == e.pdo, e.c_ident
        assert (var.unit or "") == e.unit, e.c_ident
        assert (var.description or "") == e.doc, e.c_ident
        if e.type == "REAL32":
            assert var.default == pytest.approx(_f32(float(e.default)), rel=0, abs=0)
        elif e.type == "VISIBLE_STRING":
            assert var.default == e.default
        else:
            want = int(e.default) + (NODE_ID if e.nodeid_relative else 0)
            assert var.default == want, e.c_ident
            if e.min is not None:
                assert var.min == e.min, e.c_ident
            if e.max is not None:
                assert var.max == e.max, e.c_ident
        n += 1
    assert n == len(od.entries) > 150


def test_float_limits_are_in_the_eds(od):
    # canopen ignores non-integer limits; check the EDS text itself.
    cp = configparser.RawConfigParser()
    cp.optionxform = str
    cp.read(EDS)
    for e in od.entries:
        if e.type != "REAL32" or e.min is None:
            continue
        sec = f"{e.index:04X}" if e.kind == "var" else f"{e.index:04X}sub{e.sub:X}"
        assert float(cp.get(sec, "LowLimit")) == _f32(float(e.min))
        assert float(cp.get(sec, "HighLimit")) == _f32(float(e.max))


def test_required_objects_present(od):
    have = {(e.index, e.sub) for e in od.entries}
    for idx in (0x1000, 0x1001, 0x1005, 0x1014, 0x1017, 0x603F, 0x6040, 0x6041, 0x6060,
                0x6061, 0x6064, 0x606C, 0x6071, 0x6077, 0x60FF):
        assert (idx, 0) in have, hex(idx)
    for base in (0x1400, 0x1600, 0x1800, 0x1A00):
        for n in range(4):
            assert (base + n, 1) in have
    assert (0x1016, 1) in have and (0x1018, 4) in have
    # 402 modes: CSV (9) and CST (10)
    m = od.find(0x6060)
    assert (m.min, m.max) == (9, 10)


def test_config_objects_carry_fw_config_limits(od):
    raw = yaml.safe_load(Path(generate.ROOT, "protocols", "od.yaml").read_text())
    lim = raw["fw_config"]
    linked = [e for e in od.entries if e.fw_config]
    assert len(linked) >= 20
    for e in linked:
        assert e.min == lim[e.fw_config]["min"] and e.max == lim[e.fw_config]["max"]


def test_bad_yaml_is_reported_with_the_field(tmp_path):
    src = Path(generate.ROOT, "protocols", "od.yaml").read_text()
    bad = src.replace("    min: 9\n    max: 10\n    default: 9\n", "    min: 9\n    max: 10\n"
                      "    default: 300\n", 1)
    p = tmp_path / "od.yaml"
    p.write_text(bad)
    with pytest.raises(OdError, match="0x6060"):
        load(p)
    p.write_text(src.replace("type: UNSIGNED16\n    access: rw\n    pdo: true\n    default: 0\n"
                             "    doc: CiA 402 controlword",
                             "type: UINT16\n    access: rw\n    pdo: true\n    default: 0\n"
                             "    doc: CiA 402 controlword", 1))
    with pytest.raises(OdError, match="0x6040.*unknown type"):
        load(p)
