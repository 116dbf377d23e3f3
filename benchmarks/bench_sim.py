"""Simulator speed and memory (issue 3 item 8). Not a timed test: prints figures.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_sim.py [--runs 7] [--json out.json]

1. Simulated seconds per wall second for the paper's load-step scenario
   (paper_salient, adaptive SOGI, 100 r/min, 2 N m at 0.5 s, 1 s) at the default
   PWM rate (24 kHz) on one core: median of several runs of the C loop (Sim.advance,
   no recording, and with full recording), for n_sub = 4 (default) and 1.
2. Peak resident memory of a 10 s run with full recording (every channel, every
   period), measured in a fresh subprocess (ru_maxrss).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # numpy must not spin other cores
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sim_fallback import SIM_REF_LOAD, SIM_REF_SPEED, Sim, load_motor  # noqa: E402


def load_step_rate(n_sub: int, record: bool, t_end: float = 1.0) -> tuple[float, float]:
    """(simulated s per wall s, simulated s per CPU s) for one load-step run (setup
    excluded). CPU time is the fair figure on a shared machine: other processes
    steal wall time, not CPU time."""
    m = load_motor("paper_salient")
    with Sim(m, "sogi_adaptive", seed=0, plant={"n_sub": n_sub}) as s:
        s.set_schedule(SIM_REF_SPEED, m.rpm_to_radps_e(100.0))
        s.set_schedule(SIM_REF_LOAD, [(0.0, 0.0), (0.5, m.nm_to_N(2.0))])
        s.enable()
        n = int(round(t_end / s.dt_s))
        t0, c0 = time.perf_counter(), time.process_time()
        s.advance(n, 1, None if record else [])
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        assert s.firmware.fault_code() == 0
    return t_end / wall, t_end / cpu


def peak_rss_child() -> None:
    """Run in a subprocess: 10 s load step, full recording; print peak RSS in MB."""
    m = load_motor("paper_salient")
    with Sim(m, "sogi_adaptive", seed=0) as s:
        s.set_schedule(SIM_REF_SPEED, m.rpm_to_radps_e(100.0))
        s.set_schedule(SIM_REF_LOAD, [(0.0, 0.0), (0.5, m.nm_to_N(2.0))])
        s.enable()
        rec = s.advance(int(round(10.0 / s.dt_s)), 1, None)
        nbytes = sum(a.nbytes for a in rec.values())
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(json.dumps({"peak_rss_MB": rss_mb, "record_MB": nbytes / 2**20}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--child-rss", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child_rss:
        peak_rss_child()
        return
    try:
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
    except (AttributeError, OSError):
        pass
    out: dict[str, float] = {}
    for n_sub in (4, 1):
        for record in (False, True):
            runs = [load_step_rate(n_sub, record) for _ in range(a.runs)]
            wall = [r[0] for r in runs]
            cpu = [r[1] for r in runs]
            key = f"realtime_factor_nsub{n_sub}_{'rec' if record else 'norec'}"
            out[key + "_wall"] = statistics.median(wall)
            out[key + "_cpu"] = statistics.median(cpu)
            what = "full recording" if record else "no recording"
            print(f"load step, 24 kHz, n_sub={n_sub}, {what:14s}:"
                  f" {out[key + '_wall']:6.1f} x real time wall (min {min(wall):.1f},"
                  f" max {max(wall):.1f}), {out[key + '_cpu']:6.1f} x per CPU second"
                  f" (median of {a.runs})")
    child = subprocess.run([sys.executable, __file__, "--child-rss"], capture_output=True,
                           text=True, check=True, env={**os.environ})
    rss = json.loads(child.stdout.strip().splitlines()[-1])
    out.update(rss)
    print(f"10 s run, full recording: peak RSS {rss['peak_rss_MB']:.1f} MB "
          f"(recorded arrays {rss['record_MB']:.1f} MB)")
    print("targets: >= 500 x real time; < 200 MB")
    if a.json:
        a.json.write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
