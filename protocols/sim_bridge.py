"""Bridge a python-can bus to the drive application (fw_app) running in C.

The drive application (control core + CANopen node + serial link,
``firmware_c/comm``) runs either in closed loop with the simulated plant of
``sim_fallback`` (when that library is available) or against a null plant
(zero currents, constant DC link; enough for NMT/SDO/PDO/heartbeat/EMCY).

With the plant it runs as on the MCU: the simulator library holds the whole
drive behind its own implementation of the port (``sim_fallback/src/
sim_port.c``, ``sim_app_*``): the batch loop's ADC counts go through the
board glue's control interrupt (``fw_board_control_isr``: the firmware's one
ADC conversion, the step, the duties) and the background loop
(``fw_board_background``: CANopen, OD, EMCY, telemetry) runs every
``background_every`` control periods in between; the frames and UART bytes
it sends through the port are collected here. The null plant steps the
application library's ``fw_app_step`` (both halves in one call).

CAN frames are forwarded both ways once per chunk of control periods; the
simulation is paced to wall-clock time by default so that CANopen timeouts
keep their meaning.

Example::

    bus = can.Bus(interface="virtual", channel="pmlsm")
    with DriveBridge(bus, node_id=5) as drive:
        drive.start()          # background thread, real-time pacing
        ...                    # canopen.Network on another virtual bus handle
"""

from __future__ import annotations

import ctypes as C
import logging
import os
import threading
import time
from collections.abc import Sequence
from typing import Any

import can
import numpy as np

from . import _clib

log = logging.getLogger(__name__)

class FwCanFrame(C.Structure):
    """Mirror of ``fw_can_frame_t``."""

    _fields_ = [("id", C.c_uint16), ("dlc", C.c_uint8), ("rtr", C.c_uint8),
                ("data", C.c_uint8 * 8)]


class FwInputs(C.Structure):
    _fields_ = [("i_abc_A", C.c_float * 3), ("u_dc_V", C.c_float)]


class FwOutputs(C.Structure):
    _fields_ = [("duty_abc", C.c_float * 3), ("pwm_enable", C.c_uint8)]


class FwConfigField(C.Structure):
    """Mirror of ``fw_config_field_t``."""

    _fields_ = [("name", C.c_char_p), ("unit", C.c_char_p), ("offset", C.c_size_t),
                ("is_int", C.c_uint8), ("is_signed", C.c_uint8), ("min", C.c_float),
                ("max", C.c_float)]


class FwConfigIssue(C.Structure):
    """Mirror of ``fw_config_issue_t``."""

    _fields_ = [("status", C.c_int), ("field", C.c_char_p), ("value", C.c_float),
                ("min", C.c_float), ("max", C.c_float)]


