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

A sequence takes parameters and loops (see :func:`expand`): top-level ``params:
{name: number}`` referenced as ``${name}`` in values (overridden by ``bench run
--set name=value``), and ``repeat`` steps expanded into the flat step list::

    params: {load: 2.0}
    steps:
      - enable: {mode: speed}
      - repeat:
          for: v
          in: [100, 200]
          steps:
            - set_speed: {value: "${v}", unit: r/min}
            - wait: {duration_s: 0.5}
            - expect: {metric: position_error_rms_rad, op: "<=", limit: 0.02,
                       window_s: [0.3, 0.5]}    # from the start of the repetition
      - disable: {}

Everything is validated (JSON schema plus timing checks, on the expanded steps) before
anything moves; :class:`SequenceError` lists every problem as ``file:line:col: field:
message``, the position always in the file as written.
"""

from __future__ import annotations

import copy
import hashlib
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
from sim_fallback.metrics import METRIC_NAMES, default_window

EXTRACTORS: tuple[str, ...] = tuple(e.key for e in Extractor)  # od.yaml enums:
OPS: tuple[str, ...] = ("<", "<=", ">", ">=")
STEP_KINDS: tuple[str, ...] = (
    "enable", "disable", "set_mode", "set_speed", "set_force", "ramp", "load_step",
    "load_ramp", "wait", "trace_capture", "expect", "repeat",
)
#: a parameter's or loop variable's name
PARAM_NAME = r"^[A-Za-z_][A-Za-z0-9_]{0,63}$"
#: most steps a sequence may have once its repeats are expanded
MAX_STEPS = 10000

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

#: a ``repeat`` step: its own fields (its steps are checked once expanded)
_REPEAT_SCHEMA: dict[str, Any] = _obj(
    {"for": {"type": "string", "pattern": PARAM_NAME},
     "in": {"type": "array", "minItems": 1, "items": _num},
     "steps": {"type": "array", "minItems": 1, "items": {"type": "object"}}},
    ["for", "in", "steps"])
_STEP_SCHEMAS["repeat"] = {**_REPEAT_SCHEMA, "properties": {
    **_REPEAT_SCHEMA["properties"],
    "steps": {"type": "array", "minItems": 1, "items": {"$ref": "#/properties/steps/items"}}}}

#: JSON schema of a sequence file (draft 2020-12), as it is validated: with its
#: ``${name}`` references substituted (``repeat`` steps are expanded before).
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
        "params": {"type": "object", "propertyNames": {"pattern": PARAM_NAME},
                   "additionalProperties": _num},
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
    loop : dict
        The loop variables of the ``repeat`` repetition this step comes from
        (``{"v": 0.2}``; empty outside a repeat).
    """

    kind: str
    params: dict[str, Any]
    index: int
    line: int
    t_start_s: float
    loop: dict[str, float] = field(default_factory=dict)

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
        The parsed YAML document (as written: ``params``, ``repeat`` steps).
    params : dict
        The parameters' values the steps were expanded with (defaults and ``--set``).
    overrides : dict
        The ``--set`` values among them.
    sha256 : str
        SHA-256 of the file's bytes (of the text for :func:`validate_sequence`).
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
    params: dict[str, float] = field(default_factory=dict)
    overrides: dict[str, float] = field(default_factory=dict)
    sha256: str = ""

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


