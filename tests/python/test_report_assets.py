"""Light reports (issue 35): one plotly.js per runs folder, referenced relatively by every
report and the runs index; a report of a 1 s run and an index of a few runs under 1 MB; the
index sized to its content at a narrow and a wide window; ``bench report --standalone``
one file with the library embedded; a report copied without the library says so. Checked
in headless Chromium with every network request refused."""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main

ROOT = Path(__file__).resolve().parents[2]
MB = 1_000_000


def chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser") or \
        shutil.which("google-chrome")


needs_chromium = pytest.mark.skipif(chromium() is None, reason="Chromium not installed "
                                    "(apt-get install chromium) - the browser check needs it")

#: no network: every request goes to a closed local port, no name resolves
_OFFLINE = ("--proxy-server=http://127.0.0.1:9", "--proxy-bypass-list=<-loopback>",
            "--host-resolver-rules=MAP * ~NOTFOUND", "--disable-background-networking")


def _browser(args: list[str], url: str, width: int, height: int) -> str:
    r = subprocess.run([chromium(), "--headless", "--disable-gpu", "--no-sandbox",
                        "--hide-scrollbars", *_OFFLINE, f"--window-size={width},{height}",
                        "--virtual-time-budget=8000", *args, url],
                       check=True, timeout=120, capture_output=True, text=True)
    return r.stdout


def screenshot(page: Path, out: Path, width: int = 1300, height: int = 2600,
               query: str = "") -> np.ndarray:
    """RGB pixels of ``page`` rendered by headless Chromium, offline."""
    from PIL import Image

    _browser([f"--screenshot={out}"], page.as_uri() + query, width, height)
    return np.asarray(Image.open(out).convert("RGB")).astype(int)


def rendered_dom(page: Path, width: int = 1300, height: int = 2600) -> str:
    """The DOM of ``page`` after its scripts ran (plotly's SVG included), offline."""
    return _browser(["--dump-dom"], page.as_uri(), width, height)


def count(img: np.ndarray, rgb: tuple[int, int, int], tol: int = 30) -> int:
    return int(np.sum(np.all(np.abs(img - np.array(rgb)) <= tol, axis=-1)))


