"""Live telemetry to rerun: ``bench live --sim --duration 10 --rerun save X.rrd``.

Runs the command as a fresh subprocess N times (whole-process wall time: interpreter
start, imports, simulated drive paced to the wall clock, rerun, exit) and prints, per run
and as medians: the wall time, the feed's latency (p50 / p95 / max, from the moment a
sample is decoded to the end of the batch's ``send_columns`` calls), the items dropped
(bounded queue full), the drive-thread stalls (a ``put`` slower than 1 ms) with the longest
put, the .rrd size per minute of drive time and the size of the blueprint file written
beside it (``X.rbl``: the views, a fixed size, not counted in the .rrd's MB/min). Then one
longer run (``--long``, default 60 s) for the size per minute of a steady recording (the
.rrd's fixed part, ~15 kB of recording properties and chunk index, weighs less). Prints
figures; asserts nothing.

    python benchmarks/bench_live.py [-n 3] [--duration 10] [--long 60]

The tree is put first on PYTHONPATH so an installed copy does not shadow it; set
PMLSM_BUILD_DIR as for the tests when the libraries are not installed. Files go to a
temporary directory.

Targets (issue 15): latency <= 200 ms at the default telemetry, <= 1 MB per minute of
drive time, wall time of ``bench live --sim --duration 10`` <= 11 s, zero stalls.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]

SUMMARY = re.compile(
    r"rerun: (?P<batches>\d+) batches, (?P<rows>\d+) samples sent, (?P<dropped>\d+) dropped"
    r".*?latency p50/p95/max (?P<p50>[\d-]+)/(?P<p95>[\d-]+)/(?P<max>[\d-]+) ms, "
    r"drive-thread stalls (?P<stalls>\d+) \(longest put (?P<put_ms>[\d.]+) ms\)")
DRIVE_TIME = re.compile(r"recording: \S+ \((?P<mb>[\d.]+) MB, drive time (?P<s>[\d.]+) s\)")


def run_once(duration_s: float, tmp: Path, k: int) -> dict[str, Any]:
    rrd = tmp / f"live{k}.rrd"
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get(
        "PYTHONPATH", "")}
    for v in ("DISPLAY", "WAYLAND_DISPLAY"):
        env.pop(v, None)
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "bench.cli", "live", "--sim", "--duration",
                        f"{duration_s:g}", "--rerun", "save", str(rrd)], capture_output=True,
                       text=True, cwd=tmp, env=env, timeout=duration_s + 120)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"bench live failed ({r.returncode}):\n{r.stderr}")
    m = SUMMARY.search(r.stderr)
    d = DRIVE_TIME.search(r.stdout)
    if m is None or d is None:
        raise SystemExit(f"no summary in the output:\n{r.stderr}\n{r.stdout}")
    size = rrd.stat().st_size
    rbl = rrd.with_suffix(".rbl")
    drive = float(d["s"])
    return {"wall_s": wall, "p50_ms": float(m["p50"]), "p95_ms": float(m["p95"]),
            "max_ms": float(m["max"]), "dropped": int(m["dropped"]),
            "stalls": int(m["stalls"]), "put_max_ms": float(m["put_ms"]),
            "rows": int(m["rows"]), "batches": int(m["batches"]), "bytes": size,
            "drive_s": drive, "mb_per_min": size / 1e6 / drive * 60.0,
            "rbl_bytes": rbl.stat().st_size if rbl.exists() else 0}


def show(tag: str, x: dict[str, Any]) -> None:
    print(f"  {tag:>6}: wall {x['wall_s']:6.2f} s | latency p50/p95/max {x['p50_ms']:.0f}/"
          f"{x['p95_ms']:.0f}/{x['max_ms']:.0f} ms | dropped {x['dropped']} | stalls "
          f"{x['stalls']} (longest put {x['put_max_ms']:.2f} ms) | .rrd {x['bytes'] / 1e6:.3f}"
          f" MB for {x['drive_s']:.2f} s of drive = {x['mb_per_min']:.2f} MB/min (+ .rbl "
          f"{x['rbl_bytes'] / 1e6:.3f} MB) | "
          f"{x['rows']} samples in {x['batches']} batches")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-n", type=int, default=3, help="runs of --duration (default 3)")
    ap.add_argument("--duration", type=float, default=10.0,
                    help="bench live --duration (s; default 10)")
    ap.add_argument("--long", type=float, default=60.0,
                    help="one more run this long for the steady MB/min (0: none)")
    a = ap.parse_args()
    if not 1 <= a.n <= 50:
        print(f"bench_live: -n {a.n}: allowed range [1, 50]", file=sys.stderr)
        return 2
    for name, v in (("--duration", a.duration), ("--long", a.long)):
        if not 0 <= v <= 3600 or (name == "--duration" and v < 1):
            print(f"bench_live: {name} {v}: allowed range [1, 3600] s"
                  + (" (0: none)" if name == "--long" else ""), file=sys.stderr)
            return 2
    print(f"bench live --sim --duration {a.duration:g} --rerun save X.rrd ({os.cpu_count()} "
          "CPUs)")
    with tempfile.TemporaryDirectory(prefix="bench-live-") as td:
        tmp = Path(td)
        runs = []
        for k in range(a.n):
            runs.append(run_once(a.duration, tmp, k))
            show(f"run {k + 1}", runs[-1])
        med = {key: statistics.median(r[key] for r in runs) for key in runs[0]}
        show("median", med)
        print(f"  worst: wall {max(r['wall_s'] for r in runs):.2f} s, latency p95 "
              f"{max(r['p95_ms'] for r in runs):.0f} ms, dropped "
              f"{sum(r['dropped'] for r in runs)}, stalls {sum(r['stalls'] for r in runs)}")
        if a.long > 0:
            print(f"bench live --sim --duration {a.long:g} --rerun save X.rrd")
            show("long", run_once(a.long, tmp, a.n))
    print("latency: decoded -> handed to rerun's SDK (send_columns returned), not to the "
          "pixel; samples queued while rerun opens count from its opening")
    return 0


if __name__ == "__main__":
    sys.exit(main())
