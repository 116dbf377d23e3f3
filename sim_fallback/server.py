"""The simulated drive as its own process, behind python-can's ``socketcand`` interface.

``bench sim start`` runs this module as a background process: one
:class:`sim_fallback.SimDrive` paced to the wall clock (the simulated
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

The server survives its clients:

* Queues. Each client has its own writer thread and a bounded send queue
  (:data:`CLIENT_QUEUE_BYTES`, 1 MiB, or ``$BENCH_SIM_CLIENT_QUEUE`` bytes at
  ``bench sim start``): the bus and the drive never wait for a client. A
  client that stops reading (a script that only sends, a process stopped with
  Ctrl-Z) fills its queue once the kernel's socket buffers are full, and is
  then dropped: its connection closed, counted and logged with its address and
  why. A client that disconnects is not a drop.
* Refusals. Each ``send`` is checked before it goes anywhere
  (:func:`parse_send`: an id of 1-3 hex digits up to 7FF or 8 up to 1FFFFFFF,
  a dlc 0-8 and exactly that many bytes of 1-2 hex digits): a malformed one is
  answered ``< error ... >``, counted and never reaches the drive or another
  client (the first few per client are logged).
* Stalls. The drive's clock is paced to the wall clock; when the server
  process was stopped (SIGSTOP, a suspended machine) or starved, the drive
  finds itself behind the wall clock and pauses for the lost time instead of
  running it at full speed (:class:`sim_fallback.SimDrive`, ``max_lag_s``):
  its bus stood still too, and a second of a frozen bus run at once would be a
  second without its supervisor's heartbeat (0x8130). Each stall is logged and
  counted.

State (``state_dir()``: ``$BENCH_SIM_DIR``, else ``$XDG_STATE_HOME/pmlsm-bench``,
else ``~/.local/state/pmlsm-bench``): ``simserver.json`` (pid, host, port,
channel, motor, ... written once the server listens, with the counters above
updated while it runs, removed when it stops), ``simserver.log`` (the server's
output) and the non-volatile memory of the simulated drive,
``nvm_<motor>_<hash>.bin`` (CiA 301 0x1010 'save'; read at start, so a saved
configuration survives ``bench sim stop`` / ``start``), keyed by the motor's
file stem and a hash of its parsed parameters (:func:`motor_key`): two motors
of one file name never share a stored configuration. A state file whose
process is gone (SIGKILL, reboot) is *stale*: ``bench sim status`` and
``stop`` say so and remove it; connecting to it fails with exit 3. A state
folder that cannot be one (a regular file on its path, a folder where a state
file must be) is one line naming it (:class:`SetupError`, exit 2; exit 3 when
the system refuses it: permissions, a read-only file system).
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import hashlib
import json
import logging
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
import zlib
from collections import deque
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

log = logging.getLogger("sim_fallback.server")

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


class SetupError(SimServerError):
    """The state folder (or a file in it) or a setting cannot be used: one line naming it
    and what is wrong. ``exit_code`` 2 when the path or setting itself is wrong (a regular
    file where a folder must be, a folder where a state file must be, a malformed
    number: the user's input), 3 when the system refuses it (permissions, a read-only or
    full file system: the environment)."""

    def __init__(self, message: str, exit_code: int) -> None:
        super().__init__(message)
        self.exit_code = exit_code


def state_dir() -> Path:
    """Folder of the state file, the log and the NVM files (created on demand)."""
    env = os.environ.get("BENCH_SIM_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "pmlsm-bench"


def _state_dir_origin() -> str:
    if os.environ.get("BENCH_SIM_DIR"):
        return "BENCH_SIM_DIR"
    return "$XDG_STATE_HOME/pmlsm-bench" if os.environ.get("XDG_STATE_HOME") else \
        "the default ~/.local/state/pmlsm-bench; set BENCH_SIM_DIR to use another"


def check_state_dir(folder: Path | None = None, create: bool = False) -> Path:
    """The state folder, checked (and created with ``create``); raises :class:`SetupError`
    when it cannot be one: a regular file on its path (exit 2), or the system refuses to
    create it (exit 3)."""
    folder = folder or state_dir()
    for p in (folder, *folder.parents):  # the deepest part that exists must be a folder
        if p.exists():
            if not p.is_dir():
                which = "it is" if p == folder else f"{p} is"
                raise SetupError(f"state folder {folder} ({_state_dir_origin()}): {which} "
                                 "not a folder (a regular file)", 2)
            break
    if create:
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise state_error(folder, folder, e) from None
    return folder


def state_error(folder: Path, path: Path, e: OSError) -> SetupError:
    """An OSError on the state folder or on ``path`` in it, as one line: exit 2 for a path
    of the wrong kind, 3 when the system refuses (:class:`SetupError`)."""
    if e.errno == errno.ENOTDIR:
        try:
            check_state_dir(folder)
        except SetupError as se:
            return se
    if e.errno in (errno.ENOTDIR, errno.EISDIR):
        kind = "a folder where a file of the server belongs; remove it" \
            if e.errno == errno.EISDIR else "not a folder"
        return SetupError(f"{path} (state folder {folder}, {_state_dir_origin()}): {kind}", 2)
    return SetupError(f"{path} (state folder {folder}, {_state_dir_origin()}): "
                      f"{e.strerror or e}", 3)


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
    #: bound of each client's send queue (bytes)
    queue_bytes: int = 0
    #: node id of the load machine coupled to the drive's mover (0: none)
    load_node: int = 0
    #: counters the running server updates (SocketcandServer.stats, the drive's stalls)
    stats: dict[str, Any] = field(default_factory=dict)
    #: CRC-32 (zlib) of the drive's running fw_config_t at start, "0x%08x"
    config_crc32: str = ""
    #: fields in which that configuration differs from the motor file's (a stored one)
    config_differs: list[str] = field(default_factory=list)

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


def read_state_file(folder: Path, name: str, build: Any, stale: Any) -> Any:
    """``build(**doc)`` of the JSON state file ``folder/name``; None when there is none;
    ``stale()`` when it is half-written or foreign (its process is then judged dead);
    raises :class:`SetupError` when the folder or file cannot be read at all (not a folder,
    a folder where the file should be, permissions). The server's and the emulated
    board's state files are read with it."""
    f = folder / name
    try:
        return build(**json.loads(f.read_text(encoding="utf-8")))
    except FileNotFoundError:
        return None
    except OSError as e:
        raise state_error(folder, f, e) from None
    except (ValueError, TypeError):  # half-written or foreign: treat as stale
        return stale()


