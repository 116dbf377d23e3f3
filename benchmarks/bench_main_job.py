"""Wall time of the main job: ``bench run sequences/paper_load_step.yaml --sim``.

Runs the job as a fresh subprocess (whole-process wall time: interpreter start,
imports, simulated drive, logging, report; the MF4 writer child process included,
since the run waits for its file) N times after one warm-up run and prints the
median, min and max, then a breakdown from one more instrumented child process: imports,
connect (simulated drive start), simulate + log (run_sequence without the
report), report (plots + HTML + runs index). Prints figures; asserts nothing.

    python benchmarks/bench_main_job.py [-n 5] [--sequence FILE]

The tree is put first on PYTHONPATH so the installed copy does not shadow it;
set PMLSM_BUILD_DIR as for the tests when the libraries are not installed.
Run folders go to a temporary directory.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_JOB = "import sys; from bench.cli import console_main; sys.exit(console_main())"

# instrumented child: same job, stage times printed as one JSON line
_BREAKDOWN = r"""
import json, sys, time
t0 = time.perf_counter()
from bench import cli  # what the console script imports
import bench._session as S
import bench._report as R
from bench._sequence import load_sequence
t_imp = time.perf_counter() - t0
seq = load_sequence(sys.argv[1])
t1 = time.perf_counter()
conn = S.connect(sim=True, motor=seq.motor, extractor=seq.extractor, seed=seq.seed)
t_conn = time.perf_counter() - t1
rep = {"report_s": 0.0}
def timed(fn):
    def w(*a, **k):
        t = time.perf_counter()
        try:
            return fn(*a, **k)
        finally:
            rep["report_s"] += time.perf_counter() - t
    return w
S.make_plots = timed(S.make_plots)
S.write_html = timed(S.write_html)
t2 = time.perf_counter()
try:
    out = S.run_sequence(seq, conn, runs_root=sys.argv[2], progress=False)
finally:
    conn.close()
t_run = time.perf_counter() - t2
t3 = time.perf_counter()
if hasattr(R, "write_index"):
    R.write_index(sys.argv[2])
t_index = time.perf_counter() - t3
print(json.dumps({"imports_s": t_imp, "connect_s": t_conn,
                  "simulate_and_log_s": t_run - rep["report_s"],
                  "report_s": rep["report_s"], "index_s": t_index,
                  "asammdf_loaded": "asammdf" in sys.modules,
                  "matplotlib_loaded": "matplotlib" in sys.modules,
                  "passed": out.result.passed}))
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=5, help="repetitions (default 5)")
    ap.add_argument("--sequence", default=str(ROOT / "sequences" / "paper_load_step.yaml"))
    args = ap.parse_args()
    env = dict(os.environ)
    # as installed (pip compiles the bytecode): a set PYTHONDONTWRITEBYTECODE would make
    # every run compile the bench's modules again
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + ([env["PYTHONPATH"]]
                                                       if env.get("PYTHONPATH") else []))
    walls: list[float] = []
    with tempfile.TemporaryDirectory(prefix="bench_main_job_") as tmp:
        runs = Path(tmp) / "runs"
        cmd = [sys.executable, "-c", _JOB, "run", args.sequence, "--sim", "--runs", str(runs)]
        subprocess.run(cmd, cwd=tmp, env=env, capture_output=True)  # warm-up, not counted
        for i in range(args.n):
            t = time.perf_counter()
            p = subprocess.run(cmd, cwd=tmp, env=env, capture_output=True, text=True)
            walls.append(time.perf_counter() - t)
            if p.returncode not in (0, 1):  # 1 = an expectation failed: still a full run
                print(f"run {i + 1}: exit {p.returncode}\n{p.stderr[-2000:]}", file=sys.stderr)
                return 1
        print(f"main job ({Path(args.sequence).name} --sim), whole process, {args.n} runs:")
        print(f"  median {statistics.median(walls):.3f} s   min {min(walls):.3f} s   "
              f"max {max(walls):.3f} s   ({', '.join(f'{w:.2f}' for w in walls)})")
        t = time.perf_counter()
        p = subprocess.run([sys.executable, "-c", "import bench.cli"], cwd=tmp, env=env,
                           capture_output=True, text=True)
        t_cli = time.perf_counter() - t
        t = time.perf_counter()
        p = subprocess.run([sys.executable, "-c", "pass"], cwd=tmp, env=env,
                           capture_output=True, text=True)
        t_py = time.perf_counter() - t
        p = subprocess.run([sys.executable, "-c", _BREAKDOWN, args.sequence, str(runs)],
                           cwd=tmp, env=env, capture_output=True, text=True)
        if p.returncode != 0:
            print(f"breakdown child failed:\n{p.stderr[-2000:]}", file=sys.stderr)
            return 1
        b = json.loads(p.stdout.strip().splitlines()[-1])
    print("breakdown (one instrumented run, in-process stage times):")
    print(f"  interpreter start          {t_py:.3f} s  (python -c pass)")
    print(f"  import bench.cli           {t_cli:.3f} s  (process incl. interpreter start)")
    print(f"  imports for a run          {b['imports_s']:.3f} s")
    print(f"  connect (sim drive start)  {b['connect_s']:.3f} s")
    print(f"  simulate + log (MF4, BLF)  {b['simulate_and_log_s']:.3f} s")
    print(f"  report (plots + HTML)      {b['report_s']:.3f} s")
    print(f"  runs index                 {b['index_s']:.3f} s")
    print(f"  asammdf imported: {b['asammdf_loaded']}, matplotlib imported: "
          f"{b['matplotlib_loaded']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
