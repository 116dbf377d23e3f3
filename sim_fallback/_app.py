"""The drive application (fw_app) in C on a python-can bus: the simulated CAN node.

The drive application (control core + CANopen node + serial link,
``firmware_c/comm``) runs either in closed loop with the simulated plant
(:class:`sim_fallback.Sim`) or against a null plant (zero currents, constant DC link;
enough for NMT/SDO/PDO/heartbeat/EMCY).

With the plant it runs as on the MCU: the simulator library holds the whole
drive behind its own implementation of the port (``sim_fallback/src/
sim_port.c``, ``sim_app_*``): the batch loop's ADC counts go through the
board glue's control interrupt (``fw_board_control_isr``: the firmware's one
ADC conversion, the step, the duties) and the background loop
(``fw_board_background``: CANopen, OD, EMCY, telemetry) runs every
``background_every`` control periods in between; the frames and UART bytes
it sends through the port are collected here. The drive is configured with the
very ``fw_config_t`` of its :class:`Sim` (:func:`sim_fallback.drive_params`: the one
configuration path of every simulated drive), through the one binding of
:mod:`sim_fallback._lib`. The null plant steps the application library's
``fw_app_step`` (both halves in one call).

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

from . import _lib
from ._lib import FwCanFrame, FwConfig, FwInputs, FwOutputs

log = logging.getLogger(__name__)


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
                from ._sim import Sim

                self.sim = Sim(**(sim_kwargs or {}))
            except Exception:
                if plant == "sim":
                    raise
                self.sim = None
        self.f_pwm_Hz = 24000.0
        if self.sim is not None:
            # with the plant, the simulator library holds the drive application too
            self._L = _lib.lib()
            st = C.c_int(0)
            path = os.fsencode(str(nvm_path)) if nvm_path else None
            self._drive = self._L.sim_app_new(C.byref(self.sim.cfg), node_id, path,
                                              C.byref(st))
            if not self._drive:
                self.sim.close()
                raise RuntimeError(f"fw_app_init returned fw_status_t {st.value} "
                                   "(configuration refused)")
            self.f_pwm_Hz = 1.0 / self.sim.dt_s
            port = _lib.SimController()
            self._L.sim_app_controller(self._drive, max(1, int(background_every)),
                                       C.byref(port))
            self._port = port
            self.sim._L.sim_set_controller(self.sim._h, C.byref(port))
            self._L.sim_app_background_now(self._drive)  # the boot-up message
            # the drive's current-zero calibration; the simulator's time runs with the
            # drive's clock (its period count is the time base of telemetry and EMCY)
            boot_steps = self.sim.boot(advance_time=True)
        else:
            boot_steps = 0
            self._L = _lib.comm_lib()
            cfg = FwConfig()
            self._L.fw_config_default(C.byref(cfg))
            self._app = C.create_string_buffer(self._L.fw_app_sizeof())
            rc = self._L.fw_app_init(self._app, C.byref(cfg), node_id)
            if rc != 0:
                raise RuntimeError(f"fw_app_init returned fw_status_t {rc} "
                                   "(configuration refused)")
        self._in = FwInputs()
        self._in.u_dc_V = 300.0
        self._out = FwOutputs()
        # the drive's period count (the time base of its telemetry and EMCY) counts its
        # boot's periods too
        self.steps = boot_steps
        self.uart = bytearray()
        self.sent: list[can.Message] = []
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.error: BaseException | None = None
        self._flush_tx()  # boot-up message

    def config(self) -> FwConfig:
        """The drive's running configuration (``fw_config_t``: booted from its non-volatile
        memory when that held one, as changed since over the bus); with the plant only."""
        if self._drive is None:
            raise RuntimeError("a drive without the plant has no simulator configuration")
        cfg = FwConfig()
        self._L.sim_app_config(self._drive, C.byref(cfg))
        return cfg

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
