"""The run report: one HTML file with interactive plots (plotly.js: the runs folder's one
copy, referenced relatively; works offline), units everywhere, labelled windows, the
expectations' doc text and the paper's citation; checked in a real browser when Chromium is
installed. The shared library, sizes and --standalone: test_report_assets.py."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from bench import open_sim, run_sequence, validate_sequence

SEQ = ("name: report_check\nmotor: paper_salient\nextractor: sogi_adaptive\nseed: 2\n"
       "steps:\n  - enable: {}\n  - set_speed: {value: 100, unit: r/min}\n"
       "  - wait: {duration_s: 0.3}\n"
       "  - expect: {metric: position_error_rms_rad, op: '<', limit: 0.5, paper: 0.01, "
       "window_s: [0.15, 0.3], doc: 'steady tracking after start-up'}\n"
       "  - expect: {metric: position_error_max_rad, op: '<', limit: 0.0001, "
       "window_s: [0.2, 0.3], doc: 'an impossible limit: this one fails'}\n"
       "  - disable: {}\n")


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    seq = validate_sequence(SEQ)
    c = open_sim(seed=seq.seed)
    try:
        out = run_sequence(seq, c, runs_root=str(tmp_path_factory.mktemp("runs")),
                           progress=False)
    finally:
        c.close()
    assert out.report is not None
    return Path(out.report)


def test_report_is_interactive_and_loads_only_the_runs_folders_plotly(report: Path) -> None:
    html = report.read_text(encoding="utf-8")
    assert "<img" not in html                           # no fixed images
    # nothing fetched from a network: the one script loaded is the runs folder's plotly.js
    srcs = re.findall(r"<script[^>]+src=\"([^\"]+)\"", html)
    assert len(srcs) == 1 and srcs[0].startswith("../plotly-")
    assert (report.parent / srcs[0]).is_file()
    assert html.count("Plotly.newPlot") >= 3            # overview, internals, PDOs (+ trace)
    assert len(html) < 1_000_000                        # plotly.js is not embedded
    assert not list(report.parent.glob("*.png"))


def test_report_tables_have_units_docs_citation_and_no_python_reprs(report: Path) -> None:
    html = report.read_text(encoding="utf-8")
    tables = html[:html.index("<h2>Plots</h2>")] + html[html.index("<h2>Metrics over"):]
    assert "<th>unit</th>" in tables and "rad (electrical)" in tables
    assert "steady tracking after start-up" in tables and "an impossible limit" in tables
    assert "Small &amp; Special Electrical Machines, 2024 (02)" in tables
    run_table = html[html.index("<h2>Run</h2>"):]
    assert "None" not in run_table and "{'" not in run_table and "{&#x27;" not in run_table
    assert "serial_telemetry: 0" in run_table or "can: 0" in run_table


def test_windows_are_labelled_and_the_time_axis_is_cut_to_the_enabled_drive(report: Path
                                                                            ) -> None:
    html = report.read_text(encoding="utf-8")
    # every expectation has its own labelled lane (no blended shading)
    assert "expectation window: pass" in html and "expectation window: FAIL" in html
    assert "position_error_rms_rad@[0.15,0.3]s" in html
    # x range of the overview = first/last OPERATION ENABLED statusword (not 0)
    m = re.search(r'"xaxis":\{[^}]*"range":\[([0-9.e+-]+),([0-9.e+-]+)\]', html)
    assert m is not None
    x0, x1 = float(m.group(1)), float(m.group(2))
    assert 0.0 < x0 < 0.05 and 0.25 < x1 < 0.35
    # the position-error axis is scaled to the errors under test, not to +-pi
    ranges = [tuple(map(float, r)) for r in
              re.findall(r'"range":\[(-[0-9.e+-]+),([0-9.e+-]+)\]', html)]
    assert any(-0.5 < a < 0 and 0 < b < 0.5 and abs(a + b) < 1e-9 for a, b in ranges)


def _chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser") or \
        shutil.which("google-chrome")


@pytest.mark.skipif(_chromium() is None, reason="Chromium not installed (apt-get install "
                                                 "chromium) - the browser check needs it")
def test_report_renders_plots_with_data_in_a_real_browser(report: Path, tmp_path: Path
                                                          ) -> None:
    from PIL import Image

    shot = tmp_path / "report.png"
    subprocess.run([_chromium(), "--headless", "--disable-gpu", "--no-sandbox",
                    "--hide-scrollbars", f"--screenshot={shot}", "--window-size=1300,2600",
                    "--virtual-time-budget=8000", report.as_uri()],
                   check=True, timeout=120, capture_output=True)
    img = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    plots = img  # the tables use other colours (#070 / #b00 text)

    def count(rgb: tuple[int, int, int], tol: int = 30) -> int:
        return int(np.sum(np.all(np.abs(plots - np.array(rgb)) <= tol, axis=-1)))

    # the pass (green) and fail (red) lane bars and traces were drawn by plotly.js
    assert count((44, 160, 44)) > 500, "no green pass-window bar rendered"
    assert count((214, 39, 40)) > 500, "no red fail-window bar / error trace rendered"
    assert len(np.unique(plots.reshape(-1, 3), axis=0)) > 200  # not a blank page


def test_decimation_keeps_a_single_sample_spike() -> None:
    """Plots are decimated to a few thousand points by min/max envelope: a one-sample
    spike (a glitch a user must see) survives, plain striding would drop it."""
    from bench._report import _decimate

    t = np.arange(100_000) / 24000.0
    v = np.sin(t)
    v[31_337] = 5.0
    a, b = _decimate(t, v, 4000)
    assert a.size <= 4100 and np.all(np.diff(a) >= 0)
    assert b.max() == 5.0 and a[np.argmax(b)] == t[31_337]


def _fake_run(root: Path, name: str, seq: str, passed: bool, rms: float,
              with_plot: bool = True) -> None:
    import json

    d = root / name
    d.mkdir(parents=True)
    (d / "summary.json").write_text(json.dumps({
        "sequence": seq, "passed": passed, "aborted": False, "error": None,
        "drive": "SIMULATED", "simulated": True,
        "metrics": {"position_error_rms_rad": rms, "settling_time_s": None},
        "expectations": [{"name": "e1", "passed": passed, "paper_reproduced": False}]}))
    (d / "meta.json").write_text(json.dumps({
        "created_utc": "2026-01-02T03:04:05+00:00",
        "sequence": {"motor": "paper_salient", "extractor": "sogi", "seed": 3}}))
    (d / "report.html").write_text("<html></html>")
    if with_plot:
        (d / "compare.js").write_text(
            "window.BENCH_RUNS = window.BENCH_RUNS || {};\n"
            f"window.BENCH_RUNS[{json.dumps(name)}] = " + json.dumps(
                {"sequence": seq, "enabled_s": [0, 1], "series": {
                    "position error (rad el.)": {"t": [0, 0.5, 1], "y": [0, rms * 5, 0]},
                    "estimated speed (r/min)": {"t": [0, 1], "y": [0, 100]},
                    "true speed (r/min)": {"t": [0, 1], "y": [0, 100]}}}) + ";\n")


def test_runs_index_lists_every_run_with_verdict_metrics_and_units(tmp_path: Path) -> None:
    from bench._report import write_index

    _fake_run(tmp_path, "20260102T030405_000001Z_alpha", "alpha", True, 0.0123456)
    _fake_run(tmp_path, "20260102T030406_000001Z_beta", "beta", False, 0.0456, False)
    (tmp_path / "20260102T030407_000001Z_broken").mkdir()
    (tmp_path / "20260102T030407_000001Z_broken" / "summary.json").write_text("{not json")
    out = write_index(tmp_path)
    html = out.read_text(encoding="utf-8")
    body = html[html.index("<body>"):]
    assert body.count("class='pick'") == 2               # the broken folder is skipped
    assert body.index("beta") < body.index("alpha")       # newest first
    assert "PASSED" in body and "FAILED" in body and "SIMULATED" in body
    assert "0.012346" in body and "rad (electrical)" in body
    assert "href='20260102T030405_000001Z_alpha/report.html'" in body
    table = body[:body.index("<script>")]
    assert "None" not in table and "{'" not in table and "nan" not in table.lower()
    # offline: the one script loaded is the runs folder's plotly.js, beside the index
    srcs = re.findall(r"<script[^>]+src=\"([^\"]+)\"", html)
    assert len(srcs) == 1 and srcs[0].startswith("plotly-")
    assert (tmp_path / srcs[0]).is_file()


def test_bench_report_index_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from bench.cli import main

    assert main(["report", "index", "--runs", str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no such folder" in err and "Traceback" not in err
    _fake_run(tmp_path, "20260102T030405_000001Z_alpha", "alpha", True, 0.01)
    assert main(["report", "index", "--runs", str(tmp_path)]) == 0
    assert "(1 run(s))" in capsys.readouterr().out and (tmp_path / "index.html").is_file()


def test_python_can_mf4_still_works_after_bench_deferred_asammdf(tmp_path: Path) -> None:
    """bench keeps python-can from importing asammdf (0.9 s) at start-up; the first real
    asammdf import gives python-can its MF4 writer back."""
    import os
    import sys

    code = ("import sys, bench.cli, bench._session, can\n"
            "assert 'asammdf' not in sys.modules, 'asammdf imported at start-up'\n"
            "import asammdf, can.io.mf4 as m\n"
            "assert m.asammdf is asammdf\n"
            f"w = can.Logger({str(tmp_path / 'x.mf4')!r})\n"
            "w.on_message_received(can.Message(arbitration_id=0x181, data=[1, 2, 3]))\n"
            "w.stop()\n"
            f"print(len(list(can.LogReader({str(tmp_path / 'x.mf4')!r}))))\n")
    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(root)] + [p for p in [os.environ.get("PYTHONPATH")] if p])}
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       env=env, timeout=120)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "1"


@pytest.mark.skipif(_chromium() is None, reason="Chromium not installed (apt-get install "
                                                 "chromium) - the browser check needs it")
def test_runs_index_comparison_overlays_runs_in_a_real_browser(tmp_path: Path) -> None:
    from PIL import Image

    from bench._report import write_index

    a, b = "20260102T030405_000001Z_alpha", "20260102T030406_000001Z_beta"
    _fake_run(tmp_path, a, "alpha", True, 0.01)
    _fake_run(tmp_path, b, "beta", False, 0.03)
    out = write_index(tmp_path)
    shot = tmp_path / "index.png"
    subprocess.run([_chromium(), "--headless", "--disable-gpu", "--no-sandbox",
                    "--hide-scrollbars", f"--screenshot={shot}", "--window-size=1300,1800",
                    "--virtual-time-budget=8000", out.as_uri() + f"?compare={a},{b}"],
                   check=True, timeout=120, capture_output=True)
    img = np.asarray(Image.open(shot).convert("RGB")).astype(int)

    def count(rgb: tuple[int, int, int], tol: int = 30) -> int:
        return int(np.sum(np.all(np.abs(img - np.array(rgb)) <= tol, axis=-1)))

    # both runs' lines drawn by plotly.js (default colours: blue, then orange)
    assert count((31, 119, 180)) > 300, "first run's line not drawn"
    assert count((255, 127, 14)) > 300, "second run's line not drawn"