def read_state(folder: Path | None = None) -> ServerState | None:
    """The state file (:func:`read_state_file`): None when there is none, a stale
    placeholder when it is unreadable, :class:`SetupError` when the folder is unusable."""
    return read_state_file(folder or state_dir(), STATE_FILE, ServerState, lambda: ServerState(
        pid=-1, host=HOST, port=0, channel=CAN_CHANNEL, motor="?", extractor="?", seed=0,
        node_id=1, nvm="", nvm_state="", log="", started=0.0, bench_version="?"))


@contextlib.contextmanager
def state_lock(folder: Path, name: str) -> Iterator[None]:
    """One start/stop at a time per state folder and kind of process (an exclusive lock
    on ``folder/name``): two concurrent starts leave one process, never an orphan."""
    import fcntl

    check_state_dir(folder, create=True)
    try:
        f = open(folder / name, "a+")
    except OSError as e:
        raise state_error(folder, folder / name, e) from None
    with f:
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


def remove_state_file(folder: Path, name: str = STATE_FILE) -> bool:
    """Remove a state file: True when it was there and is gone; raises
    :class:`SetupError` when it cannot be removed."""
    try:
        (folder / name).unlink()
    except FileNotFoundError:
        return False
    except OSError as e:
        raise state_error(folder, folder / name, e) from None
    return True


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
    return process_is(pid, b"sim_fallback.server")


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


_HEX_ID = re.compile(r"[0-9A-Fa-f]{1,3}|[0-9A-Fa-f]{8}")
_HEX_BYTE = re.compile(r"[0-9A-Fa-f]{1,2}")


