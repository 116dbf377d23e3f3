"""pmlsm-bench supervisor: drive control, sequences, logging, telemetry, reports.

Metrics are the project's single definitions in :mod:`sim_fallback.metrics`
(re-exported here as ``compute_metrics`` and ``METRIC_NAMES``).

Public API (internals live in private modules)::

    from bench import load_sequence, connect, run_sequence, Drive, Runner
"""

__version__ = "0.1.0"

from bench._drive import Drive, DriveError, Param, ParamError, WallClock, fault_text
from bench._load import CanopenLoad, LoadDevice, NoLoad
from bench._logging import RunLogger, SeqCounter, read_signals
from bench._report import summary, write_html, write_junit, write_summary_json
from bench._runner import ExpectResult, Runner, RunResult
from bench._sequence import (
    SCHEMA,
    Issue,
    Sequence,
    SequenceError,
    Step,
    load_sequence,
    validate_sequence,
)
from bench._session import Connection, NoHardware, connect, open_sim, run_sequence
from bench._simdrive import LayoutMismatch, SimDrive, SimLoad
from bench._units import MotorUnits
from sim_fallback.metrics import METRIC_NAMES, compute_metrics

__all__ = [
    "CanopenLoad", "compute_metrics", "connect", "Connection", "Drive", "DriveError",
    "ExpectResult", "fault_text", "Issue", "LayoutMismatch", "load_sequence", "LoadDevice",
    "METRIC_NAMES", "MotorUnits", "NoHardware", "NoLoad", "open_sim", "Param", "ParamError",
    "read_signals", "run_sequence", "RunLogger", "Runner", "RunResult", "SCHEMA", "SeqCounter",
    "Sequence", "SequenceError", "SimDrive", "SimLoad", "Step", "summary", "validate_sequence",
    "WallClock", "write_html", "write_junit", "write_summary_json", "__version__",
]
