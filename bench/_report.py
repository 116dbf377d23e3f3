"""Run reports: HTML with interactive plotly plots, the runs index, JUnit XML, summary JSON.

plotly.js is kept once per runs folder (``<runs>/plotly-<version>.min.js``, a file beside
the run folders: every folder in a runs root stays a run; written once and checked by its
content hash) and referenced relatively by every report, the runs
index and the comparison pages; ``bench report --standalone RUN_DIR`` writes a copy of a
report with the library embedded (one file that works offline on its own).
"""

from __future__ import annotations

import base64
import hashlib
import html
import json
import math
import os
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np

from bench._runner import RunResult
from bench._units import MotorUnits, run_units
from sim_fallback.metrics import (
    METRIC_DEFS,
    definitions_rows,
    metric_base,
    metric_system,
    metric_twin,
    wrap_pi,
)


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


def summary(result: RunResult, extra: dict[str, Any] | None = None,
            units: MotorUnits | None = None) -> dict[str, Any]:
    """The ``--summary-json`` document: ``{"sequence", "passed", "metrics", ...}``.

    Metrics that cannot be computed (no truth) are ``null``; ``metric_windows_s``
    gives the window each headline metric covers (definitions:
    :mod:`sim_fallback.metrics`). Every metric is there in every unit (the r/min ones and
    their m/s twins); ``units`` says which the motor is reported in (``system`` "linear":
    m/s, mm, N; "rotary": r/min, N·m) and ``metrics_in_motor_units`` names those metrics.
    ``units`` is the connection's, else the run folder's (``extra["run_dir"]``'s
    ``meta.json``, :func:`bench._units.run_units`).
    """
    if units is None or units.linear is None:
        meta: dict[str, Any] = {}
        try:
            meta = json.loads((Path(str((extra or {})["run_dir"])) / "meta.json")
                              .read_text(encoding="utf-8"))
        except (KeyError, OSError, ValueError):
            pass
        units = run_units(meta if isinstance(meta, dict) else {}, units)
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
        "units": {"system": units.system, "speed": units.speed_unit, "force": units.force_unit,
                  "position": "mm" if units.linear else "rad (electrical)",
                  "pole_pitch_m": units.pole_pitch_m, "pole_pairs": units.pole_pairs},
        "metrics_in_motor_units": shown_metrics(units, result.metrics),
    }
    if extra:
        doc.update(_clean(extra))
    return doc


def write_summary_json(path: str | Path, result: RunResult,
                       extra: dict[str, Any] | None = None,
                       units: MotorUnits | None = None) -> None:
    """Write :func:`summary` to ``path``."""
    Path(path).write_text(json.dumps(summary(result, extra, units), indent=2) + "\n")


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


# ---- plotly.js: one copy per runs folder ---------------------------------------------

_PLOTLY: dict[str, str] = {}


def plotly_js() -> tuple[str, str]:
    """``(version, text)`` of the plotly.js that the installed plotly package ships."""
    if not _PLOTLY:
        from plotly.offline import get_plotlyjs, get_plotlyjs_version

        _PLOTLY["version"], _PLOTLY["text"] = get_plotlyjs_version(), get_plotlyjs()
    return _PLOTLY["version"], _PLOTLY["text"]


def plotly_asset_name() -> str:
    """``plotly-<version>.min.js``."""
    return f"plotly-{plotly_js()[0]}.min.js"


def write_plotly_asset(runs_root: str | Path) -> Path:
    """``<runs_root>/plotly-<version>.min.js``: written when missing or when its
    content is not the library's (checked by SHA-256; written to a temporary file and
    renamed, so a reader never sees half a file). Returns its path."""
    text = plotly_js()[1].encode("utf-8")
    out = Path(runs_root) / plotly_asset_name()
    try:
        if hashlib.sha256(out.read_bytes()).digest() == hashlib.sha256(text).digest():
            return out
    except OSError:
        pass
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f"{out.name}.{os.getpid()}.tmp")
    tmp.write_bytes(text)
    tmp.replace(out)
    return out


