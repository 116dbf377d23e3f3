"""Object dictionary: generated files match od.yaml, the EDS loads cleanly in
canopen and every attribute survives the round trip."""

from __future__ import annotations

import configparser
import logging
import re
import struct
import warnings
from pathlib import Path

import canopen
import pytest
import yaml

from protocols import generate
from protocols._od import INT_RANGE, OdError, load

EDS = Path(generate.ROOT) / "protocols" / "generated" / "pmlsm_drive.eds"
#: the firmware version as od.yaml writes it (the edits below start from it)
_FW_VERSION = yaml.safe_load((Path(generate.ROOT) / "protocols" / "od.yaml").read_text())[
    "device"]["firmware_version"]
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
    linked = [e for e in od.entries if e.fw_config and e.type == "REAL32"]
    assert len(linked) >= 40
    for e in linked:
        assert e.min == lim[e.fw_config]["min"] and e.max == lim[e.fw_config]["max"]
        assert e.default == lim[e.fw_config]["default"]
    # the section lists every fw_config_t field (the C table is generated from it), and
    # every field is on the bus: a drive configured over CANopen alone can set (or, for
    # the board's ADC scaling and PWM frequency, read) all of its configuration
    on_bus = {e.fw_config: e for e in od.entries if e.fw_config}
    assert set(lim) - set(on_bus) == set()
    assert {k for k, e in on_bus.items() if e.access == "ro" and k in lim} >= {
        "f_pwm_Hz", "adc_A_per_count", "adc_offset_counts", "adc_V_per_count",
        "adc_max_count"}


@pytest.mark.parametrize("index,sub,field,scale", [
    (0x6080, 0, "v_max_mps", 1e6), (0x6065, 0, "follow_err_mps", 1e6),
    (0x6066, 0, "follow_err_time_s", 1e3), (0x607D, 1, "pos_limit_min_m", 1e6),
    (0x607D, 2, "pos_limit_max_m", 1e6)])
def test_cia402_views_in_wire_units(od, index, sub, field, scale):
    """0x6080/0x6065/0x6066/0x607D show fw_config fields in um/s, ms, um: the wire
    limits are exactly the integers the firmware's float32 conversion accepts."""
    e = od.find(index, sub)
    lim = od.fw_config[field]
    lo, hi = INT_RANGE[e.type]
    assert e.fw_config == field and e.scale == scale
    assert e.unit == {1e6: "um/s" if "mps" in field else "um", 1e3: "ms"}[scale]

    def fld(n: int) -> float:
        return _f32(_f32(float(n)) / _f32(scale))

    if e.min > lo:
        assert fld(e.min) >= _f32(lim["min"]) > fld(e.min - 1)
    else:
        assert lim["min"] * scale <= lo
    if e.max < hi:
        assert fld(e.max) <= _f32(lim["max"]) < fld(e.max + 1)
    else:
        assert lim["max"] * scale >= hi
    assert e.default == round(lim["default"] * scale)


def test_option_codes_are_cia402_int16(od):
    """0x605A / 0x605E: INTEGER16 views of signed (int32_t) fields; the quick stop
    defaults to the quick-stop ramp (2), the fault reaction to the manufacturer-specific
    time-bounded braking (-1: a lost supervisor sees the PWM off within its consumer
    time + fault_brake_time_s at any speed)."""
    from protocols.generated import od_names

    want = {0x605A: ("quick_stop_option", 2, (0, 2)),
            0x605E: ("fault_reaction_option", -1, (-1, 2))}
    for index, (field, default, limits) in want.items():
        e = od.find(index)
        assert (e.type, e.access, e.fw_config) == ("INTEGER16", "rw", field)
        assert e.default == od.fw_config[field]["default"] == default
        assert (e.min, e.max) == limits == (od.fw_config[field]["min"],
                                            od.fw_config[field]["max"])
        assert field in od_names.FW_CONFIG_SIGNED
    assert od_names.Reaction(-1).key == "brake_timed"