def compose_yaml(text: str, file: str) -> tuple[Any, dict[tuple[Any, ...], tuple[int, int]]]:
    """``text`` (YAML, read with :class:`SequenceLoader`) as plain data, and the (line,
    column) of every node by its path; raises :class:`SequenceError` for invalid YAML, an
    empty file or a duplicate key, positioned in ``file``. Sequences and campaign files
    are read with it."""
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
        lines = text.splitlines()
        if mark and mark.line < len(lines) and "${" in lines[mark.line]:
            what += ("; a ${name} reference inside {...} or [...] must be quoted, e.g. "
                     "{value: \"${speed}\", unit: r/min}")
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
    if err.validator == "pattern" and err.validator_value == PARAM_NAME:
        return (f"{err.instance!r}: a name is letters, digits and _ (at most 64), not "
                "starting with a digit")
    if err.validator == "oneOf" and err.schema.get("oneOf") and "required" in str(err.schema):
        return ("give either 'op' and 'limit' (e.g. op: '<=', limit: 0.01) or 'value' and "
                "'tolerance'")
    if err.validator in ("minProperties", "maxProperties"):
        return "a step is a mapping with exactly one key, e.g. '- wait: {duration_s: 0.5}'"
    return err.message


def _signal_names() -> list[str]:
    """Telemetry/trace signal names from protocols/od.yaml ([] if unavailable)."""
    try:
        from protocols import load_od

        return [sig["name"] for sig in load_od().signals]
    except Exception:  # noqa: BLE001 - validation then skips this check
        return []


# ---- where a problem is, in the file as written -----------------------------------------


@dataclass
class _Origin:
    """Where an expanded step comes from: its path in the document as written, the loop
    variables of its repetition and the time that repetition starts (None: no repeat)."""

    path: tuple[Any, ...]
    loop: tuple[tuple[str, float], ...] = ()
    t_offset: float | None = None

    @property
    def context(self) -> str:
        return ", ".join(f"{n}={_fmt(v)}" for n, v in self.loop)


class _Locator:
    """Turns a path in the expanded document (``steps[7].set_speed.value``) into an
    :class:`Issue` at the position and field of the file as written
    (``steps[2].repeat.steps[1].set_speed.value (v=0.2)``)."""

    def __init__(self, file: str, marks: dict[tuple[Any, ...], tuple[int, int]]) -> None:
        self.file = file
        self.marks = marks
        self.origins: list[_Origin] = []
        #: expanded path -> (name, value, source) of a whole-value ${name} substitution
        self.subs: dict[tuple[Any, ...], tuple[str, float, str]] = {}

    def origin(self, i: int) -> _Origin:
        return self.origins[i] if 0 <= i < len(self.origins) else _Origin(("steps", i))

    def original(self, path: tuple[Any, ...]) -> tuple[tuple[Any, ...], str]:
        path = tuple(path)
        if len(path) >= 2 and path[0] == "steps" and isinstance(path[1], int) and \
                path[1] < len(self.origins):
            o = self.origins[path[1]]
            return o.path + path[2:], o.context
        return path, ""

    def field(self, path: tuple[Any, ...]) -> str:
        orig, ctx = self.original(path)
        return _field(orig) + (f" ({ctx})" if ctx else "")

    def line(self, path: tuple[Any, ...]) -> int:
        return _mark(self.marks, self.original(path)[0])[0]

    def at(self, orig: tuple[Any, ...], msg: str, ctx: str = "") -> Issue:
        """An issue at a path of the document as written."""
        line, col = _mark(self.marks, orig)
        return Issue(self.file, line, col, _field(orig) + (f" ({ctx})" if ctx else ""), msg)

    def issue(self, path: tuple[Any, ...], msg: str) -> Issue:
        """An issue at a path of the expanded document."""
        orig, ctx = self.original(path)
        sub = self.subs.get(tuple(path))
        if sub is not None:
            name, value, source = sub
            if source in ("params", "--set"):
                msg += f" (${{{name}}} = {_fmt(value)} from {source})"
            elif source.startswith("loop:"):  # a loop value that is a parameter
                _, ref, src = source.split(":", 2)
                msg += f" (${{{name}}} = ${{{ref}}} = {_fmt(value)} from {src})"
        return self.at(orig, msg, ctx)


def _fmt(v: Any) -> str:
    """A parameter's value in a name or message: 100, 0.2, 1e-05 (round-trip exact)."""
    if isinstance(v, float) and v.is_integer() and abs(v) < 1e15:
        return str(int(v))
    return repr(v) if isinstance(v, float) else str(v)


