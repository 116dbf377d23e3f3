"""The simulated drive as its own process, behind python-can's ``socketcand`` interface.

``bench sim start`` runs this module as a background process: one
:class:`bench._simdrive.SimDrive` paced to the wall clock (the simulated
clock follows real time, like a drive that is powered on) and a small
server that speaks the socketcand protocol on ``127.0.0.1`` only. The bench
reaches it exactly as it reaches hardware: python-can's ``socketcand``
interface (``--interface socketcand --channel can0 --host 127.0.0.1 --port
N``, or ``--sim-server``, which reads the port from the state file), the
same canopen code path, and successive commands see the same drive.

socketcand protocol (the subset python-can's client uses, rawmode)::

    server: < hi >                 client: < open can0 >
    server: < ok >                 client: < rawmode >
    server: < ok >
    server: < frame 181 1700000000.123456 11223344 >     (every frame on the bus)
    client: < send 601 8 40 0 10 0 0 0 0 0 >             (id, dlc, data bytes in hex)

A frame sent by one client goes to the simulated drive and to every other
client (as on a real bus; the sender does not get its own frame back).

State (``state_dir()``: ``$BENCH_SIM_DIR``, else ``$XDG_STATE_HOME/pmlsm-bench``,
else ``~/.local/state/pmlsm-bench``): ``simserver.json`` (pid, host, port,
channel, motor, ... written once the server listens, removed when it stops),
``simserver.log`` (the server's output) and the non-volatile memory of the
simulated drive, ``nvm_<motor>.bin`` (CiA 301 0x1010 'save'; read at start,
so a saved configuration survives ``bench sim stop`` / ``start``). A state file
whose process is gone (SIGKILL, reboot) is *stale*: ``bench sim status`` and
``stop`` say so and remove it; connecting to it fails with exit 3.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

log = logging.getLogger("bench.simserver")

STATE_FILE = "simserver.json"
LOG_FILE = "simserver.log"
LOCK_FILE = "simserver.lock"
HOST = "127.0.0.1"  # never anything else: the simulated drive is not a network service
CAN_CHANNEL = "can0"  # the bus name the server offers (socketcand serves interfaces by name)

#: What the drive application's last boot did with the stored block (fw_app_nvm_state_t).
NVM_STATES = {0: "no non-volatile memory", 1: "nothing stored: defaults",
              2: "stored parameters loaded", 3: "stored block rejected (size, magic or CRC)",
              4: "stored block rejected (another product)",
              5: "stored block rejected (another firmware version or layout)",
              6: "stored block rejected (a value out of range)",
              7: "non-volatile memory read error"}


class SimServerError(RuntimeError):
    """No usable simulated drive server (none, stale, not answering); exit 3."""


class AlreadyRunning(SimServerError):
    """``start`` while a server runs: the user's mistake (exit 2), nothing started."""


def state_dir() -> Path:
    """Folder of the state file, the log and the NVM files (created on demand)."""
    env = os.environ.get("BENCH_SIM_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "pmlsm-bench"


@dataclass
class ServerState:
    """Contents of ``simserver.json``."""

    pid: int
    host: str
    port: int
    channel: str
    motor: str
    extractor: str
    seed: int
    node_id: int
    nvm: str
    nvm_state: str
    log: str
    started: float
    bench_version: str

    @property
    def address(self) -> str:
        return f"{self.host}:{self.port}"

    def bus_config(self) -> dict[str, Any]:
        """python-can arguments that reach this server."""
        return {"interface": "socketcand", "channel": self.channel, "host": self.host,
                "port": self.port}

    def serial_url(self) -> None:
        """The server has no serial link (its drive's telemetry stays in its process)."""
        return None

    def what(self) -> str:
        return f"simulated drive server pid {self.pid}, socketcand {self.address}, motor " \
               f"{self.motor}"


def read_state(folder: Path | None = None) -> ServerState | None:
    """The state file, or None when there is none (or it is unreadable: stale)."""
    f = (folder or state_dir()) / STATE_FILE
    try:
        doc = json.loads(f.read_text(encoding="utf-8"))
        return ServerState(**doc)
    except FileNotFoundError:
        return None
    except (OSError, ValueError, TypeError):  # half-written or foreign: treat as stale
        return ServerState(pid=-1, host=HOST, port=0, channel=CAN_CHANNEL, motor="?",
                           extractor="?", seed=0, node_id=1, nvm="", nvm_state="", log="",
                           started=0.0, bench_version="?")


@contextlib.contextmanager
def state_lock(folder: Path, name: str) -> Iterator[None]:
    """One start/stop at a time per state folder and kind of process (an exclusive lock
    on ``folder/name``): two concurrent starts leave one process, never an orphan."""
    import fcntl

    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / name, "a+") as f:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f.fileno(), fcntl.LOCK_UN)


