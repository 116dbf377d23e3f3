"""Live telemetry from the wire to rerun (rerun-sdk 0.41), the same code for hardware and
the simulated drive.

Data flow::

    canopen notifier thread --PdoRecorder (decodes TPDOs)-----.
    serial reader thread ----TelemetryReader (decodes frames)--+--> LiveFeed.put()  (never blocks)
    simulated drive thread --truth chunks (simulation only)----'        |
                                                                bounded queue (drops counted)
                                                                        |
                                            sender thread: every ``batch_s`` (100 ms) one
                                            column per entity -> RerunSink.send()
                                                                        |
                                     viewer stream (spawn / serve / connect) at once,
                                     .rrd file stream in 1 s columns, compacted at close;
                                     the views (blueprint) go to the viewer and to X.rbl
                                     beside X.rrd (``rerun X.rrd X.rbl`` opens both)

The threads that talk to the drive only call :meth:`LiveFeed.put` (a C ``SimpleQueue``,
bounded by its size: no Python-level lock the sender could hold); a full queue drops the
item and counts it, it never waits. The sender never waits on the queue either: it sleeps
until a batch is due and takes what is there (``get_nowait``), so a put never has a waiter
to wake (waking the sender on every item was what made puts slow under CPU load: 170-250
stalls per 10 s run, none after). Everything else (mapping to entities, unit conversion,
decimation, ``rr.send_columns``) happens on the sender thread. The feed can start before
rerun is open (``LiveFeed(None)`` + :meth:`LiveFeed.attach`): ``bench live`` enables the
drive while a recording-only sink opens; items wait in the queue meanwhile.

Every server binds 127.0.0.1 only: ``serve`` runs ``rerun --serve-web --bind 127.0.0.1``
(the SDK's own ``serve_grpc`` / ``serve_web_viewer`` bind 0.0.0.0), ``spawn`` starts the
native viewer with ``--bind 127.0.0.1``.

Entities (scalars on the ``drive_time`` timeline, s). Decoded from the wire (hardware and
simulation alike)::

    position/estimate        tel.theta_hat_rad     electrical angle, wrapped (rad el.)
    speed/estimate           tel.omega_hat_radps   r/min (rotary equivalent)
    speed/reference          tel.speed_ref_radps_e r/min
    speed/pdo                pdo.speed_hat_mps     r/min (0x606C)
    position_m/estimate      pdo.pos_hat_m         m (0x6064)
    force/estimate           pdo.force_hat_N       N (0x6077)
    current/i_d, current/i_q ...                   A (serial telemetry)
    pll/error, hf/amplitude  ...                   rad, A
    state/statusword, state/mode, state/error_code steps (0x6041, 0x6061, 0x603F)
    tel/<name>, pdo/<name>   any other decoded signal

The simulated drive's truth is added beside, under ``truth/`` (never instead)::

    truth/position (rad el.), truth/speed (r/min), truth/position_error (rad el.,
    true angle - the firmware's estimate), truth/load (N)

Continuous signals are decimated to ``rate_hz`` (default 50 Hz, the first sample of each
1/rate interval); steps keep every change (drawn as a step) plus 5 samples/s. The full
rate record of a ``bench run`` is signals.mf4; the .rrd is the viewing copy.
"""

from __future__ import annotations

import math
import os
import queue
import tempfile
import threading
import time
import uuid
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from protocols.units import radps_e_to_rpm

TIMELINE = "drive_time"
DEFAULT_RATE_HZ = 50.0
#: one column per entity and batch: 100 ms (50 ms doubles the chunks; rerun's web viewer in
#: a software-rendered headless Chromium then fell 23 s behind in 44 s, 6 s with 100 ms)
DEFAULT_BATCH_S = 0.1
FILE_BATCH_S = 1.0
STEP_KEEPALIVE_HZ = 5.0
STALL_S = 1e-3  #: a put() slower than this counts as a drive-thread stall
DEFAULT_GRPC_PORT = 9876
DEFAULT_WEB_PORT = 9090
DEFAULT_QUEUE_MAX = 16384  #: items (~4 s of the simulated drive's ~4,000 items/s)

#: truth channels sent by default (``truth`` argument of :class:`LiveFeed`)
DEFAULT_TRUTH = ("position", "speed", "position_error", "load")

_TWO_PI = 2.0 * math.pi

# decoded name -> (entity, conversion, kind); conversion: "wrap", "rpm" (rad/s el.),
# "mps_rpm" (m/s), None; kind "step" for state-like signals
_WIRE: dict[str, tuple[str, str | None, str]] = {
    "tel.theta_hat_rad": ("position/estimate", "wrap", "cont"),
    "tel.omega_hat_radps": ("speed/estimate", "rpm", "cont"),
    "tel.omega_f_radps": ("speed/estimate_filtered", "rpm", "cont"),
    "tel.speed_ref_radps_e": ("speed/reference", "rpm", "cont"),
    "tel.pll_err_rad": ("pll/error", None, "cont"),
    "tel.pll_err_f_rad": ("pll/error_filtered", None, "cont"),
    "tel.hf_amp_A": ("hf/amplitude", None, "cont"),
    "tel.hf_q_A": ("hf/q", None, "cont"),
    "tel.i_d_A": ("current/i_d", None, "cont"),
    "tel.i_q_A": ("current/i_q", None, "cont"),
    "tel.i_d_ref_A": ("current/i_d_ref", None, "cont"),
    "tel.i_q_ref_A": ("current/i_q_ref", None, "cont"),
    "tel.force_hat_N": ("force/estimate_tel", None, "cont"),
    "tel.statusword": ("state/statusword_tel", None, "step"),
    "tel.fault_code": ("state/fault_code", None, "step"),
    "tel.start_phase": ("state/start_phase", None, "step"),
    "pdo.pos_hat_m": ("position_m/estimate", None, "cont"),
    "pdo.speed_hat_mps": ("speed/pdo", "mps_rpm", "cont"),
    "pdo.force_hat_N": ("force/estimate", None, "cont"),
    "pdo.statusword": ("state/statusword", None, "step"),
    "pdo.mode_display": ("state/mode", None, "step"),
    "pdo.error_code": ("state/error_code", None, "step"),
    "pdo.error_register": ("state/error_register", None, "step"),
    "pdo.start_phase": ("state/start_phase_pdo", None, "step"),
}

