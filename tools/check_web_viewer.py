#!/usr/bin/env python3
"""Check rerun's web viewer in a real browser: ``bench live --sim --rerun serve`` streams
live telemetry, headless Chromium opens the exact URL the bench printed, waits and saves a
screenshot (PNG), which is then checked for plotted data.

Usage::

    PYTHONPATH=. python tools/check_web_viewer.py [--out web_viewer.png] [--wait 20]
        [--duration 40] [--grpc-port PORT] [--web-port PORT] [--chromium PATH]
    PYTHONPATH=. python tools/check_web_viewer.py --recording [--duration 10] ...

``--recording`` checks a saved recording instead of the live stream: ``bench live --sim
--duration D --rerun save X.rrd`` runs to its end, then the command it printed to open the
recording (``rerun X.rrd X.rbl``: the .rrd and the blueprint beside it) is run as a web
viewer server (``--serve-web --bind 127.0.0.1`` added) and opened in the browser.

Exit 0 when the screenshot shows plots with data, 1 when it does not, 2 for bad options,
busy ports, a bench that did not start or no Chromium found (``apt-get install
chromium``; or ``--chromium PATH``, or ``CHROMIUM``). CI can run it wherever Chromium is
installed (``tests/python/test_web_viewer.py`` does, and skips without Chromium).

How: Chromium is driven over the DevTools protocol on a pipe (``--remote-debugging-pipe``:
no extra Python packages, no open debugging port). ``--screenshot`` alone is not enough:
it fires when the page has loaded, before the viewer's WebAssembly has started and the
data has streamed in. WebGL runs on SwiftShader (software), so no GPU is needed.

The check on the image: the viewer's plot lines are saturated colours, the UI itself is
grey. Below the top bar (which has an orange "Software rasterizer" note), the screenshot
passes when at least ``--min-pixels`` (default 2000) pixels are saturated (HSV saturation
> 0.5, value > 0.35) AND they spread over at least half of the columns and a quarter of
the rows (lines across several plots). Measured: the loading screen 0 pixels; rerun's
welcome screen (viewer up, no data) 3,706 pixels but 13 % of the columns and 3 % of the
rows (a blue selection box); the live plots 7,000-16,000 pixels, 97-99 % of the columns,
63-64 % of the rows.
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

try:  # first: one line, not a traceback, outside the venv (not when loaded as a module)
    import _project_env  # noqa: F401
except ModuleNotFoundError:
    pass

ROOT = Path(__file__).resolve().parents[1]
URL_RE = re.compile(r"web viewer: (http://127\.0\.0\.1:\d+/\?url=\S+)")


def find_chromium(explicit: str | None = None) -> str | None:
    """The Chromium binary: ``explicit``, ``$CHROMIUM``, else the usual names on PATH."""
    for c in (explicit, os.environ.get("CHROMIUM"), "chromium", "chromium-browser",
              "google-chrome", "google-chrome-stable", "chrome"):
        if c and (p := shutil.which(c)):
            return p
    return None


class Browser:
    """Headless Chromium, DevTools protocol over fds 3/4 (``--remote-debugging-pipe``)."""

    def __init__(self, exe: str, width: int = 1400, height: int = 900) -> None:
        import fcntl

        self.profile = tempfile.mkdtemp(prefix="bench-chromium-")
        to_chrome_r, self._w = os.pipe()
        self._r, from_chrome_w = os.pipe()
        # the child's fds 3 and 4 must be these pipes: copy them out of the way first
        a = fcntl.fcntl(to_chrome_r, fcntl.F_DUPFD, 10)
        b = fcntl.fcntl(from_chrome_w, fcntl.F_DUPFD, 10)
        os.close(to_chrome_r)
        os.close(from_chrome_w)

        def child_fds() -> None:
            os.dup2(a, 3)
            os.dup2(b, 4)

        self.proc = subprocess.Popen(
            [exe, "--headless", "--no-sandbox", "--remote-debugging-pipe", "--no-first-run",
             "--no-default-browser-check", "--disable-extensions", "--mute-audio",
             "--enable-unsafe-swiftshader", "--use-angle=swiftshader",
             f"--window-size={width},{height}", f"--user-data-dir={self.profile}",
             "about:blank"],
            pass_fds=(3, 4), preexec_fn=child_fds, stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(a)
        os.close(b)
        self._buf = b""
        self._id = 0
        self.width, self.height = width, height

    def call(self, method: str, params: dict[str, Any] | None = None,
             session: str | None = None, timeout_s: float = 30.0) -> dict[str, Any]:
        self._id += 1
        msg: dict[str, Any] = {"id": self._id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self._w, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + timeout_s
        while True:
            while b"\0" in self._buf:
                raw, self._buf = self._buf.split(b"\0", 1)
                reply = json.loads(raw)
                if reply.get("id") == self._id:
                    if "error" in reply:
                        raise RuntimeError(f"{method}: {reply['error']}")
                    return reply.get("result", {})
            if time.monotonic() > deadline:
                raise TimeoutError(f"{method}: no answer from Chromium in {timeout_s} s")
            import select

            ready, _, _ = select.select([self._r], [], [], 0.5)
            if ready:
                chunk = os.read(self._r, 1 << 20)
                if not chunk:
                    raise RuntimeError("Chromium closed the DevTools pipe")
                self._buf += chunk

    def screenshot(self, url: str, wait_s: float, out: Path) -> None:
        target = self.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        sess = self.call("Target.attachToTarget", {"targetId": target,
                                                   "flatten": True})["sessionId"]
        self.call("Emulation.setDeviceMetricsOverride", {
            "width": self.width, "height": self.height, "deviceScaleFactor": 1,
            "mobile": False}, session=sess)
        self.call("Page.navigate", {"url": url}, session=sess)
        time.sleep(wait_s)  # the viewer's wasm starts, connects and the data streams in
        png = self.call("Page.captureScreenshot", {"format": "png"}, session=sess,
                        timeout_s=60.0)["data"]
        out.write_bytes(base64.b64decode(png))

    def close(self) -> None:
        try:
            self.call("Browser.close", timeout_s=5.0)
        except Exception:  # noqa: BLE001 - terminated below anyway
            pass
        try:
            self.proc.wait(5.0)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5.0)
        for fd in (self._r, self._w):
            try:
                os.close(fd)
            except OSError:
                pass
        shutil.rmtree(self.profile, ignore_errors=True)


def plot_pixels(png: Path) -> tuple[int, float, float]:
    """Saturated-colour pixels below the viewer's top bar (the plot lines): their number
    and the fractions of the columns and of the rows that hold any."""
    import numpy as np
    from matplotlib.image import imread

    img = imread(str(png))[..., :3].astype(np.float64)
    if img.max() > 1.0:
        img /= 255.0
    img = img[40:]  # the top bar (menus, logo) is not plot area
    mx, mn = img.max(axis=2), img.min(axis=2)
    sat = np.where(mx > 0, (mx - mn) / np.maximum(mx, 1e-9), 0.0)
    m = (sat > 0.5) & (mx > 0.35)
    return (int(np.count_nonzero(m)), float(m.any(axis=0).mean()),
            float(m.any(axis=1).mean()))


def free_port(avoid: int = 0) -> int:
    """A TCP port free on 127.0.0.1 now."""
    import socket

    while True:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = int(s.getsockname()[1])
        if port != avoid:
            return port


def start_bench(duration_s: float, grpc_port: int, web_port: int, cwd: Path
                ) -> tuple[subprocess.Popen[str], str, list[str]]:
    """``bench live --sim --rerun serve``; returns it, the web viewer URL it printed and
    its stderr lines so far."""
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get(
        "PYTHONPATH", "")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "bench.cli", "live", "--sim", "--duration", str(duration_s),
         "--rerun", "serve", str(grpc_port), str(web_port)],
        cwd=cwd, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    deadline = time.monotonic() + 60.0
    assert proc.stderr is not None
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            break
        lines.append(line.rstrip())
        if m := URL_RE.search(line):
            return proc, m.group(1), lines
    proc.kill()
    proc.wait()
    raise RuntimeError("bench live printed no web viewer URL; its stderr: " +
                       " | ".join(lines[-3:]))


VIEW_RE = re.compile(r"; view: (rerun .+)$", re.M)


def serve_recording(duration_s: float, grpc_port: int, web_port: int, cwd: Path
                    ) -> tuple[subprocess.Popen[str], str, list[str]]:
    """``bench live --sim --rerun save X.rrd`` to its end, then the viewer command it
    printed, served to the web viewer on 127.0.0.1; returns the server, the URL and the
    bench's stderr lines."""
    import shlex

    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    from bench import rerun_exe, wait_port, web_viewer_url

    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get(
        "PYTHONPATH", "")}
    for v in ("DISPLAY", "WAYLAND_DISPLAY"):
        env.pop(v, None)
    r = subprocess.run([sys.executable, "-m", "bench.cli", "live", "--sim", "--duration",
                        str(duration_s), "--rerun", "save", str(cwd / "x.rrd")], cwd=cwd,
                       env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True,
                       timeout=duration_s + 120)
    lines = r.stderr.splitlines()
    m = VIEW_RE.search(r.stderr)
    if r.returncode != 0 or m is None:
        raise RuntimeError(f"bench live (exit {r.returncode}) printed no viewer command; "
                           "its stderr: " + " | ".join(lines[-3:]))
    argv = shlex.split(m.group(1))
    lines.append(f"bench printed: {m.group(1)}")
    proc = subprocess.Popen([rerun_exe(), "--serve-web", "--bind", "127.0.0.1", "--port",
                             str(grpc_port), "--web-viewer-port", str(web_port), *argv[1:]],
                            cwd=cwd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, text=True)
    wait_port(grpc_port, proc, "server")
    wait_port(web_port, proc, "server")
    return proc, web_viewer_url(f"rerun+http://127.0.0.1:{grpc_port}/proxy", web_port), lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="web_viewer.png", help="screenshot (PNG)")
    ap.add_argument("--wait", type=float, default=20.0,
                    help="seconds between opening the URL and the screenshot (default 20)")
    ap.add_argument("--duration", type=float, default=40.0,
                    help="bench live --duration (s of drive time; default 40)")
    ap.add_argument("--grpc-port", type=int, default=0,
                    help="bench live --rerun serve GRPC_PORT (default: a free port)")
    ap.add_argument("--web-port", type=int, default=0,
                    help="bench live --rerun serve ... WEB_PORT (default: a free port)")
    ap.add_argument("--min-pixels", type=int, default=2000,
                    help="saturated plot pixels needed to pass (default 2000)")
    ap.add_argument("--chromium", help="Chromium binary (default: $CHROMIUM, else PATH)")
    ap.add_argument("--recording", action="store_true",
                    help="check a saved recording opened with the command the bench printed "
                         "(bench live --rerun save) instead of the live stream")
    args = ap.parse_args(argv)
    for name, v, lo, hi in (("--wait", args.wait, 1.0, 600.0),
                            ("--duration", args.duration, 5.0, 3600.0)):
        if not lo <= v <= hi:
            print(f"check_web_viewer: {name} {v}: allowed range [{lo:g}, {hi:g}] s",
                  file=sys.stderr)
            return 2
    if args.duration < args.wait + 5.0 and not args.recording:
        print(f"check_web_viewer: --duration {args.duration}: allowed range >= --wait + 5 "
              f"s ({args.wait + 5:g} s): the drive must still stream at the screenshot",
              file=sys.stderr)
        return 2
    for name, port in (("--grpc-port", args.grpc_port), ("--web-port", args.web_port)):
        if not 0 <= port <= 65535:
            print(f"check_web_viewer: {name} {port}: allowed range [1, 65535] (0: a free "
                  "port)", file=sys.stderr)
            return 2
    grpc_port = args.grpc_port or free_port()
    web_port = args.web_port or free_port(avoid=grpc_port)
    exe = find_chromium(args.chromium)
    if exe is None:
        print("check_web_viewer: no Chromium found (apt-get install chromium, or --chromium "
              "PATH / CHROMIUM=PATH)", file=sys.stderr)
        return 2
    out = Path(args.out).resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="bench-webcheck-") as tmp:
        try:
            if args.recording:
                bench, url, lines = serve_recording(args.duration, grpc_port, web_port,
                                                    Path(tmp))
                print(lines[-1])
            else:
                bench, url, lines = start_bench(args.duration, grpc_port, web_port,
                                                Path(tmp))
                print(f"bench printed: {url}")
        except RuntimeError as e:
            print(f"check_web_viewer: {' '.join(str(e).split())}", file=sys.stderr)
            return 2
        browser = None
        try:
            browser = Browser(exe)
            t0 = time.monotonic()
            browser.screenshot(url, args.wait, out)
            print(f"screenshot after {time.monotonic() - t0:.1f} s: {out}")
        finally:
            if browser is not None:
                browser.close()
            # Ctrl-C: the drive is disabled, .rrd saved (--recording: the viewer server ends)
            bench.send_signal(signal.SIGTERM if args.recording else signal.SIGINT)
            try:
                _, err = bench.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                bench.kill()
                _, err = bench.communicate()
            lines += (err or "").splitlines()
        summary = next((ln for ln in lines if "batches" in ln), "")
        if summary:
            print(summary)
    n, cols, rows = plot_pixels(out)
    ok = n >= args.min_pixels and cols >= 0.5 and rows >= 0.25
    print(f"plot pixels (saturated colour): {n} (need >= {args.min_pixels}) over "
          f"{cols:.0%} of the columns (need >= 50 %) and {rows:.0%} of the rows (need >= "
          f"25 %): {'PLOTS WITH DATA' if ok else 'NO PLOTTED DATA'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
