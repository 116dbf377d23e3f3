"""Training run of the simulator library's profile-guided build (sim_fallback/CMakeLists.txt,
PMLSM_SIM_PGO): runs an instrumented copy of the library ($PMLSM_SIM_LIB) through the
closed loop as campaigns use it, so that the compiler lays out and inlines the hot path by
its measured branch and call counts. Only the code layout depends on this run: the
library computes the same values with or without a profile (no value-changing option).

Mostly the campaign case (paper load step, lean recording, adaptive SOGI), plus short
runs of the other paper scenarios, extractors, the linear motor, full recording and
n_sub = 2, so that none of them is laid out as never executed. Deterministic (fixed
seeds): the same profile on every build. Without numpy (e.g. an isolated wheel build
environment), or when the Python side cannot run the instrumented library, it says so and
trains nothing (or what ran before the failure): the library is then built without (or
with a partial) profile, the same values either way; the tests report the failure.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))


def main() -> int:
    try:
        from sim_fallback import paper_scenario
    except ImportError as e:  # no numpy: build without a profile
        print(f"pgo_train: skipped ({e}); the simulator is built without a profile")
        return 0
    try:
        train(paper_scenario)
    except Exception as e:  # noqa: BLE001 - a profile is an optimisation, never a build error
        print(f"pgo_train: stopped ({type(e).__name__}: {e}); partial profile")
        return 0
    print("pgo_train: done")
    return 0


def train(paper_scenario: Callable[..., Any]) -> None:
    """The training runs (sim_fallback.paper_scenario on the instrumented library)."""
    lean = ["position_error_rms_rad"]
    for seed in range(8):  # the campaign run (bench campaign, benchmarks/bench_campaign.py)
        paper_scenario("load_step", seed=seed, t_end=0.5, record_decimation=8, metrics=lean)
    paper_scenario("load_step", seed=1, t_end=0.7)  # the load step itself, full recording
    paper_scenario("speed_reversal", seed=2, t_end=0.7, record_decimation=8, metrics=lean)
    paper_scenario("startup", seed=3, record_decimation=8, metrics=lean)
    for ex in ("pseudo", "sogi"):
        paper_scenario("load_step", extractor=ex, seed=4, t_end=0.3, metrics=lean)
    paper_scenario("load_step", motor="iron_core_linear", seed=5, t_end=0.3, metrics=lean)
    paper_scenario("load_step", seed=6, t_end=0.2, plant={"n_sub": 2}, metrics=lean)


if __name__ == "__main__":
    sys.exit(main())