def _eds_int(text: str) -> int:
    return int(text.replace("$NODEID+", ""), 0)


def test_eds_limits_are_the_accepted_ranges(od):
    """Issue 34: the EDS's LowLimit/HighLimit say what the drive accepts. Read from the
    EDS text itself (not the loader): every entry that shows a fw_config field as it is
    (scale 1) declares exactly the field's range of od.yaml's fw_config section (the
    range the firmware's table is generated from, tests/c/test_co_od_config.c), the
    option codes among them; every signal id entry the ids of the signals list."""
    raw = yaml.safe_load(Path(generate.ROOT, "protocols", "od.yaml").read_text())
    eds = configparser.ConfigParser()
    eds.optionxform = str
    eds.read(EDS)

    def section(e):
        return f"{e.index:04X}" if e.kind == "var" else f"{e.index:04X}sub{e.sub:X}"

    checked = 0
    for e in od.entries:
        if not e.fw_config or e.scale != 1.0:
            continue
        lim = raw["fw_config"][e.fw_config]
        sec = eds[section(e)]
        if e.type == "REAL32":
            got = (float(sec["LowLimit"]), float(sec["HighLimit"]))
            assert got == (_f32(lim["min"]), _f32(lim["max"])), (section(e), got)
        else:
            got = (_eds_int(sec["LowLimit"]), _eds_int(sec["HighLimit"]))
            assert got == (lim["min"], lim["max"]), (section(e), got, lim)
        checked += 1
    assert checked >= 60
    for index in (0x605A, 0x605E):
        assert _eds_int(eds[f"{index:04X}"]["LowLimit"]) > INT_RANGE["INTEGER16"][0]
    ids = [s for s in eds.sections()
           if eds[s].get("ParameterName", "").startswith(("Signal ", "Trigger signal"))
           and eds[s].get("ParameterName") != "Signal count"]
    assert len(ids) == 17
    for s in ids:
        assert _eds_int(eds[s]["HighLimit"]) == len(raw["signals"]) - 1, s


def _c_fault_enum() -> dict[int, str]:
    """fw_fault_t parsed from the C header: code -> name without FW_FAULT_."""
    text = Path(generate.ROOT, "firmware_c", "include", "pmlsm", "fw_faults.h").read_text()
    body = re.search(r"typedef enum \{(.*?)\}\s*fw_fault_t;", text, re.S)
    assert body, "fw_fault_t not found in fw_faults.h"
    code = re.sub(r"/\*.*?\*/", "", body.group(1), flags=re.S)
    out: dict[int, str] = {}
    for m in re.finditer(r"FW_FAULT_(\w+)\s*=\s*(0[xX][0-9A-Fa-f]+|\d+)", code):
        out[int(m.group(2), 0)] = m.group(1)
    assert len(out) == code.count("FW_FAULT_"), "an enumerator without an explicit value"
    return out


def test_fault_list_matches_the_c_enum(od):
    c = _c_fault_enum()
    assert c.pop(0) == "NONE"
    y = {f.code: f.name for f in od.faults}
    assert len(y) >= 20
    assert c == y


def test_fault_enum_parser_sees_a_difference(od):
    """The comparison above can fail: a renamed enumerator is caught."""
    c = _c_fault_enum()
    assert c[0x8130] == "HEARTBEAT_LOST"
    y = {f.code: f.name for f in od.faults}
    assert y[0x8130] == "HEARTBEAT_LOST" and y[0x8400] == "OVERSPEED"
    assert {**y, 0x8130: "HB_LOST"} != {k: v for k, v in c.items() if k}