# truth channel -> (simulator channel, entity, conversion)
_TRUTH: dict[str, tuple[str, str, str | None]] = {
    "position": ("theta_e_rad", "truth/position", "wrap"),
    "speed": ("omega_e_radps", "truth/speed", "rpm"),
    "load": ("load_N", "truth/load", None),
    "force": ("force_N", "truth/force", None),
    "position_m": ("x_m", "truth/position_m", None),
    "i_d": ("i_d_A", "truth/current/i_d", None),
    "i_q": ("i_q_A", "truth/current/i_q", None),
}
TRUTH_CHANNELS = (*_TRUTH, "position_error")


def _wrap(x: np.ndarray) -> np.ndarray:
    return (x + np.pi) % _TWO_PI - np.pi


_GREY = (190, 190, 190)
#: legend name and colour of the known entities (the truth in grey, beside its estimate)
_STYLE: dict[str, tuple[str, tuple[int, int, int] | None]] = {
    "position/estimate": ("estimate (serial)", (66, 165, 245)),
    "truth/position": ("truth", _GREY),
    "truth/position_error": ("truth - estimate", (255, 167, 38)),
    "speed/estimate": ("estimate (serial)", (66, 165, 245)),
    "speed/estimate_filtered": ("estimate filtered (serial)", (38, 198, 218)),
    "speed/pdo": ("estimate (PDO 0x606C)", (255, 167, 38)),
    "speed/reference": ("reference", (102, 187, 106)),
    "truth/speed": ("truth", _GREY),
    "force/estimate": ("estimate (PDO 0x6077)", (255, 167, 38)),
    "force/estimate_tel": ("estimate (serial)", (66, 165, 245)),
    "truth/load": ("load (truth)", _GREY),
    "truth/force": ("thrust (truth)", (120, 120, 120)),
    "position_m/estimate": ("estimate (PDO 0x6064)", (255, 167, 38)),
    "truth/position_m": ("truth", _GREY),
    "state/statusword": ("statusword 0x6041", None),
    "state/mode": ("mode 0x6061", None),
    "state/error_code": ("error code 0x603F", None),
}


def _matches(entity: str, pattern: str) -> bool:
    """``entity`` (no leading /) is selected by a view's content ``pattern`` ("/a/**" or
    "/a/b")."""
    pat = pattern.lstrip("/")
    if pat.endswith("/**"):
        return entity == pat[:-3] or entity.startswith(pat[:-2])
    return entity == pat


def blueprint() -> Any:
    """The bench's default rerun blueprint: wire estimates with the truth beside them.

    The legend name and colour of the known entities (:data:`_STYLE`) are overrides in the
    blueprint, not data in the recording: the .rrd holds only the samples (and the
    recording's name), the blueprint is the .rbl beside it (and what a viewer is sent)."""
    import rerun as rr
    import rerun.blueprint as rrb

    def view(name: str, *contents: str) -> Any:
        overrides = {}
        for entity, (label, color) in _STYLE.items():
            if any(_matches(entity, c) for c in contents):
                arch = (rr.SeriesLines(names=label, colors=color) if color is not None
                        else rr.SeriesLines(names=label))
                overrides["/" + entity] = arch.visualizer()
        return rrb.TimeSeriesView(origin="/", contents=[f"+ {c}" for c in contents], name=name,
                                  overrides=overrides or None)

    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                view("position (rad el.): estimate vs truth", "/position/**", "/truth/position"),
                view("position error (rad el.)", "/truth/position_error"),
            ),
            rrb.Horizontal(
                view("speed (r/min): estimates, reference, truth", "/speed/**",
                     "/truth/speed"),
                view("currents (A)", "/current/**", "/truth/current/**"),
            ),
            rrb.Horizontal(
                view("force (N): estimate, load", "/force/**", "/truth/force", "/truth/load"),
                view("position (m)", "/position_m/**", "/truth/position_m"),
                view("PLL error (rad), HF amplitude (A)", "/pll/**", "/hf/**"),
                view("drive state", "/state/**"),
                view("other wire signals", "/tel/**", "/pdo/**"),
            ),
        ),
        collapse_panels=True,
    )


# ---- what to connect to -----------------------------------------------------------------


class RerunSpecError(ValueError):
    """An invalid ``--rerun`` specification (one line, names the allowed forms)."""


class RerunStartError(RuntimeError):
    """The rerun viewer or server could not be started (one line)."""


@dataclass
class RerunSpec:
    """Where live telemetry goes (``--rerun MODE [ARGS]``).

    Every mode also records an .rrd file: ``path`` if given (``save PATH``), else
    ``telemetry.rrd`` in the run folder.
    """

    mode: str  #: spawn | save | serve | connect
    path: Path | None = None
    url: str | None = None
    grpc_port: int = DEFAULT_GRPC_PORT
    web_port: int = DEFAULT_WEB_PORT
    rate_hz: float = DEFAULT_RATE_HZ
    batch_s: float = DEFAULT_BATCH_S
    truth: tuple[str, ...] = DEFAULT_TRUTH
    queue_max: int = DEFAULT_QUEUE_MAX

    FORMS = ("spawn", "save [PATH.rrd]", "serve [GRPC_PORT [WEB_PORT]]", "connect [URL|PORT]")


