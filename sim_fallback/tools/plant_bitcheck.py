"""Bit-identity check of the simulated plant across a code change.

Records a fixed set of closed-loop runs (every recorded channel, every period)
with the library that PMLSM_BUILD_DIR selects, and either saves them or compares
them with a saved set (np.array_equal per array; NaN == NaN where the channel
holds NaN, e.g. duty_abc with the PWM off)::

    PMLSM_BUILD_DIR=<old build> python sim_fallback/tools/plant_bitcheck.py record /tmp/ref.npz
    PMLSM_BUILD_DIR=<new build> python sim_fallback/tools/plant_bitcheck.py compare /tmp/ref.npz

Runs: every shipped motor with each extractor (load step, ADC noise and offsets),
the same with dead time, cogging, n_sub = 2 / 4, locked mover, ideal sensing; every
case of the fault-injection matrix (plant events: open phase, stuck ADC, offsets,
DC-link steps, ...) with all channels; plant-only runs with fixed duties (PWM off:
freewheeling diodes, stuck / break-away, a huge step that takes the libm paths).
A change meant to be value-preserving must leave every array bit-identical.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sim_fallback import MOTOR_DIR, SIM_REF_LOAD, SIM_REF_SPEED, Sim, load_motor  # noqa: E402
from sim_fallback.faults import CASES, record_case  # noqa: E402

T_END = 0.4


def _closed_loop(motor: str, extractor: str, plant: dict[str, Any], seed: int,
                 speed_rpm: float = 100.0, load_nm: float = 2.0) -> dict[str, np.ndarray]:
    m = load_motor(motor)
    with Sim(m, extractor, seed=seed, plant=plant, strict=False) as s:
        s.set_schedule(SIM_REF_SPEED, m.rpm_to_radps_e(speed_rpm))
        s.set_schedule(SIM_REF_LOAD, [(0.0, 0.0), (0.5 * T_END, m.nm_to_N(load_nm))])
        s.enable()
        rec = s.advance(int(round(T_END / s.dt_s)))
        rec["_state"] = np.array(list(s.state().values()), dtype=float)
        rec["_force"] = np.array([s.force_N()])
    return rec


def _fault_case(case: Any, seed: int) -> dict[str, np.ndarray]:
    """The matrix's run (sim_fallback.faults.record_case) recording every channel."""
    return record_case(case, seed)[0]


def _plant_only() -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for motor in sorted(p.stem for p in MOTOR_DIR.glob("*.toml")):
        m = load_motor(motor)
        for dt in (0.0, 2e-6):
            with Sim(m, seed=3, plant={"dead_time_s": dt}, strict=False) as s:
                # PWM on, then off with current flowing (diodes), stuck / break-away
                rows = []
                s.set_state(x0_m=0.01, v0_mps=0.0, i_d_A=1.0, i_q_A=4.0)
                for k in range(4000):
                    on = k < 2500
                    d = (0.5 + 0.3 * np.sin(k * 0.01), 0.5 + 0.3 * np.sin(k * 0.01 - 2.0),
                         0.5 + 0.3 * np.sin(k * 0.01 + 2.0))
                    s.plant_advance(d, on, s.dt_s, 1 + k % 3)
                    rows.append(list(s.state().values()) + [s.force_N()])
                # huge steps: far stages (libm paths)
                for h in (1e-3, 5e-3):
                    s.plant_advance((0.9, 0.1, 0.5), True, h, 1)
                    rows.append(list(s.state().values()) + [s.force_N()])
                out[f"plant/{motor}/dt{dt:g}"] = np.array(rows, dtype=float)
    return out


def collect(quick: bool = False) -> dict[str, np.ndarray]:
    arrays: dict[str, np.ndarray] = {}

    def put(prefix: str, rec: dict[str, np.ndarray]) -> None:
        for k, v in rec.items():
            arrays[f"{prefix}/{k}"] = np.asarray(v)

    motors = sorted(p.stem for p in MOTOR_DIR.glob("*.toml"))
    for motor in motors:
        for ex in ("pseudo", "sogi", "sogi_adaptive"):
            put(f"cl/{motor}/{ex}", _closed_loop(motor, ex, {}, seed=1))
        variants: dict[str, dict[str, Any]] = {
            "deadtime": {"dead_time_s": 2e-6},
            "deadtime_noband": {"dead_time_s": 1e-6, "dead_band_A": 0.0},
            "cog": {"cog_amp_N": 5.0},
            "nsub2": {"n_sub": 2},
            "nsub4_dt": {"n_sub": 4, "dead_time_s": 1e-6},
            "noiseless": {"adc_noise_counts": 0.0, "udc_noise_V": 0.0,
                          "adc_offset_counts": [0.0, 0.0, 0.0]},
            "locked": {"locked": 1},
        }
        for name, pl in variants.items():
            put(f"cl/{motor}/{name}", _closed_loop(motor, "sogi_adaptive", pl, seed=2))
        put(f"cl/{motor}/fast", _closed_loop(motor, "sogi_adaptive", {}, seed=4,
                                             speed_rpm=600.0, load_nm=0.5))
    if not quick:
        for case in CASES:
            put(f"fault/{case.name}", _fault_case(case, seed=0))
    arrays.update(_plant_only())
    return arrays


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=("record", "compare"))
    ap.add_argument("file", type=Path)
    ap.add_argument("--quick", action="store_true", help="skip the fault-matrix cases")
    a = ap.parse_args()
    arrays = collect(a.quick)
    if a.mode == "record":
        np.savez(a.file, **arrays)
        print(f"recorded {len(arrays)} arrays "
              f"({sum(v.size for v in arrays.values())} values) to {a.file}")
        return
    ref = np.load(a.file)
    names = [k for k in ref.files if not a.quick or not k.startswith("fault/")]
    bad = [k for k in names if k not in arrays
           or not np.array_equal(ref[k], arrays[k], equal_nan=ref[k].dtype.kind in "fc")]
    extra = sorted(set(arrays) - set(ref.files))
    n_val = sum(ref[k].size for k in names)
    print(f"compared {len(names)} arrays ({n_val} values): {len(bad)} differ"
          + (f", {len(extra)} not in the reference" if extra else ""))
    for k in bad[:20]:
        print("  differs:", k)
    sys.exit(1 if bad or extra else 0)


if __name__ == "__main__":
    main()