def write_state_file(folder: Path, name: str, doc: dict[str, Any]) -> None:
    """A state file written atomically (a reader never sees half of it)."""
    folder.mkdir(parents=True, exist_ok=True)
    tmp = folder / f".{name}.{os.getpid()}.tmp"
    tmp.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    os.replace(tmp, folder / name)


def _write_state(folder: Path, st: ServerState) -> None:
    write_state_file(folder, STATE_FILE, asdict(st))


def process_is(pid: int, *needles: bytes) -> bool:
    """Whether ``pid`` is alive, not a zombie, and its command line holds every needle
    (a background process of ours, not a reused pid)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, someone else's: not ours
        return False
    try:
        cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ")
    except OSError:
        return True  # no /proc: trust the pid
    if not all(n in cmd for n in needles):
        return False
    try:  # a zombie (killed, not yet reaped by its parent) is gone for us
        stat = Path(f"/proc/{pid}/stat").read_text()
        return stat.rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return True


def stop_process(pid: int, alive: Any, timeout_s: float) -> str:
    """SIGTERM, then SIGKILL after ``timeout_s``: ``"stopped"`` or ``"killed"``
    (``alive(pid)`` tells whether it is still the process of ours)."""
    os.kill(pid, signal.SIGTERM)
    deadline = time.monotonic() + timeout_s
    while alive(pid):
        if time.monotonic() > deadline:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
            time.sleep(0.1)
            return "killed"
        time.sleep(0.05)
    return "stopped"


def pid_is_server(pid: int) -> bool:
    """Whether ``pid`` is alive and is a simulated drive server (not a reused pid)."""
    return process_is(pid, b"bench._simserver")


def probe(host: str, port: int, timeout_s: float = 1.0) -> str | None:
    """None when a socketcand server greets on host:port, else why not."""
    try:
        with socket.create_connection((host, port), timeout=timeout_s) as s:
            s.settimeout(timeout_s)
            hello = s.recv(64)
    except OSError as e:
        return f"{host}:{port}: {e.strerror or e}"
    if not hello.startswith(b"< hi >"):
        return f"{host}:{port}: not a socketcand server (it said {hello[:20]!r})"
    return None


def check_running(folder: Path | None = None) -> ServerState:
    """The running server's state; raises :class:`SimServerError` with a one-line reason."""
    folder = folder or state_dir()
    st = read_state(folder)
    if st is None:
        raise SimServerError(f"no simulated drive server running (no {folder / STATE_FILE}); "
                             "start one with `bench sim start`")
    if not pid_is_server(st.pid):
        raise SimServerError(f"stale state file {folder / STATE_FILE}: the simulated drive "
                             f"server (pid {st.pid}) is not running; `bench sim start` starts "
                             "a new one")
    why = probe(st.host, st.port)
    if why is not None:
        raise SimServerError(f"simulated drive server pid {st.pid} does not answer: {why}")
    return st


# ---- the server process --------------------------------------------------------------


def frame_text(msg: Any) -> bytes:
    """A frame as socketcand sends it: ``< frame ID SEC.USEC HEXDATA >``."""
    ident = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
    ts = msg.timestamp or time.time()
    return f"< frame {ident} {ts:.6f} {bytes(msg.data).hex().upper()} >".encode("ascii")


def parse_send(body: str) -> Any:
    """``send ID DLC B0 B1 ...`` (hex) -> can.Message; ValueError when malformed."""
    import can

    parts = body.split()
    if len(parts) < 3 or parts[0] != "send":
        raise ValueError(f"not a send command: {body!r}")
    ident, dlc = int(parts[1], 16), int(parts[2], 16)
    data = bytes(int(b, 16) for b in parts[3:])
    ext = len(parts[1]) > 3
    if not 0 <= dlc <= 8 or len(data) != dlc or ident > (0x1FFFFFFF if ext else 0x7FF):
        raise ValueError(f"bad frame: {body!r}")
    return can.Message(arbitration_id=ident, is_extended_id=ext, data=data,
                       timestamp=time.time())