def _port(tok: str) -> int | None:
    try:
        p = int(tok)
    except ValueError:
        return None
    return p


def parse_rerun_spec(tokens: list[str]) -> tuple[RerunSpec, list[str]]:
    """``--rerun`` tokens -> (spec, the tokens left over: e.g. ``bench run --rerun spawn
    SEQ.yaml`` leaves ``SEQ.yaml``). Raises :class:`RerunSpecError`."""
    allowed = "allowed: " + ", ".join(RerunSpec.FORMS)
    if not tokens:
        raise RerunSpecError(f"--rerun needs a mode; {allowed}")
    mode, rest = tokens[0], list(tokens[1:])
    if mode == "spawn":
        return RerunSpec("spawn"), rest
    if mode == "save":
        if rest and rest[0].endswith(".rrd"):
            return RerunSpec("save", path=Path(rest[0])), rest[1:]
        if rest and not rest[0].lower().endswith((".yaml", ".yml")):
            raise RerunSpecError(f"--rerun save {rest[0]}: PATH must end in .rrd")
        return RerunSpec("save"), rest
    if mode == "serve":
        ports: list[int] = []
        while rest and len(ports) < 2 and (p := _port(rest[0])) is not None:
            if not 1 <= p <= 65535:
                raise RerunSpecError(f"--rerun serve {rest[0]}: port allowed range [1, 65535]")
            ports.append(p)
            rest.pop(0)
        if len(ports) == 2 and ports[0] == ports[1]:
            raise RerunSpecError(f"--rerun serve {ports[0]} {ports[1]}: the gRPC and web "
                                 "viewer ports must differ")
        return RerunSpec("serve", grpc_port=ports[0] if ports else DEFAULT_GRPC_PORT,
                         web_port=ports[1] if len(ports) > 1 else DEFAULT_WEB_PORT), rest
    if mode == "connect":
        url = None
        if rest and rest[0].startswith(("rerun://", "rerun+http://", "rerun+https://")):
            url = rest.pop(0)
        elif rest and (p := _port(rest[0])) is not None:
            if not 1 <= p <= 65535:
                raise RerunSpecError(f"--rerun connect {rest[0]}: port allowed range "
                                     "[1, 65535]")
            url = f"rerun+http://127.0.0.1:{p}/proxy"
            rest.pop(0)
        elif rest and "://" in rest[0]:
            raise RerunSpecError(f"--rerun connect {rest[0]}: URL must start with "
                                 "rerun+http://, rerun+https:// or rerun://")
        return RerunSpec("connect", url=url or
                         f"rerun+http://127.0.0.1:{DEFAULT_GRPC_PORT}/proxy"), rest
    raise RerunSpecError(f"--rerun {mode}: unknown mode; {allowed}")


def web_viewer_url(grpc_url: str, web_port: int) -> str:
    """The URL that opens the bundled web viewer on ``grpc_url``."""
    from urllib.parse import quote

    return f"http://127.0.0.1:{web_port}/?url={quote(grpc_url, safe='')}"


def _display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _port_in_use(port: int) -> bool:
    """True when something listens on (or holds) ``port`` of 127.0.0.1."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return True
    return False


def recording_only(spec: RerunSpec) -> bool:
    """No viewer: ``save``, or ``spawn`` without a display."""
    return spec.mode == "save" or (spec.mode == "spawn" and not _display())


def check_spec(spec: RerunSpec) -> None:
    """What can be checked before anything connects or moves: ``serve`` needs both ports
    free (unless this process serves them already), ``connect`` a server that answers.
    Raises :class:`RerunSpecError`."""
    if spec.mode == "connect":
        import socket
        from urllib.parse import urlsplit

        u = urlsplit(spec.url or "")
        host, port = u.hostname or "127.0.0.1", u.port or DEFAULT_GRPC_PORT
        try:
            socket.create_connection((host, port), timeout=1.0).close()
        except OSError:
            raise RerunSpecError(
                f"--rerun connect {spec.url}: no rerun viewer or server answers at {host}:"
                f"{port}; start one (rerun) or use --rerun spawn / serve") from None
        return
    if spec.mode != "serve" or (spec.grpc_port, spec.web_port) in _servers:
        return
    for what, port in (("GRPC_PORT", spec.grpc_port), ("WEB_PORT", spec.web_port)):
        if _port_in_use(port):
            raise RerunSpecError(
                f"--rerun serve {spec.grpc_port} {spec.web_port}: {what} {port} is in use on "
                "127.0.0.1; give free ports: --rerun serve GRPC_PORT WEB_PORT (allowed range "
                "[1, 65535])")


def rerun_exe() -> str:
    """The rerun viewer/server binary shipped with rerun-sdk (``RERUN_CLI_PATH``
    overrides; else the ``rerun_cli`` package's, else ``rerun`` on PATH)."""
    import shutil

    env = os.environ.get("RERUN_CLI_PATH")
    if env:
        return env
    try:
        import rerun_cli

        exe = Path(rerun_cli.__file__).parent / "rerun"
        if exe.is_file():
            return str(exe)
    except ImportError:
        pass
    exe_path = shutil.which("rerun")
    if exe_path is None:
        raise RerunStartError("the rerun binary was not found (rerun-sdk's rerun_cli package, "
                           "or set RERUN_CLI_PATH)")
    return exe_path


def wait_port(port: int, proc: Any, what: str, timeout_s: float = 10.0) -> None:
    import socket

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            err = ""
            log_file = getattr(proc, "log_file", None)
            if log_file is not None:
                log_file.seek(0)
                err = log_file.read().decode(errors="replace")
            last = (err.strip().splitlines() or ["no output"])[-1]
            raise RerunStartError(f"rerun {what} exited ({proc.returncode}): "
                                  f"{' '.join(last.split())[-300:]}")
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.settimeout(0.2)
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.02)
    raise RerunStartError(f"rerun {what} did not listen on 127.0.0.1:{port} within "
                          f"{timeout_s:g} s")


