"""Load and expand protocols/od.yaml, the drive's object dictionary.

The YAML is the single source of truth; this module turns it into a flat,
sorted list of :class:`OdEntry` (one per index/sub-index) that the
generators (C table, EDS, Markdown) and the tests share.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

OD_YAML = Path(__file__).with_name("od.yaml")

#: CiA 301 basic data types used here: name -> (code, size in bytes, C tag).
TYPES: dict[str, tuple[int, int, str]] = {
    "BOOLEAN": (0x0001, 1, "CO_TYPE_BOOLEAN"),
    "INTEGER8": (0x0002, 1, "CO_TYPE_I8"),
    "INTEGER16": (0x0003, 2, "CO_TYPE_I16"),
    "INTEGER32": (0x0004, 4, "CO_TYPE_I32"),
    "UNSIGNED8": (0x0005, 1, "CO_TYPE_U8"),
    "UNSIGNED16": (0x0006, 2, "CO_TYPE_U16"),
    "UNSIGNED32": (0x0007, 4, "CO_TYPE_U32"),
    "REAL32": (0x0008, 4, "CO_TYPE_REAL32"),
    "VISIBLE_STRING": (0x0009, 0, "CO_TYPE_VSTRING"),
}
ACCESS = ("ro", "rw", "wo", "const")
INT_RANGE = {
    "BOOLEAN": (0, 1),
    "INTEGER8": (-(2**7), 2**7 - 1),
    "INTEGER16": (-(2**15), 2**15 - 1),
    "INTEGER32": (-(2**31), 2**31 - 1),
    "UNSIGNED8": (0, 2**8 - 1),
    "UNSIGNED16": (0, 2**16 - 1),
    "UNSIGNED32": (0, 2**32 - 1),
}

NODEID_RE = re.compile(r"^\$NODEID\+(0x[0-9A-Fa-f]+|\d+)$")
C_IDENT_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")

#: ``min:`` / ``max:`` of an entry that holds a signal id (telemetry, trace): the
#: highest id of the ``signals:`` list, so the limit follows the list
SIGNAL_ID_MAX = "signals.last_id"

#: C storage of a fw_config field: od.yaml ``u32: true`` (uint32_t), ``i32: true``
#: (int32_t, e.g. option codes with manufacturer-specific negative values), else float
FW_CONFIG_KINDS = ("f32", "u32", "i32")


def fw_config_kind(field: dict[str, Any]) -> str:
    """``f32``, ``u32`` or ``i32``: how a ``fw_config:`` field is stored."""
    if field.get("u32") and field.get("i32"):
        raise OdError("a fw_config field is u32 or i32, not both")
    return "u32" if field.get("u32") else "i32" if field.get("i32") else "f32"


class OdError(ValueError):
    """od.yaml is malformed; the message names the object and field."""


@dataclass(frozen=True)
class OdEntry:
    """One object dictionary entry (a VAR, or one sub-index of a RECORD/ARRAY).

    Attributes
    ----------
    index, sub : int
        Object index and sub-index.
    name : str
        Parameter name (the object's name for VARs, the sub's name otherwise).
    object_name : str
        Name of the enclosing object (equal to ``name`` for VARs).
    kind : str
        ``var``, ``record`` or ``array`` (of the enclosing object).
    type : str
        CiA 301 type name, see :data:`TYPES`.
    access : str
        ``ro``, ``rw``, ``wo`` or ``const``.
    unit : str
        Physical unit on the wire ("" when dimensionless).
    min, max : int | float | None
        Inclusive limits (None: the type's range).
    default : int | float | str
        Default value; for COB-IDs with ``nodeid_relative`` the node id is added.
    nodeid_relative : bool
        Default is ``$NODEID+default``.
    pdo : bool
        PDO mappable.
    command : bool
        Writing it is an action or a set-point (controlword, targets, store
        commands), not configuration: not stored by 0x1010, not backed up.
    size : int
        Size in bytes (maximum length for strings).
    fw_config : str | None
        fw_config_t field this entry mirrors.
    scale : float
        Wire value = field value x scale (integer objects that show a
        fw_config_t field in wire units, e.g. 1e6 for m/s -> um/s); 1 otherwise.
    doc : str
        Description.
    live : bool
        The value is the drive's own, not configuration: a measurement, a state,
        a capability or an identity the port or the build sets (od.yaml ``live:
        true``; every read-only PDO-mappable entry is live). Its default is only
        the value before the drive writes it.
    hook : str | None
        C handler the drive application calls when the entry is written
        (od.yaml ``hook:``; the generated dispatch, fw_app_hooks.c).
    hook_unlocked : bool
        The handler runs outside the lock of the background's core changes
        (od.yaml ``hook_unlocked: true``: a flash write must not hold the
        control interrupt off).
    """

    index: int
    sub: int
    name: str
    object_name: str
    kind: str
    type: str
    access: str
    unit: str = ""
    min: int | float | None = None
    max: int | float | None = None
    default: int | float | str = 0
    nodeid_relative: bool = False
    pdo: bool = False
    command: bool = False
    size: int = 0
    fw_config: str | None = None
    scale: float = 1.0
    doc: str = ""
    live: bool = False
    hook: str | None = None
    hook_unlocked: bool = False

    @property
    def type_code(self) -> int:
        return TYPES[self.type][0]

    @property
    def is_int(self) -> bool:
        return self.type in INT_RANGE

    @property
    def c_ident(self) -> str:
        """Identifier used in the generated C header (CO_OD_6040_00)."""
        return f"CO_OD_{self.index:04X}_{self.sub:02X}"


@dataclass(frozen=True)
class Fault:
    """One fault code (``faults:`` section): EMCY error code, 0x603F, fw_fault_t."""

    code: int
    name: str
    text: str
    reaction: str


@dataclass(frozen=True)
class SdoAbort:
    """One SDO abort code (``sdo_aborts:`` section): CO_ABORT_<name> in C, its text."""

    code: int
    name: str
    text: str


@dataclass(frozen=True)
class EnumValue:
    """One value of an enumeration (``enums:`` section)."""

    name: str   # C enumerator suffix and Python member name (SOGI_ADAPTIVE)
    value: int
    key: str    # the lower-case name the bench and motor files use (sogi_adaptive)
    text: str


@dataclass(frozen=True)
class Enum:
    """An enumeration whose values cross the wire (``enums:`` section): a C enum of
    fw_enums.h and an IntEnum of od_names.py."""

    name: str    # extractor
    ctype: str   # fw_extractor_t
    prefix: str  # FW_EXTRACTOR_
    doc: str
    values: tuple[EnumValue, ...]


@dataclass
class ObjectDictionary:
    """The expanded dictionary: device info, entries sorted by (index, sub), signals,
    fault codes."""

    device: dict[str, Any]
    entries: list[OdEntry]
    signals: list[dict[str, str]]
    fw_config: dict[str, dict[str, float]] = field(default_factory=dict)
    faults: list[Fault] = field(default_factory=list)
    enums: list[Enum] = field(default_factory=list)
    #: fw_config_t's parts in struct order: part name -> doc (od.yaml fw_config_parts)
    fw_config_parts: dict[str, str] = field(default_factory=dict)
    sdo_aborts: list[SdoAbort] = field(default_factory=list)

    def objects(self) -> dict[int, list[OdEntry]]:
        """Entries grouped by index, in order."""
        out: dict[int, list[OdEntry]] = {}
        for e in self.entries:
            out.setdefault(e.index, []).append(e)
        return out

    def find(self, index: int, sub: int = 0) -> OdEntry:
        for e in self.entries:
            if e.index == index and e.sub == sub:
                return e
        raise KeyError(f"0x{index:04X}:{sub}")


def _parse_default(where: str, typ: str, raw: Any) -> tuple[int | float | str, bool]:
    if typ == "VISIBLE_STRING":
        return ("" if raw is None else str(raw)), False
    if raw is None:
        return (0.0 if typ == "REAL32" else 0), False
    if isinstance(raw, str):
        m = NODEID_RE.match(raw.strip())
        if not m:
            raise OdError(f"{where}: default {raw!r} is not a number or $NODEID+n")
        return int(m.group(1), 0), True
    if typ == "REAL32":
        return float(raw), False
    if isinstance(raw, float):
        raise OdError(f"{where}: integer type {typ} has float default {raw}")
    return int(raw), False


def _entry(obj: dict[str, Any], sub: dict[str, Any], kind: str,
           fw_limits: dict[str, dict[str, float]], signal_id_max: int) -> OdEntry:
    index = int(obj["index"])
    sub_i = int(sub.get("sub", 0))
    where = f"od.yaml 0x{index:04X}:{sub_i}"
    for key in ("min", "max"):
        v = sub.get(key)
        if isinstance(v, str):
            if v != SIGNAL_ID_MAX:
                raise OdError(f"{where}: {key} {v!r}, expected a number or {SIGNAL_ID_MAX!r}")
            sub = {**sub, key: signal_id_max}
    typ = sub.get("type")
    if typ not in TYPES:
        raise OdError(f"{where}: unknown type {typ!r}")
    access = sub.get("access", "ro")
    if access not in ACCESS:
        raise OdError(f"{where}: access {access!r} not in {ACCESS}")
    fwc = sub.get("fw_config")
    scale = float(sub.get("scale", 1.0))
    mn, mx, dflt = sub.get("min"), sub.get("max"), sub.get("default")
    if scale != 1.0 and (fwc is None or typ not in INT_RANGE):
        raise OdError(f"{where}: scale needs fw_config and an integer type")
    if fwc is not None:
        if fwc not in fw_limits:
            raise OdError(f"{where}: fw_config field {fwc!r} has no entry in the fw_config section")
        lim = fw_limits[fwc]
        if typ in INT_RANGE:
            lo, hi = INT_RANGE[typ]
            # the wire range holds exactly the integers whose field value is allowed
            mn = max(lo, scaled_bound(lim["min"], scale, up=True)) if mn is None else mn
            mx = min(hi, scaled_bound(lim["max"], scale, up=False)) if mx is None else mx
            dflt = round(float(lim["default"]) * scale) if dflt is None else dflt
        else:
            mn = lim["min"] if mn is None else mn
            mx = lim["max"] if mx is None else mx
            dflt = lim["default"] if dflt is None else dflt
        if not sub.get("unit") and lim.get("unit") and scale == 1.0:
            sub = {**sub, "unit": lim["unit"]}
    default, rel = _parse_default(where, typ, dflt)
    if typ in INT_RANGE:
        lo, hi = INT_RANGE[typ]
        for label, v in (("min", mn), ("max", mx)):
            if v is not None and not (isinstance(v, int) and lo <= v <= hi):
                raise OdError(f"{where}: {label} {v!r} outside {typ} range")
        if not rel:
            lo2 = lo if mn is None else mn
            hi2 = hi if mx is None else mx
            if not lo2 <= int(default) <= hi2:
                raise OdError(f"{where}: default {default} outside [{lo2}, {hi2}]")
    elif typ == "REAL32":
        mn = None if mn is None else float(mn)
        mx = None if mx is None else float(mx)
        if mn is not None and mx is not None and not mn <= float(default) <= mx:
            raise OdError(f"{where}: default {default} outside [{mn}, {mx}]")
    size = TYPES[typ][1]
    if typ == "VISIBLE_STRING":
        size = int(sub.get("size", 0)) or 0
    name = str(sub.get("name", obj["name"]))
    pdo = bool(sub.get("pdo", False))
    live = bool(sub.get("live", False))
    if live and access not in ("ro", "rw"):
        raise OdError(f"{where}: live needs access ro or rw, not {access}")
    if live and fwc is not None:
        raise OdError(f"{where}: live and fw_config exclude each other (configuration is "
                      "not live)")
    hook = sub.get("hook")
    if hook is not None and (not isinstance(hook, str) or not C_IDENT_RE.fullmatch(hook)):
        raise OdError(f"{where}: hook {hook!r} is not a C identifier")
    if hook is not None and access not in ("rw", "wo"):
        raise OdError(f"{where}: hook needs a writable entry, not access {access}")
    hook_unlocked = bool(sub.get("hook_unlocked", False))
    if hook_unlocked and hook is None:
        raise OdError(f"{where}: hook_unlocked without a hook")
    return OdEntry(
        index=index, sub=sub_i, name=name, object_name=str(obj["name"]), kind=kind,
        type=typ, access=access, unit=str(sub.get("unit", "") or ""), min=mn, max=mx,
        default=default, nodeid_relative=rel, pdo=pdo,
        command=bool(sub.get("command", False)), size=size, fw_config=fwc, scale=scale,
        doc=str(sub.get("doc", "") or ""), live=live or (access == "ro" and pdo),
        hook=hook, hook_unlocked=hook_unlocked,
    )


def scaled_bound(v: float, scale: float, up: bool) -> int:
    """Smallest (up) / largest integer n with n / scale inside the float32 limit v.

    The firmware converts with a float32 division, so the bound is checked in
    float32 too (1000 um/s / 1e6 must not fall below a 1e-3 m/s minimum).
    """
    import struct

    def f32(x: float) -> float:
        return struct.unpack("<f", struct.pack("<f", x))[0]

    def inside(n: int) -> bool:
        val = f32(f32(float(n)) / f32(scale))
        return val >= lim if up else val <= lim

    lim = f32(float(v))
    step = 1 if up else -1
    n = round(lim * scale)
    while not inside(n):  # float32 rounding moves the boundary by an integer or so
        n += step
    while inside(n - step):
        n -= step
    return int(n)


def _pdo_objects(pdos: dict[str, list[dict[str, Any]]]) -> list[dict[str, Any]]:
    """Expand the `pdos` section into CiA 301 communication/mapping objects."""
    objs: list[dict[str, Any]] = []
    for n, p in enumerate(pdos.get("rpdo", [])):
        objs.append({
            "index": 0x1400 + n, "name": f"RPDO{n + 1} communication parameter",
            "kind": "record",
            "doc": "bit 31 of the COB-ID: PDO not valid. Type 0-240: applied at the next SYNC; "
                   "254/255: applied on reception",
            "subs": [
                {"sub": 1, "name": "COB-ID", "type": "UNSIGNED32", "access": "rw",
                 "default": p["cob_id"]},
                {"sub": 2, "name": "Transmission type", "type": "UNSIGNED8", "access": "rw",
                 "default": p["trans_type"]},
                {"sub": 5, "name": "Event timer", "type": "UNSIGNED16", "access": "rw",
                 "unit": "ms", "default": p.get("event_timer", 0),
                 "doc": "deadline: data not applied for this long (no frame, or no SYNC for "
                        "a synchronous RPDO) raises fault 0x8250 RPDO_TIMEOUT while the drive "
                        "is enabled; 0 = off; armed by the first PDO applied in OPERATIONAL"},
            ],
        })
    for n, p in enumerate(pdos.get("tpdo", [])):
        objs.append({
            "index": 0x1800 + n, "name": f"TPDO{n + 1} communication parameter",
            "kind": "record",
            "doc": "Type 0: on SYNC if changed; 1-240: every n-th SYNC; 254/255: on change "
                   "(inhibit time) and on the event timer",
            "subs": [
                {"sub": 1, "name": "COB-ID", "type": "UNSIGNED32", "access": "rw",
                 "default": p["cob_id"]},
                {"sub": 2, "name": "Transmission type", "type": "UNSIGNED8", "access": "rw",
                 "default": p["trans_type"]},
                {"sub": 3, "name": "Inhibit time", "type": "UNSIGNED16", "access": "rw",
                 "unit": "100 us", "default": p.get("inhibit", 0)},
                {"sub": 5, "name": "Event timer", "type": "UNSIGNED16", "access": "rw",
                 "unit": "ms", "default": p.get("event_timer", 0)},
            ],
        })
    for base, key, label in ((0x1600, "rpdo", "RPDO"), (0x1A00, "tpdo", "TPDO")):
        for n, p in enumerate(pdos.get(key, [])):
            m = list(p.get("map", []))
            if len(m) > 8:
                raise OdError(f"od.yaml pdos.{key}[{n}]: more than 8 mapped objects")
            subs = [{"sub": 0, "name": "Number of mapped objects", "type": "UNSIGNED8",
                     "access": "rw", "min": 0, "max": 8, "default": len(m)}]
            for k in range(8):
                subs.append({"sub": k + 1, "name": f"Mapped object {k + 1}",
                             "type": "UNSIGNED32", "access": "rw",
                             "default": m[k] if k < len(m) else 0})
            objs.append({"index": base + n, "name": f"{label}{n + 1} mapping parameter",
                         "kind": "record",
                         "doc": "0xIIIISSLL: index, sub-index, length in bits. To change: "
                                "disable the PDO (COB-ID bit 31), write 0 to sub 0, write "
                                "the entries, write the count, enable.",
                         "subs": subs})
    return objs


_PARSED: dict[tuple[str, int, int], Any] = {}


def _parse(path: Path) -> Any:
    """The YAML document of ``path``, parsed once per file version (path, mtime, size):
    the bench loads the OD from several modules, and parsing is the expensive part.
    Uses libyaml's C loader when PyYAML has it. Callers must not mutate the result
    (``load`` only reads it)."""
    st = path.stat()
    key = (str(path.resolve()), st.st_mtime_ns, st.st_size)
    if key not in _PARSED:
        loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
        _PARSED.clear()  # one version per process is enough
        _PARSED[key] = yaml.load(path.read_text(), Loader=loader)  # noqa: S506 - safe loader
    return _PARSED[key]


_LOADED: dict[tuple[str, int, int], ObjectDictionary] = {}


def load(path: Path | str = OD_YAML) -> ObjectDictionary:
    """Load and validate od.yaml; raises :class:`OdError` naming the field.

    Expanded once per file version (like :func:`_parse`): the bench asks for it from
    several modules in one run. Callers must not mutate the result."""
    path = Path(path)
    st = path.stat()
    key = (str(path.resolve()), st.st_mtime_ns, st.st_size)
    if key not in _LOADED:
        od = _load(path)
        _LOADED.clear()
        _LOADED[key] = od
    return _LOADED[key]


VERSION_RE = re.compile(r"(\d{1,3})\.(\d{1,3})\.(\d{1,3})")


def _device(raw: dict[str, Any]) -> dict[str, Any]:
    """The ``device:`` section with what is derived from ``firmware_version`` (MAJOR.MINOR.PATCH):
    ``revision_number`` (0x00MMmmpp, FW_VERSION_U32), never written by hand."""
    dev = dict(raw)
    v = str(dev.get("firmware_version", ""))
    m = VERSION_RE.fullmatch(v)
    if not m or any(int(x) > 255 for x in m.groups()):
        raise OdError(f"od.yaml device.firmware_version: {v!r}, expected MAJOR.MINOR.PATCH "
                      "with each part 0..255")
    if "revision_number" in dev:
        raise OdError("od.yaml device.revision_number: derived from device.firmware_version; "
                      "remove it")
    major, minor, patch = (int(x) for x in m.groups())
    dev["firmware_version"] = v
    dev["revision_number"] = (major << 16) | (minor << 8) | patch
    return dev


def _with_device_refs(obj: dict[str, Any], dev: dict[str, Any]) -> dict[str, Any]:
    """``default: device.<key>`` replaced by the device section's value (a copy: the
    parsed document is shared)."""
    def sub(d: dict[str, Any], where: str) -> dict[str, Any]:
        v = d.get("default")
        if isinstance(v, str) and v.startswith("device."):
            key = v[len("device."):]
            if key not in dev:
                raise OdError(f"{where}: default {v!r}, the device section has no {key!r} "
                              f"(it has {', '.join(sorted(dev))})")
            return {**d, "default": dev[key]}
        return d

    where = f"od.yaml 0x{int(obj['index']):04X}"
    out = sub(obj, where)
    if "subs" in obj:
        out = {**out, "subs": [sub(s, f"{where}:{s.get('sub')}") for s in obj["subs"]]}
    return out


def _load(path: Path) -> ObjectDictionary:
    data = _parse(path)
    dev = _device(data["device"])
    fw_limits = data.get("fw_config", {}) or {}
    for name, lim in fw_limits.items():
        try:
            kind = fw_config_kind(lim)
        except OdError as e:
            raise OdError(f"od.yaml fw_config {name}: {e}") from None
        if kind != "f32" and not all(isinstance(lim.get(k), int)
                                     for k in ("min", "max", "default")):
            raise OdError(f"od.yaml fw_config {name}: a {kind} field needs integer min, max "
                          "and default")
        if kind == "u32" and int(lim["min"]) < 0:
            raise OdError(f"od.yaml fw_config {name}: min {lim['min']} of a u32 field is "
                          "negative (use i32)")
    signal_id_max = len(data.get("signals", []) or []) - 1
    objs = ([_with_device_refs(o, dev) for o in data["objects"]]
            + _pdo_objects(data.get("pdos", {}) or {}))
    max_string = int(data["device"].get("max_string", 24))
    entries: list[OdEntry] = []
    seen: set[tuple[int, int]] = set()
    for obj in objs:
        kind = obj.get("kind", "var")
        if kind == "var":
            e = _entry(obj, obj, "var", fw_limits, signal_id_max)
            if e.type == "VISIBLE_STRING" and e.size == 0:
                e = OdEntry(**{**e.__dict__, "size": max_string})
            items = [e]
        elif kind in ("record", "array"):
            subs = list(obj["subs"])
            items = []
            if not any(int(s.get("sub", 0)) == 0 for s in subs):
                highest = max(int(s["sub"]) for s in subs)
                items.append(OdEntry(
                    index=int(obj["index"]), sub=0, name="Highest sub-index supported",
                    object_name=str(obj["name"]), kind=kind, type="UNSIGNED8", access="const",
                    size=1, default=highest))
            for s in subs:
                s2 = dict(s)
                e = _entry(obj, s2, kind, fw_limits, signal_id_max)
                if e.type == "VISIBLE_STRING" and e.size == 0:
                    e = OdEntry(**{**e.__dict__, "size": max_string})
                items.append(e)
        else:
            raise OdError(f"od.yaml 0x{int(obj['index']):04X}: kind {kind!r}")
        for e in items:
            if (e.index, e.sub) in seen:
                raise OdError(f"od.yaml 0x{e.index:04X}:{e.sub}: defined twice")
            seen.add((e.index, e.sub))
            entries.append(e)
        if kind != "var" and obj.get("doc"):
            # keep the object doc on sub 0 for the docs table
            i0 = next(i for i, e in enumerate(entries) if e.index == int(obj["index"]))
            if not entries[i0].doc:
                entries[i0] = OdEntry(**{**entries[i0].__dict__, "doc": str(obj["doc"])})
    entries.sort(key=lambda e: (e.index, e.sub))
    signals = list(data.get("signals", []))
    faults: list[Fault] = []
    for k, f in enumerate(data.get("faults", []) or []):
        where = f"od.yaml faults[{k}]"
        try:
            flt = Fault(int(f["code"]), str(f["name"]), str(f["text"]), str(f["reaction"]))
        except KeyError as e:
            raise OdError(f"{where}: missing {e}") from None
        if not re.fullmatch(r"[A-Z][A-Z0-9_]*", flt.name) or not 0 <= flt.code <= 0xFFFF:
            raise OdError(f"{where}: name {flt.name!r} / code {flt.code:#x}")
        if any(g.code == flt.code or g.name == flt.name for g in faults):
            raise OdError(f"{where}: code or name {flt.name} defined twice")
        faults.append(flt)
    aborts: list[SdoAbort] = []
    for k, a in enumerate(data.get("sdo_aborts", []) or []):
        where = f"od.yaml sdo_aborts[{k}]"
        try:
            ab = SdoAbort(int(a["code"]), str(a["name"]), str(a["text"]))
        except KeyError as e:
            raise OdError(f"{where}: missing {e}") from None
        if not re.fullmatch(r"[A-Z][A-Z0-9_]*", ab.name) or not 0 < ab.code <= 0xFFFFFFFF:
            raise OdError(f"{where}: name {ab.name!r} / code {ab.code:#x}")
        if any(b.code == ab.code or b.name == ab.name for b in aborts):
            raise OdError(f"{where}: code or name {ab.name} defined twice")
        aborts.append(ab)
    parts = {str(k): str(v) for k, v in (data.get("fw_config_parts", {}) or {}).items()}
    for name, lim in fw_limits.items():
        if lim.get("group") not in parts:
            raise OdError(f"od.yaml fw_config {name}: group {lim.get('group')!r} is not one of "
                          f"fw_config_parts ({', '.join(parts)})")
    return ObjectDictionary(device=dev, entries=entries, signals=signals,
                            fw_config=fw_limits, faults=faults, fw_config_parts=parts,
                            sdo_aborts=aborts,
                            enums=_enums(data.get("enums", []) or []))


def _enums(raw: list[dict[str, Any]]) -> list[Enum]:
    """The ``enums:`` section, checked: C/Python identifiers, unique names, keys and
    values within each enumeration."""
    out: list[Enum] = []
    for k, e in enumerate(raw):
        where = f"od.yaml enums[{k}]"
        try:
            vals = []
            for j, v in enumerate(e["values"]):
                w = f"{where}.values[{j}]"
                ev = EnumValue(str(v["name"]), int(v["value"]), str(v["key"]), str(v["text"]))
                if not re.fullmatch(r"[A-Z][A-Z0-9_]*", ev.name) or not -128 <= ev.value <= 255:
                    raise OdError(f"{w}: name {ev.name!r} (A-Z0-9_) / value {ev.value} "
                                  "(-128..255; negative: manufacturer-specific codes)")
                if ev.key != ev.name.lower():
                    raise OdError(f"{w}: key {ev.key!r} must be {ev.name.lower()!r}")
                if any(u.name == ev.name or u.value == ev.value for u in vals):
                    raise OdError(f"{w}: name {ev.name} or value {ev.value} defined twice")
                vals.append(ev)
            en = Enum(str(e["name"]), str(e["ctype"]), str(e["prefix"]), str(e["doc"]),
                      tuple(vals))
        except KeyError as err:
            raise OdError(f"{where}: missing {err}") from None
        if not re.fullmatch(r"[a-z][a-z0-9_]*", en.name) or not en.values:
            raise OdError(f"{where}: name {en.name!r} (a-z0-9_) and at least one value")
        if not re.fullmatch(r"fw_[a-z0-9_]+_t", en.ctype) or not re.fullmatch(
                r"FW_[A-Z0-9_]*_", en.prefix):
            raise OdError(f"{where}: ctype {en.ctype!r} (fw_..._t) / prefix {en.prefix!r} "
                          "(FW_..._)")
        if any(g.name == en.name or g.ctype == en.ctype for g in out):
            raise OdError(f"{where}: enumeration {en.name} defined twice")
        out.append(en)
    return out