def _is_num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


# ---- parameters and loops ------------------------------------------------------------

_REF = re.compile(r"\$\{([^}]*)\}")
_NAME_RE = re.compile(PARAM_NAME)
_REPEAT_VALIDATOR = jsonschema.Draft202012Validator(_REPEAT_SCHEMA)


class _Expander:
    """Substitutes ``${name}`` and expands ``repeat`` steps (see :func:`expand`)."""

    def __init__(self, doc: dict[str, Any], loc: _Locator,
                 overrides: dict[str, Any]) -> None:
        self.doc = doc
        self.loc = loc
        self.issues: list[Issue] = []
        self.out: list[Any] = []
        self.t = 0.0
        self.env: dict[str, tuple[Any, str]] = {}
        self.params: dict[str, float] = {}
        self.overrides: dict[str, float] = {}
        raw = doc.get("params", {})
        defined = raw if isinstance(raw, dict) else {}
        for k, v in defined.items():
            if isinstance(k, str) and _NAME_RE.match(k) and _is_num(v):
                self.env[k] = (v, "params")  # a bad entry: the schema says so at params
        for k, v in overrides.items():
            if k not in defined:
                have = ", ".join(str(n) for n in defined) or "none (no 'params:' in the file)"
                self.issues.append(loc.at(("params",) if "params" in doc else (),
                                          f"--set {k}: no such parameter; defined: {have}"))
            elif not _is_num(v) or not math.isfinite(v):
                self.issues.append(loc.at(("params", k), f"--set {k}={v!r}: not a finite "
                                                         "number"))
            else:
                self.env[k] = (v, "--set")
                self.overrides[k] = v
        self.params = {k: v for k, (v, _) in self.env.items()}
        settle = doc.get("settle_s", 0.15)
        self.settle = float(settle) if _is_num(settle) and math.isfinite(settle) else 0.15

    # substitution
    def subst(self, node: Any, env: dict[str, tuple[Any, str]], orig: tuple[Any, ...],
              exp: tuple[Any, ...] | None, ctx: str) -> Any:
        if isinstance(node, dict):
            return {k: self.subst(v, env, orig + (k,), None if exp is None else exp + (k,),
                                  ctx) for k, v in node.items()}
        if isinstance(node, list):
            return [self.subst(v, env, orig + (i,), None if exp is None else exp + (i,), ctx)
                    for i, v in enumerate(node)]
        if not isinstance(node, str) or "${" not in node:
            return node
        refs = _REF.findall(node)
        bad = [r for r in refs if r.strip() not in env]
        if bad or not refs:
            r = bad[0] if bad else node
            if bad and _NAME_RE.match(r.strip()):
                known = [n for n, (_, s) in env.items() if not s.startswith("loop")]
                loops = [n for n, (_, s) in env.items() if s.startswith("loop")]
                have = (", ".join(known) or "none") + (
                    f"; loop variable{'s' if len(loops) > 1 else ''} here: "
                    f"{', '.join(loops)}" if loops else "")
                msg = f"unknown parameter '{r.strip()}' in {node!r}; defined: {have}"
            else:
                msg = (f"{node!r}: a reference is ${{name}} with a parameter or loop "
                       "variable name (letters, digits, _)")
            self.issues.append(self.loc.at(orig, msg, ctx))
            return node
        whole = _REF.fullmatch(node.strip())
        if whole:
            name = whole.group(1).strip()
            value, source = env[name]
            if exp is not None:
                self.loc.subs[exp] = (name, value, source)
            return value
        return _REF.sub(lambda m: _fmt(env[m.group(1).strip()][0]), node)

    # expansion
    def run(self) -> None:
        for k in list(self.doc):
            if k not in ("params", "steps"):
                self.doc[k] = self.subst(self.doc[k], self.env, (k,), (k,), "")
        steps = self.doc.get("steps")
        if isinstance(steps, list):
            self.steps(steps, ("steps",), self.env, (), None)
            self.doc["steps"] = self.out
            self._unique_names()

    def steps(self, items: list[Any], base: tuple[Any, ...], env: dict[str, tuple[Any, str]],
              loop: tuple[tuple[str, float], ...], t_off: float | None) -> None:
        ctx = ", ".join(f"{n}={_fmt(v)}" for n, v in loop)
        unnamed: dict[Any, int] = {}
        for st in items:
            p = st.get("expect") if isinstance(st, dict) and len(st) == 1 else None
            if isinstance(p, dict) and "name" not in p:
                unnamed[p.get("metric")] = unnamed.get(p.get("metric"), 0) + 1
        for i, step in enumerate(items):
            path = base + (i,)
            if isinstance(step, dict) and len(step) == 1 and "repeat" in step:
                self.repeat(step["repeat"], path + ("repeat",), env, loop, ctx)
                continue
            k = len(self.out)
            if k >= MAX_STEPS:
                raise SequenceError([self.loc.at(path, f"the sequence has more than "
                                                       f"{MAX_STEPS} steps once its repeats "
                                                       "are expanded", ctx)])
            self.loc.origins.append(_Origin(path, loop, t_off))
            new = self.subst(step, env, path, ("steps", k), ctx)
            if loop and t_off is not None:
                self._in_loop(new, loop, t_off, unnamed)
            self.out.append(new)
            if isinstance(new, dict) and len(new) == 1:
                (kind, p), = new.items()
                d = p.get("duration_s") if isinstance(p, dict) else None
                if kind in ("wait", "ramp", "load_ramp") and _is_num(d) and \
                        math.isfinite(d) and d > 0:
                    self.t += float(d)

    def _in_loop(self, step: Any, loop: tuple[tuple[str, float], ...], t_off: float,
                 unnamed: dict[Any, int]) -> None:
        """An expectation in a repetition: named with the loop values, its window from
        the repetition's start moved to sequence time."""
        p = step.get("expect") if isinstance(step, dict) and len(step) == 1 else None
        if not isinstance(p, dict):
            return
        suffix = "@" + ",".join(f"{n}={_fmt(v)}" for n, v in loop)
        metric = p.get("metric")
        w = p.get("window_s")
        good_w = isinstance(w, list) and len(w) == 2 and all(_is_num(x) for x in w)
        if isinstance(p.get("name"), str):
            p["name"] += suffix
        elif "name" not in p and isinstance(metric, str):
            base = metric
            if unnamed.get(metric, 0) > 1 and good_w:
                base = f"{metric}@[{w[0]:g},{w[1]:g}]s"
            p["name"] = base + suffix
            p["_generated_name"] = True
        if good_w:
            p["window_s"] = [round(float(x) + t_off, 9) for x in w]
        elif w is None and metric in METRIC_NAMES:
            a, b = default_window(metric, self.settle, self.t - t_off)
            p["window_s"] = [round(a + t_off, 9), round(b + t_off, 9)]

    def repeat(self, r: Any, rpath: tuple[Any, ...], env: dict[str, tuple[Any, str]],
               loop: tuple[tuple[str, float], ...], ctx: str) -> None:
        if not isinstance(r, dict):
            self.issues.append(self.loc.at(rpath, "a repeat is a mapping: {for: v, in: "
                                                  "[0.1, 0.2], steps: [...]}", ctx))
            return
        refs: dict[int, str] = {}  # in: entries that are a parameter given by params / --set
        if isinstance(r.get("in"), list):
            for j, item in enumerate(r["in"]):
                m = _REF.fullmatch(item.strip()) if isinstance(item, str) else None
                if m and m.group(1).strip() in env and \
                        env[m.group(1).strip()][1] in ("params", "--set"):
                    refs[j] = f"loop:{m.group(1).strip()}:{env[m.group(1).strip()][1]}"
        r = {**r, "in": self.subst(r["in"], env, rpath + ("in",), None, ctx)} if "in" in r \
            else dict(r)
        errs = _schema_issues(_REPEAT_VALIDATOR, r,
                              lambda p, m: self.loc.at(rpath + tuple(p), m, ctx))
        if errs:
            self.issues += errs
            return
        var, values = r["for"], r["in"]
        if var in env:
            what = "a parameter" if not env[var][1].startswith("loop") else \
                "the loop variable of an enclosing repeat"
            self.issues.append(self.loc.at(rpath + ("for",), f"'{var}' is already {what}; "
                                                              "give the loop variable another "
                                                              "name", ctx))
            return
        seen: set[float] = set()
        bad: list[Issue] = []
        for j, v in enumerate(values):
            if not math.isfinite(v):
                bad.append(self.loc.at(rpath + ("in", j), f"{v} is not a finite number", ctx))
            elif v in seen:
                bad.append(self.loc.at(rpath + ("in", j), f"{_fmt(v)} is listed twice (each "
                                                          "repetition is named by its value)",
                                       ctx))
            seen.add(v)
        if bad:
            self.issues += bad
            return
        for j, v in enumerate(values):
            self.steps(r["steps"], rpath + ("steps",), {**env, var: (v, refs.get(j, "loop"))},
                       loop + ((var, v),), self.t)

    def _unique_names(self) -> None:
        """Expectations in repetitions are named with the loop values; two the same (the
        same metric twice in a repetition, without windows or names) is an error."""
        first: dict[str, int] = {}
        for k, st in enumerate(self.out):
            p = st.get("expect") if isinstance(st, dict) and len(st) == 1 else None
            if not isinstance(p, dict):
                continue
            gen = p.pop("_generated_name", False)
            name = p.get("name")
            if not isinstance(name, str) or not self.loc.origin(k).loop:
                continue
            if name in first:
                hint = ("two expectations on this metric in the repetition: give each a "
                        "'name:' or a 'window_s:'" if gen else "give each expectation in the "
                        "repetition its own 'name:'")
                self.issues.append(self.loc.issue(
                    ("steps", k, "expect"), "the same name as the expectation at line "
                    f"{self.loc.line(('steps', first[name]))}; {hint}"))
            else:
                first[name] = k


