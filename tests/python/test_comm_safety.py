"""The communication side of "stop safely" (issue 10), end to end: the python
``canopen`` library is the master, the C drive application (core + CANopen
slave) runs in closed loop with the simulated plant (sim_fallback.DriveBridge).

Timing is judged in simulated time: the bridge is stepped by the test
(``DriveBridge.advance``), frames sent before a call are processed in its
first control period, and the PWM state is the simulator's record of the
firmware's outputs (``duty_abc`` is NaN while the PWM is off). Set-up that
needs SDO round trips runs with the bridge's real-time thread; the timed part
runs with the thread stopped, so no wall-clock speed enters any assertion.
"""

from __future__ import annotations

import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import can
import canopen
import numpy as np
import pytest
from canopen.sdo.exceptions import SdoAbortedError
from sim_libs import rig_maker

from protocols.generated.od_names import FAULT_CODES
from sim_fallback import DriveBridge

ROOT = Path(__file__).resolve().parents[2]
EDS = ROOT / "protocols" / "generated" / "pmlsm_drive.eds"
NID = 5
MASTER = 0x7E
F_PWM = 24000  # control periods per second (both motors)
MS = F_PWM // 1000  # control periods per ms = bridge chunk
REC = ["duty_abc", "v_mps", "fault_code", "cia402_state"]
OP_ENABLED, SWITCH_ON_DISABLED = 4, 1  # fw_cia402_state_t