def _declare(lib: C.CDLL) -> None:
    """The functions the bridge calls. ``lib`` is a handle of its own: ctypes keeps
    argument types per handle, so these never change another module's declarations
    of the same library (sim_fallback declares the simulator library its own way)."""
    V = C.c_void_p
    lib.fw_app_sizeof.restype = C.c_size_t
    lib.fw_app_init.argtypes = [V, V, C.c_uint8]
    lib.fw_app_init.restype = C.c_int
    lib.fw_app_can_rx.argtypes = [V, C.POINTER(FwCanFrame)]
    lib.fw_app_can_rx.restype = C.c_bool
    lib.fw_app_can_tx_pop.argtypes = [V, C.POINTER(FwCanFrame)]
    lib.fw_app_can_tx_pop.restype = C.c_bool
    lib.fw_app_step.argtypes = [V, C.POINTER(FwInputs), C.POINTER(FwOutputs)]
    lib.fw_app_uart_read.argtypes = [V, C.c_char_p, C.c_size_t]
    lib.fw_app_uart_read.restype = C.c_size_t
    lib.fw_config_default.argtypes = [V]
    lib.fw_config_field_find.argtypes = [C.c_char_p]
    lib.fw_config_field_find.restype = C.POINTER(FwConfigField)
    lib.fw_config_check.argtypes = [V, C.POINTER(FwConfigIssue)]
    lib.fw_config_check.restype = C.c_int
    if hasattr(lib, "sim_app_new"):  # the simulator library: the drive behind sim_port.c
        lib.sim_app_new.argtypes = [V, C.c_uint8, C.c_char_p, C.POINTER(C.c_int)]
        lib.sim_app_new.restype = V
        lib.sim_app_free.argtypes = [V]
        lib.sim_app_controller.argtypes = [V, C.c_uint32, V]
        lib.sim_app_can_rx.argtypes = [V, C.POINTER(FwCanFrame)]
        lib.sim_app_can_rx.restype = C.c_bool
        lib.sim_app_can_pop.argtypes = [V, C.POINTER(FwCanFrame)]
        lib.sim_app_can_pop.restype = C.c_bool
        lib.sim_app_uart_read.argtypes = [V, C.c_char_p, C.c_size_t]
        lib.sim_app_uart_read.restype = C.c_size_t
        lib.sim_app_background_now.argtypes = [V]
        lib.sim_app_fw_app.argtypes = [V]
        lib.sim_app_fw_app.restype = V
        lib.sim_app_nvm_state.argtypes = [V]
        lib.sim_app_nvm_state.restype = C.c_int
        lib.sim_app_crit_unbalanced.argtypes = [V]
        lib.sim_app_crit_unbalanced.restype = C.c_uint32


