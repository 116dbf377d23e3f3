"""The bench's HARDWARE load path against a real (simulated) CANopen load machine.

Two drive applications (the real C firmware + C CANopen slave, ``fw_app``, each in closed
loop with its own simulated plant, :class:`sim_fallback.DriveBridge`) share one
python-can ``virtual`` channel and are paced to the wall clock:

* node 1: the drive under test (speed mode),
* node 2: the load machine, which the bench drives as a second CiA 402 node in cyclic
  synchronous torque mode (:class:`bench.CanopenLoad`, created by
  ``open_hardware(..., load_node=2)``).

The bench connects with ``connect(interface="virtual", channel=..., load_node=2)``, i.e. the
hardware path (no ``--sim``): it cannot tell these nodes from real drives.

The two drives are NOT mechanically coupled here: each has its own simulated plant, so the
load machine's force does not act on the drive under test's mover. What is checked is the
load machine itself, observed from inside node 2 (its object dictionary read directly from the
C slave through the bridge after every 1 ms chunk, and its plant's true current), never
through the bench's own view:

* it is walked to OPERATION ENABLED in cyclic synchronous torque mode (0x6061 = 10),
* its target torque 0x6071 gets the load step in the bench's units: per mille of the load
  machine's rated force K_f i_max_A (K_f = 1.5 pi / tau psi_f, od.yaml "torque"), with the sign
  inverted (a positive load opposes positive motion, so the load machine pushes backwards),
  and its motor really produces that thrust,
* after the sequence, and after an exception injected mid-sequence, the load is removed
  (0x6071 = 0) and node 2 is disabled (SWITCH ON DISABLED): the safe state covers the load
  machine too,
* while the bench runs, node 2 watches the bench's heartbeat (0x1016:1) like node 1, so a dead
  bench also stops the load machine; the watch is switched off again on a clean close.
"""

from __future__ import annotations

import ctypes as C
import json
import math
import threading
import time
import uuid
from pathlib import Path
from typing import Any

import can
import pytest
from canopen.profiles.p402 import State402

from bench import CanopenLoad, WallClock, connect, run_sequence, validate_sequence
from sim_fallback import DriveBridge

MOTOR = "paper_salient"
DUT, LOAD = 1, 2
#: bench heartbeat watch written to 0x1016:1 (producer 0x7F, 5 x 100 ms)
HB_WATCH = (0x7F << 16) | 500
#: 1 N*m rotary equivalent = 32.7 N on the mover: below the plant's static friction (49 N),
#: so the uncoupled load machine's mover stays put while it pushes
LOAD_NM = 1.0


def _why_unavailable() -> str | None:
    try:
        from protocols import clib
        from sim_fallback import _lib

        _lib.lib()
        clib.load_app()
    except (OSError, ImportError) as e:
        return str(e)
    return None


_WHY = _why_unavailable()
pytestmark = pytest.mark.skipif(_WHY is not None, reason=f"drive libraries unavailable: {_WHY}")


def _state_name(sw: int) -> str:
    for name, (mask, bits) in State402.SW_MASK.items():
        if sw & mask == bits:
            return name
    return "UNKNOWN"


