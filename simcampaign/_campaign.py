"""Campaigns: many simulated-drive runs described by one YAML file.

A campaign file names a base scenario, the axes to vary, the metrics to keep
and limits on their distributions::

    name: mismatch_noise
    base: {scenario: load_step, motor: paper_salient, extractor: sogi_adaptive}
    sampling: {method: lhs, n: 200, seed: 7}       # grid | random | lhs
    axes:
      fw.L_q_H: {scale: [0.8, 1.2]}                # configured value x factor (mismatch)
      plant.adc_noise_counts: {values: [0.5, 1, 2]}
      seed: {range: [0, 1000]}
    metrics: [position_error_rms_rad, position_error_max_rad]
    limits:
      - {metric: position_error_rms_rad, stat: p99, max: 0.03}

Runs are deterministic: run ``k`` of a campaign always gets the same
parameters and seed, so any run can be replayed alone (``replay_command``).
Results are appended to a Parquet dataset (one file per batch) as runs finish:
an interrupted campaign resumes where it stopped and loses no finished run; a
run that raises is recorded with its error, never dropped.
"""

from __future__ import annotations

import contextlib
import functools
import itertools
import json
import math
import os
import re
import shlex
import time
import traceback
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import yaml

from sim_fallback import metrics as SM

SCENARIOS = ("load_step", "speed_reversal", "startup", "linear_load_step", "fault_case")
#: Scenarios in linear units (sim_fallback.linear_scenario_args): the speed loop holds
#: ``speed_mps`` and a load of ``load_N`` (or ``load_rated`` x the motor's rated thrust)
#: steps on at ``base.event_s``.
LINEAR_SCENARIOS = ("linear_load_step",)
#: Axis targets that are plain run arguments (besides plant.<field> and fw.<field>).
DIRECT_TARGETS = ("seed", "noise", "x0_m")
#: ... and those of a linear-units scenario (base keys too).
LINEAR_TARGETS = ("speed_mps", "load_N", "load_rated")
#: What a named axis's case may set (LINEAR_TARGETS too, in a linear-units scenario).
CASE_TARGETS = ("extractor", "noise", "x0_m")
#: Keys of ``base``.
BASE_KEYS = ("scenario", "motor", "extractor", "t_end", "record_decimation", "case",
             "windows", "event_s", "trace", "x0_m") + LINEAR_TARGETS
#: What a linear-units scenario accepts (|value| at most): speeds in m/s, loads in N and
#: in rated thrusts (K_f i_rated_A; a drive holds 2x at its peak current).
LINEAR_MAX = {"speed_mps": 20.0, "load_N": 1.0e5, "load_rated": 10.0}
#: ``base.motor`` and ``base.extractor`` when the file does not give them.
BASE_MOTOR = "paper_salient"
BASE_EXTRACTOR = "sogi_adaptive"
#: Metrics of a fault_case run (sim_fallback.faults.run_case), beside the drive metrics.
FAULT_CASE_METRICS = ("blind_max_s", "rms_rad", "max_rad", "t_fault_s", "pwm_off_after_s",
                      "verdict_ok")
METHODS = ("grid", "random", "lhs")
STATS = ("mean", "max", "min", "p50", "p90", "p95", "p99", "fail_fraction")


class CampaignError(ValueError):
    """A campaign file is wrong; ``str()`` is one line per problem, file:line: field: what."""


class ResultsError(OSError):
    """A results folder cannot be used (another campaign's results, an unreadable part);
    ``str()`` is one line naming the folder or file."""


class SchedulerError(ValueError):
    """The Dask scheduler given cannot be reached; ``str()`` is one line."""


@dataclass
class Axis:
    """One varied parameter: ``target`` is 'seed', 'noise', 'x0_m', 'plant.<field>' or
    'fw.<field>'; the value is drawn from ``values`` (discrete), ``range``
    [lo, hi] (absolute) or ``scale`` [lo, hi] (times the nominal value)."""

    target: str
    kind: str
    spec: list[Any]
    #: a named axis: target -> expression of its value x (kind "values"), or
    #: case label -> {target: value} (kind "cases")
    sets: dict[str, str] | None = None
    cases: dict[str, dict[str, Any]] | None = None

    def value(self, u: float) -> Any:
        """Map u in [0, 1) to this axis's value."""
        if self.kind in ("values", "cases"):
            v = self.spec[min(int(u * len(self.spec)), len(self.spec) - 1)]
            return v if isinstance(v, str) else float(v)
        lo, hi = self.spec
        v = lo + (hi - lo) * u
        return float(int(v)) if self.target == "seed" else float(v)

    def targets(self) -> list[str]:
        """What this axis sets in a run (a named axis: every target it sets)."""
        if self.sets is not None:
            return list(self.sets)
        if self.cases is not None:
            return list(dict.fromkeys(t for c in self.cases.values() for t in c))
        return [self.target]

    def grid_size(self) -> int:
        """len(self.grid()), without building it (a seed range may be huge)."""
        if self.kind in ("values", "cases"):
            return len(self.spec)
        return max(0, int(self.spec[1]) - int(self.spec[0])) if self.target == "seed" else 5

    def grid(self) -> list[Any]:
        if self.kind in ("values", "cases"):
            return [x if isinstance(x, str) else float(x) for x in self.spec]
        lo, hi = self.spec
        if self.target == "seed":
            return [float(x) for x in range(int(lo), int(hi))]
        return [float(x) for x in np.linspace(lo, hi, 5)]


@dataclass
class Limit:
    metric: str
    stat: str
    max: float | None = None
    min: float | None = None


@dataclass
class Campaign:
    name: str
    path: Path | None
    base: dict[str, Any]
    method: str
    n: int
    sampling_seed: int
    axes: list[Axis]
    metrics: list[str]
    limits: list[Limit] = field(default_factory=list)
    title: str = ""

    def run_base(self) -> dict[str, Any]:
        """The base a worker gets: the file's base plus which axes scale their nominal
        value (``_scales``) and the named axes' targets (``_named``)."""
        base = dict(self.base)
        base["_scales"] = {a.target: a.kind == "scale" for a in self.axes}
        base["_named"] = {a.target: (["set", a.sets] if a.sets is not None else
                                     ["cases", a.cases]) for a in self.axes
                          if a.sets is not None or a.cases is not None}
        return base

    def runs(self) -> list[dict[str, Any]]:
        """Every run's parameters, deterministic in the file alone."""
        out: list[dict[str, Any]] = []
        if self.method == "grid":
            for combo in itertools.product(*[a.grid() for a in self.axes]):
                out.append(dict(zip([a.target for a in self.axes], combo, strict=True)))
        else:
            rng = np.random.default_rng(self.sampling_seed)
            d = len(self.axes)
            if self.method == "random":
                u = rng.random((self.n, d))
            else:  # Latin hypercube: one sample per stratum and axis
                u = (np.argsort(rng.random((d, self.n)), axis=1).T + rng.random((self.n, d)))
                u = u / self.n
            for row in u:
                out.append({a.target: a.value(float(x)) for a, x in zip(self.axes, row,
                                                                         strict=True)})
        for k, r in enumerate(out):
            r["run"] = k
            # a seed is an integer (what the run uses: int(seed)), shown as one: 96707,
            # not 96707.0 or 9.671e+04
            r["seed"] = int(r.get("seed", k))
        return out


# ---- loading -----------------------------------------------------------------


def _line(node: yaml.Node | None) -> int:
    return (node.start_mark.line + 1) if node is not None else 0


def _find(node: yaml.MappingNode, key: str) -> yaml.Node | None:
    for k, v in node.value:
        if isinstance(k, yaml.ScalarNode) and k.value == key:
            return v
    return None


