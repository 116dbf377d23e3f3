"""The real other side of the wire: the python canopen library (RemoteNode +
BaseNode402 over python-can ``virtual``) talks to the C drive application
(fw_app: core + CANopen slave) running in closed loop with the simulated
plant (sim_fallback.DriveBridge, paced to real time)."""

from __future__ import annotations

import math
import time

import can
import canopen
import pytest
from canopen.profiles.p402 import BaseNode402
from canopen.sdo.exceptions import SdoAbortedError
from sim_libs import drive_on_bus

NID = 5
MASTER = 0x7E


@pytest.fixture(scope="module")
def rig():
    seen: list[can.Message] = []

    def boot_up_seen(net: canopen.Network) -> None:
        net.subscribe(0x700 + NID, lambda cob, data, ts: seen.append(bytes(data)))

    with drive_on_bus(NID, "auto", node_class=BaseNode402, before=boot_up_seen) as (
            net, node, bridge):
        yield net, node, bridge, seen


def test_boot_up_and_heartbeat(rig):
    net, node, bridge, seen = rig
    assert bridge.error is None
    assert seen and seen[0] == b"\x00"  # boot-up
    assert node.nmt.wait_for_heartbeat(timeout=1.0) == "PRE-OPERATIONAL"


def test_eds_objects_readable(rig):
    net, node, bridge, _ = rig
    assert node.sdo[0x1000].raw == 0x00020192
    assert node.sdo[0x1008].raw == "PMLSM sensorless drive"  # segmented upload
    assert node.sdo[0x1018][2].raw == 0x504D4C53
    assert node.sdo["HF extractor"].raw == 2
    node.sdo[0x2042].raw = "bench axis 1"  # segmented download
    assert node.sdo[0x2042].raw == "bench axis 1"


def test_handover_levels_derived_over_canopen(rig):
    """A drive configured over CANopen gets the back-EMF levels of the Python
    configuration path (one derivation, in the core): psi_f and the handover and witness
    speeds written by SDO, the derived levels read back from their read-only objects."""
    net, node, bridge, seen = rig
    if bridge.sim is None:
        pytest.skip("no simulated plant: the Python configuration path is not there")
    from sim_fallback._motors import fw_config

    # written in this order, given back in the reverse one: down stays below up
    speeds = {(0x2053, 2): ("bemf_v_off_mps", 0.175), (0x2053, 1): ("bemf_v_on_mps", 0.25),
              (0x2052, 5): ("mon_bemf_min_mps", 0.125), (0x2050, 5): ("psi_f_Wb", 0.26)}
    keep = {a: node.sdo[a[0]][a[1]].raw for a in speeds}
    try:
        for (i, s), (_, v) in speeds.items():
            node.sdo[i][s].raw = v
        ref = fw_config(bridge.sim.motor, **dict(speeds.values()))
        k = 0.26 * math.pi / ref.pole_pitch_m  # V per m/s
        for (i, s), name, v in (((0x2053, 4), "bemf_e_on_V", 0.25),
                                ((0x2053, 5), "bemf_e_off_V", 0.175),
                                ((0x2052, 9), "mon_bemf_min_V", 0.125)):
            got = node.sdo[i][s].raw
            assert got == pytest.approx(getattr(ref, name), rel=1e-6), name
            assert got == pytest.approx(k * v, rel=1e-6), name
        with pytest.raises(SdoAbortedError):
            node.sdo[0x2053][4].raw = 1.0  # derived: read-only
    finally:
        for (i, s), v in reversed(keep.items()):
            node.sdo[i][s].raw = v