def test_generated_names_module(od):
    from protocols.generated import od_names

    assert od_names.FAULTS == {f.code: (f.name, f.text) for f in od.faults}
    assert od_names.fault_name(0x8130) == "HEARTBEAT_LOST"
    assert od_names.fault_name(0) == "NONE" and od_names.fault_name(0x1234) == "0x1234"
    assert od_names.FAULT_CODES["OVERSPEED"] == 0x8400
    assert od_names.INDEX_MAX_MOTOR_SPEED == 0x6080
    assert od_names.INDEX_SOFTWARE_POSITION_LIMIT == 0x607D
    assert od_names.ENTRIES[(0x1400, 5)] == "Event timer"
    md = Path(generate.ROOT, "docs", "od_table.md").read_text()
    for f in od.faults:
        assert f"| 0x{f.code:04X} | {f.name} |" in md


def test_drift_check_compares_numbers_as_numbers():
    """Generated files are compared with numbers as float32 values: another
    printing of the same number is not drift, another number is."""
    a = "{0x6080u, 1.0e-3f, 0.1, 3000000}"
    assert generate.same_content(a, "{0x6080u, 0.001f, 1e-1, 3000000}")
    assert generate.same_content(a, "{0x6080u, 0.0010000000474974513f, 0.100000001, 3000000}")
    assert not generate.same_content(a, "{0x6080u, 0.002f, 0.1, 3000000}")
    assert not generate.same_content(a, "{0x6080u, 1.0e-3f, 0.1, 3000001}")
    assert not generate.same_content(a, "{0x6081u, 1.0e-3f, 0.1, 3000000}")
    assert not generate.same_content(a, "{0x6080u, 1.0e-3f, 0.1, 3000000} ")


def test_drift_is_detected(tmp_path, monkeypatch):
    """drifted() reports a generated file whose numbers changed."""
    outs = generate.outputs()
    p = generate.ROOT / "firmware_c" / "comm" / "generated" / "co_od_table.c"
    changed = outs[p].replace("0.9580000042915344f", "0.9590000042915344f", 1)
    assert changed != outs[p]
    fake = tmp_path / "co_od_table.c"
    fake.write_text(changed)
    monkeypatch.setattr(generate, "outputs", lambda od=None: {fake: outs[p]})
    assert generate.drifted() == [fake]
    fake.write_text(outs[p].replace("0.9580000042915344f", "9.58e-1f", 1))
    assert generate.drifted() == []


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


def test_enums_are_one_list_for_c_and_python(od):
    """od.yaml's enums: generate the C enums of fw_enums.h and the IntEnums of od_names;
    the C header is parsed here independently of the generator, and the values the
    simulated drive and the bench rely on are checked literally."""
    from protocols.generated import od_names

    h = Path(generate.ROOT, "firmware_c", "include", "pmlsm", "fw_enums.h").read_text()
    c = {m.group(1): int(m.group(2)) for m in re.finditer(r"\b(FW_[A-Z0-9_]+) = (-?\d+)", h)}
    seen = 0
    for en in od.enums:
        cls = getattr(od_names, "".join(w.capitalize() for w in en.name.split("_")))
        assert f"}} {en.ctype};" in h
        for v in en.values:
            assert c[en.prefix + v.name] == v.value == int(cls[v.name]), (en.name, v.name)
            assert cls[v.name].key == v.key
            seen += 1
    assert seen == len(c) >= 13
    assert od_names.StartPhase.RUN == 3 and od_names.StartPhase.ALIGN == 1
    assert [e.key for e in od_names.Extractor] == ["pseudo", "sogi", "sogi_adaptive"]
    assert od_names.Mode.FORCE == 1 and od_names.Reaction.QUICK_RAMP == 2
    # the header is the one definition: the bottom layer (fw_types.h) includes it, and
    # neither it nor the core's header defines any of them
    pmlsm = Path(generate.ROOT, "firmware_c", "include", "pmlsm")
    assert '#include "fw_enums.h"' in (pmlsm / "fw_types.h").read_text()
    for name in ("fw_types.h", "fw_ctrl.h"):
        text = (pmlsm / name).read_text()
        assert not any(f"}} {en.ctype};" in text for en in od.enums), name


