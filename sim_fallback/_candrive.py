"""The simulated drive on a python-can ``virtual`` bus: same CANopen as hardware.

:class:`SimDrive` runs

* the plant and the batch loop of ``sim_fallback`` (``sim_t``, truth), and
* the drive application of ``firmware_c/comm`` (``fw_app_t``: the firmware
  core + the C CANopen slave + the serial link) behind the simulator's port
  (``sim_port.c``): its control interrupt on the loop's ADC counts, its
  background loop between the control periods, through the same board glue
  (``fw_board.c``) as the MCU image, so the firmware that runs is the
  firmware that ships, shaped as it runs there.

It is a :class:`sim_fallback.DriveBridge` (library loading, the
configuration taken over by field name, the controller port, the boot-up
message) extended for the bench: a
background thread steps it in chunks (default 1 ms of simulated time, one C
call each); between chunks it forwards CAN frames between the virtual bus and
the C slave, produces SYNC (it is the bus's SYNC producer, period = one
chunk), applies load changes to the plant, hands the UART bytes to a
serial-port-like object (:attr:`SimDrive.serial`) and passes the recorded
truth + firmware signals to a sink (the run logger). Truth never travels over
the bus.

Pacing
    ``realtime=False`` (CI): the simulated clock is driven by the bench, never
    by the wall clock: it advances while the bench waits for it
    (:meth:`SimClock.sleep_until` raises the horizon) and by exactly one chunk
    per frame the bench sends (one frame enters the C slave per chunk; an SDO
    request is answered within that chunk). The bench's own latency therefore
    eats no simulated time, sequence events land at their nominal times, and a
    run is reproducible: the same sequence and seed give the same samples,
    whatever the machine's load. Two hand-overs make it so: a wait returns only
    after the bench's receive thread has dispatched every frame the drive sent
    (:meth:`SimDrive.attach_peer`), and the bench reads the time only after the
    chunk that answered it has published its end (``t_s``).
    Runs go as fast as the CPU allows.
    ``realtime=True`` (live): the simulated clock follows the wall clock and
    every pending frame enters at the next chunk. A lag behind the wall clock
    is made up at full speed; with ``max_lag_s`` set (the simulated drive
    server, whose process can be stopped), a drive that finds itself further
    behind than that (its process was stopped, SIGSTOP or a suspended machine,
    or starved of CPU) does not run the lost time: its clock pauses for it, as
    the bus it sees stood still too (no heartbeat could reach it), and the
    stall is counted (:attr:`SimDrive.stalls`, :attr:`SimDrive.stalled_s`).
    Running it would make a second of a frozen bus a second of silence for
    the drive: its heartbeat consumer faults (0x8130) on a supervisor that was
    alive.

Frame timestamps on the bus are ``epoch + simulated time`` (s); a stall moves
``epoch`` on by the paused time, so that they stay on the wall clock.
"""

from __future__ import annotations

import ctypes as C
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import can
import numpy as np

from ._app import DriveBridge
from ._lib import FwCanFrame

log = logging.getLogger("sim_fallback.candrive")

#: Channels recorded from the simulation (truth + firmware internals) and their units.
SIM_CHANNELS: dict[str, str] = {
    "theta_e_rad": "rad", "omega_e_radps": "rad/s", "x_m": "m", "v_mps": "m/s",
    "force_N": "N", "load_N": "N", "i_d_A": "A", "i_q_A": "A",
    "theta_hat_rad": "rad", "omega_hat_radps": "rad/s", "omega_f_radps": "rad/s",
    "pll_err_rad": "rad",
    "hf_amp_A": "A", "sogi_k_eff": "", "i_dq_hat_A": "A", "speed_ref_radps_e": "rad/s",
    "cia402_state": "", "start_phase": "", "fault_code": "",
}


#: How every drive the bench simulates models its plant, the host's and the emulated
#: board's alike (sim_fallback.emu_boot_blob): the ADC noise restarts from the seed when
#: the inverter is switched on, so the noise after an enable depends on the seed alone -
#: not on how long the drive idled on the bus before it (which differs between the two,
#: and between any two runs reached over a bus): the twin comparison then compares the
#: drives, not two draws of the noise (docs/boards.md).
BENCH_PLANT: dict[str, Any] = {"noise_restart": 1}