class Rig:
    """canopen master + the drive application on one virtual bus."""

    def __init__(self, motor: str | None) -> None:
        ch = f"pmlsm-safety-{uuid.uuid4().hex[:8]}"
        self.net = canopen.Network()
        self.net.connect(interface="virtual", channel=ch)
        self.bus = can.Bus(interface="virtual", channel=ch)
        self.boot: list[bytes] = []
        self.net.subscribe(0x700 + NID, lambda cob, data, ts: self.boot.append(bytes(data)))
        plant = "sim" if motor else "none"
        kw = {"motor": motor, "seed": 2} if motor else None
        self.bridge = DriveBridge(self.bus, node_id=NID, plant=plant, sim_kwargs=kw)
        self.node = canopen.RemoteNode(NID, str(EDS))
        self.net.add_node(self.node)
        self.hb_every = 50 * MS  # master heartbeat period, control periods
        self.last_hb: int | None = None

    def close(self) -> None:
        self.bridge.close()
        self.net.disconnect()
        self.bus.shutdown()

    # --- stepping in simulated time (bridge thread stopped) -------------
    def hb(self) -> None:
        self.net.send_message(0x700 + MASTER, b"\x05")
        self.last_hb = self.bridge.steps  # processed in the next period

    def rpdo1(self, cw: int, v_umps: int) -> None:
        self.net.send_message(0x200 + NID, cw.to_bytes(2, "little")
                              + int(v_umps).to_bytes(4, "little", signed=True))

    def run_ms(self, n_ms: int, target: Callable[[int], int] | None = None,
               heartbeat: bool = True) -> None:
        """n_ms ms with the master's heartbeat and (optionally) RPDO1 each ms."""
        for k in range(n_ms):
            if heartbeat and (self.last_hb is None
                              or self.bridge.steps - self.last_hb >= self.hb_every):
                self.hb()
            if target is not None:
                self.rpdo1(0x0F, target(k))
            self.bridge.advance(MS)

    def enable_and_run_to(self, v_mps: float) -> None:
        """NMT start, 402 walk by RPDO1, start-up, ramp to v_mps (0.45 s), hold."""
        self.net.send_message(0x000, bytes([0x01, NID]))
        for cw in (0x06, 0x07, 0x0F):
            self.rpdo1(cw, 0)
            self.bridge.advance(MS)
        self.run_ms(200, lambda k: 0)
        v = int(round(v_mps * 1e6))
        self.run_ms(450, lambda k: v * (k + 1) // 450)
        self.run_ms(250, lambda k: v)


@pytest.fixture
def make_rig() -> Iterator[Callable[[str | None], Rig]]:
    """Rigs (the canopen master and the drive on one virtual bus; None: the null
    plant), closed after the test (sim_libs.rig_maker)."""
    with rig_maker(Rig) as make:
        yield make


def _sdo(rig: Rig, fn: Callable[[], object]) -> object:
    rig.bridge.start()
    try:
        return fn()
    finally:
        rig.bridge.stop()


def _emcy(rig: Rig, code: int) -> canopen.emcy.EmcyError:
    """The EMCY received by the canopen consumer (it runs on the bus thread)."""
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline:
        hits = [e for e in rig.node.emcy.log if e.code == code]
        if hits:
            return hits[0]
        time.sleep(0.01)
    raise AssertionError(f"no EMCY 0x{code:04X}; log {[hex(e.code) for e in rig.node.emcy.log]}")


def _emcy_step(err: canopen.emcy.EmcyError) -> int:
    """Control period in which the drive latched the fault (EMCY bytes 4-7)."""
    return int.from_bytes(bytes(err.data[1:5]), "little")


# ---- heartbeat loss: fault and EMCY at T, PWM off by T + 100 ms ------------------


@pytest.mark.parametrize("motor,v_mps,t_ms", [("iron_core_linear", 2.0, 200),
                                              ("paper_salient", 0.3, 200),
                                              ("iron_core_linear", 1.0, 120)])
def test_heartbeat_loss_pwm_off_within_consumer_time_plus_100ms(make_rig, motor, v_mps, t_ms):
    rig = make_rig(motor)
    _sdo(rig, lambda: rig.node.sdo[0x1016][1].__setattr__("raw", (MASTER << 16) | t_ms))
    rig.enable_and_run_to(v_mps)
    v0 = rig.bridge.state()["v_mps"]
    assert abs(v0 - v_mps) < 0.1 * v_mps, v0  # really at speed (truth)
    rig.hb()  # the last heartbeat
    hb_step = rig.last_hb
    rig.node.emcy.reset()
    r = rig.bridge.advance((t_ms + 300) * MS, channels=REC)
    step = r["step"]
    # fault latched exactly at T (consumer time counted from the last heartbeat)
    fault_at = step[np.argmax(r["fault_code"] == FAULT_CODES["HEARTBEAT_LOST"])]
    assert np.all(r["fault_code"][step < fault_at] == 0)
    assert t_ms * MS <= fault_at - hb_step <= t_ms * MS + 1, (fault_at - hb_step) / MS
    err = _emcy(rig, 0x8130)
    assert err.register & 0x11 == 0x11
    assert abs(_emcy_step(err) - fault_at) <= 1
    # PWM off within T + 100 ms, and stays off
    off = np.isnan(r["duty_abc"][:, 0])
    assert not off[step < fault_at].any()  # driven until the fault
    off_at = step[np.argmax(off)]
    assert off_at - hb_step <= (t_ms + 100) * MS, (off_at - hb_step) / MS
    assert off[step >= off_at].all()
    assert r["cia402_state"][-1] == 7  # FAULT
    # it braked while it could (truth): slower at switch-off than before
    assert abs(r["v_mps"][step == off_at][0]) < abs(v0)


# ---- NMT while the power stage is on -------------------------------------------


@pytest.mark.parametrize("cmd", [0x02, 0x82, 0x81], ids=["stop", "reset_comm", "reset_node"])
def test_nmt_switches_pwm_off_in_the_same_period(make_rig, cmd):
    rig = make_rig("paper_salient")
    _sdo(rig, lambda: rig.node.sdo[0x6080].__setattr__("raw", 2_500_000))  # a changed setting
    rig.enable_and_run_to(0.3)
    before = rig.bridge.advance(MS, channels=REC)
    assert before["cia402_state"][-1] == OP_ENABLED and not np.isnan(before["duty_abc"]).any()
    rig.boot.clear()
    rig.net.send_message(0x000, bytes([cmd, NID]))
    nmt_step = rig.bridge.steps  # the frame is processed in this control period
    r = rig.bridge.advance(300 * MS, channels=REC)
    assert r["step"][0] == nmt_step
    off = np.isnan(r["duty_abc"][:, 0])
    assert off.all(), f"PWM on {np.count_nonzero(~off)} periods after the NMT command"
    if cmd == 0x81:
        # the application restarts: the boot's current-zero calibration (NOT READY TO
        # SWITCH ON, 0) with the PWM off, then SWITCH ON DISABLED
        st = r["cia402_state"]
        k = int(np.argmax(st != 0))
        assert 0 < k < 100 * MS and (st[:k] == 0).all() and (st[k:] == SWITCH_ON_DISABLED).all()
    else:
        assert (r["cia402_state"] == SWITCH_ON_DISABLED).all()
    assert (r["fault_code"] == 0).all()
    time.sleep(0.05)
    if cmd == 0x02:
        assert rig.boot and rig.boot[-1] == b"\x04"  # heartbeat says STOPPED
        rig.net.send_message(0x000, bytes([0x80, NID]))  # back to pre-op for SDO
    else:
        assert b"\x00" in rig.boot  # boot-up message
    rig.bridge.start()
    try:
        sw = rig.node.sdo[0x6041].raw
        assert sw & 0x4F == 0x40, hex(sw)  # switch on disabled
        assert sw & 0x08 == 0  # no fault
        assert rig.node.sdo[0x603F].raw == 0
        # reset node: the configuration of the boot; otherwise it is kept
        want = 3_000_000 if cmd == 0x81 else 2_500_000
        assert rig.node.sdo[0x6080].raw == want
        assert rig.node.sdo[0x2051][1].raw == pytest.approx(want * 1e-6, rel=1e-6)
    finally:
        rig.bridge.stop()


# ---- CiA 301 write rules -------------------------------------------------------------


def test_emcy_cob_id_cannot_change_while_valid(make_rig):
    rig = make_rig(None)
    rig.bridge.start()
    sdo = rig.node.sdo
    assert sdo[0x1014].raw == 0x80 + NID
    sdo[0x1014].raw = 0x80 + NID  # the same value is fine
    for bad in (0x81 + NID, 0x80000081 + NID, 0x40000080 + NID):
        with pytest.raises(SdoAbortedError) as ei:
            sdo[0x1014].raw = bad
        assert ei.value.code == 0x06090030, hex(bad)
        assert sdo[0x1014].raw == 0x80 + NID  # nothing changed
    sdo[0x1014].raw = 0x80000080 + NID  # invalidate first (same id)
    sdo[0x1014].raw = 0x80000090  # then change the id
    sdo[0x1014].raw = 0x90  # and validate it
    assert sdo[0x1014].raw == 0x90
    with pytest.raises(SdoAbortedError) as ei:
        sdo[0x1014].raw = 0x20000090  # 29-bit id
    assert ei.value.code == 0x06090030


def test_heartbeat_consumer_refuses_a_second_entry_for_a_node(make_rig):
    rig = make_rig(None)
    rig.bridge.start()
    hb = rig.node.sdo[0x1016]
    hb[1].raw = (MASTER << 16) | 200
    with pytest.raises(SdoAbortedError) as ei:
        hb[2].raw = (MASTER << 16) | 300
    assert ei.value.code == 0x06040043
    assert hb[2].raw == 0
    hb[2].raw = (MASTER << 16) | 0  # an unused entry may name the node
    hb[2].raw = (0x10 << 16) | 300  # another node is fine
    with pytest.raises(SdoAbortedError) as ei:
        hb[1].raw = (0x10 << 16) | 100
    assert ei.value.code == 0x06040043
    hb[1].raw = (MASTER << 16) | 250  # the same entry may change its time
    assert (hb[1].raw, hb[2].raw) == ((MASTER << 16) | 250, (0x10 << 16) | 300)


# ---- RPDO deadline (event timer 0x1400+n:5) ------------------------------------------


@pytest.mark.parametrize("sync", [False, True], ids=["rpdo_lost", "sync_lost"])
def test_rpdo_deadline_faults_when_data_goes_stale(make_rig, sync):
    """RPDO1 with a 30 ms deadline: the drive runs while fresh targets arrive
    (event-driven RPDO, or synchronous RPDO + SYNC every ms); when the RPDO
    (or only the SYNC) stops, it faults 0x8250 30 ms after the last applied
    data and switches the PWM off, instead of running on the stale target."""
    rig = make_rig("paper_salient")

    def setup() -> None:
        rig.node.rpdo.read()
        p = rig.node.rpdo[1]
        p.trans_type = 1 if sync else 255
        p.save()
        rig.node.sdo[0x1400][5].raw = 30

    _sdo(rig, setup)
    assert rig.node.rpdo[1].trans_type == (1 if sync else 255)
    rig.net.send_message(0x000, bytes([0x01, NID]))
    p = rig.node.rpdo[1]

    def send(cw: int, v_umps: int) -> None:
        p["Controlword"].raw = cw
        p["Target velocity"].raw = v_umps
        p.transmit()
        if sync:
            rig.net.send_message(0x080, b"")

    for cw in (0x06, 0x07, 0x0F):
        send(cw, 0)
        rig.bridge.advance(MS)
    for k in range(600):
        send(0x0F, min(300_000, 1000 * k))
        last = rig.bridge.steps  # data applied in the first period of this chunk
        r = rig.bridge.advance(MS, channels=REC)
    assert r["cia402_state"][-1] == OP_ENABLED and r["fault_code"][-1] == 0
    assert abs(rig.bridge.state()["v_mps"] - 0.3) < 0.05  # running on the RPDO targets
    rig.node.emcy.reset()
    if sync:
        p.transmit()  # the RPDO still arrives, the SYNC does not
    r = rig.bridge.advance(60 * MS, channels=REC)
    code = FAULT_CODES["RPDO_TIMEOUT"]
    fault_at = r["step"][np.argmax(r["fault_code"] == code)]
    assert (r["fault_code"] == code).any()
    assert 30 * MS <= fault_at - last <= 30 * MS + 1, (fault_at - last) / MS
    off_at = r["step"][np.argmax(np.isnan(r["duty_abc"][:, 0]))]
    assert off_at - fault_at <= 1  # switched off at once
    err = _emcy(rig, code)
    assert err.register & 0x11 == 0x11
    assert abs(_emcy_step(err) - fault_at) <= 1


def test_rpdo_deadline_off_by_default_and_quiet_when_fresh(make_rig):
    """The same run without a deadline (default 0) or with fresh data never faults."""
    rig = make_rig("paper_salient")
    rig.enable_and_run_to(0.3)  # RPDO1 every ms, no deadline configured
    r = rig.bridge.advance(100 * MS, channels=REC)  # no RPDO for 100 ms
    assert (r["fault_code"] == 0).all() and not np.isnan(r["duty_abc"]).any()
