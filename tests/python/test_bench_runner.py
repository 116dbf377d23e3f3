"""Runner: safe state on exceptions and SIGINT, expectations, with canopen's LocalNode
standing in for the drive (over python-can ``virtual``)."""

from __future__ import annotations

import os
import signal
import threading
import uuid
from collections.abc import Iterator

import can
import pytest
from sim_libs import stand_in_drive

from bench import Drive, MotorUnits, Runner, validate_sequence
from protocols.generated import od_names
from sim_fallback import FakeDrive402

UNITS = MotorUnits(pole_pitch_m=0.024, pole_pairs=4)
HEAD = "name: t\nmotor: paper_salient\nextractor: sogi_adaptive\nseed: 0\nsteps:\n"


@pytest.fixture()
def rig() -> Iterator[tuple[Drive, FakeDrive402]]:
    with stand_in_drive() as r:
        yield r


class FailingLoad:
    name = "failing"

    def __init__(self) -> None:
        self.calls: list[float] = []

    def enable(self) -> None:
        pass

    def disable(self) -> None:
        self.calls.append(0.0)

    def set_force_N(self, force_N: float) -> None:
        self.calls.append(force_N)
        if force_N:
            raise RuntimeError("load machine tripped")

    def ramp_force_N(self, force_N: float, duration_s: float) -> bool:
        return False


def test_walks_402_state_machine_and_writes_references(rig) -> None:
    drive, fake = rig
    seq = validate_sequence(HEAD + "  - enable: {mode: speed}\n"
                            "  - set_speed: {value: 0.5, unit: m/s}\n"
                            "  - wait: {duration_s: 0.05}\n  - disable: {}\n")
    r = Runner(drive, UNITS).run(seq)
    assert fake.history == ["SWITCH ON DISABLED", "READY TO SWITCH ON", "SWITCHED ON",
                            "OPERATION ENABLED", "SWITCH ON DISABLED"]
    assert (0x60FF, 0, 500000) in fake.writes  # 0.5 m/s in um/s
    assert (0x6060, 0, 9) in fake.writes      # CSV
    assert r.passed and r.safe_state == "disabled" and not r.aborted


def test_exception_mid_sequence_disables_drive_first(rig) -> None:
    drive, fake = rig
    load = FailingLoad()
    seq = validate_sequence(HEAD + "  - enable: {}\n  - set_speed: {value: 100, unit: r/min}\n"
                            "  - load_step: {value: 2, unit: N*m}\n"
                            "  - wait: {duration_s: 5}\n  - disable: {}\n")
    runner = Runner(drive, UNITS, load=load)
    with pytest.raises(RuntimeError, match="load machine tripped"):
        runner.run(seq)
    assert fake.state == "SWITCH ON DISABLED"
    assert fake.history[-2:] == ["OPERATION ENABLED", "SWITCH ON DISABLED"]
    assert load.calls[-1] == 0.0  # load removed too
    r = runner.result
    assert r.aborted and not r.passed and r.safe_state == "disabled"
    assert "load machine tripped" in r.error


def test_sigint_mid_sequence_disables_drive_before_exit(rig) -> None:
    drive, fake = rig
    seq = validate_sequence(HEAD + "  - enable: {}\n  - set_speed: {value: 100, unit: r/min}\n"
                            "  - wait: {duration_s: 30}\n  - disable: {}\n")
    runner = Runner(drive, UNITS)
    # a CI runner may start the suite with SIGINT ignored (a background job of a
    # non-interactive shell): Python's own handler, as `bench` installs it (cli.main)
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(0.5, os.kill, (os.getpid(), signal.SIGINT))
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            runner.run(seq)
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, old)
    assert fake.state == "SWITCH ON DISABLED"
    assert runner.result.aborted and runner.result.safe_state == "disabled"
    assert runner.result.duration_s < 5


def test_failed_safe_state_is_reported(rig) -> None:
    drive, fake = rig
    fake.fail_disable = True
    seq = validate_sequence(HEAD + "  - enable: {}\n  - disable: {}\n")
    runner = Runner(drive, UNITS)
    with pytest.raises(Exception):  # noqa: B017 - the disable step itself fails
        runner.run(seq)
    assert runner.result.safe_state.startswith("SAFE STATE FAILED")
    assert not runner.result.passed


