"""The load on the motor under test, as a device with one interface.

Positive load force opposes positive motion (N), as in the simulator.

* :class:`CanopenLoad`: on hardware, a second CiA 402 node (the load
  machine) in cyclic synchronous torque mode; it produces ``-F`` so that a
  positive load brakes positive motion.
* :class:`SimLoad` (in :mod:`sim_fallback`): the plant's external load
  force of the simulated drive, applied at an exact simulation time.
* :class:`NoLoad`: nothing attached; load steps are refused.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from bench._drive import Drive


@runtime_checkable
class LoadDevice(Protocol):
    """Something that applies an external force to the mover (N)."""

    name: str

    def enable(self) -> None:
        """Make the load able to apply force."""

    def disable(self) -> None:
        """Remove the load force (safe state)."""

    def set_force_N(self, force_N: float) -> None:
        """Apply a constant load force (N, positive opposes positive motion)."""

    def ramp_force_N(self, force_N: float, duration_s: float) -> bool:
        """Ramp linearly to ``force_N`` over ``duration_s`` (s) if the device can do
        it natively; return False to let the runner ramp in small steps."""


class NoLoad:
    """No load machine: any non-zero load is an error."""

    name = "none"

    def enable(self) -> None:
        pass

    def disable(self) -> None:
        pass

    def set_force_N(self, force_N: float) -> None:
        if force_N != 0.0:
            raise RuntimeError("this bench has no load device; load steps need a load "
                               "machine (--load-node) or the simulated drive")

    def ramp_force_N(self, force_N: float, duration_s: float) -> bool:
        self.set_force_N(force_N)
        return True


class CanopenLoad:
    """A load machine: a second CiA 402 drive in torque (force) mode.

    Parameters
    ----------
    drive : Drive
        The load machine's node (same network, other node id).
    """

    name = "canopen"

    def __init__(self, drive: Drive) -> None:
        self.drive = drive

    def enable(self) -> None:
        d = self.drive
        # The runner enables the load with every `enable` step; Drive.enable zeroes 0x6071,
        # which would silently drop a load already applied (the simulated load keeps it).
        if d.enabled and d.mode == "force" and d.state == "OPERATION ENABLED":
            return
        d.enable("force")

    def disable(self) -> None:
        self.drive.disable()

    def set_force_N(self, force_N: float) -> None:
        self.drive.set_force_N(-force_N)

    def ramp_force_N(self, force_N: float, duration_s: float) -> bool:
        return False