def test_out_of_range_write_aborts_and_changes_nothing(rig):
    net, node, bridge, _ = rig
    before = node.sdo[0x6060].raw
    with pytest.raises(SdoAbortedError) as ei:
        node.sdo.download(0x6060, 0, bytes([11]))
    assert ei.value.code == 0x06090031
    with pytest.raises(SdoAbortedError) as ei:
        node.sdo.download(0x6060, 0, bytes([3]))
    assert ei.value.code == 0x06090032
    with pytest.raises(SdoAbortedError) as ei:
        node.sdo.download(0x6071, 0, (2000).to_bytes(2, "little", signed=True))
    assert ei.value.code == 0x06090031
    with pytest.raises(SdoAbortedError) as ei:
        node.sdo.download(0x6041, 0, b"\x00\x00")
    assert ei.value.code == 0x06010002
    with pytest.raises(SdoAbortedError) as ei:
        node.sdo.upload(0x1234, 0)
    assert ei.value.code == 0x06020000
    with pytest.raises(SdoAbortedError) as ei:
        node.sdo.upload(0x1018, 9)
    assert ei.value.code == 0x06090011
    with pytest.raises(SdoAbortedError) as ei:
        node.sdo.download(0x6040, 0, b"\x06\x00\x00\x00")
    assert ei.value.code == 0x06070010
    assert node.sdo[0x6060].raw == before
    assert node.sdo[0x6071].raw == 0


def test_start_up_supervision_and_board_sensing_over_canopen(rig):
    """Every configuration field is on the bus: the start-up and estimate-loss tuning
    (0x2055) and the rotary-equivalent pole pairs (0x2050:19) are written and read back
    by SDO, an out-of-range value aborts and changes nothing; the board's ADC scaling
    (0x2056) reads what the simulated board uses and refuses writes."""
    net, node, bridge, _ = rig
    new = {(0x2055, 1): 0.12, (0x2055, 2): 48.0, (0x2055, 3): 10, (0x2055, 4): 3,
           (0x2055, 5): 0.05, (0x2055, 6): 0.25, (0x2055, 7): 0.4, (0x2055, 8): 0.04,
           (0x2050, 19): 5.0}
    keep = {a: node.sdo[a[0]][a[1]].raw for a in new}
    assert keep[(0x2055, 7)] == pytest.approx(0.5) and keep[(0x2055, 3)] == 12  # defaults
    try:
        for (i, s), v in new.items():
            node.sdo[i][s].raw = v
        for (i, s), v in new.items():
            assert node.sdo[i][s].raw == pytest.approx(v, rel=1e-6), (hex(i), s)
        with pytest.raises(SdoAbortedError) as ei:
            node.sdo[0x2055][7].raw = 2.0  # pll_err_max_rad: 0.01 .. 1.6
        assert ei.value.code == 0x06090031
        assert node.sdo[0x2055][7].raw == pytest.approx(0.4)
    finally:
        for (i, s), v in keep.items():
            node.sdo[i][s].raw = v
    if bridge.sim is not None:
        cfg = bridge.sim.cfg
        for s, name in ((1, "adc_A_per_count"), (2, "adc_offset_counts"),
                        (3, "adc_V_per_count"), (4, "adc_max_count")):
            assert node.sdo[0x2056][s].raw == pytest.approx(getattr(cfg, name), rel=1e-6)
    with pytest.raises(SdoAbortedError) as ei:
        node.sdo[0x2056][1].raw = 1.0
    assert ei.value.code == 0x06010002


def test_walk_to_operation_enabled_and_follow_target_velocity(rig):
    net, node, bridge, _ = rig
    node.nmt.state = "PRE-OPERATIONAL"
    node.setup_402_state_machine()
    node.nmt.state = "OPERATIONAL"
    assert node.nmt.wait_for_heartbeat(timeout=1.0) == "OPERATIONAL"
    node.op_mode = "CYCLIC SYNCHRONOUS VELOCITY"
    node.state = "OPERATION ENABLED"
    assert node.state == "OPERATION ENABLED"
    assert node.sdo[0x6061].raw == 9
    if bridge.sim is None:
        pytest.skip("sim_fallback library not available: no plant to follow")
    target_umps = 200_000  # 0.2 m/s
    node.sdo[0x60FF].raw = target_umps
    time.sleep(1.5)
    v_est = node.sdo[0x606C].raw
    v_true = bridge.state()["v_mps"]
    assert abs(v_est - target_umps) < 0.2 * target_umps, v_est
    assert abs(v_true - 0.2) < 0.04, v_true
    assert node.sdo[0x603F].raw == 0


