"""The whole EDS against the drive (issue 34): the python ``canopen`` library is the
master, the C drive application (fw_app: core + CANopen slave, the code of every
board) is the node on python-can's ``virtual`` bus (sim_fallback.DriveBridge,
paced to real time). For every object of protocols/generated/pmlsm_drive.eds:

- a readable entry uploads, and its size is its EDS data type's (CiA 301);
- a read-only or constant entry refuses a download with 0x06010002;
- after boot its value is the EDS DefaultValue, unless od.yaml marks the value as the
  drive's own (``live``: measurements, states, capabilities, identities;
  protocols._od.OdEntry.live), which has no default to compare with;
- a writable entry with limits takes its LowLimit and HighLimit (drive disabled;
  the old value is restored after) and refuses LowLimit - 1 and HighLimit + 1 (the
  next float32 for REAL32), where the type can hold them, with 0x06090030/31/32.

The limits are read from the EDS text (canopen parses no REAL32 limits). A limit of a
configuration field may be refused because another field forbids it at present (the
drive checks some fields together: u_dc_min_V < u_dc_max_V, f_pwm / f_inj an even
integer, ...), which an EDS cannot express: such a refusal (0x06090030) passes only
when the drive's own configuration check, run on the drive's present configuration
(read over SDO) with that one field at the limit, calls it an inconsistency between
fields (FW_ERR_INCONSISTENT), not a range error. The PDO mapping counts (0x1600+n:0,
0x1A00+n:0) are written as CiA 301 says: the PDO invalid, the count 0, the entries,
the count (eight 8-bit PDO-mappable objects of the EDS for the HighLimit).

Two drives: one on the factory configuration (fw_config_default, the EDS defaults) with
the null plant, and the simulated drive in closed loop with its motor, configured as the
simulator's; the configuration entries' defaults are compared on the first only (the
second's are its motor's).
"""

from __future__ import annotations

import configparser
import ctypes as C
import math
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import canopen
import numpy as np
import pytest
from canopen.objectdictionary import ODArray, ODRecord, ODVariable
from canopen.sdo.exceptions import SdoAbortedError
from sim_libs import drive_on_bus

from protocols._od import load
from sim_fallback import DriveBridge
from sim_fallback._lib import FwConfigField, FwConfigIssue

ROOT = Path(__file__).resolve().parents[2]
EDS = ROOT / "protocols" / "generated" / "pmlsm_drive.eds"
NID = 5
READ_ONLY = 0x06010002
RANGE_ABORTS = {0x06090030, 0x06090031, 0x06090032}
FW_ERR_INCONSISTENT = 5  # fw_status_t
#: CiA 301 basic data types: code -> (size in bytes, struct format, range or None)
TYPES: dict[int, tuple[int, str, tuple[int, int] | None]] = {
    0x0001: (1, "<B", (0, 1)), 0x0002: (1, "<b", (-(2**7), 2**7 - 1)),
    0x0003: (2, "<h", (-(2**15), 2**15 - 1)), 0x0004: (4, "<i", (-(2**31), 2**31 - 1)),
    0x0005: (1, "<B", (0, 2**8 - 1)), 0x0006: (2, "<H", (0, 2**16 - 1)),
    0x0007: (4, "<I", (0, 2**32 - 1)), 0x0008: (4, "<f", None)}
VSTRING = 0x0009


@pytest.fixture(params=["none", "sim"], ids=["factory", "simulated_motor"])
def drive(request: pytest.FixtureRequest) -> Iterator[tuple[canopen.RemoteNode, DriveBridge]]:
    """The drive on the factory configuration (null plant), and the simulated drive in
    closed loop with its motor (paper_salient, configured as the simulator's)."""
    kw = {"motor": "paper_salient", "seed": 3} if request.param == "sim" else None
    with drive_on_bus(NID, request.param, kw) as (_, node, bridge):
        yield node, bridge


def _variables(cod: canopen.ObjectDictionary) -> list[ODVariable]:
    out: list[ODVariable] = []
    for obj in cod.values():
        out.extend([obj] if isinstance(obj, ODVariable) else obj.values())
    return out


def _section(var: ODVariable) -> str:
    """The variable's EDS section: [IIII] for a VAR, [IIIIsubS] for a sub-index."""
    if isinstance(var.parent, (ODRecord, ODArray)):
        return f"{var.index:04X}sub{var.subindex:X}"
    return f"{var.index:04X}"


@pytest.fixture(scope="module")
def eds() -> configparser.ConfigParser:
    p = configparser.ConfigParser()
    p.optionxform = str
    p.read(EDS)
    return p


def _limit(eds: configparser.ConfigParser, var: ODVariable, key: str) -> int | float | None:
    """LowLimit/HighLimit as the EDS writes it (hex or decimal; REAL32 as a float)."""
    sec = eds[_section(var)]
    if key not in sec:
        return None
    text = sec[key]
    return float(text) if var.data_type == 0x0008 else int(text, 0)


