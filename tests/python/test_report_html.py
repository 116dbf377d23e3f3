"""The run report: one self-contained HTML file with interactive plots (plotly.js
embedded, works offline), units everywhere, labelled windows, the expectations' doc text
and the paper's citation; checked in a real browser when Chromium is installed."""

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


def test_report_is_self_contained_and_interactive(report: Path) -> None:
    html = report.read_text(encoding="utf-8")
    assert "<img" not in html                           # no fixed images
    assert not re.search(r"<script[^>]+src=", html)     # nothing fetched: works offline
    assert html.count("Plotly.newPlot") >= 3            # overview, internals, PDOs (+ trace)
    assert len(html) > 3_000_000                        # plotly.js is embedded
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
