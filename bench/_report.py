"""Run reports: HTML with matplotlib PNG plots, JUnit XML, summary JSON."""

from __future__ import annotations

import base64
import html
import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np

from bench._runner import RunResult
from bench._units import MotorUnits
from sim_fallback.metrics import METRIC_DEFS, definitions_rows, wrap_pi


def _clean(x: Any) -> Any:
    """NaN/inf -> None so the JSON stays valid."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        return _clean(x.item())
    return x


def summary(result: RunResult, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """The ``--summary-json`` document: ``{"sequence", "passed", "metrics", ...}``.

    Metrics that cannot be computed (no truth) are ``null``; ``metric_windows_s``
    gives the window each headline metric covers (definitions:
    :mod:`sim_fallback.metrics`).
    """
    doc: dict[str, Any] = {
        "sequence": result.sequence,
        "passed": bool(result.passed),
        "metrics": _clean(dict(result.metrics)),
        "metric_windows_s": _clean({k: list(w) for k, w in result.metric_windows.items()}),
        "expectations": [_clean({"name": e.name, "metric": e.metric, "measured": e.measured,
                                 "criterion": e.criterion, "window_s": list(e.window_s),
                                 "passed": e.passed, "judged": e.judged,
                                 "status": e.status.lower(), "message": e.message or None,
                                 "paper": e.paper, "paper_reproduced": e.paper_met})
                         for e in result.expectations],
        "evidence": _clean(dict(result.evidence)) or None,
        "aborted": result.aborted,
        "error": result.error,
        "safe_state": result.safe_state,
    }
    if extra:
        doc.update(_clean(extra))
    return doc


def write_summary_json(path: str | Path, result: RunResult,
                       extra: dict[str, Any] | None = None) -> None:
    """Write :func:`summary` to ``path``."""
    Path(path).write_text(json.dumps(summary(result, extra), indent=2) + "\n")


def write_junit(path: str | Path, results: list[RunResult],
                drive: dict[str, Any] | None = None) -> None:
    """JUnit XML: one testsuite per sequence, one testcase per expectation.

    A sequence that aborted (exception, Ctrl-C) or could not reach the safe
    state gets an ``<error>`` testcase named ``run``. ``drive`` (from
    ``bench._session.drive_kind``) becomes testsuite properties ``drive``
    (what the drive said it is: hardware, simulated, emulated, no_io, unknown),
    ``simulated``, ``fallback`` and ``board``, so that a CI job can tell a simulated
    or emulated pass from a hardware pass.
    """
    suites = ET.Element("testsuites")
    for r in results:
        suite_props = None
        if drive:
            suite_props = ET.Element("properties")
            for k in ("drive", "simulated", "fallback", "board"):
                v = drive.get(k)
                ET.SubElement(suite_props, "property", name=k,
                              value=str(v).lower() if isinstance(v, bool) else str(v))
        cases = []
        for e in r.expectations:
            # time = the stretch of sequence time the expectation judged (s)
            tc = ET.Element("testcase", classname=f"bench.{r.sequence}", name=e.name,
                            time=f"{max(0.0, e.window_s[1] - e.window_s[0]):.6g}")
            if not e.judged:  # needs what the run did not have (a reference sensor)
                ET.SubElement(tc, "skipped", message=e.message or "not judged")
            elif not e.passed:
                f = ET.SubElement(tc, "failure", message=e.message or "failed",
                                  type="ExpectationFailed")
                f.text = (f"{e.metric} over {list(e.window_s)} s: measured {e.measured!r}, "
                          f"required {e.criterion} (sequence line {e.line})")
            props = ET.SubElement(tc, "properties")
            unit = METRIC_DEFS[e.metric].unit if e.metric in METRIC_DEFS else ""
            limit = e.criterion.split()[-1] if e.criterion else ""
            for k, v in (("metric", e.metric),
                         ("measured", "nan" if not math.isfinite(e.measured)
                          else f"{e.measured:.9g}"),
                         ("required", e.criterion), ("limit", limit), ("unit", unit),
                         ("window_s", f"{e.window_s[0]:g} {e.window_s[1]:g}"),
                         ("sequence_line", str(e.line)), ("doc", e.doc)):
                ET.SubElement(props, "property", name=k, value=v)
            if e.paper is not None:
                ET.SubElement(props, "property", name="paper", value=f"{e.paper:g}")
                ET.SubElement(props, "property", name="paper_reproduced",
                              value=str(bool(e.paper_met)).lower())
            cases.append(tc)
        run = ET.Element("testcase", classname=f"bench.{r.sequence}", name="run",
                         time=f"{r.wall_s:.3f}")
        if r.aborted or r.safe_state != "disabled":
            err = ET.SubElement(run, "error", message=r.error or r.safe_state,
                                type="RunAborted")
            err.text = f"error: {r.error}\nsafe state: {r.safe_state}"
        cases.append(run)
        n_fail = sum(1 for c in cases if c.find("failure") is not None)
        n_err = sum(1 for c in cases if c.find("error") is not None)
        n_skip = sum(1 for c in cases if c.find("skipped") is not None)
        suite = ET.SubElement(suites, "testsuite", name=r.sequence, tests=str(len(cases)),
                              failures=str(n_fail), errors=str(n_err), skipped=str(n_skip),
                              time=f"{r.wall_s:.3f}")
        if suite_props is not None:
            suite.append(suite_props)
        suite.extend(cases)
    ET.indent(suites)
    ET.ElementTree(suites).write(path, encoding="utf-8", xml_declaration=True)


# ---- plots ----------------------------------------------------------------------------


def _decimate(t: np.ndarray, v: np.ndarray, n_max: int = 4000
              ) -> tuple[np.ndarray, np.ndarray]:
    """At most about ``n_max`` points: the min and the max of each of ``n_max / 2``
    buckets in time order, so spikes and noise bands survive (plain striding hides
    them)."""
    t, v = np.asarray(t), np.asarray(v)
    n_b = max(1, n_max // 2)
    if t.size <= n_max or v.ndim != 1:
        return t, v
    k = t.size // n_b
    m = k * n_b
    blk = v[:m].astype(np.float64).reshape(n_b, k)
    fin = np.isfinite(blk)
    lo = np.argmin(np.where(fin, blk, np.inf), axis=1)
    hi = np.argmax(np.where(fin, blk, -np.inf), axis=1)
    base = np.arange(n_b) * k
    idx = np.stack([base + np.minimum(lo, hi), base + np.maximum(lo, hi)], axis=1).ravel()
    idx = np.concatenate([idx, np.arange(m, t.size)])
    return t[idx], v[idx]


#: The paper the reproduced claims come from (docs/method.md).
PAPER_CITATION = ("Position Sensorless Control of Permanent Magnet Linear Synchronous Motor "
                  "Based on SOGI High Frequency Square Wave Voltage Injection, Small & Special "
                  "Electrical Machines, 2024 (02), pp. 59-63")

_PASS, _FAIL, _TRACE = "#2ca02c", "#d62728", "#9467bd"
_TIME_AXIS = "sequence time (s)"
#: line colours, restarted in every row so the first line of a row is always blue
_COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#17becf", "#8c564b", "#e377c2")


def _enabled_window(logger: Any) -> tuple[float, float] | None:
    """Sequence time from the first to the last statusword saying OPERATION ENABLED
    (0x6041 & 0x6F == 0x27); None when the statusword was not recorded."""
    t, v = logger.channel("pdo.statusword")
    if t.size == 0:
        return None
    on = (v.astype(np.int64) & 0x6F) == 0x27
    if not np.any(on):
        return None
    tt = t[on] - logger.t_origin_s
    return float(tt[0]), float(tt[-1])


def _nums(a: Any) -> dict[str, str]:
    """A float array as a plotly.js typed array (float32, base64: about 7 significant
    digits, 5.3 characters per point, and no float formatting in Python, which made
    JSON the report's largest cost); NaN/inf become NaN, a gap in the line."""
    a = np.asarray(a, dtype=np.float64).ravel()
    b = np.where(np.isfinite(a), a, np.nan).astype("<f4")
    return {"dtype": "f4", "bdata": base64.b64encode(b.tobytes()).decode("ascii")}


class _Figure:
    """A plotly figure as plain JSON (rows of stacked subplots sharing the time axis).

    Building the dicts directly instead of through ``plotly.graph_objects`` keeps the
    report at a few tens of milliseconds; the browser does the rest (plotly.js).
    """

    def __init__(self, rows: list[str], title: str, lane: bool = False,
                 x_range: tuple[float, float] | None = None) -> None:
        self.lane = lane
        labels = (["windows"] if lane else []) + rows
        n = len(labels)
        heights = ([0.55] if lane else []) + [1.0] * len(rows)
        gap = 0.035
        unit_h = (1.0 - gap * (n - 1)) / sum(heights)
        self.data: list[dict[str, Any]] = []
        self.layout: dict[str, Any] = {
            "title": {"text": html.escape(title), "x": 0.0, "xanchor": "left",
                      "xref": "container", "y": 1.0, "yref": "container", "yanchor": "top",
                      "pad": {"t": 12, "l": 10}, "font": {"size": 16}},
            "height": 150 + 175 * n + (25 if lane else 0),
            "margin": {"l": 80, "r": 20, "t": 105, "b": 50},
            "legend": {"orientation": "h", "y": 1.0, "yanchor": "bottom", "x": 0,
                       "xanchor": "left", "font": {"size": 12}},
            "hovermode": "x unified", "paper_bgcolor": "white", "plot_bgcolor": "white",
        }
        self._per_row: dict[int, int] = {}
        top = 1.0
        for i, lab in enumerate(labels):
            k = "" if i == 0 else str(i + 1)
            h = heights[i] * unit_h
            last = i == n - 1
            xa: dict[str, Any] = {}
            if x_range is not None:
                xa["range"] = [x_range[0], x_range[1]]
            xa.update({"anchor": f"y{k}", "domain": [0, 1], "showticklabels": last,
                       "gridcolor": "#e5e5e5", "zeroline": False, "ticks": "outside"})
            if i:
                xa["matches"] = "x"
            if last:
                xa["title"] = {"text": _TIME_AXIS}
            ya: dict[str, Any] = {"anchor": f"x{k}", "domain": [max(0.0, top - h), top],
                                  "gridcolor": "#e5e5e5", "zeroline": False,
                                  "title": {"text": html.escape(lab), "font": {"size": 12}}}
            if lane and i == 0:
                ya.update({"type": "category", "title": {"text": ""}, "fixedrange": True,
                           "tickfont": {"size": 11}, "automargin": True})
            self.layout[f"xaxis{k}"] = xa
            self.layout[f"yaxis{k}"] = ya
            top -= h + gap
        self.n = n

    def axis(self, row: int) -> str:
        """Axis suffix of data row ``row`` (1-based, not counting the lane)."""
        i = row - 1 + (1 if self.lane else 0)
        return "" if i == 0 else str(i + 1)

    def line(self, row: int, t: np.ndarray, v: np.ndarray, name: str, color: str | None = None,
             dash: str | None = None, shape: str | None = None, group: str | None = None,
             showlegend: bool = True) -> None:
        a, b = _decimate(t, v)
        k = self.axis(row)
        j = self._per_row.get(row, 0)
        self._per_row[row] = j + 1
        ln: dict[str, Any] = {"width": 1.3, "color": color or _COLORS[j % len(_COLORS)]}
        if dash:
            ln["dash"] = dash
        if shape:
            ln["shape"] = shape
        tr: dict[str, Any] = {"type": "scatter", "mode": "lines", "x": _nums(a), "y": _nums(b),
                              "name": name, "line": ln, "xaxis": f"x{k}", "yaxis": f"y{k}",
                              "showlegend": showlegend}
        if group:
            tr["legendgroup"] = group
        self.data.append(tr)

    def y_range(self, row: int, lo: float, hi: float) -> None:
        self.layout[f"yaxis{self.axis(row)}"]["range"] = [lo, hi]

    def lanes(self, result: RunResult, windows: list[dict[str, Any]]) -> None:
        """First row: one labelled bar per expectation window (green pass, red FAIL) and
        per trace capture (purple); the legend names the colours."""
        shown: set[str] = set()
        names: list[str] = []
        for e in result.expectations:
            grp = "expectation window: pass" if e.passed else "expectation window: FAIL"
            names.append(e.name)
            meas = "n/a" if not math.isfinite(e.measured) else f"{e.measured:.4g}"
            self.data.append({
                "type": "scatter", "mode": "lines", "x": list(e.window_s),
                "y": [e.name, e.name], "xaxis": "x", "yaxis": "y", "name": grp,
                "legendgroup": grp, "showlegend": grp not in shown,
                "line": {"color": _PASS if e.passed else _FAIL, "width": 10},
                "hovertemplate": html.escape(f"{e.name}: measured {meas}, required "
                                             f"{e.criterion}") + "<extra></extra>"})
            shown.add(grp)
        for w in windows:
            lab = f"trace '{w['name']}'"
            names.append(lab)
            self.data.append({
                "type": "scatter", "mode": "lines", "x": [w["t0_s"], w["t1_s"]],
                "y": [lab, lab], "xaxis": "x", "yaxis": "y", "name": "trace capture",
                "legendgroup": "trace", "showlegend": "trace" not in shown,
                "line": {"color": _TRACE, "width": 10},
                "hovertemplate": html.escape(f"{lab}: {w['t0_s']:.4f}-{w['t1_s']:.4f} s")
                + "<extra></extra>"})
            shown.add("trace")
        self.layout["yaxis"].update({"categoryorder": "array",
                                     "categoryarray": names[::-1]})
        self.layout["height"] += 14 * max(0, len(names) - 3)

    def div(self, div_id: str) -> str:
        """``<div>`` + the script that draws it (plotly.js must be loaded before)."""
        cfg = {"displaylogo": False, "responsive": True,
               "toImageButtonOptions": {"format": "png", "filename": div_id}}
        fig = json.dumps({"data": self.data, "layout": self.layout, "config": cfg},
                         separators=(",", ":"), allow_nan=False)
        return (f'<div id="{div_id}" class="plot" style="height:{self.layout["height"]}px">'
                f'</div>\n<script>(function(){{var f={fig};'
                f'Plotly.newPlot("{div_id}",f.data,f.layout,f.config);}})();</script>')


def make_plots(logger: Any, result: RunResult, units: MotorUnits, out_dir: Path
               ) -> list[tuple[str, str]]:
    """Interactive plots of a run; returns ``[(html <div> + script, caption), ...]``.

    The x range is cut to the time the drive was enabled (zoom out or double-click to
    see the rest), every axis has its unit, and a first row names each expectation
    window and trace capture. plotly.js itself is embedded once by :func:`write_html`.
    Also writes ``compare.js`` (decimated key signals) for the runs index's comparison
    view.
    """
    t0 = logger.t_origin_s
    rpm = 60.0 / (2.0 * math.pi * units.pole_pairs)  # electrical rad/s -> r/min
    en = _enabled_window(logger)

    def ch(name: str) -> tuple[np.ndarray, np.ndarray]:
        t, v = logger.channel(name)
        return t - t0, v

    plots: list[tuple[str, str]] = []
    compare: dict[str, Any] = {}
    truth = logger.truth()
    lane_done = False
    if truth is not None:
        t = truth["t_s"]
        fig = _Figure(["electrical angle (rad)", "position error (rad el.)", "speed (r/min)",
                       "force (N·m rotary equiv.)"], f"{result.sequence}: truth vs estimate",
                      lane=True, x_range=en)
        fig.lanes(result, logger.windows)
        lane_done = True
        fig.line(1, t, wrap_pi(truth["theta_e_rad"]), "true angle")
        fig.line(1, t, wrap_pi(truth["theta_hat_rad"]), "estimated angle", dash="dash")
        err = wrap_pi(truth["theta_e_rad"] - truth["theta_hat_rad"])
        fig.line(2, t, err, "position error (true - estimate)", color=_FAIL)
        sel = (t >= en[0] + 0.1) & (t <= en[1]) if en is not None else t > 0.1
        if np.any(sel):  # the errors under test, not the spike after disable
            lim = max(0.02, float(np.nanpercentile(np.abs(err[sel]), 99.5)) * 1.3)
            fig.y_range(2, -lim, lim)
        fig.line(3, t, truth["omega_e_radps"] * rpm, "true speed")
        fig.line(3, t, truth["omega_hat_radps"] * rpm, "estimated speed", dash="dash")
        ts, vs = ch("sim.speed_ref_radps_e")
        if ts.size:
            fig.line(3, ts, vs * rpm, "speed reference", color="black")
        tl, vl = ch("sim.load_N")
        if tl.size:
            fig.line(4, tl, vl * units.radius_m, "load", color="#8c564b")
        tf, vf = ch("sim.force_N")
        if tf.size:
            fig.line(4, tf, vf * units.radius_m, "thrust")
        plots.append((fig.div("plot-overview"),
                      "true vs estimated position and speed (simulator truth), position "
                      "error, load; top row: expectation windows (green pass, red fail) and "
                      "trace captures (purple)"))
        m = (t >= en[0]) & (t <= en[1]) if en is not None else np.ones(t.size, bool)
        for key, v in (("position error (rad el.)", err),
                       ("estimated speed (r/min)", truth["omega_hat_radps"] * rpm),
                       ("true speed (r/min)", truth["omega_e_radps"] * rpm)):
            a, b = _decimate(t[m], np.asarray(v)[m], 3000)
            compare[key] = {"t": _nums(a), "y": _nums(b)}

    names = [("sim.i_dq_hat_A", "i_d / i_q (A)"), ("sim.pll_err_rad", "PLL error (rad)"),
             ("sim.hf_amp_A", "HF amplitude (A)"), ("sim.sogi_k_eff", "SOGI gain k (-)")]
    have = [(n, lbl) for n, lbl in names if logger.channel(n)[0].size]
    if have:
        fig = _Figure([lbl for _, lbl in have], "firmware internals", x_range=en)
        for i, (n, _lbl) in enumerate(have):
            t, v = ch(n)
            if v.ndim > 1:
                for j, lab in enumerate(("i_d", "i_q")[: v.shape[1]]):
                    fig.line(i + 1, t, v[:, j], lab)
            else:
                fig.line(i + 1, t, v, n[4:])
        plots.append((fig.div("plot-internals"),
                      "firmware internals (from the simulated drive's record)"))

    wanted = ("pdo.statusword", "pdo.speed_hat_mps", "pdo.pos_hat_m", "pdo.force_hat_N",
              "pdo.error_code", "pdo.theta_hat_rad")
    have_ch = logger.channels()
    pdo = [(n, have_ch[n]) for n in wanted if n in have_ch]
    if pdo:
        fig = _Figure([f"{n[4:]} ({u or '-'})" for n, u in pdo], "received over CAN (TPDOs)",
                      lane=not lane_done, x_range=en)
        if not lane_done:
            fig.lanes(result, logger.windows)
        for i, (n, _u) in enumerate(pdo):
            t, v = ch(n)
            fig.line(i + 1, t, v, n[4:], shape="hv")
        plots.append((fig.div("plot-pdo"), "signals decoded from the drive's TPDOs (what "
                                            "the bench receives over CAN)"))

    for k, w in enumerate(logger.windows):
        sigs = w["signals"] or ["theta_hat_rad", "pll_err_rad"]
        drv = f"trace.{w['name']}."
        rows = [s for s in sigs if logger.channel("sim." + s)[0].size
                or logger.channel(drv + s)[0].size]
        if not rows:
            continue
        fig = _Figure([f"{s} ({have_ch.get(drv + s) or have_ch.get('sim.' + s) or '-'})"
                       for s in rows], f"trace capture '{w['name']}' (full control rate)",
                      x_range=(w["t0_s"], w["t1_s"]))
        for i, sgl in enumerate(rows):
            t, v = ch("sim." + sgl)
            m = (t >= w["t0_s"]) & (t <= w["t1_s"])
            if t.size:
                fig.line(i + 1, t[m], v[m], "simulator record", color="#1f77b4",
                         group="sim", showlegend=i == 0)
            t, v = ch(drv + sgl)
            if t.size:
                fig.line(i + 1, t, v, "drive trace buffer (serial upload)", color="#ff7f0e",
                         dash="dash", group="drv", showlegend=i == 0)
        plots.append((fig.div(f"plot-trace-{k}"),
                      f"trace capture {w['name']}: {w['t0_s']:.3f}-{w['t1_s']:.3f} s"))
    _write_compare_js(out_dir, result, en, compare)
    return plots


def _write_compare_js(out_dir: Path, result: RunResult, en: tuple[float, float] | None,
                      series: dict[str, Any]) -> None:
    """``compare.js``: the key signals of this run for the runs index (a script, not JSON,
    so that the index can load it from file:// where browsers refuse fetch())."""
    doc = {"sequence": result.sequence, "enabled_s": list(en) if en else None,
           "series": series}
    key = json.dumps(Path(out_dir).name)
    (Path(out_dir) / "compare.js").write_text(
        "window.BENCH_RUNS = window.BENCH_RUNS || {};\n"
        f"window.BENCH_RUNS[{key}] = {json.dumps(doc, separators=(',', ':'))};\n",
        encoding="utf-8")


def _fmt(v: Any) -> str:
    """A table cell: numbers to 5 digits, None as a dash, dicts as ``key: value`` pairs
    (never a Python repr)."""
    if v is None:
        return "&mdash;"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return "n/a" if not math.isfinite(v) else f"{v:.5g}"
    if isinstance(v, dict):
        return ", ".join(f"{html.escape(str(k))}: {_fmt(x)}" for k, x in v.items()) or "&mdash;"
    if isinstance(v, (list, tuple)):
        return ", ".join(_fmt(x) for x in v) or "&mdash;"
    return html.escape(str(v))


#: what each kind of drive (0x2090:1, what the drive says it is) means for the results
_KIND_BANNER = {
    "simulated": ("SIMULATED DRIVE", "These results come from the simulator (plant + "
                  "firmware on this host), not from hardware."),
    "emulated": ("EMULATED BOARD", "These results come from the firmware image running on "
                 "an emulated MCU (QEMU) with a virtual motor, not from hardware."),
    "no_io": ("NO-I/O DRIVE", "The drive has no power stage at all (the blank port): "
              "nothing was driven."),
    "unknown": ("UNKNOWN DRIVE", "The drive did not say what it is (no 0x2090): these "
                "results are not labelled as hardware."),
}


def drive_kind_of(meta_or_summary: dict[str, Any]) -> str:
    """The kind of drive a run's meta.json (connection_info.kind) or summary.json (drive)
    names; older files ("sim", "SIMULATED", "HARDWARE") read as their kind."""
    info = meta_or_summary.get("connection_info") or {}
    k = str(info.get("kind") or meta_or_summary.get("drive") or "unknown")
    return {"sim": "simulated", "SIMULATED": "simulated", "HARDWARE": "hardware"}.get(k, k)


def _sim_banner(meta: dict[str, Any]) -> str:
    """A banner that no reader can miss when the drive was not hardware."""
    info = meta.get("connection_info") or {}
    kind = drive_kind_of(meta)
    if kind == "hardware":
        return ""
    title, what = _KIND_BANNER.get(kind, _KIND_BANNER["unknown"])
    why = ("FALLBACK: no drive hardware answered, the bench used the simulated drive. "
           if info.get("fallback") else "")
    return (f'<p class="simbanner">{title} &mdash; ' + why + what +
            " Use --require-hardware to make a missing rig an error.</p>")


def _sim_suffix(meta: dict[str, Any]) -> str:
    kind = drive_kind_of(meta)
    return "" if kind == "hardware" else f" ({_KIND_BANNER.get(kind, _KIND_BANNER['unknown'])[0]})"


def _evidence_html(result: RunResult) -> str:
    """What the run was judged on, and - once - what it could not judge."""
    ev = result.evidence or {}
    if not ev:
        return ""
    n_nj = sum(1 for e in result.expectations if not e.judged)
    note = ev.get("note") or ""
    extra = (f" {n_nj} expectation(s) not judged." if n_nj else "")
    cls = "evidence nosensor" if note else "evidence"
    return (f"<p class='{cls}'>Judged on: {html.escape(str(ev.get('description', '')))}."
            + (f"<br>{html.escape(note)}." if note else "") + html.escape(extra) + "</p>")


def write_html(path: Path, result: RunResult, plots: list[tuple[str, str]],
               meta: dict[str, Any], logstats: dict[str, Any]) -> None:
    """One self-contained HTML file: tables, interactive plots, plotly.js embedded once
    (works offline, from file://)."""
    from plotly.offline import get_plotlyjs

    ok = result.passed

    def unit(metric: str) -> str:
        return METRIC_DEFS[metric].unit if metric in METRIC_DEFS else ""

    rows = "\n".join(
        f"<tr class='{'nj' if not e.judged else 'pass' if e.passed else 'fail'}'>"
        f"<td>{_fmt(e.name)}</td>"
        f"<td>{_fmt(e.metric)}</td><td>[{e.window_s[0]:g}, {e.window_s[1]:g}]</td>"
        f"<td>{_fmt(e.measured)}</td><td>{_fmt(e.criterion)}</td><td>{_fmt(unit(e.metric))}</td>"
        f"<td>{e.status}</td>"
        f"<td>{'' if e.paper is None else _fmt(e.paper)}</td>"
        f"<td>{'' if e.paper_met is None else ('yes' if e.paper_met else 'NO')}</td>"
        f"<td>{_fmt(e.doc)}{'<br>' if e.doc and e.message else ''}{_fmt(e.message)}</td></tr>"
        for e in result.expectations)
    cite = ""
    if any(e.paper is not None for e in result.expectations):
        cite = ("<p class='cite'>paper: the value the reference paper claims, shown beside "
                "what this bench holds (<i>required</i>); reproduced = the measurement also "
                f"meets it. Reference: {html.escape(PAPER_CITATION)}.</p>")
    def win(k: str) -> str:
        w = result.metric_windows.get(k)
        return "" if w is None else f"[{w[0]:g}, {w[1]:g}]"

    metrics = "\n".join(
        f"<tr><td>{_fmt(k)}</td><td>{_fmt(v)}</td>"
        f"<td>{_fmt(METRIC_DEFS[k].unit if k in METRIC_DEFS else '')}</td><td>{win(k)}</td></tr>"
        for k, v in result.metrics.items())
    defs = definitions_rows()
    defs_html = ("<tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in defs[0]) + "</tr>\n"
                 + "\n".join("<tr>" + "".join(f"<td>{html.escape(v)}</td>" for v in r.values())
                              + "</tr>" for r in defs))
    figs = "\n".join(f"<figure>{div}<figcaption>{html.escape(c)}</figcaption></figure>"
                     for div, c in plots)
    drive = meta.get("drive", {})
    info = "\n".join(f"<tr><td>{_fmt(k)}</td><td>{_fmt(v)}</td></tr>" for k, v in {
        "connection": meta.get("connection"), "firmware": drive.get("firmware_version"),
        "build id": drive.get("build_id"), "motor": meta.get("sequence", {}).get("motor"),
        "extractor": meta.get("sequence", {}).get("extractor"),
        "seed": meta.get("sequence", {}).get("seed"), "bench": meta.get("bench_version"),
        "CAN frames logged": logstats.get("frames_logged"),
        "lost frames": logstats.get("lost_frames"),
        "receive-thread errors": len(logstats.get("receive_errors", [])),
        "safe state": result.safe_state, "error": result.error,
        "sequence time (s)": result.duration_s, "wall time (s)": result.wall_s}.items())
    doc = f"""<!doctype html>
<html><head><meta charset="utf-8"><title>{html.escape(result.sequence)} - bench report</title>
<style>
body {{ font-family: sans-serif; margin: 2em; max-width: 1300px; }}
table {{ border-collapse: collapse; margin: 1em 0; }}
td, th {{ border: 1px solid #ccc; padding: 3px 8px; font-size: 14px; }}
tr.pass td:nth-child(7) {{ color: #070; font-weight: bold; }}
tr.fail td {{ background: #fee; }} tr.fail td:nth-child(7) {{ color: #b00; font-weight: bold; }}
tr.nj td {{ color: #666; }} tr.nj td:nth-child(7) {{ font-weight: bold; }}
.evidence {{ border-left: 4px solid #888; padding: 0.3em 0.8em; }}
.nosensor {{ border-left-color: #c80; font-weight: bold; }}
.cite {{ color: #444; font-size: 13px; }}
.verdict {{ font-size: 1.4em; font-weight: bold; color: {'#070' if ok else '#b00'}; }}
img {{ max-width: 100%; }} figcaption {{ color: #555; font-size: 13px; }}
.simbanner {{ background: #ffe08a; border: 3px solid #c80; padding: 0.6em 1em;
  font-weight: bold; font-size: 1.1em; }}
</style>
<script type="text/javascript">{get_plotlyjs()}</script></head><body>
<h1>{html.escape(result.sequence)}</h1>
{_sim_banner(meta)}
<p class="verdict">{'PASSED' if ok else 'FAILED'}{_sim_suffix(meta)}</p>
{_evidence_html(result)}
<p>{html.escape(str(meta.get('sequence', {}).get('description', '')))}</p>
<h2>Expectations</h2>
<table><tr><th>expectation</th><th>metric</th><th>window (s)</th><th>measured</th>
<th>required</th><th>unit</th><th>result</th><th>paper</th><th>paper reproduced</th>
<th>what it checks</th></tr>
{rows}
</table>
{cite}
<h2>Plots</h2>
<p class="cite">Zoom with the mouse (double-click resets), hover for values; the time axis
starts cut to the time the drive was enabled.</p>
{figs}
<h2>Metrics over their default windows</h2>
<table><tr><th>metric</th><th>value</th><th>unit</th><th>window (s)</th></tr>
{metrics}</table>
<h2>Metric definitions</h2>
<table>{defs_html}</table>
<h2>Run</h2>
<table>{info}</table>
</body></html>
"""
    path.write_text(doc, encoding="utf-8")


# ---- runs index -----------------------------------------------------------------------

#: metrics shown as columns of the runs index (all of them are in the comparison view)
INDEX_METRICS = ("position_error_rms_rad", "position_error_max_rad",
                 "speed_estimate_error_max_rpm", "speed_tracking_error_max_rpm",
                 "settling_time_s")


def _read_run(d: Path) -> dict[str, Any] | None:
    """One run folder's entry for the index; None when it has no readable summary."""
    try:
        s = json.loads((d / "summary.json").read_text(encoding="utf-8"))
        if not isinstance(s, dict) or "sequence" not in s:
            return None
    except (OSError, ValueError):
        return None
    try:
        meta = json.loads((d / "meta.json").read_text(encoding="utf-8"))
        if not isinstance(meta, dict):
            meta = {}
    except (OSError, ValueError):
        meta = {}
    seq = meta.get("sequence") if isinstance(meta.get("sequence"), dict) else {}
    date = str(meta.get("created_utc") or "")
    if not date:  # folder names start with the UTC time stamp: 20261123T024552_...
        stamp = d.name.split("_", 1)[0]
        date = (f"{stamp[0:4]}-{stamp[4:6]}-{stamp[6:8]} {stamp[9:11]}:{stamp[11:13]}:"
                f"{stamp[13:15]}" if len(stamp) >= 15 and stamp[8:9] == "T" else "")
    exps = [e for e in s.get("expectations") or [] if isinstance(e, dict)]
    verdict = ("ABORTED" if s.get("aborted") else "PASSED" if s.get("passed") else "FAILED")
    metrics = s.get("metrics") if isinstance(s.get("metrics"), dict) else {}
    return {
        "dir": d.name, "sequence": str(s.get("sequence")), "date": date.replace("T", " ")[:19],
        "verdict": verdict, "drive": drive_kind_of(s).upper(),
        "motor": seq.get("motor"), "extractor": seq.get("extractor"), "seed": seq.get("seed"),
        "passed_exp": sum(1 for e in exps if e.get("passed")), "n_exp": len(exps),
        "paper_not_reproduced": sum(1 for e in exps if e.get("paper_reproduced") is False),
        "metrics": {k: v for k, v in metrics.items() if isinstance(v, (int, float))
                    and not isinstance(v, bool)},
        "error": s.get("error"),
        "report": (d / "report.html").is_file(), "compare": (d / "compare.js").is_file(),
    }


def write_index(runs_root: str | Path) -> Path:
    """Write ``<runs_root>/index.html``: every run (newest first) with sequence, date,
    verdict and key metrics, and a comparison of the runs ticked (metrics side by side,
    position error and speed overlaid). plotly.js is embedded once; each run's signals
    come from its ``compare.js`` (loaded by a script tag, so it works from file://).

    Raises FileNotFoundError when ``runs_root`` is not a directory.
    """
    root = Path(runs_root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no such runs folder")
    runs = [r for d in sorted(root.iterdir(), reverse=True) if d.is_dir()
            for r in [_read_run(d)] if r is not None]
    units = {k: METRIC_DEFS[k].unit for k in METRIC_DEFS}
    names = [k for k in METRIC_DEFS if any(k in r["metrics"] for r in runs)]
    names += sorted({k for r in runs for k in r["metrics"]} - set(names))

    def cell(v: Any) -> str:
        return "&mdash;" if v is None or v == "" else _fmt(v)

    head = "".join(f"<th>{html.escape(k)}<br><span class='u'>"
                   f"{html.escape(units.get(k, '') or '-')}</span></th>" for k in INDEX_METRICS)
    rows = []
    for r in runs:
        link = (f"<a href='{html.escape(r['dir'])}/report.html'>{html.escape(r['dir'])}</a>"
                if r["report"] else html.escape(r["dir"]))
        cls = r["verdict"].lower()
        exp = (f"{r['passed_exp']}/{r['n_exp']}"
               + (f"<br><span class='u'>paper not reproduced: {r['paper_not_reproduced']}"
                  "</span>" if r["paper_not_reproduced"] else ""))
        met = "".join(f"<td class='num'>{cell(r['metrics'].get(k))}</td>"
                      for k in INDEX_METRICS)
        drive = f" <span class='sim'>{html.escape(r['drive'])}</span>" if r["drive"] else ""
        tip = "" if r["compare"] else " title='no plot data (run from an older bench)'"
        rows.append(
            f"<tr><td><input type='checkbox' class='pick' value='{html.escape(r['dir'])}'"
            f"{tip}>"
            f"</td><td>{html.escape(r['sequence'])}</td><td>{html.escape(r['date'])}</td>"
            f"<td class='{cls}'>{r['verdict']}{drive}</td><td>{exp}</td>{met}"
            f"<td>{cell(r['motor'])}, {cell(r['extractor'])}, seed {cell(r['seed'])}</td>"
            f"<td>{link}</td></tr>")
    data = {"runs": {r["dir"]: {k: r[k] for k in ("sequence", "date", "verdict", "metrics",
                                                   "compare", "drive")} for r in runs},
            "metrics": names, "units": {k: units.get(k, "") for k in names}}
    from plotly.offline import get_plotlyjs

    body = ("\n".join(rows) if rows else
            f"<tr><td colspan='{7 + len(INDEX_METRICS)}'>no runs yet</td></tr>")
    doc = f"""<!doctype html>
<html><head><meta charset="utf-8"><title>bench runs</title>
<style>
body {{ font-family: sans-serif; margin: 1.5em; }}
table {{ border-collapse: collapse; margin: 1em 0; }}
td, th {{ border: 1px solid #ccc; padding: 3px 6px; font-size: 13px; vertical-align: top; }}
#runs td:nth-child(3) {{ white-space: nowrap; }}
th {{ background: #f4f4f4; }} .u {{ font-weight: normal; color: #555; font-size: 12px; }}
td.num {{ text-align: right; font-variant-numeric: tabular-nums; }}
td.passed {{ color: #070; font-weight: bold; }} td.failed, td.aborted {{ color: #b00;
  font-weight: bold; background: #fee; }}
.sim {{ background: #ffe08a; color: #000; font-size: 11px; padding: 0 4px; font-weight: normal; }}
button {{ font-size: 14px; padding: 4px 12px; }} .note {{ color: #555; font-size: 13px; }}
</style>
<script type="text/javascript">{get_plotlyjs()}</script></head><body>
<h1>Bench runs</h1>
<p class="note">{len(runs)} run(s) in {html.escape(str(root))}, newest first. Tick two or more
runs and press <b>Compare</b>: the same metric side by side and the signals overlaid.
Regenerate with <code>bench report index --runs {html.escape(str(root))}</code>.</p>
<button id="cmp">Compare selected</button> <span id="msg" class="note"></span>
<table id="runs"><tr><th></th><th>sequence</th><th>date (UTC)</th><th>verdict</th>
<th>expectations passed</th>{head}<th>motor, extractor, seed</th><th>run folder</th></tr>
{body}
</table>
<div id="comparison"></div>
<script>
var INDEX = {json.dumps(data, separators=(",", ":"), allow_nan=False)};
window.BENCH_RUNS = window.BENCH_RUNS || {{}};
function esc(s) {{ return String(s).replace(/[&<>"']/g, function (c) {{
  return {{"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;"}}[c]; }}); }}
function fmt(v) {{ return (v === undefined || v === null) ? "&mdash;" :
  Number(v).toPrecision(5).replace(/\\.?0+$/, "").replace(/\\.?0+e/, "e"); }}
function load(dir) {{
  return new Promise(function (ok) {{
    if (window.BENCH_RUNS[dir] || !INDEX.runs[dir].compare) {{ ok(); return; }}
    var s = document.createElement("script");
    s.src = encodeURI(dir) + "/compare.js"; s.onload = ok; s.onerror = ok;
    document.head.appendChild(s); }}); }}
function compare() {{
  var dirs = Array.from(document.querySelectorAll(".pick:checked")).map(function (c) {{
    return c.value; }});
  var msg = document.getElementById("msg");
  if (dirs.length < 2) {{ msg.textContent = "tick at least two runs"; return; }}
  msg.textContent = "";
  Promise.all(dirs.map(load)).then(function () {{ draw(dirs); }}); }}
function draw(dirs) {{
  var out = document.getElementById("comparison");
  var h = "<h2>Comparison</h2><table><tr><th>metric</th><th>unit</th>";
  dirs.forEach(function (d) {{ var r = INDEX.runs[d];
    h += "<th>" + esc(r.sequence) + "<br><span class='u'>" + esc(r.date) + "<br>" +
      esc(d) + "</span></th>"; }});
  h += "</tr><tr><td>verdict</td><td></td>";
  dirs.forEach(function (d) {{ var r = INDEX.runs[d];
    h += "<td class='" + r.verdict.toLowerCase() + "'>" + r.verdict + "</td>"; }});
  h += "</tr>";
  INDEX.metrics.forEach(function (m) {{
    h += "<tr><td>" + esc(m) + "</td><td>" + esc(INDEX.units[m] || "-") + "</td>";
    dirs.forEach(function (d) {{ h += "<td class='num'>" + fmt(INDEX.runs[d].metrics[m]) +
      "</td>"; }});
    h += "</tr>"; }});
  h += "</table>";
  var keys = ["position error (rad el.)", "estimated speed (r/min)", "true speed (r/min)"];
  var missing = dirs.filter(function (d) {{ return !window.BENCH_RUNS[d]; }});
  if (missing.length) h += "<p class='note'>no plot data for: " + esc(missing.join(", ")) +
    " (runs from an older bench, or no simulator truth)</p>";
  keys.forEach(function (k, i) {{
    h += "<div id='cmpplot" + i + "' style='height:330px'></div>"; }});
  out.innerHTML = h;
  keys.forEach(function (k, i) {{
    var traces = [];
    dirs.forEach(function (d) {{ var r = window.BENCH_RUNS[d];
      if (!r || !r.series[k]) return;
      traces.push({{type: "scatter", mode: "lines", x: r.series[k].t, y: r.series[k].y,
        line: {{width: 1.5, dash: ["solid", "dash", "dot", "dashdot"][traces.length % 4]}},
        name: INDEX.runs[d].sequence + " " + INDEX.runs[d].date}}); }});
    Plotly.newPlot("cmpplot" + i, traces, {{
      title: {{text: k + " (runs overlaid)", x: 0, xanchor: "left"}},
      margin: {{l: 70, r: 20, t: 40, b: 45}}, hovermode: "x unified",
      legend: {{orientation: "h", y: -0.25}},
      xaxis: {{title: {{text: "sequence time (s)"}}, gridcolor: "#e5e5e5"}},
      yaxis: {{title: {{text: k}}, gridcolor: "#e5e5e5", zeroline: false}}}},
      {{displaylogo: false, responsive: true}}); }});
  out.scrollIntoView(); }}
document.getElementById("cmp").addEventListener("click", compare);
var pre = new URLSearchParams(location.search).get("compare");
if (pre) {{ pre.split(",").forEach(function (d) {{
  var c = document.querySelector(".pick[value='" + CSS.escape(d) + "']");
  if (c) c.checked = true; }}); compare(); }}
</script>
</body></html>
"""
    out = root / "index.html"
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(doc, encoding="utf-8")
    tmp.replace(out)
    return out
