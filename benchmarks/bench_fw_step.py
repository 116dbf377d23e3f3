"""Benchmark: cost of one firmware control step on this host.

Prints
  * median ns per fw_step (batches of 1000 replayed closed-loop samples), and
  * instructions per fw_step from valgrind --tool=callgrind (repeatable):
    Ir(N2) - Ir(N1) over N2 - N1 steps, so warm-up and set-up cancel.

Usage: python benchmarks/bench_fw_step.py [--build-dir build/bench]
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def build(build_dir: Path) -> Path:
    subprocess.run(
        ["cmake", "-S", str(ROOT), "-B", str(build_dir), "-G", "Ninja",
         "-DCMAKE_BUILD_TYPE=Release", "-DPMLSM_BUILD_SIM=OFF", "-DPMLSM_BUILD_TESTS=ON"],
        check=True, capture_output=True,
    )
    subprocess.run(["cmake", "--build", str(build_dir), "--target", "bench_fw_step"],
                   check=True, capture_output=True)
    return build_dir / "bench_fw_step"


def callgrind_ir(exe: Path, n: int) -> int:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "cg.out"
        res = subprocess.run(
            ["valgrind", "--tool=callgrind", "--toggle-collect=fw_step",
             f"--callgrind-out-file={out}", str(exe), "count", str(n)],
            capture_output=True, text=True, check=True,
        )
    m = re.search(r"Collected\s*:\s*(\d+)", res.stderr)
    if not m:
        raise RuntimeError(f"no callgrind total in:\n{res.stderr}")
    return int(m.group(1))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build-dir", default=str(ROOT / "build" / "benchmarks"))
    args = ap.parse_args()
    exe = build(Path(args.build_dir))
    timing = subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout
    print(timing.strip())
    if shutil.which("valgrind") is None:
        print("valgrind not installed: instruction count skipped", file=sys.stderr)
        return 1
    n1, n2 = 2000, 12000
    ir = (callgrind_ir(exe, n2) - callgrind_ir(exe, n1)) / (n2 - n1)
    print(f"fw_step instructions/step (x86-64, callgrind, {n2 - n1} steps): {ir:.0f}")
    m = re.search(r"median ([\d.]+)", timing)
    if m:
        print(f"target <= 1000 ns/step on this host: {float(m.group(1)):.0f} ns "
              f"({1000.0 / float(m.group(1)):.1f}x margin)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