def parse_send(body: str) -> Any:
    """``send ID DLC B0 B1 ...`` (hex) -> can.Message; ValueError (why, one line) when
    malformed: the id is 1-3 hex digits (11-bit, at most 7FF) or 8 (29-bit, at most
    1FFFFFFF), the dlc 0-8, and exactly dlc data bytes of 1-2 hex digits each follow.
    Nothing else (signs, ``0x``, ``_``, other digits) is a frame."""
    import can

    parts = body.split()
    if len(parts) < 3 or parts[0] != "send":
        raise ValueError("expected 'send ID DLC DATA...'")
    ident_s, dlc_s, data_s = parts[1], parts[2], parts[3:]
    if not _HEX_ID.fullmatch(ident_s):
        raise ValueError(f"id '{ident_s}': 1-3 hex digits (11-bit) or 8 (29-bit)")
    ext = len(ident_s) == 8
    ident = int(ident_s, 16)
    if ident > (0x1FFFFFFF if ext else 0x7FF):
        raise ValueError(f"id {ident_s} above {'1FFFFFFF' if ext else '7FF'}")
    if not _HEX_BYTE.fullmatch(dlc_s) or int(dlc_s, 16) > 8:
        raise ValueError(f"dlc '{dlc_s}': 0-8")
    dlc = int(dlc_s, 16)
    if len(data_s) != dlc:
        raise ValueError(f"dlc {dlc} but {len(data_s)} data bytes")
    bad = next((b for b in data_s if not _HEX_BYTE.fullmatch(b)), None)
    if bad is not None:
        raise ValueError(f"data byte '{bad}': 1-2 hex digits")
    return can.Message(arbitration_id=ident, is_extended_id=ext,
                       data=bytes(int(b, 16) for b in data_s), timestamp=time.time())


def _quoted(text: str, limit: int = 60) -> str:
    """A client's text, safe inside a socketcand message and a log line."""
    t = "".join(ch if " " <= ch <= "~" and ch not in "<>" else "?" for ch in text)
    return t if len(t) <= limit else t[:limit] + "..."


class _Client:
    """One TCP client: a reader thread (its commands in: :meth:`SocketcandServer._serve`)
    and a writer thread draining a bounded queue (the bus out), so that a client that
    stops reading blocks its own writer only; the server drops it when its queue would
    exceed ``queue_bytes``.

    ``on_full(client, why)`` is called (outside the client's lock) when :meth:`send`
    finds the queue full.
    """

    def __init__(self, sock: socket.socket, addr: Any, queue_bytes: int,
                 on_full: Any) -> None:
        self.sock = sock
        self.name = f"{addr[0]}:{addr[1]}"
        self.raw = False  # in rawmode: receives the bus
        self.alive = True
        self.dropped = False
        self.refused = 0
        self.queue_bytes = queue_bytes
        self._on_full = on_full
        self._q: deque[bytes] = deque()
        self._pending = 0  # bytes queued or being written
        self._cond = threading.Condition()
        self.writer = threading.Thread(target=self._write_loop, daemon=True,
                                       name=f"simserver-write-{addr[1]}")

    def send(self, data: bytes) -> bool:
        """Queue ``data``, never blocking: False when the client is gone or its queue is
        full (a queue holds at least one item, however large: a batch of frames)."""
        with self._cond:
            if not self.alive:
                return False
            if self._pending and self._pending + len(data) > self.queue_bytes:
                why = (f"not reading: {self._pending} bytes waiting for it, "
                       f"{len(data)} more would exceed its queue of {self.queue_bytes}")
            else:
                self._q.append(data)
                self._pending += len(data)
                self._cond.notify_all()
                return True
        self._on_full(self, why)
        return False

    def flush(self, timeout_s: float) -> bool:
        """Wait until everything queued is written (False: not within ``timeout_s``)."""
        with self._cond:
            return self._cond.wait_for(lambda: not self.alive or not self._pending,
                                       timeout_s) and self.alive

    def _write_loop(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._q or not self.alive)
                if not self.alive:
                    return
                data = b"".join(self._q)
                self._q.clear()
            try:
                self.sock.sendall(data)  # blocks this client's writer only
            except OSError:  # it disconnected, or was dropped (socket shut down)
                self.shutdown()
                return
            with self._cond:
                self._pending -= len(data)
                self._cond.notify_all()

    def shutdown(self) -> None:
        """Stop serving it: queue dropped, both directions shut down (wakes its reader and
        writer; its reader thread closes the socket when both are done)."""
        with self._cond:
            self.alive = False
            self._q.clear()
            self._cond.notify_all()
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)


#: bytes queued for one client at most (``BENCH_SIM_CLIENT_QUEUE`` overrides): beyond the
#: kernel's socket buffers, ~30 s of the idle drive's bus traffic (SYNC and TPDOs, ~35
#: kB/s). A client that has not read them is dropped: it is stopped, hung, or a script
#: that only sends
CLIENT_QUEUE_BYTES = 1 << 20
#: the kernel's send buffer of a client's socket (fixed: not grown by the kernel up to
#: megabytes, which would hold minutes of traffic for a client that does not read before
#: its queue even starts to fill)
SOCKET_SNDBUF = 64 << 10
#: refusals logged per client; the others are counted only
REFUSALS_LOGGED = 3