def plotly_page_parts(page: Path, runs_root: Path | None = None,
                       fix: str = "one file that works anywhere: <code>bench report "
                                  "--standalone RUN_DIR</code>") -> tuple[str, str, str]:
    """``(head, notice, footer)`` of a page at ``page`` that loads the runs folder's
    plotly.js (``runs_root``, by default the folder that holds the page's folder:
    ``<runs>/<run>/report.html`` -> ``<runs>/plotly-<version>.min.js``; written if
    needed). The notice says,
    in one line of the page, that the library is missing when the page was copied without
    it and ``fix`` (HTML: what to do); it removes itself when the library loaded. The
    footer says where the library comes from, and ``fix``."""
    root = Path(runs_root) if runs_root is not None else page.resolve().parent.parent
    asset = write_plotly_asset(root)
    rel = os.path.relpath(asset.resolve(), page.resolve().parent).replace(os.sep, "/")
    src = html.escape(rel, quote=True)
    head = f'<script src="{src}" data-plotly-asset="{html.escape(asset.name)}"></script>'
    notice = ('<p id="plotly-missing" style="background:#fee;border:2px solid #b00;'
              'padding:0.3em 0.8em;font-weight:bold">No plots: plotly.js is missing '
              f'({src}: copied without it); {fix}</p>\n'
              '<script>if (window.Plotly) document.getElementById("plotly-missing").remove();'
              '</script>')
    footer = (f'<footer class="libnote" id="plotly-footer">Plots drawn by plotly.js '
              f'{html.escape(plotly_js()[0])}, loaded from <code>{src}</code> (one copy per '
              f'runs folder); copied alone, this page has no plots: {fix}.</footer>')
    return head, notice, footer


_ASSET_TAG = re.compile(r'<script src="[^"]*" data-plotly-asset="[^"]*"></script>')
_FOOTER = re.compile(r'<footer class="libnote" id="plotly-footer">.*?</footer>', re.S)


def write_standalone(run_dir: str | Path, out: str | Path | None = None) -> Path:
    """A copy of ``run_dir/report.html`` with plotly.js embedded instead of referenced:
    one file that works offline when copied alone (default ``run_dir/report_standalone
    .html``); its footer says so. A report written before the library was shared (it
    embeds it already) is copied as it is.

    Raises FileNotFoundError (no such run folder or no report in it) and ValueError (the
    file is not a bench report).
    """
    d = Path(run_dir)
    if not d.is_dir():
        raise FileNotFoundError(f"{d}: no such folder (give a run folder, "
                                "runs/<time>_<name>)")
    src = d / "report.html"
    if not src.is_file():
        raise FileNotFoundError(f"{d}: no report.html in it (give a run folder, "
                                "runs/<time>_<name>)")
    doc = src.read_text(encoding="utf-8")
    ver, lib = plotly_js()
    if _ASSET_TAG.search(doc):
        inline = "<script data-plotly-embedded>" + lib.replace("</script", "<\\/script") \
            + "</script>"
        doc = _ASSET_TAG.sub(lambda _m: inline, doc, count=1)
        note = (f'<footer class="libnote" id="plotly-footer">Standalone copy: plotly.js '
                f'{html.escape(ver)} is embedded in this file, which works offline on its own '
                f'(written by <code>bench report --standalone</code> from {html.escape(str(src))}).'
                '</footer>')
        doc = _FOOTER.sub(lambda _m: note, doc, count=1)
    elif "Plotly.newPlot" not in doc or "<script src=" in doc:
        raise ValueError(f"{src}: not a bench run report")
    dest = Path(out) if out is not None else d / "report_standalone.html"
    tmp = dest.with_name(dest.name + ".tmp")
    tmp.write_text(doc, encoding="utf-8")
    tmp.replace(dest)
    return dest


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
#: line colours, one per signal of a figure (its legend names each once): none of them is
#: a window lane's green, red or purple, nor the speed reference's black
_COLORS = ("#1f77b4", "#ff7f0e", "#17becf", "#8c564b", "#e377c2", "#bcbd22", "#7f7f7f",
           "#393b79", "#e6ab02", "#a55194")
