"""A campaign's run replayed as a full bench run (``bench campaign C.yaml --replay N
--full``): the same motor, extractor, seed, plant and firmware values, the scenario as a
sequence, through the simulated drive over CANopen, with everything a run writes (report,
waveforms, CAN log, summary) — so a failing corner can be looked at, not only read as a
row of numbers.

The campaign computed its row in-process (``sim_fallback.run_scenario``: the firmware
core stepped directly, references applied at exact times); the full run reaches the drive
over the bus, so its enable (several CiA 402 transitions over SDO) and its references
arrive at the times the bench sends them, and its ADC noise is another draw. Both numbers
are shown side by side; they differ by that timeline, not by the drive: on one timeline
the two paths compute the same drive to the control period (tests/python/test_one_drive.py:
a bench run replayed through the core alone gives the same true angle to 1e-9 rad).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: the paper scenarios' schedules are in the units of sim_fallback.run_scenario's
#: defaults; a linear-units scenario's in m/s and N (the sequence language's units)
_SPEED_UNIT, _LOAD_UNIT = "r/min", "N*m"
_LINEAR_UNITS = ("m/s", "N")


class ReplayError(ValueError):
    """This run cannot be replayed as a bench run (one line naming why)."""


def _schedule(s: Any) -> list[tuple[float, float]]:
    """A run_scenario schedule (constant or breakpoints) as breakpoints."""
    if s is None:
        return []
    if isinstance(s, (int, float)):
        return [(0.0, float(s))]
    if isinstance(s, (list, tuple)):
        return [(float(t), float(v)) for t, v in s]
    raise ReplayError(f"schedule {s!r}: only constants and breakpoints replay as a sequence")


def sequence_text(name: str, scenario: str, motor: str, extractor: str, seed: int,
                  t_end: float, x0: float | str, linear: dict[str, float] | None = None
                  ) -> str:
    """The scenario as a bench sequence: a paper scenario's schedules
    (``sim_fallback.PAPER_SCENARIO_ARGS``, r/min and N*m), or a linear-units scenario's
    (``sim_fallback.linear_scenario_args`` of ``linear``: speed_mps, load_N, event_s,
    t_end; m/s and N)."""
    from sim_fallback import LINEAR_SCENARIOS, PAPER_SCENARIO_ARGS, linear_scenario_args

    if scenario in LINEAR_SCENARIOS and linear is not None:
        args = linear_scenario_args(scenario, **linear)
        su, lu = _LINEAR_UNITS
    elif scenario in PAPER_SCENARIO_ARGS:
        args, su, lu = PAPER_SCENARIO_ARGS[scenario], _SPEED_UNIT, _LOAD_UNIT
    else:
        raise ReplayError(f"scenario {scenario!r}: a fault case injects faults inside the "
                          "simulation, which a bench sequence cannot; --replay without "
                          "--full prints its row")
    events = [(t, 0, f"set_speed: {{value: {v!r}, unit: {su}}}")
              for t, v in _schedule(args.get("speed_ref"))]
    events += [(t, 1, f"load_step: {{value: {v!r}, unit: '{lu}'}}")
               for t, v in _schedule(args.get("load")) if not (t == 0.0 and v == 0.0)]
    steps = ["  - enable: {mode: speed}"]
    now = 0.0
    for t, _, step in sorted(e for e in events if e[0] < t_end):
        if t > now + 1e-12:
            steps.append(f"  - wait: {{duration_s: {t - now!r}}}")
            now = t
        steps.append(f"  - {step}")
    if t_end > now:
        steps.append(f"  - wait: {{duration_s: {t_end - now!r}}}")
    steps.append("  - disable: {}")
    x0_text = "random" if x0 == "random" else repr(float(x0))
    return (f"name: {name}\nmotor: '{motor}'\nextractor: {extractor}\nseed: {seed}\n"
            f"x0: {x0_text}\ndescription: 'campaign run replayed as a bench run'\n"
            "steps:\n" + "\n".join(steps) + "\n")


@dataclass
class Replay:
    """What a full replay produced."""

    run_dir: Path
    report: Path | None
    passed: bool
    metrics: dict[str, float]
    error: str | None


def replay_full(c: Any, params: dict[str, Any], runs_root: str = "runs") -> Replay:
    """Run campaign ``c``'s run ``params`` as a bench run on the simulated drive."""
    from bench import open_sim, run_sequence, validate_sequence
    from sim_fallback import PAPER_SCENARIO_ARGS

    from ._campaign import LINEAR_SCENARIOS, linear_args, resolve_run

    base = c.run_base()
    scenario = str(base.get("scenario", "load_step"))
    rr = resolve_run(base, params)
    t_end = float(base.get("t_end", PAPER_SCENARIO_ARGS.get(scenario, {}).get("t_end", 1.0)))
    x0 = rr.rest.get("x0_m", base.get("x0_m", PAPER_SCENARIO_ARGS.get(scenario, {}).get(
        "x0_m", 0.0)))
    linear = linear_args(base, rr.rest, rr.motor) if scenario in LINEAR_SCENARIOS else None
    text = sequence_text(f"{c.name}_run{int(params['run'])}", scenario, rr.motor_name,
                         rr.extractor, rr.seed, t_end, x0, linear)
    seq = validate_sequence(text, f"<campaign {c.name} run {int(params['run'])}>")
    conn = open_sim(motor=rr.motor_name, extractor=rr.extractor, seed=rr.seed, x0=seq.x0,
                    plant=rr.plant or None, noise=float(rr.rest.get("noise", 1.0)))
    try:
        if rr.fw:  # the run's firmware values, written as a rig's would be
            conn.drive.set_many({k: float(v) for k, v in rr.fw.items()})
        out = run_sequence(seq, conn, runs_root=runs_root, progress=False)
    finally:
        conn.close()
    (out.run_dir / "campaign_run.json").write_text(
        json.dumps({"campaign": c.name, "file": str(c.path or ""), "params": params},
                   indent=1, default=float) + "\n")
    r = out.result
    return Replay(out.run_dir, out.report, r.passed, dict(r.metrics), r.error)


def comparison(row: dict[str, Any], rep: Replay, metrics: list[str]) -> list[str]:
    """Lines: each campaign metric, the campaign's in-process value and the full run's."""
    lines = [f"{'metric':<38} {'campaign':>12} {'full run':>12}"]
    for m in metrics:
        a = row.get(m)
        b = rep.metrics.get(m)

        def f(v: Any) -> str:
            return "n/a" if v is None or (isinstance(v, float) and not math.isfinite(v)) \
                else f"{float(v):.5g}"
        lines.append(f"{m:<38} {f(a):>12} {f(b):>12}")
    lines.append("(the same drive and configuration; the full run's timeline differs: its "
                 "enable and references travel over the bus, and its noise is another draw)")
    return lines
