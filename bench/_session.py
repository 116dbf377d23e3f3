"""Connecting to a drive (hardware or the simulated drive) and running sequences.

:func:`connect` returns a :class:`Connection`: a python-can bus, a canopen
network with the drive (:class:`bench.Drive`), the load device, the clock and,
for the simulated drive, the :class:`bench.SimDrive` behind the bus. The bench
code that follows is identical for both.

Connection rules
    ``--sim``: the simulated drive. Else a bus from ``--interface/--channel/
    --bitrate`` or python-can's configuration (``~/.canrc``, ``CAN_INTERFACE``
    ...); if none is configured, the bus cannot be opened or the drive does not
    answer, the bench falls back to the simulated drive and says so on stderr.
    ``--serial URL`` (pyserial URL, e.g. ``/dev/ttyUSB0``, ``socket://host:port``,
    ``loop://``) adds the drive's serial telemetry link; telemetry sequence
    numbers give the lost-frame count. The simulated drive's UART is read the
    same way (in-process byte pipe).
"""

from __future__ import annotations

import contextlib
import logging
import sys
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import can
import canopen
import numpy as np

from bench._drive import Drive
from bench._load import CanopenLoad, LoadDevice, NoLoad
from bench._logging import RunLogger, run_dir_for
from bench._report import make_plots, summary, write_html, write_junit, write_summary_json
from bench._runner import InterruptGuard, Runner, RunResult
from bench._sequence import Sequence
from bench._units import WIRE_UNITS, MotorUnits, motor_units, units_of, wire_unit
from protocols.generated import od_names as od

log = logging.getLogger("bench.session")

#: the drive's consumer heartbeat entry that watches the bench
HB_WATCH = od.CONSUMER_HEARTBEAT_TIME__CONSUMER_HEARTBEAT_TIME_1

# TPDO-mapped objects -> (signal name, SI unit, wire-to-SI factor; None for "per mille of
# the rated force"), the units from od.yaml (bench._units.wire_unit)
_PER_MILLE = WIRE_UNITS["per mille"][1]
_PDO_SIGNALS: dict[tuple[int, int], tuple[str, str, float | None]] = {
    (e.index, e.sub): (name, *(("N", None) if e.unit == "per mille" else wire_unit(e)))
    for e, name in (
        (od.STATUSWORD, "statusword"),
        (od.MODES_OF_OPERATION_DISPLAY, "mode_display"),
        (od.POSITION_ACTUAL_VALUE, "pos_hat_m"),
        (od.VELOCITY_ACTUAL_VALUE, "speed_hat_mps"),
        (od.TORQUE_ACTUAL_VALUE, "force_hat_N"),
        (od.ERROR_CODE, "error_code"),
        (od.ERROR_REGISTER, "error_register"),
        (od.ESTIMATOR__ESTIMATED_ANGLE, "theta_hat_rad"),
        (od.ESTIMATOR__ESTIMATED_SPEED, "omega_hat_radps"),
        (od.ESTIMATOR__ESTIMATED_LINEAR_SPEED, "speed_hat_mps_pll"),
        (od.ESTIMATOR__PLL_ERROR, "pll_err_rad"),
        (od.ESTIMATOR__HF_AMPLITUDE, "hf_amp_A"),
        (od.ESTIMATOR__FILTERED_PLL_ERROR, "pll_err_f_rad"),
        (od.ESTIMATOR__SOGI_K_IN_USE, "sogi_k_eff"),
        (od.ESTIMATOR__START_UP_PHASE, "start_phase"),
        (od.BOARD__DRIVE_TIME, "drive_periods"),
        (od.REFERENCE_SENSOR__COUNT, "ref_count"),
        (od.REFERENCE_SENSOR__POSITION, "ref_pos_m"),
    )
}


_PDO_UNITS = {name: unit for name, unit, _ in _PDO_SIGNALS.values()}


class NoHardware(RuntimeError):
    """No usable CAN bus or no drive answering on it."""


