"""Campaign report: distributions, worst cases per axis, limits, comparison.

One HTML file (plotly.js: the results root's one copy, ``<out>/plotly-<version>.min.js``,
as for run reports; it works offline when copied with that file): the limits
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

from ._campaign import Campaign, judge, load_results, replay_command, statistic

_STATS = ("mean", "p50", "p95", "p99", "max", "fail_fraction")


def _params(res: dict[str, np.ndarray]) -> list[dict[str, Any]]:
    return [json.loads(p) for p in res.get("params", [])]


def _table(head: list[str], rows: list[list[str]], fail_rows: set[int] | None = None) -> str:
    h = "".join(f"<th>{html.escape(x)}</th>" for x in head)
    b = "".join(("<tr class='beyond'>" if i in (fail_rows or ()) else "<tr>")
                + "".join(f"<td>{x}</td>" for x in r) + "</tr>" for i, r in enumerate(rows))
    return f"<table><thead><tr>{h}</tr></thead><tbody>{b}</tbody></table>"


def _fmt(x: Any) -> str:
    if x is None:
        return "–"
    if isinstance(x, float):
        return "–" if not np.isfinite(x) else f"{x:.4g}"
    return html.escape(str(x))


def beyond_limits(c: Campaign, res: dict[str, np.ndarray]) -> dict[int, list[str]]:
    """The failing corners: row index -> the limits its own value breaks (a value above
    a limit's max or below its min: the runs that make a failed max, p99 or mean fail),
    or, for a fail_fraction limit, "no <metric>" (a failed run or a drive fault)."""
    out: dict[int, list[str]] = {}
    for lim in c.limits:
        v = np.asarray(res.get(lim.metric, []), dtype=float)
        for k, x in enumerate(v):
            if lim.stat == "fail_fraction":
                why = None if np.isfinite(x) else f"no {lim.metric}"
            elif not np.isfinite(x):
                why = None
            elif lim.max is not None and x > lim.max:
                why = f"{lim.metric} {x:.4g} > {lim.max:g}"
            elif lim.min is not None and x < lim.min:
                why = f"{lim.metric} {x:.4g} < {lim.min:g}"
            else:
                why = None
            if why and why not in out.setdefault(k, []):
                out[k].append(why)
    return {k: v for k, v in out.items() if v}


def _error_text(res: dict[str, np.ndarray], k: int) -> str:
    """A run's error, or its drive fault code."""
    err = res["error"][k] if "error" in res else None
    fault = int(res["fault"][k] or 0) if "fault" in res else 0
    return _fmt(err) if err else (f"drive fault 0x{fault:04X}" if fault else "–")


def _axes_text(c: Campaign, p: dict[str, Any]) -> str:
    return ", ".join(f"{a.target}={_fmt(p.get(a.target))}" for a in c.axes)


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
    bad = beyond_limits(c, res)
    if bad:
        order = sorted(bad, key=lambda k: int(res["run"][k]))
        parts.append(f"<h2 class='fail'>Failing corners: {len(bad)} of {n} runs beyond a "
                     "limit</h2>")
        parts.append(_table(["run", "beyond", "axes", "error", "replay"], [
            [str(int(res["run"][k])), html.escape("; ".join(bad[k])),
             _axes_text(c, params[k]), _error_text(res, k),
             f"<code>{html.escape(replay_command(c, int(res['run'][k])))}</code>"]
            for k in order[:50]], fail_rows=set(range(len(order)))))
        if len(order) > 50:
            parts.append(f"<p>and {len(order) - 50} more (runs "
                         f"{', '.join(str(int(res['run'][k])) for k in order[50:200])}"
                         f"{' ...' if len(order) > 200 else ''})</p>")
    ores = load_results(other) if other is not None else None
    if ores is not None:
        missing = [m for m in c.metrics if m not in ores]
        if not ores:
            parts.append(f"<p class='fail'>{html.escape(str(other))} holds no runs: nothing "
                         "to compare.</p>")
        elif missing:
            parts.append(f"<p class='fail'>{html.escape(str(other))} has no "
                         f"{html.escape(', '.join(missing))}: compared on the other metrics "
                         "only.</p>")
    for m in c.metrics:
        vals = np.asarray(res.get(m, []), dtype=float)
        fig = go.Figure(go.Histogram(x=vals[np.isfinite(vals)], name=c.name, opacity=0.7))
        if ores is not None and m in ores:
            ov = np.asarray(ores[m], dtype=float)
            fig.add_trace(go.Histogram(x=ov[np.isfinite(ov)], name=str(other.name),
                                       opacity=0.6))
            fig.update_layout(barmode="overlay")
        fig.update_layout(title=f"{m}: distribution", xaxis_title=m, yaxis_title="runs",
                          height=360)
        parts.append(to_html(fig, full_html=False, include_plotlyjs=False))
        for ax in c.axes:
            x = [p.get(ax.target) for p in params]  # numbers, or case names
            fails = [k in bad for k in range(n)]
            sc = go.Figure(go.Scatter(
                x=x, y=vals, mode="markers", name=m,
                marker={"color": ["#c00" if f else "#36c" for f in fails],
                        "size": [10 if f else 6 for f in fails],
                        "symbol": ["x" if f else "circle" for f in fails]},
                text=[f"run {p['run']}" + (f" beyond: {'; '.join(bad[k])}<br>"
                                           f"{replay_command(c, int(p['run']))}"
                                           if k in bad else "")
                      for k, p in enumerate(params)]))
            if any(fails):
                sc.add_annotation(text="red x: beyond a limit (hover: replay command)",
                                  xref="paper", yref="paper", x=1, y=1.12,
                                  showarrow=False, font={"color": "#c00"})
            sc.update_layout(title=f"{m} against {ax.target} ({ax.kind})",
                             xaxis_title=ax.target, yaxis_title=m, height=320)
            parts.append(to_html(sc, full_html=False, include_plotlyjs=False))
        order = np.argsort(-np.nan_to_num(vals, nan=np.inf))[:worst]
        rows = [[str(int(res["run"][k])), _fmt(float(vals[k])), _axes_text(c, params[k]),
                 _error_text(res, k),
                 f"<code>{html.escape(replay_command(c, int(res['run'][k])))}</code>"]
                for k in order]
        parts.append(f"<h3>Worst {len(rows)} runs by {html.escape(m)}</h3>")
        parts.append(_table(["run", m, "axes", "error", "replay"], rows,
                            fail_rows={i for i, k in enumerate(order) if k in bad}))
        if ores is not None and m in ores:
            parts.append(f"<h3>{html.escape(m)}: this campaign vs "
                         f"{html.escape(str(other))}</h3>")
            parts.append(_table(["statistic", c.name, str(other.name)], [
                [s, _fmt(statistic(res.get(m, np.array([])), s)),
                 _fmt(statistic(ores.get(m, np.array([])), s))] for s in _STATS]))
    style = ("<style>body{font-family:sans-serif;margin:2em;max-width:1100px}"
             "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;"
             "padding:3px 8px}.pass{color:#176e17;font-weight:bold}"
             ".fail{color:#b00;font-weight:bold}tr.beyond td{background:#fde2e2}"
             ".libnote{color:#555;font-size:12px;border-top:1px solid #ccc;margin-top:2em}"
             "</style>")
    from bench import plotly_page_parts

    head, notice, footer = plotly_page_parts(
        Path(rdir) / "report.html", fix="copy it together with the plotly-*.min.js "
                                        "beside its campaign folder")
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>campaign "
            f"{html.escape(c.name)}</title>{style}{head}</head><body>{notice}{''.join(parts)}"
            f"{footer}</body></html>")


def write_report(c: Campaign, rdir: Path, other: Path | None = None) -> Path:
    out = rdir / "report.html"
    out.write_text(render(c, rdir, other), encoding="utf-8")
    return out