def _expect_od_error(tmp_path, old: str, new: str, match: str) -> None:
    """od.yaml with one edit (``old`` must be there) is refused with ``match``."""
    src = Path(generate.ROOT, "protocols", "od.yaml").read_text()
    assert old in src
    p = tmp_path / "od.yaml"
    p.write_text(src.replace(old, new, 1))
    with pytest.raises(OdError, match=match):
        load(p)


@pytest.mark.parametrize("old, new, match", [
    ("{name: RUN, value: 3, key: run,", "{name: RUN, value: 2, key: run,",
     r"enums\[2\]\.values\[3\]: name RUN or value 2 defined twice"),
    ("{name: RUN, value: 3, key: run,", "{name: RUN, value: 3, key: closed,",
     r"enums\[2\]\.values\[3\]: key 'closed' must be 'run'"),
    ("    ctype: fw_mode_t\n", "", r"enums\[1\]: missing 'ctype'"),
])
def test_bad_enum_is_reported_with_its_place(tmp_path, old, new, match):
    _expect_od_error(tmp_path, old, new, match)


@pytest.mark.parametrize("old, new, match", [
    ("fault_reaction_option: {group: protection, i32: true,",
     "fault_reaction_option: {group: protection, i32: true, u32: true,",
     r"fw_config fault_reaction_option: a fw_config field is u32 or i32, not both"),
    ("fault_reaction_option: {group: protection, i32: true,",
     "fault_reaction_option: {group: protection, u32: true,",
     r"fw_config fault_reaction_option: min -1 of a u32 field is negative \(use i32\)"),
    ("quick_stop_option:     {group: protection, i32: true, min: 0, max: 2,",
     "quick_stop_option:     {group: protection, i32: true, min: 0, max: 2.5,",
     r"fw_config quick_stop_option: a i32 field needs integer min, max and default"),
    ("max: signals.last_id, default: 11}", "max: signals.last, default: 11}",
     r"0x2060:6: max 'signals.last', expected a number or 'signals.last_id'"),
    ("access: ro, default: 0, live: true,", "access: const, default: 0, live: true,",
     r"live needs access ro or rw, not const"),
])
def test_bad_field_kind_limit_or_live_is_a_one_line_error(tmp_path, old, new, match):
    _expect_od_error(tmp_path, old, new, match)


def test_hooked_objects_are_od_yaml_keys(od):
    """The objects the drive application acts on when written are od.yaml `hook:` keys:
    the generated dispatch (fw_app_hooks.c) names each handler, and each handler is
    defined in the application's sources; the storage commands run outside the lock."""
    hooked = {(e.index, e.sub): (e.hook, e.hook_unlocked) for e in od.entries if e.hook}
    assert set(hooked) == {(0x1010, 1), (0x1011, 1), (0x2000, 0), (0x2002, 0), (0x2070, 1),
                           (0x2080, 1), (0x6040, 0)}
    assert {k for k, (_, unlocked) in hooked.items() if unlocked} == {(0x1010, 1), (0x1011, 1)}
    comm = Path(generate.ROOT, "firmware_c", "comm")
    table = (comm / "generated" / "fw_app_hooks.c").read_text()
    src = "".join(p.read_text() for p in (comm / "src").glob("*.c"))
    for (index, sub), (name, unlocked) in hooked.items():
        assert f"{{0x{index:04X}u, {sub}u, {0 if unlocked else 1}u, {name}}}" in table
        assert re.search(rf"^co_abort_t {name}\(fw_app_t \*app, uint32_t \w+\) {{", src,
                         re.M), name