#: the CiA 402 states, bottom to top of a statusword plot (the profile's order: power off,
#: the way up to OPERATION ENABLED, then stopping and faults); names of bench._drive.state_of
CIA402_STATES = ("NOT READY TO SWITCH ON", "SWITCH ON DISABLED", "READY TO SWITCH ON",
                 "SWITCHED ON", "OPERATION ENABLED", "QUICK STOP ACTIVE",
                 "FAULT REACTION ACTIVE", "FAULT", "UNKNOWN")
#: points of a plotted signal: the minimum and the maximum of about 1200 time buckets (one
#: per pixel column of a full-width plot: the envelope is exact at the default zoom)
PLOT_POINTS = 2400


def _state_names(statusword: np.ndarray) -> np.ndarray:
    """The CiA 402 state name of each statusword (``bench._drive.state_of``)."""
    from bench._drive import state_of

    sw = np.asarray(statusword).astype(np.int64).ravel()
    names = {int(x): state_of(int(x)) for x in np.unique(sw)}
    return np.array([names[int(x)] for x in sw], dtype=object)


def _enabled_window(logger: Any) -> tuple[float, float] | None:
    """Sequence time from the first to the last statusword saying OPERATION ENABLED;
    None when the statusword was not recorded."""
    t, v = logger.channel("pdo.statusword")
    if t.size == 0:
        return None
    on = _state_names(v) == "OPERATION ENABLED"
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
        #: legend name -> its colour: one colour per signal, the same for its every line
        self._colour: dict[str, str] = {}
        self._used: set[str] = {_PASS, _FAIL, _TRACE} if lane else set()
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
        a, b = _decimate(t, v, PLOT_POINTS)
        k = self.axis(row)
        ln: dict[str, Any] = {"width": 1.3, "color": self._pick(group or name, color)}
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

    def _pick(self, key: str, color: str | None) -> str:
        """The colour of legend entry ``key``: its own when it has one, else ``color``, else
        the first palette colour no other entry of this figure has."""
        c = self._colour.get(key) or color or next(
            (x for x in _COLORS if x not in self._used), _COLORS[len(self._used) % len(_COLORS)])
        self._colour[key] = c
        self._used.add(c)
        return c

    def states(self, row: int, t: np.ndarray, statusword: np.ndarray, name: str) -> None:
        """A statusword as its CiA 402 state names (a category axis in the profile's order,
        the states the run went through), a step line through the changes."""
        lab = _state_names(statusword)
        t = np.asarray(t)
        if lab.size == 0:
            return
        keep = np.ones(lab.size, bool)
        keep[1:] = lab[1:] != lab[:-1]
        keep[-1] = True
        k = self.axis(row)
        self.data.append({
            "type": "scatter", "mode": "lines+markers", "x": _nums(t[keep]),
            "y": [str(x) for x in lab[keep]], "name": name, "xaxis": f"x{k}", "yaxis": f"y{k}",
            "line": {"width": 1.6, "shape": "hv", "color": self._pick(name, None)},
            "marker": {"size": 4}, "showlegend": True})
        present = set(lab)
        self.layout[f"yaxis{k}"].update({
            "type": "category", "categoryorder": "array", "automargin": True,
            "tickfont": {"size": 10},
            "categoryarray": [n for n in CIA402_STATES if n in present]
            + sorted(present - set(CIA402_STATES))})

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
                f'</div>\n<script>(function(){{var f={fig};if(window.Plotly)'
                f'Plotly.newPlot("{div_id}",f.data,f.layout,f.config);}})();</script>')


