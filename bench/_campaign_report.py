"""Campaign report: distributions, worst cases per axis, limits, comparison.

One self-contained HTML file (plotly.js embedded, works offline): the limits
with their measured statistics, a histogram per metric, the metric against
each axis, the worst runs with the command that replays each, and, given a
second campaign, both distributions overlaid with their statistics side by
side (before/after a firmware change).
"""

from __future__ import annotations

import html
import json
from pathlib import Path
from typing import Any

import numpy as np

from bench._campaign import Campaign, judge, load_results, replay_command, statistic

_STATS = ("mean", "p50", "p95", "p99", "max", "fail_fraction")


def _params(res: dict[str, np.ndarray]) -> list[dict[str, Any]]:
    return [json.loads(p) for p in res.get("params", [])]


def _table(head: list[str], rows: list[list[str]]) -> str:
    h = "".join(f"<th>{html.escape(x)}</th>" for x in head)
    b = "".join("<tr>" + "".join(f"<td>{x}</td>" for x in r) + "</tr>" for r in rows)
    return f"<table><thead><tr>{h}</tr></thead><tbody>{b}</tbody></table>"


def _fmt(x: Any) -> str:
    if x is None:
        return "–"
    if isinstance(x, float):
        return "–" if not np.isfinite(x) else f"{x:.4g}"
    return html.escape(str(x))


def render(c: Campaign, rdir: Path, other: Path | None = None, worst: int = 10) -> str:
    """HTML text of the report for the results in ``rdir`` (optionally vs ``other``)."""
    import plotly.graph_objects as go
    from plotly.io import to_html

    res = load_results(rdir)
    n = len(res.get("run", []))
    params = _params(res)
    errors = [e for e in res.get("error", []) if e]
    faults = int(np.count_nonzero(np.asarray(res.get("fault", []), dtype=float)))
    verdicts = judge(c, res)
    parts = [f"<h1>Campaign {html.escape(c.name)}</h1>",
             f"<p>{n} runs ({c.method}{', n=' + str(c.n) if c.n else ''}), "
             f"{len(errors)} failed to run, {faults} ended in a drive fault. "
             f"Source: <code>{html.escape(str(c.path))}</code>; results: "
             f"<code>{html.escape(str(rdir))}</code>.</p>"]
    all_ok = all(v["ok"] for v in verdicts)
    parts.append(f"<p class='{'pass' if all_ok else 'fail'}'>"
                 f"{'PASSED' if all_ok else 'FAILED'}: {sum(v['ok'] for v in verdicts)} of "
                 f"{len(verdicts)} limits hold</p>")
    parts.append(_table(["metric", "statistic", "measured", "min", "max", "verdict"], [
        [_fmt(v["metric"]), v["stat"], _fmt(v["value"]), _fmt(v["min"]), _fmt(v["max"]),
         "pass" if v["ok"] else "<b>FAIL</b>"] for v in verdicts]))
    first = True
    for m in c.metrics:
        vals = np.asarray(res.get(m, []), dtype=float)
        fig = go.Figure(go.Histogram(x=vals[np.isfinite(vals)], name=c.name, opacity=0.7))
        if other is not None:
            ov = np.asarray(load_results(other).get(m, []), dtype=float)
            fig.add_trace(go.Histogram(x=ov[np.isfinite(ov)], name=str(other.name),
                                       opacity=0.6))
            fig.update_layout(barmode="overlay")
        fig.update_layout(title=f"{m}: distribution", xaxis_title=m, yaxis_title="runs",
                          height=360)
        parts.append(to_html(fig, full_html=False, include_plotlyjs=first))
        first = False
        for ax in c.axes:
            x = [p.get(ax.target) for p in params]  # numbers, or case names
            sc = go.Figure(go.Scatter(x=x, y=vals, mode="markers", name=m,
                                      text=[f"run {p['run']}" for p in params]))
            sc.update_layout(title=f"{m} against {ax.target} ({ax.kind})",
                             xaxis_title=ax.target, yaxis_title=m, height=320)
            parts.append(to_html(sc, full_html=False, include_plotlyjs=False))
        order = np.argsort(-np.nan_to_num(vals, nan=np.inf))[:worst]
        rows = [[str(int(res["run"][k])), _fmt(float(vals[k])),
                 html.escape(json.dumps({a: params[k].get(a) for a in
                                         [x.target for x in c.axes]})),
                 _fmt(res["error"][k]) if "error" in res else "",
                 f"<code>{html.escape(replay_command(c, int(res['run'][k])))}</code>"]
                for k in order]
        parts.append(f"<h3>Worst {len(rows)} runs by {html.escape(m)}</h3>")
        parts.append(_table(["run", m, "axes", "error", "replay"], rows))
        if other is not None:
            ores = load_results(other)
            parts.append(f"<h3>{html.escape(m)}: this campaign vs "
                         f"{html.escape(str(other))}</h3>")
            parts.append(_table(["statistic", c.name, str(other.name)], [
                [s, _fmt(statistic(res.get(m, np.array([])), s)),
                 _fmt(statistic(ores.get(m, np.array([])), s))] for s in _STATS]))
    style = ("<style>body{font-family:sans-serif;margin:2em;max-width:1100px}"
             "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;"
             "padding:3px 8px}.pass{color:#176e17;font-weight:bold}"
             ".fail{color:#b00;font-weight:bold}</style>")
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>campaign "
            f"{html.escape(c.name)}</title>{style}</head><body>{''.join(parts)}</body></html>")


def write_report(c: Campaign, rdir: Path, other: Path | None = None) -> Path:
    out = rdir / "report.html"
    out.write_text(render(c, rdir, other), encoding="utf-8")
    return out