def script_srcs(html: str) -> list[str]:
    return re.findall(r"<script[^>]*\bsrc=[\"']([^\"']+)[\"']", html)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A runs folder with a 1 s run (the paper's load step, 1.0 s of sequence) and two
    copies of it under other names: a few runs for the index."""
    root = tmp_path_factory.mktemp("light") / "runs"
    assert main(["run", str(ROOT / "sequences" / "paper_load_step.yaml"), "--sim",
                 "--runs", str(root), "--no-progress"]) == 0
    (run,) = [d for d in root.iterdir() if d.is_dir()]
    for k in (1, 2):
        shutil.copytree(run, root / run.name.replace("Z_", f"{k}Z_", 1))
    main(["report", "index", "--runs", str(root)])
    return root


def _runs(root: Path) -> list[Path]:
    return sorted(d for d in root.iterdir() if (d / "summary.json").is_file())


def test_one_plotly_per_runs_folder_referenced_relatively(runs: Path) -> None:
    from plotly.offline import get_plotlyjs, get_plotlyjs_version

    asset = runs / f"plotly-{get_plotlyjs_version()}.min.js"
    assert [p.name for p in runs.glob("*.js")] == [asset.name]
    from bench._results import store_path

    store = store_path(runs).name  # the results store (and SQLite's -wal, -shm) beside
    assert all(d.is_dir() for d in runs.iterdir() if d != asset and d.suffix != ".html"
               and not d.name.startswith(store))
    assert asset.read_bytes() == get_plotlyjs().encode("utf-8")
    for page in [d / "report.html" for d in _runs(runs)] + [runs / "index.html"]:
        html = page.read_text(encoding="utf-8")
        srcs = script_srcs(html)
        assert len(srcs) == 1 and "://" not in srcs[0] and not srcs[0].startswith("/")
        assert (page.parent / srcs[0]).resolve() == asset.resolve()   # the link resolves
        assert "Plotly.newPlot" in html and "var Plotly" not in html  # not embedded


def test_the_library_is_written_once_and_repaired_by_its_hash(runs: Path) -> None:
    from bench._report import write_index, write_plotly_asset

    (asset,) = runs.glob("plotly-*.min.js")
    before = asset.stat().st_mtime_ns, asset.stat().st_ino
    write_index(runs)
    assert (asset.stat().st_mtime_ns, asset.stat().st_ino) == before  # not written again
    good = hashlib.sha256(asset.read_bytes()).hexdigest()
    asset.write_bytes(asset.read_bytes()[:1000])                     # a broken copy
    assert write_plotly_asset(runs) == asset
    assert hashlib.sha256(asset.read_bytes()).hexdigest() == good
    assert not list(runs.glob("*.tmp"))


def test_sizes_report_of_a_1_s_run_and_index_under_1_mb(runs: Path) -> None:
    run = _runs(runs)[0]
    report = (run / "report.html").stat().st_size
    index = (runs / "index.html").stat().st_size
    print(f"report of a 1 s run: {report / MB:.3f} MB, index of {len(_runs(runs))} runs: "
          f"{index / MB:.3f} MB")
    assert report < 1 * MB
    assert index < 1 * MB and len(_runs(runs)) == 3


def test_standalone_is_one_file_with_the_library(runs: Path, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    from plotly.offline import get_plotlyjs

    run = _runs(runs)[0]
    assert main(["report", "--standalone", str(run)]) == 0
    out = run / "report_standalone.html"
    assert str(out) in capsys.readouterr().out
    html = out.read_text(encoding="utf-8")
    assert script_srcs(html) == []                   # nothing referenced: works alone
    assert get_plotlyjs()[:2000] in html and len(html) > 3 * MB
    assert "Standalone copy: plotly.js" in html and "embedded in this file" in html
    assert "loaded from" not in html                 # the shared-library footer is gone
    # --out, and one-line mistakes naming the option
    assert main(["report", "--standalone", str(run), "--out", str(tmp_path / "x.html")]) == 0
    assert (tmp_path / "x.html").read_text(encoding="utf-8") == html
    capsys.readouterr()
    for argv, word in ((["report", "--standalone", str(tmp_path / "nope")], "--standalone"),
                       (["report", "--standalone", str(runs)], "no report.html"),
                       (["report", "--standalone", str(run), "--out",
                         str(tmp_path / "no" / "x.html")], "--out"),
                       (["report"], "--standalone RUN_DIR"),
                       (["report", "--standalone", str(run), "index"], "give one")):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and word in err and "Traceback" not in err, err


@needs_chromium
def test_report_and_index_draw_their_plots_offline(runs: Path, tmp_path: Path) -> None:
    run = _runs(runs)[0]
    img = screenshot(run / "report.html", tmp_path / "report.png")
    assert count(img, (44, 160, 44)) > 500, "no green pass-window bar drawn"
    assert count(img, (31, 119, 180)) > 300, "no blue signal line drawn"
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 200          # not a blank page
    dom = rendered_dom(run / "report.html")
    assert dom.count('class="main-svg"') >= 3                        # plotly drew the figures
    assert 'id="plotly-missing"' not in dom                          # the library loaded
    a, b = _runs(runs)[:2]
    img = screenshot(runs / "index.html", tmp_path / "index.png", 1300, 1800,
                     f"?compare={a.name},{b.name}")
    assert count(img, (31, 119, 180)) > 300, "first run's line not drawn"
    assert count(img, (255, 127, 14)) > 300, "second run's line not drawn"


@needs_chromium
def test_standalone_copy_alone_draws_and_a_bare_copy_says_what_is_missing(
        runs: Path, tmp_path: Path) -> None:
    run = _runs(runs)[0]
    main(["report", "--standalone", str(run)])
    alone = tmp_path / "elsewhere"
    alone.mkdir()
    shutil.copy(run / "report_standalone.html", alone / "r.html")
    shutil.copy(run / "report.html", alone / "bare.html")           # without the library
    img = screenshot(alone / "r.html", tmp_path / "r.png")
    assert count(img, (44, 160, 44)) > 500 and count(img, (31, 119, 180)) > 300
    dom = rendered_dom(alone / "bare.html")
    assert 'id="plotly-missing"' in dom and 'class="main-svg"' not in dom
    notice = re.search(r'<p id="plotly-missing"[^>]*>(.*?)</p>', dom, re.S).group(1)
    assert "plotly.js is missing" in notice and "bench report --standalone" in notice
    img = screenshot(alone / "bare.html", tmp_path / "bare.png", 1300, 600)
    assert count(img, (187, 0, 0), tol=20) > 200                    # the notice's red frame
    assert "expectation" in dom and "PASSED" in dom                  # the tables are there
    # and where the library is, no notice
    assert 'id="plotly-missing"' not in rendered_dom(run / "report.html")


_PROBE = ("<script>window.addEventListener('load', function () {"
          "var t = document.getElementById('runs').getBoundingClientRect();"
          "document.body.setAttribute('data-probe', JSON.stringify({"
          "sw: document.documentElement.scrollWidth, vw: window.innerWidth,"
          "right: t.right}));});</script></body>")


@needs_chromium
@pytest.mark.parametrize("width", [1000, 1920])
def test_index_is_sized_to_its_content_at_a_narrow_and_a_wide_window(
        runs: Path, tmp_path: Path, width: int) -> None:
    probe = runs / f"probe_{width}.html"
    probe.write_text((runs / "index.html").read_text(encoding="utf-8")
                     .replace("</body>", _PROBE), encoding="utf-8")
    try:
        dom = rendered_dom(probe, width, 800)
        img = screenshot(probe, tmp_path / "index.png", width, 800)
    finally:
        probe.unlink()
    m = re.search(r"data-probe=\"([^\"]+)\"", dom)
    assert m, "the probe did not run"
    got = json.loads(m.group(1).replace("&quot;", '"'))
    assert got["sw"] <= got["vw"], f"page wider than the window: {got}"
    assert got["right"] <= got["vw"], f"the table is clipped: {got}"
    # the last column (the run folder links, blue) is on the screenshot
    links = np.all(np.abs(img - np.array([0, 0, 238])) <= 40, axis=-1)
    assert links.sum() > 100 and np.nonzero(links.any(axis=0))[0].max() < width
