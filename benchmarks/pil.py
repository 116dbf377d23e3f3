#!/usr/bin/env python3
"""Processor-in-the-loop: the Cortex-M4F build of the firmware core against the host build.

1. Closed-loop simulations of the shipped scenarios record what the drive's ADC
   delivered every period (phase currents, DC link) together with the commands
   it received (enable sequence, mode, speed references).
2. The same harness (benchmarks/cm4/harness.c, ``replay`` mode) is built from
   the same core sources twice: for this host with the host compiler, and for
   the Cortex-M4F with the real target flags (-mcpu=cortex-m4 -mfpu=fpv4-sp-d16
   -mfloat-abi=hard), run under QEMU (mps2-an386). Both replay the recorded
   inputs and write duties, angle estimate, fault code and PWM state per period.
3. The outputs are compared. Expected: identical fault codes and PWM states in
   every period; duties and angle within ``TOL`` (the two libms differ in the
   last bit of expf/atan2f used for filter coefficients and the monitor; the
   core has no other libm call on its signal path and C11 mode keeps the
   compilers from contracting a*b+c into FMA).

Usage: python benchmarks/pil.py [--t-end 1.0] [--opt Os] [--scenario NAME ...]
Exit 0 when every scenario agrees, 1 when one does not, 2 when tools are missing.
"""

from __future__ import annotations

import argparse
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_cm4_estimate as cm4  # noqa: E402

TOL_DUTY = 1e-4  # of the 0..1 duty range
TOL_THETA_RAD = 1e-3
EV_CW, EV_MODE, EV_SPEED, EV_IQ = 0, 1, 2, 3
OUT_DTYPE = np.dtype([("duty", "<f4", 3), ("theta", "<f4"), ("fault", "<u2"),
                      ("pwm", "u1"), ("state", "u1")])
IN_DTYPE = np.dtype([("i_abc", "<f4", 3), ("u_dc", "<f4")])

#: name -> (motor, speed schedule [(t_s, m/s)], load schedule [(t_s, N)], plant events)
SCENARIOS: dict[str, tuple[str, list, list, list]] = {
    "paper_load_step": ("paper_salient", [(0.0, 0.3)], [(0.0, 0.0), (0.5, 65.0)], []),
    "paper_speed_reversal": ("paper_salient", [(0.0, 0.3), (0.5, -0.3)], [(0.0, 0.0)], []),
    "paper_startup_random": ("paper_salient", [(0.0, 0.3)], [(0.0, 0.0)], []),
    "iron_core_linear_load": ("iron_core_linear", [(0.0, 0.5)], [(0.0, 0.0), (0.5, 20.0)], []),
    # the monitor's fault path: phase a opens at 0.4 s
    "paper_open_phase": ("paper_salient", [(0.0, 0.3)], [(0.0, 0.0)],
                         [(0.4, {"open_phase_mask": 1})]),
}


def make_trace(name: str, t_end: float, path: Path, seed: int = 3) -> np.ndarray:
    """Closed-loop run of a scenario; writes the PIL trace, returns the loop's duties."""
    from sim_fallback import SIM_REF_LOAD, SIM_REF_SPEED, Sim
    from sim_fallback._motors import load_motor

    motor, speed, load, events = SCENARIOS[name]
    mot = load_motor(motor)
    x0 = 0.37 * 2 * mot.tau_m if "random" in name else 0.0
    k_w = mot.mps_to_radps_e(1.0)
    with Sim(mot, seed=seed, x0_m=x0) as sim:
        n = int(round(t_end / sim.dt_s))
        sim.set_schedule(SIM_REF_SPEED, speed, k_w)
        sim.set_schedule(SIM_REF_LOAD, load)
        sim.enable("speed")
        ch = ["i_abc_meas_A", "u_dc_meas_V", "duty_abc"]
        parts, done = [], 0
        for t_ev, change in [*events, (t_end, None)]:
            k = min(n, int(round(t_ev / sim.dt_s)))
            if k > done:
                parts.append(sim.advance(k - done, channels=ch))
                done = k
            if change:
                sim.set_plant(**change)
        rec = {c: np.concatenate([p_[c] for p_ in parts]) for c in ch}
        cfg = bytes(sim.cfg)
    # the commands the drive got: the enable walk, then each speed breakpoint
    ev = [(0, EV_MODE, 0.0), (0, EV_CW, 0x06), (0, EV_CW, 0x07), (0, EV_CW, 0x0F)]
    for t, v in speed:
        ev.append((int(round(t / (1.0 / 24000.0))), EV_SPEED, v * k_w))
    ev = [e for e in ev if e[0] < n]
    inputs = np.zeros(n, IN_DTYPE)
    inputs["i_abc"] = rec["i_abc_meas_A"]
    inputs["u_dc"] = rec["u_dc_meas_V"]
    with path.open("wb") as f:
        f.write(struct.pack("<4I", 0x544C4950, n, len(ev), len(cfg)))
        f.write(cfg)
        for k, kind, val in ev:
            f.write(struct.pack("<IIf", k, kind, val))
        f.write(inputs.tobytes())
    return rec["duty_abc"]