class DriveBridge:
    """The drive application on a python-can bus.

    Parameters
    ----------
    bus : can.BusABC
        The drive's side of the bus (e.g. ``interface="virtual"``).
    node_id : int
        CANopen node id (1..127).
    plant : {"auto", "sim", "none"}
        "sim": closed loop with ``sim_fallback.Sim`` (error if unavailable);
        "none": null plant; "auto": "sim" when importable.
    chunk_steps : int
        Control periods per bridge iteration (frames are exchanged between chunks).
    realtime : float
        Wall-clock pacing factor for :meth:`start` (1.0 = real time, 0 = as fast as possible).
    sim_kwargs : dict
        Passed to ``sim_fallback.Sim`` (motor, seed, noise, x0_m, ...).
    background_every : int
        With the plant: control periods per pass of the drive's background loop.
    nvm_path : str or Path, optional
        With the plant: the drive's non-volatile memory (a file; booted from at
        construction). None: a drive without storage.
    """

    def __init__(self, bus: can.BusABC, node_id: int = 5, plant: str = "auto",
                 chunk_steps: int = 24, realtime: float = 1.0,
                 sim_kwargs: dict[str, Any] | None = None, background_every: int = 1,
                 nvm_path: Any = None) -> None:
        self.bus = bus
        self.node_id = node_id
        self.chunk_steps = chunk_steps
        self.realtime = realtime
        self.sim = None
        self._drive = None  # sim_app_t * (with the plant)
        if plant in ("auto", "sim"):
            try:
                from sim_fallback import _lib as simlib
                from sim_fallback._sim import Sim

                self.sim = Sim(**(sim_kwargs or {}))
            except Exception:
                if plant == "sim":
                    raise
                self.sim = None
        # with the plant, the simulator library holds the drive application too
        self._L = (C.CDLL(self.sim._L._name) if self.sim is not None  # own handle: _declare
                   else _clib.load_app())
        _declare(self._L)
        # Our own fw_config_t (this library's layout), defaults first, then the
        # simulated motor's values copied field by field by name, so that the
        # two libraries never have to agree on the struct layout.
        self._cfg = C.create_string_buffer(4096)
        self._L.fw_config_default(self._cfg)
        self.f_pwm_Hz = 24000.0
        if self.sim is not None:
            self._copy_config(self.sim.cfg)
            st = C.c_int(0)
            path = os.fsencode(str(nvm_path)) if nvm_path else None
            self._drive = self._L.sim_app_new(self._cfg, node_id, path, C.byref(st))
            if not self._drive:
                self.sim.close()
                raise RuntimeError(f"fw_app_init returned fw_status_t {st.value} "
                                   "(configuration refused)")
            self.f_pwm_Hz = 1.0 / self.sim.dt_s
            port = simlib.SimController()
            self._L.sim_app_controller(self._drive, max(1, int(background_every)),
                                       C.addressof(port))
            self._port = port
            self.sim._L.sim_set_controller(self.sim._h, C.byref(port))
            self._L.sim_app_background_now(self._drive)  # the boot-up message
        else:
            self._app = C.create_string_buffer(self._L.fw_app_sizeof())
            rc = self._L.fw_app_init(self._app, self._cfg, node_id)
            if rc != 0:
                raise RuntimeError(f"fw_app_init returned fw_status_t {rc} "
                                   "(configuration refused)")
        self._in = FwInputs()
        self._in.u_dc_V = 300.0
        self._out = FwOutputs()
        self.steps = 0
        self.uart = bytearray()
        self.sent: list[can.Message] = []
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.error: BaseException | None = None
        self._flush_tx()  # boot-up message

    def _copy_config(self, src: C.Structure) -> None:
        """Copy the sim's fw_config_t - every field, by name: the drive is configured as
        the simulator API's and the emulated board's drive for the same motor
        (``sim_fallback.drive_params``) - into this library's layout; a field the core
        refuses keeps the firmware default (logged), so a binding that is out of step
        with the header cannot stop the bridge."""
        dflt = C.create_string_buffer(self._cfg.raw, len(self._cfg))
        for name, v in src.as_dict().items():  # flat field names (FwConfig nests in parts)
            f = self._L.fw_config_field_find(name.encode())
            if not f:
                continue
            off = f.contents.offset
            if f.contents.is_int:  # int32_t or uint32_t: the same 32 bits
                C.c_uint32.from_buffer(self._cfg, off).value = int(v) & 0xFFFFFFFF
            else:
                C.c_float.from_buffer(self._cfg, off).value = float(v)
        issue = FwConfigIssue()
        for _ in range(64):
            if self._L.fw_config_check(self._cfg, C.byref(issue)) in (0, 4):  # OK, SALIENCY
                return
            if not issue.field:
                break
            f = self._L.fw_config_field_find(issue.field)
            off = f.contents.offset
            log.warning("sim config field %s = %g refused (range %g..%g): firmware default kept",
                        issue.field.decode(), issue.value, issue.min, issue.max)
            self._cfg[off:off + 4] = dflt.raw[off:off + 4]

    # ---- the drive's CAN and UART ----------------------------------------
    def _can_rx(self, f: FwCanFrame) -> bool:
        """A frame into the drive's receive queue (its CAN RX interrupt)."""
        if self._drive is not None:
            return bool(self._L.sim_app_can_rx(self._drive, C.byref(f)))
        return bool(self._L.fw_app_can_rx(self._app, C.byref(f)))

    def _can_pop(self, f: FwCanFrame) -> bool:
        """The next frame the drive sent, into f; False when none."""
        if self._drive is not None:
            return bool(self._L.sim_app_can_pop(self._drive, C.byref(f)))
        return bool(self._L.fw_app_can_tx_pop(self._app, C.byref(f)))

    def _uart_read(self, buf: Any, cap: int) -> int:
        """Bytes the drive wrote to its UART, into buf."""
        if self._drive is not None:
            return int(self._L.sim_app_uart_read(self._drive, buf, cap))
        return int(self._L.fw_app_uart_read(self._app, buf, cap))

    def _app_ptr(self) -> int:
        """Address of the drive's ``fw_app_t`` (for tests that read its object dictionary)."""
        if self._drive is not None:
            return int(self._L.sim_app_fw_app(self._drive))
        return C.addressof(self._app)

    def nvm_state(self) -> int:
        """``fw_app_nvm_state_t`` of the drive's boot (0: no storage)."""
        return int(self._L.sim_app_nvm_state(self._drive)) if self._drive is not None else 0

    # ---- stepping --------------------------------------------------------
    def _flush_rx(self) -> None:
        while True:
            msg = self.bus.recv(timeout=0)
            if msg is None:
                return
            if msg.is_extended_id or msg.is_error_frame:
                continue
            f = FwCanFrame()
            f.id = msg.arbitration_id
            f.dlc = min(msg.dlc, 8)
            f.rtr = 1 if msg.is_remote_frame else 0
            for i, b in enumerate(bytes(msg.data)[:8]):
                f.data[i] = b
            self._can_rx(f)

    def _flush_tx(self) -> None:
        f = FwCanFrame()
        while self._can_pop(f):
            msg = can.Message(arbitration_id=f.id, is_extended_id=False,
                              data=bytes(f.data[: f.dlc]), is_remote_frame=bool(f.rtr))
            self.bus.send(msg)
        buf = C.create_string_buffer(4096)
        n = self._uart_read(buf, 4096)
        if n:
            self.uart += buf.raw[:n]

    def advance(self, n_steps: int, channels: Sequence[str] | None = None,
                ) -> dict[str, np.ndarray]:
        """Run n_steps control periods now, exchanging frames every chunk.

        Frames sent to the drive before the call are processed in its first
        control period. With ``channels`` (names of ``sim_fallback``'s record,
        e.g. ``t_s``, ``duty_abc`` (NaN while the PWM is off), ``v_mps``,
        ``fault_code``) every period is recorded and returned, plus ``step``
        (the drive's control period index); without a plant only ``step``,
        ``pwm_enable`` and ``duty_abc`` exist.
        """
        parts: list[dict[str, np.ndarray]] = []
        with self._lock:
            left = n_steps
            while left > 0:
                k = min(left, self.chunk_steps)
                self._flush_rx()
                rec: dict[str, np.ndarray] = {}
                if self.sim is not None:
                    rec = self.sim.advance(k, decimation=1 if channels else k,
                                           channels=list(channels or []))
                else:
                    pwm, duty = np.zeros(k, np.uint8), np.zeros((k, 3))
                    for j in range(k):
                        self._L.fw_app_step(self._app, C.byref(self._in), C.byref(self._out))
                        pwm[j] = self._out.pwm_enable
                        duty[j] = self._out.duty_abc[:] if pwm[j] else [np.nan] * 3
                    rec = {"pwm_enable": pwm, "duty_abc": duty}
                if channels:
                    rec["step"] = np.arange(self.steps, self.steps + k, dtype=np.int64)
                    parts.append(rec)
                self.steps += k
                self._flush_tx()
                left -= k
        if not parts:
            return {}
        return {name: np.concatenate([p[name] for p in parts]) for name in parts[0]}

    def state(self) -> dict[str, float]:
        """True plant state (truth, for test assertions), {} without a plant."""
        return self.sim.state() if self.sim is not None else {}

    def _run(self) -> None:
        t0 = time.perf_counter()
        s0 = self.steps
        dt = 1.0 / self.f_pwm_Hz
        try:
            while not self._stop.is_set():
                self.advance(self.chunk_steps)
                if self.realtime > 0:
                    due = t0 + (self.steps - s0) * dt / self.realtime
                    wait = due - time.perf_counter()
                    if wait > 0:
                        time.sleep(wait)
                    elif wait < -0.005:
                        # fell behind (GIL, scheduler): do not catch up in a
                        # burst, which would compress wall-clock gaps between
                        # received frames into nothing of simulated time
                        t0 -= wait
        except BaseException as e:  # pragma: no cover - reported to the test
            self.error = e

    def start(self) -> None:
        """Step in a background thread, paced to wall-clock time."""
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="drive-bridge", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        if self._thread is not None:
            self._stop.set()
            self._thread.join(timeout=5)
            self._thread = None

    def close(self) -> None:
        self.stop()
        if self.sim is not None:
            self.sim.close()  # first: the loop's controller points into the drive
            self.sim = None
        if self._drive is not None:
            self._L.sim_app_free(self._drive)
            self._drive = None

    def __enter__(self) -> DriveBridge:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
