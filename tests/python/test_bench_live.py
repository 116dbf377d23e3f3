"""Live telemetry from the wire to rerun (bench/_live.py, bench live, bench run --rerun).

The references are computed here, independently of the feed: decimation is "the first
sample of each 1/rate interval" (np.unique on the interval index), angles are wrapped with
np.angle(exp(j x)), r/min from electrical rad/s and from m/s with the motor's pole pairs
and equivalent radius; a step signal must reproduce every raw sample by sample-and-hold.
The .rrd files are read back with rerun's own reader (bench._live.read_rrd).
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from sim_libs import needs_sim

from bench._live import (
    DEFAULT_GRPC_PORT,
    DEFAULT_WEB_PORT,
    LiveFeed,
    RerunSink,
    RerunSpec,
    RerunSpecError,
    parse_rerun_spec,
    read_rrd,
    web_viewer_url,
)

ROOT = Path(__file__).resolve().parents[2]
TWO_PI = 2.0 * np.pi


# ---- --rerun forms ----------------------------------------------------------------------


@pytest.mark.parametrize("tokens, want, rest", [
    (["spawn", "a.yaml"], {"mode": "spawn", "path": None}, ["a.yaml"]),
    (["save"], {"mode": "save", "path": None}, []),
    (["save", "out/x.rrd", "a.yaml"], {"mode": "save", "path": Path("out/x.rrd")},
     ["a.yaml"]),
    (["save", "a.yaml", "b.yml"], {"mode": "save", "path": None}, ["a.yaml", "b.yml"]),
    (["serve"], {"mode": "serve", "grpc_port": DEFAULT_GRPC_PORT,
                 "web_port": DEFAULT_WEB_PORT}, []),
    (["serve", "9100", "9101", "a.yaml"], {"mode": "serve", "grpc_port": 9100,
                                           "web_port": 9101}, ["a.yaml"]),
    (["connect"], {"mode": "connect", "url": "rerun+http://127.0.0.1:9876/proxy"}, []),
    (["connect", "9200"], {"mode": "connect", "url": "rerun+http://127.0.0.1:9200/proxy"},
     []),
    (["connect", "rerun+http://10.0.0.2:9876/proxy", "a.yaml"],
     {"mode": "connect", "url": "rerun+http://10.0.0.2:9876/proxy"}, ["a.yaml"]),
])
def test_parse_rerun_spec_forms(tokens: list[str], want: dict[str, Any],
                                rest: list[str]) -> None:
    spec, left = parse_rerun_spec(tokens)
    for k, v in want.items():
        assert getattr(spec, k) == v, (k, getattr(spec, k))
    assert left == rest


@pytest.mark.parametrize("tokens, needle", [
    ([], "needs a mode"),
    (["bogus"], "unknown mode"),
    (["save", "x.txt"], "must end in .rrd"),
    (["serve", "0"], "[1, 65535]"),
    (["serve", "70000"], "[1, 65535]"),
    (["serve", "9000", "9000"], "must differ"),
    (["connect", "http://host:9876"], "must start with rerun+http://"),
    (["connect", "0"], "[1, 65535]"),
])
def test_parse_rerun_spec_errors_name_the_allowed_values(tokens: list[str],
                                                         needle: str) -> None:
    with pytest.raises(RerunSpecError) as ei:
        parse_rerun_spec(tokens)
    msg = str(ei.value)
    assert "\n" not in msg and msg.startswith("--rerun") and needle in msg, msg


def test_web_viewer_url_is_exact() -> None:
    assert (web_viewer_url("rerun+http://127.0.0.1:9876/proxy", 9090) ==
            "http://127.0.0.1:9090/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A9876%2Fproxy")


# ---- the feed: values through rerun and back ---------------------------------------------


def _first_per_interval(t: np.ndarray, rate_hz: float) -> np.ndarray:
    """Indices of the first sample of each 1/rate interval (the documented decimation)."""
    _, idx = np.unique(np.floor(t * rate_hz), return_index=True)
    return idx


def _wrap(x: np.ndarray) -> np.ndarray:
    return np.angle(np.exp(1j * x))


def test_feed_to_rrd_values_match_independent_reference(tmp_path: Path) -> None:
    pp, radius, rate = 4.0, 0.0305, 50.0
    # serial telemetry at 1 kHz, TPDOs at 500 Hz, simulator truth at 2 kHz (its own times)
    t_tel = np.arange(2000) / 1000.0 + 3e-4
    theta_hat = 30.0 * t_tel  # rad el., unwrapped: wraps about 10 times
    omega_hat = 30.0 + 5.0 * np.sin(TWO_PI * t_tel)
    t_pdo = np.arange(1000) / 500.0 + 1e-4
    v_mps = 0.2 + 0.01 * np.cos(3.0 * t_pdo)
    status = np.where(t_pdo < 0.5, 0x0237, np.where(t_pdo < 1.5, 0x1637, 0x0218)).astype(float)
    t_sim = np.arange(4000) / 2000.0
    theta_e = 30.0 * t_sim + 0.02 * np.sin(7.0 * t_sim)
    theta_hat_sim = 30.0 * t_sim
    omega_e = 30.0 + 0.14 * np.cos(7.0 * t_sim)
    load = np.where(t_sim < 1.0, 0.0, 40.0)

    path = tmp_path / "t.rrd"
    sink = RerunSink(RerunSpec("save"), path)
    feed = LiveFeed(sink, pole_pairs=pp, radius_m=radius, rate_hz=rate, batch_s=0.01)
    for k in range(200):  # 10 ms per round, interleaved as the threads would put them
        s = slice(10 * k, 10 * k + 10)
        feed.put("tel.", t_tel[s], {"theta_hat_rad": theta_hat[s],
                                    "omega_hat_radps": omega_hat[s]})
        for i in range(5 * k, 5 * k + 5):
            feed.put("pdo.", t_pdo[i], {"speed_hat_mps": v_mps[i], "statusword": status[i]})
        s2 = slice(20 * k, 20 * k + 20)
        feed.put_truth(t_sim[s2], {"theta_e_rad": theta_e[s2], "theta_hat_rad":
                                   theta_hat_sim[s2], "omega_e_radps": omega_e[s2],
                                   "load_N": load[s2], "i_d_A": 0 * t_sim[s2]})
    stats = feed.close()
    sink.close()
    assert stats.items_dropped == 0 and stats.items_in == 200 * 7
    got = read_rrd(path)

    def check(entity: str, t: np.ndarray, v: np.ndarray, tol: float = 1e-9) -> None:
        idx = _first_per_interval(t, rate)
        tg, vg = got[entity]
        assert tg.size == idx.size, (entity, tg.size, idx.size)
        np.testing.assert_allclose(tg, t[idx], atol=2e-9, rtol=0, err_msg=entity)
        np.testing.assert_allclose(vg, v[idx], atol=tol, rtol=0, err_msg=entity)

    check("position/estimate", t_tel, _wrap(theta_hat))
    check("speed/estimate", t_tel, omega_hat * 60.0 / (TWO_PI * pp))
    check("speed/pdo", t_pdo, v_mps * 60.0 / (TWO_PI * radius))
    check("truth/position", t_sim, _wrap(theta_e))
    check("truth/speed", t_sim, omega_e * 60.0 / (TWO_PI * pp))
    check("truth/position_error", t_sim, _wrap(theta_e - theta_hat_sim))
    check("truth/load", t_sim, load)
    assert "truth/current/i_d" not in got  # not in the default truth set

    # a step signal: sample-and-hold of what was recorded gives back every raw sample
    ts, vs = got["state/statusword"]
    assert ts.size < 40  # 2 changes (2 rows each) + 5 rows/s keep-alive, not 1000 rows
    held = vs[np.searchsorted(ts, t_pdo, side="right") - 1]
    np.testing.assert_array_equal(held, status)
    for tc in (t_pdo[np.argmax(t_pdo >= 0.5)], t_pdo[np.argmax(t_pdo >= 1.5)]):
        at = vs[np.abs(ts - tc) < 2e-9]  # the old and the new value at the change
        assert at.size == 2 and at[0] != at[1], (tc, at)


# ---- the bounded queue ------------------------------------------------------------------


class Recorder:
    """A transport double: what the feed sent."""

    def __init__(self, block: threading.Event | None = None) -> None:
        self.rows: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
        self.block = block

    def send(self, entity: str, t: np.ndarray, v: np.ndarray) -> None:
        if self.block is not None:
            self.block.wait(10.0)
        self.rows.setdefault(entity, []).append((t.copy(), v.copy()))


def test_full_queue_drops_and_counts_never_waits() -> None:
    feed = LiveFeed(None, rate_hz=0, queue_max=8)  # no transport yet: nothing is taken
    ok, took = [], []
    for k in range(20):
        t = k + np.arange(3) * 0.1
        c0 = time.perf_counter()
        ok.append(feed.put("tel.", t, {"i_d_A": t * 2.0, "i_q_A": -t}))
        took.append(time.perf_counter() - c0)
    assert ok == [True] * 8 + [False] * 12
    assert feed.stats.items_dropped == 12
    assert feed.stats.samples_dropped == 12 * 3 * 2
    assert max(took) < 0.05
    rec = Recorder()
    feed.attach(rec)
    stats = feed.close()
    assert stats.items_in == 8 and stats.backlog_items == 8 and stats.items_unsent == 0
    t_sent = np.concatenate([t for t, _ in rec.rows["current/i_d"]])
    v_sent = np.concatenate([v for _, v in rec.rows["current/i_d"]])
    want = np.concatenate([k + np.arange(3) * 0.1 for k in range(8)])
    np.testing.assert_array_equal(t_sent, want)  # exactly the 8 accepted items
    np.testing.assert_array_equal(v_sent, want * 2.0)


def test_blocked_sender_never_blocks_the_producer() -> None:
    gate = threading.Event()
    feed = LiveFeed(Recorder(block=gate), rate_hz=0, batch_s=0.005, queue_max=16)
    ok, took = [], []
    for k in range(300):
        c0 = time.perf_counter()
        ok.append(feed.put("pdo.", k * 1e-3, {"force_hat_N": float(k)}))
        took.append(time.perf_counter() - c0)
        if k % 50 == 0:
            time.sleep(0.01)  # let the sender take a batch and block in send()
    gate.set()
    stats = feed.close()
    n_drop = ok.count(False)
    assert n_drop > 0, "the queue never filled although the sender was blocked"
    assert stats.items_dropped == n_drop
    assert stats.items_in + stats.items_dropped == 300
    assert max(took) < 0.05, max(took)  # the sender was blocked for the whole loop
    assert stats.latency_ms(0.5) is not None


def test_closed_before_the_sink_opened_counts_unsent() -> None:
    feed = LiveFeed(None)
    for k in range(5):
        feed.put("tel.", float(k), {"i_q_A": 1.0})
    stats = feed.close(timeout_s=2.0)
    assert stats.items_unsent == 5 and stats.items_in == 0


def test_feed_rejects_bad_parameters() -> None:
    with pytest.raises(ValueError, match=r"batch_s 2.0: allowed range \[0.005, 1.0\] s"):
        LiveFeed(None, batch_s=2.0)
    with pytest.raises(ValueError, match="allowed: position"):
        LiveFeed(None, truth=("nonsense",))


# ---- the command line, on the simulated drive ---------------------------------------------


BANNERS = ("bench: using the SIMULATED drive", "bench: no drive hardware found",
           "bench: FALLING BACK TO THE SIMULATED DRIVE")


def bench(*args: str, cwd: Path, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for k in ("BENCH_DEBUG", "DISPLAY", "WAYLAND_DISPLAY"):
        env.pop(k, None)
    r = subprocess.run([sys.executable, "-m", "bench.cli", *args], capture_output=True,
                       text=True, cwd=cwd, env=env, timeout=timeout)
    assert "Traceback" not in r.stderr, r.stderr
    return r


#: judged until this long before the statusword leaves OPERATION ENABLED (see the test)
DISABLE_MARGIN_S = 0.2


def _enabled(got: dict[str, tuple[np.ndarray, np.ndarray]]) -> tuple[float, float]:
    """Drive times between which the statusword (0x6041, from the TPDO) says operation
    enabled (the end: the disable on exit)."""
    ts, sw = got["state/statusword"]
    on = (sw.astype(np.int64) & 0x6F) == 0x27
    assert on.any(), sw
    i = int(np.argmax(on))
    off = np.flatnonzero(~on[i:])
    return float(ts[i]), float(ts[i + off[0]]) if off.size else float(ts[-1])


def _nearest(t_ref: np.ndarray, t: np.ndarray) -> np.ndarray:
    i = np.searchsorted(t_ref, t).clip(1, t_ref.size - 1)
    return np.where(np.abs(t_ref[i - 1] - t) <= np.abs(t_ref[i] - t), i - 1, i)


@needs_sim
def test_bench_live_sim_records_wire_estimates_and_truth_that_agree(tmp_path: Path) -> None:
    out = tmp_path / "live.rrd"
    r = bench("live", "--sim", "--duration", "1.5", "--speed", "100", "--rerun", "save",
              str(out), cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "paced to the wall clock" in r.stderr and "as fast as possible" not in r.stderr
    assert "0 dropped" in r.stderr
    got = read_rrd(out)
    wire = {"position/estimate", "speed/estimate", "speed/pdo", "position_m/estimate",
            "force/estimate", "current/i_q", "state/statusword"}
    truth = {"truth/position", "truth/speed", "truth/position_error", "truth/load"}
    assert wire | truth <= set(got), sorted(got)
    assert not (tmp_path / "runs").exists()  # 'save PATH': the file is where it was asked

    t_on, t_off = _enabled(got)
    te, pe = got["position/estimate"]  # decoded from the serial link
    tt, pt = got["truth/position"]
    _, st = got["truth/speed"]
    _, perr_fw = got["truth/position_error"]
    # after the start-up (alignment, polarity test, settling), before the disable. The
    # bench's disable zeroes the references by SDO before it walks the state machine, so
    # the mover slows down while the statusword still says OPERATION ENABLED: by one SDO
    # round trip or two, which take tens of ms on a loaded machine (60 ms seen)
    t_off -= DISABLE_MARGIN_S
    sel = (te > t_on + 0.3) & (te < t_off)
    assert sel.sum() >= 40, (t_on, te[-1])
    te, pe = te[sel], pe[sel]
    j = _nearest(tt, te)
    dt = te - tt[j]
    assert np.abs(dt).max() < 1e-3
    omega_e = st[j] * TWO_PI / 60.0 * 4.0  # r/min -> rad/s el. (paper_salient: 4 pole pairs)
    err = _wrap(pt[j] + omega_e * dt - pe)  # truth at the estimate's time - estimate
    assert np.abs(err).max() < 0.1, np.abs(err).max()
    # the firmware-internal error the simulator gives agrees with the one from the wire
    assert np.abs(err - perr_fw[j]).max() < 0.02

    ts_e, se = got["speed/estimate"]
    ts_p, sp = got["speed/pdo"]
    k = (ts_e > t_on + 0.5) & (ts_e < t_off)
    assert np.abs(st[_nearest(tt, ts_e[k])] - 100.0).max() < 5.0
    assert np.abs(se[k] - st[_nearest(tt, ts_e[k])]).max() < 5.0
    kp = (ts_p > t_on + 0.5) & (ts_p < t_off)
    assert np.abs(sp[kp] - se[_nearest(ts_e, ts_p[kp])]).max() < 5.0  # PDO vs serial


SHORT = ("name: short\nmotor: paper_salient\nextractor: sogi_adaptive\nseed: 0\nsteps:\n"
         "  - enable: {mode: speed}\n  - set_speed: {value: 100, unit: r/min}\n"
         "  - wait: {duration_s: 0.5}\n  - disable: {}\n")


@needs_sim
def test_bench_run_rerun_file_name_after_mode_and_rrd_in_each_run_folder(
        tmp_path: Path) -> None:
    (tmp_path / "short.yaml").write_text(SHORT)
    for mode in ("save", "spawn"):  # spawn without a display: recording only
        r = bench("run", "--rerun", mode, "short.yaml", "--sim", "--runs", "runs",
                  "--no-progress", cwd=tmp_path)
        assert r.returncode == 0, r.stderr
    rrds = sorted((tmp_path / "runs").glob("*_short/telemetry.rrd"))
    assert len(rrds) == 2, list((tmp_path / "runs").rglob("*"))  # one per run folder
    assert not (tmp_path / "runs" / "telemetry.rrd").exists()
    for rrd in rrds:
        got = read_rrd(rrd)
        assert {"position/estimate", "speed/estimate", "speed/pdo", "truth/position",
                "truth/speed"} <= set(got), sorted(got)
        t, _ = got["truth/position"]
        assert t[-1] - t[0] > 0.4  # the whole sequence (0.5 s)


@needs_sim
@pytest.mark.parametrize("args, needles", [
    (["live", "--sim", "--rerun", "bogus"], ["--rerun bogus", "unknown mode", "allowed:"]),
    (["live", "--sim", "--rerun", "save", "x.txt"], ["--rerun save x.txt", ".rrd"]),
    (["live", "--sim", "--rerun", "serve", "0"], ["--rerun serve 0", "[1, 65535]"]),
    (["live", "--sim", "--rerun", "serve", "9300", "9300"], ["must differ"]),
    (["live", "--sim", "--rerun", "save", "a.rrd", "extra"], ["unexpected 'extra'",
                                                              "allowed:"]),
    (["run", "--sim", "--rerun", "serve", "70000", "short.yaml"], ["[1, 65535]"]),
    (["run", "--sim", "--rerun", "save"], ["at least one sequence file"]),
    (["run", "--sim", "--rerun", "save", "a.rrd", "short.yaml", "short.yaml"],
     ["one file for 2 sequences"]),
])
def test_bad_rerun_is_one_line_exit_2_nothing_written(tmp_path: Path, args: list[str],
                                                      needles: list[str]) -> None:
    (tmp_path / "short.yaml").write_text(SHORT)
    r = bench(*args, cwd=tmp_path)
    lines = [ln for ln in r.stderr.splitlines() if ln and not ln.startswith(BANNERS)]
    assert r.returncode == 2, (r.returncode, lines)
    assert len(lines) == 1, lines
    for n in needles:
        assert n in lines[0], (n, lines[0])
    assert not (tmp_path / "runs").exists() and not list(tmp_path.glob("*.rrd"))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@needs_sim
def test_serve_port_in_use_is_one_line_exit_2(tmp_path: Path) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        web = _free_port()
        r = bench("live", "--sim", "--rerun", "serve", str(port), str(web), cwd=tmp_path)
    lines = [ln for ln in r.stderr.splitlines() if ln and not ln.startswith(BANNERS)]
    assert r.returncode == 2 and len(lines) == 1, lines
    assert f"GRPC_PORT {port} is in use" in lines[0] and "[1, 65535]" in lines[0]


def _listeners(port: int) -> list[str]:
    """Local addresses (hex, as in /proc/net/tcp*) listening on ``port``."""
    out = []
    for f in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            rows = Path(f).read_text().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            cols = row.split()
            addr, p = cols[1].rsplit(":", 1)
            if int(p, 16) == port and cols[3] == "0A":  # LISTEN
                out.append(addr)
    return out


@needs_sim
@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="needs Linux /proc/net/tcp")
def test_serve_prints_the_exact_url_and_binds_localhost_only(tmp_path: Path) -> None:
    import urllib.request

    grpc, web = _free_port(), _free_port()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    p = subprocess.Popen([sys.executable, "-m", "bench.cli", "live", "--sim", "--duration",
                          "6", "--rerun", "serve", str(grpc), str(web)], cwd=tmp_path,
                         env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert p.stderr is not None
        url = None
        deadline = time.monotonic() + 60
        while url is None and time.monotonic() < deadline:
            line = p.stderr.readline()
            if not line:
                break
            if "web viewer: " in line:
                url = line.split("web viewer: ", 1)[1].strip()
        assert url == (f"http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}"
                       "%2Fproxy"), url
        for port in (grpc, web):
            addrs = _listeners(port)
            assert addrs and all(a == "0100007F" for a in addrs), (port, addrs)
        with urllib.request.urlopen(url, timeout=10) as resp:
            assert resp.status == 200 and b"<html" in resp.read(4096).lower()
        _, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
            p.communicate()
    assert p.returncode == 0, err
    assert "Traceback" not in err
    rrd = next((tmp_path / "runs").glob("*_live/telemetry.rrd"))
    assert "truth/position" in read_rrd(rrd)
    assert not _listeners(grpc) and not _listeners(web)  # the server ended with the bench
