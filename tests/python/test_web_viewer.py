"""rerun's web viewer in a real browser (tools/check_web_viewer.py): ``bench live --sim
--rerun serve`` streams, headless Chromium opens the URL the bench printed, and the
screenshot must show plots with data; the same for a saved recording opened with the
command the bench printed. Skipped without Chromium or the simulator."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tools"))

from check_web_viewer import find_chromium, plot_pixels  # noqa: E402
from sim_libs import needs_sim  # noqa: E402


@pytest.mark.skipif(find_chromium() is None,
                    reason="no Chromium (apt-get install chromium, or set CHROMIUM=PATH)")
@needs_sim
def test_web_viewer_shows_plots_with_data(tmp_path: Path) -> None:
    png = tmp_path / "web_viewer.png"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "check_web_viewer.py"), "--out",
                        str(png), "--wait", "20", "--duration", "30"], capture_output=True,
                       text=True, cwd=tmp_path, env=env, timeout=240)
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 0, r.stdout + r.stderr
    assert "bench printed: http://127.0.0.1:" in r.stdout
    n, cols, rows = plot_pixels(png)  # the tool's verdict, checked on the file itself
    assert n >= 2000 and cols >= 0.5 and rows >= 0.25, (n, cols, rows)


@pytest.mark.skipif(find_chromium() is None,
                    reason="no Chromium (apt-get install chromium, or set CHROMIUM=PATH)")
@needs_sim
def test_saved_recording_opened_with_the_printed_command_shows_plots(tmp_path: Path) -> None:
    """``bench live --rerun save X.rrd`` keeps the views in ``X.rbl`` beside the .rrd: the
    command the bench printed (``rerun X.rrd X.rbl``) must give the plots with data."""
    png = tmp_path / "recording.png"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "check_web_viewer.py"),
                        "--recording", "--out", str(png), "--wait", "15", "--duration", "6"],
                       capture_output=True, text=True, cwd=tmp_path, env=env, timeout=240)
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 0, r.stdout + r.stderr
    assert "bench printed: rerun " in r.stdout and ".rbl" in r.stdout, r.stdout
    n, cols, rows = plot_pixels(png)
    assert n >= 2000 and cols >= 0.5 and rows >= 0.25, (n, cols, rows)


def test_blank_screenshot_is_not_plots(tmp_path: Path) -> None:
    """The image check itself: a grey viewer-like image with a small blue box (rerun's
    welcome screen has one) must not pass as plots."""
    import numpy as np
    from matplotlib.image import imsave

    img = np.full((900, 1400, 3), 0.07)
    img[60:85, 10:190] = (0.13, 0.43, 0.9)  # a selection box: saturated but local
    imsave(tmp_path / "x.png", img)
    n, cols, rows = plot_pixels(tmp_path / "x.png")
    assert n == 25 * 180 and cols < 0.5 and rows < 0.25
    img[300:302, :, :] = (0.26, 0.65, 0.96)  # a line across the width: not yet enough rows
    imsave(tmp_path / "y.png", img)
    _, cols, rows = plot_pixels(tmp_path / "y.png")
    assert cols == 1.0 and rows < 0.25
