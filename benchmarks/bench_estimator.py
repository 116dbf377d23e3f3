"""Angle/speed observer: the default gain law against the innovation-adaptive one
(fw_config obs_mode, docs/method.md section 5). Not a timed test: prints figures.

    python benchmarks/bench_estimator.py [--seeds 20] [--json out.json]
    python benchmarks/bench_estimator.py --set obs_bw_narrow=0.2   # a variant as "new"

Scenarios (each run well under a second of wall time):

1. The paper's load step (paper_salient, adaptive SOGI, 100 r/min, 2 N m at 0.5 s,
   1 s, 12-bit ADC with 1 count of noise, 50 V injection: the reproduction's
   campaigns/reproduction/load_step.yaml): steady RMS and max |angle error| over
   0.7-1.0 s, transient max over 0.5-0.7 s (el. rad), steady speed-estimate error
   max (the drive's filtered speed omega_f minus the true speed, r/min): the
   reproduction's ``steady.pos_rms``, ``steady.pos_max``, ``transient.pos_max``,
   ``steady.spd_max`` (bench/_scenario_metrics.py).
2. iron_core_linear, a load step of 20 % of the rated thrust (K_F i_rated = 120 N)
   at 0.5 s, at 0.1 and 0.3 m/s from a random position, 1 s: position error RMS and
   max from 0.15 s (position_error_rms_rad, position_error_max_rad).

For each: median and spread (min-max, and the 10-90 % range) over the seeds, the
ratio new / baseline of the medians, and whether the issue's target holds for the
median. Baseline is the configuration default (od.yaml); new is obs_mode 2 unless
the default already is, then baseline is obs_mode 1.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import sys
from pathlib import Path

import numpy as np

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sim_fallback import fw_config, load_motor, paper_scenario, run_scenario  # noqa: E402
from sim_fallback.metrics import window_metrics  # noqa: E402

#: the issue's targets (upper bounds, judged on the median over seeds)
PAPER_TARGETS = {"steady.pos_rms": 0.004, "steady.pos_max": 0.010, "steady.spd_max": 1.0,
                 "transient.pos_max": 0.05}
IRON_TARGETS = {"pos_rms": 0.008, "pos_max": 0.05}
IRON_SPEEDS_MPS = (0.1, 0.3)


def paper_metrics(seed: int, fw: dict[str, float]) -> dict[str, float]:
    r = paper_scenario("load_step", "sogi_adaptive", seed=seed, fw=fw or None)
    if not r.valid:
        return {k: math.nan for k in PAPER_TARGETS}
    s, t = window_metrics(r, 0.7, 1.0), window_metrics(r, 0.5, 0.7)
    return {"steady.pos_rms": s["pos_rms"], "steady.pos_max": s["pos_max"],
            "steady.spd_max": s["spd_max"], "transient.pos_max": t["pos_max"]}


def iron_load_N() -> float:
    mot = load_motor("iron_core_linear")
    K_F = 1.5 * math.pi / mot.tau_m * mot.plant["psi_f_Wb"]  # N/A, from the motor file
    return 0.2 * float(fw_config(mot).i_rated_A) * K_F


def iron_metrics(seed: int, v_mps: float, load_N: float,
                 fw: dict[str, float]) -> dict[str, float]:
    r = run_scenario("iron_core_linear", speed_ref=v_mps, speed_unit="mps",
                     load=[(0.0, 0.0), (0.5, load_N)], load_unit="N", t_end=1.0, seed=seed,
                     x0_m="random", fw=fw or None)
    if not r.valid:
        return {k: math.nan for k in IRON_TARGETS}
    return {"pos_rms": r.metrics["position_error_rms_rad"],
            "pos_max": r.metrics["position_error_max_rad"]}


def _iron_at(seed: int, fw: dict[str, float], v_mps: float,
             load_N: float) -> dict[str, float]:
    return iron_metrics(seed, v_mps, load_N, fw)


def stats(x: list[float]) -> dict[str, float]:
    a = np.asarray(x, dtype=float)
    return {"median": float(np.nanmedian(a)), "min": float(np.nanmin(a)),
            "max": float(np.nanmax(a)), "p10": float(np.nanpercentile(a, 10)),
            "p90": float(np.nanpercentile(a, 90)), "invalid": int(np.isnan(a).sum())}


def run(seeds: int, new: dict[str, float], base: dict[str, float]) -> dict:
    out: dict = {"seeds": seeds, "baseline": base, "new": new, "rows": []}
    load_N = iron_load_N()
    cases = [("paper load step", PAPER_TARGETS, paper_metrics)]
    cases += [(f"iron_core_linear {v:g} m/s, {load_N:.0f} N step", IRON_TARGETS,
               functools.partial(_iron_at, v_mps=v, load_N=load_N))
              for v in IRON_SPEEDS_MPS]
    for name, targets, fn in cases:
        got = {lab: [fn(s, fw) for s in range(seeds)] for lab, fw in (("baseline", base),
                                                                      ("new", new))}
        for metric, bound in targets.items():
            b = stats([g[metric] for g in got["baseline"]])
            n = stats([g[metric] for g in got["new"]])
            out["rows"].append({"case": name, "metric": metric, "target": bound,
                                "baseline": b, "new": n,
                                "ratio": n["median"] / b["median"] if b["median"] else math.nan,
                                "met": bool(n["median"] <= bound and n["invalid"] == 0)})
    return out


def print_table(res: dict) -> None:
    print(f"seeds 0..{res['seeds'] - 1}; baseline {res['baseline'] or 'default'}; "
          f"new {res['new']}")
    print("| case | metric | target | baseline median [min, max] | new median [min, max] "
          "(p10-p90) | new/baseline | target met |")
    print("|---|---|---|---|---|---|---|")
    for r in res["rows"]:
        b, n = r["baseline"], r["new"]
        print(f"| {r['case']} | {r['metric']} | <= {r['target']:g} | {b['median']:.4g} "
              f"[{b['min']:.4g}, {b['max']:.4g}] | {n['median']:.4g} [{n['min']:.4g}, "
              f"{n['max']:.4g}] ({n['p10']:.4g}-{n['p90']:.4g}) | {r['ratio']:.2f} | "
              f"{'yes' if r['met'] else 'no'} |")


def _parse_set(items: list[str]) -> dict[str, float]:
    """FIELD=VALUE pairs; a value without a point or exponent is an integer (the
    unsigned fields such as obs_mode take only integers)."""
    out: dict[str, float] = {}
    for it in items:
        k, _, v = it.partition("=")
        v = v.strip()
        out[k.strip()] = int(v) if v.lstrip("-").isdigit() else float(v)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                    help="fw_config field of the new estimator (repeatable)")
    ap.add_argument("--base-set", action="append", default=[], metavar="FIELD=VALUE",
                    help="fw_config field of the baseline (repeatable)")
    ap.add_argument("--json", type=Path, help="write the figures as JSON")
    a = ap.parse_args(argv)
    default_mode = int(fw_config(load_motor("paper_salient")).obs_mode)
    base: dict[str, float] = {"obs_mode": 1} if default_mode == 2 else {}
    base.update(_parse_set(a.base_set))
    new: dict[str, float] = {"obs_mode": 2}
    new.update(_parse_set(a.set))
    res = run(a.seeds, new, base)
    print_table(res)
    if a.json:
        a.json.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
