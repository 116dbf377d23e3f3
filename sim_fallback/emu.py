"""The emulated board: the drive's firmware image on QEMU, reached as a rig is.

``bench emu start`` boots the board port ``firmware_c/boards/mps2_an386`` (the whole
drive application on an emulated Cortex-M4F with the simulator's plant compiled in as
its virtual motor, docs/boards.md) in ``qemu-system-arm``, bound to 127.0.0.1 only:

* its CAN controller is a serial-line CAN adapter on UART0: python-can's ``slcan``
  interface over ``socket://127.0.0.1:<can port>`` (``--emu``, or ``--interface slcan
  --channel socket://127.0.0.1:<can port>``);
* its serial telemetry link is UART1: ``--serial socket://127.0.0.1:<serial port>``;
* its virtual load machine (test equipment of the emulated rig, not part of the drive)
  is UART2: text lines ``load <N>``, ``ref_fault <0|1>``, ``status``
  (:class:`EmuLoad`, used by ``--emu`` runs for load steps).

What the board's "hardware" is on this power-up (motor, initial position, noise seed,
reference scale, factory configuration, node id, the flash page's backing file) is the
boot block :func:`sim_fallback.emu_boot_blob` writes and QEMU loads before the first
instruction. QEMU runs with ``-icount shift=0,sleep=off``: the virtual clock is the
instruction count, so the board runs paced by its own virtual clock, deterministic for
the same inputs, at a fraction of real time (``bench emu status`` says how much); the
bench paces every run by the drive's clock (:class:`bench._clock.DriveClock`), so
sequence times mean drive time on the emulated board as on a rig.

State (``state_dir()``, shared with ``bench sim``): ``emu.json`` (pid, ports, motor,
... written once QEMU listens, removed when it stops), ``emu.log`` (QEMU's and the
board's console), ``emu_boot.bin`` and the flash page ``emu_nvm_<motor>_<hash>.bin``, which
survives ``bench emu stop`` / ``start`` (``bench config save --emu``). One CAN client
at a time, as with a USB-CAN adapter.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import subprocess
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from .server import (
    HOST,
    log_tail,
    motor_key,
    process_is,
    read_state_file,
    state_dir,
    state_lock,
    stop_process,
    write_state_file,
)

STATE_FILE = "emu.json"
LOG_FILE = "emu.log"
BOOT_FILE = "emu_boot.bin"
LOCK_FILE = "emu.lock"
BOARD = "mps2_an386"
IMAGE_NAME = f"pmlsm_{BOARD}.elf"
ROOT = Path(__file__).resolve().parent.parent


class EmuError(RuntimeError):
    """No usable emulated board (none, stale, QEMU missing or refusing); exit 3."""


class EmuRefused(EmuError):
    """A motor or plant the emulated board cannot run (the user's choice); exit 2."""

    exit_code = 2


class AlreadyRunning(EmuError):
    """``start`` while one runs: the user's mistake (exit 2), nothing started."""


@dataclass
class EmuState:
    """Contents of ``emu.json``."""

    pid: int
    host: str
    can_port: int
    serial_port: int
    load_port: int
    motor: str
    plant: str
    extractor: str
    seed: int
    node_id: int
    x0_m: float
    ref_sensor: bool
    image: str
    nvm: str
    log: str
    started: float
    bench_version: str

    # ---- how the bench reaches it (bench._session.connect) ----------------------------
    def bus_config(self) -> dict[str, Any]:
        """python-can arguments that reach its CAN adapter (no 2 s wait after opening:
        it is a socket, not a USB adapter that resets)."""
        return {"interface": "slcan", "channel": f"socket://{self.host}:{self.can_port}",
                "sleep_after_open": 0}

    def serial_url(self) -> str:
        return f"socket://{self.host}:{self.serial_port}"

    def load_url(self) -> str:
        return f"{self.host}:{self.load_port}"

    def load_device(self) -> EmuLoad:
        return EmuLoad(self.host, self.load_port)

    def what(self) -> str:
        other = f", virtual motor {self.plant}" if self.plant != self.motor else ""
        return (f"emulated board {BOARD} in QEMU pid {self.pid}, motor {self.motor}{other}, "
                f"seed {self.seed}")

    def connect_line(self) -> str:
        return (f"--interface slcan --channel socket://{self.host}:{self.can_port} "
                f"--serial socket://{self.host}:{self.serial_port}")


# ---- the virtual load machine ---------------------------------------------------------


class EmuLoad:
    """The emulated rig's load machine (UART2 of the board): a load force on the
    virtual motor, applied when the line arrives (drive time), positive opposes +x."""

    name = "emulated"

    def __init__(self, host: str, port: int, timeout_s: float = 2.0) -> None:
        self.addr = (host, port)
        self.timeout_s = timeout_s
        self._sock: socket.socket | None = None
        self._buf = b""

    def _conn(self) -> socket.socket:
        if self._sock is None:
            try:
                self._sock = socket.create_connection(self.addr, timeout=self.timeout_s)
            except OSError as e:
                raise EmuError(f"virtual load machine {self.addr[0]}:{self.addr[1]}: "
                               f"{e.strerror or e}") from None
        return self._sock

    def command(self, line: str) -> str:
        """Send one line, return the board's answer (``ok ...``); raises on ``err``."""
        s = self._conn()
        try:
            s.sendall(line.encode("ascii") + b"\n")
            deadline = time.monotonic() + self.timeout_s
            while b"\n" not in self._buf:
                s.settimeout(max(0.01, deadline - time.monotonic()))
                chunk = s.recv(256)
                if not chunk:
                    raise EmuError("virtual load machine: the emulated board closed the link")
                self._buf += chunk
        except (OSError, TimeoutError) as e:
            self.close()
            raise EmuError(f"virtual load machine: {line!r}: {e}") from None
        reply, _, self._buf = self._buf.partition(b"\n")
        text = reply.decode("ascii", "replace").strip()
        if not text.startswith("ok"):
            raise EmuError(f"virtual load machine refused {line!r}: {text}")
        return text

    def enable(self) -> None:
        pass

    def disable(self) -> None:
        with contextlib.suppress(EmuError):
            self.set_force_N(0.0)

    def set_force_N(self, force_N: float) -> None:
        self.command(f"load {float(force_N):.9g}")

    def ramp_force_N(self, force_N: float, duration_s: float) -> bool:
        return False  # the runner ramps in steps

    def status(self) -> dict[str, float]:
        """``status``: the board's period count, load, scale fault, overruns."""
        out: dict[str, float] = {}
        for tok in self.command("status").split()[2:]:
            k, _, v = tok.partition("=")
            with contextlib.suppress(ValueError):
                out[k] = float(v)
        return out

    def close(self) -> None:
        if self._sock is not None:
            with contextlib.suppress(OSError):
                self._sock.close()
            self._sock = None


# ---- the image and QEMU ---------------------------------------------------------------


def find_image(explicit: str | None = None) -> Path:
    """The emulated board's firmware image: ``explicit``, ``$PMLSM_EMU_IMAGE``, the one
    installed with the package (built when arm-none-eabi-gcc was there at install), or
    a build tree's. Raises :class:`EmuError` with how to get one."""
    cands: list[Path] = []
    if explicit:
        p = Path(explicit)
        if not p.is_file():
            raise EmuError(f"--image {explicit}: no such file")
        return p
    env = os.environ.get("PMLSM_EMU_IMAGE")
    if env:
        if not Path(env).is_file():
            raise EmuError(f"PMLSM_EMU_IMAGE={env}: no such file")
        return Path(env)
    import sim_fallback

    cands.append(Path(sim_fallback.__file__).parent / "emu" / IMAGE_NAME)
    sub = Path("emu-image") / "firmware_c" / "boards" / BOARD / IMAGE_NAME
    bd = os.environ.get("PMLSM_BUILD_DIR")
    if bd:
        cands.append(Path(bd) / sub)
    cands += sorted((ROOT / "build").glob(f"*/{sub}"), key=lambda p: -p.stat().st_mtime)
    for c in cands:
        if c.is_file():
            return c
    raise EmuError(f"the emulated board's image ({IMAGE_NAME}) is not installed: install "
                   "arm-none-eabi-gcc (Debian: apt-get install gcc-arm-none-eabi "
                   "libnewlib-arm-none-eabi) and reinstall the bench, or build it (cmake "
                   "-DPMLSM_TARGET_CM4=ON -DPMLSM_BOARD=mps2_an386 with "
                   "firmware_c/cmake/arm-none-eabi.cmake) and give --image PATH")


def qemu_binary() -> str:
    q = shutil.which("qemu-system-arm")
    if q is None:
        raise EmuError("qemu-system-arm not found: install it (Debian/Ubuntu: apt-get install "
                       "qemu-system-arm)")
    return q


def qemu_command(image: Path, boot: Path, ports: tuple[int, int, int],
                 qemu: str = "qemu-system-arm") -> list[str]:
    """The QEMU command line of the emulated board (docs/boards.md)."""
    cmd = [qemu, "-M", "mps2-an386", "-nographic", "-monitor", "none",
           "-icount", "shift=0,sleep=off",
           "-semihosting-config", "enable=on,target=native",
           "-kernel", str(image), "-device", f"loader,file={boot},addr=0x21000000"]
    for p in ports:  # UART0 CAN adapter, UART1 serial telemetry, UART2 virtual load machine
        cmd += ["-serial", f"tcp:{HOST}:{p},server=on,wait=off,nodelay=on"]
    return cmd


def free_ports(n: int) -> list[int]:
    """n free TCP ports on 127.0.0.1 (bound and released: free at the time of asking)."""
    socks = []
    try:
        for _ in range(n):
            s = socket.socket()
            s.bind((HOST, 0))
            socks.append(s)
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def _listening(port: int) -> bool:
    """Whether QEMU listens on ``port`` (a connection that is accepted and closed)."""
    try:
        with socket.create_connection((HOST, port), timeout=0.2):
            return True
    except OSError:
        return False


# ---- state --------------------------------------------------------------------------


def read_state(folder: Path | None = None) -> EmuState | None:
    """The state file (the server's :func:`read_state_file`): None when there is none, a
    stale placeholder when it is half-written or foreign, the state folder's
    :class:`SetupError` (exit 2 or 3) when the folder or file cannot be read at all."""
    return read_state_file(folder or state_dir(), STATE_FILE, EmuState, lambda: EmuState(
        pid=-1, host=HOST, can_port=0, serial_port=0, load_port=0, motor="?", plant="?",
        extractor="?", seed=0, node_id=1, x0_m=0.0, ref_sensor=False, image="", nvm="",
        log="", started=0.0, bench_version="?"))


def _write_state(folder: Path, st: EmuState) -> None:
    write_state_file(folder, STATE_FILE, asdict(st))


def pid_is_emu(pid: int, folder: Path | None = None) -> bool:
    """Whether ``pid`` is alive and is this state folder's QEMU (not a reused pid)."""
    boot = str((folder or state_dir()) / BOOT_FILE).encode()
    return process_is(pid, b"qemu-system-arm", boot)


def check_running(folder: Path | None = None) -> EmuState:
    """The running board's state; raises :class:`EmuError` with a one-line reason."""
    folder = folder or state_dir()
    st = read_state(folder)
    if st is None:
        raise EmuError(f"no emulated board running (no {folder / STATE_FILE}); start one "
                       "with `bench emu start`")
    if not pid_is_emu(st.pid, folder):
        raise EmuError(f"stale state file {folder / STATE_FILE}: the emulated board (QEMU pid "
                       f"{st.pid}) is not running{_exit_reason(folder)}; `bench emu start` "
                       "starts a new one")
    return st


def _exit_reason(folder: Path) -> str:
    tail = log_tail(folder / LOG_FILE, 2)
    return f" (its log: {tail})" if tail else ""


def nvm_file(folder: Path, motor: str) -> Path:
    """The emulated board's flash page for a motor: keyed by the motor's content
    (:func:`sim_fallback.server.motor_key`), as the simulated drive server's NVM, so two
    motor files of one name (every `bench identify` writes a motor.toml) never share a
    stored configuration."""
    return folder / f"emu_nvm_{motor_key(motor)}.bin"


def start(motor: str = "paper_salient", extractor: str = "sogi_adaptive", seed: int = 0,
          node_id: int = 1, x0_m: float = 0.0, plant_motor: str | None = None,
          ref_sensor: bool = True, image: str | None = None, timeout_s: float = 20.0,
          say: Any = print) -> EmuState:
    """Boot the emulated board in the background and wait until it listens.

    Raises
    ------
    AlreadyRunning
        A board runs already in this state folder.
    EmuError
        No image, no QEMU, or QEMU exited (the board's own line from its log, e.g. a
        refused boot block).
    """
    from protocols import __version__

    from ._emu_blob import write_emu_boot_blob

    folder = state_dir()
    with state_lock(folder, LOCK_FILE):
        st = read_state(folder)
        if st is not None:
            if pid_is_emu(st.pid, folder):
                raise AlreadyRunning(f"an emulated board is already running (QEMU pid "
                                     f"{st.pid}, motor {st.motor}); `bench emu stop` first")
            say(f"bench: removed the stale state file {folder / STATE_FILE} (pid {st.pid} "
                "was not running)")
            with contextlib.suppress(OSError):
                (folder / STATE_FILE).unlink()
        img = find_image(image)
        qemu = qemu_binary()
        plant: dict[str, Any] | None = None
        if plant_motor and plant_motor != motor:
            from sim_fallback._motors import machine_params

            from ._motors import load_motor

            plant = machine_params(load_motor(plant_motor))
        if not ref_sensor:
            plant = {**(plant or {}), "ref_res_m": 0.0}
        nvm = nvm_file(folder, motor)
        boot = folder / BOOT_FILE
        try:
            write_emu_boot_blob(boot, motor=motor, extractor=extractor, seed=seed,
                                x0_m=x0_m, node_id=node_id, nvm_path=nvm.name, plant=plant)
        except ValueError as e:  # a motor or plant the emulated board cannot run
            raise EmuRefused(str(e)) from None
        ports = free_ports(3)
        logf = folder / LOG_FILE
        cmd = qemu_command(img, boot, (ports[0], ports[1], ports[2]), qemu)
        with open(logf, "ab") as out:
            out.write(f"\n--- {time.strftime('%Y-%m-%d %H:%M:%S')} {' '.join(cmd)}\n".encode())
            out.flush()
            proc = subprocess.Popen(cmd, cwd=folder, stdin=subprocess.DEVNULL, stdout=out,
                                    stderr=subprocess.STDOUT, start_new_session=True,
                                    close_fds=True)
        deadline = time.monotonic() + timeout_s
        while True:
            if proc.poll() is not None:
                raise EmuError(f"the emulated board exited with code {proc.returncode}: "
                               f"{log_tail(logf) or 'no output'} (log: {logf})")
            if all(_listening(p) for p in ports[1:]):  # not the CAN port: one client there
                break
            if time.monotonic() > deadline:
                proc.kill()
                raise EmuError(f"QEMU did not listen within {timeout_s:g} s (log: {logf})")
            time.sleep(0.05)
        st = EmuState(pid=proc.pid, host=HOST, can_port=ports[0], serial_port=ports[1],
                      load_port=ports[2], motor=motor, plant=plant_motor or motor,
                      extractor=extractor, seed=seed, node_id=node_id, x0_m=x0_m,
                      ref_sensor=ref_sensor, image=str(img), nvm=str(nvm), log=str(logf),
                      started=time.time(), bench_version=__version__)
        _write_state(folder, st)
        return st


def stop(timeout_s: float = 5.0) -> tuple[str, int | None]:
    """Stop the board (SIGTERM, SIGKILL after ``timeout_s``): ``("stopped" | "killed" |
    "stale" | "none", pid)``."""
    folder = state_dir()
    with state_lock(folder, LOCK_FILE):
        st = read_state(folder)
        if st is None:
            return "none", None
        if not pid_is_emu(st.pid, folder):
            with contextlib.suppress(OSError):
                (folder / STATE_FILE).unlink()
            return "stale", st.pid
        how = stop_process(st.pid, lambda pid: pid_is_emu(pid, folder), timeout_s)
        with contextlib.suppress(OSError):
            (folder / STATE_FILE).unlink()
        return how, st.pid


def speed(st: EmuState, window_s: float = 1.0) -> float | None:
    """Drive seconds per wall second now (the board's period count over ``window_s``),
    None when the load link does not answer."""
    ld = st.load_device()
    try:
        a = ld.status()
        t0 = time.monotonic()
        time.sleep(window_s)
        b = ld.status()
        t1 = time.monotonic()
    except EmuError:
        return None
    finally:
        ld.close()
    from ._motors import load_motor

    f = float(load_motor(st.plant).plant["f_pwm_Hz"])
    return (b.get("periods", 0.0) - a.get("periods", 0.0)) / f / (t1 - t0)


def describe(st: EmuState, measure: bool = False) -> str:
    """Multi-line status of a running board; the connect line that works."""
    up = time.time() - st.started
    rate = speed(st) if measure else None
    pace = (f"{rate:.2f} drive seconds per wall second" if rate is not None else
            "paced by its own virtual clock (bench emu status measures its speed)")
    return (f"emulated board: running, QEMU pid {st.pid}, up {up:.0f} s, {pace}\n"
            f"  connect: --emu   (or {st.connect_line()})\n"
            f"  CAN (slcan) {st.host}:{st.can_port}, serial telemetry {st.host}:"
            f"{st.serial_port}, virtual load machine {st.host}:{st.load_port}\n"
            f"  drive: node {st.node_id}, motor {st.motor}, extractor {st.extractor}, seed "
            f"{st.seed}; virtual motor {st.plant}, x0 {st.x0_m:g} m, reference scale "
            f"{'fitted' if st.ref_sensor else 'none'}\n"
            f"  image: {st.image}\n  flash page: {st.nvm}\n  log: {st.log}")

