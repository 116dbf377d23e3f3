"""docs/audible_noise.md agrees with the numbers it was generated from
(docs/audible_noise.json, written by tools/audible_noise.py from the campaign's results):
the recommendation follows the stated rule, the Pareto front is the non-dominated set, and
the campaign file still describes the runs the doc counts."""

from __future__ import annotations

import json
import math
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DATA = json.loads((ROOT / "docs" / "audible_noise.json").read_text())
MD = (ROOT / "docs" / "audible_noise.md").read_text()
NOISE, ERR = "steady.thrust_ripple_dBA", "steady.pos_rms"


def _ok(r: dict) -> bool:
    return (r["valid"] == r["seeds"]
            and r[ERR] + 2 * r[ERR + ".sd"] <= DATA["accuracy_limit_rad"])


def test_the_recommendation_follows_the_rule() -> None:
    rec = DATA["recommended"]
    assert rec is not None and _ok(rec)
    assert all(r[NOISE] >= rec[NOISE] for r in DATA["settings"] if _ok(r))
    assert (f"**Recommended: u_inj_V = {rec['u_inj_V']:g} V, f_inj_Hz = "
            f"{rec['f_inj_Hz']:g} Hz**") in MD
    assert f"{rec[NOISE] - DATA['default'][NOISE]:+.1f} dB(A)" in MD


def test_the_pareto_front_is_the_non_dominated_settings() -> None:
    rows = {(r["u_inj_V"], r["f_inj_Hz"]): r for r in DATA["settings"]}
    pts = [r for r in rows.values() if r["valid"] == r["seeds"]]
    front = {tuple(k) for k in DATA["pareto_noise"]}
    for r in pts:
        dominated = any(o[NOISE] <= r[NOISE] and o[ERR] <= r[ERR]
                        and (o[NOISE] < r[NOISE] or o[ERR] < r[ERR]) for o in pts)
        assert ((r["u_inj_V"], r["f_inj_Hz"]) in front) == (not dominated)


def test_the_doc_counts_the_campaigns_runs() -> None:
    from sim_fallback.metrics import METRIC_NAMES
    from simcampaign import load_campaign
    c = load_campaign(ROOT / "campaigns" / "audible_noise.yaml", METRIC_NAMES)
    assert DATA["runs"] == len(c.runs()) == sum(r["seeds"] for r in DATA["settings"])
    assert f"{DATA['runs']} runs" in MD
    assert all(math.isfinite(r[NOISE]) for r in DATA["settings"] if r["valid"])
