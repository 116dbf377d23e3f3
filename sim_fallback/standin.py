"""A stand-in CiA 402 drive on a python-can bus, built on canopen's LocalNode.

It answers SDOs from the generated EDS, runs the CiA 402 state machine from
the controlword, mirrors 0x6060 into 0x6061, sends TPDO1 (statusword, mode
display) on every change, TPDO4 (its time, 0x2090:3, at 24 kHz of the host's
monotonic clock; no reference sensor) on every SYNC, and can be told to raise a
fault. It has no plant and no truth, and says so: its drive kind (0x2090:1) is
"no I/O", as the blank port's. It exists to test the bench's protocol side
(state machine, parameters, safe state, logging) without the simulated drive.
"""

from __future__ import annotations

import struct
import threading
import time
from typing import Any

import can
import canopen

from protocols import EDS_PATH as DEFAULT_EDS
from protocols.generated import od_names as od

_OD = od

# statusword values per state (CiA 402, bits 0-3, 5, 6; bit 9 remote)
_SW = {
    "NOT READY TO SWITCH ON": 0x0200,
    "SWITCH ON DISABLED": 0x0240,
    "READY TO SWITCH ON": 0x0221,
    "SWITCHED ON": 0x0223,
    "OPERATION ENABLED": 0x0227,
    "QUICK STOP ACTIVE": 0x0207,
    "FAULT": 0x0208,
}


class FakeDrive402:
    """LocalNode-based CiA 402 drive for tests.

    Parameters
    ----------
    bus : can.BusABC
        Its own connection to the bus (e.g. a second ``virtual`` bus on the
        same channel).
    node_id : int
    eds : path
    """

    def __init__(self, bus: can.BusABC, node_id: int = 1, eds: Any = DEFAULT_EDS) -> None:
        self.network = canopen.Network(bus)
        self.network.NOTIFIER_CYCLE = 0.1
        self.network.connect()
        self.node = canopen.LocalNode(node_id, str(eds))
        self.network.add_node(self.node)
        self.node_id = node_id
        self.state = "SWITCH ON DISABLED"
        self.mode = 9
        self.lock = threading.Lock()
        self.history: list[str] = [self.state]
        self.writes: list[tuple[int, int, Any]] = []
        self.fail_disable = False
        #: called after a state change or a target torque write (a coupled plant's hook)
        self.on_change: Any = None
        self.target_torque = 0  # 0x6071 as last written (per mille)
        self.node.add_write_callback(self._on_write)
        self._set(od.STATUSWORD, _SW[self.state])
        self._t0 = time.monotonic()
        self.network.subscribe(0x200 + node_id, self._on_rpdo1)
        self.network.subscribe(0x080, self._on_sync)

    def close(self) -> None:
        self.network.disconnect()

    # ---- helpers ----------------------------------------------------------------------
    def _set(self, e: od.Entry, value: Any) -> None:
        var = e.of(self.node.object_dictionary)
        self.node.set_data(e.index, e.sub, var.encode_raw(value), check_writable=False)

    def _tpdo1(self) -> None:
        self.network.send_message(0x180 + self.node_id,
                                  struct.pack("<Hb", _SW[self.state], self.mode))

    def _enter(self, state: str) -> None:
        self.state = state
        self.history.append(state)
        self._set(od.STATUSWORD, _SW[state])
        self._tpdo1()
        if self.on_change is not None:
            self.on_change()

    def raise_fault(self, code: int = od.FAULT_CODES["EST_PLL_ERROR"]) -> None:
        """Latch a fault (0x603F) and enter FAULT."""
        with self.lock:
            self._set(od.ERROR_CODE, code)
            self._set(od.FAULT_HISTORY__FAULT_1, code)
            self._enter("FAULT")
        self.network.send_message(0x80 + self.node_id, struct.pack("<HB5x", code, 0x80))

    # ---- CiA 402 ----------------------------------------------------------------------
    def _controlword(self, cw: int) -> None:
        with self.lock:
            s = self.state
            if s == "NOT READY TO SWITCH ON":
                return  # the drive's self-test: it leaves by itself, commands wait
            if s == "FAULT":
                if cw & 0x80:
                    self._set(od.ERROR_CODE, 0)
                    self._enter("SWITCH ON DISABLED")
                return
            if cw & 0x02 == 0:  # disable voltage
                if self.fail_disable:
                    return
                self._enter("SWITCH ON DISABLED")
            elif cw & 0x04 == 0:  # quick stop
                self._enter("QUICK STOP ACTIVE" if s == "OPERATION ENABLED"
                            else "SWITCH ON DISABLED")
            elif cw & 0x0F == 0x06:
                self._enter("READY TO SWITCH ON")
            elif cw & 0x0F == 0x07 and s in ("READY TO SWITCH ON", "OPERATION ENABLED"):
                self._enter("SWITCHED ON")
            elif cw & 0x0F == 0x0F and s in ("SWITCHED ON", "READY TO SWITCH ON"):
                self._enter("OPERATION ENABLED")

    def _on_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        # (canopen passes the variable as the keyword `od`: the module is _OD here)
        value = od.decode_raw(data)
        self.writes.append((index, subindex, value))
        if index == _OD.CONTROLWORD.index:
            threading.Thread(target=self._controlword, args=(int(value),), daemon=True).start()
        elif index == _OD.MODES_OF_OPERATION.index:
            self.mode = int(value)
            self._set(_OD.MODES_OF_OPERATION_DISPLAY, self.mode)
        elif index == _OD.TARGET_TORQUE.index:
            self.target_torque = int(value)
            if self.on_change is not None:
                self.on_change()

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """TPDO4 as the drive's default mapping: its period count, no reference count."""
        periods = int((time.monotonic() - self._t0) * 24000.0) & 0xFFFFFFFF
        self.network.send_message(0x480 + self.node_id, struct.pack("<Ii", periods, -2**31))

    def _on_rpdo1(self, can_id: int, data: bytearray, timestamp: float) -> None:
        cw, vel = struct.unpack_from("<Hi", bytes(data).ljust(6, b"\0"))
        self.writes.append((*od.CONTROLWORD[:2], cw))
        self.writes.append((*od.TARGET_VELOCITY[:2], vel))
        self._controlword(cw)
