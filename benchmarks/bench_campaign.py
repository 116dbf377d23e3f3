"""Benchmark: campaign throughput, Dask local cluster vs a plain serial loop.

Prints simulated seconds per wall second for the same N short runs (paper load
step cut to --t-end seconds, recording decimated to what the metrics need),
run serially in this process and on a dask.distributed LocalCluster with one
single-threaded worker process per core, and their ratio (target >= 1.8x on 2
cores, >= 300 simulated s per wall s). Cluster start-up is included in the
Dask figure and printed separately.

Usage: python benchmarks/bench_campaign.py [--runs 200] [--t-end 0.5]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench._campaign import parse_campaign, run_campaign  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--t-end", type=float, default=0.5)
    a = ap.parse_args()
    text = (f"name: bench\nbase: {{scenario: load_step, t_end: {a.t_end}}}\n"
            f"sampling: {{method: random, n: {a.runs}, seed: 1}}\n"
            "axes:\n  seed: {range: [0, 1000000]}\nmetrics: [position_error_rms_rad]\n")
    c = parse_campaign(yaml.safe_load(text), yaml.compose(text), None)
    sim_s = a.runs * a.t_end
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        run_campaign(c, Path(tmp) / "serial", serial=True)
        ts = time.perf_counter() - t0
        from dask.distributed import Client, LocalCluster
        t0 = time.perf_counter()
        cl = LocalCluster(n_workers=os.cpu_count(), threads_per_worker=1,
                          dashboard_address=None, host="127.0.0.1")
        addr = cl.scheduler_address
        t_start = time.perf_counter() - t0
        t1 = time.perf_counter()
        run_campaign(c, Path(tmp) / "dask", scheduler=addr)
        td = time.perf_counter() - t1
        Client(addr).close()
        cl.close()
    print(f"{a.runs} runs x {a.t_end} s simulated, {os.cpu_count()} cores")
    print(f"serial loop:        {ts:7.2f} s wall, {sim_s / ts:7.1f} simulated s per wall s")
    print(f"dask local cluster: {td:7.2f} s wall, {sim_s / td:7.1f} simulated s per wall s "
          f"(+ {t_start:.2f} s cluster start)")
    print(f"ratio dask/serial:  {ts / td:.2f}x (with start-up: {ts / (td + t_start):.2f}x)")


if __name__ == "__main__":
    main()
