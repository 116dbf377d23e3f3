"""Benchmark: campaign throughput, Dask local cluster vs a plain serial loop.

Runs the same N short runs (paper load step cut to --t-end seconds, random seeds,
one metric, recording only what it needs) twice, back to back: serially in this
process (``run_campaign(serial=True)``) and on the local cluster ``bench campaign``
starts (``start_local_cluster``: one single-threaded worker process per core) through
one client (``run_campaign(scheduler=client)``),
both writing their Parquet results as usual. Prints simulated seconds per wall
second for each, their ratio, the cluster start-up (processes, imports, library
load: paid once per cluster, shown apart and in the "with start-up" ratio) and
the peak RSS of each worker. The issue's targets: >= 1.8x serial on 2 cores and
>= 300 simulated s per wall s. Prints figures, asserts nothing.

Usage: python benchmarks/bench_campaign.py [--runs 1000] [--t-end 0.5] [--repeat 1]
"""

from __future__ import annotations

import os

# One thread per process, here as in the workers (dask's nanny sets the same): a BLAS
# thread pool spinning in the client would take a core from the workers.
for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import yaml  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from simcampaign import (  # noqa: E402
    parse_campaign,
    peak_rss_mb,
    run_campaign,
    start_local_cluster,
    warm_worker,
    warm_writer,
)


def _busy_s() -> float | None:
    """CPU seconds all processes of the machine have used so far (Linux /proc/stat;
    None elsewhere): what other processes took while a figure was measured."""
    try:
        with open("/proc/stat") as f:
            v = [int(x) for x in f.readline().split()[1:]]
    except OSError:
        return None
    return (sum(v[:8]) - v[3] - v[4]) / os.sysconf("SC_CLK_TCK")  # all but idle, iowait


def _threads_cpu() -> tuple[float, float]:
    """(this process's main thread, its other threads): CPU seconds so far (Linux /proc;
    NaN elsewhere). In a worker the main thread runs dask's event loop and the runs go
    to its executor thread; in the client process the main thread runs the campaign
    loop and the other thread the event loop of the local scheduler, nannies and client."""
    import threading
    tick, mine, rest = os.sysconf("SC_CLK_TCK"), float("nan"), 0.0
    main_tid = threading.main_thread().native_id
    try:
        for tid in os.listdir("/proc/self/task"):
            with open(f"/proc/self/task/{tid}/stat") as f:
                v = f.read().rsplit(")", 1)[1].split()
            t = (int(v[11]) + int(v[12])) / tick  # utime, stime
            if int(tid) == main_tid:
                mine = t
            else:
                rest += t
    except OSError:
        return float("nan"), float("nan")
    return mine, rest


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--t-end", type=float, default=0.5)
    ap.add_argument("--repeat", type=int, default=1,
                    help="serial/cluster pairs, back to back (medians printed)")
    a = ap.parse_args()
    text = (f"name: bench\nbase: {{scenario: load_step, t_end: {a.t_end}}}\n"
            f"sampling: {{method: random, n: {a.runs}, seed: 1}}\n"
            "axes:\n  seed: {range: [0, 1000000]}\nmetrics: [position_error_rms_rad]\n")
    c = parse_campaign(yaml.safe_load(text), yaml.compose(text), None)
    sim_s = a.runs * a.t_end
    n_workers = os.cpu_count() or 1
    warm_worker()  # the serial loop's one-time costs, as the cluster's below
    warm_writer()
    t0 = time.perf_counter()
    cl, client = start_local_cluster(n_workers)  # what bench campaign starts
    t_start = time.perf_counter() - t0
    # per pair: wall (s), our CPU (cores), other processes' CPU (cores)
    ts, td, cs, cd, cm, os_, od = [], [], [], [], [], [], []
    # per pair, CPU seconds of the cluster's threads: client process (main thread, event
    # loop), workers (event loops, runs)
    split: list[tuple[float, float, float, float]] = []

    def others(b0: float | None, ours: float, wall: float) -> float:
        b1 = _busy_s()
        return float("nan") if b0 is None or b1 is None else (b1 - b0 - ours) / wall

    try:
        for _ in range(a.repeat):
            with tempfile.TemporaryDirectory() as tmp:
                t0, p0, b0 = time.perf_counter(), time.process_time(), _busy_s()
                run_campaign(c, Path(tmp) / "serial", serial=True)
                ts.append(time.perf_counter() - t0)
                ours = time.process_time() - p0
                cs.append(ours / ts[-1])
                os_.append(others(b0, ours, ts[-1]))
                w0, th0 = client.run(time.process_time), client.run(_threads_cpu)
                m0 = _threads_cpu()
                t0, p0, b0 = time.perf_counter(), time.process_time(), _busy_s()
                run_campaign(c, Path(tmp) / "dask", scheduler=client)
                td.append(time.perf_counter() - t0)
                m1 = _threads_cpu()
                w1, th1 = client.run(time.process_time), client.run(_threads_cpu)
                split.append((m1[0] - m0[0], m1[1] - m0[1],
                              sum(th1[k][0] - th0[k][0] for k in th0),
                              sum(th1[k][1] - th0[k][1] for k in th0)))
                work = sum(w1[k] - w0[k] for k in w0)
                cd.append(work / (len(w0) * td[-1]))
                cm.append((time.process_time() - p0) / td[-1])
                od.append(others(b0, work + time.process_time() - p0, td[-1]))
        rss = client.run(peak_rss_mb)
    finally:
        client.close()
        cl.close()
    s, d = statistics.median(ts), statistics.median(td)
    print(f"{a.runs} runs x {a.t_end} s simulated, {n_workers} cores"
          + (f", median of {a.repeat} pairs" if a.repeat > 1 else ""))
    # our CPU well below a core each, or other processes busy: the figures are low
    med = statistics.median
    print(f"serial loop:        {s:7.2f} s wall, {sim_s / s:7.1f} simulated s per wall s "
          f"(CPU {100 * med(cs):.0f} % of a core; other processes {med(os_):.2f} cores)")
    print(f"dask local cluster: {d:7.2f} s wall, {sim_s / d:7.1f} simulated s per wall s "
          f"(workers {100 * med(cd):.0f} % of a core each, client + scheduler "
          f"{100 * med(cm):.0f} %; other processes {med(od):.2f} cores)")
    sp = [med(x) for x in zip(*split, strict=True)]
    print(f"cluster CPU (s):    client process: main thread {sp[0]:.2f}, event loop "
          f"(scheduler, nannies, client) {sp[1]:.2f}; workers (sum): event loops {sp[2]:.2f}, "
          f"runs {sp[3]:.2f}")
    print(f"ratio dask/serial:  {s / d:.2f}x")
    print(f"cluster start-up:   {t_start:7.2f} s (with it: {sim_s / (d + t_start):.1f} "
          f"simulated s per wall s, {s / (d + t_start):.2f}x)")
    print("peak RSS per worker: " + ", ".join(f"{v:.0f} MiB" for v in rss.values())
          + f" (client + serial loop: {peak_rss_mb():.0f} MiB)")
    if a.repeat > 1:
        print("pairs (serial, dask sim-s/s; other processes' cores): " + ", ".join(
            f"({sim_s / x:.0f}, {sim_s / y:.0f}; {p:.2f}, {q:.2f})"
            for x, y, p, q in zip(ts, td, os_, od, strict=True)))


if __name__ == "__main__":
    main()