class _Client:
    def __init__(self, sock: socket.socket, addr: Any) -> None:
        self.sock = sock
        self.addr = addr
        self.raw = False  # in rawmode: receives the bus
        self.lock = threading.Lock()
        self.alive = True

    def send(self, data: bytes) -> bool:
        with self.lock:
            if not self.alive:
                return False
            try:
                self.sock.sendall(data)
                return True
            except OSError:
                self.alive = False
                return False

    def close(self) -> None:
        self.alive = False
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        with contextlib.suppress(OSError):
            self.sock.close()


class SocketcandServer:
    """Bridges a python-can bus (the simulated drive's) to socketcand TCP clients.

    Parameters
    ----------
    bus : can.BusABC
        The server's own handle on the simulated drive's bus.
    port : int
        TCP port on 127.0.0.1 (0: any free port; see :attr:`port`).
    channel : str
        Bus name clients must ``open``.
    """

    def __init__(self, bus: Any, port: int = 0, channel: str = CAN_CHANNEL) -> None:
        self.bus = bus
        self.channel = channel
        self.listener = socket.create_server((HOST, port))
        self.port = int(self.listener.getsockname()[1])
        self.clients: list[_Client] = []
        self._lock = threading.Lock()
        self.stop_event = threading.Event()
        self.frames_from_clients = 0
        self.frames_to_clients = 0
        self._threads = [threading.Thread(target=self._accept_loop, name="simserver-accept",
                                          daemon=True),
                         threading.Thread(target=self._bus_loop, name="simserver-bus",
                                          daemon=True)]

    def start(self) -> SocketcandServer:
        for t in self._threads:
            t.start()
        return self

    def close(self) -> None:
        self.stop_event.set()
        with contextlib.suppress(OSError):
            self.listener.close()
        with self._lock:
            clients, self.clients = self.clients, []
        for c in clients:
            c.close()
        for t in self._threads:
            t.join(timeout=2.0)

    # ---- threads ----------------------------------------------------------------------
    def _accept_loop(self) -> None:
        self.listener.settimeout(0.2)
        while not self.stop_event.is_set():
            try:
                sock, addr = self.listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            c = _Client(sock, addr)
            threading.Thread(target=self._client_loop, args=(c,), daemon=True,
                             name=f"simserver-client-{addr[1]}").start()

    def _client_loop(self, c: _Client) -> None:
        """Handshake, then frames from this client onto the bus (and to the others)."""
        buf = b""
        try:
            c.sock.settimeout(None)
            if not c.send(b"< hi >"):
                return
            while not self.stop_event.is_set():
                data = c.sock.recv(4096)
                if not data:
                    return
                buf += data
                while True:
                    start = buf.find(b"<")
                    end = buf.find(b">", start + 1)
                    if start < 0 or end < 0:
                        buf = buf[start:] if start >= 0 else b""
                        if len(buf) > 4096:  # garbage without an end: drop the client
                            return
                        break
                    body = buf[start + 1:end].decode("ascii", "replace").strip()
                    buf = buf[end + 1:]
                    self._command(c, body)
        except OSError:
            return
        finally:
            with self._lock:
                if c in self.clients:
                    self.clients.remove(c)
            c.close()

    def _command(self, c: _Client, body: str) -> None:
        word = body.split(" ", 1)[0]
        if word == "send" and c.raw:
            try:
                msg = parse_send(body)
            except ValueError as e:
                c.send(f"< error {e} >".encode("ascii", "replace"))
                return
            self.frames_from_clients += 1
            self.bus.send(msg)
            text = frame_text(msg)
            with self._lock:
                others = [o for o in self.clients if o is not c]
            for o in others:
                o.send(text)
        elif word == "open":
            name = body.split()[1] if len(body.split()) > 1 else ""
            if name != self.channel:
                c.send(f"< error could not open bus '{name}': this server offers "
                       f"'{self.channel}' >".encode("ascii", "replace"))
            else:
                c.send(b"< ok >")
        elif word == "rawmode":
            c.send(b"< ok >")
            # python-can's client reads the '< ok >' with one recv(): frames sent right
            # behind it would arrive glued to it and fail its handshake check
            time.sleep(0.05)
            c.raw = True
            with self._lock:
                self.clients.append(c)
        elif word == "echo":
            c.send(b"< echo >")
        else:
            c.send(f"< error unsupported command '{word}' (rawmode only) >".encode(
                "ascii", "replace"))

    def _bus_loop(self) -> None:
        """Frames of the simulated drive -> every client in rawmode (batched)."""
        while not self.stop_event.is_set():
            msg = self.bus.recv(0.05)
            if msg is None:
                continue
            batch = [frame_text(msg)]
            while len(batch) < 512 and (m := self.bus.recv(0)) is not None:
                batch.append(frame_text(m))
            data = b"".join(batch)
            with self._lock:
                clients = list(self.clients)
            for c in clients:
                if c.send(data):
                    self.frames_to_clients += len(batch)
                else:
                    with self._lock:
                        if c in self.clients:
                            self.clients.remove(c)
                    c.close()