@pytest.mark.parametrize("limit_object", ["speed limit 0x2050:11", "max motor speed 0x6080"])
def test_target_beyond_the_speed_limit_sets_internal_limit_active(rig, limit_object):
    """CiA 402 statusword bit 11: a target velocity beyond the drive's speed limit is
    clamped and says so, a target within it clears the bit; the mover follows the
    clamped target (the simulator's truth). Both limits clamp: the loops' speed limit
    (electrical rad/s) and 0x6080, which CiA 402 has limit the target. 0x6080 does
    not trip OVERSPEED for a target beyond it (the trip is overspeed_margin above)."""
    net, node, bridge, _ = rig
    if bridge.sim is None:
        pytest.skip("sim_fallback library not available: no plant to follow")
    tau = bridge.sim.cfg.pole_pitch_m
    assert node.state == "OPERATION ENABLED"
    assert node.sdo[0x6041].raw & 0x0800 == 0  # 0.2 m/s, within every limit
    obj = node.sdo[0x2050][11] if "0x2050" in limit_object else node.sdo[0x6080]
    limit_old = obj.raw
    node.state = "SWITCHED ON"  # the configuration is written with the power stage off
    # 0.15 m/s, in electrical rad/s or um/s
    obj.raw = 0.15 * math.pi / tau if "0x2050" in limit_object else 150_000
    time.sleep(0.5)  # the mover coasts to a stop: enabling on a moving mover is refused
    try:
        node.state = "OPERATION ENABLED"
        node.sdo[0x60FF].raw = 200_000  # 0.2 m/s: beyond the limit
        time.sleep(1.0)
        assert node.sdo[0x603F].raw == 0, hex(node.sdo[0x603F].raw)
        assert node.sdo[0x6041].raw & 0x0800, hex(node.sdo[0x6041].raw)
        assert abs(bridge.state()["v_mps"] - 0.15) < 0.03, bridge.state()
        node.sdo[0x60FF].raw = 100_000  # within
        time.sleep(0.05)
        assert node.sdo[0x6041].raw & 0x0800 == 0
    finally:  # leave the rig as the other tests expect it: enabled at 0.2 m/s
        node.state = "SWITCHED ON"
        obj.raw = limit_old
        time.sleep(0.5)
        node.state = "OPERATION ENABLED"
        node.sdo[0x60FF].raw = 200_000
    time.sleep(1.0)
    assert node.sdo[0x6041].raw & 0x0800 == 0
    assert abs(bridge.state()["v_mps"] - 0.2) < 0.04, bridge.state()


def test_remap_tpdo_and_receive_it(rig):
    net, node, bridge, _ = rig
    node.tpdo.read()
    tp = node.tpdo[4]
    tp.clear()
    tp.add_variable(0x6041)
    tp.add_variable(0x606C)
    tp.cob_id = 0x480 + NID
    tp.trans_type = 254
    tp.event_timer = 20
    tp.inhibit_time = 10
    tp.enabled = True
    tp.save()
    # read back the mapping over SDO
    assert node.sdo[0x1A03][0].raw == 2
    assert node.sdo[0x1A03][1].raw == 0x60410010
    assert node.sdo[0x1A03][2].raw == 0x606C0020
    assert tp.wait_for_reception(timeout=1.0)
    assert tp["Statusword"].raw & 0x6F == 0x27
    if bridge.sim is not None:
        assert abs(tp["Velocity actual value"].raw - 200_000) < 60_000


