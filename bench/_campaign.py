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

import functools
import itertools
import json
import math
import time
import traceback
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

SCENARIOS = ("load_step", "speed_reversal", "startup", "fault_case")
#: Metrics of a fault_case run (sim_fallback._faults.run_case), beside the drive metrics.
FAULT_CASE_METRICS = ("blind_max_s", "rms_rad", "max_rad", "t_fault_s", "pwm_off_after_s",
                      "verdict_ok")
METHODS = ("grid", "random", "lhs")
STATS = ("mean", "max", "min", "p50", "p90", "p95", "p99", "fail_fraction")


class CampaignError(ValueError):
    """A campaign file is wrong; ``str()`` is one line per problem, file:line: field: what."""


@dataclass
class Axis:
    """One varied parameter: ``target`` is 'seed', 'noise', 'x0_m', 'plant.<field>' or
    'fw.<field>'; the value is drawn from ``values`` (discrete), ``range``
    [lo, hi] (absolute) or ``scale`` [lo, hi] (times the nominal value)."""

    target: str
    kind: str
    spec: list[Any]

    def value(self, u: float) -> Any:
        """Map u in [0, 1) to this axis's value."""
        if self.kind == "values":
            v = self.spec[min(int(u * len(self.spec)), len(self.spec) - 1)]
            return v if isinstance(v, str) else float(v)
        lo, hi = self.spec
        v = lo + (hi - lo) * u
        return float(int(v)) if self.target == "seed" else float(v)

    def grid(self) -> list[Any]:
        if self.kind == "values":
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
            r.setdefault("seed", float(k))
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


