"""The start-up motion check (MOVING_AT_ENABLE, docs/integrity.md) at standstill and on a
slowly moving mover: its statistic against its threshold.

During the alignment the drive holds zero current; from 15 ms on the magnitude of the
voltage residual it needs, |u - R i - L di/dt| low-passed 5 ms (the firmware's own value,
snapshot ``mon_e_bemf_V`` while aligning), is compared with the back-EMF at
``start_speed_max_mps``. For every start position and noise seed this prints the largest
statistic over the check window as a share of the threshold (above 1: refused), the drive's
verdict, and from the simulator's truth (verdict only) the largest true speed during the
alignment: a mover at rest must not be refused, one moving faster than the limit must.

    python tools/start_motion_check.py [--positions 16] [--seeds 1-8] [--motors 0-7]
                                       [--moving 0.1,0.12] [--steady 0.06,0.075]

``--moving``: true speeds at enable with the motor's friction (the mover slows through the
check); ``--steady``: without friction and cogging (it keeps its speed but for what the
start's own current does to it). Measured numbers: docs/integrity.md, start-up.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

try:  # first: one line, not a traceback, outside the venv (not when loaded as a module)
    import _project_env  # noqa: F401
except ModuleNotFoundError:
    pass
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sim_fallback import load_motor, randomized_plant, seed_range  # noqa: E402
from sim_fallback.start_check import FRICTIONLESS, MOVING_AT_ENABLE, motion_check  # noqa: E402


def cases(motor_seeds: range) -> list[tuple[str, str, dict[str, Any] | None,
                                            dict[str, float] | None]]:
    """(label, motor, plant, fw): the shipped motors as their files configure them, and
    randomized iron-core variants, each configured with its own parameters (as if
    identified, gains derived by the drive) and with the nominal file (bench identify's
    first standstill start)."""
    out: list[tuple[str, str, dict[str, Any] | None, dict[str, float] | None]] = [
        ("iron_core_linear", "iron_core_linear", None, None),
        ("paper_salient", "paper_salient", None, None)]
    for s in motor_seeds:
        p = randomized_plant(s)
        fw = {"R_ohm": p["R_ohm"], "L_d_H": p["L_d0_H"], "L_q_H": p["L_q_H"],
              "psi_f_Wb": p["psi_f_Wb"], "mass_kg": p["mass_kg"], "gains_auto": 1}
        out.append((f"random {s} (own parameters)", "iron_core_linear", p, fw))
        out.append((f"random {s} (nominal file)", "iron_core_linear", p, None))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--positions", type=int, default=16, help="start positions per period")
    ap.add_argument("--seeds", default="1-8", type=seed_range,
                    help="simulator noise seeds, 'a-b'")
    ap.add_argument("--motors", default="0-7", type=seed_range,
                    help="randomized motor seeds, 'a-b'")
    ap.add_argument("--moving", default="0.1,0.12",
                    help="true speeds at enable (m/s), friction on (the mover slows)")
    ap.add_argument("--steady", default="0.06,0.075",
                    help="true speeds at enable (m/s), friction and cogging off (a mover "
                    "coasting at that speed through the check)")
    args = ap.parse_args()
    seeds = args.seeds
    moving = [(float(v), None) for v in args.moving.split(",") if v]
    moving += [(float(v), FRICTIONLESS) for v in args.steady.split(",") if v]
    print("standstill: largest statistic / threshold over the check window "
          f"({args.positions} positions x {len(seeds)} seeds)")
    print(f"{'case':34s} {'min':>6s} {'median':>6s} {'p99':>6s} {'max':>6s}  refused  "
          "true |v| max (mm/s)")
    for label, motor, plant, fw in cases(args.motors):
        tau = load_motor(motor).tau_m
        rs, refused, vmax = [], 0, 0.0
        for seed in seeds:
            for k in range(args.positions):
                r = motion_check(motor, seed, 2.0 * tau * k / args.positions, plant=plant,
                                 fw=fw)
                rs.append(r["ratio"])
                refused += r["fault"] == MOVING_AT_ENABLE
                vmax = max(vmax, r["v_max"])
        a = np.array(rs)
        print(f"{label:34s} {a.min():6.3f} {np.median(a):6.3f} {np.quantile(a, 0.99):6.3f} "
              f"{a.max():6.3f}  {refused:3d}/{a.size}  {vmax * 1e3:7.2f}")
    print("\nmoving at enable (iron_core_linear; must be refused, or caught on the back-EMF "
          "above bemf_v_off_mps): statistic / threshold, smallest and largest")
    print(f"{'v0 (m/s)':>9s} {'friction':>8s} {'min':>6s} {'max':>6s}  refused  caught  "
          "true |v| at 15 ms (m/s)  over the limit there: refused  statistic / true "
          "back-EMF at 15 ms")
    tau = load_motor("iron_core_linear").tau_m
    for v0, pl in moving:
        rs, refused, caught, vc, acc, over, over_ref = [], 0, 0, [], [], 0, 0
        for seed in seeds:
            for k in range(args.positions):
                r = motion_check("iron_core_linear", seed, 2.0 * tau * k / args.positions,
                                 v0_mps=v0, plant=pl)
                rs.append(r["ratio"])
                refused += r["fault"] == MOVING_AT_ENABLE
                caught += r["flying"]
                vc.append(r["v_check"])
                acc.append(r["accuracy"])
                if r["v_check"] > r["v_limit"]:
                    over += 1
                    over_ref += r["fault"] == MOVING_AT_ENABLE
        a = np.array(rs)
        print(f"{v0:9.3f} {'off' if pl else 'on':>8s} {a.min():6.3f} {a.max():6.3f}  "
              f"{refused:3d}/{a.size} {caught:4d}    "
              f"{min(vc):.3f} .. {max(vc):.3f}       {over_ref:3d}/{over:<3d}         "
              f"{min(acc):.3f} .. {max(acc):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