class SocketcandServer:
    """Bridges a python-can bus (the simulated drive's) to socketcand TCP clients.

    Nothing a client does (stop reading, send garbage) blocks the bus, the drive or the
    other clients: each client has its own writer thread and a bounded queue (a client
    whose queue is full is dropped: counted in :attr:`clients_dropped`, logged with its
    address and why), and each ``send`` is checked (:func:`parse_send`) before it goes
    anywhere (a malformed one is answered ``< error ... >`` and counted in
    :attr:`frames_refused`).

    Parameters
    ----------
    bus : can.BusABC
        The server's own handle on the simulated drive's bus.
    port : int
        TCP port on 127.0.0.1 (0: any free port; see :attr:`port`).
    channel : str
        Bus name clients must ``open``.
    queue_bytes : int
        Bound of each client's send queue (bytes).
    """

    def __init__(self, bus: Any, port: int = 0, channel: str = CAN_CHANNEL,
                 queue_bytes: int = CLIENT_QUEUE_BYTES) -> None:
        self.bus = bus
        self.channel = channel
        self.queue_bytes = int(queue_bytes)
        self.listener = socket.create_server((HOST, port))
        self.port = int(self.listener.getsockname()[1])
        self.clients: list[_Client] = []  # in rawmode: receive the bus
        self._all: set[_Client] = set()  # connected
        self._lock = threading.Lock()
        self.stop_event = threading.Event()
        self.frames_from_clients = 0
        self.frames_to_clients = 0
        self.frames_refused = 0
        self.commands_refused = 0
        self.clients_dropped = 0
        self.last_drop = ""
        self.last_refusal = ""
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
            clients = list(self._all)
            self.clients = []
        for c in clients:
            c.shutdown()
        for t in self._threads:
            t.join(timeout=2.0)

    def stats(self) -> dict[str, Any]:
        """Counters for the state file (``bench sim status``)."""
        with self._lock:
            connected = len(self._all)
        return {"clients_connected": connected, "clients_dropped": self.clients_dropped,
                "last_drop": self.last_drop, "frames_from_clients": self.frames_from_clients,
                "frames_to_clients": self.frames_to_clients,
                "frames_refused": self.frames_refused,
                "commands_refused": self.commands_refused, "last_refusal": self.last_refusal}

    def drop(self, c: _Client, why: str) -> None:
        """Stop serving a client that cannot be served (counted, logged)."""
        with self._lock:
            if c.dropped or not c.alive:
                return
            c.dropped = True
            if c in self.clients:
                self.clients.remove(c)
            self.clients_dropped += 1
            self.last_drop = f"{c.name} at {time.strftime('%H:%M:%S')}: {why}"
        log.warning("dropped client %s: %s", c.name, why)
        c.shutdown()

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
            sock.settimeout(None)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SOCKET_SNDBUF)
            c = _Client(sock, addr, self.queue_bytes, self.drop)
            with self._lock:
                self._all.add(c)
            c.writer.start()
            threading.Thread(target=self._serve, args=(c,), daemon=True,
                             name=f"simserver-client-{addr[1]}").start()

    def _serve(self, c: _Client) -> None:
        """A client's reader thread: the handshake, then its commands; at its end (the
        client left or was dropped) the socket is closed."""
        try:
            if c.send(b"< hi >"):
                self._read_loop(c)
        finally:
            with self._lock:
                self._all.discard(c)
                if c in self.clients:
                    self.clients.remove(c)
            c.shutdown()
            c.writer.join(timeout=2.0)
            with contextlib.suppress(OSError):
                c.sock.close()

    def _read_loop(self, c: _Client) -> None:
        buf = b""
        while not self.stop_event.is_set() and c.alive:
            try:
                data = c.sock.recv(4096)
            except OSError:
                return
            if not data:
                return
            buf += data
            while True:
                start = buf.find(b"<")
                end = buf.find(b">", start + 1)
                if start < 0 or end < 0:
                    buf = buf[start:] if start >= 0 else b""
                    if len(buf) > 4096:
                        self.drop(c, f"{len(buf)} bytes without a command's end '>'")
                        return
                    break
                body = buf[start + 1:end].decode("ascii", "replace").strip()
                buf = buf[end + 1:]
                self._command(c, body)

    def _refuse(self, c: _Client, body: str, why: str, frame: bool) -> None:
        """Answer a bad command ``< error ... >``; counted, the first ones logged."""
        text = f"'{_quoted(body)}': {_quoted(why, 120)}"
        with self._lock:
            if frame:
                self.frames_refused += 1
            else:
                self.commands_refused += 1
            self.last_refusal = f"{c.name} at {time.strftime('%H:%M:%S')}: {text}"
        c.refused += 1
        if c.refused <= REFUSALS_LOGGED:
            log.warning("refused from %s: %s%s", c.name, text,
                        " (further refusals from it are counted, not logged)"
                        if c.refused == REFUSALS_LOGGED else "")
        c.send(f"< error {text} >".encode("ascii", "replace"))

    def _command(self, c: _Client, body: str) -> None:
        word = body.split(" ", 1)[0]
        if word == "send" and c.raw:
            try:
                msg = parse_send(body)
            except ValueError as e:
                self._refuse(c, body, f"bad frame: {e}", frame=True)
                return
            self.bus.send(msg)
            text = frame_text(msg)
            with self._lock:
                self.frames_from_clients += 1
                others = [o for o in self.clients if o is not c]
            for o in others:
                o.send(text)
        elif word == "open":
            name = body.split()[1] if len(body.split()) > 1 else ""
            if name != self.channel:
                self._refuse(c, body, f"could not open bus '{name}': this server offers "
                             f"'{self.channel}'", frame=False)
            else:
                c.send(b"< ok >")
        elif word == "rawmode":
            c.send(b"< ok >")
            # python-can's client reads the '< ok >' with one recv(): frames sent right
            # behind it would arrive glued to it and fail its handshake check
            c.flush(2.0)
            time.sleep(0.05)
            c.raw = True
            with self._lock:
                if c.alive:
                    self.clients.append(c)
        elif word == "echo":
            c.send(b"< echo >")
        else:
            self._refuse(c, body, f"unsupported command '{word}' (rawmode only)",
                         frame=False)

    def _bus_loop(self) -> None:
        """Frames of the simulated drive -> every client in rawmode (batched; queued, so
        this loop never waits for a client)."""
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