#: (gRPC port, web port) -> the ``rerun --serve-web`` child process this process started
_servers: dict[tuple[int, int], Any] = {}


def _stop_servers() -> None:
    for proc in _servers.values():
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(2.0)
            except Exception:  # noqa: BLE001
                proc.kill()
    _servers.clear()


def serve(grpc_port: int, web_port: int) -> str:
    """Start (once per process and port pair) ``rerun --serve-web --bind 127.0.0.1``: a
    gRPC proxy server that buffers the recording for late viewers, and the web viewer over
    HTTP, both on 127.0.0.1 only (the SDK's own server functions bind 0.0.0.0). It runs
    until this process exits. Returns the gRPC URL."""
    import atexit
    import subprocess

    url = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
    key = (grpc_port, web_port)
    if key in _servers and _servers[key].poll() is None:
        return url
    if not _servers:
        atexit.register(_stop_servers)
    log_file = tempfile.TemporaryFile()  # not a pipe: nobody reads it while it runs
    proc = subprocess.Popen(
        [rerun_exe(), "--serve-web", "--bind", "127.0.0.1", "--port", str(grpc_port),
         "--web-viewer-port", str(web_port), "--server-memory-limit", "1GiB"],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=log_file)
    proc.log_file = log_file  # type: ignore[attr-defined]
    _servers[key] = proc
    wait_port(grpc_port, proc, "server")
    wait_port(web_port, proc, "server")
    return url


def spawn_viewer(grpc_port: int) -> str:
    """A native viewer listening on 127.0.0.1 (detached: it outlives the bench); an
    already running one on that port is reused, as ``rr.spawn`` does."""
    import subprocess

    url = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
    if not _port_in_use(grpc_port):
        log_file = tempfile.TemporaryFile()  # detached: it outlives this process
        proc = subprocess.Popen([rerun_exe(), "--bind", "127.0.0.1", "--port", str(grpc_port),
                                 "--expect-data-soon", "--memory-limit", "75%"],
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=log_file, start_new_session=True)
        proc.log_file = log_file  # type: ignore[attr-defined]
        wait_port(grpc_port, proc, "viewer", timeout_s=5.0)
        time.sleep(0.3)  # a viewer that cannot open its window exits right after listening
        if proc.poll() is not None:
            raise RerunStartError(f"rerun viewer exited ({proc.returncode}) right after "
                                  f"starting (display {os.environ.get('DISPLAY') or '-'}); "
                                  "use --rerun serve or save")
    return url


# ---- the transport: rerun recording streams ---------------------------------------------


def blueprint_path(rrd: Path) -> Path:
    """The blueprint file written beside a recording: ``X.rrd`` -> ``X.rbl``."""
    return Path(rrd).with_suffix(".rbl")


def view_command(rrd: Path) -> str:
    """The command that opens a recording with the bench's views (rerun loads the .rbl
    beside it as the blueprint of the same application id)."""
    import shlex

    return f"rerun {shlex.quote(str(rrd))} {shlex.quote(str(blueprint_path(rrd)))}"