def expand(doc: dict[str, Any], file: str = "<string>",
           marks: dict[tuple[Any, ...], tuple[int, int]] | None = None,
           overrides: dict[str, Any] | None = None) -> tuple[dict[str, Any], dict[str, float]]:
    """A sequence document with its parameters substituted and its repeats expanded.

    ``params: {name: number}`` defines parameters (``overrides``, ``bench run --set
    name=value``, replace their values); ``${name}`` as a whole value is replaced by the
    number, inside a longer string by its text (``"fast_${v}"``). Substituted everywhere
    but in ``params``. A step ``{repeat: {for: v, in: [values], steps: [...]}}`` is
    replaced by its steps once per value, with ``${v}`` the value; repeats nest. In a
    repetition, an ``expect``'s ``window_s`` is counted from the start of the
    repetition (without one: ``[settle_s, evaluation]`` from that start) and its name
    gets ``@v=value`` (``position_error_rms_rad@v=0.2``).

    Returns
    -------
    (dict, dict)
        The expanded document (``repeat`` steps replaced; ``params`` kept) and the
        parameters' values used.

    Raises
    ------
    SequenceError
        Unknown references or ``--set`` names, malformed repeats, duplicate
        expectation names, more than :data:`MAX_STEPS` steps.
    """
    loc = _Locator(file, marks or {})
    doc, params, _, issues = _expand(doc, loc, overrides or {})
    if issues:
        raise SequenceError(issues)
    return doc, params


