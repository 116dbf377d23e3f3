"""Wire protocols of the PMLSM drive: the object dictionary (od.yaml and its
generators), the serial telemetry link and the CAN bridge to the C drive.

Public API:

- :func:`load_od` / :class:`ObjectDictionary` / :class:`OdEntry`: protocols/od.yaml;
  :data:`EDS_PATH`: the generated EDS.
- :mod:`protocols.serial_link`: COBS + CRC-16 frames, :class:`Receiver`,
  :class:`TraceAssembler`.
- :class:`protocols.sim_bridge.DriveBridge`: python-can bus <-> fw_app in C
  (import it from its module; it compiles the firmware on first use).
- ``python -m protocols.generate [--check]``: regenerate / check generated files.
"""

from pathlib import Path

from ._od import ObjectDictionary, OdEntry, OdError
from ._od import load as load_od
from .serial_link import (
    Frame,
    FrameError,
    FrameType,
    Receiver,
    Trace,
    TraceAssembler,
    decode_frame,
    encode_frame,
)

#: The generated EDS (for ``canopen.RemoteNode`` / ``BaseNode402``).
EDS_PATH = Path(__file__).resolve().parent / "generated" / "pmlsm_drive.eds"

__all__ = [
    "EDS_PATH",
    "Frame",
    "FrameError",
    "FrameType",
    "ObjectDictionary",
    "OdEntry",
    "OdError",
    "Receiver",
    "Trace",
    "TraceAssembler",
    "decode_frame",
    "encode_frame",
    "load_od",
]