def serve(folder: Path, motor: str, extractor: str, seed: int, node_id: int, port: int,
          nvm: Path, channel: str = CAN_CHANNEL) -> int:
    """Run the simulated drive and its server until SIGTERM/SIGINT (this process)."""
    import can

    from bench import __version__
    from bench._simdrive import SimDrive

    stop = threading.Event()

    def on_signal(signum: int, frame: Any) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    vchan = f"pmlsm-simserver-{os.getpid()}-vcan"  # no trailing digits (BLF channel names)
    nvm.parent.mkdir(parents=True, exist_ok=True)
    sim = SimDrive(vchan, motor=motor, extractor=extractor, seed=seed, node_id=node_id,
                   realtime=True, nvm_path=nvm)  # boots from the file
    server = None
    bus = None
    try:
        nvm_state = NVM_STATES.get(sim.nvm_state(), "unknown")
        log.warning("simulated drive: motor %s, extractor %s, seed %d, node %d; NVM %s: %s",
                    sim.motor.name, extractor, seed, node_id, nvm, nvm_state)
        bus = can.Bus(interface="virtual", channel=vchan, receive_own_messages=False)
        server = SocketcandServer(bus, port, channel).start()
        sim.start()
        st = ServerState(pid=os.getpid(), host=HOST, port=server.port, channel=channel,
                         motor=motor, extractor=extractor, seed=seed, node_id=node_id,
                         nvm=str(nvm), nvm_state=nvm_state, log=str(folder / LOG_FILE),
                         started=time.time(), bench_version=__version__)
        _write_state(folder, st)
        log.warning("socketcand server on %s:%d, bus '%s' (pid %d)", HOST, server.port,
                    channel, os.getpid())
        while not stop.wait(0.2):
            if sim.error is not None:
                log.error("simulated drive stopped: %s", sim.error)
                return 1
        log.warning("stopping (signal); frames from clients %d, to clients %d",
                    server.frames_from_clients, server.frames_to_clients)
        return 0
    finally:
        cur = read_state(folder)
        if cur is not None and cur.pid == os.getpid():
            with contextlib.suppress(OSError):
                (folder / STATE_FILE).unlink()
        if server is not None:
            server.close()
        sim.close()
        if bus is not None:
            bus.shutdown()


# ---- bench sim start / stop / status ---------------------------------------------------


def nvm_path(folder: Path, motor: str) -> Path:
    """Default NVM file of a simulated drive: one per motor (a block stores the motor's
    parameters, which must not leak into a simulation of another motor)."""
    name = Path(motor).stem if motor.endswith((".toml", ".yaml")) else motor
    safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name)
    return folder / f"nvm_{safe}.bin"


def start(motor: str, extractor: str, seed: int, node_id: int, port: int,
          nvm: str | None = None, timeout_s: float = 30.0,
          say: Any = print) -> ServerState:
    """Start the server in the background and wait until it listens.

    Raises
    ------
    AlreadyRunning
        A server is running already.
    SimServerError
        The process did not come up (its log's last lines).
    """
    folder = state_dir()
    with state_lock(folder, LOCK_FILE):
        return _start_locked(folder, motor, extractor, seed, node_id, port, nvm, timeout_s,
                             say)


