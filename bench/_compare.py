"""``bench compare RUN_A RUN_B``: two runs side by side, judged against tolerances.

The twin check of the hardware path: the same sequence on the emulated board and on
the host simulated drive (and, on a rig, a hardware run beside its simulation). For
every metric both runs have (:mod:`sim_fallback.metrics`, their default windows): both
values, the difference, and whether it is within the metric's tolerance
(:data:`TOLERANCES`, or ``--tol NAME=VALUE``); the faults each drive raised must be the
same codes; a metric one run could not judge (no truth) is shown, not compared. The
page ``compare.html`` (one file, offline) overlays their signals in sequence time.

Exit codes: 0 every compared metric within its tolerance and the same faults, 1 a
difference beyond tolerance or different faults, 2 bad input (a folder that is no run,
a bad ``--tol``).
"""

from __future__ import annotations

import html
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sim_fallback.metrics import METRIC_DEFS

#: Default tolerance per metric: (kind, value) with kind "rel" (|b - a| <= v |a|) or "abs"
#: (|b - a| <= v, in the metric's unit). RMS figures are statistics of hundreds of
#: samples: 10 %; maxima are one sample's extreme: 35 %; times: 30 ms.
TOLERANCES: dict[str, tuple[str, float]] = {
    "position_error_rms_rad": ("rel", 0.10),
    "position_error_rms_mm": ("rel", 0.10),
    "position_error_max_rad": ("rel", 0.35),
    "position_error_mean_rad": ("abs", 0.005),
    "speed_estimate_error_max_rpm": ("rel", 0.35),
    "speed_estimate_error_max_mps": ("rel", 0.35),
    "speed_filtered_estimate_error_max_rpm": ("rel", 0.35),
    "speed_filtered_estimate_error_rms_rpm": ("rel", 0.25),
    "speed_tracking_error_max_rpm": ("rel", 0.35),
    "settling_time_s": ("abs", 0.03),
    "speed_tracking_estimate_error_max_rpm": ("rel", 0.35),
    "estimate_settling_time_s": ("abs", 0.03),
    "current_q_max_A": ("rel", 0.15),
    # the linear twins (m/s, mm) of the figures above: the same tolerance as their twin
    "position_error_max_mm": ("rel", 0.35),
    "position_error_mean_mm": ("abs", 0.04),  # 0.005 rad el. at the paper motor's 24 mm
    "speed_filtered_estimate_error_max_mps": ("rel", 0.35),
    "speed_filtered_estimate_error_rms_mps": ("rel", 0.25),
    "speed_tracking_error_max_mps": ("rel", 0.35),
    "speed_tracking_estimate_error_max_mps": ("rel", 0.35),
}

#: signals overlaid in compare.html: (title, [(channel candidates in order), unit])
_PLOTS = (
    ("speed estimate", ("pdo.speed_hat_mps", "tel.omega_hat_radps", "sim.omega_hat_radps")),
    ("angle estimate", ("tel.theta_hat_rad", "pdo.theta_hat_rad", "sim.theta_hat_rad")),
    ("i_q", ("tel.i_q_A", "sim.i_dq_hat_A")),
    ("PLL error", ("tel.pll_err_rad", "sim.pll_err_rad")),
)


class CompareError(ValueError):
    """A folder that is not a run, a bad tolerance: exit 2."""


@dataclass
class Row:
    metric: str
    a: float
    b: float
    tol: tuple[str, float] | None
    status: str  # "within", "BEYOND", "not compared"
    why: str = ""

    @property
    def diff(self) -> float:
        return self.b - self.a


def parse_tolerances(items: list[str] | None) -> dict[str, tuple[str, float]]:
    """``NAME=10%`` (relative) or ``NAME=0.002`` (absolute, the metric's unit)."""
    tol = dict(TOLERANCES)
    for it in items or []:
        m = re.fullmatch(r"\s*([A-Za-z0-9_]+)\s*=\s*([0-9.eE+-]+)\s*(%?)\s*", it)
        if not m or m.group(1) not in METRIC_DEFS:
            raise CompareError(f"--tol {it!r}: expected METRIC=VALUE or METRIC=PERCENT%, "
                               f"METRIC one of {', '.join(METRIC_DEFS)}")
        v = float(m.group(2))
        if not math.isfinite(v) or v < 0:
            raise CompareError(f"--tol {it!r}: the tolerance must be a finite number >= 0")
        tol[m.group(1)] = ("rel", v / 100.0) if m.group(3) else ("abs", v)
    return tol