def _expand(doc: dict[str, Any], loc: _Locator, overrides: dict[str, Any]
            ) -> tuple[dict[str, Any], dict[str, float], dict[str, float], list[Issue]]:
    ex = _Expander(copy.deepcopy(doc), loc, overrides)
    ex.run()
    return ex.doc, ex.params, ex.overrides, ex.issues


def _schema_issues(validator: jsonschema.Draft202012Validator, instance: Any,
                   make: Any) -> list[Issue]:
    """Schema errors as issues; ``make(path, message)`` places them."""
    issues: list[Issue] = []
    for err in sorted(validator.iter_errors(instance), key=lambda e: list(map(str, e.path))):
        for e in _best_errors(err):
            path = tuple(e.absolute_path)
            if e.validator == "additionalProperties" and isinstance(e.instance, dict):
                allowed = set(e.schema.get("properties", {}))
                for extra in sorted(set(e.instance) - allowed, key=str):
                    issues.append(make(path + (extra,),
                                       f"unknown field; allowed: {', '.join(sorted(allowed))}"))
                continue
            if e.validator == "required" and isinstance(e.instance, dict):
                missing = [r for r in e.validator_value if r not in e.instance]
                # one error per missing key (duplicates are dropped below)
                for r in missing or [None]:
                    iss = make(path, f"{r!r} is a required property" if r else e.message)
                    if r:
                        iss = Issue(iss.file, iss.line, iss.column,
                                    _join_field(iss.field, r), iss.message)
                    issues.append(iss)
                continue
            if "propertyNames" in e.schema_path and path[:1] == ("steps",):
                issues.append(make(path + (e.instance,), f"unknown step {e.instance!r}; "
                                                         f"allowed: {', '.join(STEP_KINDS)}"))
                continue
            if "propertyNames" in e.schema_path:
                issues.append(make(path + (e.instance,), f"{e.instance!r}: a name is letters, "
                                                         "digits and _, not starting with a "
                                                         "digit"))
                continue
            issues.append(make(path, _message(e)))
    return issues