def make_plots(logger: Any, result: RunResult, units: MotorUnits, out_dir: Path
               ) -> list[tuple[str, str]]:
    """Interactive plots of a run; returns ``[(html <div> + script, caption), ...]``.

    The x range is cut to the time the drive was enabled (zoom out or double-click to
    see the rest), every axis has its unit, and a first row names each expectation
    window and trace capture. A linear motor is plotted in m/s, mm and N, a
    rotary-equivalent one in r/min and N·m (:func:`bench._units.run_units`). plotly.js
    itself is loaded once by :func:`write_html`. Also writes ``compare.js`` (decimated key
    signals) for the runs index's comparison view.
    """
    t0 = logger.t_origin_s
    units = run_units(getattr(logger, "meta", None) or {}, units)
    spd, frc = units.speed_unit, units.force_unit
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
        pos_lab = "position error (mm)" if units.linear else "position error (rad el.)"
        fig = _Figure(["electrical angle (rad)", pos_lab, f"speed ({spd})",
                       f"force ({frc})"], f"{result.sequence}: truth vs estimate",
                      lane=True, x_range=en)
        fig.lanes(result, logger.windows)
        lane_done = True
        fig.line(1, t, wrap_pi(truth["theta_e_rad"]), "true angle")
        fig.line(1, t, wrap_pi(truth["theta_hat_rad"]), "estimated angle", dash="dash")
        err = wrap_pi(truth["theta_e_rad"] - truth["theta_hat_rad"])
        if units.linear:
            err = units.rad_e_to_mm(err)
        fig.line(2, t, err, "position error (true - estimate)")
        sel = (t >= en[0] + 0.1) & (t <= en[1]) if en is not None else t > 0.1
        if np.any(sel):  # the errors under test, not the spike after disable
            lim = max(units.rad_e_to_mm(0.02) if units.linear else 0.02,
                      float(np.nanpercentile(np.abs(err[sel]), 99.5)) * 1.3)
            fig.y_range(2, -lim, lim)
        fig.line(3, t, units.speed_of(truth["omega_e_radps"]), "true speed")
        fig.line(3, t, units.speed_of(truth["omega_hat_radps"]), "estimated speed", dash="dash")
        ts, vs = ch("sim.speed_ref_radps_e")
        if ts.size:
            fig.line(3, ts, units.speed_of(vs), "speed reference", color="black")
        tl, vl = ch("sim.load_N")
        if tl.size:
            fig.line(4, tl, units.force_of(vl), "load")
        tf, vf = ch("sim.force_N")
        if tf.size:
            fig.line(4, tf, units.force_of(vf), "thrust")
        plots.append((fig.div("plot-overview"),
                      "true vs estimated position and speed (simulator truth), position "
                      "error, load; top row: expectation windows (green pass, red fail) and "
                      "trace captures (purple)"))
        m = (t >= en[0]) & (t <= en[1]) if en is not None else np.ones(t.size, bool)
        for key, v in ((pos_lab, err),
                       (f"estimated speed ({spd})", units.speed_of(truth["omega_hat_radps"])),
                       (f"true speed ({spd})", units.speed_of(truth["omega_e_radps"]))):
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

    # the TPDOs in the motor's units: (label, unit, conversion from the wire's SI unit)
    shown = {"m/s": (spd, units.speed_of_mps), "m": ("mm", lambda x: x * 1e3),
             "N": (frc, units.force_of)}
    wanted = ("pdo.statusword", "pdo.speed_hat_mps", "pdo.pos_hat_m", "pdo.force_hat_N",
              "pdo.error_code", "pdo.theta_hat_rad")
    have_ch = logger.channels()
    pdo = [(n, have_ch[n]) for n in wanted if n in have_ch]
    if pdo:
        def label(n: str, u: str) -> str:
            if n == "pdo.statusword":
                return "statusword (CiA 402 state)"
            base = re.sub(r"_(mps|m|N|rad)$", "", n[4:])
            return f"{base} ({shown[u][0] if u in shown else u or '-'})"

        fig = _Figure([label(n, u) for n, u in pdo], "received over CAN (TPDOs)",
                      lane=not lane_done, x_range=en)
        if not lane_done:
            fig.lanes(result, logger.windows)
        for i, (n, u) in enumerate(pdo):
            t, v = ch(n)
            if n == "pdo.statusword":
                fig.states(i + 1, t, v, "statusword")
                continue
            conv = shown[u][1] if u in shown else (lambda x: x)
            fig.line(i + 1, t, conv(np.asarray(v, dtype=np.float64)), label(n, u).split(" (")[0],
                     shape="hv")
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
                fig.line(i + 1, t[m], v[m], "simulator record", group="sim",
                         showlegend=i == 0)
            t, v = ch(drv + sgl)
            if t.size:
                fig.line(i + 1, t, v, "drive trace buffer (serial upload)", dash="dash",
                         group="drv", showlegend=i == 0)
        plots.append((fig.div(f"plot-trace-{k}"),
                      f"trace capture {w['name']}: {w['t0_s']:.3f}-{w['t1_s']:.3f} s"))
    _write_compare_js(out_dir, result, en, compare)
    return plots


