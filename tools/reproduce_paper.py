#!/usr/bin/env python3
"""Reproduce the seed paper's simulations on the simulated drive, in one command.

    python tools/reproduce_paper.py                # local Dask cluster, writes docs/
    python tools/reproduce_paper.py --serial       # the same in this process
    python tools/reproduce_paper.py --quick        # seed 0 only, writes build/reproduce_quick/
    python tools/reproduce_paper.py --render-only  # the report again from the last results

The simulations are the campaigns in campaigns/reproduction/ (the paper's three
scenarios for the three extractors over 20 seeds, the sweeps, the sensing floor and
the paper's own Table 1 machine; docs/campaigns.md, "The paper reproduction"), run
by the campaign runner (simcampaign/_campaign.py) into fresh Parquet results
(runs/reproduction/<campaign>/). The report is rendered from those results only
(simcampaign/_reproduction.py):

    <out>/reproduction.md     tables, the paper's claims beside ours with verdicts, discussion
    <out>/reproduction.json   every number of the tables, as data
    <out>/figures/*.png       figures analogous to the paper's Figs. 6-11, and the sweeps

Exit codes: 0 done and every campaign limit holds; 1 a limit fails or a run failed
(the report is still written when possible; no results for --render-only); 2 a bad
campaign file or argument; 3 a results folder that cannot be used (a damaged Parquet part,
results of another campaign).
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

try:  # first: one line, not a traceback, outside the venv (not when loaded as a module)
    import _project_env  # noqa: F401
except ModuleNotFoundError:
    pass

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from simcampaign import (  # noqa: E402
    Axis,
    Campaign,
    CampaignError,
    judge,
    load_campaign,
    load_results,
    render,  # noqa: E402
    replay_command,
    run_campaigns,
)

CAMPAIGN_DIR = REPO / "campaigns" / "reproduction"


def campaigns(quick: bool = False) -> list[Campaign]:
    """The reproduction's campaigns; ``quick``: every seed axis cut to its first seed."""
    from sim_fallback.metrics import METRIC_NAMES

    out = []
    for f in sorted(CAMPAIGN_DIR.glob("*.yaml")):
        c = load_campaign(f, METRIC_NAMES)
        if quick:
            c = dataclasses.replace(c, axes=[Axis("seed", "values", a.grid()[:1])
                                             if a.target == "seed" else a for a in c.axes])
        out.append(c)
    return out


def run(results: Path, quick: bool = False, serial: bool = False, workers: int | None = None,
        log: Callable[[str], None] = print) -> list[str]:
    """Run every campaign into fresh results under ``results`` (one cluster for all);
    returns the failed limits and failed runs, one line each."""
    cs = campaigns(quick)
    for c in cs:  # fresh results: a resumed campaign would keep runs of an older build
        shutil.rmtree(results / c.name, ignore_errors=True)
    t0 = time.perf_counter()
    rdirs = run_campaigns(cs, results, workers=workers, serial=serial)
    failed = []
    for c, rdir in zip(cs, rdirs, strict=True):
        res = load_results(rdir)
        err_runs = [r for r, e in zip(res["run"], res["error"], strict=True) if e]
        errs = len(err_runs)
        bad = [f"{c.name}: {v['stat']}({v['metric']}) = {v['value']:.4g} outside "
               f"[{v['min']}, {v['max']}]" for v in judge(c, res) if not v["ok"]]
        failed += bad + ([f"{c.name}: {errs} runs failed (the first: "
                          f"{replay_command(c, int(err_runs[0]))})"] if errs else [])
        log(f"{c.name:34s} {len(res['run']):4d} runs, limits "
            + ("hold" if not bad else "FAIL") + (f", {errs} failed runs" if errs else ""))
    log(f"{sum(len(c.runs()) for c in cs)} runs in {time.perf_counter() - t0:.1f} s "
        f"({'serial' if serial else 'local Dask cluster'})")
    return failed


def reproduce(out: Path, results: Path, quick: bool = False, serial: bool = False,
              workers: int | None = None, dpi: int = 80,
              log: Callable[[str], None] = print) -> tuple[Path, list[str]]:
    """Run the campaigns and render the report into ``out``; returns the markdown's path
    and the failed limits."""
    t0 = time.perf_counter()
    failed = run(results, quick, serial, workers, log)
    path = render(results, out, quick=quick, elapsed_s=time.perf_counter() - t0, dpi=dpi)
    return path, failed


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="seed 0 only (a few seconds)")
    ap.add_argument("--serial", action="store_true", help="no Dask: a plain loop")
    ap.add_argument("--workers", type=int, metavar="N", help="local cluster size (default: "
                                                             "cores)")
    ap.add_argument("--out", type=Path, default=None,
                    help="report directory (reproduction.md/.json, figures/); default docs/, "
                         "or build/reproduce_quick/ with --quick (a smoke run never "
                         "overwrites the committed report)")
    ap.add_argument("--results", type=Path, default=None,
                    help="campaign results root (default runs/reproduction/, or "
                         "runs/reproduction_quick/ with --quick)")
    ap.add_argument("--render-only", action="store_true",
                    help="no simulation: render the report from the results already there")
    ap.add_argument("--dpi", type=int, default=80, help="figure resolution (default 80)")
    a = ap.parse_args(argv)
    if a.workers is not None and not 1 <= a.workers <= 1024:
        print(f"reproduce_paper: --workers {a.workers}: allowed 1..1024", file=sys.stderr)
        return 2
    if not 20 <= a.dpi <= 600:
        print(f"reproduce_paper: --dpi {a.dpi}: allowed 20..600", file=sys.stderr)
        return 2
    out = a.out or (REPO / "build" / "reproduce_quick" if a.quick else REPO / "docs")
    results = a.results or REPO / "runs" / ("reproduction_quick" if a.quick else "reproduction")
    try:
        if a.render_only:
            path = render(results, out, quick=a.quick, dpi=a.dpi)
            print(f"wrote {path}")
            return 0
        t0 = time.perf_counter()
        path, failed = reproduce(out, results, a.quick, a.serial, a.workers, a.dpi)
    except CampaignError as e:
        print(f"reproduce_paper: {e}", file=sys.stderr)
        return 2
    except (FileNotFoundError, RuntimeError) as e:
        print(f"reproduce_paper: {e}", file=sys.stderr)
        return 1
    except OSError as e:  # ResultsError: a damaged part, results of another campaign
        print(f"reproduce_paper: {e}", file=sys.stderr)
        return 3
    for f in failed:
        print(f"FAIL {f}")
    print(f"wrote {path}, reproduction.json and figures/ ({time.perf_counter() - t0:.1f} s)")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