@pytest.mark.parametrize("old, new, match", [
    ("    hook: fw_app_hook_controlword\n", "    hook: fw-app-hook\n",
     r"0x6040:0: hook 'fw-app-hook' is not a C identifier"),
    ("      - {sub: 2, name: State, type: UNSIGNED8, access: ro, default: 0, live: true,",
     "      - {sub: 2, name: State, type: UNSIGNED8, access: ro, default: 0, live: true, hook: h,",
     r"0x2070:2: hook needs a writable entry, not access ro"),
    ("    hook: fw_app_hook_controlword\n", "    hook_unlocked: true\n",
     r"0x6040:0: hook_unlocked without a hook"),
])
def test_bad_hook_is_a_one_line_error(tmp_path, old, new, match):
    _expect_od_error(tmp_path, old, new, match)


def test_live_entries(od):
    """Live entries (the drive's own values: measurements, states, capabilities, the
    port's and the build's identity) are marked in od.yaml or are read-only and PDO
    mappable; configuration never is."""
    live = {(e.index, e.sub) for e in od.entries if e.live}
    assert {(0x6041, 0), (0x6064, 0), (0x2020, 1), (0x2090, 1), (0x2090, 2), (0x2041, 0),
            (0x2030, 1), (0x2080, 2), (0x1010, 1)} <= live
    assert not any(e.fw_config for e in od.entries if e.live)
    assert {(0x1000, 0), (0x2040, 0), (0x1018, 2), (0x2050, 1), (0x6060, 0)}.isdisjoint(live)


def test_firmware_version_is_written_once(od):
    """device.firmware_version is the one place: 0x100A (text), 0x2040 and 0x1018:3
    (packed 0x00MMmmpp), the EDS and the C header all come from it."""
    v = od.device["firmware_version"]
    major, minor, patch = (int(x) for x in v.split("."))
    packed = (major << 16) | (minor << 8) | patch
    assert od.find(0x100A).default == v
    assert od.find(0x2040).default == packed == od.find(0x1018, 3).default
    assert od.find(0x1018, 2).default == od.device["product_number"]
    h = Path(generate.ROOT, "firmware_c", "include", "pmlsm", "fw_version.h").read_text()
    got = {k: int(n) for k, n in re.findall(r"#define FW_VERSION_(MAJOR|MINOR|PATCH) (\d+)", h)}
    assert got == {"MAJOR": major, "MINOR": minor, "PATCH": patch}
    eds = configparser.ConfigParser()
    eds.read(Path(generate.ROOT, "protocols", "generated", "pmlsm_drive.eds"))
    assert int(eds["DeviceInfo"]["RevisionNumber"], 0) == packed


@pytest.mark.parametrize("old, new, match", [
    (f"  firmware_version: {_FW_VERSION}\n", "  firmware_version: 0.2\n",
     r"device.firmware_version: '0.2', expected MAJOR.MINOR.PATCH"),
    (f"  firmware_version: {_FW_VERSION}\n",
     f"  firmware_version: {_FW_VERSION}\n  revision_number: 0x200\n",
     r"device.revision_number: derived from device.firmware_version"),
    ("    default: device.firmware_version\n", "    default: device.firmware\n",
     r"0x100A: default 'device.firmware', the device section has no 'firmware'"),
])
def test_bad_device_section_is_a_one_line_error(tmp_path, old, new, match):
    _expect_od_error(tmp_path, old, new, match)