def _write_compare_js(out_dir: Path, result: RunResult, en: tuple[float, float] | None,
                      series: dict[str, Any]) -> None:
    """``compare.js``: the key signals of this run for the runs index (a script, not JSON,
    so that the index can load it from file:// where browsers refuse fetch()). It files
    them under the name of the folder it is loaded from (a run folder copied or renamed
    still compares), else under the run folder's name when written."""
    doc = {"sequence": result.sequence, "enabled_s": list(en) if en else None,
           "series": series}
    key = json.dumps(Path(out_dir).name)
    (Path(out_dir) / "compare.js").write_text(
        "window.BENCH_RUNS = window.BENCH_RUNS || {};\n"
        "(function (s) { var p = s && s.src ? decodeURI(s.src).split(/[\\/\\\\]/) : [];\n"
        f"  window.BENCH_RUNS[p.length > 1 ? p[p.length - 2] : {key}] = "
        f"{json.dumps(doc, separators=(',', ':'))};\n}})(document.currentScript);\n",
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


def in_motor_units(units: MotorUnits, metric: str, value: float) -> tuple[str, float] | None:
    """A measured value of a speed metric of the other kind of units than the motor's
    (an ``..._rpm`` expectation on a linear motor, an ``..._mps`` one on a
    rotary-equivalent motor) as its twin in the motor's units: ``(twin metric, value)``;
    None when ``metric`` is in the motor's units already (or has no twin)."""
    twin = metric_twin(metric, units.system)
    if twin is None or twin == metric or not math.isfinite(value):
        return None
    suffix = metric.rpartition("_")[2]
    if suffix == "rpm":
        return twin, units.speed_to_mps(value, "r/min")
    if suffix == "mps":
        return twin, units.mps_to_rpm(value)
    return None


def value_text(units: MotorUnits, metric: str, value: float) -> str:
    """A measured value with its unit, and - for a speed metric in the other kind of
    units than the motor's - its value in the motor's (``1.2 r/min (= 0.0012 m/s)``)."""
    if not math.isfinite(value):
        return "n/a"
    u = METRIC_DEFS[metric].unit if metric in METRIC_DEFS else ""
    u = u.replace(" (rotary equivalent)", "").replace(" (electrical)", " el.")
    text = f"{value:.5g}" + (f" {u}" if u else "")
    other = in_motor_units(units, metric, value)
    if other is not None:
        text += f" (= {other[1]:.5g} {units.speed_unit})"
    return text


def _by_statistic(names: Any) -> list[str]:
    """Metric names in their order, each statistic's twins in other units right after it
    (``position_error_rms_rad``, ``position_error_rms_mm``, ...)."""
    names = list(names)
    first = {}
    for i, k in enumerate(names):
        first.setdefault(metric_base(k)[0], i)
    return sorted(names, key=lambda k: (first[metric_base(k)[0]], names.index(k)))


def shown_metrics(units: MotorUnits, names: Any) -> list[str]:
    """The metrics of ``names`` a report of this motor shows: those in its units (a
    linear motor's m/s and mm, a rotary-equivalent one's r/min) and those of no particular
    kind (rad, s, A)."""
    return [k for k in names if metric_system(k) in ("", units.system)]


def write_html(path: Path, result: RunResult, plots: list[tuple[str, str]],
               meta: dict[str, Any], logstats: dict[str, Any],
               units: MotorUnits | None = None) -> None:
    """One HTML file: tables, interactive plots; plotly.js is the runs folder's one copy
    (``<runs>/plotly-<version>.min.js``, :func:`write_plotly_asset`): a page copied without
    it says so
    (:func:`write_standalone` embeds it). Linear motors are reported in m/s, mm and N,
    rotary-equivalent ones in r/min and N·m (:func:`bench._units.run_units`)."""
    ok = result.passed
    units = run_units(meta, units)
    lib_head, lib_notice, lib_footer = plotly_page_parts(Path(path))

    def unit(metric: str) -> str:
        return METRIC_DEFS[metric].unit if metric in METRIC_DEFS else ""

    def measured(metric: str, value: float) -> str:
        other = in_motor_units(units, metric, value)
        return _fmt(value) + ("" if other is None else
                              f" <span class='u'>(= {_fmt(other[1])} {units.speed_unit})</span>")

    rows = "\n".join(
        f"<tr class='{'nj' if not e.judged else 'pass' if e.passed else 'fail'}'>"
        f"<td>{_fmt(e.name)}</td>"
        f"<td>{_fmt(e.metric)}</td><td>[{e.window_s[0]:g}, {e.window_s[1]:g}]</td>"
        f"<td>{measured(e.metric, e.measured)}</td><td>{_fmt(e.criterion)}</td>"
        f"<td>{_fmt(unit(e.metric))}</td>"
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

    keep = set(shown_metrics(units, list(METRIC_DEFS) + list(result.metrics)))
    metrics = "\n".join(
        f"<tr><td>{_fmt(k)}</td><td>{_fmt(result.metrics[k])}</td>"
        f"<td>{_fmt(METRIC_DEFS[k].unit if k in METRIC_DEFS else '')}</td><td>{win(k)}</td></tr>"
        for k in _by_statistic(result.metrics) if k in keep)
    rows_by = {r["metric"]: r for r in definitions_rows()}
    defs = [rows_by[k] for k in _by_statistic(rows_by) if k in keep]
    defs_html = ("<tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in defs[0]) + "</tr>\n"
                 + "\n".join("<tr>" + "".join(f"<td>{html.escape(v)}</td>" for v in r.values())
                              + "</tr>" for r in defs))
    figs = "\n".join(f"<figure>{div}<figcaption>{html.escape(c)}</figcaption></figure>"
                     for div, c in plots)
    drive = meta.get("drive", {})
    info = "\n".join(f"<tr><td>{_fmt(k)}</td><td>{_fmt(v)}</td></tr>" for k, v in {
        "connection": meta.get("connection"), "firmware": drive.get("firmware_version"),
        "build id": drive.get("build_id"), "motor": meta.get("sequence", {}).get("motor"),
        "units": (f"{units.system} ({units.speed_unit}, {units.force_unit}"
                  + (", mm" if units.linear else "") + ")"),
        "extractor": meta.get("sequence", {}).get("extractor"),
        "seed": meta.get("sequence", {}).get("seed"), "bench": meta.get("bench_version"),
        "CAN frames logged": logstats.get("frames_logged"),
        "lost frames": ", ".join(f"{k}: {v}" for k, v in
                                 (logstats.get("lost_frames") or {}).items()) or "none",
        "receive-thread errors": len(logstats.get("receive_errors", [])),
        "safe state": result.safe_state, "error": result.error,
        "sequence time (s)": result.duration_s, "wall time (s)": result.wall_s}.items())
    dut = meta.get("dut") or {}
    rec = meta.get("record") or {}

    def hexid(v: Any) -> Any:
        return f"0x{v:08X}" if isinstance(v, int) and not isinstance(v, bool) else v

    record_rows = "\n".join(
        f"<tr><td>{_fmt(k)}</td><td>{_fmt(v)}</td></tr>" for k, v in {
            "drive serial number (0x1018:4)": hexid(dut.get("serial")),
            "vendor / product / revision (0x1018)": " / ".join(
                str(hexid(dut.get(k))) for k in ("vendor_id", "product_code", "revision")),
            "device": dut.get("device_name"), "firmware (0x2040)": dut.get("firmware_version"),
            "drive kind, board (0x2090)": f"{dut.get('kind', '')} {dut.get('board', '')}",
            "operator": rec.get("operator"), "station": rec.get("station"),
            "fixture": rec.get("fixture"), "started (UTC)": rec.get("started_utc"),
            "parameters": rec.get("params"),
            "identity not read": dut.get("error")}.items() if v not in (None, "", {}))
    record_html = (f"<h2>Test record</h2>\n<p class='cite'>What was tested, read from the "
                   f"drive; who and where, from --operator, --station, --fixture (also in "
                   f"summary.json and the results store: <code>bench results</code>).</p>"
                   f"\n<table>{record_rows}</table>") if record_rows else ""
    doc = f"""<!doctype html>
<html><head><meta charset="utf-8"><title>{html.escape(result.sequence)} - bench report</title>
<style>
body {{ font-family: sans-serif; margin: 2em; max-width: 1300px; }}
.u {{ color: #555; font-size: 12px; }}
.libnote {{ color: #555; font-size: 12px; border-top: 1px solid #ccc; margin-top: 2em;
  padding-top: 0.5em; }}
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
{lib_head}</head><body>
{lib_notice}
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
{record_html}
<h2>Run</h2>
<table>{info}</table>
{lib_footer}
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
        "error": s.get("error"), "system": run_units(meta).system,
        "report": (d / "report.html").is_file(), "compare": (d / "compare.js").is_file(),
    }


def _short_unit(unit: str) -> str:
    """A metric's unit for a narrow column: "r/min", "rad el." (the full one is in the
    report and the comparison table)."""
    return unit.replace(" (rotary equivalent)", "").replace(" (electrical)", " el.")


def _breakable(text: str) -> str:
    """HTML text that may wrap after each underscore (long metric and folder names)."""
    return html.escape(text).replace("_", "_<wbr>")


def write_index(runs_root: str | Path) -> Path:
    """Write ``<runs_root>/index.html``: every run (newest first) with sequence, date,
    verdict and key metrics, and a comparison of the runs ticked (metrics side by side,
    position error and speed overlaid). plotly.js is the runs folder's one copy
    (:func:`write_plotly_asset`); each run's signals come from its
    ``compare.js`` (loaded by a script tag, so it works from file://). The table wraps to
    the window's width (no clipping). A linear motor's runs show their m/s metrics, a
    rotary-equivalent one's r/min (the twin of each column's metric).

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

    # each column: the metric in each run's units (its twin), named once when all agree
    cols: list[tuple[str, bool]] = []
    head = ""
    for k in INDEX_METRICS:
        used = list(dict.fromkeys(metric_twin(k, r["system"]) or k for r in runs)) or [k]
        mixed = len(used) > 1
        name = k.rpartition("_")[0] if mixed else used[0]
        unit_txt = " or ".join(_short_unit(units.get(u, "")) or "-" for u in used)
        head += (f"<th>{_breakable(name)}<br><span class='u'>{html.escape(unit_txt)}"
                 "</span></th>")
        cols.append((k, mixed))

    def metric_cell(r: dict[str, Any], k: str, mixed: bool) -> str:
        m = metric_twin(k, r["system"]) or k
        v = r["metrics"].get(m)
        u = _short_unit(units.get(m, "")) if mixed and v is not None else ""
        return f"<td class='num'>{cell(v)}{' ' + html.escape(u) if u else ''}</td>"

    rows = []
    for r in runs:
        link = (f"<a href='{html.escape(r['dir'])}/report.html'>{_breakable(r['dir'])}</a>"
                if r["report"] else _breakable(r["dir"]))
        cls = r["verdict"].lower()
        exp = (f"{r['passed_exp']}/{r['n_exp']}"
               + (f"<br><span class='u'>paper not reproduced: {r['paper_not_reproduced']}"
                  "</span>" if r["paper_not_reproduced"] else ""))
        met = "".join(metric_cell(r, k, mixed) for k, mixed in cols)
        drive = f" <span class='sim'>{html.escape(r['drive'])}</span>" if r["drive"] else ""
        tip = "" if r["compare"] else " title='no plot data (run from an older bench)'"
        rows.append(
            f"<tr><td><input type='checkbox' class='pick' value='{html.escape(r['dir'])}'"
            f"{tip}>"
            f"</td><td class='id'>{_breakable(r['sequence'])}</td>"
            f"<td>{html.escape(r['date'])}</td>"
            f"<td class='{cls}'>{r['verdict']}{drive}</td><td>{exp}</td>{met}"
            f"<td class='id'>{_breakable(str(r['motor']))}, {_breakable(str(r['extractor']))}"
            f", seed {cell(r['seed'])}</td>"
            f"<td class='id'>{link}</td></tr>")
    data = {"runs": {r["dir"]: {k: r[k] for k in ("sequence", "date", "verdict", "metrics",
                                                   "compare", "drive", "system")} for r in runs},
            "metrics": names, "units": {k: units.get(k, "") for k in names},
            "system": {k: metric_system(k) for k in names}}
    lib_head, lib_notice, lib_footer = plotly_page_parts(
        root / "index.html", root, fix=f"<code>bench report index --runs "
                                       f"{html.escape(str(root))}</code> writes it again")

    body = ("\n".join(rows) if rows else
            f"<tr><td colspan='{7 + len(INDEX_METRICS)}'>no runs yet</td></tr>")
    doc = f"""<!doctype html>
<html><head><meta charset="utf-8"><title>bench runs</title>
<style>
body {{ font-family: sans-serif; margin: 1.5em; }}
table {{ border-collapse: collapse; margin: 1em 0; max-width: 100%; }}
td, th {{ border: 1px solid #ccc; padding: 3px 6px; font-size: 13px; vertical-align: top; }}
#runs td.id {{ overflow-wrap: anywhere; }} #runs td.num {{ white-space: nowrap; }}
.wide {{ overflow-x: auto; }}
.libnote {{ color: #555; font-size: 12px; border-top: 1px solid #ccc; margin-top: 2em;
  padding-top: 0.5em; }}
th {{ background: #f4f4f4; }} .u {{ font-weight: normal; color: #555; font-size: 12px; }}
td.num {{ text-align: right; font-variant-numeric: tabular-nums; }}
td.passed {{ color: #070; font-weight: bold; }} td.failed, td.aborted {{ color: #b00;
  font-weight: bold; background: #fee; }}
.sim {{ background: #ffe08a; color: #000; font-size: 11px; padding: 0 4px; font-weight: normal; }}
button {{ font-size: 14px; padding: 4px 12px; }} .note {{ color: #555; font-size: 13px; }}
</style>
{lib_head}</head><body>
{lib_notice}
<h1>Bench runs</h1>
<p class="note">{len(runs)} run(s) in {html.escape(str(root))}, newest first. Tick two or more
runs and press <b>Compare</b>: the same metric side by side and the signals overlaid.
Regenerate with <code>bench report index --runs {html.escape(str(root))}</code>.</p>
<button id="cmp">Compare selected</button> <span id="msg" class="note"></span>
<div class="wide"><table id="runs"><tr><th></th><th>sequence</th><th>date (UTC)</th>
<th>verdict</th><th>expectations passed</th>{head}<th>motor, extractor, seed</th>
<th>run folder</th></tr>
{body}
</table></div>
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
  // the metrics in the units of the runs compared (linear: m/s, mm; rotary: r/min)
  var systems = {{"": true}};
  dirs.forEach(function (d) {{ systems[INDEX.runs[d].system || "rotary"] = true; }});
  INDEX.metrics.forEach(function (m) {{
    if (!systems[INDEX.system[m] || ""]) return;
    h += "<tr><td>" + esc(m) + "</td><td>" + esc(INDEX.units[m] || "-") + "</td>";
    dirs.forEach(function (d) {{ h += "<td class='num'>" + fmt(INDEX.runs[d].metrics[m]) +
      "</td>"; }});
    h += "</tr>"; }});
  h += "</table>";
  // one plot per signal and unit (a linear run's m/s never on a r/min axis)
  var keys = [];
  dirs.forEach(function (d) {{ var r = window.BENCH_RUNS[d];
    if (r) Object.keys(r.series).forEach(function (k) {{
      if (keys.indexOf(k) < 0) keys.push(k); }}); }});
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
    if (window.Plotly) Plotly.newPlot("cmpplot" + i, traces, {{
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
{lib_footer}
</body></html>
"""
    out = root / "index.html"
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(doc, encoding="utf-8")
    tmp.replace(out)
    return out