def _finite(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*$")
_FACTOR = re.compile(r"(?:x(?:\^(\d+))?|(plant\.[A-Za-z0-9_]+)|([-+]?(?:\d+\.?\d*|\.\d+)"
                     r"(?:[eE][-+]?\d+)?))$")


def _valid_extractor(v: Any) -> bool:
    from bench import EXTRACTORS
    return v in EXTRACTORS


@functools.lru_cache(maxsize=32)
def _motor_loaded(name: str) -> tuple[dict[str, Any] | None, str]:
    """(plant parameters, "") or (None, why the motor file cannot be loaded; "" when
    there is no such motor). The plant parameters include the plant realism ones
    (``sim_realism_t``: cross_L_H, emf_h5, ...), which run_scenario's ``plant`` sets too."""
    from sim_fallback import load_motor
    try:
        return _all_plant(load_motor(name)), ""
    except FileNotFoundError:
        return None, ""
    except Exception as e:  # noqa: BLE001 - MotorFileError, TOML errors: said, one line
        return None, (str(e).splitlines() or [type(e).__name__])[0]


def _all_plant(motor: Any) -> dict[str, Any]:
    """A motor's nominal plant parameters: ``sim_plant_params_t``'s and the plant
    realism's (``sim_realism_t``)."""
    return {**motor.plant, **motor.realism}


def _motor_plant(name: Any) -> dict[str, Any] | None:
    """The motor file's plant parameters (nominal), or None if it is not a motor."""
    return _motor_loaded(name)[0] if isinstance(name, str) and _NAME.match(name) else None


def _motor_why(name: Any) -> str:
    """Why ``name`` is not a usable motor, in words."""
    broken = _motor_loaded(name)[1] if isinstance(name, str) and _NAME.match(name) else ""
    return (f"{name!r}: its motor file cannot be loaded: {broken}" if broken else
            f"{name!r}: need one of {_choices('motor')}")


def _choices(what: str) -> str:
    if what == "extractor":
        from bench import EXTRACTORS
        return ", ".join(EXTRACTORS)
    from sim_fallback import MOTOR_DIR
    return "motor names (" + ", ".join(sorted(f.stem for f in Path(MOTOR_DIR).glob("*.toml"))) \
        + ")"


def _is_field(t: Any) -> bool:
    return isinstance(t, str) and t.startswith(("plant.", "fw.")) and bool(
        _NAME.match(t.partition(".")[2]))


def _field_error(t: str, plant: dict[str, Any] | None) -> str | None:
    """Why ``plant.<f>`` / ``fw.<f>`` names no parameter (None: it does)."""
    kind, _, f = t.partition(".")
    if kind == "plant" and plant is not None and f not in plant:
        return f"no plant parameter {f!r} (sim_plant_params_t, sim_realism_t; docs/simulator.md)"
    if kind == "fw":
        from sim_fallback import FwConfig
        if f not in FwConfig.field_names():
            return f"no drive configuration field {f!r} (fw_config_t; docs/firmware.md)"
    return None


def _value_error(t: str, kind: str, vals: list[float], motor: Any, extractor: Any
                 ) -> str | None:
    """Why an axis's values leave what its target accepts (None: they do not): noise
    is a scale >= 0, x0_m the simulator's initial positions (X0_MAX_M), plant.<field>
    the motor files' range of that field and what the simulator then accepts
    (_plant_value_error), fw.<field> the firmware's own range (fw_config_field(); a
    scale times the motor's nominal configuration)."""
    lo_hi = [min(vals), max(vals)]
    if t in LINEAR_MAX and max(abs(lo_hi[0]), abs(lo_hi[1])) > LINEAR_MAX[t]:
        return f"{_span(lo_hi)}: allowed [{-LINEAR_MAX[t]:g}, {LINEAR_MAX[t]:g}]" + (
            " m/s" if t == "speed_mps" else " N" if t == "load_N" else
            " x the motor's rated thrust")
    if t == "noise" and lo_hi[0] < 0:
        return f"{lo_hi[0]:g}: noise scales the sensor noise; allowed >= 0"
    if t == "x0_m":
        from sim_fallback import X0_MAX_M
        if lo_hi[0] < -X0_MAX_M or lo_hi[1] > X0_MAX_M:
            return f"{_span(lo_hi)}; the simulator allows {_allowed('x0_m', motor)}"
        return None
    if t.startswith("plant."):
        return _plant_value_error(t[6:], kind, vals, motor)
    if not t.startswith("fw."):
        return None
    from sim_fallback import firmware_field_ranges
    f = t[3:]
    rng = firmware_field_ranges().get(f)
    if rng is None:
        return None
    lo, hi, unit = rng
    if _fw_is_int(f) and (kind == "range" or (kind == "values"
                                              and not all(float(v).is_integer()
                                                          for v in vals))):
        return (f"{_span(sorted(vals))}: an integer field; need values: [...] of integers "
                f"in [{lo:g}, {hi:g}]")
    if kind == "scale":
        if _motor_plant(motor) is None or not _valid_extractor(extractor):
            return None  # reported on base
        nominal = float(getattr(_motor_and_config(motor, extractor)[1], f))
        if nominal == 0:
            return None
        lo_hi = sorted(x * nominal for x in lo_hi)
        what = f"x {nominal:g} (nominal) gives [{lo_hi[0]:g}, {lo_hi[1]:g}]"
    else:
        what = f"[{lo_hi[0]:g}, {lo_hi[1]:g}]"
    # the firmware's limits are float32: a bound written as such passes
    if lo_hi[0] < lo * (1 - 1e-6) or lo_hi[1] > hi * (1 + 1e-6):
        return f"{what}; the firmware allows [{lo:g}, {hi:g}]" + (f" {unit}" if unit else "")
    return None


def _span(xs: list[float]) -> str:
    """Sorted values as '[lo, hi]', or the one value."""
    return f"{xs[0]:g}" if xs[0] == xs[-1] else f"[{xs[0]:g}, {xs[-1]:g}]"


def _allowed(t: str, motor: Any) -> str | None:
    """What the simulator allows for x0_m or plant.<field> ('[lo, hi] unit'), else None."""
    if t == "x0_m":
        from sim_fallback import X0_MAX_M
        return f"initial positions [{-X0_MAX_M:g}, {X0_MAX_M:g}] m"
    if not t.startswith("plant.") or _motor_plant(motor) is None:
        return None
    from sim_fallback import plant_field_range
    rng = plant_field_range(t[6:])
    return None if rng is None else f"[{rng[0]:g}, {rng[1]:g}]" + (
        f" {rng[2]}" if rng[2] else "")


def _plant_value_error(f: str, kind: str, vals: list[float], motor: Any) -> str | None:
    """Why values of ``plant.<f>`` (absolute, or with kind "scale" times the motor's
    nominal value) leave what the simulator accepts (None: they do not): the range of
    the motor-file field it comes from (sim_fallback plant_field_range, the one table
    load_motor checks files against), integers for integer fields, then each end with
    the motor's other parameters through the simulator's own sim_params_check."""
    from sim_fallback import (
        PLANT_FIELD_SOURCES,
        plant_field_range,
        plant_params,
        plant_params_refused,
        realism_params,
        realism_refused,
        split_plant_overrides,
    )
    plant = _motor_plant(motor)
    if plant is None or f not in plant:
        return None  # reported on base / by _field_error
    rng = plant_field_range(f)
    if rng is None:
        return (f"has no allowed range (not a motor-file field), so no axis sets it; "
                f"plant fields an axis can set: {', '.join(PLANT_FIELD_SOURCES)}")
    nominal = plant[f]
    if isinstance(nominal, list):
        return (f"is one value per phase ({len(nominal)}), which an axis's single number "
                "cannot set (noise scales the offsets)")
    lo, hi, _ = rng
    allowed = _allowed("plant." + f, motor)
    xs = sorted(float(v) * float(nominal) if kind == "scale" else float(v) for v in vals)
    what = (f"x {nominal:g} (nominal) gives {_span(xs)}" if kind == "scale" else _span(xs))
    if xs[0] < lo or xs[-1] > hi:
        return f"{what}; the simulator allows {allowed}"
    if isinstance(nominal, int) and (kind == "range" or not all(x.is_integer() for x in xs)):
        return f"{what}: an integer field; need values: [...] of integers in {allowed}"
    try:
        mot = _motor_and_config(motor, BASE_EXTRACTOR)[0]
        for x in (xs[0], xs[-1]):
            ov, real = split_plant_overrides({f: int(x) if isinstance(nominal, int) else x})
            pp = plant_params(mot, **ov)
            bad = plant_params_refused(pp) or realism_refused(pp, realism_params(mot, **real))
            if bad is not None:
                return (f"{x:g} with motor {motor}'s other plant parameters: the simulator "
                        f"refuses {bad} (sim_params_check: dL_sat_H < L_d0_H, F_coulomb_N "
                        "<= F_static_N, udc_fullscale_V > u_dc_V, dead_time_s < 0.2 / "
                        "f_pwm_Hz)")
    except OSError:  # no simulator library here: the runs will say
        pass
    return None


def parse_expr(expr: Any) -> list[tuple[str, Any]] | None:
    """A named axis's ``set`` expression: a product of factors, each a number, ``x``
    (the axis value), ``x^N`` or ``plant.<field>`` (the motor file's nominal value),
    evaluated left to right. None if malformed."""
    if isinstance(expr, (int, float)) and not isinstance(expr, bool):
        expr = str(expr)
    if not isinstance(expr, str) or not expr.strip():
        return None
    out: list[tuple[str, Any]] = []
    for f in expr.split("*"):
        m = _FACTOR.match(f.strip())
        if m is None:
            return None
        if m.group(2):
            out.append(("plant", m.group(2)[6:]))
        elif m.group(3):
            out.append(("num", float(m.group(3))))
        else:
            out.append(("x", int(m.group(1) or 1)))
    return out


def eval_expr(expr: str, x: float, plant: dict[str, Any]) -> float:
    """Value of a ``set`` expression for axis value ``x`` (see :func:`parse_expr`)."""
    acc: float | None = None
    for kind, v in parse_expr(expr) or []:
        try:
            f = float(plant[v]) if kind == "plant" else v if kind == "num" else float(x) ** v
        except OverflowError:  # x^400: not a number the drive could take (checked after)
            return math.inf
        acc = f if acc is None else acc * f
    return float(acc if acc is not None else "nan")


def _node_at(node: yaml.Node | None, path: str) -> yaml.Node | None:
    """The deepest node along a dotted path of mapping keys (labels and targets may hold
    dots: the longest key that matches is taken)."""
    while path and isinstance(node, yaml.MappingNode):
        for k, v in node.value:
            key = str(k.value)
            if path == key or path.startswith(key + "."):
                node, path = v, path[len(key) + 1:]
                break
        else:
            break
    return node


def _is_named_axis(tgt: Any, spec: Any) -> bool:
    return (isinstance(tgt, str) and bool(_NAME.match(tgt)) and tgt not in DIRECT_TARGETS
            and tgt not in LINEAR_TARGETS
            and isinstance(spec, dict) and ("set" in spec or "cases" in spec))


def _parse_named_axis(name: str, spec: dict[str, Any], plant: dict[str, Any] | None,
                      err: Callable[[str, str], None], motor: Any = BASE_MOTOR,
                      extractor: Any = BASE_EXTRACTOR, scenario: Any = "load_step"
                      ) -> Axis | None:
    """``name: {values: [...], set: {target: expr}}`` or ``name: {cases: {label: {...}}}``;
    the values a case or an expression gives are checked as an axis's (_value_error)."""
    fld = f"axes.{name}"
    if "cases" in spec:
        cases = spec["cases"]
        if set(spec) != {"cases"} or not isinstance(cases, dict) or not cases:
            err(fld, "cases: need a non-empty mapping label: {target: value, ...} (and "
                "nothing else)")
            return None
        ok = True
        for label, sets in cases.items():
            cf = f"{fld}.cases.{label}"
            if not isinstance(sets, dict):
                err(cf, "need a mapping target: value ({} for the nominal run)")
                ok = False
                continue
            for t, v in sets.items():
                if t == "extractor":
                    good = _valid_extractor(v)
                    why = None if good else f"{v!r} not one of {_choices('extractor')}"
                elif t in LINEAR_TARGETS and scenario not in LINEAR_SCENARIOS:
                    why = _LINEAR_ONLY
                elif t in CASE_TARGETS or t in LINEAR_TARGETS or _is_field(t):
                    rng = _allowed(str(t), motor)
                    why = (_field_error(t, plant) if _is_field(t) else None) or (
                        None if _finite(v) else f"{v!r}: need a finite number" + (
                            f"; the simulator allows {rng}" if rng else "")) or \
                        _value_error(t, "values", [float(v)], motor, extractor)
                else:
                    why = ("target must be extractor, noise, x0_m, plant.<field> or "
                           f"fw.<field> ({', '.join(LINEAR_TARGETS)} with base.scenario: "
                           f"{' or '.join(LINEAR_SCENARIOS)})")
                if why:
                    err(f"{cf}.{t}", why)
                    ok = False
        return Axis(name, "cases", [str(k) for k in cases],
                    cases={str(k): dict(v) for k, v in cases.items()}) if ok else None
    vals, sets = spec.get("values"), spec.get("set")
    if set(spec) != {"values", "set"}:
        err(fld, "a named axis needs values: [...] and set: {target: expression} (or cases)")
        return None
    if not isinstance(vals, list) or not vals or not all(_finite(v) for v in vals):
        err(fld, "values must be a non-empty list of finite numbers")
        return None
    if not isinstance(sets, dict) or not sets:
        err(fld, "set: need a mapping target: expression")
        return None
    ok = True
    for t, expr in sets.items():
        why = (_field_error(t, plant) if _is_field(t) else
               "target must be plant.<field> or fw.<field>")
        factors = parse_expr(expr)
        if why is None and factors is None:
            why = (f"{expr!r}: need a product of numbers, x, x^N and plant.<field>, "
                   "e.g. 1100 * plant.L_d0_H * x")
        bad = [v for k, v in factors or [] if k == "plant" and plant is not None
               and v not in plant]
        if why is None and bad:
            why = f"no plant parameter {bad[0]!r} in the expression"
        if why is None and plant is not None:
            got = [eval_expr(str(expr), float(x), plant) for x in vals]
            verr = ("a non-finite value" if not all(map(math.isfinite, got)) else
                    _value_error(t, "values", got, motor, extractor))
            why = f"{expr!r} gives {verr}" if verr else None
        if why:
            err(f"{fld}.set.{t}", why)
            ok = False
    return Axis(name, "values", [float(v) for v in vals], sets={str(k): str(v) for k, v
                                                                  in sets.items()}) if ok \
        else None


_LINEAR_ONLY = ("a linear-units scenario's argument; needs base.scenario: "
                + " or ".join(LINEAR_SCENARIOS))


def _check_base(base: dict[str, Any], bnode: yaml.Node | None, sc: str,
                err: Callable[[yaml.Node | None, str, str], None]
                ) -> tuple[dict[str, Any] | None, dict[str, list[float]], float | None]:
    """Validate ``base``; returns the motor's plant parameters, the windows and event_s."""
    def node(key: str) -> yaml.Node | None:
        return (_find(bnode, key) or bnode) if isinstance(bnode, yaml.MappingNode) else bnode

    for k in base:
        if k not in BASE_KEYS:
            err(node(k), f"base.{k}", f"unknown; known: {', '.join(BASE_KEYS)}")
    plant = None
    base_motor = base.get("motor", BASE_MOTOR)
    if sc != "fault_case":
        plant = _motor_plant(base_motor)
        if plant is None:
            err(node("motor"), "base.motor", _motor_why(base_motor))
        if "extractor" in base and not _valid_extractor(base["extractor"]):
            err(node("extractor"), "base.extractor",
                f"{base['extractor']!r} not one of {_choices('extractor')}")
    t_end = base.get("t_end", 1.0)
    if not _finite(t_end) or not 0 < t_end <= 3600:
        err(node("t_end"), "base.t_end", f"{t_end!r}: need a number in (0, 3600] s")
        t_end = 1.0
    dec = base.get("record_decimation", 8)
    if not isinstance(dec, int) or isinstance(dec, bool) or not 1 <= dec <= 10_000:
        err(node("record_decimation"), "base.record_decimation",
            f"{dec!r}: need an integer in [1, 10000]")
    windows: dict[str, list[float]] = {}
    raw = base.get("windows", {})
    if not isinstance(raw, dict):
        err(node("windows"), "base.windows", "need a mapping name: [t0, t1] (s)")
        raw = {}
    for w, span in raw.items():
        if not (isinstance(w, str) and _NAME.match(w)):
            err(node("windows"), f"base.windows.{w}", "name must be an identifier")
        elif (not isinstance(span, list) or len(span) != 2 or not all(_finite(x) for x in span)
              or not 0 <= span[0] < span[1] <= t_end):
            err(node("windows"), f"base.windows.{w}",
                f"{span!r}: need [t0, t1] with 0 <= t0 < t1 <= t_end ({t_end:g} s)")
        else:
            windows[w] = [float(span[0]), float(span[1])]
    event_s = base.get("event_s")
    if event_s is not None and not (_finite(event_s) and 0 <= event_s < t_end):
        err(node("event_s"), "base.event_s", f"{event_s!r}: need a time in [0, t_end) s")
        event_s = None
    for k in LINEAR_TARGETS:
        if k not in base:
            continue
        v = base[k]
        if sc not in LINEAR_SCENARIOS:
            err(node(k), f"base.{k}", _LINEAR_ONLY)
        elif not _finite(v):
            err(node(k), f"base.{k}", f"{v!r}: need a finite number")
        else:
            why = _value_error(k, "values", [float(v)], base_motor, None)
            if why:
                err(node(k), f"base.{k}", why)
    x0 = base.get("x0_m")
    if x0 is not None and x0 != "random":
        from sim_fallback import X0_MAX_M
        if not (_finite(x0) and abs(x0) <= X0_MAX_M):
            err(node("x0_m"), "base.x0_m", f"{x0!r}: need random or an initial position in "
                f"[{-X0_MAX_M:g}, {X0_MAX_M:g}] m")
    tr = base.get("trace")
    if tr is not None:
        sig = tr.get("signals") if isinstance(tr, dict) else None
        dec_t = tr.get("decimation", 8) if isinstance(tr, dict) else None
        seeds = tr.get("seeds") if isinstance(tr, dict) else None
        if (not isinstance(tr, dict) or set(tr) - {"signals", "decimation", "seeds"}
                or not isinstance(sig, list) or not sig
                or any(x not in SM.TRACE_SIGNALS for x in sig)):
            err(node("trace"), "base.trace", "need {signals: [...], decimation: N, seeds: "
                f"[...]}} with signals from {', '.join(SM.TRACE_SIGNALS)}")
        elif not isinstance(dec_t, int) or isinstance(dec_t, bool) or not 1 <= dec_t <= 10_000:
            err(node("trace"), "base.trace.decimation", f"{dec_t!r}: need an integer in "
                "[1, 10000]")
        elif seeds is not None and (not isinstance(seeds, list) or not all(
                isinstance(x, int) and not isinstance(x, bool) for x in seeds)):
            err(node("trace"), "base.trace.seeds", "need a list of integer seeds (or leave "
                "it out: every run)")
    return plant, windows, (float(event_s) if event_s is not None else None)


def load_campaign(path: str | Path, metric_names: Iterable[str] | None = None) -> Campaign:
    """Read and validate a campaign file. Raises CampaignError naming file:line: field.
    Read as sequence files are (bench.compose_yaml: YAML errors and duplicate keys with
    their line, no aliases, YAML 1.2 numbers such as 1e-3)."""
    from bench import SequenceError, SequenceLoader, compose_yaml
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise CampaignError(f"{p}: cannot read campaign file: {e}") from None
    try:
        data, _ = compose_yaml(text, str(p))
        root = yaml.compose(text, Loader=SequenceLoader)
    except SequenceError as e:
        raise CampaignError("\n".join(str(i) for i in e.issues)) from None
    return parse_campaign(data, root, p, metric_names)


#: The local cluster's largest --workers per core: a run is CPU-bound and a worker holds
#: ~150 MiB, so more worker processes than this only compete for the cores and memory.
WORKERS_PER_CORE = 4


def max_local_workers() -> int:
    """The largest --workers for a local cluster on this machine."""
    return WORKERS_PER_CORE * (os.cpu_count() or 1)


#: At most this many runs in a campaign (a grid's product or sampling.n): the run list
#: is built in memory (~0.5 kB a run) before anything starts.
MAX_RUNS = 1_000_000
_NUMBER = {"type": "number"}
#: The campaign file's shape (jsonschema); the values are checked in parse_campaign.
SHAPE_SCHEMA: dict[str, Any] = {
    "type": "object", "additionalProperties": False,
    "required": ["name", "base", "axes", "metrics"],
    "properties": {
        "name": {"type": "string", "pattern": r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,99}$"},
        "title": {"type": "string"},
        "base": {"type": "object"},
        "sampling": {"type": "object", "additionalProperties": False, "properties": {
            "method": {"enum": list(METHODS)},
            "n": {"type": "integer", "minimum": 1, "maximum": MAX_RUNS},
            "seed": {"type": "integer", "minimum": 0, "maximum": 2**63 - 1}}},
        "axes": {"type": "object", "minProperties": 1,
                 "additionalProperties": {"type": "object", "minProperties": 1}},
        "metrics": {"type": "array", "minItems": 1, "uniqueItems": True,
                    "items": {"type": "string"}},
        "limits": {"type": "array", "items": {
            "type": "object", "additionalProperties": False, "required": ["metric", "stat"],
            "properties": {"metric": {"type": "string"}, "stat": {"enum": list(STATS)},
                           "min": _NUMBER, "max": _NUMBER}}},
    }}
_SHAPE = jsonschema.Draft202012Validator(SHAPE_SCHEMA)
#: Clearer words than jsonschema's for a wrong field (by its path).
_SHAPE_HINTS = {
    ("name",): "need a name of letters, digits, '_', '.' and '-' (the results folder "
               "runs/campaigns/<name>/), not starting with '.' or '-', at most 100 characters",
    ("sampling", "n"): f"need an integer in [1, {MAX_RUNS}]",
    ("sampling", "seed"): "need an integer >= 0",
    ("axes",): "need a non-empty mapping of parameter: {values|range|scale}",
    ("metrics",): "need a non-empty list of distinct metric names",
    ("limits",): "need a list of {metric, stat, min and/or max}",
}


def _node_path(root: yaml.Node | None, path: list[Any]) -> yaml.Node | None:
    """The YAML node at a path of mapping keys and list indexes (the deepest found)."""
    node = root
    for key in path:
        if isinstance(node, yaml.MappingNode):
            nxt = _find(node, str(key))
        elif isinstance(node, yaml.SequenceNode) and isinstance(key, int) \
                and key < len(node.value):
            nxt = node.value[key]
        else:
            nxt = None
        if nxt is None:
            break
        node = nxt
    return node


def _dotted(path: list[Any]) -> str:
    out = ""
    for k in path:
        out += f"[{k}]" if isinstance(k, int) else (f".{k}" if out else str(k))
    return out


def parse_campaign(data: Any, root: yaml.Node | None, p: Path | None,
                   metric_names: Iterable[str] | None = None) -> Campaign:
    errs: list[str] = []
    where = str(p) if p else "<campaign>"

    def err(node: yaml.Node | None, fld: str, msg: str) -> None:
        errs.append(f"{where}:{_line(node)}: {fld}: {msg}")

    if not isinstance(data, dict) or not isinstance(root, yaml.MappingNode):
        raise CampaignError(f"{where}:1: (top level): must be a mapping with name, base, axes")
    # the file's shape first (keys, types, counts): the checks below assume it
    for e in sorted(_SHAPE.iter_errors(data), key=lambda e: [str(x) for x in e.path]):
        path = list(e.absolute_path)
        if e.validator == "additionalProperties":
            extra = sorted(set(e.instance) - set(e.schema.get("properties", {})))
            for k in extra:
                err(_node_path(root, path + [k]), _dotted(path + [k]),
                    f"unknown key; known: {', '.join(e.schema['properties'])}")
            continue
        err(_node_path(root, path), _dotted(path) or "(top level)",
            _SHAPE_HINTS.get(tuple(path), e.message))
    if errs:
        raise CampaignError("\n".join(errs))
    base = data.get("base", {})
    bnode = _find(root, "base")
    if not isinstance(base, dict):
        err(bnode, "base", "must be a mapping")
        base = {}
    sc = base.get("scenario", "load_step")
    if sc not in SCENARIOS:
        err(bnode, "base.scenario", f"{sc!r} not one of {', '.join(SCENARIOS)}")
    case_names: list[str] = []
    if sc == "fault_case":
        from sim_fallback.faults import CASES
        names = case_names = [c.name for c in CASES]
        if "case" not in data.get("axes", {}) and base.get("case") not in names:
            err(bnode, "base.case", f"{base.get('case')!r} is not a fault case ({len(names)} "
                "listed in docs/fault_matrix.md)")
    motor_plant, windows, event_s = _check_base(base, bnode, sc, err)
    base_motor = base.get("motor", BASE_MOTOR)
    base_extractor = base.get("extractor", BASE_EXTRACTOR)
    samp = data.get("sampling", {"method": "grid"})
    snode = _find(root, "sampling")
    method = samp.get("method", "grid") if isinstance(samp, dict) else None
    if method not in METHODS:
        err(snode, "sampling.method", f"{method!r} not one of {', '.join(METHODS)}")
    n = samp.get("n", 0) if isinstance(samp, dict) else 0
    if method in ("random", "lhs") and "n" not in samp:
        err(snode, "sampling.n", f"missing: {method} sampling needs n, an integer in "
            f"[1, {MAX_RUNS}]")
    sseed = samp.get("seed", 0) if isinstance(samp, dict) else 0
    axes: list[Axis] = []
    anode = _find(root, "axes")
    raw_axes = data.get("axes", {})
    if not isinstance(raw_axes, dict) or not raw_axes:
        err(anode, "axes", "need a non-empty mapping of parameter: {values|range|scale}")
        raw_axes = {}
    for tgt, spec in raw_axes.items():
        node = _find(anode, str(tgt)) if isinstance(anode, yaml.MappingNode) else anode
        fld = f"axes.{tgt}"
        if tgt == "case":  # rows of the fault-injection matrix
            vals = spec.get("values") if isinstance(spec, dict) else None
            vals = case_names if vals == "all" else vals
            if sc != "fault_case":
                err(node, fld, "a case axis needs base.scenario: fault_case")
            elif not isinstance(vals, list) or not vals or any(v not in case_names
                                                               for v in vals):
                err(node, fld, "values: all, or a list of fault-case names "
                    "(docs/fault_matrix.md)")
            else:
                axes.append(Axis("case", "values", list(vals)))
            continue
        if tgt in ("extractor", "motor"):  # string-valued axes
            vals = spec.get("values") if isinstance(spec, dict) and len(spec) == 1 else None
            bad = (None if not isinstance(vals, list) or not vals else
                   [v for v in vals if not (_valid_extractor(v) if tgt == "extractor"
                                            else _motor_plant(v) is not None)])
            if bad and tgt == "motor" and "cannot be loaded" in _motor_why(bad[0]):
                err(node, fld, "values: " + _motor_why(bad[0]))
            elif bad is None or bad:
                err(node, fld, f"need values: [...] of {_choices(tgt)}"
                    + (f"; {bad[0]!r} is not one" if bad else ""))
            else:
                axes.append(Axis(str(tgt), "values", list(vals)))
            continue
        if _is_named_axis(tgt, spec):
            ax = _parse_named_axis(str(tgt), spec, motor_plant,
                                   lambda f, m, n=node, t=str(tgt):
                                   err(_node_at(n, f[len("axes." + t) + 1:]), f, m),
                                   base_motor, base_extractor, sc)
            if ax is not None:
                axes.append(ax)
            continue
        if tgt in LINEAR_TARGETS and sc not in LINEAR_SCENARIOS:
            err(node, fld, _LINEAR_ONLY)
            continue
        ok_target = tgt in DIRECT_TARGETS or tgt in LINEAR_TARGETS or _is_field(tgt)
        if not ok_target:
            err(node, fld, "target must be seed, noise, x0_m, case, extractor, motor, "
                "plant.<field> or fw.<field>, or a named axis with values and set, or "
                f"cases ({', '.join(LINEAR_TARGETS)} with base.scenario: "
                f"{' or '.join(LINEAR_SCENARIOS)})")
            continue
        if not isinstance(spec, dict) or len(spec) != 1:
            err(node, fld, "need exactly one of values: [...], range: [lo, hi], "
                "scale: [lo, hi]")
            continue
        kind, vals = next(iter(spec.items()))
        if kind not in ("values", "range", "scale"):
            err(node, fld, f"{kind!r} not one of values, range, scale")
            continue
        if not isinstance(vals, list) or not vals or not all(_finite(v) for v in vals):
            rng = _allowed(str(tgt), base_motor)
            err(node, fld, f"{kind} must be a non-empty list of finite numbers"
                + (f"; the simulator allows {rng}" if rng else ""))
            continue
        if kind in ("range", "scale") and (len(vals) != 2 or not vals[0] < vals[1]):
            err(node, fld, f"{kind} must be [lo, hi] with lo < hi")
            continue
        if kind == "scale" and not str(tgt).startswith(("plant.", "fw.")):
            err(node, fld, "scale applies to plant.<field> and fw.<field> only")
            continue
        if kind == "scale" and vals[0] <= 0:
            err(node, fld, "scale factors must be > 0")
            continue
        why = _field_error(str(tgt), motor_plant) or _value_error(
            str(tgt), kind, vals, base_motor, base_extractor)
        if why:
            err(node, fld, why)
            continue
        axes.append(Axis(str(tgt), kind, [float(v) for v in vals]))
    seen: dict[str, str] = {}
    for ax in axes:
        for t in ax.targets():
            if t in seen:
                err(anode, f"axes.{ax.target}", f"sets {t}, which axis {seen[t]} sets too")
            seen.setdefault(t, ax.target)
    if sc in LINEAR_SCENARIOS:
        if "speed_mps" not in base and "speed_mps" not in seen:
            err(bnode, "base.speed_mps", f"missing: {sc} needs the speed reference (m/s), "
                "in base or on an axis")
        if base.get("event_s") is None:
            err(bnode, "base.event_s", f"missing: {sc} steps its load at event_s (s)")
        loads = {"load_N", "load_rated"}
        options = [[set(c) & loads for c in ax.cases.values()] if ax.cases is not None
                   else [set(ax.targets()) & loads] for ax in axes]
        if any(set().union(base.keys() & loads, *combo) == loads
               for combo in itertools.product(*options)):
            err(bnode, "base.load_N", "give the load as load_N (N) or load_rated (x the "
                "rated thrust), not both (in base or on axes)")
    metrics = data.get("metrics", [])
    mnode = _find(root, "metrics")
    known = set(metric_names) if metric_names is not None else None
    if known is not None and sc == "fault_case":
        known |= set(FAULT_CASE_METRICS)
    elif known is not None:
        known |= set(SM.EVENT_METRICS + SM.STARTUP_METRICS + SM.RUN_METRICS)
    if not isinstance(metrics, list) or not metrics:
        err(mnode, "metrics", "need a non-empty list of metric names")
        metrics = []
    for m in metrics:
        if known is None or m in known or (sc != "fault_case"
                                           and SM.is_window_metric(str(m), windows)):
            if m in SM.EVENT_METRICS and event_s is None:
                err(mnode, "metrics", f"{m} needs base.event_s (the event's time, s)")
            continue
        hint = (f"; or <window>.<{'|'.join(SM.WINDOW_METRICS)}> with a window of "
                f"base.windows ({', '.join(windows) or 'none defined'})"
                if sc != "fault_case" else "")
        err(mnode, "metrics", f"unknown metric {m!r}; known: {', '.join(sorted(known))}"
            + hint)
    limits: list[Limit] = []
    for i, lim in enumerate(data.get("limits", []) or []):
        fld = f"limits[{i}]"
        lnode = _node_path(root, ["limits", i])
        if lim["metric"] not in metrics:
            err(_node_path(root, ["limits", i, "metric"]), f"{fld}.metric",
                f"{lim['metric']!r} is not one of the campaign's metrics "
                f"({', '.join(map(str, metrics))})")
            continue
        if lim.get("stat") not in STATS:
            err(lnode, fld, f"stat {lim.get('stat')!r} not one of {', '.join(STATS)}")
            continue
        lo, hi = lim.get("min"), lim.get("max")
        if (lo is None and hi is None) or any(v is not None and not _finite(v)
                                              for v in (lo, hi)):
            err(lnode, fld, "need a finite min and/or max")
            continue
        limits.append(Limit(lim["metric"], lim["stat"], hi, lo))
    if method == "grid" and axes:
        total = math.prod(a.grid_size() for a in axes)
        if not 1 <= total <= MAX_RUNS:
            err(anode, "axes", f"a grid of {total} runs; allowed 1..{MAX_RUNS} (fewer values, "
                "a shorter seed range, or sampling random or lhs)")
    title = data.get("title", "")
    if not isinstance(title, str):
        err(_find(root, "title"), "title", "must be text")
    if errs:
        raise CampaignError("\n".join(errs))
    return Campaign(str(data["name"]), p, dict(base), method or "grid",
                    int(n) if method != "grid" else 0, int(sseed), axes, list(metrics), limits,
                    str(title))


# ---- one run -----------------------------------------------------------------


def run_one(base: dict[str, Any], params: dict[str, Any],
            metrics: list[str]) -> dict[str, Any]:
    """Run one simulated-drive case; never raises (the error is recorded)."""
    row: dict[str, Any] = {"run": int(params["run"]), "params": json.dumps(params),
                           "error": None, "fault": 0}
    t0 = time.perf_counter()
    try:
        row.update(_simulate(base, params, metrics))
    except Exception as e:  # noqa: BLE001 - recorded, never dropped
        row = failed_row(params, metrics, f"{type(e).__name__}: {e}",
                         traceback.format_exc(limit=5))
    row["wall_s"] = time.perf_counter() - t0
    return row


def failed_row(params: dict[str, Any], metrics: list[str], error: str,
               tb: str | None = None) -> dict[str, Any]:
    """The row of a run that did not finish: its error, every metric NaN."""
    row: dict[str, Any] = {"run": int(params["run"]), "params": json.dumps(params),
                           "error": error, "fault": 0}
    if tb is not None:
        row["traceback"] = tb
    row.update({m: float("nan") for m in metrics})
    row["wall_s"] = float("nan")
    return row


def run_chunk(base: dict[str, Any], chunk: list[dict[str, Any]], metrics: list[str],
              out: str | None = None, batch: int = 64) -> list[dict[str, Any]] | int:
    """Several runs in one task: a run costs milliseconds, a task's round trip
    through the scheduler about as much, so tasks carry chunks of runs (_chunks).
    ``out``: a results folder this worker can write (a local cluster's): the rows go
    there in parts of ``batch`` as they finish (:func:`_write_part`) and the task
    returns only how many runs it wrote, instead of the rows."""
    if out is None:
        return [run_one(base, p, metrics) for p in chunk]
    rdir, buf = Path(out), []
    for p in chunk:
        buf.append(run_one(base, p, metrics))
        if len(buf) >= batch:
            _write_part(rdir, buf)
            buf = []
    if buf:
        _write_part(rdir, buf)
    return len(chunk)


def _split(params: dict[str, Any]) -> tuple[dict[str, float], dict[str, float], dict[str, Any]]:
    plant = {k[6:]: v for k, v in params.items() if k.startswith("plant.")}
    fw = {k[3:]: v for k, v in params.items() if k.startswith("fw.")}
    rest = {k: v for k, v in params.items() if "." not in k and k not in ("run", "case")}
    return plant, fw, rest


def _expand(base: dict[str, Any], params: dict[str, Any],
            plant: dict[str, Any]) -> dict[str, Any]:
    """A run's parameters with each named axis replaced by the targets it sets."""
    named = base.get("_named", {})
    out = {k: v for k, v in params.items() if k not in named}
    for name, (kind, spec) in named.items():
        if name not in params:
            continue
        if kind == "set":
            out.update({t: eval_expr(e, params[name], plant) for t, e in spec.items()})
        else:
            out.update(spec[params[name]])
    return out


@functools.lru_cache(maxsize=256)
def _fw_is_int(name: str) -> bool:
    """Whether configuration field ``name`` is an integer in fw_config_t (obs_mode)."""
    from sim_fallback import FwConfig
    leaf = FwConfig.leaves().get(name)
    return leaf is not None and getattr(leaf[2], "_type_", "f") in "bBhHiIlLqQ"


@functools.lru_cache(maxsize=16)
def _motor_and_config(motor: str, extractor: str) -> tuple[Any, Any]:
    """Motor file and its nominal configuration, parsed once per worker process."""
    from sim_fallback import fw_config, load_motor
    mot = load_motor(motor)
    return mot, fw_config(mot, extractor)


@dataclass
class ResolvedRun:
    """What one campaign run simulates: the motor, extractor, seed and the absolute plant
    and firmware values its axes give (scale axes times the nominal ones)."""

    motor_name: str
    motor: Any
    nominal_fw: Any
    extractor: str
    seed: int
    plant: dict[str, Any]
    fw: dict[str, float]
    rest: dict[str, Any]


def resolve_run(base: dict[str, Any], params: dict[str, Any]) -> ResolvedRun:
    """One run's parameters resolved (the campaign's run and its full replay share it)."""
    scales = base.get("_scales", {})
    motor_name = str(params.get("motor", base.get("motor", BASE_MOTOR)))
    motor, _ = _motor_and_config(motor_name, BASE_EXTRACTOR)
    nominal = _all_plant(motor)
    plant, fw, rest = _split(_expand(base, params, nominal))
    extractor = str(rest.get("extractor", base.get("extractor", BASE_EXTRACTOR)))
    # scale axes multiply the nominal value (motor plant / derived configuration)
    motor, nominal_fw = _motor_and_config(motor_name, extractor)
    fw_abs = {k: (float(getattr(nominal_fw, k)) * v if scales.get("fw." + k) else v)
              for k, v in fw.items()}
    for k, v in fw_abs.items():  # integer configuration fields (obs_mode) from an axis
        if _fw_is_int(k) and float(v).is_integer():
            fw_abs[k] = int(v)
    plant_abs = {k: (float(nominal[k]) * v if scales.get("plant." + k) else v)
                 for k, v in plant.items()}
    for k, v in plant_abs.items():  # integer plant fields (adc_bits, n_sub) from a float axis
        if isinstance(nominal.get(k), int) and float(v).is_integer():
            plant_abs[k] = int(v)
    return ResolvedRun(motor_name, motor, nominal_fw, extractor, int(params.get("seed", 0)),
                       plant_abs, fw_abs, rest)


def linear_args(base: dict[str, Any], rest: dict[str, Any], motor: Any) -> dict[str, float]:
    """A linear-units run's speed (m/s), load (N), event and end times: an axis's value
    (``rest``) before the base's; ``load_rated`` times the motor's rated thrust
    (sim_fallback.rated_thrust_N)."""
    from sim_fallback import rated_thrust_N

    def get(k: str, default: Any = None) -> Any:
        return rest.get(k, base.get(k, default))

    load = (float(get("load_rated")) * rated_thrust_N(motor)
            if get("load_rated") is not None else float(get("load_N", 0.0)))
    return {"speed_mps": float(get("speed_mps")), "load_N": load,
            "event_s": float(base["event_s"]), "t_end": float(base.get("t_end", 1.0))}


def _simulate(base: dict[str, Any], params: dict[str, Any],
              metrics: list[str]) -> dict[str, Any]:
    from sim_fallback import paper_scenario

    seed = int(params.get("seed", 0))
    if base.get("scenario") == "fault_case":
        from sim_fallback.faults import CASES, run_case
        name = params.get("case", base.get("case"))
        case = next(c for c in CASES if c.name == name)
        r = run_case(case, seed)
        out = {k: r[k] for k in ("case", "doc", "fault_name", "why")}
        out.update(fault=int(r["fault"] or 0), verdict_ok=float(bool(r["verdict"])))
        for m in FAULT_CASE_METRICS:
            if m != "verdict_ok":
                out[m] = float(r[m]) if r.get(m) is not None else float("nan")
        return out
    rr = resolve_run(base, params)
    motor, nominal_fw, extractor = rr.motor, rr.nominal_fw, rr.extractor
    plant_abs, fw_abs, rest = rr.plant, rr.fw, rr.rest
    windows = base.get("windows", {})
    analysis = SM.needs_analysis(metrics, windows)
    tr = base.get("trace")
    kw: dict[str, Any] = {"t_end": float(base.get("t_end", 1.0)),
                          "record_decimation": int(base.get("record_decimation", 8)),
                          # only what the metrics need
                          "channels": list(SM.SCENARIO_CHANNELS) if analysis or tr else []}
    if "noise" in rest:
        kw["noise"] = float(rest["noise"])
    if "x0_m" in rest:
        kw["x0_m"] = float(rest["x0_m"])
    elif base.get("x0_m") is not None:
        kw["x0_m"] = base["x0_m"] if base["x0_m"] == "random" else float(base["x0_m"])
    scenario = base.get("scenario", "load_step")
    if not analysis and not tr:
        # the lean run: only the requested metrics and the channels they need
        kw.pop("channels")
        kw["metrics"] = metrics
    if scenario in LINEAR_SCENARIOS:
        from sim_fallback import linear_scenario
        kw.update(linear_args(base, rest, motor))
        r = linear_scenario(scenario, extractor=extractor, motor=motor, seed=seed,
                            plant=plant_abs or None, fw=fw_abs or None, **kw)
    else:
        r = paper_scenario(scenario, extractor=extractor, motor=motor,
                           seed=seed, plant=plant_abs or None, fw=fw_abs or None, **kw)
    out: dict[str, Any] = {"fault": int(r.fault_code)}
    for m in metrics:
        out[m] = float(r.metrics.get(m, float("nan")))
    if analysis:
        f_inj = float(fw_abs.get("f_inj_Hz", nominal_fw.f_inj_Hz))
        f_pwm = float(plant_abs.get("f_pwm_Hz", motor.plant["f_pwm_Hz"]))
        out.update(SM.analyse(r, metrics, windows, base.get("event_s"),
                              int(round(f_pwm / f_inj)),
                              float(plant_abs.get("R_ohm", motor.plant["R_ohm"]))))
    if tr:
        keep = tr.get("seeds") is None or seed in tr["seeds"]
        sig = SM.trace(r, tr["signals"], int(tr.get("decimation", 8))) if keep else {}
        out.update({f"trace.{s}": sig.get(f"trace.{s}") for s in tr["signals"]})
    return out


# ---- running -----------------------------------------------------------------


def warm_worker(motors: tuple[str, ...] = (BASE_MOTOR,),
                extractors: tuple[str, ...] = (BASE_EXTRACTOR,)) -> None:
    """A worker's one-time costs (imports, loading the simulator library, parsing the
    motor files), paid when the cluster starts rather than by its first runs."""
    from sim_fallback import lib_path
    lib_path()  # loads the simulator library
    warm_writer()  # a local cluster's workers write the Parquet parts
    for m in motors:
        for e in extractors:
            _motor_and_config(m, e)


#: Dask settings of the local cluster: its background work (the workers' statistical
#: profiler sampling the busy thread every 10 ms, 20 ms event-loop ticks, 100 ms memory
#: and work-stealing polls) took ~10 % of a core on an idle 2-core cluster, ~1.5 % with
#: these. Workers run one thread and dask's nanny sets OMP/MKL/OPENBLAS_NUM_THREADS=1.
#: worker-saturation 1.0: a worker is sent only the task it runs (dask's default 1.1
#: rounds up to a second one, queued on it), so when a run kills its worker the death is
#: counted against that task alone; with 1.1 the queued task was counted too and, once
#: isolated to one run, recorded as "the worker died running this run" though it never
#: started (an innocent run blamed). The next task then waits for a scheduler round trip
#: (~1 ms, against chunks of 8 to 1024 runs of milliseconds each).
LOCAL_CLUSTER_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "500ms",
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.scheduler.work-stealing-interval": "500ms",
    "distributed.scheduler.worker-saturation": 1.0,
}


