"""A stand-in CiA 402 drive on a python-can bus, built on canopen's LocalNode.

It answers SDOs from the generated EDS, runs the CiA 402 state machine from
the controlword, mirrors 0x6060 into 0x6061, sends TPDO1 (statusword, mode
display) on every change and can be told to raise a fault. It has no plant
and no truth: it exists to test the bench's protocol side (state machine,
parameters, safe state, logging) without the simulated drive.
"""

from __future__ import annotations

import struct
import threading
from typing import Any

import can
import canopen

from bench._drive import DEFAULT_EDS

# statusword values per state (CiA 402, bits 0-3, 5, 6; bit 9 remote)
_SW = {
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
        self.node.add_write_callback(self._on_write)
        self._set(0x6041, 0, _SW[self.state])
        self.network.subscribe(0x200 + node_id, self._on_rpdo1)

    def close(self) -> None:
        self.network.disconnect()

    # ---- helpers ----------------------------------------------------------------------
    def _set(self, index: int, sub: int, value: Any) -> None:
        self.node.set_data(index, sub, self.node.object_dictionary[index].encode_raw(value)
                           if sub == 0 and not hasattr(self.node.object_dictionary[index],
                                                       "subindices")
                           else self.node.object_dictionary[index][sub].encode_raw(value),
                           check_writable=False)

    def _tpdo1(self) -> None:
        self.network.send_message(0x180 + self.node_id,
                                  struct.pack("<Hb", _SW[self.state], self.mode))

    def _enter(self, state: str) -> None:
        self.state = state
        self.history.append(state)
        self._set(0x6041, 0, _SW[state])
        self._tpdo1()

    def raise_fault(self, code: int = 0xFF02) -> None:
        """Latch a fault (0x603F) and enter FAULT."""
        with self.lock:
            self._set(0x603F, 0, code)
            self._set(0x2030, 1, code)
            self._enter("FAULT")
        self.network.send_message(0x80 + self.node_id, struct.pack("<HB5x", code, 0x80))

    # ---- CiA 402 ----------------------------------------------------------------------
    def _controlword(self, cw: int) -> None:
        with self.lock:
            s = self.state
            if s == "FAULT":
                if cw & 0x80:
                    self._set(0x603F, 0, 0)
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
        value = od.decode_raw(data)
        self.writes.append((index, subindex, value))
        if index == 0x6040:
            threading.Thread(target=self._controlword, args=(int(value),), daemon=True).start()
        elif index == 0x6060:
            self.mode = int(value)
            self._set(0x6061, 0, self.mode)

    def _on_rpdo1(self, can_id: int, data: bytearray, timestamp: float) -> None:
        cw, vel = struct.unpack_from("<Hi", bytes(data).ljust(6, b"\0"))
        self.writes.append((0x6040, 0, cw))
        self.writes.append((0x60FF, 0, vel))
        self._controlword(cw)
