"""Unit conversions between the sequence files' units and the drive's SI units.

The paper describes its linear motor in rotary-equivalent units (r/min, N·m).
A linear motor is described by its pole pitch tau (m); the rotary equivalent
needs the pole-pair count p as well. With the equivalent radius
``r = p tau / pi`` (so that ``theta_e = p theta_m = pi x / tau``):

* speed: ``v [m/s] = n [r/min] * 2 pi / 60 * r``
* force: ``F [N] = T [N·m] / r``

The bench works in linear SI units internally (m/s, N); per-mille force values
(CiA 402 0x6071) are relative to the drive's rated force.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

from protocols import units as U

#: Speed units accepted in sequence files.
SPEED_UNITS: tuple[str, ...] = ("r/min", "rpm", "m/s", "mm/s")
#: Force/torque units accepted in sequence files.
FORCE_UNITS: tuple[str, ...] = ("N", "N*m", "N.m", "Nm", "N·m")


@dataclass(frozen=True)
class MotorUnits:
    """Geometry needed to convert rotary-equivalent units to linear ones, and which of the
    two the motor is reported in.

    Attributes
    ----------
    pole_pitch_m : float
        Pole pitch tau (m); ``theta_e = pi x / tau``.
    pole_pairs : float
        Rotary-equivalent pole pairs p (dimensionless).
    linear : bool or None
        The motor file's ``[motor] parameterization`` is "linear": reported in m/s, mm and
        N; else (a "rotary" file: the paper's rotary-equivalent description) in r/min and
        N·m. None: not told (geometry only); :func:`run_units` resolves it for a run, and
        it reads as rotary-equivalent (the bench's units before motor files said it).
    """

    pole_pitch_m: float
    pole_pairs: float
    linear: bool | None = None

    @property
    def system(self) -> str:
        """"linear" or "rotary": the units the bench speaks for this motor."""
        return "linear" if self.linear else "rotary"

    @property
    def speed_unit(self) -> str:
        """Unit of :meth:`speed_of` ("m/s" or "r/min")."""
        return "m/s" if self.linear else "r/min"

    @property
    def force_unit(self) -> str:
        """Unit of :meth:`force_of` ("N" or "N·m rotary equiv.")."""
        return "N" if self.linear else "N·m rotary equiv."

    def speed_of(self, w_radps_e: Any) -> Any:
        """Electrical rad/s in this motor's speed unit (:attr:`speed_unit`; arrays too)."""
        if self.linear:
            return w_radps_e * U.m_per_electrical_rad(self.pole_pitch_m)
        return U.radps_e_to_rpm(w_radps_e, self.pole_pairs)

    def speed_of_mps(self, v_mps: Any) -> Any:
        """A linear speed (m/s) in this motor's speed unit (arrays too)."""
        return v_mps if self.linear else U.mps_to_rpm(v_mps, self.pole_pairs,
                                                      self.pole_pitch_m)

    def force_of(self, force_N: Any) -> Any:
        """A force (N) in this motor's force unit: N, or the rotary-equivalent torque
        ``T = F r`` (N·m) (arrays too)."""
        return force_N if self.linear else force_N * self.radius_m

    @property
    def radius_m(self) -> float:
        """Equivalent radius ``r = p tau / pi`` (m)."""
        return U.radius_m(self.pole_pairs, self.pole_pitch_m)

    def speed_to_mps(self, value: float, unit: str) -> float:
        """Convert a speed in ``unit`` (one of :data:`SPEED_UNITS`) to m/s."""
        if unit in ("r/min", "rpm"):
            return U.rpm_to_mps(value, self.pole_pairs, self.pole_pitch_m)
        if unit == "m/s":
            return float(value)
        if unit == "mm/s":
            return value * 1e-3
        raise ValueError(f"unknown speed unit {unit!r}; allowed: {SPEED_UNITS}")

    def mps_to_rpm(self, v_mps: float) -> float:
        """Linear speed (m/s) to rotary-equivalent speed (r/min)."""
        return U.mps_to_rpm(v_mps, self.pole_pairs, self.pole_pitch_m)

    def force_to_N(self, value: float, unit: str) -> float:
        """Convert a force (N) or rotary-equivalent torque (N·m) to N."""
        if unit == "N":
            return float(value)
        if unit in ("N*m", "N.m", "Nm", "N·m"):
            return value / self.radius_m
        raise ValueError(f"unknown force unit {unit!r}; allowed: {FORCE_UNITS}")

    def theta_e_rad(self, x_m: float) -> float:
        """Electrical angle (rad) of a position x (m)."""
        return x_m * U.electrical_rad_per_m(self.pole_pitch_m)

    def rad_e_to_mm(self, angle_rad: float) -> float:
        """Electrical angle (rad) to mover displacement (mm)."""
        return angle_rad * U.m_per_electrical_rad(self.pole_pitch_m) * 1e3


#: Units the drive's CiA 402 objects use on the wire (od.yaml's ``unit:``) -> (SI unit, factor
#: from wire to SI). "per mille" is of the drive's rated force (:attr:`Drive.force_rated_N`).
#: Entries whose wire unit is not listed are SI already.
WIRE_UNITS: dict[str, tuple[str, float]] = {
    "um": ("m", 1e-6),
    "um/s": ("m/s", 1e-6),
    "ms": ("s", 1e-3),
    "per mille": ("", 1e-3),
}


def wire_unit(e: Any) -> tuple[str, float]:
    """(SI unit, wire-to-SI factor) of an OD entry (``protocols.generated.od_names.Entry``)."""
    return WIRE_UNITS.get(e.unit, (e.unit, 1.0))


def wire_to_si(e: Any, raw: float) -> float:
    """An OD entry's wire value in SI (per mille: the fraction of the rated value)."""
    return float(raw) * wire_unit(e)[1]


def si_to_wire(e: Any, value: float) -> int:
    """An SI value in an integer OD entry's wire unit, rounded to the nearest count."""
    return int(round(value / wire_unit(e)[1]))


#: The paper's Table 1 geometry (p = 4) with the sim's pole pitch (24 mm).
PAPER_UNITS = MotorUnits(pole_pitch_m=0.024, pole_pairs=4.0, linear=False)


def units_of(motor: Any) -> MotorUnits:
    """Units of a loaded motor (``sim_fallback.load_motor``): its geometry, and linear when
    its file says ``parameterization = "linear"`` (the one place that decides it)."""
    return MotorUnits(pole_pitch_m=float(motor.tau_m), pole_pairs=float(motor.pole_pairs),
                      linear=motor.parameterization == "linear")


def motor_units(motor: str | None) -> MotorUnits:
    """Units of a motor file from ``sim_fallback/motors`` (name or path).

    Falls back to :data:`PAPER_UNITS` when the simulator package cannot be
    imported (e.g. a bench-only install talking to hardware).
    """
    if not motor:
        return PAPER_UNITS
    try:
        from sim_fallback import load_motor
    except ImportError:  # pragma: no cover - bench-only install
        return PAPER_UNITS
    return units_of(load_motor(motor))


def run_units(meta: dict[str, Any], units: MotorUnits | None = None) -> MotorUnits:
    """The units a run is reported in, from its ``meta.json`` (``units``, ``sequence.motor``)
    and the connection's :class:`MotorUnits` when at hand.

    The geometry is ``units``' (else meta's); linear is ``units.linear`` when told, else
    meta's ``units.linear``, else the sequence's motor file's ``parameterization`` when
    that file has the run's geometry (a ``--motor`` of another geometry, or a file no
    longer there, reads as rotary-equivalent, the bench's units before motor files said
    it).
    """
    mu = meta.get("units") if isinstance(meta.get("units"), dict) else {}
    if units is None:
        try:
            units = MotorUnits(float(mu["pole_pitch_m"]), float(mu["pole_pairs"]))
        except (KeyError, TypeError, ValueError):
            units = PAPER_UNITS
    if units.linear is not None:
        return units
    if isinstance(mu.get("linear"), bool):
        return replace(units, linear=mu["linear"])
    seq = meta.get("sequence") if isinstance(meta.get("sequence"), dict) else {}
    linear = False
    try:
        m = motor_units(str(seq["motor"])) if seq.get("motor") else PAPER_UNITS
        if (math.isclose(m.pole_pitch_m, units.pole_pitch_m, rel_tol=1e-9)
                and math.isclose(m.pole_pairs, units.pole_pairs, rel_tol=1e-9)):
            linear = bool(m.linear)
    except Exception:  # noqa: BLE001 - a motor file gone or broken: rotary-equivalent
        pass
    return replace(units, linear=linear)
