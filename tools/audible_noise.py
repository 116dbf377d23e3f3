#!/usr/bin/env python3
"""Audible noise against accuracy: run campaigns/audible_noise.yaml and write
docs/audible_noise.md, docs/audible_noise.json and docs/figures/audible_pareto.png.

    python tools/audible_noise.py                  # local Dask cluster (2 workers), writes docs/
    python tools/audible_noise.py --serial         # the same in this process
    python tools/audible_noise.py --render-only    # the doc again from the last results

The campaign sweeps the injection amplitude u_inj_V and frequency f_inj_Hz over the paper's
load step (10 seeds each); each run reports the A-weighted levels of the thrust ripple and
of the phase currents in the audible band, the injection's copper loss (sim_fallback.metrics,
"audible noise") and the position error. The doc gives every setting's numbers, the Pareto
front of position error against thrust-ripple level (and against copper loss), and the
recommended default by the rule :data:`RULE` states. It only recommends: the firmware's
default (protocols/od.yaml) is not changed here.

Exit codes: 0 written; 1 a run failed (raised) or no setting qualifies; 2 a bad campaign
file or argument; 3 a results folder that cannot be used.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

try:  # first: one line, not a traceback, outside the venv (not when loaded as a module)
    import _project_env  # noqa: F401
except ModuleNotFoundError:
    pass

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from sim_fallback import metrics as SM  # noqa: E402
from simcampaign import (  # noqa: E402
    CampaignError,
    load_campaign,
    load_results,
    run_campaigns,
)

CAMPAIGN = REPO / "campaigns" / "audible_noise.yaml"
#: the recommendation checked with a real inverter's dead time, compensated and not
CAMPAIGN_DT = REPO / "campaigns" / "audible_deadtime.yaml"
#: the campaign whose limit the accuracy criterion takes (the paper's load step)
LOAD_STEP = REPO / "campaigns" / "reproduction" / "load_step.yaml"
#: the firmware's default injection (protocols/od.yaml)
DEFAULT = (50.0, 3000.0)
NOISE = "steady.thrust_ripple_dBA"
ERROR = "steady.pos_rms"
LOSS = "steady.inj_copper_loss_W"
#: what each setting's row shows: (column, header, format)
COLUMNS = (
    ("steady.thrust_ripple_dBA", "thrust ripple dB(A) re 1 N (2 N·m)", "{:.1f}"),
    ("before.thrust_ripple_dBA", "thrust ripple dB(A) (no load)", "{:.1f}"),
    ("steady.phase_current_dBA", "phase current dB(A) re 1 A", "{:.1f}"),
    ("steady.inj_copper_loss_W", "injection copper loss W", "{:.3f}"),
    ("steady.pos_rms", "steady RMS error el. rad", "{:.4f}"),
    ("steady.pos_max", "steady max error el. rad", "{:.3f}"),
    ("transient.pos_max", "load-step max error el. rad", "{:.3f}"),
    ("before.pos_rms", "no-load RMS error el. rad", "{:.4f}"),
)
#: the recommendation's rule, as the doc states it
RULE = ("every seed valid (no fault), and the steady RMS position error's mean + 2 standard "
        "deviations over the seeds within the paper load step's limit ({limit} el. rad, "
        "`campaigns/reproduction/load_step.yaml`: about 98 % of runs hold it); of those, the "
        "lowest mean thrust-ripple level under load")


def accuracy_limit() -> float:
    """The load-step campaign's limit on the steady RMS position error (el. rad)."""
    c = load_campaign(LOAD_STEP, SM.METRIC_NAMES)
    return float(next(lim.max for lim in c.limits
                      if lim.metric == ERROR and lim.stat == "max" and lim.max is not None))


def run(results: Path, serial: bool, workers: int) -> tuple[Path, Path]:
    """Both campaigns into fresh results under ``results``; their results folders (the
    sweep's, the dead-time check's)."""
    cs = [load_campaign(f, SM.METRIC_NAMES) for f in (CAMPAIGN, CAMPAIGN_DT)]
    for c in cs:
        shutil.rmtree(results / c.name, ignore_errors=True)
    a, b = run_campaigns(cs, results, workers=workers, serial=serial)
    return a, b