def _encode(var: ODVariable, value: int | float) -> bytes:
    return struct.pack(TYPES[var.data_type][1], value)


def _beyond(var: ODVariable, value: int | float, up: bool) -> int | float | None:
    """The next value past a limit in the entry's type; None when the type has none."""
    if var.data_type == 0x0008:
        nxt = np.nextafter(np.float32(value), np.float32(np.inf if up else -np.inf))
        return float(nxt) if np.isfinite(nxt) else None
    lo, hi = TYPES[var.data_type][2]
    v = int(value) + (1 if up else -1)
    return v if lo <= v <= hi else None


def _write(node: canopen.RemoteNode, index: int, sub: int, data: bytes) -> int:
    """SDO download: 0 when accepted, else the abort code."""
    try:
        node.sdo.download(index, sub, data)
    except SdoAbortedError as e:
        return int(e.code)
    return 0


class ConfigProbe:
    """The drive's own configuration check (fw_config_derive + fw_config_check, as
    fw_set_config runs them) on the drive's present configuration with one field
    changed: why a limit of a configuration field was refused."""

    def __init__(self, bridge: DriveBridge) -> None:
        L = C.CDLL(bridge._L._name)  # a handle of its own: its own argument types
        L.fw_config_default.argtypes = [C.c_void_p]
        L.fw_config_derive.argtypes = [C.c_void_p]
        L.fw_config_check.argtypes = [C.c_void_p, C.POINTER(FwConfigIssue)]
        L.fw_config_check.restype = C.c_int
        L.fw_config_field_find.argtypes = [C.c_char_p]
        L.fw_config_field_find.restype = C.POINTER(FwConfigField)
        self._L = L
        self._od = load()

    def _put(self, buf: Any, field: str, value: float) -> None:
        f = self._L.fw_config_field_find(field.encode()).contents
        if f.is_int:  # a 32-bit integer field (uint32_t or int32_t): its 32 bits
            C.c_uint32.from_buffer(buf, f.offset).value = int(value) & 0xFFFFFFFF
        else:
            C.c_float.from_buffer(buf, f.offset).value = float(value)

    def status(self, node: canopen.RemoteNode, field: str, value: float) -> tuple[int, str]:
        """fw_status_t and the field named, for the drive's configuration (every field
        read over SDO from the entries that show it as it is) with ``field`` = value."""
        buf = C.create_string_buffer(4096)
        self._L.fw_config_default(buf)
        for e in self._od.entries:
            if e.fw_config and e.scale == 1.0:
                self._put(buf, e.fw_config, node.sdo[e.index][e.sub].raw if e.kind != "var"
                          else node.sdo[e.index].raw)
        self._put(buf, field, value)
        self._L.fw_config_derive(buf)
        issue = FwConfigIssue()
        st = int(self._L.fw_config_check(buf, C.byref(issue)))
        return st, (issue.field or b"").decode()


def _pdo_map_entry(cod: canopen.ObjectDictionary, rx: bool) -> int:
    """0xIIIISS08 of an 8-bit PDO-mappable entry of the EDS that this PDO direction
    may map (writable for an RPDO, readable for a TPDO)."""
    for var in _variables(cod):
        if var.pdo_mappable and TYPES.get(var.data_type, (0,))[0] == 1 and (
                var.writable if rx else var.readable):
            return (var.index << 16) | (var.subindex << 8) | 8
    raise AssertionError("no 8-bit PDO-mappable entry in the EDS")


def _check_pdo_count(node: canopen.RemoteNode, cod: canopen.ObjectDictionary, var: ODVariable,
                     lo: int, hi: int) -> list[str]:
    """0x1600+n:0 / 0x1A00+n:0 the CiA 301 way; the mapping and COB-ID restored."""
    bad: list[str] = []
    sdo = node.sdo
    comm = var.index - 0x200  # 0x1400+n / 0x1800+n
    rx = var.index < 0x1800
    cob = sdo[comm][1].raw
    old = [sdo[var.index][k].raw for k in range(0, 9)]
    sdo[comm][1].raw = cob | 0x80000000  # the PDO invalid first
    try:
        for v in (lo, hi):
            sdo[var.index][0].raw = 0
            if v > 0:
                m = _pdo_map_entry(cod, rx)
                for k in range(1, v + 1):
                    sdo[var.index][k].raw = m
            a = _write(node, var.index, 0, _encode(var, v))
            if a or sdo[var.index][0].raw != v:
                bad.append(f"0x{var.index:04X}:0 limit {v} refused (0x{a:08X})")
        for v in (_beyond(var, lo, False), _beyond(var, hi, True)):
            if v is not None:
                a = _write(node, var.index, 0, _encode(var, v))
                if a not in RANGE_ABORTS:
                    bad.append(f"0x{var.index:04X}:0 {v} beyond a limit: abort 0x{a:08X}")
    finally:
        sdo[var.index][0].raw = 0
        for k in range(1, 9):
            sdo[var.index][k].raw = old[k]
        sdo[var.index][0].raw = old[0]
        sdo[comm][1].raw = cob
    return bad