class SimSerial:
    """Serial-port-like byte pipe carrying the drive's UART output (read side).

    Has the part of the ``serial.Serial`` interface the telemetry reader uses
    (``read``, ``in_waiting``, ``timeout``, ``close``).
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._cond = threading.Condition()
        self.timeout: float | None = 0.1
        self.closed = False

    def feed(self, data: bytes) -> None:
        with self._cond:
            self._buf += data
            self._cond.notify_all()

    @property
    def in_waiting(self) -> int:
        return len(self._buf)

    def read(self, size: int = 1) -> bytes:
        with self._cond:
            if not self._buf and not self.closed:
                self._cond.wait(self.timeout)
            out = bytes(self._buf[:size])
            del self._buf[:size]
            return out

    def close(self) -> None:
        with self._cond:
            self.closed = True
            self._cond.notify_all()


class SimClock:
    """The simulated drive's clock (s of simulated time = control steps x dt)."""

    exact_steps = True
    #: the runner's wait slice (s of simulated time): each slice is a hand-over between
    #: the bench and the simulation thread; 10 ms slices cost the main job 0.1-0.2 s, and a
    #: fault's power-stage switch-off does not wait for the bench anyway
    slice_s = 0.05

    def __init__(self, drive: SimDrive) -> None:
        self._d = drive

    def now(self) -> float:
        return self._d.t_s

    def sleep_until(self, t_s: float) -> None:
        self._d.run_until(t_s)