def _join_field(field_: str, key: str) -> str:
    """``steps[3].load_step (v=0.2)`` + ``unit`` -> ``steps[3].load_step.unit (v=0.2)``."""
    base, sep, ctx = field_.partition(" (")
    return (f"{base}.{key}" if base else key) + (sep + ctx if sep else "")


def _check_timing(seq: dict[str, Any], loc: _Locator) -> tuple[list[Issue], list[float], float]:
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
            issues.append(loc.issue(("steps", i, kind),
                                    f"'{kind}' before 'enable': the drive would ignore it"))
        if kind == "trace_capture" and p.get("signals"):
            known = _signal_names()
            for j, sig in enumerate(p["signals"]):
                if known and sig not in known:
                    issues.append(loc.issue(("steps", i, kind, "signals", j),
                                            f"unknown signal {sig!r}; allowed (od.yaml "
                                            f"signals): {', '.join(known)}"))
        if kind in ("wait", "ramp", "load_ramp"):
            t += float(p["duration_s"])
        if kind == "expect" and "window_s" in p:
            t0, t1 = (float(v) for v in p["window_s"])
            path = ("steps", i, kind, "window_s")
            off = loc.origin(i).t_offset
            if off is None:
                if not (math.isfinite(t0) and math.isfinite(t1) and 0 <= t0 < t1):
                    issues.append(loc.issue(path, f"window [{t0}, {t1}] s must satisfy 0 <= "
                                                  "start < end"))
                elif t1 > t + 1e-9:
                    issues.append(loc.issue(path, f"window ends at {t1} s but the expectation "
                                                  f"is evaluated at {t:g} s (sum of the waits "
                                                  "before it)"))
                continue
            r0, r1, now = t0 - off, t1 - off, t - off  # from the start of the repetition
            if not (math.isfinite(t0) and math.isfinite(t1) and -1e-9 <= r0 < r1):
                issues.append(loc.issue(path, f"window [{r0:g}, {r1:g}] s (from the start of "
                                              "the repetition) must satisfy 0 <= start < end"))
            elif t1 > t + 1e-9:
                issues.append(loc.issue(path, f"window ends {r1:g} s after the start of the "
                                              "repetition but the expectation is evaluated "
                                              f"{now:g} s after it (sum of the waits before it "
                                              "in the repetition); in a repeat, window_s "
                                              "counts from the repetition's start"))
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