@dataclass
class Connection:
    """An open connection to a drive.

    Attributes
    ----------
    bus : can.BusABC
    network : canopen.Network
    drive : Drive
    load : LoadDevice
    units : MotorUnits
    description : str
        Human-readable (printed and stored in the run metadata).
    sim : SimDrive or None
        The simulated drive behind the bus, when simulated.
    serial : object or None
        Serial port (pyserial or the sim's byte pipe) carrying telemetry.
    """

    bus: can.BusABC
    network: canopen.Network
    drive: Drive
    load: LoadDevice
    units: MotorUnits
    description: str
    sim: Any = None
    serial: Any = None
    info: dict[str, Any] = field(default_factory=dict)
    sync_period_ms: int = 10
    _hb_task: Any = None
    _sync_on: bool = False
    _rate_Hz: float | None = None

    @property
    def is_sim(self) -> bool:
        return self.sim is not None

    @property
    def kind(self) -> str:
        """What the drive said it is (0x2090:1): hardware, simulated, emulated, no_io or
        unknown (:meth:`bench.Drive.kind`)."""
        return str(self.info.get("kind", "unknown"))

    def clock_of(self, msg_ts: float) -> float:
        """Convert a frame timestamp (s since the epoch) to the drive clock (s)."""
        if self.sim is not None:
            return msg_ts - self.sim.epoch
        of_host = getattr(self.drive.clock, "of_host", None)
        if of_host is not None:
            return float(of_host(msg_ts))
        return msg_ts - (time.time() - time.monotonic())

    def start_sync(self) -> None:
        """Produce SYNC every ``sync_period_ms`` (the drive's TPDOs, its time among them,
        are SYNC-triggered); idempotent, stopped by :meth:`close`. Not for the
        in-process simulated drive, which produces its SYNC in simulated time."""
        if self.sim is None and not self._sync_on and self.sync_period_ms > 0:
            self.network.sync.start(self.sync_period_ms / 1000.0)
            self._sync_on = True

    def control_rate_Hz(self) -> float | None:
        """The drive's control rate (= its PWM frequency, ``f_pwm_Hz``) read from the
        drive once (it is read-only); the simulated drive's configuration, or None, when
        it cannot be read."""
        if self._rate_Hz is None:
            try:
                self._rate_Hz = float(self.drive.get("f_pwm_Hz")[0])
            except Exception:  # noqa: BLE001 - an old firmware, a lost answer
                return float(self.sim.sim.cfg.f_pwm_Hz) if self.sim is not None else None
        return self._rate_Hz

    def start_heartbeat(self, period_ms: int = 100) -> None:
        """Hardware: be the supervisor the drive watches while it may move, and the SYNC producer.

        The bench (node 0x7F) produces a heartbeat every ``period_ms``; the
        drive's consumer heartbeat (0x1016:1), and the load machine's
        (:class:`CanopenLoad`), watch it with a 5x margin and fault (quick
        stop, then PWM off) if the bench dies. :meth:`close`
        switches the watch off before stopping the heartbeat, so a clean exit
        does not fault the drive. Not used for the simulated drive, whose
        clock does not follow the wall clock.
        """
        if self.sim is not None or self._hb_task is not None:
            return
        self._hb_task = self.network.send_periodic(0x700 + 0x7F, bytes([0x05]),
                                                   period_ms / 1000.0)
        for d in self._watchers():  # the load machine too: a dead bench must stop it as well
            d.var(HB_WATCH).raw = (0x7F << 16) | (5 * period_ms)
        # The bench is also the SYNC producer: the drive's TPDOs (position,
        # velocity, torque, its time) are SYNC-triggered and would never flow without one.
        self.start_sync()

    def _watchers(self) -> list[Drive]:
        """The nodes that watch the bench's heartbeat: the drive and a load machine."""
        load = self.load.drive if isinstance(self.load, CanopenLoad) else None
        return [self.drive] + ([load] if load is not None else [])

    def drive_lost(self) -> str | None:
        """Why the drive on the bus counts as lost (its time stopped, its bus failed),
        None while it answers or when that cannot be told."""
        lost = getattr(self.drive.clock, "lost", None)
        return lost() if callable(lost) else None

    def close(self) -> None:
        """Disconnect everything (does not change the drive state). A lost drive is not
        asked anything (each request would wait for its SDO timeout)."""
        lost = self.drive_lost()
        if self._hb_task is not None:
            for d in ([] if lost else self._watchers()):
                try:
                    d.var(HB_WATCH).raw = 0  # stop watching, then stop beating
                except Exception as e:  # noqa: BLE001
                    log.warning("could not switch node %d's heartbeat watch off: %s",
                                d.node_id, e)
            self._hb_task.stop()
            self._hb_task = None
        if self._sync_on:
            self._sync_on = False
            try:
                self.network.sync.stop()
            except Exception as e:  # noqa: BLE001 - a dead bus: nothing left to stop
                log.warning("could not stop SYNC: %s", e)
        close_load = getattr(self.load, "close", None)  # the emulated rig's load link
        if callable(close_load):
            close_load()
        try:
            self.network.disconnect()
        except Exception as e:  # noqa: BLE001 - canopen re-raises receive-thread errors here
            log.warning("CAN receive thread had failed: %s: %s", type(e).__name__, e)
        if self.serial is not None and self.sim is None:
            self.serial.close()
        if self.sim is not None:
            self.sim.close()