def _stall_stats(sim: Any) -> dict[str, Any]:
    return {"stalls": sim.stalls, "stalled_s": round(sim.stalled_s, 3),
            "last_stall_s": round(sim.last_stall_s, 3)}


def _events(stats: dict[str, Any]) -> dict[str, Any]:
    """The counters but the traffic ones (which change with every frame)."""
    return {k: v for k, v in stats.items()
            if k not in ("frames_from_clients", "frames_to_clients")}


class LoadMachineNode:
    """The load machine of the simulated drive server: a CiA 402 node on the same bus
    (``node_id``, by default the drive's + 1), in cyclic synchronous torque mode as a
    rig's load drive is, mechanically coupled to the drive's mover: in OPERATION ENABLED
    its target torque (0x6071, per mille of its rated force K_f i_max_A, which it
    publishes like the drive: 0x2050) is the plant's external force, with the sign of
    a load machine (a positive target pushes forward, i.e. a load of -F); out of it, no
    force. The bench reaches it with ``--load-node`` (``--sim-server`` uses it by
    default) through :class:`bench.CanopenLoad`, exactly as a rig's load drive."""

    def __init__(self, channel: str, node_id: int, sim: Any) -> None:
        import can

        from protocols.generated import od_names as od
        from protocols.units import force_constant_N_per_A

        from ._motors import fw_config
        from .standin import FakeDrive402

        c = fw_config(sim.motor)  # the load machine is sized like the drive's motor
        self.rated_N = force_constant_N_per_A(c.psi_f_Wb, c.pole_pitch_m) * c.i_max_A
        self.sim = sim
        self.force_N = 0.0
        self.node = FakeDrive402(can.Bus(interface="virtual", channel=channel,
                                         receive_own_messages=False), node_id)
        for e, v in ((od.DRIVE_CONFIGURATION__I_MAX_A, c.i_max_A),
                     (od.DRIVE_CONFIGURATION__PSI_F_WB, c.psi_f_Wb),
                     (od.DRIVE_CONFIGURATION__POLE_PITCH_M, c.pole_pitch_m)):
            self.node._set(e, float(v))  # what the bench reads for the rated force
        self.node.on_change = self._apply
        # no time of its own on every SYNC (the stand-in's TPDO4): the drive's is the bus's
        self.node.network.unsubscribe(0x080)

    def _apply(self) -> None:
        fake = self.node
        pm = fake.target_torque
        force = pm / 1000.0 * self.rated_N if fake.state == "OPERATION ENABLED" else 0.0
        if force != self.force_N:
            self.force_N = force
            self.sim.set_load_N(-force)  # a load opposes +x: the machine's +F is a load -F

    def close(self) -> None:
        self.node.close()