class RerunSink:
    """The rerun side: a viewer stream (spawn / serve / connect; none for save or a
    headless spawn) and an .rrd file stream, both of one recording.

    :meth:`send` goes to the viewer at once and to the file in ``file_batch_s`` columns;
    :meth:`close` compacts the file (rerun's chunk optimiser: a few large chunks instead of
    one per entity and batch). Every server binds 127.0.0.1 only.

    The .rrd holds the samples and the recording's name only. The blueprint (the views,
    the legend names and colours) goes to the viewer with the stream and, for the file, to
    ``X.rbl`` beside ``X.rrd`` (:func:`view_command` opens both): a fixed size (~0.2 MB
    with the legend overrides) that does not grow with drive time.
    """

    def __init__(self, spec: RerunSpec, path: Path, name: str = "bench",
                 app_id: str = "pmlsm_bench", file_batch_s: float = FILE_BATCH_S,
                 compact: bool = True) -> None:
        import rerun as rr

        self.rr = rr
        self.spec = spec
        self.mode = spec.mode
        self.path = Path(path)
        self.app_id = app_id
        self.file_batch_s = file_batch_s
        self.compact = compact
        self.recording_id = f"{name}-{uuid.uuid4().hex[:12]}"
        self.url: str | None = None         # gRPC URL a viewer connects to
        self.web_url: str | None = None     # the bundled web viewer (serve)
        self.notes: list[str] = []          # what to tell the user
        self.send_s = 0.0                   # time spent in rerun's send_columns (s)
        self._file_buf: dict[str, tuple[list[np.ndarray], list[np.ndarray]]] = {}
        self._file_t0 = time.monotonic()
        self.bp = blueprint()
        self.blueprint_path = blueprint_path(self.path)
        self.viewer: Any = None
        mode = spec.mode
        if mode == "spawn" and not _display():
            self.notes.append("no display: no viewer spawned, recording only")
            mode = "save"
        # the viewer or server first: when it fails to start, no file has been written
        if mode == "spawn":
            self.url = spawn_viewer(spec.grpc_port)
        elif mode == "serve":
            self.url = serve(spec.grpc_port, spec.web_port)
            self.web_url = web_viewer_url(self.url, spec.web_port)
            self.notes.append(f"web viewer: {self.web_url}")
            self.notes.append(f"native viewer: rerun --connect {self.url}")
        elif mode == "connect":
            self.url = spec.url
            self.notes.append(f"streaming to the viewer at {self.url}")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.bp.save(app_id, self.blueprint_path)
        self.file = rr.RecordingStream(app_id, recording_id=self.recording_id)
        self.file.set_sinks(rr.FileSink(str(self.path)))
        self.file.send_recording_name(name)
        if self.url is not None:
            self.viewer = rr.RecordingStream(app_id, recording_id=self.recording_id)
            self.viewer.set_sinks(rr.GrpcSink(self.url), default_blueprint=self.bp)
            self.viewer.send_recording_name(name)
        self.notes.append(f"recording -> {self.path} (views: {self.blueprint_path.name}; "
                          f"open with: {view_command(self.path)})")

    def send(self, entity: str, t: np.ndarray, v: np.ndarray) -> None:
        """One column: to the viewer now, to the file in ``file_batch_s`` columns."""
        if self.viewer is not None:
            self._send(self.viewer, entity, t, v)
        b = self._file_buf.setdefault(entity, ([], []))
        b[0].append(t)
        b[1].append(v)

    def end_batch(self) -> None:
        """Called after each batch: the file gets its column once ``file_batch_s`` passed."""
        if time.monotonic() - self._file_t0 >= self.file_batch_s:
            self._flush_file()

    def _send(self, stream: Any, entity: str, t: np.ndarray, v: np.ndarray) -> None:
        rr = self.rr
        c0 = time.perf_counter()
        stream.send_columns(entity, indexes=[rr.TimeColumn(TIMELINE, duration=t)],
                            columns=rr.Scalars.columns(scalars=np.asarray(v, np.float64)))
        self.send_s += time.perf_counter() - c0

    def _flush_file(self) -> None:
        buf, self._file_buf = self._file_buf, {}
        self._file_t0 = time.monotonic()
        for entity, (ts, vs) in buf.items():
            self._send(self.file, entity, np.concatenate(ts), np.concatenate(vs))

    def close(self) -> dict[str, Any]:
        """Flush, disconnect (a served gRPC server stops), compact the .rrd; its stats."""
        self._flush_file()
        if self.viewer is not None:
            try:
                self.viewer.flush(timeout_sec=2.0)  # a viewer that went away: 2 s at most
                self.viewer.disconnect()
            except Exception:  # noqa: BLE001 - a viewer that went away must not stop the run
                pass
        self.file.flush()
        self.file.disconnect()
        out: dict[str, Any] = {"path": str(self.path), "bytes_raw": self.path.stat().st_size,
                               "blueprint": str(self.blueprint_path),
                               "blueprint_bytes": self.blueprint_path.stat().st_size}
        if self.compact:
            try:
                compact_rrd(self.path, self.app_id, self.recording_id)
            except Exception as e:  # noqa: BLE001 - the raw file stays, valid and complete
                out["compact_error"] = f"{type(e).__name__}: {e}"
        out["bytes"] = self.path.stat().st_size
        return out


def compact_rrd(path: Path, app_id: str, recording_id: str) -> None:
    """Rewrite ``path`` with rerun's chunk optimiser (object-store profile: chunks of up to
    2 MiB); atomic (a temporary file, then a rename). Only the recording is kept (the
    blueprint is the .rbl beside it)."""
    import rerun as rr
    from rerun.chunk import OptimizationProfile, RrdReader

    store = RrdReader(path).stream().collect(optimize=OptimizationProfile.OBJECT_STORE)
    tmp = path.with_name(path.name + ".tmp")
    rec = rr.RecordingStream(app_id, recording_id=recording_id, send_properties=False)
    rec.set_sinks(rr.FileSink(str(tmp)))
    rr.send_chunks(store, recording=rec)
    rec.flush()
    rec.disconnect()
    os.replace(tmp, path)