def start_local_cluster(n_workers: int | None = None) -> tuple[Any, Any]:
    """(cluster, client): one single-threaded worker process per core (or
    ``n_workers``), with :data:`LOCAL_CLUSTER_CONFIG`, workers warmed up."""
    import logging

    import dask
    from dask.distributed import Client, LocalCluster
    # importing distributed sets its loggers to INFO: the in-process scheduler and
    # nannies then printed ~30 lines per campaign (start, ports, every worker, close)
    # between the progress bar's updates; warnings and errors still show, and -v
    # (the root logger at INFO or below) keeps them all
    if logging.getLogger().getEffectiveLevel() > logging.INFO:
        logging.getLogger("distributed").setLevel(logging.WARNING)
    with dask.config.set(LOCAL_CLUSTER_CONFIG):
        cluster = LocalCluster(n_workers=n_workers or os.cpu_count() or 1,
                               threads_per_worker=1, processes=True, dashboard_address=None,
                               host="127.0.0.1", silence_logs=logging.ERROR)
        client = Client(cluster)
    client.run(warm_worker)
    warm_writer()
    return cluster, client


def warm_writer() -> None:
    """The result writer's one-time cost in this process: pyarrow's first conversion
    imports pandas (~0.2 s), which would otherwise hold the GIL of the process that
    also runs the local scheduler while the first results arrive."""
    import pyarrow as pa
    pa.array([0.0])