def test_defaults_derived_from_the_paper_motor(od):
    """od.yaml's defaults are the firmware's (fw_config_default applies them): the ones
    derived from the paper's motor are recomputed here from their formulas in float32,
    in the operation order the firmware used when it computed them, and must be the
    same float32 value (those rounded for readability: within their last digit)."""
    import numpy as np
    f = np.float32
    d = {k: v["default"] for k, v in od.fw_config.items()}
    two_pi_p = f(2 * np.pi) * f(d["pole_pairs"])
    exact = {
        "cur_kp_V_per_A": f(d["L_d_H"]) * f(1100.0),          # paper: L_d x 1100 rad/s
        "cur_ki_V_per_As": f(d["R_ohm"]) * f(1100.0),         # R x 1100 rad/s
        "spd_kp_A_per_radps": f(0.1) * f(60.0) / two_pi_p,    # 0.1 A/(r/min)
        "spd_ki_A_per_rad": f(0.6) * f(60.0) / two_pi_p,      # 0.6 A/(r/min s)
        # p K_t / J, K_t = 1.5 p psi_f, J = 0.03 kg m^2
        "pll_accel_per_A": f(d["pole_pairs"]) * f(1.5) * f(d["pole_pairs"])
        * f(d["psi_f_Wb"]) / f(0.03),
        "adc_A_per_count": f(50.0) / f(4096.0),               # +/-25 A over 12 bits
        "adc_V_per_count": f(500.0) / f(4096.0),              # 0..500 V over 12 bits
        "L_q_H": f(1.5) * f(d["L_d_H"]),                      # the salient variant
        "f_pwm_Hz": f(8) * f(d["f_inj_Hz"]),                  # 8 samples per period
    }
    for name, want in exact.items():
        assert f(d[name]) == want, f"od.yaml fw_config.{name} default {d[name]!r}, " \
            f"formula {float(want)!r}"
    # the paper's rotary machine as a linear one: r = p tau / pi
    r = d["pole_pairs"] * d["pole_pitch_m"] / np.pi
    rounded = {"mass_kg": 0.03 / r**2, "visc_Ns_per_m": 0.008 / r**2, "coulomb_N": 1.5 / r}
    for name, want in rounded.items():
        assert abs(d[name] - want) <= 5e-3 * want, (name, d[name], want)
    # the observer's disturbance gain: poles -28 +/- 50j and -30 rad/s with the paper's
    # kp, ki (s^3 + kp s^2 + ki s + kd)
    poles = np.sort_complex(np.roots([1.0, d["pll_kp"], d["pll_ki"], d["pll_kd"]]))
    assert np.allclose(poles, [-30.4, -28.1 - 50.0j, -28.1 + 50.0j], atol=0.5), poles
    # the enum defaults by name: the adaptive SOGI, quick-stop ramps
    names = {e.name: {v.value: v.key for v in e.values} for e in od.enums}
    assert names["extractor"][d["extractor"]] == "sogi_adaptive"
    assert names["reaction"][d["quick_stop_option"]] == "quick_ramp"
    assert names["reaction"][d["fault_reaction_option"]] == "brake_timed"


def test_sdo_abort_codes_have_one_source_and_are_cia301s() -> None:
    """od.yaml's sdo_aborts: is the one list: the C enum co_abort_t is generated from it,
    the bench explains an abort with its texts, and every code is one CiA 301 defines
    (the canopen library's table, an independent reference)."""
    import re

    from canopen.sdo.exceptions import SdoAbortedError

    from bench._drive import SDO_ABORTS
    from protocols import load_od
    from protocols.generated import od_names

    od = load_od()
    codes = {a.code: a for a in od.sdo_aborts}
    assert set(od_names.SDO_ABORTS) == set(codes) == set(SDO_ABORTS)
    assert all(SDO_ABORTS[c] == a.text for c, a in codes.items())
    assert all(c in SdoAbortedError.CODES for c in codes)
    REPO = Path(__file__).resolve().parents[2]
    header = (REPO / "firmware_c" / "comm" / "generated" / "co_aborts.h").read_text()
    enum = {int(v, 16): n for n, v in re.findall(r"CO_ABORT_(\w+) = (0x[0-9A-F]+)u", header)}
    assert enum.pop(0) == "NONE"
    assert enum == {c: a.name for c, a in codes.items()}
    # and no abort code is written as a number in the firmware's sources
    for src in (REPO / "firmware_c" / "comm" / "src").glob("*.c"):
        code = re.sub(r"/\*.*?\*/", "", src.read_text(), flags=re.S)
        assert not re.search(r"0x0[568]0[0-9A-Fa-f]{5}", code), src.name
