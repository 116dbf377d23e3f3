"""The bench's one watch over its drive (``Drive.check``): a run, ``bench live`` and the
identification stop with a named cause when the drive leaves the state the bench put it
in without a fault (another master on the bus), when only its statusword shows a fault,
and when its heartbeat stops; never on a normal run.

The other side of the wire is canopen's LocalNode (``sim_fallback.FakeDrive402``), a
second canopen master built from the canopen library, and the simulated drive.
"""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import Iterator

import can
import canopen
import pytest
from sim_libs import stand_in_drive
from test_bench_runner import HEAD, UNITS

from bench import Drive, Runner, validate_sequence
from bench._drive import DriveError, DriveFault, DriveLeftState, DriveLost
from protocols.generated import od_names as od
from sim_fallback import FakeDrive402


@pytest.fixture()
def rig() -> Iterator[tuple[Drive, FakeDrive402]]:
    with stand_in_drive() as r:
        yield r


def _second_master(ch: str) -> tuple[canopen.Network, canopen.RemoteNode]:
    """Another master on the same bus (a second bench, a shell left open)."""
    from bench._drive import DEFAULT_EDS

    net = canopen.Network(can.Bus(interface="virtual", channel=ch))
    net.connect()
    node = canopen.RemoteNode(1, str(DEFAULT_EDS))
    net.add_node(node)
    return net, node


def test_run_stops_when_another_master_switches_the_drive_off(rig) -> None:
    drive, fake = rig
    ch = fake.network.bus.channel_id  # the second master joins the same bus
    seq = validate_sequence(HEAD + "  - enable: {}\n  - set_speed: {value: 0.1, unit: m/s}\n"
                            "  - wait: {duration_s: 5}\n  - disable: {}\n")
    net2, other = _second_master(ch)
    timer = threading.Timer(0.4, lambda: other.sdo["Controlword"].__setattr__("raw", 0x0000))
    timer.start()
    runner = Runner(drive, UNITS)
    try:
        with pytest.raises(DriveLeftState, match=r"left OPERATION ENABLED without a fault: "
                           r"statusword 0x0240 \(SWITCH ON DISABLED\)"):
            runner.run(seq)
    finally:
        timer.cancel()
        net2.disconnect()
    r = runner.result
    assert r.aborted and not r.passed
    assert "another master" in r.error
    assert r.duration_s < 2.0  # noticed within a slice, not at the end of the 5 s wait
    assert r.safe_state == "disabled" and fake.state == "SWITCH ON DISABLED"


def test_a_fault_shown_only_by_the_statusword_is_named(rig) -> None:
    """No EMCY (a lost frame, a drive that sends none): the statusword's FAULT is
    confirmed by SDO and named from 0x603F."""
    drive, fake = rig
    drive.enable("speed")
    code = od.FAULT_CODES["EST_PLL_ERROR"]
    with fake.lock:
        fake._set(od.ERROR_CODE, code)
        fake._enter("FAULT")  # the statusword TPDO, no EMCY
    deadline = time.monotonic() + 2.0
    with pytest.raises(DriveFault, match=f"0x{code:04X} EST_PLL_ERROR"):
        while time.monotonic() < deadline:
            drive.check()
            time.sleep(0.01)


def test_no_abort_while_the_drive_does_what_it_was_told(rig) -> None:
    """Enable, speed, disable, enable again: every statusword TPDO on the way (including
    the intermediate states of the walk) is expected; check() never raises."""
    drive, fake = rig
    for _ in range(3):
        drive.enable("speed")
        for _ in range(20):
            drive.check()
            time.sleep(0.005)
        drive.disable()
        drive.check()
    assert fake.history.count("OPERATION ENABLED") == 3


def test_heartbeat_consumer_on_a_drive_without_published_time(rig) -> None:
    """The host clock (no TPDO4 time): the drive's CiA 301 heartbeat (0x1017 = 100 ms in
    the EDS) is consumed; three periods without one is a lost drive."""
    drive, fake = rig
    for _ in range(3):
        fake.network.send_message(0x700 + fake.node_id, struct.pack("B", 0x05))
        time.sleep(0.05)
    drive.check()  # heartbeats coming: fine
    time.sleep(0.5)
    with pytest.raises(DriveLost, match=r"no heartbeat for 0\.[4-9]\d s \(0x1017 = 100 ms"):
        drive.check()


def test_simulated_drive_switched_off_by_a_second_master_mid_run(tmp_path) -> None:
    """The issue's case on the simulated drive: a second master disables the drive at
    0.3 s of a 1.2 s run; the run stops there with the cause (before: PASSED)."""
    from bench import run_sequence
    from bench._session import open_sim

    seq = validate_sequence(
        "name: other_master\nmotor: paper_salient\nextractor: sogi_adaptive\nseed: 1\n"
        "steps:\n  - enable: {}\n  - set_speed: {value: 100, unit: r/min}\n"
        "  - wait: {duration_s: 1.2}\n"
        "  - expect: {metric: position_error_rms_rad, op: '<', limit: 1}\n"
        "  - disable: {}\n")
    c = open_sim(seed=1)
    bus2 = can.Bus(interface="virtual", channel=c.info["channel"])
    stop = threading.Event()

    def intruder() -> None:  # an SDO download of controlword 0 once the drive passed 0.3 s
        while not stop.is_set():
            try:
                if c.sim.clock.now() > 0.3 and c.drive.enabled:
                    bus2.send(can.Message(arbitration_id=0x601, is_extended_id=False,
                                          data=[0x2B, 0x40, 0x60, 0, 0, 0, 0, 0]))
                    return
            except Exception:  # noqa: BLE001, S110 - the clock before the first step
                pass
            time.sleep(0.001)

    th = threading.Thread(target=intruder, daemon=True)
    th.start()
    try:
        out = run_sequence(seq, c, runs_root=str(tmp_path), progress=False, report=False)
    finally:
        stop.set()
        th.join(2)
        bus2.shutdown()
        c.close()
    r = out.result
    assert not r.passed and r.aborted
    assert "left OPERATION ENABLED without a fault" in (r.error or "")
    assert r.duration_s < 0.6, r.duration_s


def test_enable_waits_out_the_drives_boot(rig) -> None:
    """After a power-up or an NMT reset the drive measures its current zeros in NOT READY
    TO SWITCH ON (about 50 ms, fw_cal.h) and ignores controlwords: the bench's enable
    (canopen's transition table: controlword 0 there, then the wait for SWITCH ON
    DISABLED) waits for it to leave by itself, then walks on; a drive that never leaves
    is named."""
    drive, fake = rig
    with fake.lock:
        fake._enter("NOT READY TO SWITCH ON")
    timer = threading.Timer(0.08, lambda: fake._enter("SWITCH ON DISABLED"))
    t0 = time.monotonic()
    timer.start()
    try:
        drive.enable("speed")
    finally:
        timer.cancel()
    assert fake.state == "OPERATION ENABLED"
    assert time.monotonic() - t0 >= 0.08
    i = fake.history.index("NOT READY TO SWITCH ON")
    assert fake.history[i + 1] == "SWITCH ON DISABLED"  # nothing it was told jumped ahead
    drive.disable()
    with fake.lock:
        fake._enter("NOT READY TO SWITCH ON")
    with pytest.raises(DriveError, match=r"did not reach OPERATION ENABLED within 0.2 s "
                       r"\(now NOT READY TO SWITCH ON\)"):
        drive.enable("speed", timeout_s=0.2)