def test_every_object_of_the_eds(drive, eds):
    node, bridge = drive
    cod = node.object_dictionary
    od = {(e.index, e.sub): e for e in load().entries}
    variables = _variables(cod)
    assert len(variables) == len(od)  # the EDS is od.yaml's, entry for entry
    assert bridge.error is None
    sw = node.sdo[0x6041].raw
    assert sw & 0x4F == 0x40, hex(sw)  # SWITCH ON DISABLED: the drive is disabled
    probe = ConfigProbe(bridge)
    bad: list[str] = []
    n_read = n_default = n_ro = n_limits = 0
    cross_field: list[str] = []
    # reads, sizes and defaults first: nothing written yet
    for var in variables:
        where = f"0x{var.index:04X}:{var.subindex} {var.name}"
        e = od[(var.index, var.subindex)]
        if not var.readable:
            continue
        data = node.sdo.upload(var.index, var.subindex)
        n_read += 1
        if var.data_type == VSTRING:
            value: Any = data.decode("ascii")
        else:
            size = TYPES[var.data_type][0]
            if len(data) != size:
                bad.append(f"{where}: {len(data)} bytes uploaded, its type has {size}")
                continue
            value = struct.unpack(TYPES[var.data_type][1], data)[0]
        # the simulated drive's configuration is its motor's, not the factory one
        factory = bridge.sim is None or not e.fw_config
        if var.default is not None and not e.live and factory:
            n_default += 1
            want = var.default
            if value != want:
                bad.append(f"{where}: {value!r} after boot, EDS DefaultValue {want!r}")
    # read-only entries, then the limits of the writable ones
    for var in variables:
        where = f"0x{var.index:04X}:{var.subindex} {var.name}"
        e = od[(var.index, var.subindex)]
        if var.access_type in ("ro", "const"):
            data = node.sdo.upload(var.index, var.subindex)
            a = _write(node, var.index, var.subindex, data)
            n_ro += 1
            if a != READ_ONLY:
                bad.append(f"{where}: a write to a {var.access_type} entry gave 0x{a:08X}")
            continue
        if not var.writable or var.data_type == VSTRING:
            continue
        lo, hi = _limit(eds, var, "LowLimit"), _limit(eds, var, "HighLimit")
        if lo is None and hi is None:
            continue
        n_limits += 1
        if var.subindex == 0 and (0x1600 <= var.index < 0x1800 or 0x1A00 <= var.index < 0x1C00):
            bad += _check_pdo_count(node, cod, var, lo, hi)
            continue
        old = node.sdo.upload(var.index, var.subindex)
        try:
            for v in (x for x in (lo, hi) if x is not None):
                a = _write(node, var.index, var.subindex, _encode(var, v))
                if a == 0x06090030 and e.fw_config:
                    st, field = probe.status(node, e.fw_config, v / e.scale)
                    if st == FW_ERR_INCONSISTENT:
                        cross_field.append(f"{where} = {v} (with {field})")
                        continue
                if a:
                    bad.append(f"{where}: its limit {v} refused with 0x{a:08X}")
                elif not e.command:  # a command's read value is the drive's (0x2080:1)
                    got = struct.unpack(TYPES[var.data_type][1],
                                        node.sdo.upload(var.index, var.subindex))[0]
                    if got != v and not (var.data_type == 0x0008 and
                                         np.float32(got) == np.float32(v)):
                        bad.append(f"{where}: {v} written, {got} read back")
            for v in (_beyond(var, lo, False) if lo is not None else None,
                      _beyond(var, hi, True) if hi is not None else None):
                if v is None:
                    continue
                a = _write(node, var.index, var.subindex, _encode(var, v))
                if a not in RANGE_ABORTS:
                    bad.append(f"{where}: {v}, beyond its limits, gave abort 0x{a:08X}")
        finally:
            node.sdo.download(var.index, var.subindex, old)
        if node.sdo.upload(var.index, var.subindex) != old and not e.command:
            bad.append(f"{where}: not restored")
    print(f"{len(variables)} entries: {n_read} read, {n_default} defaults compared, {n_ro} "
          f"read-only, {n_limits} with limits; limits refused for another field: "
          + ("; ".join(cross_field) or "none"))
    assert bad == [], "\n".join(bad)
    assert n_read == len(variables) and n_ro > 50 and n_limits > 80
    assert n_default > (200 if bridge.sim is None else 150)
    # the cross-field refusals are few and all of configuration fields
    assert len(cross_field) <= 16, cross_field
    assert math.isfinite(bridge.f_pwm_Hz) and bridge.error is None
