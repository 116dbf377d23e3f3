"""A linear bench speaks m/s, mm and N (issue 35): a linear motor file's runs are reported
in linear units everywhere (report plots and tables, console verdict lines, summary.json),
a rotary-equivalent motor file's (the paper's) keeps r/min and N·m; the m/s and mm metrics
are the r/min and rad ones through one unit conversion; the statusword is plotted as CiA
402 state names and no two signals of a figure share a colour."""

from __future__ import annotations

import contextlib
import io
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from test_report_assets import needs_chromium, rendered_dom, screenshot

from bench.cli import main

ROOT = Path(__file__).resolve().parents[2]

LINEAR_SEQ = """name: linear_units
description: 0.3 m/s, a 60 N load step at 0.5 s, iron-core linear motor
motor: iron_core_linear
extractor: sogi_adaptive
seed: 1
settle_s: 0.15
steps:
  - enable: {mode: speed}
  - set_speed: {value: 0.3, unit: m/s}
  - wait: {duration_s: 0.5}
  - load_step: {value: 60, unit: N}
  - wait: {duration_s: 0.3}
  - expect: {metric: speed_estimate_error_max_mps, op: "<=", limit: 0.5, window_s: [0.6, 0.8]}
  - expect: {metric: position_error_rms_mm, op: "<=", limit: 5, window_s: [0.6, 0.8]}
  - disable: {}
"""
ROTARY_SEQ = LINEAR_SEQ.replace("iron_core_linear", "paper_salient").replace(
    "{value: 0.3, unit: m/s}", "{value: 100, unit: r/min}").replace(
    "{value: 60, unit: N}", "{value: 2, unit: N*m}").replace(
    "speed_estimate_error_max_mps, op: \"<=\", limit: 0.5",
    "speed_estimate_error_max_rpm, op: \"<=\", limit: 50").replace(
    "name: linear_units", "name: rotary_units")


def _run(tmp: Path, text: str) -> tuple[Path, str]:
    """Run ``text`` through ``bench run --sim``: (its run folder, what it printed)."""
    seq = tmp / "seq.yaml"
    seq.write_text(text)
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(["run", str(seq), "--sim", "--runs", str(tmp / "runs"), "--no-progress"])
    assert rc == 0, buf.getvalue()
    (run,) = [d for d in (tmp / "runs").iterdir() if (d / "summary.json").is_file()]
    return run, buf.getvalue()