def deadtime_rows(res: dict[str, Any]) -> list[dict[str, Any]]:
    """The dead-time check: one row per (inverter, setting) case, in the campaign's order:
    valid seeds, faults, and mean (sd) of its metrics over the valid seeds."""
    params = _params(res)
    keys = list(dict.fromkeys((p["inverter"], p["setting"]) for p in params))
    cols = (ERROR, "steady.pos_max", "transient.pos_max", NOISE, LOSS)
    return [{"inverter": inv, "setting": sett, **_case_stats(
        res, np.array([(p["inverter"], p["setting"]) == (inv, sett) for p in params]), cols)}
        for inv, sett in keys]


def summarise(res: dict[str, Any]) -> list[dict[str, Any]]:
    """One row per (u_inj_V, f_inj_Hz): seeds, valid seeds, faults, and mean and
    standard deviation over the valid seeds of every campaign metric."""
    params = _params(res)
    u = np.array([p["fw.u_inj_V"] for p in params])
    f = np.array([p["fw.f_inj_Hz"] for p in params])
    rows = []
    for uu in sorted(set(u)):
        for ff in sorted(set(f)):
            k = (u == uu) & (f == ff)
            row = {"u_inj_V": float(uu), "f_inj_Hz": float(ff),
                   **_case_stats(res, k, [col for col, _, _ in COLUMNS])}
            ok = k & (np.asarray(res["valid"], dtype=float) == 1.0)
            row[ERROR + ".max"] = (float(np.max(np.asarray(res[ERROR], dtype=float)[ok]))
                                   if ok.any() else math.nan)
            rows.append(row)
    return rows


def _params(res: dict[str, Any]) -> list[dict[str, Any]]:
    """The runs' parameters; raises RuntimeError when a run failed (not a drive fault:
    an error of the run itself)."""
    errors = [e for e in res["error"] if e]
    if errors:
        raise RuntimeError(f"{len(errors)} runs failed; the first: {errors[0]}")
    return [json.loads(p) for p in res["params"]]


def _case_stats(res: dict[str, Any], k: np.ndarray, cols: Sequence[str]) -> dict[str, Any]:
    """The runs ``k`` of one case: seeds, valid seeds, the faults' codes, and each column's
    mean (``col``) and standard deviation (``col.sd``) over the valid ones."""
    ok = k & (np.asarray(res["valid"], dtype=float) == 1.0)
    faults = sorted({int(x) for x in np.asarray(res["fault"])[k] if int(x)})
    row: dict[str, Any] = {"seeds": int(k.sum()), "valid": int(ok.sum()),
                           "faults": [f"0x{x:04X}" for x in faults]}
    for col in cols:
        v = np.asarray(res[col], dtype=float)[ok]
        row[col] = float(np.mean(v)) if v.size else math.nan
        row[col + ".sd"] = float(np.std(v, ddof=1)) if v.size > 1 else math.nan
    return row


def pareto(rows: list[dict[str, Any]], x: str, y: str) -> list[dict[str, Any]]:
    """The rows of all-valid settings no other all-valid setting beats in both ``x`` and
    ``y`` (lower is better in both), by increasing ``x``."""
    pts = [r for r in rows if r["valid"] == r["seeds"] and np.isfinite(r[x] + r[y])]
    front = [r for r in pts if not any(o[x] <= r[x] and o[y] <= r[y]
                                       and (o[x] < r[x] or o[y] < r[y]) for o in pts)]
    return sorted(front, key=lambda r: r[x])


def eligible(r: dict[str, Any], limit: float) -> bool:
    """The accuracy criterion of :data:`RULE`."""
    return (r["valid"] == r["seeds"] and r["seeds"] > 1
            and r[ERROR] + 2.0 * r[ERROR + ".sd"] <= limit)