def load_campaign(path: str | Path, metric_names: Iterable[str] | None = None) -> Campaign:
    """Read and validate a campaign file. Raises CampaignError naming file:line: field."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise CampaignError(f"{p}: cannot read campaign file: {e}") from None
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise CampaignError(f"{p}: not valid YAML: {str(e).splitlines()[0]}") from None
    return parse_campaign(data, root, p, metric_names)


def parse_campaign(data: Any, root: yaml.Node | None, p: Path | None,
                   metric_names: Iterable[str] | None = None) -> Campaign:
    errs: list[str] = []
    where = str(p) if p else "<campaign>"

    def err(node: yaml.Node | None, fld: str, msg: str) -> None:
        errs.append(f"{where}:{_line(node)}: {fld}: {msg}")

    if not isinstance(data, dict) or not isinstance(root, yaml.MappingNode):
        raise CampaignError(f"{where}:1: (top level): must be a mapping with name, base, axes")
    for key in ("name", "base", "axes", "metrics"):
        if key not in data:
            err(root, key, "missing")
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
        from sim_fallback._faults import CASES
        names = case_names = [c.name for c in CASES]
        if "case" not in data.get("axes", {}) and base.get("case") not in names:
            err(bnode, "base.case", f"{base.get('case')!r} is not a fault case ({len(names)} "
                "listed in docs/fault_matrix.md)")
    samp = data.get("sampling", {"method": "grid"})
    snode = _find(root, "sampling")
    method = samp.get("method", "grid") if isinstance(samp, dict) else None
    if method not in METHODS:
        err(snode, "sampling.method", f"{method!r} not one of {', '.join(METHODS)}")
    n = samp.get("n", 0) if isinstance(samp, dict) else 0
    if method in ("random", "lhs") and not (isinstance(n, int) and 1 <= n <= 10_000_000):
        err(snode, "sampling.n", f"{n!r}: need an integer in [1, 10000000]")
    sseed = samp.get("seed", 0) if isinstance(samp, dict) else 0
    if not isinstance(sseed, int) or sseed < 0:
        err(snode, "sampling.seed", f"{sseed!r}: need an integer >= 0")
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
        ok_target = (tgt in ("seed", "noise", "x0_m") or str(tgt).startswith("plant.")
                     or str(tgt).startswith("fw."))
        if not ok_target:
            err(node, fld, "target must be seed, noise, x0_m, case, plant.<field> or "
                "fw.<field>")
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
            err(node, fld, f"{kind} must be a non-empty list of finite numbers")
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
        axes.append(Axis(str(tgt), kind, [float(v) for v in vals]))
    metrics = data.get("metrics", [])
    mnode = _find(root, "metrics")
    known = set(metric_names) if metric_names is not None else None
    if known is not None and sc == "fault_case":
        known |= set(FAULT_CASE_METRICS)
    if not isinstance(metrics, list) or not metrics:
        err(mnode, "metrics", "need a non-empty list of metric names")
        metrics = []
    for m in metrics:
        if known is not None and m not in known:
            err(mnode, "metrics", f"unknown metric {m!r}; known: {', '.join(sorted(known))}")
    limits: list[Limit] = []
    lnode = _find(root, "limits")
    for i, lim in enumerate(data.get("limits", []) or []):
        fld = f"limits[{i}]"
        if not isinstance(lim, dict) or lim.get("metric") not in metrics:
            err(lnode, fld, "metric must be one of the campaign's metrics")
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
        total = int(np.prod([len(a.grid()) for a in axes]))
        if total > 10_000_000:
            err(anode, "axes", f"grid of {total} runs; use sampling random or lhs")
    if errs:
        raise CampaignError("\n".join(errs))
    return Campaign(str(data["name"]), p, dict(base), method or "grid",
                    int(n) if method != "grid" else 0, int(sseed), axes, list(metrics), limits)


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
        row["error"] = f"{type(e).__name__}: {e}"
        row["traceback"] = traceback.format_exc(limit=5)
        for m in metrics:
            row[m] = float("nan")
    row["wall_s"] = time.perf_counter() - t0
    return row


def run_chunk(base: dict[str, Any], chunk: list[dict[str, Any]],
              metrics: list[str]) -> list[dict[str, Any]]:
    """Several runs in one task: a run costs milliseconds, a task's round trip
    through the scheduler about as much, so tasks carry chunks of runs."""
    return [run_one(base, p, metrics) for p in chunk]


def _split(params: dict[str, Any]) -> tuple[dict[str, float], dict[str, float], dict[str, Any]]:
    plant = {k[6:]: v for k, v in params.items() if k.startswith("plant.")}
    fw = {k[3:]: v for k, v in params.items() if k.startswith("fw.")}
    rest = {k: v for k, v in params.items() if "." not in k and k not in ("run", "case")}
    return plant, fw, rest


@functools.lru_cache(maxsize=16)
def _motor_and_config(motor: str, extractor: str) -> tuple[Any, Any]:
    """Motor file and its nominal configuration, parsed once per worker process."""
    from sim_fallback import fw_config, load_motor
    mot = load_motor(motor)
    return mot, fw_config(mot, extractor)


def _simulate(base: dict[str, Any], params: dict[str, Any],
              metrics: list[str]) -> dict[str, Any]:
    from sim_fallback import paper_scenario

    plant, fw, rest = _split(params)
    seed = int(rest.get("seed", 0))
    scales = base.get("_scales", {})
    if base.get("scenario") == "fault_case":
        from sim_fallback._faults import CASES, run_case
        name = params.get("case", base.get("case"))
        case = next(c for c in CASES if c.name == name)
        r = run_case(case, seed)
        out = {k: r[k] for k in ("case", "doc", "fault_name", "why")}
        out.update(fault=int(r["fault"] or 0), verdict_ok=float(bool(r["verdict"])))
        for m in FAULT_CASE_METRICS:
            if m != "verdict_ok":
                out[m] = float(r[m]) if r.get(m) is not None else float("nan")
        return out
    # scale axes multiply the nominal value (motor plant / derived configuration)
    motor, nominal_fw = _motor_and_config(base.get("motor", "paper_salient"),
                                          base.get("extractor", "sogi_adaptive"))
    fw_abs = {k: (float(getattr(nominal_fw, k)) * v if scales.get("fw." + k) else v)
              for k, v in fw.items()}
    plant_abs = {k: (float(motor.plant[k]) * v if scales.get("plant." + k) else v)
                 for k, v in plant.items()}
    kw: dict[str, Any] = {"t_end": float(base.get("t_end", 1.0)),
                          "record_decimation": int(base.get("record_decimation", 8)),
                          "channels": []}  # only what the metrics need
    if "noise" in rest:
        kw["noise"] = float(rest["noise"])
    if "x0_m" in rest:
        kw["x0_m"] = float(rest["x0_m"])
    r = paper_scenario(base.get("scenario", "load_step"),
                       extractor=base.get("extractor", "sogi_adaptive"), motor=motor,
                       seed=seed, plant=plant_abs or None, fw=fw_abs or None, **kw)
    out = {"fault": int(r.fault_code)}
    for m in metrics:
        out[m] = float(r.metrics.get(m, float("nan")))
    return out


# ---- running -----------------------------------------------------------------


def results_dir(c: Campaign, out: Path) -> Path:
    return out / c.name


def done_runs(rdir: Path) -> set[int]:
    """Run numbers already in the Parquet dataset (resume)."""
    import pyarrow.parquet as pq
    done: set[int] = set()
    for f in sorted(rdir.glob("part-*.parquet")):
        try:
            done.update(int(x) for x in pq.read_table(f, columns=["run"]).column(0).to_pylist())
        except Exception:  # noqa: BLE001 - a torn last file (killed mid-write) is redone
            f.unlink()
    return done


def _write_part(rdir: Path, rows: list[dict[str, Any]]) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq
    k = len(list(rdir.glob("part-*.parquet")))
    tmp = rdir / f".part-{k:06d}.tmp"
    pq.write_table(pa.Table.from_pylist(rows), tmp)
    tmp.replace(rdir / f"part-{k:06d}.parquet")  # atomic: a kill leaves no torn file


def run_campaign(c: Campaign, out: Path, scheduler: str | None = None,
                 workers: int | None = None, serial: bool = False, batch: int = 64,
                 progress: Callable[[int, int, float], None] | None = None) -> Path:
    """Run every run not yet in the results; return the results folder."""
    rdir = results_dir(c, out)
    rdir.mkdir(parents=True, exist_ok=True)
    (rdir / "campaign.json").write_text(json.dumps(
        {"name": c.name, "file": str(c.path), "base": c.base, "method": c.method, "n": c.n,
         "sampling_seed": c.sampling_seed, "metrics": c.metrics,
         "axes": [[a.target, a.kind, a.spec] for a in c.axes]}, indent=1))
    base = dict(c.base)
    base["_scales"] = {a.target: a.kind == "scale" for a in c.axes}
    todo = [r for r in c.runs() if r["run"] not in done_runs(rdir)]
    total, t0, buf, finished = len(todo), time.perf_counter(), [], 0

    def emit(row: dict[str, Any]) -> None:
        nonlocal finished
        buf.append(row)
        finished += 1
        if len(buf) >= batch:
            _write_part(rdir, buf)
            buf.clear()
        if progress:
            progress(finished, total, time.perf_counter() - t0)

    try:
        if serial or total == 0:
            for r in todo:
                emit(run_one(base, r, c.metrics))
        else:
            from dask.distributed import Client, LocalCluster, as_completed
            if scheduler:
                client = Client(scheduler)
                cluster = None
            else:
                import logging
                import os
                cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1,
                                       threads_per_worker=1, processes=True,
                                       dashboard_address=None, host="127.0.0.1",
                                       silence_logs=logging.ERROR)
                client = Client(cluster)
            try:
                n_workers = max(1, len(client.scheduler_info().get("workers", {})) or 1)
                size = max(1, min(64, total // (8 * n_workers)))
                chunks = [todo[i:i + size] for i in range(0, total, size)]
                futs = client.map(run_chunk, [base] * len(chunks), chunks,
                                  [c.metrics] * len(chunks), pure=False)
                for fut in as_completed(futs):
                    for row in fut.result():
                        emit(row)
                    fut.release()
            finally:
                client.close()
                if cluster is not None:
                    cluster.close()
    finally:
        if buf:
            _write_part(rdir, buf)
    return rdir


def load_results(rdir: Path) -> Any:
    """All runs of a campaign as a pandas-free dict of numpy columns."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    parts = [pq.read_table(f) for f in sorted(rdir.glob("part-*.parquet"))]
    if not parts:
        return {}
    t = pa.concat_tables(parts, promote_options="default")
    return {name: np.asarray(t.column(name).to_pylist(), dtype=object)
            for name in t.column_names}


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
    """The one command that reruns a single run of a campaign."""
    return f"bench campaign {c.path} --replay {run}"


