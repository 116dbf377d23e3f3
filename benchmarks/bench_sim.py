"""Simulator speed and memory (issue 3 item 8). Not a timed test: prints figures.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_sim.py [--runs 7] [--json out.json]

1. Simulated seconds per wall second for the paper's load-step scenario
   (paper_salient, adaptive SOGI, 100 r/min, 2 N m at 0.5 s, 1 s) at the default
   PWM rate (24 kHz) on one core: median of >= 5 runs of the C loop (Sim.advance,
   no recording, and with full recording), for n_sub = 1 (default), 2 and 4, with
   the ratio to the issue's 500x target. Per-CPU-second figures are printed too:
   on a shared machine other processes steal wall time, not CPU time.
2. The firmware's own ceiling: fw_step alone (benchmarks/bench_fw_step.c, when
   built next to the library) bounds the loop at 1 / (f_pwm t_fw_step) x real time
   even with a free plant; and the plant alone (sim_fallback/tools/bench_sim_plant.c,
   when built), so that the per-period budget can be split.
3. Peak resident memory of a 10 s run with full recording (every channel, every
   period), measured in a fresh subprocess (ru_maxrss).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # numpy must not spin other cores
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sim_fallback import SIM_REF_LOAD, SIM_REF_SPEED, Sim, lib_path, load_motor  # noqa: E402

TARGET_X = 500.0
F_PWM_HZ = 24000.0


def load_step_rate(n_sub: int, record: bool, t_end: float = 1.0) -> tuple[float, float]:
    """(simulated s per wall s, simulated s per CPU s) for one load-step run (setup
    excluded, recording buffers included)."""
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
        t0, c0 = time.perf_counter(), time.process_time()
        rec = s.advance(int(round(10.0 / s.dt_s)), 1, None)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        nbytes = sum(a.nbytes for a in rec.values())
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(json.dumps({"peak_rss_MB": rss_mb, "record_MB": nbytes / 2**20,
                      "realtime_factor_10s_rec_wall": 10.0 / wall,
                      "realtime_factor_10s_rec_cpu": 10.0 / cpu}))


def fw_step_ns() -> float | None:
    """Median ns of fw_step alone from bench_fw_step next to the library, if built."""
    exe = Path(lib_path()).resolve().parents[1] / "bench_fw_step"
    if not exe.is_file():
        return None
    try:
        out = subprocess.run([str(exe), "time"], capture_output=True, text=True, timeout=120,
                             check=True).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    m = re.search(r"median\s+([0-9.]+)", out)
    return float(m.group(1)) if m else None


def plant_ns() -> dict[str, float]:
    """ns per period of the plant alone for n_sub = 1, 2, 4 and at standstill
    (bench_sim_plant), if built."""
    exe = Path(lib_path()).resolve().parent / "bench_sim_plant"
    if not exe.is_file():
        return {}
    try:
        out = subprocess.run([str(exe)], capture_output=True, text=True, timeout=300,
                             check=True).stdout
    except (OSError, subprocess.SubprocessError):
        return {}
    res = {f"plant_ns_nsub{m.group(1)}": float(m.group(2))
           for m in re.finditer(r"alone, n_sub=(\d+): ([0-9.]+) ns", out)}
    m = re.search(r"standstill.*?: ([0-9.]+) ns", out)
    if m:
        res["plant_ns_standstill"] = float(m.group(1))
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--child-rss", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child_rss:
        peak_rss_child()
        return
    runs_n = max(5, a.runs)
    try:
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
    except (AttributeError, OSError):
        pass
    out: dict[str, float] = {"target_x": TARGET_X}
    load_step_rate(1, False)  # warm-up (library load, page cache)
    for n_sub in (1, 2, 4):
        for record in (False, True):
            runs = [load_step_rate(n_sub, record) for _ in range(runs_n)]
            wall = [r[0] for r in runs]
            cpu = [r[1] for r in runs]
            key = f"realtime_factor_nsub{n_sub}_{'rec' if record else 'norec'}"
            out[key + "_wall"] = statistics.median(wall)
            out[key + "_cpu"] = statistics.median(cpu)
            what = "full recording" if record else "no recording"
            dflt = " (default)" if n_sub == 1 else ""
            print(f"load step, 24 kHz, n_sub={n_sub}{dflt:10s} {what:14s}:"
                  f" {out[key + '_wall']:6.1f} x real time wall (min {min(wall):.1f},"
                  f" max {max(wall):.1f}; {out[key + '_wall'] / TARGET_X:.2f} of the"
                  f" {TARGET_X:.0f}x target), {out[key + '_cpu']:6.1f} x per CPU second,"
                  f" {1e9 / (F_PWM_HZ * out[key + '_cpu']):5.0f} ns CPU per period"
                  f" (median of {runs_n})")
    fw = fw_step_ns()
    if fw is not None:
        out["fw_step_ns"] = fw
        out["fw_ceiling_x"] = 1e9 / (F_PWM_HZ * fw)
        print(f"fw_step alone (bench_fw_step): {fw:.0f} ns -> even with a free plant the "
              f"loop cannot exceed {out['fw_ceiling_x']:.0f} x real time at 24 kHz "
              f"({out['fw_ceiling_x'] / TARGET_X:.2f} of the target; 500x leaves "
              f"{1e9 / (F_PWM_HZ * TARGET_X):.0f} ns per period for everything)")
    else:
        print("fw_step alone: bench_fw_step not built next to the library (skipped)")
    pl = plant_ns()
    out.update(pl)
    if pl:
        print("plant alone (bench_sim_plant, CPU median of 7): " + ", ".join(
            f"n_sub={k[-1]}: {v:.0f} ns" if k[-1].isdigit() else f"standstill: {v:.0f} ns"
            for k, v in pl.items()) + " per period")
    child = subprocess.run([sys.executable, __file__, "--child-rss"], capture_output=True,
                           text=True, check=True, env={**os.environ})
    rss = json.loads(child.stdout.strip().splitlines()[-1])
    out.update(rss)
    print(f"10 s run, full recording: peak RSS {rss['peak_rss_MB']:.1f} MB "
          f"(recorded arrays {rss['record_MB']:.1f} MB), "
          f"{rss['realtime_factor_10s_rec_wall']:.1f} x real time wall, "
          f"{rss['realtime_factor_10s_rec_cpu']:.1f} x per CPU second")
    print(f"targets: >= {TARGET_X:.0f} x real time; < 200 MB")
    if a.json:
        a.json.write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