def serve(folder: Path, motor: str, extractor: str, seed: int, node_id: int, port: int,
          nvm: Path, channel: str = CAN_CHANNEL,
          queue_bytes: int = CLIENT_QUEUE_BYTES) -> int:
    """Run the simulated drive and its server until SIGTERM/SIGINT (this process)."""
    import can

    from protocols import __version__

    from ._candrive import SimDrive

    stop = threading.Event()

    def on_signal(signum: int, frame: Any) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    vchan = f"pmlsm-simserver-{os.getpid()}-vcan"  # no trailing digits (BLF channel names)
    nvm.parent.mkdir(parents=True, exist_ok=True)
    sim = SimDrive(vchan, motor=motor, extractor=extractor, seed=seed, node_id=node_id,
                   realtime=True, nvm_path=nvm,  # boots from the file
                   max_lag_s=SimDrive.MAX_LAG_S)  # a stopped process pauses its clock
    server = None
    bus = None
    load = None
    try:
        nvm_state = NVM_STATES.get(sim.nvm_state(), "unknown")
        log.warning("simulated drive: motor %s, extractor %s, seed %d, node %d; NVM %s: %s",
                    sim.motor.name, extractor, seed, node_id, nvm, nvm_state)
        running = sim.config()
        crc = f"0x{zlib.crc32(bytes(running)):08x}"
        mine, given = running.as_dict(), sim.sim.cfg.as_dict()
        differs = sorted(k for k in mine if mine[k] != given[k])
        log.warning("configuration: fw_config_t CRC-32 %s%s", crc, (
            f"; booted from the stored one, which differs from the motor file's in: "
            f"{', '.join(differs)}") if differs else " (the motor file's, as every "
            "simulated drive of this motor is configured: sim_fallback.drive_params)")
        bus = can.Bus(interface="virtual", channel=vchan, receive_own_messages=False)
        load = LoadMachineNode(vchan, node_id + 1, sim)  # coupled to the drive's mover
        server = SocketcandServer(bus, port, channel, queue_bytes).start()
        sim.start()
        st = ServerState(pid=os.getpid(), host=HOST, port=server.port, channel=channel,
                         motor=motor, extractor=extractor, seed=seed, node_id=node_id,
                         nvm=str(nvm), nvm_state=nvm_state, log=str(folder / LOG_FILE),
                         started=time.time(), bench_version=__version__,
                         queue_bytes=server.queue_bytes, load_node=node_id + 1,
                         config_crc32=crc, config_differs=differs,
                         stats={**server.stats(), **_stall_stats(sim)})
        _write_state(folder, st)
        log.warning("socketcand server on %s:%d, bus '%s' (pid %d), client queues of %d "
                    "bytes", HOST, server.port, channel, os.getpid(), server.queue_bytes)
        stalls, written, unwritable = 0, time.monotonic(), False
        while not stop.wait(0.2):
            if sim.error is not None:
                log.error("simulated drive stopped: %s", sim.error)
                return 1
            if sim.stalls != stalls:
                n, stalls = sim.stalls - stalls, sim.stalls
                log.warning("drive clock paused %.3f s%s: the server process was stopped or "
                            "starved (%d stalls, %.3f s in all); the drive's time resumed "
                            "where it stopped", sim.last_stall_s,
                            f" (and {n - 1} more)" if n > 1 else "", stalls, sim.stalled_s)
            # for `bench sim status`: at once when a client comes, goes, is dropped or
            # refused, or the clock stalled; the traffic counters every 5 s at most
            stats = {**server.stats(), **_stall_stats(sim)}
            if _events(stats) != _events(st.stats) or (
                    stats != st.stats and time.monotonic() - written > 5.0):
                st.stats, written = stats, time.monotonic()
                try:
                    _write_state(folder, st)
                except OSError as e:  # the folder went away: serve on, say it once
                    if not unwritable:
                        log.warning("cannot update %s: %s", folder / STATE_FILE, e)
                    unwritable = True
        log.warning("stopping (signal); frames from clients %d, to clients %d, refused %d; "
                    "clients dropped %d; drive clock stalls %d (%.3f s)",
                    server.frames_from_clients, server.frames_to_clients,
                    server.frames_refused, server.clients_dropped, sim.stalls, sim.stalled_s)
        return 0
    finally:
        with contextlib.suppress(SimServerError):
            cur = read_state(folder)
            if cur is not None and cur.pid == os.getpid():
                remove_state_file(folder)
        if server is not None:
            server.close()
        if load is not None:
            load.close()
        sim.close()
        if bus is not None:
            bus.shutdown()