class SimDrive(DriveBridge):
    """Plant + firmware application + C CANopen slave on a virtual CAN bus.

    Parameters
    ----------
    channel : str
        python-can ``virtual`` channel name (unique per run).
    motor : str
        Motor file name or path (``sim_fallback/motors``).
    extractor : {"pseudo", "sogi", "sogi_adaptive"}
    seed : int
        ADC noise seed.
    x0 : float or "random"
        Initial true position (m) or a seed-derived random one.
    node_id : int
    realtime : bool
        Pace to the wall clock (live) instead of running as fast as possible.
    chunk_s : float
        Simulated time per C call and SYNC period (s).
    record_decimation : int
        Record every n-th control period (1 = full rate).
    sink : callable(t_s, values, units), optional
        Receives each recorded chunk (truth + firmware signals).
    noise : float
        Scale of the motor file's ADC noise and offsets.
    plant : dict, optional
        Plant overrides (``sim_fallback.Sim``'s ``plant``): the motor actually simulated
        differs from ``motor``, from which the drive is configured.
    max_lag_s : float, optional
        Paced only: a lag behind the wall clock beyond this (s) is a stall; the clock
        pauses for it instead of running it at full speed (module docstring, Pacing).
        None (default): every lag is made up (an in-process drive, whose frame
        timestamps the bench maps back to its time through ``epoch``).
    """

    #: ``max_lag_s`` of the simulated drive server: 50 chunks of 1 ms. Above a thread's
    #: scheduling jitter on a loaded machine (a few ms), and well below any heartbeat
    #: consumer time the bench uses (500 ms), so that the lag made up at full speed
    #: never faults the drive
    MAX_LAG_S = 0.05

    def __init__(self, channel: str, motor: str = "paper_salient",
                 extractor: str = "sogi_adaptive", seed: int = 0, x0: float | str = 0.0,
                 node_id: int = 1, realtime: bool = False, chunk_s: float = 1e-3,
                 record_decimation: int = 1,
                 sink: Callable[[np.ndarray, dict[str, np.ndarray], dict[str, str]], None]
                 | None = None, noise: float = 1.0,
                 plant: dict[str, Any] | None = None, nvm_path: Any = None,
                 background_every: int = 1, max_lag_s: float | None = None) -> None:
        from ._motors import load_motor

        #: plant overrides: the motor actually simulated, when it is not the configured one
        self.plant_overrides = dict(plant or {})

        # set before DriveBridge.__init__, which already calls _flush_tx (boot-up)
        self.channel = channel
        self.paced = realtime
        self.sink = sink
        self.record_decimation = record_decimation
        self.frames_to_bus = 0
        self.frames_from_bus = 0
        self.rx_dropped = 0
        self.syncs_sent = 0
        self.sent_by_id: dict[int, int] = {}
        self.cpu_s = 0.0  # CPU time of the simulation thread while stepping (s)
        self.max_lag_s = max_lag_s
        self.stalls = 0  # paced: times the clock paused (lag beyond max_lag_s)
        self.stalled_s = 0.0  # ... and the wall-clock time it paused for in all (s)
        self.last_stall_s = 0.0
        self.serial = SimSerial()
        self.epoch = time.time()
        self.peer_bus: Any = None  # the bench's bus on the virtual channel (attach_peer)
        self._peer_base = 0  # frames_sent before the bench's bus was attached
        self._peer_seen = 0  # ... of them the bench's receive thread has dispatched
        self._peer_cond = threading.Condition()
        self._t_lock = threading.Lock()  # a chunk's frames out + its time published
        self._t = 0.0
        self._held: list[can.Message] = []
        self._uart_buf = C.create_string_buffer(8192)
        mot = load_motor(motor)
        if x0 == "random":
            x0_m = float(np.random.default_rng([int(seed), 0x5EED]).uniform(0.0, 2.0 * mot.tau_m))
        else:
            x0_m = float(x0)
        self.x0_m = x0_m
        bus = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True,
                      receive_own_messages=False)
        try:
            super().__init__(bus, node_id=node_id, plant="sim",
                             chunk_steps=max(1, int(round(chunk_s * mot.plant["f_pwm_Hz"]))),
                             realtime=0.0, sim_kwargs={"motor": mot, "extractor": extractor,
                                                       "seed": seed, "noise": noise,
                                                       "x0_m": x0_m,
                                                       "plant": {**BENCH_PLANT,
                                                                 **(plant or {})}},
                             background_every=background_every, nvm_path=nvm_path)
        except BaseException:
            bus.shutdown()
            raise
        assert self.sim is not None
        self.node_id = node_id
        self.motor = self.sim.motor
        self.dt_s = self.sim.dt_s
        self.n_chunk = self.chunk_steps
        self.chunk_s = self.n_chunk * self.dt_s
        self.clock = SimClock(self)
        self._cond = threading.Condition()
        self._horizon = 0.0
        self._pending: deque[tuple[str, tuple[Any, ...]]] = deque()
        self._idle = threading.Event()
        self._wall0 = time.monotonic()
        self._sync = FwCanFrame()
        self._sync.id, self._sync.dlc, self._sync.rtr = 0x080, 0, 0

    # ---- life cycle -------------------------------------------------------------------
    def start(self) -> SimDrive:  # type: ignore[override]
        """Start the simulation thread."""
        if self._thread is None:
            self._wall0 = time.monotonic() - self._t
            self._stop.clear()
            self._thread = threading.Thread(target=self._loop, name=f"simdrive-{self.channel}",
                                            daemon=True)
            self._thread.start()
        return self

    def close(self) -> None:
        """Stop the thread, free the simulation, close the bus."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        super().close()
        self.serial.close()
        self.bus.shutdown()

    def __enter__(self) -> SimDrive:  # type: ignore[override]
        return self.start()

    # ---- clock ------------------------------------------------------------------------
    @property
    def t_s(self) -> float:
        """Simulated time (s): the end of the last chunk whose frames are on the bus."""
        with self._t_lock:
            return self._t

    def run_until(self, t_s: float, timeout_s: float | None = None) -> None:
        """Let the simulation run to ``t_s`` and block until it got there."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        with self._cond:
            self._horizon = max(self._horizon, t_s)
            self._cond.notify_all()
            while self._t < t_s - 1e-12:
                if self.error is not None:
                    raise RuntimeError(f"simulated drive stopped: {self.error}")
                if self._stop.is_set():
                    raise RuntimeError("simulated drive closed")
                if deadline is not None and time.monotonic() > deadline:
                    raise TimeoutError(f"simulation did not reach {t_s} s")
                self._cond.wait(0.1)
        self._drain_peer()

    def attach_peer(self, bus: Any, notifier: Any) -> None:
        """The bench's side of the virtual bus: ``bus`` and the ``can.Notifier`` that
        dispatches its frames (canopen's). A listener added after the bench's own counts
        the frames the notifier has handed to every listener before it, so that
        :meth:`run_until` returns only when the bench has processed each frame the drive
        sent so far (a TPDO's statusword included). Without it, what the bench reads
        after a wait, and so the simulated time of its next command, depended on its
        receive thread's timing: a loaded machine gave a different run."""
        with self._peer_cond:
            self.peer_bus = bus
            # sent before (boot-up): the bench never receives them. The drive must be
            # idle here (not paced), or frames in flight would be miscounted
            self._peer_base = self.frames_sent
            self._peer_seen = 0
        notifier.add_listener(self._peer_dispatched)

    def _peer_dispatched(self, msg: can.Message) -> None:
        with self._peer_cond:
            self._peer_seen += 1
            self._peer_cond.notify_all()

    @property
    def frames_sent(self) -> int:
        """Frames this drive has put on the bus: its own (TPDOs, answers, EMCY, ...)
        and the SYNC it produces."""
        return self.frames_to_bus + self.syncs_sent

    def _drain_peer(self, timeout_s: float = 5.0) -> None:
        """Wait until the bench has dispatched every frame sent so far (attach_peer);
        not when paced to the wall clock, where runs are not reproducible anyway."""
        if self.peer_bus is None or self.paced:
            return
        with self._peer_cond:
            ok = self._peer_cond.wait_for(
                lambda: self._peer_seen >= self.frames_sent - self._peer_base, timeout_s)
            if not ok:
                # a stalled or closed bench: not fatal for the drive; the run may differ
                log.warning("the bench dispatched %d of %d frames within %.1f s",
                            self._peer_seen, self.frames_sent - self._peer_base, timeout_s)

    def set_realtime(self, on: bool) -> None:
        """Switch pacing; wall-clock pacing resumes from the present simulated time."""
        self._wall0 = time.monotonic() - self._t
        self._horizon = max(self._horizon, self._t)
        self.paced = on

    def wait_idle(self, timeout_s: float = 5.0) -> bool:
        """Wait until the simulation is paused (nothing to run, no frames pending)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self._idle.is_set() and not self._want_run():
                time.sleep(0.002)
                if self._idle.is_set() and not self._want_run():
                    return True
            time.sleep(0.001)
        return False

    # ---- load (truth side: the plant's external force) -------------------------------
    def set_load_N(self, force_N: float) -> None:
        """Apply a constant external load (N, opposes +x) from the next chunk on."""
        self._pending.append(("load", (float(force_N),)))

    def ramp_load_N(self, force_N: float, duration_s: float) -> None:
        """Ramp the external load linearly to ``force_N`` over ``duration_s``."""
        self._pending.append(("ramp", (float(force_N), float(duration_s))))

    def truth_state(self) -> dict[str, float]:
        """True plant state (for logs and metrics only)."""
        return self.state()

    # ---- DriveBridge hooks ------------------------------------------------------------
    def _flush_rx(self, limit: int | None = None) -> int:  # type: ignore[override]
        """Frames from the bench into the C slave's receive queue (at most ``limit``)."""
        while (m := self.bus.recv(timeout=0)) is not None:
            self._held.append(m)
        n_take = len(self._held) if limit is None else min(limit, len(self._held))
        msgs, self._held = self._held[:n_take], self._held[n_take:]
        f = FwCanFrame()
        n = 0
        for msg in msgs:
            if msg.is_extended_id or msg.is_error_frame:
                continue
            f.id = msg.arbitration_id
            f.dlc = min(msg.dlc, 8)
            f.rtr = 1 if msg.is_remote_frame else 0
            C.memmove(f.data, bytes(msg.data).ljust(8, b"\0"), 8)
            if not self._can_rx(f):
                self.rx_dropped += 1
            n += 1
        self.frames_from_bus += n
        return n

    def _flush_tx(self, t_s: float | None = None) -> None:
        """Frames from the C slave to the bus, stamped with the simulated time."""
        f = FwCanFrame()
        ts = self.epoch + (self._t if t_s is None else t_s)
        while self._can_pop(f):
            self.bus.send(can.Message(arbitration_id=f.id, data=bytes(f.data[: f.dlc]),
                                      is_extended_id=False, is_remote_frame=bool(f.rtr),
                                      timestamp=ts))
            self.frames_to_bus += 1
            self.sent_by_id[f.id] = self.sent_by_id.get(f.id, 0) + 1
        n = self._uart_read(self._uart_buf, len(self._uart_buf))
        if n:
            self.serial.feed(self._uart_buf.raw[:n])

    # ---- the thread ---------------------------------------------------------------------
    def _apply_pending(self) -> None:
        from ._sim import SIM_REF_LOAD

        assert self.sim is not None
        while self._pending:
            kind, args = self._pending.popleft()
            t = self._t
            if kind == "load":
                self.sim.set_schedule(SIM_REF_LOAD, [(t, args[0])])
            else:
                now = float(self.sim._L.sim_sched_value(self.sim._h, SIM_REF_LOAD))
                now = 0.0 if math.isnan(now) else now
                self.sim.set_schedule(SIM_REF_LOAD, {"t_s": [t, t + args[1]],
                                                     "value": [now, args[0]], "ramp": True})

    def _keep_pace(self, max_lag_s: float) -> None:
        """Paced: a lag beyond ``max_lag_s`` pauses the clock for the lost time (a stall,
        counted) instead of being run at full speed."""
        lag = time.monotonic() - self._wall0 - self._t
        if lag > max_lag_s:
            self._wall0 += lag
            self.epoch += lag  # frame timestamps stay on the wall clock
            self.stalls += 1
            self.stalled_s += lag
            self.last_stall_s = lag
            log.info("simulated drive %s: %.3f s behind the wall clock (its process was "
                     "stopped or starved): its clock paused for it", self.channel, lag)

    def _want_run(self) -> bool:
        if self.paced:
            return self._t < time.monotonic() - self._wall0
        return self._t < self._horizon - 1e-12 or bool(self._held)

    def _chunk(self) -> dict[str, np.ndarray]:
        """One chunk: bench frames in, SYNC, n control periods recorded, frames out."""
        assert self.sim is not None
        self._flush_rx(None if self.paced else 1)
        self._apply_pending()
        self._can_rx(self._sync)  # we are the SYNC producer
        self.bus.send(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False,
                                  timestamp=self.epoch + self._t))
        self.syncs_sent += 1
        rec = self.sim.advance(self.n_chunk, self.record_decimation,
                               ["t_s", *SIM_CHANNELS] if self.sink else [])
        self.steps += self.n_chunk
        # the chunk's frames are on the bus before its time is: a waiter that sees the
        # new time (run_until) also finds the drive's answers of that chunk; and both
        # under one lock with the clock's reader (t_s): a bench that got an answer of
        # this chunk and reads the time gets the chunk's end, never the time before it
        # (which depended on the threads' timing and moved every later event by a chunk)
        t = self.sim.t_s
        with self._t_lock:
            self._flush_tx(t)
            self._t = t
        return rec

    @staticmethod
    def _deliver(sink: Any, recs: list[dict[str, np.ndarray]]) -> None:
        if len(recs) == 1:
            rec = recs[0]
        else:
            rec = {k: np.concatenate([r[k] for r in recs]) for k in recs[0]}
        t = rec.pop("t_s")
        sink(t, rec, SIM_CHANNELS)

    def _loop(self) -> None:
        pending: list[dict[str, np.ndarray]] = []
        try:
            while not self._stop.is_set():
                if self.paced and self.max_lag_s is not None:
                    self._keep_pace(self.max_lag_s)
                if not self._want_run():
                    self._idle.set()
                    # idle: block briefly for a frame from the bench (held for the next
                    # chunk) or a new horizon
                    msg = self.bus.recv(0.0005)
                    if msg is not None:
                        self._held.append(msg)
                    continue
                self._idle.clear()
                c0 = time.thread_time()
                with self._lock:
                    rec = self._chunk()
                self.cpu_s += time.thread_time() - c0
                sink = self.sink
                if sink is None:
                    pending.clear()
                elif "t_s" in rec and rec["t_s"].size:
                    pending.append(rec)
                # the records go to the sink in batches (one logger append per channel
                # per 50 ms of drive time instead of per 1 ms chunk; 10 ms when paced for
                # live viewing), and always before waiters hear that the horizon is
                # reached, so that what they read next includes it
                if pending and (len(pending) >= (10 if self.paced else 50)
                                or not self._want_run()):
                    self._deliver(sink, pending)
                    pending = []
                with self._cond:
                    self._cond.notify_all()
        except BaseException as e:  # surfaced to waiters
            self.error = e
            log.exception("simulated drive thread died")
            with self._cond:
                self._cond.notify_all()


class SimLoad:
    """The load device of the simulated drive: the plant's external force.

    Parameters
    ----------
    drive : SimDrive
    """

    name = "sim"

    def __init__(self, drive: SimDrive) -> None:
        self.drive = drive

    def enable(self) -> None:
        pass

    def disable(self) -> None:
        self.drive.set_load_N(0.0)

    def set_force_N(self, force_N: float) -> None:
        self.drive.set_load_N(force_N)

    def ramp_force_N(self, force_N: float, duration_s: float) -> bool:
        self.drive.ramp_load_N(force_N, duration_s)
        return True