def read_rrd(path: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """All scalar series of an .rrd: entity path (no leading /) -> (t in s, values),
    sorted by time. Reads with rerun's own reader (``rerun.chunk.RrdReader``)."""
    from rerun.chunk import RrdReader

    parts: dict[str, tuple[list[np.ndarray], list[np.ndarray]]] = {}
    for ch in RrdReader(Path(path)).stream():
        rb = ch.to_record_batch()
        names = rb.schema.names
        if TIMELINE not in names:
            continue
        col = next((n for n in names if n.endswith("Scalars:scalars")), None)
        if col is None:
            continue
        t = rb.column(TIMELINE).cast("int64").to_numpy(zero_copy_only=False) * 1e-9
        vals = rb.column(col).to_pylist()
        v = np.array([x[0] if x else np.nan for x in vals], dtype=np.float64)
        p = parts.setdefault(ch.entity_path.lstrip("/"), ([], []))
        p[0].append(t)
        p[1].append(v)
    out = {}
    for k, (ts, vs) in parts.items():
        t, v = np.concatenate(ts), np.concatenate(vs)
        o = np.argsort(t, kind="stable")
        out[k] = (t[o], v[o])
    return out


# ---- the feed: bounded queue + sender thread --------------------------------------------


@dataclass
class FeedStats:
    """What the feed did (printed at the end, stored in the run's metadata)."""

    items_in: int = 0
    items_dropped: int = 0
    samples_dropped: int = 0
    batches: int = 0
    send_calls: int = 0
    rows_sent: int = 0
    queue_max: int = 0
    queue_high_water: int = 0
    put_max_s: float = 0.0
    stalls: int = 0
    send_errors: int = 0
    last_error: str | None = None
    items_unsent: int = 0      #: queued but never sent (closed before the sink opened)
    open_wait_s: float | None = None  #: feed start -> sink attached (s)
    backlog_items: int = 0     #: items queued while the sink was opening
    #: the first 20 stalls: (s since the feed started, put duration ms)
    stall_log: list[tuple[float, float]] = field(default_factory=list)
    latency_hist_ms: np.ndarray = field(default_factory=lambda: np.zeros(2001, np.int64))

    def latency_ms(self, q: float) -> float | None:
        """Quantile ``q`` of the decode-to-sent latency (ms, 1 ms bins; last bin >= 2 s).

        From :meth:`LiveFeed.put` (the sample decoded) to the end of the batch's
        ``send_columns`` calls (handed to rerun's SDK, which streams it on its own thread);
        for items queued while the sink was still opening, from the moment it opened."""
        n = int(self.latency_hist_ms.sum())
        if n == 0:
            return None
        c = np.cumsum(self.latency_hist_ms)
        return float(np.searchsorted(c, q * n - 1e-9) + 1)

    def as_dict(self) -> dict[str, Any]:
        return {"items_in": self.items_in, "items_dropped": self.items_dropped,
                "samples_dropped": self.samples_dropped, "batches": self.batches,
                "send_calls": self.send_calls, "rows_sent": self.rows_sent,
                "queue_max": self.queue_max, "queue_high_water": self.queue_high_water,
                "put_max_ms": round(self.put_max_s * 1e3, 3), "stalls": self.stalls,
                "stall_threshold_ms": STALL_S * 1e3,
                "latency_ms": {"p50": self.latency_ms(0.5), "p95": self.latency_ms(0.95),
                               "max": self.latency_ms(1.0)},
                "send_errors": self.send_errors, "last_error": self.last_error,
                "items_unsent": self.items_unsent, "backlog_items": self.backlog_items,
                "stall_log_s_ms": list(self.stall_log),
                "open_wait_s": None if self.open_wait_s is None else
                round(self.open_wait_s, 3)}


_STOP = object()


class LiveFeed:
    """Decoded telemetry -> bounded queue -> sender thread -> batched columns.

    Parameters
    ----------
    transport : object or None
        ``send(entity, t, v)`` (a :class:`RerunSink`, or a test double), optionally
        ``end_batch()``. None: :meth:`attach` it later; until then items wait in the
        queue (``bench live`` starts the drive while rerun opens).
    pole_pairs, radius_m : float
        Rotary equivalent for r/min (electrical rad/s and m/s -> r/min).
    rate_hz : float
        Continuous signals are decimated to this rate (0 = every sample).
    batch_s : float
        A batch is sent this long after its first item arrived.
    queue_max : int
        Queue capacity in items (one item = one decoded PDO, serial read or sim chunk).
    truth : tuple of str
        Truth channels of the simulated drive (:data:`TRUTH_CHANNELS`).
    """

    def __init__(self, transport: Any = None, pole_pairs: float = 4.0,
                 radius_m: float | None = None, rate_hz: float = DEFAULT_RATE_HZ,
                 batch_s: float = DEFAULT_BATCH_S, queue_max: int = DEFAULT_QUEUE_MAX,
                 truth: Iterable[str] = DEFAULT_TRUTH) -> None:
        bad = [c for c in truth if c not in TRUTH_CHANNELS]
        if bad:
            raise ValueError(f"truth channels {bad}; allowed: {', '.join(TRUTH_CHANNELS)}")
        if not 0.005 <= batch_s <= 1.0:
            raise ValueError(f"batch_s {batch_s}: allowed range [0.005, 1.0] s")
        if not queue_max >= 1:
            raise ValueError(f"queue_max {queue_max}: allowed range >= 1")
        self.transport = transport
        self._t_start = time.monotonic()
        self._t_start_pc = time.perf_counter()
        self._t_attach = self._t_start
        self._attached = threading.Event()
        self._wake = threading.Event()  #: set by close(): the sender stops sleeping
        if transport is not None:
            self._attached.set()
        self.rpm = radps_e_to_rpm(1.0, pole_pairs)
        # r/min per m/s: a mechanical rad/s is r m/s
        self.mps_rpm = (radps_e_to_rpm(1.0, 1.0) / radius_m) if radius_m else float("nan")
        self.rate_hz = float(rate_hz)
        self.batch_s = float(batch_s)
        self.truth = tuple(truth)
        self.stats = FeedStats(queue_max=queue_max)
        # SimpleQueue (C): put never takes a Python-level lock that the sender thread could
        # hold while it waits for the GIL; the bound is checked on its size (a few items of
        # overshoot when several producers put at the same instant)
        self._q: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._queue_max = queue_max
        self._drop_lock = threading.Lock()
        self._bucket: dict[str, int] = {}        # continuous: last decimation bucket sent
        self._last: dict[str, tuple[float, float]] = {}  # steps: last raw sample
        self._step_bucket: dict[str, int] = {}
        self._thread = threading.Thread(target=self._run, name="bench-live-sender",
                                        daemon=True)
        self._closed = False
        if transport is not None:
            self.stats.open_wait_s = 0.0
        self._thread.start()

    def attach(self, transport: Any) -> None:
        """Give the feed its transport; the sender thread starts sending (what waited in
        the queue first)."""
        self.transport = transport
        self._t_attach = time.monotonic()
        self.stats.open_wait_s = self._t_attach - self._t_start
        self.stats.backlog_items = self._q.qsize()
        self._attached.set()

    # ---- producer side (the threads that talk to the drive) --------------------------
    def put(self, prefix: str, t: Any, values: dict[str, Any]) -> bool:
        """Queue decoded samples (``prefix`` "pdo." / "tel." / "sim."); never blocks.

        ``t`` is a time (s) or an array; ``values`` maps signal names to values or arrays
        of the same length. Returns False (and counts the drop) when the queue is full.
        """
        c0 = time.perf_counter()
        if self._q.qsize() < self._queue_max:
            self._q.put((prefix, t, values, time.monotonic()))
            ok = True
        else:
            with self._drop_lock:
                self.stats.items_dropped += 1
                self.stats.samples_dropped += int(np.size(t)) * len(values)
            ok = False
        dt = time.perf_counter() - c0
        if dt > self.stats.put_max_s:
            self.stats.put_max_s = dt
        if dt > STALL_S:
            self.stats.stalls += 1
            if len(self.stats.stall_log) < 20:
                self.stats.stall_log.append((round(c0 - self._t_start_pc, 3),
                                             round(dt * 1e3, 2)))
        return ok

    def put_truth(self, t: np.ndarray, values: dict[str, np.ndarray],
                  units: dict[str, str] | None = None) -> None:
        """The simulated drive's chunk sink (truth + firmware internals): the truth
        channels selected go in beside the wire data."""
        want = {_TRUTH[c][0] for c in self.truth if c in _TRUTH}
        if "position_error" in self.truth:
            want |= {"theta_e_rad", "theta_hat_rad"}
        self.put("sim.", t, {k: v for k, v in values.items() if k in want})

    # ---- sender thread ---------------------------------------------------------------
    def _run(self) -> None:
        while not self._attached.wait(0.05):
            if self._closed:  # closed before a transport came: nothing can be sent
                while True:
                    try:
                        if self._q.get_nowait() is not _STOP:
                            self.stats.items_unsent += 1
                    except queue.Empty:
                        return
        pending: dict[str, tuple[list[np.ndarray], list[np.ndarray]]] = {}
        put_times: list[float] = []
        deadline: float | None = None
        stopping = False
        # never blocks on the queue (get_nowait only): a put then never wakes this thread (no
        # waiter to release, no GIL hand-off per item); it sleeps until the batch is due
        while True:
            hw = self._q.qsize()  # the backlog when the sender wakes
            if hw > self.stats.queue_high_water:
                self.stats.queue_high_water = hw
            drained = False
            for _ in range(self.stats.queue_max + 1):  # what is queued now (bounded)
                try:
                    item = self._q.get_nowait()
                except queue.Empty:
                    drained = True
                    break
                if item is _STOP:  # drain what is still queued, then stop
                    stopping = True
                    continue
                prefix, t, values, t_put = item
                self.stats.items_in += 1
                tt = np.atleast_1d(np.asarray(t, dtype=np.float64))
                for k, v in values.items():
                    b = pending.setdefault(prefix + k, ([], []))
                    b[0].append(tt)
                    b[1].append(np.atleast_1d(np.asarray(v, dtype=np.float64)))
                put_times.append(max(t_put, self._t_attach))
                if deadline is None:
                    deadline = max(t_put, self._t_attach) + self.batch_s
            if stopping and drained:
                self._flush(pending, put_times)
                return
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                self._flush(pending, put_times)
                pending, put_times, deadline = {}, [], None
            elif drained:  # asleep until the batch is due, waking 4 times a batch to take
                # what came (spreads the work: the batch is not all converted at its end)
                self._wake.wait(self.batch_s / 4 if deadline is None else
                                min(deadline - now, self.batch_s / 4))

    def _flush(self, pending: dict[str, tuple[list[np.ndarray], list[np.ndarray]]],
               put_times: list[float]) -> None:
        if not pending:
            return
        cols = {k: (np.concatenate(ts), np.concatenate(vs)) for k, (ts, vs) in pending.items()}
        try:
            for entity, t, v, kind in self._entities(cols):
                t, v = (self._steps if kind == "step" else self._decimate)(entity, t, v)
                if t.size:
                    self.transport.send(entity, t, v)
                    self.stats.send_calls += 1
                    self.stats.rows_sent += int(t.size)
            end = getattr(self.transport, "end_batch", None)
            if end is not None:
                end()
        except Exception as e:  # noqa: BLE001 - a failing viewer must not stop the drive
            self.stats.send_errors += 1
            self.stats.last_error = f"{type(e).__name__}: {e}"
        self.stats.batches += 1
        lat = (time.monotonic() - np.asarray(put_times)) * 1e3
        self.stats.latency_hist_ms += np.bincount(np.clip(lat, 0, 2000).astype(np.int64),
                                                  minlength=2001)

    def _entities(self, cols: dict[str, tuple[np.ndarray, np.ndarray]]
                  ) -> Iterable[tuple[str, np.ndarray, np.ndarray, str]]:
        for key, (t, v) in cols.items():
            if key.startswith("sim."):
                continue
            spec = _WIRE.get(key)
            if spec is None:
                src, name = key.split(".", 1)
                yield f"{src}/{name}", t, v, "cont"
                continue
            entity, conv, kind = spec
            yield entity, t, self._convert(v, conv), kind
        for ch in self.truth:
            if ch == "position_error":
                a, b = cols.get("sim.theta_e_rad"), cols.get("sim.theta_hat_rad")
                if a is not None and b is not None and a[1].size == b[1].size:
                    yield "truth/position_error", a[0], _wrap(a[1] - b[1]), "cont"
                continue
            src, entity, conv = _TRUTH[ch]
            c = cols.get("sim." + src)
            if c is not None:
                yield entity, c[0], self._convert(c[1], conv), "cont"

    def _convert(self, v: np.ndarray, conv: str | None) -> np.ndarray:
        if conv == "wrap":
            return _wrap(v)
        if conv == "rpm":
            return v * self.rpm
        if conv == "mps_rpm":
            return v * self.mps_rpm
        return v

    def _decimate(self, entity: str, t: np.ndarray, v: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
        """The first sample of each 1/rate interval (intervals carried across batches)."""
        if self.rate_hz <= 0 or t.size == 0:
            return t, v
        if t.size > 1 and np.any(np.diff(t) < 0):
            o = np.argsort(t, kind="stable")
            t, v = t[o], v[o]
        b = np.floor(t * self.rate_hz).astype(np.int64)
        prev = np.empty_like(b)
        prev[0] = self._bucket.get(entity, np.iinfo(np.int64).min)
        prev[1:] = b[:-1]
        keep = b > prev
        self._bucket[entity] = max(int(b[-1]), int(prev[0]))
        return t[keep], v[keep]

    def _steps(self, entity: str, t: np.ndarray, v: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
        """Every change as a step (the old value repeated at the change time) plus
        ``STEP_KEEPALIVE_HZ`` samples/s so the line reaches the present."""
        if t.size == 0:
            return t, v
        last = self._last.get(entity)
        v_prev = np.empty_like(v)
        v_prev[0] = last[1] if last is not None else np.nan
        v_prev[1:] = v[:-1]
        change = ~((v == v_prev) | (np.isnan(v) & np.isnan(v_prev)))
        if last is None:
            change[0] = True
        b = np.floor(t * STEP_KEEPALIVE_HZ).astype(np.int64)
        bp = np.empty_like(b)
        bp[0] = self._step_bucket.get(entity, np.iinfo(np.int64).min)
        bp[1:] = b[:-1]
        keep = change | (b > bp)
        self._last[entity] = (float(t[-1]), float(v[-1]))
        self._step_bucket[entity] = max(int(b[-1]), int(bp[0]))
        idx = np.flatnonzero(keep)
        out_t, out_v = [], []
        for i in idx:
            if change[i] and not np.isnan(v_prev[i]):
                out_t.append(t[i])
                out_v.append(v_prev[i])
            out_t.append(t[i])
            out_v.append(v[i])
        return np.asarray(out_t, np.float64), np.asarray(out_v, np.float64)

    # ---- end -------------------------------------------------------------------------
    def close(self, timeout_s: float = 10.0) -> FeedStats:
        """Send what is queued, stop the sender thread; the stats."""
        if not self._closed:
            self._closed = True
            self._q.put(_STOP)  # the stop marker gets in even when the queue is full
            self._wake.set()
            self._thread.join(timeout_s)
        return self.stats


def summary_line(stats: FeedStats, rec: dict[str, Any] | None = None,
                 drive_time_s: float | None = None) -> str:
    """One line for the console: batches, drops, latency, stalls, recording size."""
    d = stats.as_dict()
    lat = d["latency_ms"]

    def ms(x: float | None) -> str:
        return "-" if x is None else f"{x:.0f}"

    s = (f"rerun: {d['batches']} batches, {d['rows_sent']} samples sent, "
         f"{d['items_dropped']} dropped (queue full; {d['samples_dropped']} samples), "
         f"latency p50/p95/max {ms(lat['p50'])}/{ms(lat['p95'])}/{ms(lat['max'])} ms, "
         f"drive-thread stalls {d['stalls']} (longest put {d['put_max_ms']:.2f} ms)")
    if d["send_errors"]:
        s += f", {d['send_errors']} send errors ({d['last_error']})"
    if rec is not None:
        mb = rec["bytes"] / 1e6
        s += f"; recording {rec['path']} ({mb:.2f} MB"
        if drive_time_s and drive_time_s > 0:
            s += f", {mb / drive_time_s * 60:.2f} MB/min"
        s += f"); view: {view_command(Path(rec['path']))}"
    return s


class LiveTelemetry:
    """A :class:`RerunSink` fed by a :class:`LiveFeed`: what ``bench run --rerun`` and
    ``bench live`` open (see :func:`bench._session.run_live`).

    ``lazy=True`` starts only the feed (cheap: the threads that talk to the drive can put
    at once) and leaves opening rerun (~0.6 s of imports and blueprint) to :meth:`open`,
    which ``bench live`` calls once the drive runs; what arrives meanwhile waits in the
    bounded queue.
    """

    def __init__(self, spec: RerunSpec, path: Path, name: str, pole_pairs: float,
                 radius_m: float | None = None, say: Callable[[str], None] | None = None,
                 lazy: bool = False) -> None:
        check_spec(spec)
        self.spec, self.path, self.name, self.say = spec, Path(path), name, say
        self.sink: RerunSink | None = None
        self.feed = LiveFeed(None, pole_pairs=pole_pairs, radius_m=radius_m,
                             rate_hz=spec.rate_hz, batch_s=spec.batch_s, truth=spec.truth,
                             queue_max=spec.queue_max)
        self.recording: dict[str, Any] | None = None
        if not lazy:
            self.open()

    def open(self) -> None:
        """Open the rerun side (viewer, server, .rrd) and start sending."""
        if self.sink is not None:
            return
        try:
            self.sink = RerunSink(self.spec, self.path, name=self.name)
        except BaseException:
            self.feed.close(timeout_s=1.0)
            raise
        if self.say is not None:
            for n in self.sink.notes:
                self.say("bench: rerun " + n)
        self.feed.attach(self.sink)

    def close(self) -> dict[str, Any]:
        stats = self.feed.close()
        if self.sink is None:
            return {**stats.as_dict(), "recording": None, "send_s": 0.0}
        self.recording = self.sink.close()
        return {**stats.as_dict(), "recording": self.recording,
                "send_s": round(self.sink.send_s, 3)}