def _read_run(d: Path) -> dict[str, Any]:
    if not d.is_dir():
        raise CompareError(f"{d}: no such run folder")
    try:
        summary = json.loads((d / "summary.json").read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise CompareError(f"{d}: not a run folder (no summary.json)") from None
    except (OSError, ValueError) as e:
        raise CompareError(f"{d}/summary.json: unreadable ({e})") from None
    try:
        meta = json.loads((d / "meta.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        meta = {}
    return {"dir": d, "summary": summary, "meta": meta}


def _faults(run: dict[str, Any], signals: dict[str, Any] | None) -> list[int]:
    """The fault codes the drive raised in the run: from its recorded error-code signals,
    and a fault named in the run's error."""
    codes: set[int] = set()
    if signals:
        for ch in ("pdo.error_code", "tel.fault_code", "sim.fault_code"):
            if ch in signals:
                v = np.asarray(signals[ch][1], dtype=float)
                codes |= {int(c) for c in np.unique(v[np.isfinite(v)]) if int(c) != 0}
    err = run["summary"].get("error") or ""
    codes |= {int(m, 16) for m in re.findall(r"0x([0-9A-Fa-f]{4})\b", err)}
    return sorted(codes)


def compare_rows(a: dict[str, Any], b: dict[str, Any],
                 tol: dict[str, tuple[str, float]]) -> list[Row]:
    ma = a["summary"].get("metrics") or {}
    mb = b["summary"].get("metrics") or {}
    rows = []
    for k in METRIC_DEFS:
        va = ma.get(k)
        vb = mb.get(k)
        fa = float("nan") if va is None else float(va)
        fb = float("nan") if vb is None else float(vb)
        t = tol.get(k)
        if not (math.isfinite(fa) and math.isfinite(fb)):
            which = " and ".join(n for n, v in (("A", fa), ("B", fb)) if not math.isfinite(v))
            rows.append(Row(k, fa, fb, t, "not compared", f"not judged in {which}"))
            continue
        if t is None:
            rows.append(Row(k, fa, fb, t, "not compared", "no tolerance"))
            continue
        kind, v = t
        lim = v * abs(fa) if kind == "rel" else v
        ok = abs(fb - fa) <= lim + 1e-15
        rows.append(Row(k, fa, fb, t, "within" if ok else "BEYOND",
                        f"|B - A| = {abs(fb - fa):.4g} {'<=' if ok else '>'} {lim:.4g}"))
    return rows


def _tol_text(t: tuple[str, float] | None) -> str:
    if t is None:
        return ""
    return f"{t[1] * 100:g} %" if t[0] == "rel" else f"{t[1]:g}"


def _faults_text(codes: list[int]) -> str:
    return ", ".join(f"0x{c:04X}" for c in codes) or "none"


def _label(run: dict[str, Any]) -> str:
    s = run["summary"]
    kind = s.get("drive", "?")
    board = s.get("board") or ""
    return f"{run['dir'].name} [{str(kind).upper()}{' ' + board if board else ''}]"


def compare(dir_a: str | Path, dir_b: str | Path, tolerances: list[str] | None = None,
            out: str | Path | None = None) -> tuple[int, str, Path]:
    """Compare two runs; returns (exit code, the text table, the page written)."""
    tol = parse_tolerances(tolerances)
    a, b = _read_run(Path(dir_a)), _read_run(Path(dir_b))
    sig_a = sig_b = None
    try:
        from bench._logging import read_signals

        sig_a, sig_b = read_signals(a["dir"]), read_signals(b["dir"])
    except Exception:  # noqa: BLE001 - signals are for the plots and faults; metrics decide
        pass
    rows = compare_rows(a, b, tol)
    fa, fb = _faults(a, sig_a), _faults(b, sig_b)
    same_faults = fa == fb
    beyond = [r for r in rows if r.status == "BEYOND"]
    lines = [f"A: {_label(a)}", f"B: {_label(b)}",
             f"{'metric':40s} {'A':>11s} {'B':>11s} {'B - A':>11s} {'tolerance':>10s}  result"]
    for r in rows:
        unit = METRIC_DEFS[r.metric].unit
        lines.append(f"{r.metric:40s} {r.a:11.5g} {r.b:11.5g} {r.diff:11.4g} "
                     f"{_tol_text(r.tol):>10s}  {r.status}"
                     + (f" ({r.why})" if r.status != "within" else "") + f"  [{unit}]")
    lines.append(f"faults: A {_faults_text(fa)}, B {_faults_text(fb)}: "
                 f"{'the same' if same_faults else 'DIFFERENT'}")
    ok = not beyond and same_faults
    lines.append(f"{'WITHIN TOLERANCES' if ok else 'DIFFERENT'}: "
                 f"{sum(r.status == 'within' for r in rows)} metrics within, {len(beyond)} "
                 f"beyond, {sum(r.status == 'not compared' for r in rows)} not compared")
    page = Path(out) if out is not None else b["dir"] / f"compare_{a['dir'].name}.html"
    _write_page(page, a, b, rows, fa, fb, ok, sig_a, sig_b)
    lines.append(f"page: {page}")
    return (0 if ok else 1), "\n".join(lines), page


def _write_page(path: Path, a: dict[str, Any], b: dict[str, Any], rows: list[Row],
                fa: list[int], fb: list[int], ok: bool, sig_a: Any, sig_b: Any) -> None:
    from bench._report import _decimate, plotly_page_parts

    lib_head, lib_notice, lib_footer = plotly_page_parts(
        path, b["dir"].resolve().parent,
        fix=f"<code>bench compare {html.escape(str(a['dir']))} {html.escape(str(b['dir']))}"
            "</code> writes it again")

    def t0(run: dict[str, Any]) -> float:
        return float((run["meta"] or {}).get("time_origin_s", 0.0))

    figs = []
    for title, cands in _PLOTS:
        traces = []
        units: set[str] = set()
        for name, run, sig in (("A", a, sig_a), ("B", b, sig_b)):
            if not sig:
                continue
            ch = next((c for c in cands if c in sig), None)
            if ch is None:
                continue
            t, v, unit = sig[ch]
            units.add(str(unit or "-"))
            v = np.asarray(v, dtype=float)
            if v.ndim == 2:
                v = v[:, -1]
            # min/max envelope: a one-sample spike survives (plain striding hid it)
            x, y = _decimate(np.asarray(t, dtype=float) - t0(run), v, 4000)
            traces.append({"x": x.tolist(), "y": [None if not np.isfinite(q) else float(q)
                                                  for q in y],
                           "name": f"{name}: {ch}", "mode": "lines"})
        if traces:
            div = f"p{len(figs)}"
            layout = {"margin": {"t": 10}, "legend": {"orientation": "h", "y": -0.25},
                      "xaxis": {"title": {"text": "sequence time (s)"}},
                      "yaxis": {"title": {"text": f"{title} ({' or '.join(sorted(units))})"}}}
            figs.append(f"<h3>{html.escape(title)}</h3><div id='{div}' style='height:340px'>"
                        f"</div><script>if (window.Plotly) Plotly.newPlot('{div}', "
                        f"{json.dumps(traces)}, {json.dumps(layout)});</script>")
    trs = "\n".join(
        f"<tr class='{'bad' if r.status == 'BEYOND' else ''}'><td>{r.metric}</td>"
        f"<td>{r.a:.5g}</td><td>{r.b:.5g}</td><td>{r.diff:.4g}</td>"
        f"<td>{_tol_text(r.tol)}</td><td>{html.escape(r.status)}</td>"
        f"<td>{html.escape(METRIC_DEFS[r.metric].unit)}</td><td>{html.escape(r.why)}</td></tr>"
        for r in rows)
    doc = f"""<!doctype html><html><head><meta charset="utf-8">
<title>compare {html.escape(a['dir'].name)} / {html.escape(b['dir'].name)}</title>
<style>body {{ font-family: sans-serif; margin: 2em; }} table {{ border-collapse: collapse; }}
td, th {{ border: 1px solid #ccc; padding: 3px 8px; font-size: 14px; }}
tr.bad td {{ background: #fee; }} .v {{ font-size: 1.3em; font-weight: bold;
color: {'#070' if ok else '#b00'}; }}</style>
{lib_head}</head><body>
{lib_notice}
<h1>Two runs side by side</h1>
<p>A: {html.escape(_label(a))}<br>B: {html.escape(_label(b))}</p>
<p class="v">{'WITHIN TOLERANCES' if ok else 'DIFFERENT'}</p>
<p>faults: A {_faults_text(fa)}, B {_faults_text(fb)}</p>
<table><tr><th>metric</th><th>A</th><th>B</th><th>B - A</th><th>tolerance</th><th>result</th>
<th>unit</th><th></th></tr>{trs}</table>
{''.join(figs)}
{lib_footer}
</body></html>"""
    path.write_text(doc, encoding="utf-8")
