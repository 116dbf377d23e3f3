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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jsonschema
import yaml

from bench._units import FORCE_UNITS, SPEED_UNITS
from sim_fallback.metrics import METRIC_NAMES

EXTRACTORS: tuple[str, ...] = ("pseudo", "sogi", "sogi_adaptive")
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


def _compose(text: str, file: str) -> tuple[Any, dict[tuple[Any, ...], tuple[int, int]]]:
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        line, col = (mark.line + 1, mark.column + 1) if mark else (0, 0)
        raise SequenceError([Issue(file, line, col, "", f"not valid YAML: {e}")]) from e
    if node is None:
        raise SequenceError([Issue(file, 1, 1, "", "empty file")])
    marks: dict[tuple[Any, ...], tuple[int, int]] = {}
    loader = yaml.SafeLoader("")

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
    t_issues, starts, total = _check_timing(doc, file, marks)
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


def load_sequence(path: str | Path) -> Sequence:
    """Load and validate a sequence file (see :func:`validate_sequence`)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as e:
        raise SequenceError([Issue(str(p), 0, 0, "", f"cannot read: {e.strerror}")]) from e
    seq = validate_sequence(text, str(p))
    seq.path = p
    return seq
