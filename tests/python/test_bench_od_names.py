"""The bench addresses the drive's object dictionary by name (issue 13 item 3): the
entries generated from protocols/od.yaml (`protocols.generated.od_names`), never a bare
index in the code. A literal equal to an object index in the bench's code, its tools,
examples and benchmarks (comments and docstrings aside) fails this test, naming the file
and line."""

from __future__ import annotations

import io
import re
import tokenize
from pathlib import Path

import yaml

from protocols.generated import od_names as od

REPO = Path(__file__).resolve().parents[2]

#: where a CiA 301 area bound is defined by name (index ranges, not objects)
AREA_DEFINITIONS = re.compile(r"^[A-Z_]+_AREA = range\(")


def _od_indices() -> set[int]:
    """The objects od.yaml lists, and the PDO parameter objects generated from it."""
    data = yaml.safe_load((REPO / "protocols" / "od.yaml").read_text())
    return ({int(o["index"]) for o in data["objects"]}
            | {v for k, v in vars(od).items() if k.startswith("INDEX_")})


def test_bench_code_names_od_entries_instead_of_indices():
    indices = _od_indices()
    assert 0x6040 in indices and 0x2060 in indices  # the reference itself is sound
    bare = []
    paths = [p for d in ("bench", "tools", "examples", "benchmarks")
             for p in sorted((REPO / d).glob("*.py"))]
    assert len(paths) > 20, paths
    for path in paths:
        src = path.read_text()
        for tok in tokenize.generate_tokens(io.StringIO(src).readline):
            if tok.type != tokenize.NUMBER or not tok.string.lower().startswith("0x"):
                continue
            if int(tok.string, 16) in indices and not AREA_DEFINITIONS.match(tok.line.strip()):
                bare.append(f"{path.relative_to(REPO)}:{tok.start[0]}: {tok.line.strip()}")
    assert not bare, "bare OD indices (use protocols.generated.od_names):\n" + "\n".join(bare)


def test_generated_entries_match_od_yaml():
    """Every named entry is the (index, sub) od.yaml gives it, and var objects are sub 0."""
    data = yaml.safe_load((REPO / "protocols" / "od.yaml").read_text())
    by_index = {int(o["index"]): o for o in data["objects"]}
    n = 0
    for name, e in vars(od).items():
        if not isinstance(e, od.Entry):
            continue
        n += 1
        if e.index not in by_index:  # PDO parameters, generated from od.yaml's pdos
            assert 0x1400 <= e.index < 0x1C00, name
            continue
        obj = by_index[e.index]
        if e.var:
            assert obj.get("kind", "var") == "var" and e.sub == 0, name
        else:
            subs = {int(s["sub"]) for s in obj["subs"]}
            assert e.sub in subs, name
        assert od.ENTRIES[(e.index, e.sub)]
    assert n > 150
    assert od.CONTROLWORD[:3] == (0x6040, 0, True)
    assert od.TELEMETRY__DECIMATION[:2] == (0x2060, 1)


def test_wire_units_agree_with_od_yaml_scales():
    """The bench's wire-unit factors (bench._units.WIRE_UNITS) and od.yaml's own scales of
    the entries that mirror a configuration field (``scale``: SI -> wire) are the same
    numbers, so that the two ways across the wire cannot drift apart; and every wire unit
    the CiA 402 process data use is known."""
    from bench._units import WIRE_UNITS, si_to_wire, wire_to_si
    from protocols import _od

    model = _od.load()
    checked = 0
    for e in model.entries:
        if e.fw_config and e.scale != 1.0:
            assert e.unit in WIRE_UNITS, (e.index, e.sub, e.unit)
            assert WIRE_UNITS[e.unit][1] * e.scale == 1.0, (e.index, e.sub, e.unit)
            checked += 1
    assert checked >= 3
    for e in (od.POSITION_ACTUAL_VALUE, od.VELOCITY_ACTUAL_VALUE, od.TARGET_VELOCITY,
              od.TORQUE_ACTUAL_VALUE, od.TARGET_TORQUE):
        assert e.unit in WIRE_UNITS, e
    assert si_to_wire(od.TARGET_VELOCITY, 0.25) == 250_000      # m/s -> um/s
    assert wire_to_si(od.POSITION_ACTUAL_VALUE, -1_500) == -1.5e-3  # um -> m
    assert si_to_wire(od.TARGET_TORQUE, 0.2) == 200              # fraction -> per mille


def test_a_parameter_name_means_one_unit() -> None:
    """`pos_limit_max_m` named both 0x2051:3 (m) and 0x607D:2 (um): a name shared by two
    objects must mean the same quantity in the same unit (the fw_config field's), else the
    object in another unit is known by its own name."""
    from bench._drive import param_table

    by_name: dict[str, set[tuple[str, str]]] = {}
    for p in {id(p): p for p in param_table().values()}.values():
        by_name.setdefault(p.name, set()).add((p.unit, p.type))
    mixed = {n: u for n, u in by_name.items() if len({unit for unit, _ in u}) > 1}
    assert not mixed, mixed
    t = param_table()
    assert (t["pos_limit_max_m"].address, t["pos_limit_max_m"].unit) == ("0x2051:3", "m")
    assert t["0x607D:2"].name == "Software position limit.Max position limit"