def recommend(rows: list[dict[str, Any]], limit: float) -> dict[str, Any] | None:
    ok = [r for r in rows if eligible(r, limit)]
    return min(ok, key=lambda r: r[NOISE]) if ok else None


def same_accuracy(rows: list[dict[str, Any]], default: dict[str, Any]) -> dict[str, Any] | None:
    """The quietest all-valid setting whose mean steady RMS error is within the default's
    mean + 1 standard deviation."""
    bound = default[ERROR] + default[ERROR + ".sd"]
    ok = [r for r in rows if r["valid"] == r["seeds"] and r[ERROR] <= bound]
    return min(ok, key=lambda r: r[NOISE]) if ok else None


def _label(r: dict[str, Any]) -> str:
    return f"{r['u_inj_V']:g} V / {r['f_inj_Hz'] / 1000:g} kHz"


def figure(rows: list[dict[str, Any]], rec: dict[str, Any] | None, default: dict[str, Any],
           limit: float, path: Path, dpi: int) -> None:
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    freqs = sorted({r["f_inj_Hz"] for r in rows})
    cmap = plt.get_cmap("viridis")
    colour = {f: cmap(i / max(1, len(freqs) - 1)) for i, f in enumerate(freqs)}
    fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    for ax, x, xlabel, logx in ((axes[0], NOISE, "thrust ripple under load, dB(A) re 1 N "
                                 "(relative, not an SPL)", False),
                                (axes[1], LOSS, "injection copper loss under load (W)", True)):
        for f in freqs:
            rr = [r for r in rows if r["f_inj_Hz"] == f]
            good = [r for r in rr if r["valid"] == r["seeds"]]
            bad = [r for r in rr if r["valid"] != r["seeds"]]
            ax.errorbar([r[x] for r in good], [r[ERROR] for r in good],
                        yerr=[r[ERROR + ".sd"] for r in good], fmt="o", ms=4, capsize=2,
                        color=colour[f], label=f"{f / 1000:g} kHz")
            for r in good:
                ax.annotate(f"{r['u_inj_V']:g}", (r[x], r[ERROR]), fontsize=6,
                            xytext=(3, 2), textcoords="offset points", color=colour[f])
            if bad:
                ax.plot([r[x] for r in bad], [r[ERROR] for r in bad], "x", color=colour[f],
                        ms=7)
        front = pareto(rows, x, ERROR)
        ax.plot([r[x] for r in front], [r[ERROR] for r in front], "-", color="k", lw=1,
                label="Pareto front")
        ax.axhline(limit, color="r", ls="--", lw=1,
                   label=f"load-step limit {limit:g} (rule: mean + 2 sd)")
        ax.plot(default[x], default[ERROR], "s", mfc="none", mec="k", ms=12,
                label=f"default {_label(default)}")
        if rec is not None:
            ax.plot(rec[x], rec[ERROR], "*", color="r", ms=15,
                    label=f"recommended {_label(rec)}")
        ax.set_yscale("log")
        if logx:
            ax.set_xscale("log")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("steady RMS position error under load (el. rad)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7, loc="lower left")
    fig.suptitle("Square-wave injection: position error against audible thrust ripple and "
                 "copper loss (load step, adaptive SOGI; mean ± sd over seeds; numbers: "
                 "u_inj V; x: a seed faulted)", fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def _fmt(r: dict[str, Any], col: str, fmt: str) -> str:
    v = r[col]
    return "–" if not np.isfinite(v) else fmt.format(v)


def _delta(a: dict[str, Any], b: dict[str, Any]) -> str:
    return (f"thrust ripple {a[NOISE] - b[NOISE]:+.1f} dB(A), phase current "
            f"{a['steady.phase_current_dBA'] - b['steady.phase_current_dBA']:+.1f} dB(A), "
            f"copper loss {a[LOSS] / b[LOSS]:.2f}x ({a[LOSS]:.3f} W against {b[LOSS]:.3f} W), "
            f"steady RMS error {a[ERROR] / b[ERROR]:.2f}x ({a[ERROR]:.4f} against "
            f"{b[ERROR]:.4f} el. rad), steady max {a['steady.pos_max']:.3f} against "
            f"{b['steady.pos_max']:.3f}, load-step max {a['transient.pos_max']:.3f} against "
            f"{b['transient.pos_max']:.3f} el. rad")


def render(rdir: Path, out: Path, dpi: int = 80, elapsed_s: float | None = None,
           dt_dir: Path | None = None) -> tuple[Path, dict[str, Any] | None]:
    """docs/audible_noise.md, .json and the figure from the campaigns' results (the
    dead-time check's in ``dt_dir``, when given and there)."""
    dt_rows = None
    if dt_dir is not None:
        dres = load_results(dt_dir)
        if not dres:
            raise FileNotFoundError(f"{dt_dir}: no results (run without --render-only first)")
        dt_rows = deadtime_rows(dres)
    res = load_results(rdir)
    if not res:
        raise FileNotFoundError(f"{rdir}: no results (run without --render-only first)")
    c = load_campaign(CAMPAIGN, SM.METRIC_NAMES)
    limit = accuracy_limit()
    rows = summarise(res)
    default = next(r for r in rows if (r["u_inj_V"], r["f_inj_Hz"]) == DEFAULT)
    rec = recommend(rows, limit)
    same = same_accuracy(rows, default)
    front = pareto(rows, NOISE, ERROR)
    front_loss = pareto(rows, LOSS, ERROR)
    fig = out / "figures" / "audible_pareto.png"
    figure(rows, rec, default, limit, fig, dpi)
    n_runs = len(res["run"])
    seeds = sorted({json.loads(p).get("seed", 0) for p in res["params"]})
    data = {"campaign": c.name, "runs": n_runs, "seeds": seeds, "accuracy_limit_rad": limit,
            "rule": RULE.format(limit=limit), "default": default, "recommended": rec,
            "same_accuracy": same,
            "pareto_noise": [(r["u_inj_V"], r["f_inj_Hz"]) for r in front],
            "pareto_loss": [(r["u_inj_V"], r["f_inj_Hz"]) for r in front_loss],
            "settings": rows, "dead_time_check": dt_rows}
    out.mkdir(parents=True, exist_ok=True)
    (out / "audible_noise.json").write_text(json.dumps(data, indent=1, allow_nan=True) + "\n")
    md = _markdown(rows, front, front_loss, default, rec, same, limit, n_runs, len(seeds),
                   elapsed_s, dt_rows)
    path = out / "audible_noise.md"
    path.write_text(md)
    return path, rec


def _markdown(rows: list[dict[str, Any]], front: list[dict[str, Any]],
              front_loss: list[dict[str, Any]], default: dict[str, Any],
              rec: dict[str, Any] | None, same: dict[str, Any] | None, limit: float,
              n_runs: int, n_seeds: int, elapsed_s: float | None,
              dt_rows: list[dict[str, Any]] | None = None) -> str:
    on_front = {(r["u_inj_V"], r["f_inj_Hz"]) for r in front}
    on_loss = {(r["u_inj_V"], r["f_inj_Hz"]) for r in front_loss}
    d_load = [r[NOISE] - r["before.thrust_ripple_dBA"] for r in rows
              if r["u_inj_V"] >= 20.0 and np.isfinite(r[NOISE] - r["before.thrust_ripple_dBA"])]
    lo_d, hi_d = (min(d_load), max(d_load)) if d_load else (math.nan, math.nan)
    L: list[str] = []
    add = L.append
    add("# Audible noise against accuracy: choosing the injection\n")
    add("*Generated by `python tools/audible_noise.py` from the campaign "
        "`campaigns/audible_noise.yaml` (" + f"{n_runs} runs" +
        (f", {elapsed_s:.0f} s on this machine" if elapsed_s is not None else "") +
        "); do not edit by hand. The numbers are in [audible_noise.json](audible_noise.json)."
        "*\n")
    add("The square-wave injection (method.md §3) puts a current at f_inj into the motor; "
        "the default 3 kHz sits where hearing is most sensitive. This page measures, on the "
        "simulated drive, what each injection amplitude u_inj_V and frequency f_inj_Hz costs "
        "in audible thrust ripple, HF current and copper loss, and what it buys in position "
        "accuracy, and picks a default from the trade-off.\n")
    add("## What is measured\n")
    add("The paper's load step (`paper_salient`, adaptive SOGI, 100 r/min, 2 N·m at 0.5 s; "
        f"{n_seeds} noise seeds per setting) for every u_inj_V in "
        + ", ".join(f"{u:g}" for u in sorted({r['u_inj_V'] for r in rows}))
        + " V and f_inj_Hz in "
        + ", ".join(f"{f:g}" for f in sorted({r['f_inj_Hz'] for r in rows}))
        + " Hz. The firmware takes an injection frequency only when f_pwm / f_inj is an even "
        "integer from 4 to 64 (`fw_config_check`, protocols/od.yaml): at 24 kHz PWM 6 kHz is "
        "the highest (4 samples per period), then 4, 3, 2.4, 2, 1.71, 1.5, ... kHz. Windows: "
        "*steady* = 0.7–1.0 s (with the load; levels, loss and the accuracy figures), "
        "*before* = 0.2–0.5 s (no load, the mover against friction), *transient* = "
        "0.5–0.7 s (the load step). Only the injection changes: the PLL and current-loop "
        "gains are the nominal ones (the PLL's w ≈ 29 rad/s is far below its f_inj / 40 "
        "design bound even at 1 kHz).\n")
    add("The metrics (`sim_fallback/metrics.py`, `AUDIBLE_DEFS`; one definition each, "
        "tests in `tests/python/test_audible_metrics.py` against analytic references):\n")
    add(SM.audible_definitions_markdown() + "\n")
    add("Why these, and what they are not:\n")
    add("* **The thrust ripple drives the noise.** A linear motor radiates sound from its "
        "mover, secondary and frame, which vibrate under the force ripple; magnetostriction "
        "(the other source) is not modelled. How loud a given force ripple sounds depends on "
        "the mechanics (structure, mounting, radiation, distance), which the simulator does "
        "not have, so **the levels are relative figures for comparing settings on one "
        "machine, in dB(A) re 1 N and re 1 A, not sound pressure levels**. Under load the "
        "injection's thrust ripple is mostly the reluctance force k (L_d − L_q) i_d,hf i_q "
        "(the HF current on the d axis times the load current), so it grows with the load "
        f"(the *no load* column is {lo_d:.1f}–{hi_d:.1f} dB lower from 20 V up).\n")
    add("* **A-weighting** (IEC 61672-1's analytic curve, `a_weighting_db`: 0.0 dB at 1 kHz, "
        "−19.1 dB at 100 Hz, +1.2 dB at 2–3 kHz, −0.1 dB at 6 kHz) over 20 Hz–20 kHz: the "
        "band edge at 20 Hz leaves out the steady thrust, the motion and the electrical "
        "fundamental (6.7 Hz at 100 r/min); their harmonics above 20 Hz count, weighted "
        "(−44 dB at 30 Hz). Between 1 and 6 kHz the curve is flat within 1.3 dB, so **the "
        "frequency matters through the current it makes (∝ u_inj / f_inj), not through the "
        "weighting**: getting out of the ear's most sensitive range would need f_inj above "
        "~10 kHz, i.e. a PWM of at least 40 kHz (4 samples per injection period).\n")
    add("* **The record is the control rate's** (24 kHz, one sample per PWM period). The "
        "plant holds the inverter's voltage over each period (average model), so its current "
        "and thrust run nearly straight between samples; the metrics read the record as "
        "those straight lines (`band_weights`, `mean_square`, hold linear), which reproduces "
        "a triangle wave's Fourier series to 20 kHz exactly, beyond the record's 12 kHz "
        "Nyquist frequency. Read as bare samples, a 6 kHz triangle's fundamental and mean "
        "square would be 1.8 dB too high (0.5 dB at 3 kHz), a bias against the higher "
        "frequencies. The switching ripple at 24 kHz and its sidebands (an average-model "
        "inverter has none) and dead time are not in these numbers.\n")
    add("* **The copper loss** is the HF part's (the current minus its moving mean over one "
        "injection period), with the plant's R; the HF *iron* loss, which grows with "
        "frequency, is not modelled.\n")
    add("## Pareto front\n")
    add("![audible_pareto.png](figures/audible_pareto.png)\n")
    add("Left: steady RMS position error against the A-weighted thrust-ripple level under "
        "load; right: against the injection's copper loss (both axes: lower is better; mean "
        "± sd over seeds; the black line joins the settings no other all-valid setting beats "
        "in both). Settings on the front, quietest first:\n")
    add("| setting | thrust ripple dB(A) | steady RMS error el. rad | copper loss W | on the "
        "copper-loss front |")
    add("|---|---|---|---|---|")
    for r in front:
        add(f"| {_label(r)} | {r[NOISE]:.1f} | {r[ERROR]:.4f} ± {r[ERROR + '.sd']:.4f} | "
            f"{r[LOSS]:.3f} | {'yes' if (r['u_inj_V'], r['f_inj_Hz']) in on_loss else 'no'} |")
    add("")
    add("## Recommended default\n")
    worst = [r for r in rows if r["valid"] == r["seeds"] and r[ERROR + ".max"] <= limit]
    edge = min(worst, key=lambda r: r[NOISE]) if worst else None
    add("The rule: " + RULE.format(limit=f"{limit:g}") + "."
        + (f" The margin is there because the worst of {default['seeds']} seeds alone is a "
           f"weak guarantee: that rule would pick {_label(edge)} (worst seed "
           f"{edge[ERROR + '.max']:.4f}, but mean + 2 sd "
           f"{edge[ERROR] + 2 * edge[ERROR + '.sd']:.4f}: a few runs in a hundred beyond "
           "the limit)." if edge is not None and edge is not rec else "") + "\n")
    if rec is None:
        add("**No setting qualifies**: keep the default.\n")
    else:
        add(f"**Recommended: u_inj_V = {rec['u_inj_V']:g} V, f_inj_Hz = "
            f"{rec['f_inj_Hz']:g} Hz** (the default is {_label(default)}). Against the "
            f"default: {_delta(rec, default)}. Its steady RMS error is "
            f"{rec[ERROR]:.4f} ± {rec[ERROR + '.sd']:.4f} el. rad (worst seed "
            f"{rec[ERROR + '.max']:.4f}; mean + 2 sd "
            f"{rec[ERROR] + 2 * rec[ERROR + '.sd']:.4f} ≤ {limit:g}).\n")
    if same is not None:
        add(f"**Without giving up accuracy**: the quietest setting whose mean steady RMS "
            f"error stays within the default's mean + 1 sd "
            f"({default[ERROR] + default[ERROR + '.sd']:.4f} el. rad) is {_label(same)}: "
            f"{_delta(same, default)}.\n")
    at3 = [r for r in rows if r["f_inj_Hz"] == DEFAULT[1] and eligible(r, limit)]
    alt = min(at3, key=lambda r: r[NOISE]) if at3 else None
    if alt is not None and alt is not rec:
        add(f"**Keeping {DEFAULT[1] / 1000:g} kHz** (no new frequency to validate): the "
            f"quietest setting there that meets the rule is {_label(alt)}: "
            f"{_delta(alt, default)}.\n")
    by = {(r["u_inj_V"], r["f_inj_Hz"]): r for r in rows}
    same_i = [by[k] for k in ((20.0, 1000.0), (40.0, 2000.0), (80.0, 4000.0)) if k in by]
    add("Why the higher frequency at a higher amplitude: at the same HF current "
        "(u_inj / f_inj constant) the thrust ripple and the phase-current level are nearly "
        "the same (A-weighting is flat from 1 to 6 kHz), but the higher frequency gives more "
        "demodulated periods per second, so the estimate is better"
        + (" (" + "; ".join(f"{_label(r)}: {r[NOISE]:.1f} dB(A), {r[ERROR]:.4f} el. rad"
                            for r in same_i) + ")" if same_i else "")
        + ". The copper loss falls with the current.\n")
    if dt_rows:
        add("## With a real inverter's dead time\n")
        add("The settings above were measured with an ideal inverter. A real one inserts dead "
            "time at every edge, a voltage error of u_dc t_d f_pwm against the current's "
            "sign, which distorts the injected square wave by a fixed volt-second per edge, "
            "i.e. more at a higher f_inj. `campaigns/audible_deadtime.yaml` repeats the "
            "default and the two 6 kHz candidates with 1 µs of dead time in the plant, with "
            "the drive's dead-time compensation (`dt_comp_s`, docs/method.md) and without it "
            f"({dt_rows[0]['seeds']} seeds each):\n")
        add("| inverter | setting | valid | faults | steady RMS error el. rad | steady max | "
            "load-step max | thrust ripple dB(A) | copper loss W |")
        add("|---|---|---|---|---|---|---|---|---|")
        for r in dt_rows:
            rms = _fmt(r, ERROR, "{:.4f}") + (f" ± {r[ERROR + '.sd']:.4f}"
                                               if np.isfinite(r[ERROR + ".sd"]) else "")
            add(f"| {r['inverter']} | {r['setting']} | {r['valid']}/{r['seeds']} | "
                f"{', '.join(r['faults']) or '–'} | {rms} | "
                f"{_fmt(r, 'steady.pos_max', '{:.3f}')} | "
                f"{_fmt(r, 'transient.pos_max', '{:.3f}')} | {_fmt(r, NOISE, '{:.1f}')} | "
                f"{_fmt(r, LOSS, '{:.3f}')} |")
        add("")
        bad = [r for r in dt_rows if r["valid"] < r["seeds"]]
        comp = [r for r in dt_rows if "compensated" in r["inverter"]
                and "not" not in r["inverter"]]
        add("Uncompensated, " + ("every setting faults" if bad and all(
            r["valid"] == 0 for r in dt_rows if "not compensated" in r["inverter"])
            else "some settings fault") + " (the back-EMF witness sees the missing volts "
            "as a wrong speed: docs/integrity.md); compensated, " + (
                "every setting runs and keeps its ideal-inverter figures within the seed "
                "spread" if comp and all(r["valid"] == r["seeds"] for r in comp)
                else "not every setting runs") + ": the 6 kHz recommendation stands with a "
            "real inverter provided the drive knows its dead time.\n")
    add("## The shipped default\n")
    add(f"The firmware's default stays {DEFAULT[0]:g} V / {DEFAULT[1] / 1000:g} kHz "
        "(protocols/od.yaml `u_inj_V`, `f_inj_Hz`) for now, and the recommendation above "
        "is what to set where acoustic noise matters: the paper's method and every pinned "
        "figure of docs/reproduction.md, the identification and the integrity monitors' "
        "thresholds were measured at it, and changing it moves them all at once. What these "
        "simulations cannot show must be checked on a rig before the default moves: 6 kHz "
        "is the firmware's highest frequency at 24 kHz PWM (4 samples per injection "
        "period); the HF iron loss grows with frequency (not modelled); and the motor's "
        "mechanics decide whether a 6 kHz force is quieter than a 3 kHz one of the same "
        "A-weighted level (a microphone beside the mover settles it).\n")
    add("## Every setting\n")
    add("Mean over the valid seeds (± sd for the steady RMS error); ◆ on the thrust-ripple "
        "Pareto front; ✓ meets the accuracy criterion; faults: the codes of the seeds that "
        "faulted (docs/integrity.md).\n")
    add("| u_inj V | f_inj Hz | valid | faults | " + " | ".join(h for _, h, _ in COLUMNS)
        + " | front | criterion |")
    add("|" + "---|" * (len(COLUMNS) + 6))
    for r in rows:
        cells = []
        for col, _, fmt in COLUMNS:
            s = _fmt(r, col, fmt)
            if col == ERROR and np.isfinite(r[col + ".sd"]):
                s += f" ± {r[col + '.sd']:.4f}"
            cells.append(s)
        key = (r["u_inj_V"], r["f_inj_Hz"])
        mark = " (default)" if key == DEFAULT else ""
        add(f"| {r['u_inj_V']:g}{mark} | {r['f_inj_Hz']:g} | {r['valid']}/{r['seeds']} | "
            f"{', '.join(r['faults']) or '–'} | " + " | ".join(cells)
            + f" | {'◆' if key in on_front else ''} | {'✓' if eligible(r, limit) else ''} |")
    add("")
    add("## Not done: a spread-spectrum injection\n")
    add("A pseudo-random or frequency-hopping square wave spreads the injection's tone over "
        "a band, which lowers the peak (and the tonal annoyance) more than the A-weighted "
        "level. The firmware does not support it: `fw_inj.c` has one period of n_inj "
        "samples (`f_pwm / f_inj`), the SOGI and the demodulation are tuned to that one "
        "frequency, and the moving-average notch of the pseudo-filter path needs a fixed "
        "period. It would need a random-polarity sequence with a matched demodulation "
        "(the sign of each half period known to the demodulator) and an extractor that does "
        "not assume one frequency; this campaign's metrics would measure it unchanged "
        "(a tonality or peak-level figure beside the A-weighted one would then be worth "
        "adding).\n")
    add("Regenerate: `python tools/audible_noise.py` (about half a minute: "
        f"{n_runs} runs of 1 s on 2 workers); `--render-only` rewrites this page from the "
        "last results; the campaign alone: `bench campaign campaigns/audible_noise.yaml`.\n")
    return "\n".join(L)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--serial", action="store_true", help="no Dask: a plain loop")
    ap.add_argument("--workers", type=int, default=2, metavar="N",
                    help="local cluster size (default 2)")
    ap.add_argument("--out", type=Path, default=REPO / "docs",
                    help="where audible_noise.md/.json and figures/ go (default docs/)")
    ap.add_argument("--results", type=Path, default=REPO / "runs" / "audible_noise",
                    help="campaign results root (default runs/audible_noise/)")
    ap.add_argument("--render-only", action="store_true",
                    help="no simulation: render from the results already there")
    ap.add_argument("--dpi", type=int, default=80, help="figure resolution (default 80)")
    a = ap.parse_args(argv)
    if not 1 <= a.workers <= 1024:
        print(f"audible_noise: --workers {a.workers}: allowed 1..1024", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    try:
        if a.render_only:
            rdir, dt_dir = (a.results / load_campaign(f, SM.METRIC_NAMES).name
                            for f in (CAMPAIGN, CAMPAIGN_DT))
        else:
            rdir, dt_dir = run(a.results, a.serial, a.workers)
        path, rec = render(rdir, a.out, a.dpi,
                           None if a.render_only else time.perf_counter() - t0, dt_dir)
    except CampaignError as e:
        print(f"audible_noise: {e}", file=sys.stderr)
        return 2
    except (FileNotFoundError, RuntimeError) as e:
        print(f"audible_noise: {e}", file=sys.stderr)
        return 1
    except OSError as e:
        print(f"audible_noise: {e}", file=sys.stderr)
        return 3
    print(f"wrote {path}, audible_noise.json and figures/audible_pareto.png "
          f"({time.perf_counter() - t0:.1f} s); recommended: "
          + (_label(rec) if rec else "none qualifies"))
    return 0 if rec is not None else 1


if __name__ == "__main__":
    raise SystemExit(main())