class _ObservedDrive(DriveBridge):
    """A drive application on the bus that records its own object dictionary after every
    chunk (read in the C slave, not over the bus) and its plant's true q current."""

    #: (index, sub, signed) of the objects recorded
    OBJECTS = {"sw": (0x6041, 0, False), "cw": (0x6040, 0, False), "mode": (0x6061, 0, True),
               "torque": (0x6071, 0, True), "hb_watch": (0x1016, 1, False),
               "fault": (0x603F, 0, False)}

    def __init__(self, bus: can.BusABC, node_id: int) -> None:
        super().__init__(bus, node_id=node_id, plant="sim", chunk_steps=24, realtime=1.0,
                         sim_kwargs={"motor": MOTOR, "seed": node_id})
        self._L.fw_app_node.argtypes = [C.c_void_p]
        self._L.fw_app_node.restype = C.c_void_p
        self._L.co_node_read.argtypes = [C.c_void_p, C.c_uint16, C.c_uint8,
                                         C.POINTER(C.c_uint8), C.POINTER(C.c_size_t)]
        self._L.co_node_read.restype = C.c_uint32
        self._node = self._L.fw_app_node(self._app_ptr())
        self.log: list[dict[str, Any]] = []
        self.log_lock = threading.Lock()

    def od(self, index: int, sub: int = 0, signed: bool = False) -> int:
        """Value of an object in node ``node_id``'s own object dictionary."""
        buf = (C.c_uint8 * 8)()
        n = C.c_size_t(8)
        abort = self._L.co_node_read(self._node, index, sub, buf, C.byref(n))
        assert abort == 0, f"0x{index:04X}:{sub} abort 0x{abort:08X}"
        return int.from_bytes(bytes(buf[: n.value]), "little", signed=signed)

    def sample(self) -> dict[str, Any]:
        s: dict[str, Any] = {k: self.od(*v) for k, v in self.OBJECTS.items()}
        s["state"] = _state_name(s["sw"])
        s["t_wall"] = time.monotonic()
        s["i_q_A"] = self.state()["i_q_A"]
        return s

    def advance(self, n_steps: int) -> None:
        super().advance(n_steps)
        with self._lock:
            s = self.sample()
        with self.log_lock:
            self.log.append(s)

    def history(self) -> list[dict[str, Any]]:
        with self.log_lock:
            return list(self.log)

    def now(self) -> dict[str, Any]:
        """A fresh sample (waits for one more chunk so that the last frames are applied)."""
        n = len(self.history())
        deadline = time.monotonic() + 1.0
        while len(self.history()) < n + 3 and time.monotonic() < deadline:
            time.sleep(0.002)
        return self.history()[-1]


@pytest.fixture
def two_drives():
    ch = f"pmlsm-2node-{uuid.uuid4().hex[:8]}-vcan"  # no trailing digits (BLF channel)
    buses = [can.Bus(interface="virtual", channel=ch) for _ in (DUT, LOAD)]
    drives: list[_ObservedDrive] = []
    try:
        for bus, nid in zip(buses, (DUT, LOAD), strict=True):
            drives.append(_ObservedDrive(bus, nid))
        for d in drives:
            d.start()
        time.sleep(0.05)
        yield ch, drives[0], drives[1]
    finally:
        for d in drives:
            d.close()
        for bus in buses:
            bus.shutdown()
    for d in drives:
        assert d.error is None, f"node {d.node_id} bridge thread died: {d.error!r}"


SEQ = f"""
name: load_node_hil
motor: {MOTOR}
extractor: sogi_adaptive
seed: 1
steps:
  - enable: {{mode: speed}}
  - set_speed: {{value: 30, unit: r/min}}
  - wait: {{duration_s: 0.2}}
  - load_step: {{value: {LOAD_NM}, unit: N*m}}
  - wait: {{duration_s: 0.4}}
  - disable: {{}}
"""


def _connect(ch: str) -> Any:
    said: list[str] = []
    conn = connect(interface="virtual", channel=ch, load_node=LOAD, motor=MOTOR,
                   say=said.append)
    assert not conn.is_sim, said
    # the hardware code path (a bus, --load-node), labelled from what the drive says it
    # is: the drive bridge's simulated drive says "simulated", never HARDWARE
    assert conn.info["via"] == "bus" and conn.kind == "simulated"
    assert "SIMULATED" in conn.description and "FALLING BACK" not in " ".join(said)
    assert isinstance(conn.load, CanopenLoad) and conn.load.drive.node_id == LOAD
    return conn


def _expected_permille(conn: Any, drive: _ObservedDrive) -> tuple[float, int]:
    """The load force (N) and the load machine's 0x6071 for it, from node 2's own config."""
    assert drive.sim is not None
    cfg = drive.sim.cfg
    force_n = conn.units.force_to_N(LOAD_NM, "N*m")
    assert force_n == pytest.approx(LOAD_NM / (cfg.pole_pairs * cfg.pole_pitch_m / math.pi))
    rated_n = 1.5 * math.pi / cfg.pole_pitch_m * cfg.psi_f_Wb * cfg.i_max_A
    # the bench reads the load machine's own rating (0x2050) for its per mille
    assert conn.load.drive.force_rated_N == pytest.approx(rated_n, rel=1e-5)
    pm = round(-1000.0 * force_n / rated_n)
    assert pm != 0
    return force_n, pm


