"""Wire protocols of the PMLSM drive: the object dictionary (od.yaml and its
generators), the serial telemetry link, and the loaders of the firmware's protocol
libraries (:mod:`protocols.clib`). It imports no simulator: the simulated drive on a bus
is :class:`sim_fallback.DriveBridge`.

Public API:

- :func:`load_od` / :class:`ObjectDictionary` / :class:`OdEntry`: protocols/od.yaml;
  :data:`EDS_PATH`: the generated EDS.
- :mod:`protocols.serial_link`: COBS + CRC-16 frames, :class:`Receiver`,
  :class:`TraceAssembler`.
- ``python -m protocols.generate [--check]``: regenerate / check generated files.
"""

from pathlib import Path

#: The product's version (pyproject.toml [project] version): the bench, the simulator and
#: the protocol tools ship as one.
__version__ = "0.1.0"

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
    "__version__",
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
