"""Motor identification by the drive: one procedure over a probe interface.

:func:`run_identification` runs the procedure (docs/identify.md) on any :class:`Probe`:
the simulated drive's (``sim_fallback.SimProbe``) or a rig's (the bench's CANopen and
serial-telemetry probe, ``bench identify``). It reads only what a drive measures; the
package imports neither the simulator nor the bench.
"""

from ._procedure import (
    IDENT_FW,
    IDENT_RESTORED,
    IDENT_SPEED_BW,
    PROBE_SIGNALS,
    RIP6_FIELDS,
    RIP_ORDERS,
    RIP_PREFIX,
    START_WINDOWS,
    XSAT_MAX_DRIFT_RAD,
    XSAT_MAX_SPEED_MPS,
    XSAT_POINTS,
    XSAT_PREFIX,
    Identified,
    MoverMoved,
    Probe,
    ident_overrides,
    rip6_fields,
    rip_fields,
    run_cross_saturation,
    run_identification,
    run_ripple,
    run_thrust_ripple,
    xsat_fields,
)

__all__ = ["IDENT_FW", "IDENT_RESTORED", "IDENT_SPEED_BW", "PROBE_SIGNALS", "START_WINDOWS",
           "XSAT_MAX_DRIFT_RAD", "XSAT_MAX_SPEED_MPS", "XSAT_POINTS", "XSAT_PREFIX", "Identified",
           "MoverMoved", "Probe", "ident_overrides", "run_cross_saturation", "run_identification",
           "RIP_ORDERS", "RIP_PREFIX", "run_ripple", "rip_fields", "xsat_fields",
           "RIP6_FIELDS", "run_thrust_ripple", "rip6_fields"]