def _assert_released(drive: _ObservedDrive) -> None:
    s = drive.now()
    assert s["torque"] == 0, s
    assert s["state"] == "SWITCH ON DISABLED", s


def test_load_machine_follows_the_sequence_and_is_released(two_drives, tmp_path: Path):
    ch, dut, load = two_drives
    conn = _connect(ch)
    try:
        _, pm = _expected_permille(conn, load)
        out = run_sequence(validate_sequence(SEQ), conn, runs_root=str(tmp_path),
                           progress=False, report=False)
        assert out.interrupted is None, out.result.error
        assert out.result.safe_state == "disabled"
        assert not out.result.aborted
        _assert_released(load)
        _assert_released(dut)
        during = load.history()
    finally:
        conn.close()

    # walked to OPERATION ENABLED in torque mode (with zero torque) before the load step
    first_on = next(s for s in during if s["state"] == "OPERATION ENABLED")
    assert first_on["mode"] == 10 and first_on["torque"] == 0, first_on
    loaded = [s for s in during if s["torque"] == pm]
    assert loaded, f"0x6071 of node 2 never became {pm} per mille: " \
                   f"{sorted({s['torque'] for s in during})}"
    assert all(s["state"] == "OPERATION ENABLED" and s["mode"] == 10 for s in loaded)
    assert {s["torque"] for s in during} <= {0, pm}
    # ... for the load window (0.4 s of wall clock) and not after the disable step
    assert 0.25 <= loaded[-1]["t_wall"] - loaded[0]["t_wall"] <= 2.0
    # the load machine's motor produced that thrust: its plant's true q current (i_d ~ 0)
    # settles at 0x6071 / 1000 * i_max_A (about -0.92 A = -32.7 N here)
    assert load.sim is not None
    i_q_ref = pm * 1e-3 * load.sim.cfg.i_max_A
    settled = [s["i_q_A"] for s in loaded if s["t_wall"] > loaded[0]["t_wall"] + 0.1]
    assert settled
    i_q = sum(settled) / len(settled)
    assert i_q == pytest.approx(i_q_ref, rel=0.15), (i_q, i_q_ref)
    # removed before PWM off: torque back to 0 while still enabled, then disabled
    i_last = max(i for i, s in enumerate(during) if s["torque"] == pm)
    after = during[i_last + 1:]
    assert after and after[0]["torque"] == 0
    assert after[-1]["state"] == "SWITCH ON DISABLED"
    # node 2 watched the bench's heartbeat while it could move; switched off on close
    assert all(s["hb_watch"] == HB_WATCH for s in loaded)
    assert load.now()["hb_watch"] == 0
    assert dut.now()["hb_watch"] == 0
    # the drive under test ran in speed mode meanwhile
    dut_on = [s for s in dut.history() if s["state"] == "OPERATION ENABLED"]
    assert dut_on and all(s["mode"] == 9 for s in dut_on)


class _FailingClock(WallClock):
    """The bench's clock, raising in the middle of the wait after the load step (once node 2
    has held the load for ``after_s``), i.e. before the sequence's own disable step."""

    def __init__(self, load: _ObservedDrive, pm: int, exc: BaseException,
                 after_s: float = 0.1) -> None:
        self.load = load
        self.exc = exc
        self.pm = pm
        self.after_s = after_s
        self.at_failure: dict[str, Any] | None = None

    def sleep_until(self, t_s: float) -> None:
        loaded = [s for s in self.load.history() if s["torque"] == self.pm]
        if loaded and time.monotonic() - loaded[0]["t_wall"] >= self.after_s:
            self.at_failure = self.load.now()
            raise self.exc
        super().sleep_until(min(t_s, time.monotonic() + 0.01))