# ---- bench sim start / stop / status ---------------------------------------------------


def motor_key(motor: str) -> str:
    """What a simulated drive's NVM file is named after: the motor's readable name (file
    stem) and a short hash of its parameters as the motor file gives them (parsed: every
    section but the name and description; not the values the simulator derives from
    them, so that a new bench version does not re-key a motor), so that two motors of one
    file name (every `bench identify` writes a motor.toml) never share a stored
    configuration, and an edited motor starts from the defaults."""
    from ._motors import load_motor

    m = load_motor(motor)
    doc = {sec: body for sec, body in m.raw.items() if sec != "motor"}
    doc["parameterization"] = m.parameterization
    digest = hashlib.sha256(json.dumps(doc, sort_keys=True, default=repr).encode()).hexdigest()
    return f"{_motor_stem(motor)}_{digest[:10]}"


def _motor_stem(motor: str) -> str:
    """A motor's name (a file's stem) as a safe file name part."""
    name = Path(motor).stem if motor.endswith((".toml", ".yaml")) else motor
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name)


def nvm_path(folder: Path, motor: str) -> Path:
    """Default NVM file of a simulated drive: one per motor, by content
    (:func:`motor_key`): a block stores the motor's parameters, which must not leak into
    a simulation of another motor."""
    return folder / f"nvm_{motor_key(motor)}.bin"


def client_queue_bytes() -> int:
    """Bound of each client's send queue: ``BENCH_SIM_CLIENT_QUEUE`` (bytes, >= 4096), else
    :data:`CLIENT_QUEUE_BYTES`; raises :class:`SetupError` (exit 2) when malformed."""
    text = os.environ.get("BENCH_SIM_CLIENT_QUEUE", "").strip()
    if not text:
        return CLIENT_QUEUE_BYTES
    try:
        n = int(text)
    except ValueError:
        n = -1
    if n < 4096:
        raise SetupError(f"BENCH_SIM_CLIENT_QUEUE={text}: bytes queued per client, an "
                         "integer >= 4096", 2)
    return n


def start(motor: str, extractor: str, seed: int, node_id: int, port: int,
          nvm: str | None = None, timeout_s: float = 30.0,
          say: Any = print) -> ServerState:
    """Start the server in the background and wait until it listens.

    Raises
    ------
    AlreadyRunning
        A server is running already.
    SetupError
        The state folder cannot be used, or a bad BENCH_SIM_CLIENT_QUEUE.
    SimServerError
        The process did not come up (its log's last lines).
    """
    folder = state_dir()
    queue = client_queue_bytes()
    with state_lock(folder, LOCK_FILE):
        return _start_locked(folder, motor, extractor, seed, node_id, port, nvm, queue,
                             timeout_s, say)


def _start_locked(folder: Path, motor: str, extractor: str, seed: int, node_id: int,
                  port: int, nvm: str | None, queue: int, timeout_s: float,
                  say: Any) -> ServerState:
    st = read_state(folder)
    if st is not None:
        if pid_is_server(st.pid):
            raise AlreadyRunning(f"a simulated drive server is already running (pid {st.pid}, "
                                 f"{st.address}, motor {st.motor}); `bench sim stop` first")
        if remove_state_file(folder):
            say(f"bench: removed the stale state file {folder / STATE_FILE} (pid {st.pid} "
                "was not running)")
    nvm_file = Path(nvm) if nvm else nvm_path(folder, motor)
    _note_unkeyed_nvm(folder, motor, nvm_file, say)
    logf = folder / LOG_FILE
    cmd = [sys.executable, "-m", "sim_fallback.server", "--state-dir", str(folder),
           "--motor", motor, "--extractor", extractor, "--seed", str(seed),
           "--node-id", str(node_id), "--port", str(port), "--nvm", str(nvm_file.resolve()),
           "--client-queue-bytes", str(queue)]
    try:
        out = open(logf, "ab")
    except OSError as e:
        raise state_error(folder, logf, e) from None
    with out:
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