def _start_locked(folder: Path, motor: str, extractor: str, seed: int, node_id: int,
                  port: int, nvm: str | None, timeout_s: float, say: Any) -> ServerState:
    st = read_state(folder)
    if st is not None:
        if pid_is_server(st.pid):
            raise AlreadyRunning(f"a simulated drive server is already running (pid {st.pid}, "
                                 f"{st.address}, motor {st.motor}); `bench sim stop` first")
        say(f"bench: removed the stale state file {folder / STATE_FILE} (pid {st.pid} "
            "was not running)")
        with contextlib.suppress(OSError):
            (folder / STATE_FILE).unlink()
    folder.mkdir(parents=True, exist_ok=True)
    nvm_file = Path(nvm) if nvm else nvm_path(folder, motor)
    logf = folder / LOG_FILE
    cmd = [sys.executable, "-m", "bench._simserver", "--state-dir", str(folder),
           "--motor", motor, "--extractor", extractor, "--seed", str(seed),
           "--node-id", str(node_id), "--port", str(port), "--nvm", str(nvm_file.resolve())]
    with open(logf, "ab") as out:
        out.write(f"\n--- {time.strftime('%Y-%m-%d %H:%M:%S')} {' '.join(cmd)}\n".encode())
        out.flush()
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True,
                                close_fds=True)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        st = read_state(folder)
        if st is not None and st.pid == proc.pid:
            return st
        if proc.poll() is not None:
            raise SimServerError(f"the simulated drive server exited with code "
                                 f"{proc.returncode}: {_log_tail(logf)}")
        time.sleep(0.05)
    proc.terminate()
    raise SimServerError(f"the simulated drive server did not start within {timeout_s:g} s "
                         f"({_log_tail(logf)})")


def log_tail(logf: Path, lines: int = 3) -> str:
    """The last lines of a background process's log, as one line ("" when none)."""
    try:
        text = logf.read_text(encoding="utf-8", errors="replace").strip().splitlines()
    except OSError:
        return ""
    tail = [t.strip() for t in text[-lines:] if t.strip() and not t.startswith("---")]
    return " | ".join(tail)


def _log_tail(logf: Path, lines: int = 3) -> str:
    tail = log_tail(logf, lines)
    return f"{tail} (log: {logf})" if tail else f"see {logf}"


def stop(timeout_s: float = 5.0) -> tuple[str, int | None]:
    """Stop the server (SIGTERM, then SIGKILL after ``timeout_s``).

    Returns (what happened, pid): ``"stopped"``, ``"killed"``, ``"stale"`` (state
    file of a dead process removed) or ``"none"``.
    """
    folder = state_dir()
    with state_lock(folder, LOCK_FILE):
        return _stop_locked(folder, timeout_s)


def _stop_locked(folder: Path, timeout_s: float) -> tuple[str, int | None]:
    st = read_state(folder)
    if st is None:
        return "none", None
    if not pid_is_server(st.pid):
        with contextlib.suppress(OSError):
            (folder / STATE_FILE).unlink()
        return "stale", st.pid
    how = stop_process(st.pid, pid_is_server, timeout_s)
    cur = read_state(folder)
    if cur is not None and cur.pid == st.pid:
        with contextlib.suppress(OSError):
            (folder / STATE_FILE).unlink()
    return how, st.pid


def describe(st: ServerState) -> str:
    """Multi-line status of a running server."""
    up = time.time() - st.started
    return (f"simulated drive server: running, pid {st.pid}, up {up:.0f} s\n"
            f"  socketcand: {st.address}, bus '{st.channel}' (connect: --sim-server, or "
            f"--interface socketcand --channel {st.channel} --host {st.host} --port {st.port})\n"
            f"  drive: node {st.node_id}, motor {st.motor}, extractor {st.extractor}, seed "
            f"{st.seed}, paced to the wall clock\n"
            f"  non-volatile memory: {st.nvm} (at start: {st.nvm_state})\n"
            f"  log: {st.log}")


def main(argv: list[str] | None = None) -> int:
    """``python -m bench._simserver``: the server process (started by ``bench sim start``)."""
    ap = argparse.ArgumentParser(prog="python -m bench._simserver",
                                 description="Simulated drive behind a socketcand server "
                                 "on 127.0.0.1 (use `bench sim start`).")
    ap.add_argument("--state-dir", default=None)
    ap.add_argument("--motor", default="paper_salient")
    ap.add_argument("--extractor", default="sogi_adaptive")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--node-id", type=int, default=1)
    ap.add_argument("--port", type=int, default=0)
    ap.add_argument("--nvm", default=None)
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(levelname)s %(message)s")
    folder = Path(a.state_dir) if a.state_dir else state_dir()
    nvm = Path(a.nvm) if a.nvm else nvm_path(folder, a.motor)
    return serve(folder, a.motor, a.extractor, a.seed, a.node_id, a.port, nvm)


if __name__ == "__main__":
    sys.exit(main())