# ---- command line ------------------------------------------------------------


def add_parser(sub: Any) -> None:
    """``bench campaign`` on the bench's subcommand parser."""
    p = sub.add_parser(
        "campaign", help="run a campaign of simulated-drive runs (Dask), report distributions",
        description="Run every run of a campaign file not yet in its results (resumable), "
                    "on a local Dask cluster of all cores, an existing scheduler "
                    "(--scheduler) or serially; then write report.html beside the Parquet "
                    "results. Exit 0 when every limit holds, 1 when one fails, 2 for a bad "
                    "file or argument, 130 when interrupted (finished runs are kept).")
    p.add_argument("file", help="campaign YAML (see campaigns/)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="dask scheduler, e.g. tcp://host:8786")
    p.add_argument("--workers", type=int, metavar="N", help="local cluster size (default: cores)")
    p.add_argument("--serial", action="store_true", help="no Dask: a plain loop in this process")
    p.add_argument("--out", default="runs/campaigns", help="results root (default %(default)s)")
    p.add_argument("--replay", type=int, metavar="RUN", help="rerun one run alone and print it")
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
    if args.workers is not None and not 1 <= args.workers <= 1024:
        print(f"bench: --workers {args.workers}: allowed 1..1024", file=sys.stderr)
        return 2
    runs = c.runs()
    if args.replay is not None:
        if not 0 <= args.replay < len(runs):
            print(f"bench: --replay {args.replay}: campaign {c.name} has runs 0.."
                  f"{len(runs) - 1}", file=sys.stderr)
            return 2
        base = dict(c.base)
        base["_scales"] = {a.target: a.kind == "scale" for a in c.axes}
        row = run_one(base, runs[args.replay], c.metrics)
        print(json.dumps({k: v for k, v in row.items() if k != "traceback"}, indent=1))
        return 0 if row["error"] is None else 1
    other = Path(args.compare) if args.compare else None
    if other is not None and not any(other.glob("part-*.parquet")):
        print(f"bench: --compare {other}: no campaign results (part-*.parquet) there",
              file=sys.stderr)
        return 2
    from tqdm import tqdm
    bar = tqdm(total=len(runs), unit="run", desc=c.name, file=sys.stderr)
    last = [0]

    def progress(done: int, total: int, elapsed: float) -> None:
        if bar.total != total:
            bar.reset(total=total)
        bar.update(done - last[0])
        last[0] = done

    interrupted = False
    try:
        rdir = run_campaign(c, Path(args.out), scheduler=args.scheduler, workers=args.workers,
                            serial=args.serial, progress=progress)
    except KeyboardInterrupt:
        interrupted = True
        rdir = results_dir(c, Path(args.out))
    except OSError as e:
        print(f"bench: campaign {c.name}: {e}", file=sys.stderr)
        return 3
    finally:
        bar.close()
    from bench._campaign_report import write_report
    res = load_results(rdir)
    report = write_report(c, rdir, other)
    verdicts = judge(c, res)
    for v in verdicts:
        print(f"{'pass' if v['ok'] else 'FAIL'}  {v['stat']}({v['metric']}) = {v['value']:.4g}"
              f"  limits [{v['min']}, {v['max']}]")
    print(f"{len(res.get('run', []))} runs in {rdir}; report {report}")
    if interrupted:
        print("bench: interrupted; run the same command again to resume", file=sys.stderr)
        return 130
    return 0 if all(v["ok"] for v in verdicts) else 1