def test_expectation_without_truth_is_not_judged_with_reason(rig) -> None:
    """Nothing to judge on: the expectation is NOT JUDGED with the reason, never a pass
    (and never a number); the run's verdict rests on what was judged."""
    drive, _ = rig
    seq = validate_sequence(HEAD + "  - enable: {}\n  - wait: {duration_s: 0.05}\n"
                            "  - expect: {metric: position_error_rms_rad, op: '<', limit: 1}\n"
                            "  - disable: {}\n")
    r = Runner(drive, UNITS).run(seq)
    (e,) = r.expectations
    assert not e.judged and not e.passed and e.status == "NOT JUDGED"
    assert "nothing recorded" in e.message and e.measured != e.measured


def test_fault_on_enable_is_a_clear_error(rig) -> None:
    drive, fake = rig
    fake.raise_fault(0xFF03)
    seq = validate_sequence(HEAD + "  - enable: {}\n  - disable: {}\n")
    with pytest.raises(Exception, match="0xFF03 SALIENCY_TOO_LOW"):
        Runner(drive, UNITS).run(seq)


def test_param_errors_are_explained(rig) -> None:
    drive, _ = rig
    from bench import ParamError

    with pytest.raises(ParamError, match="unit 'A' given, the parameter is in 'V'"):
        drive.set("u_inj_V", "20 A")
    with pytest.raises(ParamError, match="read-only"):
        drive.set("Statusword", 1)
    with pytest.raises(ParamError, match="unknown parameter 'u_inj'; did you mean: u_inj_V"):
        drive.set("u_inj", 1)
    value, p = drive.get("Injection.Amplitude")
    assert p.name == "u_inj_V" and p.unit == "V" and isinstance(value, float)


def test_hardware_path_with_a_stand_in_drive(tmp_path) -> None:
    """`connect` on a real python-can bus with a (LocalNode) drive: no fallback, heartbeat
    watch configured while running and switched off on close, run folder written."""
    import json

    from bench import connect, run_sequence

    ch = f"hw-{uuid.uuid4().hex[:8]}-bus"
    fake = FakeDrive402(can.Bus(interface="virtual", channel=ch))
    spy = can.Bus(interface="virtual", channel=ch)  # another node on the same bus
    said: list[str] = []
    try:
        conn = connect(interface="virtual", channel=ch, say=said.append)
        try:
            # the hardware path (a bus), labelled from what the drive says: the stand-in
            # has no power stage and says "no I/O" - never HARDWARE
            assert not conn.is_sim and conn.info["via"] == "bus"
            assert conn.kind == "no_io" and "NO-I/O" in conn.description
            assert "HARDWARE" not in conn.description
            seq = validate_sequence(HEAD + "  - enable: {}\n"
                                    "  - set_speed: {value: 10, unit: mm/s}\n"
                                    "  - wait: {duration_s: 0.2}\n  - disable: {}\n")
            out = run_sequence(seq, conn, runs_root=str(tmp_path), progress=False)
            hb = [w for w in fake.writes if w[0] == 0x1016]
            assert hb and hb[0][2] == (0x7F << 16) | 500
            ids = []
            while (m := spy.recv(0.0)) is not None:
                ids.append(m.arbitration_id)
            assert ids.count(0x080) >= 5, "the bench must produce SYNC on hardware"
            assert 0x77F in ids  # its heartbeat
        finally:
            conn.close()
        assert fake.writes[-1][:2] == (0x1016, 1) and fake.writes[-1][2] == 0
        assert out.result.passed and out.result.safe_state == "disabled"
        assert fake.history[-1] == "SWITCH ON DISABLED"
        assert (0x60FF, 0, 10000) in fake.writes
        meta = json.loads((out.run_dir / "meta.json").read_text())
        assert meta["connection_info"]["kind"] == "no_io"
        assert meta["drive"]["firmware_version"] == od_names.FW_VERSION_STRING
        assert meta["clock"].startswith("the drive's own clock")
        assert any("connected to the NO-I/O" in s for s in said)
    finally:
        fake.close()
        spy.shutdown()


def test_silent_load_machine_is_a_clear_error_not_a_fallback() -> None:
    """The drive answers but the configured load machine does not: no simulator
    fallback (the drive is real), a ConnectionError that names the load node."""
    from bench import connect

    ch = f"hw-{uuid.uuid4().hex[:8]}-bus"
    fake = FakeDrive402(can.Bus(interface="virtual", channel=ch))
    said: list[str] = []
    try:
        with pytest.raises(ConnectionError, match="load machine node 5"):
            connect(interface="virtual", channel=ch, load_node=5, say=said.append)
        assert not any("SIMULATED" in s for s in said)
    finally:
        fake.close()