def build_host(outdir: Path) -> Path:
    """The replay harness for this host, from the same sources as the M4 image."""
    outdir.mkdir(parents=True, exist_ok=True)
    exe = outdir / "harness_host"
    srcs, incs = cm4.harness_sources()
    r = subprocess.run(["cc", "-O2", "-std=c11", "-DNDEBUG", "-Wall", "-Wextra", *incs, *srcs,
                        "-lm", "-o", str(exe)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"host build failed:\n{r.stderr}")
    return exe


def replay_host(exe: Path, trace: Path, out: Path) -> np.ndarray:
    r = subprocess.run([str(exe), "replay", str(trace), str(out)], capture_output=True,
                       text=True, timeout=600)
    if r.returncode != 0:
        raise RuntimeError(f"host replay failed: {r.stdout}{r.stderr}")
    return np.fromfile(out, OUT_DTYPE)


def replay_cm4(elf: Path, trace: Path, out: Path) -> tuple[np.ndarray, float]:
    t0 = time.perf_counter()
    r = cm4.qemu(elf, ["replay", str(trace), str(out)], [], timeout=900)
    if r.returncode != 0 or "replay ok" not in r.stdout:
        raise RuntimeError(f"M4 replay failed: {r.stdout}{r.stderr}")
    return np.fromfile(out, OUT_DTYPE), time.perf_counter() - t0


def compare(a: np.ndarray, b: np.ndarray) -> dict[str, float | int | bool]:
    """Agreement of two replays (host a, M4 b)."""
    on = a["pwm"] == 1
    dd = np.abs(a["duty"] - b["duty"])[on]
    dth = np.abs((a["theta"].astype(float) - b["theta"] + np.pi) % (2 * np.pi) - np.pi)
    return {
        "steps": int(a.size),
        "bit_identical": bool(a.tobytes() == b.tobytes()),
        "pwm_equal": bool(np.array_equal(a["pwm"], b["pwm"])),
        "fault_equal": bool(np.array_equal(a["fault"], b["fault"])),
        "state_equal": bool(np.array_equal(a["state"], b["state"])),
        "duty_max_abs": float(dd.max()) if dd.size else 0.0,
        "theta_max_abs_rad": float(dth.max()) if dth.size else 0.0,
        "final_fault": int(a["fault"][-1]),
        "closed_loop_steps": int(np.count_nonzero(on)),
    }


def agrees(c: dict) -> bool:
    return (c["pwm_equal"] and c["fault_equal"] and c["state_equal"]
            and c["duty_max_abs"] <= TOL_DUTY and c["theta_max_abs_rad"] <= TOL_THETA_RAD)


def run(names: list[str], t_end: float, opt: str, work: Path) -> list[dict]:
    cm4.check_tools()
    elf = cm4.build(opt, work / f"m4-{opt}")
    exe = build_host(work / "host")
    results = []
    for name in names:
        trace = work / f"{name}.pilt"
        loop_duty = make_trace(name, t_end, trace)
        a = replay_host(exe, trace, work / f"{name}.host.out")
        b, wall = replay_cm4(elf, trace, work / f"{name}.m4.out")
        c = compare(a, b)
        # the replay reproduces the closed loop it was recorded from (the host library
        # is built by CMake with other flags, so within the same tolerance)
        on = ~np.isnan(loop_duty[:, 0])
        c["loop_duty_max_abs"] = float(np.abs(loop_duty[on] - a["duty"][on]).max()) if np.any(
            on) else 0.0
        c.update(name=name, opt=opt, qemu_wall_s=wall, ok=agrees(c))
        results.append(c)
    return results


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t-end", type=float, default=1.0)
    ap.add_argument("--opt", default="Os", help="M4 optimisation level (Os is the shipped one)")
    ap.add_argument("--scenario", nargs="*", default=list(SCENARIOS), choices=list(SCENARIOS))
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        res = run(a.scenario, a.t_end, a.opt, Path(tmp))
    for c in res:
        print(f"{c['name']:24s} -{c['opt']}: {c['steps']} steps "
              f"({c['closed_loop_steps']} with PWM), "
              f"bit-identical {c['bit_identical']}, duty max |diff| {c['duty_max_abs']:.2e}, "
              f"theta max |diff| {c['theta_max_abs_rad']:.2e} rad, faults/PWM/states equal "
              f"{c['fault_equal'] and c['pwm_equal'] and c['state_equal']}, replay vs loop "
              f"{c['loop_duty_max_abs']:.1e}, QEMU {c['qemu_wall_s']:.1f} s -> "
              f"{'AGREE' if c['ok'] else 'DIFFER'}")
    return 0 if all(c["ok"] for c in res) else 1


if __name__ == "__main__":
    raise SystemExit(main())