def _check_values(doc: dict[str, Any], loc: _Locator, starts: list[float],
                  total: float) -> list[Issue]:
    """Finite numbers, the drive's envelope, trace captures that fit and cover their event."""
    issues: list[Issue] = []

    def add(path: tuple[Any, ...], msg: str) -> None:
        issues.append(loc.issue(path, msg))

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
                                            f"s but the '{ev}' it precedes "
                                            f"({loc.field(('steps', nxt))}) is at "
                                            f"{t_ev:g} s; move it closer or lengthen it")
    if not issues and total > MAX_DURATION_S:
        add(("steps",), f"the sequence lasts {total:g} s; allowed up to {MAX_DURATION_S:g} s")
    return issues


def _dedupe(issues: list[Issue]) -> list[Issue]:
    """Each problem once, in order: a mistake in a repeat's steps that is the same in
    every repetition is said once (for the first repetition)."""
    seen: set[tuple[Any, ...]] = set()
    uniq = []
    for i in issues:
        key = (i.line, i.column, i.field.partition(" (")[0], i.message)
        if key not in seen:
            seen.add(key)
            uniq.append(i)
    return uniq


def validate_sequence(text: str, file: str = "<string>",
                      overrides: dict[str, Any] | None = None) -> Sequence:
    """Parse and validate a sequence document.

    Parameters
    ----------
    text : str
        YAML text.
    file : str
        File name used in error messages.
    overrides : dict, optional
        Values for the sequence's ``params`` (``bench run --set name=value``); a name
        the sequence does not define is an error.

    Returns
    -------
    Sequence
        Its steps expanded (:func:`expand`).

    Raises
    ------
    SequenceError
        With every problem found, each naming the file, line and field as written
        (and the loop values of a repetition).
    """
    doc, marks = compose_yaml(text, file)
    if not isinstance(doc, dict):
        raise SequenceError([Issue(file, 1, 1, "", "top level must be a mapping")])
    loc = _Locator(file, marks)
    written = doc
    doc, params, overridden, issues = _expand(doc, loc, dict(overrides or {}))
    where = {(i.line, i.column) for i in issues}
    issues += [i for i in _schema_issues(_VALIDATOR, doc, loc.issue)
               if (i.line, i.column) not in where]  # an unknown ${x} is said once
    if issues:
        raise SequenceError(_dedupe(issues))
    doc["motor"] = written["motor"] = motor_beside(doc["motor"], file)
    t_issues, starts, total = _check_timing(doc, loc)
    t_issues += _check_values(doc, loc, starts, total)
    if t_issues:
        raise SequenceError(_dedupe(t_issues))
    steps = []
    for i, step in enumerate(doc["steps"]):
        (kind, p), = step.items()
        steps.append(Step(kind=kind, params=dict(p or {}), index=i,
                          line=loc.line(("steps", i)), t_start_s=starts[i],
                          loop=dict(loc.origin(i).loop)))
    return Sequence(name=doc["name"], motor=doc["motor"], extractor=doc["extractor"],
                    seed=int(doc["seed"]), steps=steps, path=Path(file),
                    description=doc.get("description", ""),
                    settle_s=float(doc.get("settle_s", 0.15)), x0=doc.get("x0", 0.0),
                    duration_s=total, raw=written, params=params, overrides=overridden,
                    sha256=hashlib.sha256(text.encode("utf-8")).hexdigest())


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


def load_sequence(path: str | Path, overrides: dict[str, Any] | None = None) -> Sequence:
    """Load and validate a sequence file (see :func:`validate_sequence`); ``overrides``:
    values for its ``params`` (``bench run --set``)."""
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
    seq = validate_sequence(text, str(p), overrides)
    seq.path = p
    seq.sha256 = hashlib.sha256(raw).hexdigest()
    return seq
