"""Test-sequence files: YAML schema, validation with file/line/field errors.

A sequence file is a YAML mapping with metadata and a list of ``steps``; each
step is a one-key mapping ``{kind: parameters}``::

    name: paper_load_step
    motor: paper_salient          # motor file (sim) / geometry for unit conversion
    extractor: sogi_adaptive      # pseudo | sogi | sogi_adaptive
    seed: 1
    steps:
      - enable: {mode: speed}
      - set_speed: {value: 100, unit: r/min}
      - wait: {duration_s: 0.5}
      - load_step: {value: 2.0, unit: N*m}
      - wait: {duration_s: 0.5}
      - expect: {metric: position_error_rms_rad, op: "<=", limit: 0.01, window_s: [0.15, 1.0]}
      - disable: {}

Everything is validated (JSON schema plus timing checks) before anything
moves; :class:`SequenceError` lists every problem as ``file:line:col: field:
message``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jsonschema
import yaml

from bench._units import FORCE_UNITS, SPEED_UNITS
from protocols.generated.od_names import Extractor
from protocols.units import m_per_electrical_rad
from sim_fallback.metrics import METRIC_NAMES

EXTRACTORS: tuple[str, ...] = tuple(e.key for e in Extractor)  # od.yaml enums:
OPS: tuple[str, ...] = ("<", "<=", ">", ">=")
STEP_KINDS: tuple[str, ...] = (
    "enable", "disable", "set_mode", "set_speed", "set_force", "ramp", "load_step",
    "load_ramp", "wait", "trace_capture", "expect",
)

_num = {"type": "number"}
_pos = {"type": "number", "exclusiveMinimum": 0}
_mode = {"enum": ["speed", "force"]}
_speed_unit = {"enum": list(SPEED_UNITS)}
_force_unit = {"enum": list(FORCE_UNITS)}


def _obj(props: dict[str, Any], required: list[str] | None = None) -> dict[str, Any]:
    return {"type": "object", "properties": props, "required": required or [],
            "additionalProperties": False}


_STEP_SCHEMAS: dict[str, dict[str, Any]] = {
    "enable": _obj({"mode": _mode, "timeout_s": _pos}),
    "disable": _obj({"timeout_s": _pos}),
    "set_mode": _obj({"mode": _mode}, ["mode"]),
    "set_speed": _obj({"value": _num, "unit": _speed_unit}, ["value", "unit"]),
    "set_force": _obj({"value": _num, "unit": _force_unit}, ["value", "unit"]),
    "ramp": _obj({"quantity": {"enum": ["speed", "force"]}, "to": _num,
                  "unit": {"enum": list(SPEED_UNITS) + list(FORCE_UNITS)},
                  "duration_s": _pos, "step_s": _pos},
                 ["quantity", "to", "unit", "duration_s"]),
    "load_step": _obj({"value": _num, "unit": _force_unit}, ["value", "unit"]),
    "load_ramp": _obj({"to": _num, "unit": _force_unit, "duration_s": _pos},
                      ["to", "unit", "duration_s"]),
    "wait": _obj({"duration_s": _pos}, ["duration_s"]),
    "trace_capture": _obj({"name": {"type": "string", "pattern": "^[A-Za-z0-9_]+$"},
                           "duration_s": _pos, "pre_s": {"type": "number", "minimum": 0},
                           "signals": {"type": "array", "items": {"type": "string"},
                                       "minItems": 1, "maxItems": 8}},
                          ["name", "duration_s"]),
    "expect": {
        "type": "object",
        "properties": {
            "metric": {"enum": list(METRIC_NAMES)},
            "op": {"enum": list(OPS)},
            "limit": _num,
            "value": _num,
            "tolerance": {"type": "number", "minimum": 0},
            "paper": _num,
            "window_s": {"type": "array", "items": _num, "minItems": 2, "maxItems": 2},
            "name": {"type": "string"},
            "doc": {"type": "string"},
        },
        "required": ["metric"],
        "additionalProperties": False,
        "oneOf": [
            {"required": ["op", "limit"], "not": {"anyOf": [{"required": ["value"]},
                                                             {"required": ["tolerance"]}]}},
            {"required": ["value", "tolerance"], "not": {"anyOf": [{"required": ["op"]},
                                                                   {"required": ["limit"]}]}},
        ],
    },
}

#: JSON schema of a sequence file (draft 2020-12).
SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "type": "object",
    "properties": {
        "name": {"type": "string", "pattern": "^[A-Za-z0-9_.-]+$"},
        "description": {"type": "string"},
        "motor": {"type": "string"},
        "extractor": {"enum": list(EXTRACTORS)},
        "seed": {"type": "integer", "minimum": 0},
        "settle_s": {"type": "number", "minimum": 0},
        "x0": {"oneOf": [{"type": "number"}, {"const": "random"}]},
        "reference": {"type": "string"},
        "steps": {
            "type": "array",
            "minItems": 1,
            "items": {
                "type": "object",
                "minProperties": 1,
                "maxProperties": 1,
                "propertyNames": {"enum": list(STEP_KINDS)},
                "properties": {k: {"oneOf": [{"type": "null"}, v]} if k in ("disable", "enable")
                               else v for k, v in _STEP_SCHEMAS.items()},
            },
        },
    },
    "required": ["name", "motor", "extractor", "seed", "steps"],
    "additionalProperties": False,
}


@dataclass(frozen=True)
class Issue:
    """One validation problem.

    Attributes
    ----------
    file : str
        Sequence file path.
    line, column : int
        1-based position of the offending YAML node (0 if unknown).
    field : str
        Dotted path of the field, e.g. ``steps[3].set_speed.unit``.
    message : str
        What is wrong.
    """

    file: str
    line: int
    column: int
    field: str
    message: str

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.column}: {self.field or '<top>'}: {self.message}"


class SequenceError(ValueError):
    """A sequence file failed validation; ``issues`` lists every problem."""

    def __init__(self, issues: list[Issue]) -> None:
        self.issues = issues
        super().__init__("invalid sequence:\n  " + "\n  ".join(str(i) for i in issues))


@dataclass(frozen=True)
class Step:
    """One sequence step.

    Attributes
    ----------
    kind : str
        One of :data:`STEP_KINDS`.
    params : dict
        The step's parameters as written in the file (units as given).
    index : int
        Position in ``steps`` (0-based).
    line : int
        1-based line of the step in the file.
    t_start_s : float
        Nominal sequence time at which the step starts (s), from the waits and
        ramps before it.
    """

    kind: str
    params: dict[str, Any]
    index: int
    line: int
    t_start_s: float

    @property
    def label(self) -> str:
        """Short human-readable label (``#3 set_speed``)."""
        return f"#{self.index} {self.kind}"


@dataclass
class Sequence:
    """A validated sequence.

    Attributes
    ----------
    name, motor, extractor : str
        Metadata (see the module docstring).
    seed : int
        Noise seed of the simulated drive.
    steps : list of Step
    path : Path
    description : str
    settle_s : float
        Default start of expectation windows (s), 0.15 as in the paper.
    x0 : float or "random"
        Initial true position of the simulated mover (m), ``"random"`` for a
        seed-derived random position.
    duration_s : float
        Nominal total duration (sum of waits and ramps, s).
    raw : dict
        The parsed YAML document.
    """

    name: str
    motor: str
    extractor: str
    seed: int
    steps: list[Step]
    path: Path
    description: str = ""
    settle_s: float = 0.15
    x0: float | str = 0.0
    duration_s: float = 0.0
    raw: dict[str, Any] = field(default_factory=dict, repr=False)

    @property
    def expectations(self) -> list[Step]:
        """The ``expect`` steps."""
        return [s for s in self.steps if s.kind == "expect"]


# ---- YAML with positions -------------------------------------------------------------

#: Deepest nesting a sequence file may have (a real one has 4 levels).
MAX_YAML_DEPTH = 32
#: Longest a single wait / ramp / capture step may last (s), and a whole sequence.
MAX_DURATION_S = 86400.0

# YAML 1.2 floats: PyYAML's YAML 1.1 regex reads 1.0e3 and 1e3 as text
_FLOAT_12 = re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
    |[-+]?\.[0-9_]+(?:[eE][-+]?[0-9]+)?
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$""", re.X)


class SequenceLoader(yaml.SafeLoader):
    """Safe YAML loader for sequence files.

    Rejects aliases (``*name``: no alias bombs) and nesting deeper than
    :data:`MAX_YAML_DEPTH` with a positioned error, and reads YAML 1.2 floats
    (``1.0e3``, ``1e3``) as numbers.
    """

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent: Any, index: Any) -> Any:  # noqa: D102
        if self.check_event(yaml.AliasEvent):
            ev = self.peek_event()
            raise yaml.composer.ComposerError(
                None, None, f"alias '*{ev.anchor}' not allowed in sequence files (write the "
                "value out)", ev.start_mark)
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                raise yaml.composer.ComposerError(
                    None, None, f"nested deeper than {MAX_YAML_DEPTH} levels",
                    self.peek_event().start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


SequenceLoader.yaml_implicit_resolvers = {
    k: [r for r in v if r[0] != "tag:yaml.org,2002:float"]
    for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()}
SequenceLoader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_12,
                                     list("-+0123456789."))


def _compose(text: str, file: str) -> tuple[Any, dict[tuple[Any, ...], tuple[int, int]]]:
    try:
        loader = SequenceLoader(text)
        try:
            node = loader.get_single_node()
        finally:
            loader.dispose()
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        line, col = (mark.line + 1, mark.column + 1) if mark else (0, 0)
        what = " ".join(str(getattr(e, "problem", "") or e).split())
        raise SequenceError([Issue(file, line, col, "", f"not valid YAML: {what}")]) from None
    if node is None:
        raise SequenceError([Issue(file, 1, 1, "", "empty file")])
    marks: dict[tuple[Any, ...], tuple[int, int]] = {}
    loader = SequenceLoader("")

    def conv(n: yaml.Node, path: tuple[Any, ...]) -> Any:
        marks[path] = (n.start_mark.line + 1, n.start_mark.column + 1)
        if isinstance(n, yaml.MappingNode):
            out: dict[Any, Any] = {}
            for k, v in n.value:
                key = loader.construct_object(k, deep=True)
                if key in out:
                    raise SequenceError([Issue(file, k.start_mark.line + 1,
                                               k.start_mark.column + 1,
                                               _field(path + (key,)), "duplicate key")])
                out[key] = conv(v, path + (key,))
            return out
        if isinstance(n, yaml.SequenceNode):
            return [conv(v, path + (i,)) for i, v in enumerate(n.value)]
        return loader.construct_object(n, deep=True)

    return conv(node, ()), marks


def _field(path: tuple[Any, ...] | list[Any]) -> str:
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out


def _mark(marks: dict[tuple[Any, ...], tuple[int, int]], path: tuple[Any, ...]) -> tuple[int, int]:
    p = tuple(path)
    while p and p not in marks:
        p = p[:-1]
    return marks.get(p, (0, 0))


_VALIDATOR = jsonschema.Draft202012Validator(SCHEMA)


def _best_errors(err: jsonschema.ValidationError) -> list[jsonschema.ValidationError]:
    """Descend into oneOf/anyOf to the most specific sub-errors."""
    if err.validator in ("oneOf", "anyOf") and err.context:
        # prefer the branch that got deepest (e.g. skip the "null" alternative)
        deepest = max(len(e.absolute_path) for e in err.context)
        subs = [e for e in err.context if len(e.absolute_path) == deepest]
        if deepest > len(err.absolute_path):
            out: list[jsonschema.ValidationError] = []
            for e in subs:
                out.extend(_best_errors(e))
            return out
        non_type = [e for e in err.context if e.validator != "type"]
        if non_type and err.validator == "oneOf" and all(
                e.validator in ("required", "not") for e in non_type):
            return [err]
    return [err]


def _message(err: jsonschema.ValidationError) -> str:
    if err.validator == "oneOf" and err.schema.get("oneOf") and "required" in str(err.schema):
        return ("give either 'op' and 'limit' (e.g. op: '<=', limit: 0.01) or 'value' and "
                "'tolerance'")
    if err.validator in ("minProperties", "maxProperties"):
        return "a step is a mapping with exactly one key, e.g. '- wait: {duration_s: 0.5}'"
    return err.message


def _signal_names() -> list[str]:
    """Telemetry/trace signal names from protocols/od.yaml ([] if unavailable)."""
    try:
        from protocols import _od

        return [sig["name"] for sig in _od.load().signals]
    except Exception:  # noqa: BLE001 - validation then skips this check
        return []


def _check_timing(seq: dict[str, Any], file: str,
                  marks: dict[tuple[Any, ...], tuple[int, int]]) -> tuple[list[Issue],
                                                                          list[float], float]:
    """Nominal step start times; expect windows must lie in the past."""
    issues: list[Issue] = []
    t = 0.0
    starts: list[float] = []
    enabled = False
    for i, step in enumerate(seq["steps"]):
        (kind, p), = step.items()
        p = p or {}
        starts.append(t)
        if kind == "enable":
            enabled = True
        elif kind == "disable":
            enabled = False
        elif kind in ("set_speed", "set_force", "ramp") and not enabled:
            path = ("steps", i, kind)
            line, col = _mark(marks, path)
            issues.append(Issue(file, line, col, _field(path),
                                f"'{kind}' before 'enable': the drive would ignore it"))
        if kind == "trace_capture" and p.get("signals"):
            known = _signal_names()
            for j, sig in enumerate(p["signals"]):
                if known and sig not in known:
                    path = ("steps", i, kind, "signals", j)
                    line, col = _mark(marks, path)
                    issues.append(Issue(file, line, col, _field(path),
                                        f"unknown signal {sig!r}; allowed (od.yaml signals): "
                                        f"{', '.join(known)}"))
        if kind in ("wait", "ramp", "load_ramp"):
            t += float(p["duration_s"])
        if kind == "expect" and "window_s" in p:
            t0, t1 = (float(v) for v in p["window_s"])
            path = ("steps", i, kind, "window_s")
            line, col = _mark(marks, path)
            if not (math.isfinite(t0) and math.isfinite(t1) and 0 <= t0 < t1):
                issues.append(Issue(file, line, col, _field(path),
                                    f"window [{t0}, {t1}] s must satisfy 0 <= start < end"))
            elif t1 > t + 1e-9:
                issues.append(Issue(file, line, col, _field(path),
                                    f"window ends at {t1} s but the expectation is evaluated at "
                                    f"{t:g} s (sum of the waits before it)"))
    return issues, starts, t


_ACTIONS = ("set_speed", "set_force", "ramp", "load_step", "load_ramp", "set_mode", "enable")


def _nonfinite(doc: Any, path: tuple[Any, ...] = ()) -> list[tuple[tuple[Any, ...], float]]:
    """Every NaN / inf number in a parsed document, with its path."""
    if isinstance(doc, dict):
        return [x for k, v in doc.items() for x in _nonfinite(v, path + (k,))]
    if isinstance(doc, list):
        return [x for i, v in enumerate(doc) for x in _nonfinite(v, path + (i,))]
    if isinstance(doc, float) and not math.isfinite(doc):
        return [(path, doc)]
    return []


def drive_envelope(motor: str) -> dict[str, float]:
    """Limits a sequence must respect, from the motor file and the firmware's config.

    Parameters
    ----------
    motor : str
        Motor name or TOML path.

    Returns
    -------
    dict
        ``speed_max_mps`` (the firmware's speed limits ``v_max_mps`` and
        ``speed_max_radps_e``), ``force_max_N`` (thrust at ``i_max_A``),
        ``x_min_m`` / ``x_max_m`` (the firmware table's range of
        ``pos_limit_*_m``), ``f_pwm_Hz``, ``radius_m``, ``pole_pitch_m``,
        ``pole_pairs``.

    Raises
    ------
    FileNotFoundError, MotorFileError
        The motor cannot be loaded.
    """
    from sim_fallback import firmware_field_ranges, fw_config, load_motor

    m = load_motor(motor)
    cfg = fw_config(m)
    lo, hi, _ = firmware_field_ranges().get("pos_limit_max_m", (-1e4, 1e4, "m"))
    return {"speed_max_mps": min(float(cfg.v_max_mps),
                                 float(cfg.speed_max_radps_e)
                                 * m_per_electrical_rad(m.tau_m)),
            "force_max_N": m.force_const_N_per_A * float(cfg.i_max_A),
            "x_min_m": lo, "x_max_m": hi, "f_pwm_Hz": float(m.plant["f_pwm_Hz"]),
            "radius_m": m.radius_m, "pole_pitch_m": m.tau_m,
            "pole_pairs": float(m.pole_pairs)}


def _check_values(doc: dict[str, Any], file: str, marks: dict[tuple[Any, ...], tuple[int, int]],
                  starts: list[float], total: float) -> list[Issue]:
    """Finite numbers, the drive's envelope, trace captures that fit and cover their event."""
    issues: list[Issue] = []

    def add(path: tuple[Any, ...], msg: str) -> None:
        line, col = _mark(marks, path)
        issues.append(Issue(file, line, col, _field(path), msg))

    for path, v in _nonfinite(doc):
        add(path, f"{v} is not a finite number")
    if issues:
        return issues
    settle = float(doc.get("settle_s", 0.15))
    if "settle_s" in doc and settle >= total > 0:
        add(("settle_s",), f"{settle:g} s is not shorter than the sequence ({total:g} s); "
                           f"allowed range [0, {total:g})")
    try:
        env = drive_envelope(doc["motor"])
    except (OSError, ValueError) as e:
        add(("motor",), " ".join(str(e).split()))
        return issues
    from bench._units import MotorUnits

    units = MotorUnits(env["pole_pitch_m"], env["pole_pairs"])
    vmax, fmax = env["speed_max_mps"], env["force_max_N"]
    x0 = doc.get("x0", 0.0)
    if isinstance(x0, (int, float)) and not env["x_min_m"] <= x0 <= env["x_max_m"]:
        add(("x0",), f"{x0:g} m outside the firmware's position range "
                     f"[{env['x_min_m']:g}, {env['x_max_m']:g}] m")
    steps = doc["steps"]
    for i, step in enumerate(steps):
        (kind, p), = step.items()
        p = p or {}
        for key in ("duration_s", "pre_s", "timeout_s", "step_s"):
            if key in p and float(p[key]) > MAX_DURATION_S:
                add(("steps", i, kind, key), f"{p[key]:g} s; allowed range (0, "
                                             f"{MAX_DURATION_S:g}] s")
        for key in ("value", "to"):
            if key not in p or "unit" not in p:
                continue
            unit = p["unit"]
            v = float(p[key])
            if kind in ("set_speed",) or (kind == "ramp" and p.get("quantity") == "speed"):
                if unit not in ("r/min", "rpm", "m/s", "mm/s"):
                    continue
                lim = vmax / units.speed_to_mps(1.0, unit)
                if abs(v) > lim:
                    add(("steps", i, kind, key), f"{v:g} {unit} exceeds the drive's speed "
                                                 f"limit; allowed range [{-lim:.4g}, {lim:.4g}] "
                                                 f"{unit}")
            elif unit in ("N", "N*m", "N.m", "Nm", "N·m"):
                lim = fmax / units.force_to_N(1.0, unit)
                if abs(v) > lim:
                    what = "load" if kind.startswith("load") else "force"
                    add(("steps", i, kind, key), f"{v:g} {unit} {what} exceeds the thrust at "
                                                 f"i_max_A; allowed range [{-lim:.4g}, "
                                                 f"{lim:.4g}] {unit}")
        if kind == "trace_capture":
            from protocols.serial_link import TRACE_FLOATS  # the firmware's buffer size
            n_sig = len(p.get("signals") or ["", "", "", ""])
            buf_s = TRACE_FLOATS // n_sig / env["f_pwm_Hz"]
            pre, dur = float(p.get("pre_s", 0.0)), float(p["duration_s"])
            if pre + dur > buf_s + 1e-12:
                add(("steps", i, kind, "duration_s"),
                    f"pre_s + duration_s = {pre + dur:g} s exceeds the drive's trace buffer: "
                    f"{TRACE_FLOATS // n_sig} samples of {n_sig} signals at "
                    f"{env['f_pwm_Hz']:g} Hz = {buf_s:.4g} s")
            nxt = next((j for j in range(i + 1, len(steps)) if next(iter(steps[j])) != "wait"),
                       None)
            if nxt is not None and next(iter(steps[nxt])) in _ACTIONS:
                t_ev, t_c = starts[nxt], starts[i]
                if not t_c - pre <= t_ev <= t_c + dur:
                    ev = next(iter(steps[nxt]))
                    add(("steps", i, kind), f"the capture covers [{t_c - pre:g}, {t_c + dur:g}] "
                                            f"s but the '{ev}' it precedes (steps[{nxt}]) is at "
                                            f"{t_ev:g} s; move it closer or lengthen it")
    if not issues and total > MAX_DURATION_S:
        add(("steps",), f"the sequence lasts {total:g} s; allowed up to {MAX_DURATION_S:g} s")
    return issues


def validate_sequence(text: str, file: str = "<string>") -> Sequence:
    """Parse and validate a sequence document.

    Parameters
    ----------
    text : str
        YAML text.
    file : str
        File name used in error messages.

    Returns
    -------
    Sequence

    Raises
    ------
    SequenceError
        With every problem found, each naming the file, line and field.
    """
    doc, marks = _compose(text, file)
    if not isinstance(doc, dict):
        raise SequenceError([Issue(file, 1, 1, "", "top level must be a mapping")])
    issues: list[Issue] = []
    for err in sorted(_VALIDATOR.iter_errors(doc), key=lambda e: list(map(str, e.path))):
        for e in _best_errors(err):
            path = tuple(e.absolute_path)
            if e.validator == "additionalProperties" and isinstance(e.instance, dict):
                allowed = set(e.schema.get("properties", {}))
                for extra in sorted(set(e.instance) - allowed):
                    line, col = _mark(marks, path + (extra,))
                    issues.append(Issue(file, line, col, _field(path + (extra,)),
                                        f"unknown field; allowed: {', '.join(sorted(allowed))}"))
                continue
            if e.validator == "required" and isinstance(e.instance, dict):
                line, col = _mark(marks, path)
                missing = [r for r in e.validator_value if r not in e.instance]
                # one error per missing key (duplicates are dropped below)
                for r in missing or [None]:
                    issues.append(Issue(file, line, col,
                                        _field(path + (r,)) if r else _field(path),
                                        f"{r!r} is a required property" if r else e.message))
                continue
            if "propertyNames" in e.schema_path:
                line, col = _mark(marks, path + (e.instance,))
                issues.append(Issue(file, line, col, _field(path + (e.instance,)),
                                    f"unknown step {e.instance!r}; allowed: "
                                    f"{', '.join(STEP_KINDS)}"))
                continue
            line, col = _mark(marks, path)
            issues.append(Issue(file, line, col, _field(path), _message(e)))
    if issues:
        # de-duplicate, keep order
        seen: set[str] = set()
        uniq = [i for i in issues if not (str(i) in seen or seen.add(str(i)))]
        raise SequenceError(uniq)
    doc["motor"] = motor_beside(doc["motor"], file)
    t_issues, starts, total = _check_timing(doc, file, marks)
    t_issues += _check_values(doc, file, marks, starts, total)
    if t_issues:
        raise SequenceError(t_issues)
    steps = []
    for i, step in enumerate(doc["steps"]):
        (kind, p), = step.items()
        steps.append(Step(kind=kind, params=dict(p or {}), index=i,
                          line=_mark(marks, ("steps", i))[0], t_start_s=starts[i]))
    return Sequence(name=doc["name"], motor=doc["motor"], extractor=doc["extractor"],
                    seed=int(doc["seed"]), steps=steps, path=Path(file),
                    description=doc.get("description", ""),
                    settle_s=float(doc.get("settle_s", 0.15)), x0=doc.get("x0", 0.0),
                    duration_s=total, raw=doc)


def motor_beside(motor: str, file: str) -> str:
    """A sequence's ``motor:``: a motor name as it is; a relative path to a motor file
    (``my_lin.toml``, ``motors/x.toml``) is relative to the sequence file's folder, as an
    include is, not to the directory the bench was started in."""
    p = Path(motor)
    if p.is_absolute() or (p.suffix != ".toml" and len(p.parts) < 2):
        return motor
    seq = Path(file)
    if file.startswith("<") or not seq.parent.is_dir():
        return motor  # text without a file (validate_sequence(text))
    return str(seq.parent / p)


def load_sequence(path: str | Path) -> Sequence:
    """Load and validate a sequence file (see :func:`validate_sequence`)."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as e:
        raise SequenceError([Issue(str(p), 0, 0, "", f"cannot read: {e.strerror}")]) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        line = raw[:e.start].count(b"\n") + 1
        col = e.start - (raw.rfind(b"\n", 0, e.start) + 1) + 1
        raise SequenceError([Issue(str(p), line, col, "", f"not UTF-8 text (byte "
                                   f"{raw[e.start]:#04x}); save the file as UTF-8")]) from None
    seq = validate_sequence(text, str(p))
    seq.path = p
    return seq