def _note_unkeyed_nvm(folder: Path, motor: str, nvm_file: Path, say: Any) -> None:
    """An NVM file named after the motor file alone (before the NVM was keyed by the
    motor's content) is not loaded: it may hold another motor's configuration. Say so,
    with how to keep it, while this motor has no file of its own."""
    old = folder / f"nvm_{_motor_stem(motor)}.bin"
    if old.is_file() and not nvm_file.exists() and nvm_file.parent == folder:
        say(f"bench: {old} (named after the motor file only, perhaps another motor's "
            f"configuration) is not loaded; this motor's is {nvm_file.name}: rename it to "
            "keep it")


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
    file of a dead process removed) or ``"none"``. Raises :class:`SetupError` when the
    state folder cannot be used.
    """
    folder = state_dir()
    with state_lock(folder, LOCK_FILE):
        return _stop_locked(folder, timeout_s)


def _stop_locked(folder: Path, timeout_s: float) -> tuple[str, int | None]:
    st = read_state(folder)
    if st is None:
        return "none", None
    if not pid_is_server(st.pid):
        return ("stale" if remove_state_file(folder) else "none"), st.pid
    how = stop_process(st.pid, pid_is_server, timeout_s)
    cur = read_state(folder)
    if cur is not None and cur.pid == st.pid:
        remove_state_file(folder)
    return how, st.pid


def describe(st: ServerState) -> str:
    """Multi-line status of a running server (its counters as of its last update of the
    state file: at once after an event, the traffic within 5 s)."""
    up = time.time() - st.started
    s = st.stats
    lines = [f"simulated drive server: running, pid {st.pid}, up {up:.0f} s",
             f"  socketcand: {st.address}, bus '{st.channel}' (connect: --sim-server, or "
             f"--interface socketcand --channel {st.channel} --host {st.host} --port "
             f"{st.port})",
             f"  drive: node {st.node_id}, motor {st.motor}, extractor {st.extractor}, seed "
             f"{st.seed}, paced to the wall clock",
             f"  non-volatile memory: {st.nvm} (keyed by the motor's name and parameters; "
             f"at start: {st.nvm_state})"]
    if st.config_crc32:
        lines.append(f"  configuration: fw_config_t CRC-32 {st.config_crc32}" + (
            f", booted from the stored one (differs from the motor file in "
            f"{', '.join(st.config_differs)})" if st.config_differs else
            ", the motor file's (as run_scenario and bench run --sim configure it)"))
    if st.load_node:
        lines.append(f"  load machine: node {st.load_node}, CiA 402 torque mode, coupled to "
                     "the drive's mover (--load-node; --sim-server uses it by default)")
    if s:
        drop = f" (last: {s['last_drop']})" if s.get("last_drop") else ""
        lines.append(f"  clients: {s.get('clients_connected', 0)} connected, "
                     f"{s.get('clients_dropped', 0)} dropped{drop}; a client that does not "
                     f"read is dropped after {st.queue_bytes} bytes queued for it")
        refused = f" (last: {s['last_refusal']})" if s.get("last_refusal") else ""
        lines.append(f"  frames: {s.get('frames_from_clients', 0)} from clients, "
                     f"{s.get('frames_to_clients', 0)} to clients, "
                     f"{s.get('frames_refused', 0)} refused (malformed), "
                     f"{s.get('commands_refused', 0)} other commands refused{refused}")
        n = s.get("stalls", 0)
        lines.append("  drive clock: " + (
            f"paused {n} time{'s' if n != 1 else ''}, {s.get('stalled_s', 0.0):.3f} s in all "
            f"(last {s.get('last_stall_s', 0.0):.3f} s): the server process was stopped or "
            "starved, and the drive's time with it" if n else
            "never paused"))
    lines.append(f"  log: {st.log}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """``python -m sim_fallback.server``: the server process (started by ``bench sim start``)."""
    ap = argparse.ArgumentParser(prog="python -m sim_fallback.server",
                                 description="Simulated drive behind a socketcand server "
                                 "on 127.0.0.1 (use `bench sim start`).")
    ap.add_argument("--state-dir", default=None)
    ap.add_argument("--motor", default="paper_salient")
    ap.add_argument("--extractor", default="sogi_adaptive")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--node-id", type=int, default=1)
    ap.add_argument("--port", type=int, default=0)
    ap.add_argument("--nvm", default=None)
    ap.add_argument("--client-queue-bytes", type=int, default=CLIENT_QUEUE_BYTES)
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(levelname)s %(message)s")
    folder = Path(a.state_dir) if a.state_dir else state_dir()
    nvm = Path(a.nvm) if a.nvm else nvm_path(folder, a.motor)
    return serve(folder, a.motor, a.extractor, a.seed, a.node_id, a.port, nvm,
                 queue_bytes=max(4096, a.client_queue_bytes))


if __name__ == "__main__":
    sys.exit(main())