def _say(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def open_sim(motor: str = "paper_salient", extractor: str = "sogi_adaptive", seed: int = 0,
             x0: float | str = 0.0, realtime: bool = False, node_id: int = 1,
             record_decimation: int = 1, read_pdos: bool = True,
             chunk_s: float = 1e-3, plant: dict[str, Any] | None = None,
             noise: float = 1.0) -> Connection:
    """Start the simulated drive on a fresh ``virtual`` channel and connect to it.

    ``chunk_s`` is the simulated time per C call, which is also the SYNC period (s).
    ``plant``: plant overrides, a motor other than the configured ``motor`` (e.g.
    ``sim_fallback._motors.machine_params(other)``). ``noise``: scale of the motor file's
    ADC noise and offsets (``sim_fallback.Sim``'s).
    """
    from sim_fallback import SimDrive, SimLoad

    channel = f"pmlsm-sim-{uuid.uuid4().hex[:8]}-vcan"  # no trailing digits (BLF channel)
    sim = SimDrive(channel, motor=motor, extractor=extractor, seed=seed, x0=x0,
                   node_id=node_id, realtime=False, chunk_s=chunk_s,
                   record_decimation=record_decimation, plant=plant, noise=noise).start()
    try:
        bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        net = canopen.Network(bus)
        net.NOTIFIER_CYCLE = 0.01  # disconnect in 10 ms, not 100; frames come at once
        net.connect()
        sim.attach_peer(bus, net.notifier)  # run_until waits for canopen's dispatch
        if realtime:
            sim.set_realtime(True)  # after attach_peer: the drive was idle until here
        # the simulated drive answers in its next chunk (well under a millisecond): a
        # wall-clock SDO timeout only fires when this machine stalls, and its retry
        # would be an extra frame that moves the simulated clock (not reproducible)
        drive = Drive(net, node_id, clock=sim.clock, sdo_timeout_s=5.0)
        drive.setup(read_pdos=read_pdos)
        kind, board = drive.kind()  # what the drive says: the simulated drive's port
    except Exception:
        sim.close()
        raise
    units = units_of(sim.motor)  # geometry, and linear or rotary from the motor file
    other = (f", simulating another motor than configured ({len(plant)} plant parameters "
             "overridden)") if plant else ""
    desc = (f"{KIND_LABEL.get(kind, kind)} drive (motor {sim.motor.name}{other}, extractor "
            f"{extractor}, seed {seed}, "
            f"{'paced to the wall clock' if realtime else 'as fast as possible'}) on "
            f"python-can virtual channel {channel}")
    return Connection(bus, net, drive, SimLoad(sim), units, desc, sim=sim, serial=sim.serial,
                      info={"kind": kind, "board": board, "via": "in-process",
                            "channel": channel, "x0_m": sim.x0_m})


#: how each kind the drive says it is (0x2090:1) is written in the console and reports
KIND_LABEL = {"hardware": "HARDWARE", "simulated": "SIMULATED", "emulated": "EMULATED",
              "no_io": "NO-I/O (blank port)", "unknown": "UNKNOWN (it does not say what it is)"}


class _BusWatch(can.Listener):
    """Tells the drive clock at once when the bus under the drive fails (a closed
    socket, an unplugged adapter), and ends the receive thread quietly instead of a
    traceback per read (python-can retries a handled error forever)."""

    def __init__(self, clock: Any, notifier: Any) -> None:
        self.clock = clock
        self.notifier = notifier
        self.error: str | None = None

    def on_message_received(self, msg: can.Message) -> None:
        pass

    def on_error(self, exc: Exception) -> None:
        self.error = " ".join(f"{type(exc).__name__}: {exc}".split())
        self.clock.fail(f"its bus failed ({self.error})")
        self.notifier._stopped = True  # python-can's receive loop ends after this error


def _start_drive_clock(conn: Connection, wait_s: float = 1.5) -> str:
    """Give the connection's drive its own clock (:class:`bench._clock.DriveClock`): the
    period count it publishes in a TPDO (0x2090:3, TPDO4 by default), SYNC started.
    Returns how the run is paced, for the metadata. A drive that publishes no time
    (an older firmware, a remapped TPDO) keeps the host's clock, said once."""
    from bench._clock import DriveClock

    drive = conn.drive
    tpdo_var = None
    for tpdo in drive.node.tpdo.values():
        if not tpdo.enabled:
            continue
        for var in tpdo:
            key = (var.index, var.subindex)
            if key == (od.BOARD__DRIVE_TIME.index, od.BOARD__DRIVE_TIME.sub) and \
                    var.offset % 8 == 0 and var.length == 32:
                tpdo_var = (tpdo, var.offset // 8)
    f_pwm = conn.control_rate_Hz()
    if tpdo_var is None or not f_pwm:
        _say("bench: the drive publishes no time (0x2090:3 in no TPDO): the run is paced by "
             "this host's clock")
        conn.start_sync()
        return "host clock (the drive publishes no time)"
    clock = DriveClock(f_pwm, what=f"drive node {drive.node_id}")
    tpdo, off = tpdo_var

    def on_time(pdo_map: Any) -> None:
        data = pdo_map.data
        if len(data) >= off + 4:
            clock.observe(int.from_bytes(bytes(data[off:off + 4]), "little"),
                          pdo_map.timestamp or time.time())

    tpdo.add_callback(on_time)
    watch = _BusWatch(clock, conn.network.notifier)
    conn.network.notifier.add_listener(watch)
    conn.start_sync()
    if not clock.wait_first(wait_s):
        tpdo.callbacks.remove(on_time)
        why = watch.error or f"no TPDO with its time within {wait_s:g} s"
        raise NoHardware(f"drive node {drive.node_id} does not publish its time ({why}); "
                         "is SYNC produced (--sync-period-ms)?")
    drive.clock = clock
    cob = getattr(tpdo, "cob_id", None)
    return (f"the drive's own clock (0x2090:3 in the TPDO of COB-ID "
            f"{'?' if cob is None else hex(cob)}, every SYNC; {f_pwm:g} periods/s)")


def bus_args(interface: str | None, channel: str | None, bitrate: int | None,
             bus_kw: dict[str, Any] | None = None) -> dict[str, Any] | None:
    """python-can arguments for a bus (``bus_kw``: further ones, e.g. socketcand's host
    and port); None when no interface is given nor in python-can's configuration."""
    kw: dict[str, Any] = {}
    if interface:
        kw["interface"] = interface
    if channel:
        kw["channel"] = channel
    if bitrate:
        kw["bitrate"] = bitrate
    kw.update(bus_kw or {})
    if not interface:
        try:
            cfg = can.util.load_config()
        except (can.CanError, NotImplementedError, ValueError):
            cfg = {}
        if not cfg.get("interface"):
            return None
    return kw


def open_bus(kw: dict[str, Any]) -> tuple[can.BusABC, str]:
    """Open a python-can bus; returns it and its arguments as shown in messages
    (``interface=pcan channel=PCAN_USBBUS1``). Raises :class:`NoHardware` (one line) when
    it cannot be opened."""
    shown = " ".join(f"{k}={v}" for k, v in kw.items() if k not in ("sleep_after_open",))
    try:
        return can.Bus(**kw), shown
    except (can.CanError, OSError, ImportError, ValueError, NotImplementedError,
            TypeError) as e:
        raise NoHardware(f"cannot open CAN bus {shown}: {' '.join(str(e).split())}") from e


def open_hardware(interface: str | None, channel: str | None, bitrate: int | None,
                  node_id: int = 1, load_node: int | None = None, motor: str | None = None,
                  serial_url: str | None = None, probe_timeout_s: float = 0.5,
                  bus_kw: dict[str, Any] | None = None, sync_period_ms: int = 10,
                  load: LoadDevice | None = None) -> Connection:
    """Open a python-can bus and check that the drive answers (``bus_kw``: further
    python-can arguments, e.g. socketcand's host and port). This is the one way the
    bench reaches a drive on a bus - a rig, the simulated drive server, the emulated
    board - and every result is labelled from what the drive says it is (0x2090:1).

    The run is paced by the drive's own clock (its period count, 0x2090:3, every
    SYNC; the bench produces SYNC every ``sync_period_ms``). ``load``: the load device
    when it is not a CANopen load machine (the emulated board's virtual one).

    Raises
    ------
    NoHardware
        No interface configured, the bus cannot be opened, or no answer from
        node ``node_id``.
    """
    kw = bus_args(interface, channel, bitrate, bus_kw)
    if kw is None:
        raise NoHardware("no CAN interface given (--interface) or configured "
                         "(~/.canrc, CAN_INTERFACE)")
    bus, shown = open_bus(kw)
    net = canopen.Network(bus)
    net.connect()
    conn: Connection | None = None
    try:
        drive = Drive(net, node_id, sdo_timeout_s=probe_timeout_s)
        try:
            _ = drive.var(od.DEVICE_TYPE).raw  # probe: does the drive answer?
        except Exception as e:
            raise NoHardware(f"no answer from drive node {node_id} on {shown}: "
                             f"{' '.join(str(e).split())}") from e
        drive.node.sdo.RESPONSE_TIMEOUT = 0.5
        drive.setup(read_pdos=True)
        kind, board = drive.kind()
        dev: LoadDevice = load if load is not None else NoLoad()
        if load_node:
            ld = Drive(net, load_node, sdo_timeout_s=probe_timeout_s)
            try:
                _ = ld.var(od.DEVICE_TYPE).raw  # probe: does the load machine answer?
            except Exception as e:
                # the drive is there, so no fallback to the simulator: a clear error
                raise ConnectionError(f"load machine node {load_node} on {shown} does not "
                                      f"answer: {e}") from e
            ld.node.sdo.RESPONSE_TIMEOUT = 0.5
            ld.setup(read_pdos=True)
            dev = CanopenLoad(ld)
        port = None
        if serial_url:
            import serial

            try:
                port = serial.serial_for_url(serial_url, baudrate=921600, timeout=0.1)
            except (serial.SerialException, ValueError, OSError) as e:
                raise NoHardware(f"--serial {serial_url}: cannot open: "
                                 f"{' '.join(str(e).split())}") from e
        units = motor_units(motor)
        where = f"{board} " if board else ""
        desc = f"{KIND_LABEL.get(kind, kind)} drive {where}node {node_id} on {shown}"
        conn = Connection(bus, net, drive, dev, units, desc, serial=port,
                          info={"kind": kind, "board": board, "via": "bus", "bus": shown,
                                "node_id": node_id},
                          sync_period_ms=sync_period_ms)
        conn.info["clock"] = _start_drive_clock(conn)
        return conn
    except BaseException:
        if conn is not None and conn._sync_on:
            with contextlib.suppress(Exception):
                net.sync.stop()
        net.disconnect()
        raise


def connect(sim: bool = False, interface: str | None = None, channel: str | None = None,
            bitrate: int | None = None, serial_url: str | None = None,
            realtime: bool = False, motor: str = "paper_salient",
            extractor: str = "sogi_adaptive", seed: int = 0, x0: float | str = 0.0,
            node_id: int = 1, load_node: int | None = None, record_decimation: int = 1,
            say: Callable[[str], None] = _say, require_hardware: bool = False,
            sim_server: Any = None, sim_plant: dict[str, Any] | None = None,
            emu: Any = None, bus_kw: dict[str, Any] | None = None,
            sync_period_ms: int = 10) -> Connection:
    """Hardware if available and not ``sim``; else the simulated drive (announced).

    ``sim_plant``: the simulated drive drives another motor than ``motor`` (plant
    overrides, see :func:`open_sim`); only with ``sim``.

    An explicit ``interface`` (or ``require_hardware``, a rig's CI job) never falls
    back: a missing drive raises :class:`NoHardware`. Without one, a missing drive
    falls back to the in-process simulated drive, said on stderr; the connection then
    has ``info["fallback"] = True`` and every result says SIMULATED.

    ``sim_server`` (a :class:`sim_fallback.server.ServerState`, ``bench sim start``) and
    ``emu`` (a :class:`sim_fallback.emu.EmuState`, ``bench emu start``) are reached exactly as
    a rig is (:func:`open_hardware`), never a fallback; what they are comes from the
    drive (0x2090:1), as for every drive on a bus.
    """
    if sim_server is not None or emu is not None:
        target = sim_server if sim_server is not None else emu
        bc = target.bus_config()
        load = target.load_device() if emu is not None else None
        if sim_server is not None and not load_node:  # its load machine, as on a rig
            load_node = getattr(sim_server, "load_node", 0) or None
        c = open_hardware(bc.pop("interface"), bc.pop("channel"), None, node_id, load_node,
                          motor, serial_url or target.serial_url(), bus_kw=bc,
                          sync_period_ms=sync_period_ms, load=load)
        c.info.update(via="sim_server" if sim_server is not None else "emu",
                      process_pid=target.pid, fallback=False)
        c.description += f" ({target.what()})"
        say(f"bench: connected to the {c.description}")
        return c
    fallback = False
    if not sim:
        try:
            c = open_hardware(interface, channel, bitrate, node_id, load_node, motor,
                              serial_url, bus_kw=bus_kw, sync_period_ms=sync_period_ms)
            say(f"bench: connected to the {c.description}")
            return c
        except NoHardware as e:
            if require_hardware or interface:
                why = ("--require-hardware forbids" if require_hardware else
                       f"--interface {interface} was named: no")
                raise NoHardware(f"{e}; {why} fallback to the simulated drive") from None
            say(f"bench: no drive hardware found ({e}).")
            say("bench: FALLING BACK TO THE SIMULATED DRIVE - results are from a simulation, "
                "not from hardware.")
            fallback = True
    if load_node:
        say(f"bench: --load-node {load_node} ignored: the simulated drive applies the load "
            "force in its plant")
    c = open_sim(motor, extractor, seed, x0, realtime, node_id, record_decimation,
                 plant=sim_plant)
    c.info["fallback"] = fallback
    say(f"bench: using the {c.description}")
    return c


def drive_kind(conn: Connection) -> dict[str, Any]:
    """What produced the results, from what the drive said it is (0x2090:1):
    ``{"drive": "hardware" | "simulated" | "emulated" | "no_io" | "unknown", "simulated":
    bool (anything but hardware), "fallback": bool, "board": str}`` (summary.json, JUnit
    properties, report banner). Only a drive that says "hardware" is hardware."""
    kind = conn.kind
    return {"drive": kind, "simulated": kind != "hardware",
            "fallback": bool(conn.info.get("fallback", False)),
            "board": str(conn.info.get("board", ""))}


# ---- decoding what comes over the wire --------------------------------------------------


class PdoRecorder:
    """Decodes the drive's TPDOs into SI signals (``pdo.<name>``) for the logger and,
    with ``live``, for the live telemetry feed (:class:`bench._live.LiveFeed`; its
    ``put`` never blocks the canopen receive thread that calls this)."""

    def __init__(self, conn: Connection, logger: RunLogger | None, live: Any = None) -> None:
        self.conn = conn
        self.logger = logger
        self.live = live
        self._buf: dict[str, tuple[list[float], list[float], str]] = {}
        self._lock = threading.Lock()
        self._layouts: dict[int, tuple[Any, list[Any]]] = {}
        try:
            self._rated = float(conn.drive.force_rated_N)
        except Exception:  # noqa: BLE001 - unknown rating: log per mille
            self._rated = float("nan")
        self._maps = [tpdo for tpdo in conn.drive.node.tpdo.values() if tpdo.enabled]
        for tpdo in self._maps:
            tpdo.add_callback(self._on_pdo)

    def detach(self) -> None:
        """Stop decoding: the callbacks leave the TPDO maps (a shell opens and closes
        live telemetry many times on one connection)."""
        self.live = None
        for tpdo in self._maps:
            if self._on_pdo in tpdo.callbacks:
                tpdo.callbacks.remove(self._on_pdo)
        self._maps = []

    def _layout(self, pdo_map: Any) -> list[tuple[str, Any, int, float | None, Any]]:
        """How to decode one mapped PDO: (signal, struct, byte offset, scale, variable)
        per known signal; the struct is None where canopen's own decoding is needed
        (not byte-aligned, or a type without a fixed struct). From the mapping canopen
        read from the drive, rebuilt when the mapping changes."""
        key = tuple((v.index, v.subindex, v.offset, v.length) for v in pdo_map)
        got = self._layouts.get(id(pdo_map))
        if got is not None and got[0] == key:
            return got[1]
        out = []
        for var in pdo_map:
            spec = _PDO_SIGNALS.get((var.index, var.subindex))
            if spec is None:
                continue
            name, _, scale = spec
            st = var.od.STRUCT_TYPES.get(var.od.data_type)
            aligned = var.offset % 8 == 0 and var.length % 8 == 0
            if not (aligned and hasattr(st, "unpack_from") and st.size * 8 == var.length):
                st = None
            out.append((name, st, var.offset // 8, scale, var))
        self._layouts[id(pdo_map)] = (key, out)
        return out

    def _on_pdo(self, pdo_map: Any) -> None:
        t = self.conn.clock_of(pdo_map.timestamp or time.time())
        vals: dict[str, float] = {}
        data = pdo_map.data
        for name, st, off, scale, var in self._layout(pdo_map):
            # struct on the frame's bytes: canopen's per-variable decoding was the
            # largest cost of a received TPDO (4 per SYNC at 1 kHz)
            raw = st.unpack_from(data, off)[0] if st is not None else var.raw
            if scale is None:  # per mille of the rated force -> N
                vals[name] = float(raw) * _PER_MILLE * self._rated
            else:
                vals[name] = float(raw) * scale
        if self.logger is not None:
            with self._lock:
                for name, val in vals.items():
                    b = self._buf.setdefault(name, ([], [], _PDO_UNITS[name]))
                    b[0].append(t)
                    b[1].append(val)
        if self.live is not None and vals:
            self.live.put("pdo.", t, vals)

    def drain(self) -> None:
        if self.logger is None:
            return
        with self._lock:
            buf, self._buf = self._buf, {}
        for name, (t, v, unit) in buf.items():
            self.logger.append(np.asarray(t), {name: np.asarray(v)}, {name: unit},
                               prefix="pdo.")


class TelemetryReader(threading.Thread):
    """Reads the serial telemetry link into the logger (``tel.<signal>``).

    Survives the wire: a corrupt frame is counted by the :class:`Receiver`
    (``frames_bad``), a frame with a valid CRC but a malformed payload in
    ``payload_errors`` (telemetry) or by the :class:`TraceAssembler` (trace
    frames), a frame of an unknown type in ``payload_errors["type"]``; each is
    skipped and the reader goes on. Completed trace uploads are appended to
    ``traces``. Only a failing port or logger ends the thread early (``error``).
    """

    def __init__(self, port: Any, logger: RunLogger | None, f_pwm_Hz: float,
                 live: Any = None) -> None:
        super().__init__(name="bench-telemetry", daemon=True)
        from protocols import serial_link

        self.sl = serial_link
        self.port = port
        self.logger = logger
        self.live = live  # LiveFeed: put() never blocks this thread
        self.rx = serial_link.Receiver()
        self.asm = serial_link.TraceAssembler()
        self.traces: list[Any] = []
        self.names = serial_link.signal_names()
        self.f_pwm_Hz = f_pwm_Hz
        # not `_stop`: that name is threading.Thread's own method (join() calls it)
        self._stop_event = threading.Event()
        self.payload_errors: dict[str, int] = {}
        self.error: str | None = None

    def run(self) -> None:
        sl = self.sl
        try:
            while not self._stop_event.is_set():
                data = self.port.read(4096)
                if not data:
                    if getattr(self.port, "closed", False):
                        return
                    continue
                cols: dict[str, tuple[list[float], list[float]]] = {}
                for fr in self.rx.feed(data):
                    if fr.type != sl.FrameType.TELEMETRY:
                        if fr.type not in (sl.FrameType.TRACE_HEADER, sl.FrameType.TRACE_DATA,
                                           sl.FrameType.TRACE_END):
                            self._count("type")
                            continue
                        tr = self.asm.feed(fr)
                        if tr is not None:
                            self.traces.append(tr)
                        continue
                    try:
                        tel = sl.parse_telemetry(fr.payload)
                    except sl.FrameError as e:
                        self._count(e.reason)
                        continue
                    t = tel.step / self.f_pwm_Hz
                    for i, v in zip(tel.ids, tel.values, strict=True):
                        name = self.names[i] if i < len(self.names) else f"sig{i}"
                        c = cols.setdefault(name, ([], []))
                        c[0].append(t)
                        c[1].append(v)
                # signals that share their times (all of them, unless a frame was
                # lost mid-read) go to the logger and the live feed as one item
                groups: dict[tuple[float, ...], dict[str, np.ndarray]] = {}
                times: dict[tuple[float, ...], np.ndarray] = {}
                for name, (t, v) in cols.items():
                    tk = tuple(t)
                    if tk not in times:
                        times[tk] = np.asarray(t)
                    groups.setdefault(tk, {})[name] = np.asarray(v)
                live = self.live
                for tk, vals in groups.items():
                    if self.logger is not None:
                        self.logger.append(times[tk], vals, {}, prefix="tel.")
                    if live is not None:
                        live.put("tel.", times[tk], vals)
        except Exception as e:  # noqa: BLE001 - surfaced in the result
            self.error = f"{type(e).__name__}: {e}"
            log.error("telemetry reader: %s", self.error)

    def _count(self, reason: str) -> None:
        self.payload_errors[reason] = self.payload_errors.get(reason, 0) + 1

    def stop(self) -> None:
        self._stop_event.set()

    @property
    def stats(self) -> dict[str, int]:
        """Frame counters: link (ok, bad, lost, restarts) and payloads skipped."""
        return {"frames_ok": self.rx.frames_ok, "frames_bad": self.rx.frames_bad,
                "frames_lost": self.rx.frames_lost, "restarts": self.rx.restarts,
                "payload_bad": sum(self.payload_errors.values()) + self.asm.frames_bad}


# ---- live telemetry to rerun ------------------------------------------------------------


def open_live(spec: Any, conn: Connection, run_dir: Any, name: str, lazy: bool = False) -> Any:
    """Open the rerun side of live telemetry (:class:`bench._live.LiveTelemetry`) for a
    connection: the .rrd goes to ``spec.path`` or ``run_dir/telemetry.rrd``. ``lazy``: the
    feed only; ``.open()`` opens rerun later."""
    from pathlib import Path

    from bench._live import LiveTelemetry

    path = Path(spec.path) if spec.path is not None else Path(run_dir) / "telemetry.rrd"
    return LiveTelemetry(spec, path, name, pole_pairs=conn.units.pole_pairs,
                         radius_m=conn.units.radius_m, say=_say, lazy=lazy)


class LiveTap:
    """What feeds live telemetry from a connection, the one wiring of ``bench live`` and
    the shell's ``drive.live()``: the TPDOs (:class:`PdoRecorder`), the serial telemetry
    when the connection has a serial link (:class:`TelemetryReader`), and, on the
    simulated drive, its truth beside them (never instead). :meth:`close` undoes all of it
    and stops the reader."""

    def __init__(self, conn: Connection, feed: Any, truth_decimation: int = 0) -> None:
        self.conn = conn
        self.sim = conn.sim
        if self.sim is not None:
            if truth_decimation:
                self.sim.record_decimation = max(self.sim.record_decimation,
                                                 truth_decimation)
            self.sim.sink = feed.put_truth
        self.pdo = PdoRecorder(conn, None, live=feed)
        self.tel: TelemetryReader | None = None
        if conn.serial is not None:
            self.tel = TelemetryReader(conn.serial, None, conn.control_rate_Hz() or 24000.0,
                                       live=feed)
            self.tel.start()

    def close(self) -> None:
        if self.sim is not None:
            self.sim.sink = None
        self.pdo.detach()
        if self.tel is not None:
            self.tel.live = None
            self.tel.stop()
            self.tel.join(timeout=1.0)
            self.tel = None


def close_live(live: Any, drive_time_s: float | None = None) -> dict[str, Any]:
    """Flush and close live telemetry; print its one-line summary; its statistics."""
    from bench._live import summary_line

    stats = live.close()
    _say("bench: " + summary_line(live.feed.stats, live.recording, drive_time_s))
    stats["drive_time_s"] = drive_time_s
    return stats


@dataclass
class LiveOutput:
    """What :func:`run_live` produced."""

    run_dir: Any
    stats: dict[str, Any]
    drive_time_s: float
    fault: str | None = None
    interrupted: bool = False


def run_live(conn: Connection, spec: Any, speed_mps: float, duration_s: float = 0.0,
             runs_root: str = "runs", scope: Any = None) -> LiveOutput:
    """``bench live``: enable the drive in speed mode, stream the decoded wire telemetry
    (TPDOs, serial telemetry; the simulated drive's truth beside) to rerun until
    ``duration_s`` of drive time after the enable (0: until Ctrl-C); the drive is disabled
    on exit.

    The same code for hardware and the simulated drive: the simulated drive is paced to
    the wall clock and feeds only its truth channels; everything else comes from the bus
    and the serial link, decoded as on hardware. The .rrd goes to ``spec.path`` or a run
    folder ``runs_root/<time>_live/telemetry.rrd``. A viewer (spawn, serve, connect) is
    opened before the drive is enabled. A recording only (save, spawn without a display)
    opens while the drive already runs (its ~0.6 s of imports and blueprint would otherwise
    come before the first sample); the samples meanwhile wait in the feed's queue.

    ``spec`` None with a ``scope`` (:class:`bench._scope.TerminalScope`, ``bench live
    --tui``): no rerun, the scope drawn in the terminal every 0.1 s of drive time.
    """
    from pathlib import Path

    from bench._drive import DriveFault, DriveLeftState, DriveLost
    from bench._live import recording_only

    live = tap = run_dir = None
    if spec is not None:
        run_dir = None if spec.path is not None else run_dir_for("live", runs_root)
        try:
            live = open_live(spec, conn, run_dir, "live", lazy=recording_only(spec))
        except BaseException:  # the viewer did not start: nothing moved, no empty folder
            if run_dir is not None and Path(run_dir).is_dir() and \
                    not any(Path(run_dir).iterdir()):
                Path(run_dir).rmdir()
            raise
        tap = LiveTap(conn, live.feed, truth_decimation=12)  # truth at 2 kHz
    if conn.sim is not None:
        conn.sim.set_realtime(True)
    d = conn.drive
    interrupted = lost = False
    fault = None
    t0 = t_end = d.clock.now()
    conn.start_heartbeat()
    try:
        d.enable("speed")
        d.set_speed_mps(speed_mps)
        t0 = d.clock.now()
        if live is not None:
            live.open()
        _say("bench: live; Ctrl-C to stop (the drive is disabled on exit)")
        if scope is not None:
            scope.speed_ref_mps = speed_mps
            scope.start()
        while duration_s <= 0 or d.clock.now() - t0 < duration_s:
            now = d.clock.now()  # the drive is watched every slice (Drive.check)
            d.wait_until(min(now + 0.1, t0 + duration_s) if duration_s > 0 else now + 0.1)
            if scope is not None:
                scope.sample(d.clock.now() - t0)
                scope.draw()
    except KeyboardInterrupt:
        interrupted = True
    except (DriveFault, DriveLeftState, DriveLost) as e:
        fault = str(e)
        lost = isinstance(e, DriveLost)
        _say(f"bench: live stopped: {e}")
    finally:
        with contextlib.suppress(DriveLost):
            t_end = d.clock.now()
        if lost:
            _say("bench: SAFE STATE NOT CONFIRMED: the drive is lost; its heartbeat consumer "
                 "(0x1016) switches its PWM off without the bench's heartbeat")
        else:
            try:
                d.disable()
                _say("bench: drive disabled")
            except Exception as e:  # noqa: BLE001
                _say(f"bench: SAFE STATE FAILED: {e}")
        drive_time = max(0.0, t_end - t0)
        stats: dict[str, Any] = {}
        if scope is not None:
            scope.close()
        if live is not None:
            tap.close()
            stats = close_live(live, drive_time_s=drive_time)
    out_dir = (Path(run_dir) if run_dir is not None else
               Path(spec.path).parent if spec is not None else Path("."))
    return LiveOutput(out_dir, stats, drive_time, fault, interrupted)


# ---- a complete run ---------------------------------------------------------------------


@dataclass
class RunOutput:
    """What :func:`run_sequence` produced."""

    result: RunResult
    run_dir: Any
    logstats: dict[str, Any]
    report: Any
    interrupted: BaseException | None = None
    #: the test record: ``{"dut": ..., "record": ...}`` as in summary.json
    record: dict[str, Any] = field(default_factory=dict)


def run_sequence(seq: Sequence, conn: Connection, runs_root: str = "runs",
                 summary_json: str | None = None, junit: str | None = None,
                 progress: bool = True, rerun: Any = None, trace_format: str = "blf",
                 report: bool = True, station_info: dict[str, str] | None = None
                 ) -> RunOutput:
    """Run ``seq`` on an open connection: log, evaluate, report.

    ``rerun`` (a :class:`bench._live.RerunSpec`) streams the decoded wire telemetry (and
    the simulated drive's truth beside it) to rerun and records ``telemetry.rrd`` in the
    run folder (or the spec's path); its statistics are in ``logstats["rerun"]``.

    KeyboardInterrupt is caught after the safe state, recorded as an aborted
    run and returned in ``interrupted`` (the report and JUnit are still
    written), so the caller can exit with 130.

    The test record (:mod:`bench._results`): the drive's identity as it answers,
    ``station_info`` (operator, station, fixture; by default from the environment,
    :func:`bench._results.station_fields`), times and verdict go into summary.json,
    meta.json and junit.xml; then the run is added to ``runs_root/results.sqlite``. A
    store that cannot be written is one line on stderr, never the run's result.
    """
    from datetime import datetime, timezone
    from pathlib import Path

    from bench import __version__
    from bench._results import (
        add_junit_properties,
        dut_fields,
        record_run,
        station_fields,
        store_path,
        utc_stamp,
        verdict_of,
    )

    who = dict(station_info) if station_info is not None else station_fields()
    started = datetime.now(timezone.utc)
    wall0 = time.monotonic()
    run_dir = run_dir_for(seq.name, runs_root)
    if conn.sim is not None:
        conn.sim.wait_idle()
    logger = RunLogger(run_dir, conn.network, trace_format=trace_format)
    sent0 = conn.sim.frames_sent if conn.sim is not None else 0
    live = open_live(rerun, conn, run_dir, seq.name) if rerun is not None else None
    feed = live.feed if live is not None else None
    sinks: list[Callable[..., None]] = [
        lambda t, v, u: logger.append(t, v, u, prefix="sim.")]
    if feed is not None:
        sinks.append(feed.put_truth)
    if conn.sim is not None:
        conn.sim.sink = lambda t, v, u: [s(t, v, u) for s in sinks]
    pdo = PdoRecorder(conn, logger, live=feed)
    tel = None
    # one time base for the telemetry and the run (the drive's, 24 kHz when it cannot be read)
    f_pwm = conn.control_rate_Hz() or 24000.0
    if conn.serial is not None:
        tel = TelemetryReader(conn.serial, logger, f_pwm, live=feed)
        tel.start()
    drive = conn.drive
    conn.start_heartbeat()
    from bench._evidence import finish_evidence, plan_evidence

    evidence = plan_evidence(conn, tel is not None, _say)
    logger.evidence = evidence
    meta: dict[str, Any] = {
        "connection": conn.description, "connection_info": conn.info,
        "sequence": {"name": seq.name, "file": str(seq.path), "motor": seq.motor,
                     "extractor": seq.extractor, "seed": seq.seed,
                     "description": seq.description, "document": seq.raw,
                     "params": seq.params, "overrides": seq.overrides, "sha256": seq.sha256},
        "seed": seq.seed, "units": {"pole_pitch_m": conn.units.pole_pitch_m,
                                    "pole_pairs": conn.units.pole_pairs,
                                    "linear": conn.units.linear},
        "evidence": evidence.to_dict(), "clock": conn.info.get("clock", "simulation clock"),
    }
    try:
        ident = drive.identity()
        meta["drive"] = ident
        meta["firmware_check"] = drive.check_firmware(ident) or "matches the EDS"
        meta["drive_config"] = drive.backup()
    except Exception as e:  # noqa: BLE001 - metadata must not stop a run
        meta["drive_error"] = str(e)
    # the device under test as the drive answered (never typed), who tested it, where
    dut = dut_fields(meta.get("drive"), drive_kind(conn),
                     None if "drive" in meta else meta.get("drive_error"))
    seq_file = Path(seq.path).resolve() if Path(seq.path).is_file() else seq.path
    rec: dict[str, Any] = {**who, "started_utc": utc_stamp(started), "sequence_name": seq.name,
                           "sequence_file": str(seq_file), "sequence_sha256": seq.sha256,
                           "params": dict(seq.params), "overrides": dict(seq.overrides),
                           "motor": seq.motor, "bench_version": __version__}
    meta["dut"] = dut
    meta["record"] = rec
    logger.write_meta(meta)

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=round(seq.duration_s, 3), unit="s", desc=seq.name, leave=False,
                   bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.2f}/{total:.2f} s "
                              "[{elapsed}<{remaining}]")

    def prog(t: float, total: float) -> None:
        pdo.drain()
        t = min(t, bar.total) if bar is not None else t
        if bar is not None and t - bar.n >= 0.01:
            bar.update(round(t - bar.n, 3))

    runner = Runner(drive, conn.units, conn.load, logger, progress=prog,
                    f_pwm_Hz=f_pwm if tel is not None else None)
    interrupted: BaseException | None = None
    # one guard from the start of the run to the last file written: the first Ctrl-C
    # stops the run, later ones cannot interrupt the safe state or the saving
    with InterruptGuard(_say) as guard:
        runner.guard = guard
        try:
            result = runner.run(seq)
        except KeyboardInterrupt as e:
            interrupted = e
            result = runner.result
        except Exception as e:  # noqa: BLE001 - the run result records it
            interrupted = e
            result = runner.result
        finally:
            guard.begin_stop()
            if bar is not None:
                bar.close()
        if runner.traces and tel is not None and runner.drive_lost is None:
            _collect_trace(runner, drive, tel, logger)
        if evidence.restore and runner.drive_lost is None:
            finish_evidence(conn, evidence)
        if conn.sim is not None:
            conn.sim.sink = None
        if conn.sim is not None and conn.sim.wait_idle():
            _settle_count(logger, expect=conn.sim.frames_sent - sent0)
        pdo.drain()
        if tel is not None:
            tel.stop()
        logstats = logger.close(join_mf4=True, sync=False)  # written beside the report
        if live is not None:
            pdo.live = None
            if tel is not None:
                tel.live = None
            logstats["rerun"] = close_live(live, drive_time_s=seq.duration_s)
        if tel is not None:
            logstats["telemetry"] = tel.stats
            logstats["lost_frames"]["serial_telemetry"] = tel.rx.frames_lost
            if tel.error:
                logstats["receive_errors"].append("telemetry: " + tel.error)
        if conn.sim is not None:
            sent = conn.sim.frames_sent - sent0
            logstats["lost_frames"]["can"] = max(0, sent - logstats["frames_logged"])
            logstats["sim_frames_to_bus"] = sent
        if logstats["receive_errors"]:
            _say("bench: CAN receive-thread errors: " + "; ".join(logstats["receive_errors"]))
        verdict, reason, code = verdict_of(result, interrupted)
        finished = datetime.now(timezone.utc)
        rec.update(finished_utc=utc_stamp(finished), duration_s=time.monotonic() - wall0,
                   sequence_s=result.duration_s, verdict=verdict, exit_reason=reason,
                   exit_code=code)
        record = {"dut": dut, "record": rec}
        logger.write_meta({"result": {"passed": result.passed, "error": result.error,
                                      "safe_state": result.safe_state},
                           "logging": logstats, "record": rec})
        rep = None
        extra = {"run_dir": str(run_dir), "lost_frames": logstats["lost_frames"],
                 "receive_errors": logstats["receive_errors"], **drive_kind(conn),
                 "evidence": evidence.to_dict(), **record}
        if report:
            plots = make_plots(logger, result, conn.units, run_dir)
            rep = run_dir / "report.html"
            write_html(rep, result, plots, logger.meta, logstats, units=conn.units)
        write_summary_json(run_dir / "summary.json", result, extra, units=conn.units)
        write_junit(run_dir / "junit.xml", [result], drive_kind(conn))
        add_junit_properties(run_dir / "junit.xml", [record])
        if summary_json:
            write_summary_json(summary_json, result, extra, units=conn.units)
        if junit:
            write_junit(junit, [result], drive_kind(conn))
            add_junit_properties(junit, [record])
        logger.sync_files(logstats)
        if logstats["mf4_errors"]:
            _say("bench: signals not written: " + "; ".join(logstats["mf4_errors"]))
        if logstats["mf4_errors"] or logstats["mf4_written_in_bench"]:
            logger.write_meta({"logging": logstats})
        try:  # after summary.json: the store can always be rebuilt from the run folders
            record_run(runs_root, run_dir, summary(result, extra), logger.meta)
        except Exception as e:  # noqa: BLE001 - the run's own files and verdict stand
            _say(f"bench: warning: results store {store_path(runs_root)} not updated: "
                 f"{' '.join(str(e).split())}; the run's files are complete ('bench results "
                 "--rebuild' recovers the store)")
    return RunOutput(result, run_dir, logstats, rep, interrupted, record)


def _collect_trace(runner: Runner, drive: Drive, tel: TelemetryReader, logger: RunLogger,
                   timeout_s: float = 1.0) -> None:
    """Upload the drive's last trace capture over the serial link into ``trace.*``.

    The buffer holds one capture, so this is the last ``trace_capture`` step's:
    only an upload completed after the command and with that step's signal ids
    is taken (not an earlier one still in ``tel.traces``). Waiting uses the drive
    clock (the simulated drive keeps running for it) and ends early when the
    reader thread has stopped.
    """
    spec = runner.traces[-1]
    want = tuple(spec.get("ids", ()))
    n_before = len(tel.traces)

    def received() -> list[Any]:
        return [tr for tr in tel.traces[n_before:] if not want or tuple(tr.ids) == want]

    try:
        drive.trace_upload()
        t_end = drive.clock.now() + timeout_s
        while not received() and tel.is_alive() and drive.clock.now() < t_end:
            drive.clock.sleep_until(drive.clock.now() + 0.02)
            time.sleep(0.005)  # let the reader thread catch up with the bytes
    except Exception as e:  # noqa: BLE001 - a measurement, not a safety matter
        logger.event(runner.now(), "trace_failed", {"name": spec["name"], "error": str(e)})
        return
    got = received()
    if not got:
        why = "no upload received" if tel.is_alive() else f"telemetry reader stopped: {tel.error}"
        logger.event(runner.now(), "trace_failed", {"name": spec["name"], "error": why,
                                                    "link": tel.stats})
        return
    tr = got[-1]
    if getattr(drive.clock, "exact_steps", False):
        # simulated drive: its clock is control steps x dt, so the header's trigger step
        # places the capture exactly
        t = tr.trigger_step * tr.dt_s + tr.time_s()
    else:  # hardware: the bench-side time at which the trigger was acknowledged
        t = spec["t_trigger_clock"] + tr.time_s()
    names = [tel.names[i] if i < len(tel.names) else f"sig{i}" for i in tr.ids]
    logger.append(t, {n: tr.samples[:, k].astype(np.float64) for k, n in enumerate(names)},
                  {}, prefix=f"trace.{spec['name']}.")
    logger.event(spec["t_s"], "trace_uploaded", {"name": spec["name"], "samples":
                                                int(tr.samples.shape[0]),
                                                "missing": tr.missing})


def _settle_count(logger: RunLogger, timeout_s: float = 1.0, expect: int | None = None
                  ) -> None:
    """Wait until the notifier has delivered every queued frame to the trace: until it
    holds ``expect`` frames (the simulated drive counts what it sent), else until the
    count stops changing for 20 ms."""
    if logger.trace is None:
        return
    deadline = time.monotonic() + timeout_s
    if expect is not None:
        while logger.trace.count < expect and time.monotonic() < deadline:
            time.sleep(0.001)
        return
    last = -1
    while time.monotonic() < deadline:
        n = logger.trace.count
        if n == last:
            return
        last = n
        time.sleep(0.02)