@pytest.mark.parametrize("exc", [RuntimeError("injected failure mid-sequence"),
                                 KeyboardInterrupt()], ids=["exception", "ctrl-c"])
def test_exception_mid_sequence_releases_the_load_machine(two_drives, tmp_path: Path,
                                                          exc: BaseException):
    """A failure in the bench while the load machine pushes (before the sequence's own
    disable step): the runner's safe state removes the load and disables node 2 too."""
    ch, dut, load = two_drives
    conn = _connect(ch)
    try:
        _, pm = _expected_permille(conn, load)
        seq = validate_sequence(SEQ)
        clock = _FailingClock(load, pm, exc)
        conn.drive.clock = clock
        out = run_sequence(seq, conn, runs_root=str(tmp_path), progress=False, report=False)
        assert out.interrupted is exc
        assert out.result.aborted and out.result.safe_state == "disabled"
        assert not any(e.get("step") == "disable" for e in _events(out.run_dir))
        _assert_released(load)
        _assert_released(dut)
    finally:
        conn.close()
    # at the failure node 2 was loaded, enabled, in torque mode
    at = clock.at_failure
    assert at is not None
    assert at["state"] == "OPERATION ENABLED" and at["mode"] == 10 and at["torque"] == pm, at
    assert at["hb_watch"] == HB_WATCH


def _events(run_dir: Path) -> list[dict[str, Any]]:
    p = Path(run_dir) / "events.jsonl"
    return [json.loads(line) for line in p.read_text().splitlines() if line.strip()]


def test_re_enable_keeps_the_load(two_drives, tmp_path: Path):
    """A second ``enable`` step (e.g. a mode change of the drive under test) must not drop
    the load: the simulated load (SimLoad) keeps it, so must the load machine."""
    ch, _, load = two_drives
    seq = validate_sequence(SEQ.replace(
        "  - wait: {duration_s: 0.4}\n",
        "  - wait: {duration_s: 0.2}\n  - enable: {mode: speed}\n"
        "  - wait: {duration_s: 0.2}\n"))
    conn = _connect(ch)
    try:
        _, pm = _expected_permille(conn, load)
        out = run_sequence(seq, conn, runs_root=str(tmp_path), progress=False, report=False)
        assert out.interrupted is None and out.result.safe_state == "disabled"
        _assert_released(load)
    finally:
        conn.close()
    during = load.history()
    on = [i for i, s in enumerate(during) if s["torque"] == pm]
    assert on and during[on[-1]]["t_wall"] - during[on[0]]["t_wall"] >= 0.3
    held = during[on[0]:on[-1] + 1]
    assert all(s["torque"] == pm and s["state"] == "OPERATION ENABLED" for s in held)


def test_dead_bench_stops_the_load_machine(two_drives):
    """The bench dies (its heartbeat stops) while the load machine pushes: node 2 faults on
    its own (0x8130 supervisor heartbeat lost) and stops producing force."""
    ch, _, load = two_drives
    conn = _connect(ch)
    try:
        force_n, pm = _expected_permille(conn, load)
        conn.start_heartbeat()
        conn.load.enable()
        conn.load.set_force_N(force_n)
        s = load.now()
        assert s["state"] == "OPERATION ENABLED" and s["torque"] == pm
        assert s["hb_watch"] == HB_WATCH
        time.sleep(0.3)  # a watch is armed by the first heartbeat after it was configured
        assert load.now()["state"] == "OPERATION ENABLED"
        conn._hb_task.stop()  # the bench is gone: no more heartbeats
        deadline = time.monotonic() + 2.0
        while load.now()["state"] != "FAULT" and time.monotonic() < deadline:
            time.sleep(0.02)
        s = load.now()
        assert s["state"] == "FAULT" and s["fault"] == 0x8130, s
        time.sleep(0.1)
        assert load.sim is not None
        assert abs(load.now()["i_q_A"]) < 0.05 * abs(pm * 1e-3 * load.sim.cfg.i_max_A)
    finally:
        conn._hb_task = None  # already stopped; the bridges go away with the fixture
        conn.close()