@pytest.fixture(scope="module")
def linear(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    return _run(tmp_path_factory.mktemp("lin"), LINEAR_SEQ)


@pytest.fixture(scope="module")
def rotary(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    return _run(tmp_path_factory.mktemp("rot"), ROTARY_SEQ)


def figures(html: str) -> dict[str, dict]:
    """Each plot's plotly JSON (data, layout) by its div id."""
    out = {}
    pat = (r'<div id="([^"]+)" class="plot"[^>]*></div>\s*<script>\(function'
           r'\(\)\{var f=(\{.*?\});(?:if\(window\.Plotly\))?Plotly')
    for div, fig in re.findall(pat, html, re.S):
        out[div] = json.loads(fig)
    assert out, "no plot in the report"
    return out


def axis_titles(fig: dict) -> list[str]:
    return [v["title"]["text"] for k, v in fig["layout"].items()
            if k.startswith("yaxis") and v.get("title", {}).get("text")]


def test_the_shipped_motor_files_say_linear_or_rotary() -> None:
    from bench._units import motor_units

    assert motor_units("iron_core_linear").linear is True
    assert motor_units("paper_salient").linear is False
    assert motor_units("paper_table1").linear is False


def test_linear_motor_report_plots_and_tables_in_m_per_s_mm_and_N(linear: tuple[Path, str]
                                                                  ) -> None:
    run, _ = linear
    html = (run / "report.html").read_text(encoding="utf-8")
    figs = figures(html)
    titles = [t for f in figs.values() for t in axis_titles(f)]
    assert {"speed (m/s)", "force (N)", "position error (mm)"} <= set(titles), titles
    assert {"speed_hat (m/s)", "force_hat (N)", "pos_hat (mm)"} <= set(titles), titles
    # no rotary unit anywhere on the page: plots, expectations, metrics, definitions (the
    # plots' binary arrays, base64 in "bdata", are data: "rpm" can occur in them by chance)
    text = re.sub(r'"bdata":"[^"]*"', '"bdata":""', html)
    assert "r/min" not in text and "N·m" not in text and "rpm" not in text
    metrics = html[html.index("<h2>Metrics over"):html.index("<h2>Metric definitions")]
    for k in ("speed_estimate_error_max_mps", "speed_tracking_error_max_mps",
              "position_error_rms_mm", "position_error_rms_rad"):
        assert f"<td>{k}</td>" in metrics, k
    assert "<td>m/s</td>" in metrics and "<td>mm</td>" in metrics


def test_rotary_equivalent_motor_keeps_r_per_min_and_N_m(rotary: tuple[Path, str]) -> None:
    run, out = rotary
    html = (run / "report.html").read_text(encoding="utf-8")
    titles = [t for f in figures(html).values() for t in axis_titles(f)]
    assert {"speed (r/min)", "force (N·m rotary equiv.)",
            "position error (rad el.)"} <= set(titles), titles
    assert "speed (m/s)" not in titles and "force (N)" not in titles
    assert "speed_estimate_error_max_rpm" in html
    assert re.search(r"\[PASS\] speed_estimate_error_max_rpm@\S+: [0-9.e+-]+ r/min ", out), out
    s = json.loads((run / "summary.json").read_text())
    assert s["units"]["system"] == "rotary" and s["units"]["speed"] == "r/min"


@needs_chromium
def test_linear_report_renders_its_linear_axis_titles_in_a_browser(
        linear: tuple[Path, str], rotary: tuple[Path, str], tmp_path: Path) -> None:
    """What the browser drew (plotly's SVG axis titles), not only what the file says."""
    def drawn_titles(run: Path) -> set[str]:
        dom = rendered_dom(run / "report.html")
        return set(re.findall(r'<text class="y\d*title"[^>]*>([^<]+)</text>', dom))

    lin = drawn_titles(linear[0])
    assert {"speed (m/s)", "force (N)", "position error (mm)"} <= lin, lin
    assert not any("r/min" in t or "N·m" in t for t in lin), lin
    rot = drawn_titles(rotary[0])
    assert {"speed (r/min)", "force (N·m rotary equiv.)"} <= rot, rot
    img = screenshot(linear[0] / "report.html", tmp_path / "lin.png")
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 200        # drawn, not blank


def test_console_verdict_lines_speak_the_motors_units(linear: tuple[Path, str]) -> None:
    _, out = linear
    lines = [ln for ln in out.splitlines() if ln.strip().startswith("[PASS]")]
    assert len(lines) == 2, out
    assert re.search(r"speed_estimate_error_max_mps@\S+: [0-9.e+-]+ m/s ", lines[0]), lines
    assert re.search(r"position_error_rms_mm@\S+: [0-9.e+-]+ mm ", lines[1]), lines
    assert "r/min" not in out and "N·m" not in out


def test_an_r_per_min_expectation_on_a_linear_motor_is_shown_in_m_per_s_too() -> None:
    from bench._report import value_text
    from bench._units import motor_units
    from protocols.units import rpm_to_mps

    u = motor_units("iron_core_linear")
    text = value_text(u, "speed_estimate_error_max_rpm", 12.5)
    assert text == f"12.5 r/min (= {rpm_to_mps(12.5, u.pole_pairs, u.pole_pitch_m):.5g} m/s)"
    assert value_text(u, "speed_estimate_error_max_mps", 0.01) == "0.01 m/s"
    assert value_text(motor_units("paper_salient"), "speed_estimate_error_max_rpm", 2.0) \
        == "2 r/min"


def test_summary_json_metrics_in_linear_units_equal_the_rotary_ones_converted(
        linear: tuple[Path, str]) -> None:
    from bench._units import motor_units
    from protocols.units import m_per_electrical_rad, rpm_to_mps
    from sim_fallback.metrics import metric_twin

    run, _ = linear
    s = json.loads((run / "summary.json").read_text())
    u = motor_units("iron_core_linear")
    assert s["units"]["system"] == "linear"
    assert (s["units"]["speed"], s["units"]["force"], s["units"]["position"]) == \
        ("m/s", "N", "mm")
    shown = s["metrics_in_motor_units"]
    assert "speed_tracking_error_max_mps" in shown and "position_error_rms_mm" in shown
    assert "speed_estimate_error_max_mps" in shown
    assert not any(k.endswith("_rpm") for k in shown)
    pairs = 0
    for k, v in s["metrics"].items():
        twin = metric_twin(k, "linear") if k.endswith("_rpm") else k[:-4] + "_mm"
        if v is None or twin not in s["metrics"] or twin == k:
            continue
        if k.endswith("_rpm"):
            want = rpm_to_mps(v, u.pole_pairs, u.pole_pitch_m)
        else:  # _rad -> _mm
            want = v * m_per_electrical_rad(u.pole_pitch_m) * 1e3
        assert s["metrics"][twin] == pytest.approx(want, rel=1e-12, abs=0), (k, twin)
        pairs += 1
    assert pairs >= 8


def test_every_r_per_min_metric_has_an_m_per_s_twin_within_1e_12() -> None:
    from protocols.units import rpm_to_mps
    from sim_fallback.metrics import METRIC_DEFS, METRIC_NAMES, compute_metrics, metric_twin

    rng = np.random.default_rng(35)
    t = np.arange(0, 1, 1 / 24000)
    d = {"t_s": t, "theta_e_rad": 30 * t, "theta_hat_rad": 30 * t + 0.02 * rng.standard_normal(
        t.size), "omega_e_radps": 30 + rng.standard_normal(t.size),
         "omega_hat_radps": 30 + rng.standard_normal(t.size),
         "omega_f_radps": 30 + 0.3 * rng.standard_normal(t.size),
         "speed_ref_radps_e": np.full(t.size, 30.0)}
    for tau, p in ((0.016, 1.0), (0.024, 4.0)):
        m = compute_metrics(d, tau, p, (0.1, 0.9))
        rpm = [k for k in METRIC_NAMES if METRIC_DEFS[k].unit.startswith("r/min")]
        assert len(rpm) == 5
        for k in rpm:
            twin = metric_twin(k, "linear")
            assert twin and METRIC_DEFS[twin].unit == "m/s", k
            assert math.isfinite(m[k])
            assert m[twin] == pytest.approx(rpm_to_mps(m[k], p, tau), rel=1e-12, abs=0), k
            assert metric_twin(twin, "rotary") == k


def test_statusword_is_plotted_as_cia402_state_names(linear: tuple[Path, str]) -> None:
    from bench._report import CIA402_STATES

    html = (linear[0] / "report.html").read_text(encoding="utf-8")
    fig = figures(html)["plot-pdo"]
    (sw,) = [tr for tr in fig["data"] if tr.get("name") == "statusword"]
    assert set(sw["y"]) <= set(CIA402_STATES) and "OPERATION ENABLED" in sw["y"]
    axis = fig["layout"]["yaxis" + sw["yaxis"][1:]]
    assert axis["type"] == "category" and axis["title"]["text"] == "statusword (CiA 402 state)"
    assert axis["categoryarray"] == [s for s in CIA402_STATES if s in axis["categoryarray"]]


def test_no_two_signals_of_a_figure_share_a_colour(linear: tuple[Path, str],
                                                   rotary: tuple[Path, str]) -> None:
    for run in (linear[0], rotary[0]):
        figs = figures((run / "report.html").read_text(encoding="utf-8"))
        assert "plot-internals" in figs
        for div, fig in figs.items():
            colour: dict[str, str] = {}
            for tr in fig["data"]:
                key = tr.get("legendgroup") or tr["name"]
                c = tr["line"]["color"]
                assert colour.setdefault(key, c) == c, (div, key)
            assert len(set(colour.values())) == len(colour), (div, colour)
        internals = [tr["name"] for tr in figs["plot-internals"]["data"]]
        assert len(internals) >= 4 and {"i_d", "i_q"} <= set(internals)