def peak_rss_mb() -> float:
    """This process's peak resident set size (MiB). Linux: VmHWM, which starts afresh
    at exec (ru_maxrss would include the parent's pages shared while the worker was
    being spawned)."""
    import resource
    import sys
    try:
        with open("/proc/self/status") as f:
            return next(int(ln.split()[1]) for ln in f if ln.startswith("VmHWM:")) / 1024
    except (OSError, StopIteration, ValueError):
        pass
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / 2**20 if sys.platform == "darwin" else rss / 1024


def _chunks(todos: list[list[dict[str, Any]]], n_workers: int, largest: int = 128
            ) -> list[tuple[int, list[dict[str, Any]]]]:
    """(campaign index, runs) per task, guided: a task holds about 1/(2 workers) of the
    runs still to hand out, at most ``largest`` and at least 8. Each task costs the
    client, scheduler and worker a few ms of CPU, taken from the runs on a small
    machine, so tasks are few while the work lasts and short at the end, where a long
    one would leave the other workers idle. An interruption loses the runs a worker
    has not yet written: with the rows sent back to the client (a remote cluster), its
    whole task, hence ``largest`` 128 there (~0.4 s of 0.5 s runs); a local cluster's
    workers write every ``batch`` runs (64) themselves, so their tasks can be larger."""
    left = sum(len(t) for t in todos)
    out = []
    for i, todo in enumerate(todos):
        k = 0
        while k < len(todo):
            size = max(8, min(largest, -(-left // (2 * n_workers))))
            out.append((i, todo[k:k + size]))
            k += size
            left -= len(out[-1][1])
    return out


def results_dir(c: Campaign, out: Path) -> Path:
    return out / c.name


def _definition(c: Campaign) -> dict[str, Any]:
    """What decides a campaign's runs and columns (campaign.json beside its results)."""
    return json.loads(json.dumps(
        {"name": c.name, "title": c.title, "file": str(c.path), "base": c.base,
         "method": c.method, "n": c.n, "sampling_seed": c.sampling_seed,
         "metrics": c.metrics, "axes": [[a.target, a.kind, a.spec] for a in c.axes]}))


def check_results_dir(c: Campaign, rdir: Path) -> None:
    """Refuse to resume into a folder that holds another campaign's runs (the file was
    changed, or another file has the same name): its run k is not this campaign's run k.
    The source file's path and the title may differ."""
    parts = any(rdir.glob("part-*.parquet"))
    meta = rdir / "campaign.json"
    if not meta.exists():
        if parts:
            raise ResultsError(f"{rdir}: holds results without campaign.json; not resuming "
                               "into it (choose another --out or remove the folder)")
        return
    try:
        old = json.loads(meta.read_text(encoding="utf-8"))
        if not isinstance(old, dict):
            raise ValueError("not a JSON object")
    except (OSError, ValueError) as e:
        raise ResultsError(f"{meta}: unreadable ({e}); not resuming into {rdir} (choose "
                           "another --out or remove the folder)") from None
    new = _definition(c)
    diff = [k for k in new if k not in ("file", "title") and old.get(k) != new[k]]
    if diff and parts:
        raise ResultsError(
            f"{rdir}: holds results of a different campaign ({', '.join(diff)} differ from "
            f"{c.path or 'this campaign'}); not mixing them: choose another --out or name, "
            "or remove the folder")


def _runs_in(rdir: Path) -> dict[Path, list[int] | Exception]:
    """Each part's run numbers, or why it cannot be read; reads only."""
    import pyarrow.parquet as pq
    out: dict[Path, list[int] | Exception] = {}
    for f in sorted(rdir.glob("part-*.parquet")):
        try:
            out[f] = [int(x) for x in pq.read_table(f, columns=["run"]).column(0).to_pylist()]
        except Exception as e:  # noqa: BLE001 - any unreadable file (pyarrow's many errors)
            out[f] = e
    return out


def done_runs(rdir: Path) -> set[int]:
    """Run numbers already in the Parquet dataset (resume). A part that cannot be read
    (damaged after it was written: parts are renamed into place whole) is moved aside
    to ``<part>.corrupt``, said in one line, and its runs are run again."""
    import logging
    for f in rdir.glob(".part-*.tmp"):  # a writer killed before its rename
        f.unlink(missing_ok=True)
    done: set[int] = set()
    for f, runs in _runs_in(rdir).items():
        if isinstance(runs, Exception):
            bad = f.with_name(f.name + ".corrupt")
            f.replace(bad)
            logging.getLogger("bench.campaign").warning(
                "%s: unreadable Parquet (%s); moved to %s, its runs are run again",
                f, str(runs).splitlines()[0] if str(runs) else type(runs).__name__, bad.name)
        else:
            done.update(runs)
    return done


def _write_part(rdir: Path, rows: list[dict[str, Any]]) -> None:
    """One Parquet part, named after its first run: a run is written once, so the names
    of the client's and of several workers' parts never collide, and a chunk run again
    (its worker died) writes the same parts again under the same names."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    name = f"part-r{int(rows[0]['run']):08d}"
    tmp = rdir / f".{name}-{os.getpid()}.tmp"
    keys = list(dict.fromkeys(key for r in rows for key in r))  # a failed run has fewer
    pq.write_table(pa.Table.from_pylist([{key: r.get(key) for key in keys} for r in rows]),
                   tmp)
    tmp.replace(rdir / f"{name}.parquet")  # atomic: a kill leaves no torn file


def _dead_worker(fut: Any, chunk: list[dict[str, Any]], rdir: Path | None
                 ) -> list[dict[str, Any]] | None:
    """For a task whose workers died (dask gave up on it: KilledWorker), the runs of its
    chunk not yet written (``rdir``: the folder its workers write; None: nothing was);
    None for any other error."""
    from distributed import KilledWorker
    if not isinstance(fut.exception(), KilledWorker):
        return None
    written: set[int] = set()
    if rdir is not None:
        for runs in _runs_in(rdir).values():
            if not isinstance(runs, Exception):
                written.update(runs)
    return [p for p in chunk if int(p["run"]) not in written]


#: How long ``--scheduler`` may take to accept a connection and answer (s); dask's own
#: default (``distributed.comm.timeouts.connect``) is 30 s, which an unreachable address
#: made the user wait before any error.
SCHEDULER_TIMEOUT_S = 5.0


def connect_scheduler(address: str) -> Any:
    """A Client of the Dask scheduler at ``address``; SchedulerError (one line naming
    ``--scheduler``, the address and why) within about :data:`SCHEDULER_TIMEOUT_S` when
    it cannot be reached. A tcp/tls address is probed first (a plain TCP connect), so a
    refused port or an unknown host says so at once instead of dask's retries."""
    import socket

    from dask.distributed import Client
    from distributed.comm import parse_address, parse_host_port

    def fail(why: str) -> SchedulerError:
        return SchedulerError(f"--scheduler {address}: cannot connect: {why}")

    def first_line(e: BaseException) -> str:
        return (str(e).splitlines() or [type(e).__name__])[0]

    try:
        scheme, loc = parse_address(address)
        if scheme in ("tcp", "tls"):
            host, port = parse_host_port(loc)
            with socket.create_connection((host, port), timeout=SCHEDULER_TIMEOUT_S):
                pass
    except TimeoutError:
        raise fail(f"no answer within {SCHEDULER_TIMEOUT_S:g} s") from None
    except OSError as e:
        raise fail(e.strerror or first_line(e)) from None
    except (ValueError, TypeError) as e:
        raise fail(first_line(e)) from None
    try:
        return Client(address, timeout=SCHEDULER_TIMEOUT_S)
    except TimeoutError:
        raise fail(f"no Dask scheduler answered within {SCHEDULER_TIMEOUT_S:g} s") from None
    except Exception as e:  # noqa: BLE001 - whatever else listens there: said, one line
        raise fail(f"no Dask scheduler answered ({type(e).__name__}: {first_line(e)})"
                   ) from None


def _shares_our_files(client: Any) -> bool:
    """Whether the client's workers run on this machine (a LocalCluster's: the one
    ``bench campaign`` starts), so that they can write the results folder themselves."""
    from dask.distributed import LocalCluster
    return isinstance(getattr(client, "cluster", None), LocalCluster)


#: Campaigns of more drive time than this say how long they will take before starting
ANNOUNCE_DRIVE_S = 600.0
#: ... and need --yes when that is longer than this (wall s on this cluster)
CONFIRM_WALL_S = 2 * 3600.0


def _duration_text(s: float) -> str:
    if s < 120:
        return f"{s:.0f} s"
    if s < 7200:
        return f"{s / 60:.0f} min"
    if s < 3 * 86400:
        return f"{s / 3600:.1f} h"
    return f"{s / 86400:.1f} days"


def size_check(c: Campaign, runs: list[dict[str, Any]], out: Path, workers: int | None,
               scheduler: Any, serial: bool) -> tuple[str, bool, str] | None:
    """How long the runs still to do (of ``runs``, :meth:`Campaign.runs`) will take (the
    line to print, whether it needs --yes, the duration's text), or None for a small
    campaign (less than
    :data:`ANNOUNCE_DRIVE_S` of drive time). The rate is measured here, on one short
    run of the campaign's base (its first run, shortened), and scaled by the workers a
    local cluster gets; for a remote scheduler, per worker."""
    t_end = float(c.base.get("t_end", 1.0))
    try:
        done = done_runs(results_dir(c, out))
    except Exception:  # noqa: BLE001 - unreadable results are reported when the run starts
        done = set()
    n = sum(1 for r in runs if r["run"] not in done)
    drive_s = n * t_end
    if drive_s <= ANNOUNCE_DRIVE_S:
        return None
    t_cal = min(0.05, t_end)
    row = run_one({**c.run_base(), "t_end": t_cal}, runs[0], c.metrics)
    per_drive_s = float(row["wall_s"]) / t_cal  # wall s per drive s, one process
    k = 1 if serial else (workers or (None if scheduler else os.cpu_count() or 1))
    wall = drive_s * per_drive_s / (k or 1)
    where = ("in this process" if serial else f"on {k} local workers" if k
             else "per scheduler worker (divide by their number)")
    text = _duration_text(wall)
    line = (f"bench: campaign {c.name}: {n} runs x {t_end:g} s = {drive_s:.4g} s of drive "
            f"time; about {text} {where} (measured {per_drive_s:.2f} wall s per drive s "
            "on one run here)")
    return line, wall > CONFIRM_WALL_S, text


def run_campaign(c: Campaign, out: Path, scheduler: Any = None,
                 workers: int | None = None, serial: bool = False, batch: int = 64,
                 progress: Callable[[int, int, float], None] | None = None) -> Path:
    """Run every run not yet in the results; return the results folder. ``scheduler``:
    None (a local cluster of ``workers`` processes, started and closed here), an
    address, or a connected ``dask.distributed.Client`` (kept open)."""
    return run_campaigns([c], out, scheduler, workers, serial, batch, progress)[0]


def run_campaigns(cs: list[Campaign], out: Path, scheduler: Any = None,
                  workers: int | None = None, serial: bool = False, batch: int = 64,
                  progress: Callable[[int, int, float], None] | None = None) -> list[Path]:
    """Several campaigns through one cluster at once (their chunks share the workers, so
    short campaigns do not each pay a start and a tail); results as for run_campaign."""
    with contextlib.ExitStack() as locks:
        return _run_campaigns(cs, out, scheduler, workers, serial, batch, progress, locks)


@contextlib.contextmanager
def _locked(rdir: Path) -> Any:
    """This process writes ``rdir`` alone while it runs (an advisory lock on
    ``rdir/.lock``, which the system drops when the process ends, killed or not)."""
    import fcntl
    with open(rdir / ".lock", "a") as f:
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise ResultsError(f"{rdir}: another campaign process is writing these results "
                               "(it holds .lock there); wait for it or stop it") from None
        yield


def _run_campaigns(cs: list[Campaign], out: Path, scheduler: Any, workers: int | None,
                   serial: bool, batch: int,
                   progress: Callable[[int, int, float], None] | None,
                   locks: contextlib.ExitStack) -> list[Path]:
    rdirs, bases, todos = [], [], []
    for c in cs:  # every folder checked before any is written
        check_results_dir(c, results_dir(c, out))
    for c in cs:
        rdir = results_dir(c, out)
        rdir.mkdir(parents=True, exist_ok=True)
        locks.enter_context(_locked(rdir))
        check_results_dir(c, rdir)  # again, now that no other process writes it
        (rdir / "campaign.json").write_text(json.dumps(_definition(c), indent=1,
                                                       ensure_ascii=False), encoding="utf-8")
        rdirs.append(rdir)
        bases.append(c.run_base())
        done = done_runs(rdir)
        todos.append([r for r in c.runs() if r["run"] not in done])
    total, t0, finished = sum(len(t) for t in todos), time.perf_counter(), 0
    bufs: list[list[dict[str, Any]]] = [[] for _ in cs]

    def emit(i: int, row: dict[str, Any]) -> None:
        nonlocal finished
        bufs[i].append(row)
        finished += 1
        if len(bufs[i]) >= batch:
            _write_part(rdirs[i], bufs[i])
            bufs[i].clear()
        if progress:
            progress(finished, total, time.perf_counter() - t0)

    try:
        if serial or total == 0:
            for i, c in enumerate(cs):
                for r in todos[i]:
                    emit(i, run_one(bases[i], r, c.metrics))
        else:
            from dask.distributed import Client, as_completed
            cluster, own = None, not isinstance(scheduler, Client)
            if not own:
                client = scheduler
            elif scheduler:
                client = connect_scheduler(str(scheduler))
            else:
                cluster, client = start_local_cluster(workers)
            try:
                n_workers = max(1, len(client.scheduler_info().get("workers", {})) or 1)
                local = _shares_our_files(client)
                owner, chunks = zip(*_chunks(todos, n_workers, 1024 if local else 128),
                                    strict=True)
                futs: list[Any] = []
                index: dict[str, tuple[int, list[dict[str, Any]]]] = {}

                def submit(owner: Iterable[int], chunks: Iterable[list[dict[str, Any]]]
                           ) -> list[Any]:
                    owner, chunks = list(owner), list(chunks)
                    new = client.map(run_chunk, [bases[i] for i in owner], chunks,
                                     [cs[i].metrics for i in owner],
                                     [str(rdirs[i]) if local else None for i in owner],
                                     [batch] * len(owner), pure=False)
                    index.update({f.key: (i, ch) for f, i, ch in zip(new, owner, chunks,
                                                                     strict=True)})
                    futs.extend(new)
                    return new

                ac = as_completed(submit(owner, chunks))
                try:
                    for fut in ac:
                        i, chunk = index.pop(fut.key)
                        if fut.status == "error":
                            # a run that kills its worker (a crash in the simulator) is
                            # isolated by halving its chunk and recorded with its error
                            isolated = _dead_worker(fut, chunk, rdirs[i] if local else None)
                            if isolated is None:
                                fut.result()  # another error: raises it
                            elif len(isolated) == 1:
                                emit(i, failed_row(isolated[0], cs[i].metrics,
                                                   f"the worker died running this run "
                                                   f"({type(fut.exception()).__name__}: "
                                                   f"{fut.exception()})"))
                            else:
                                finished += len(chunk) - len(isolated)
                                half = (len(isolated) + 1) // 2
                                for f in (submit([i, i], [isolated[:half], isolated[half:]])
                                          if isolated else []):
                                    ac.add(f)
                                if progress:
                                    progress(finished, total, time.perf_counter() - t0)
                        elif local:  # the workers write the parts; a result is a count
                            finished += len(chunk)
                            if progress:
                                progress(finished, total, time.perf_counter() - t0)
                        else:  # the rows come back here
                            for row in fut.result():
                                emit(i, row)
                        fut.release()
                except BaseException:
                    # interrupted or failed: tasks not yet started do not start (a
                    # cluster kept open would go on writing the results folder)
                    with contextlib.suppress(Exception):
                        client.cancel([f for f in futs if not f.done()])
                    raise
            finally:
                if own:
                    client.close()
                if cluster is not None:
                    cluster.close()
    finally:
        for i, buf in enumerate(bufs):
            if buf:
                _write_part(rdirs[i], buf)
    return rdirs


def load_results(rdir: Path) -> Any:
    """All runs of a campaign as a pandas-free dict of numpy columns."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    parts = []
    for f in sorted(rdir.glob("part-*.parquet")):
        try:
            parts.append(pq.read_table(f))
        except Exception as e:  # noqa: BLE001 - pyarrow's many errors: one line
            raise ResultsError(f"{f}: unreadable Parquet ({str(e).splitlines()[0]}); "
                               "`bench campaign` on its file moves it aside and runs its "
                               "runs again") from None
    if not parts:
        return {}
    try:
        t = pa.concat_tables(parts, promote_options="default")
    except (pa.ArrowInvalid, pa.ArrowTypeError) as e:
        raise ResultsError(f"{rdir}: parts that do not fit together ({e}); results of "
                           "different campaigns?") from None
    if "run" not in t.column_names:
        raise ResultsError(f"{rdir}: parts without a 'run' column: not campaign results")
    # in run order, whatever order the parts were written in; a run written twice (a
    # chunk run again after its worker died) counts once
    _, first = np.unique(np.asarray(t.column("run").to_numpy(), dtype=np.int64),
                         return_index=True)
    t = t.take(pa.array(first))
    out = {}
    for name in t.column_names:
        vals = t.column(name).to_pylist()
        col = np.empty(len(vals), dtype=object)
        if pa.types.is_list(t.schema.field(name).type):
            for i, v in enumerate(vals):  # list cells (traces) stay one object each
                col[i] = v
        else:
            col[:] = vals
        out[name] = col
    return out


def statistic(values: np.ndarray, stat: str) -> float:
    """One distribution statistic over the finite values (NaN = a failed run)."""
    v = np.asarray(values, dtype=float)
    if stat == "fail_fraction":
        return float(np.mean(~np.isfinite(v))) if v.size else float("nan")
    v = v[np.isfinite(v)]
    if v.size == 0:
        return float("nan")
    if stat.startswith("p"):
        return float(np.percentile(v, float(stat[1:])))
    return float(getattr(np, stat)(v))


def judge(c: Campaign, res: dict[str, np.ndarray]) -> list[dict[str, Any]]:
    """Each limit with its measured statistic and verdict."""
    out = []
    for lim in c.limits:
        val = statistic(res.get(lim.metric, np.array([])), lim.stat)
        ok = math.isfinite(val) and (lim.max is None or val <= lim.max) and (
            lim.min is None or val >= lim.min)
        out.append({"metric": lim.metric, "stat": lim.stat, "value": val, "max": lim.max,
                    "min": lim.min, "ok": ok})
    return out


def replay_command(c: Campaign, run: int) -> str:
    """The one command that reruns a single run of a campaign, from any directory: the
    campaign file's absolute path, quoted for a POSIX shell."""
    path = Path(c.path).resolve() if c.path is not None else Path("<campaign file>")
    return f"bench campaign {shlex.quote(str(path))} --replay {run}"


# ---- command line ------------------------------------------------------------


def add_parser(sub: Any) -> None:
    """``bench campaign`` on the bench's subcommand parser."""
    p = sub.add_parser(
        "campaign", help="run a campaign of simulated-drive runs (Dask), report distributions",
        description="Run every run of a campaign file not yet in its results (resumable), "
                    "on a local Dask cluster of all cores, an existing scheduler "
                    "(--scheduler) or serially; then write report.html beside the Parquet "
                    "results. Exit 0 when every limit holds, 1 when one fails, 2 for a bad "
                    "file or argument, 3 when the results folder cannot be used, 130 when "
                    "interrupted (finished runs are kept).")
    p.add_argument("file", help="campaign YAML (see campaigns/)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="dask scheduler, e.g. tcp://host:8786")
    p.add_argument("--workers", type=int, metavar="N",
                   help="local cluster size (default: cores; 1 to 4 per core)")
    p.add_argument("--serial", action="store_true", help="no Dask: a plain loop in this process")
    p.add_argument("--out", default="runs/campaigns", help="results root (default %(default)s)")
    p.add_argument("--replay", type=int, metavar="RUN", help="rerun one run alone and print it")
    p.add_argument("--full", action="store_true",
                   help="with --replay: also run it as a bench run on the simulated drive "
                        "(sequence, report, waveforms, CAN log under --runs) and show its "
                        "metrics beside the campaign's")
    p.add_argument("--runs", default="runs", metavar="DIR",
                   help="where --replay --full writes its run folder (default %(default)s)")
    p.add_argument("--yes", action="store_true",
                   help="start a campaign that will take longer than "
                        f"{CONFIRM_WALL_S / 3600:g} h on this cluster (its size is always "
                        "said first)")
    p.add_argument("--compare", metavar="DIR", help="results folder of another campaign to "
                                                    "overlay in the report")


def cmd(args: Any) -> int:
    """Run ``bench campaign``; returns the exit code."""
    import sys

    try:
        from sim_fallback.metrics import METRIC_NAMES
        c = load_campaign(args.file, METRIC_NAMES)
    except CampaignError as e:
        print(f"bench: {e}", file=sys.stderr)
        return 2
    if args.workers is not None and not 1 <= args.workers <= max_local_workers():
        print(f"bench: --workers {args.workers}: allowed 1..{max_local_workers()} "
              f"({WORKERS_PER_CORE} per core of this machine's {os.cpu_count() or 1})",
              file=sys.stderr)
        return 2
    runs = c.runs()
    if args.replay is not None:
        if not 0 <= args.replay < len(runs):
            print(f"bench: --replay {args.replay}: campaign {c.name} has runs 0.."
                  f"{len(runs) - 1}", file=sys.stderr)
            return 2
        row = run_one(c.run_base(), runs[args.replay], c.metrics)
        # strict JSON (jq and others refuse NaN): a metric the run has not is null; the
        # run's parameters as an object, not a JSON string inside JSON
        shown = {k: None if isinstance(v, float) and not math.isfinite(v) else v
                 for k, v in row.items() if k != "traceback"}
        shown["params"] = json.loads(row["params"])
        print(json.dumps(shown, indent=1, allow_nan=False))
        if not args.full:
            return 0 if row["error"] is None else 1
        from ._replay import ReplayError, comparison, replay_full
        try:
            rep = replay_full(c, runs[args.replay], args.runs)
        except ReplayError as e:
            print(f"bench: --replay {args.replay} --full: {e}", file=sys.stderr)
            return 2
        for line in comparison(row, rep, c.metrics):
            print(line, file=sys.stderr)
        print(f"bench: run {args.replay} of {c.name} replayed as a bench run "
              f"({'PASSED' if rep.passed else 'FAILED'}"
              f"{': ' + rep.error if rep.error else ''}): {rep.run_dir}"
              + (f"; report {rep.report}" if rep.report else ""), file=sys.stderr)
        return 0 if row["error"] is None and rep.error is None else 1
    size = size_check(c, runs, Path(args.out), args.workers, args.scheduler, args.serial)
    if size:
        print(size[0], file=sys.stderr)
        if size[1] and not args.yes:
            print(f"bench: campaign {c.name}: about {size[2]}; give --yes to start it",
                  file=sys.stderr)
            return 2
    other = Path(args.compare) if args.compare else None
    if other is not None:
        try:
            found = bool(load_results(other)) if other.is_dir() else False
        except ResultsError as e:
            print(f"bench: --compare {other}: {e}", file=sys.stderr)
            return 2
        if not found:
            print(f"bench: --compare {other}: no campaign results (part-*.parquet) there",
                  file=sys.stderr)
            return 2
    from tqdm import tqdm

    class _Bar:  # shown from the first finished run: the folder's checks print first
        bar: Any = None

        def close(self) -> None:
            if self.bar is not None:
                self.bar.close()

    bar, last = _Bar(), [0]

    def progress(done: int, total: int, elapsed: float) -> None:
        if bar.bar is None:
            bar.bar = tqdm(total=total, unit="run", desc=c.name, file=sys.stderr)
        bar.bar.update(done - last[0])
        last[0] = done

    import signal

    def terminate(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt  # `kill PID` as Ctrl-C: the finished runs are written

    interrupted = False
    old_term = signal.signal(signal.SIGTERM, terminate)
    try:
        rdir = run_campaign(c, Path(args.out), scheduler=args.scheduler, workers=args.workers,
                            serial=args.serial, progress=progress)
    except KeyboardInterrupt:
        interrupted = True
        rdir = results_dir(c, Path(args.out))
    except SchedulerError as e:
        bar.close()  # its line ends before the message
        print(f"bench: {e}", file=sys.stderr)
        return 2
    except ResultsError as e:
        bar.close()
        print(f"bench: {e}", file=sys.stderr)
        return 3
    except OSError as e:
        bar.close()
        print(f"bench: campaign {c.name}: results folder {results_dir(c, Path(args.out))}: "
              f"{e}", file=sys.stderr)
        return 3
    finally:
        signal.signal(signal.SIGTERM, old_term)
        bar.close()
    from ._report import write_report
    try:
        res = load_results(rdir)
        report = write_report(c, rdir, other)
    except OSError as e:  # ResultsError included
        print(f"bench: {e}", file=sys.stderr)
        return 3
    verdicts = judge(c, res)
    for v in verdicts:
        lim = " and ".join(f"{w} {v[k]:g}" for k, w in (("min", ">="), ("max", "<="))
                           if v[k] is not None)
        print(f"{'pass' if v['ok'] else 'FAIL'}  {v['stat']}({v['metric']}) = {v['value']:.4g}"
              f"  (required {lim})")
    print(f"{len(res.get('run', []))} runs in {rdir}; report {report}")
    if interrupted:
        print("bench: interrupted; run the same command again to resume", file=sys.stderr)
        return 130
    return 0 if all(v["ok"] for v in verdicts) else 1