def test_heartbeat_loss_gives_emcy_and_fault(rig):
    net, node, bridge, _ = rig
    node.sdo[0x1016][1].raw = (MASTER << 16) | 200  # watch the master, 200 ms
    for _ in range(5):
        net.send_message(0x700 + MASTER, b"\x05")
        time.sleep(0.03)
    assert node.sdo[0x603F].raw == 0
    node.emcy.reset()
    # master goes silent
    err = node.emcy.wait(0x8130, timeout=2.0)
    assert err is not None, "no EMCY 0x8130"
    assert err.register & 0x11 == 0x11
    assert node.sdo[0x603F].raw == 0x8130
    assert node.sdo[0x2030][1].raw == 0x8130
    sw = node.sdo[0x6041].raw
    assert sw & 0x08, hex(sw)  # fault bit
    if bridge.sim is not None:
        # fault reaction: quick stop, then PWM off -> the mover is stopped
        time.sleep(0.5)
        assert abs(bridge.state()["v_mps"]) < 0.02, bridge.state()
    # supervisor back: fault reset over SDO
    node.sdo[0x1016][1].raw = 0
    node.sdo[0x6040].raw = 0x80
    time.sleep(0.05)
    assert node.sdo[0x603F].raw == 0
    assert node.sdo[0x6041].raw & 0x4F == 0x40  # switch on disabled
    assert any(e.code == 0 for e in node.emcy.log)  # "error reset" EMCY


def test_serial_telemetry_and_trace_of_a_speed_step(rig):
    """The serial link of the running drive: telemetry without loss, and a
    trace capture triggered by a step of the speed reference."""
    from protocols import serial_link as sl

    net, node, bridge, _ = rig
    node.sdo[0x6040].raw = 0x06
    node.sdo[0x6040].raw = 0x07
    node.sdo[0x6040].raw = 0x0F
    time.sleep(0.5)
    names = sl.signal_names()
    ref = names.index("speed_ref_radps_e")
    new_umps = 300_000
    w_new = 3.141592653589793 * new_umps * 1e-6 / 0.024  # pole pitch of the default config
    tr = node.sdo[0x2070]
    tr[3].raw = ref
    tr[4].raw = 0.5 * w_new + 0.5 * (3.141592653589793 * 0.2 / 0.024)
    tr[5].raw = 0  # rising
    tr[6].raw = 200
    tr[7].raw = 3
    tr[8].raw = ref
    tr[9].raw = names.index("omega_hat_radps")
    tr[10].raw = names.index("i_q_A")
    tr[1].raw = 1  # arm
    time.sleep(0.1)
    assert tr[2].raw == 1  # armed
    node.sdo[0x60FF].raw = new_umps
    deadline = time.time() + 3.0
    while tr[2].raw != 3 and time.time() < deadline:
        time.sleep(0.05)
    assert tr[2].raw == 3, "trace not done"
    with bridge._lock:
        bridge.uart.clear()
    tr[1].raw = 3  # upload
    rx, asm = sl.Receiver(), sl.TraceAssembler()
    trace = None
    telem = []
    deadline = time.time() + 3.0
    while trace is None and time.time() < deadline:
        time.sleep(0.05)
        with bridge._lock:
            data = bytes(bridge.uart)
            bridge.uart.clear()
        for fr in rx.feed(data):
            if fr.type == sl.FrameType.TELEMETRY:
                telem.append(sl.parse_telemetry(fr.payload))
            trace = asm.feed(fr) or trace
    assert trace is not None and trace.complete, rx
    assert rx.frames_bad == 0 and rx.frames_lost == 0
    n = trace.samples.shape[0]
    assert trace.ids[0] == ref and n == 4096 // 3
    assert trace.pre_trigger == 200
    before, after = trace.samples[:190, 0], trace.samples[210:, 0]
    assert abs(before.mean() - 3.141592653589793 * 0.2 / 0.024) < 1.0
    assert abs(after.mean() - w_new) < 1.0
    # telemetry at 1 kHz, consecutive steps 24 apart
    steps = [t.step for t in telem]
    assert len(steps) > 10 and all(b - a == 24 for a, b in zip(steps, steps[1:], strict=False))

