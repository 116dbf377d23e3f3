"""Shared by the bench tests: skip when the simulator libraries are not built; the
bench's Drive against canopen's LocalNode standing in for the drive; a canopen master
and the drive application on one virtual bus."""

from __future__ import annotations

import contextlib
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

EDS = Path(__file__).resolve().parents[2] / "protocols" / "generated" / "pmlsm_drive.eds"


def sim_available() -> bool:
    """Whether the simulator library and the drive application library both load."""
    try:
        from sim_fallback import _lib

        _lib.lib()
        from protocols import clib

        clib.load_app()
        return True
    except Exception:  # noqa: BLE001
        return False


needs_sim = pytest.mark.skipif(not sim_available(), reason="simulator libraries not built")


@contextlib.contextmanager
def stand_in_drive() -> Iterator[tuple[Any, Any]]:
    """``(drive, fake)``: a :class:`bench.Drive` set up against
    :class:`sim_fallback.FakeDrive402` on a fresh python-can ``virtual`` channel
    (``fake.network.bus.channel_id``: where another master can join)."""
    import can
    import canopen

    from bench import Drive
    from sim_fallback import FakeDrive402

    ch = f"test-{uuid.uuid4().hex[:8]}"
    fake = FakeDrive402(can.Bus(interface="virtual", channel=ch))
    net = canopen.Network(can.Bus(interface="virtual", channel=ch))
    net.NOTIFIER_CYCLE = 0.1
    net.connect()
    drive = Drive(net, 1)
    drive.setup(read_pdos=False)
    try:
        yield drive, fake
    finally:
        net.disconnect()
        fake.close()


@contextlib.contextmanager
def rig_maker(rig_class: Any) -> Iterator[Any]:
    """``make(motor)``: rigs of ``rig_class`` (a canopen master and the drive application
    on one virtual bus; motor None: the null plant), all closed afterwards. Skips when the
    drive application cannot be built, or the simulator library is missing for a motor."""
    import subprocess

    from protocols import clib

    try:
        clib.load_app()
    except (OSError, subprocess.CalledProcessError) as e:  # pragma: no cover - no compiler
        pytest.skip(f"drive application cannot be built: {e}")
    rigs: list[Any] = []

    def make(motor: str | None) -> Any:
        r = rig_class(motor)
        rigs.append(r)
        if motor and r.bridge.sim is None:  # pragma: no cover
            pytest.skip("sim_fallback library not available")
        return r

    try:
        yield make
    finally:
        for r in rigs:
            r.close()


@contextlib.contextmanager
def drive_on_bus(node_id: int, plant: str = "sim", sim_kwargs: dict | None = None,
                 node_class: Any = None,
                 before: Any = None) -> Iterator[tuple[Any, Any, Any]]:
    """``(net, node, bridge)``: a canopen master (``node_class``, default
    ``canopen.RemoteNode``, on the generated EDS) and the drive application
    (:class:`sim_fallback.DriveBridge` with ``plant`` and ``sim_kwargs``) on a fresh
    python-can ``virtual`` channel, the bridge's real-time thread started; all closed
    afterwards. ``before(net)`` runs before the drive is made (a subscription that must
    see its boot-up message). Skips when the drive application cannot be built, or the
    simulator library is missing for a simulated plant."""
    import subprocess
    import time

    import can
    import canopen

    from protocols import clib
    from sim_fallback import DriveBridge

    try:
        clib.load_app()
    except (OSError, subprocess.CalledProcessError) as e:  # pragma: no cover - no compiler
        pytest.skip(f"drive application cannot be built: {e}")
    ch = f"pmlsm-{uuid.uuid4().hex[:8]}"
    net = canopen.Network()
    net.connect(interface="virtual", channel=ch)
    bus = can.Bus(interface="virtual", channel=ch)
    bridge = None
    try:
        if before is not None:
            before(net)
        bridge = DriveBridge(bus, node_id=node_id, plant=plant, sim_kwargs=sim_kwargs)
        if plant == "sim" and bridge.sim is None:  # pragma: no cover
            pytest.skip("sim_fallback library not available")
        node = (node_class or canopen.RemoteNode)(node_id, str(EDS))
        net.add_node(node)
        bridge.start()
        time.sleep(0.05)
        yield net, node, bridge
    finally:
        if bridge is not None:
            bridge.close()
        net.disconnect()
        bus.shutdown()
