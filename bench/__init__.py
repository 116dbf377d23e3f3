"""pmlsm-bench supervisor: drive control, sequences, logging, telemetry, reports.

Metrics are the project's single definitions in :mod:`sim_fallback.metrics`
(re-exported here as ``compute_metrics`` and ``METRIC_NAMES``).

Public API (internals live in private modules)::

    from bench import load_sequence, connect, run_sequence, Drive, Runner

The names are imported on first use (PEP 562), so ``bench --help`` or
``bench validate`` do not pay for python-can, canopen and the simulator.
python-can imports asammdf (with pandas and sympy, about 0.9 s) for its MF4
CAN-log reader/writer, which the bench does not use: while ``can.io.mf4`` is
being imported that import is deferred (python-can then treats asammdf as
missing); the first real ``import asammdf`` (the bench's MF4 signal writer)
re-imports ``can.io.mf4`` so python-can's MF4 support is complete again.
"""

from __future__ import annotations

import importlib
import sys
from typing import Any

from protocols import __version__  # the product's one version


class _RestoreCanMf4Loader:
    """Wraps asammdf's own loader: after asammdf is executed, re-import ``can.io.mf4``
    so python-can's MF4 reader/writer see it. Everything else is the real loader's."""

    def __init__(self, real: Any) -> None:
        self._real = real

    def __getattr__(self, name: str) -> Any:
        return getattr(self._real, name)

    def create_module(self, spec: Any) -> Any:
        return self._real.create_module(spec)

    def exec_module(self, module: Any) -> None:
        self._real.exec_module(module)
        mf4 = sys.modules.get("can.io.mf4")
        if mf4 is not None and getattr(mf4, "asammdf", None) is None:
            try:
                importlib.reload(mf4)
            except Exception:  # noqa: BLE001, S110 - python-can keeps "asammdf missing"
                pass


class _DeferAsammdfForCan:
    """Meta-path hook, see the module docstring; only ever answers for ``asammdf``."""

    @classmethod
    def find_spec(cls, name: str, path: Any = None, target: Any = None) -> Any:
        if name != "asammdf":
            return None
        mf4 = sys.modules.get("can.io.mf4")
        if mf4 is None:
            return None
        if getattr(getattr(mf4, "__spec__", None), "_initializing", False):
            raise ImportError("asammdf deferred by bench while python-can loads")
        if getattr(mf4, "asammdf", True) is not None:
            return None
        for finder in sys.meta_path:
            if finder is cls or not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(name, path, target)
            if spec is not None:
                if spec.loader is not None and hasattr(spec.loader, "exec_module"):
                    spec.loader = _RestoreCanMf4Loader(spec.loader)
                return spec
        return None


if "can" not in sys.modules and _DeferAsammdfForCan not in sys.meta_path:
    sys.meta_path.insert(0, _DeferAsammdfForCan)

_EXPORTS: dict[str, str] = {
    "Drive": "bench._drive", "DriveError": "bench._drive", "Param": "bench._drive",
    "ParamError": "bench._drive", "WallClock": "bench._drive", "fault_text": "bench._drive",
    "CanopenLoad": "bench._load", "LoadDevice": "bench._load", "NoLoad": "bench._load",
    "RunLogger": "bench._logging", "SeqCounter": "bench._logging",
    "read_signals": "bench._logging",
    "summary": "bench._report", "write_html": "bench._report", "write_junit": "bench._report",
    "write_summary_json": "bench._report",
    "ExpectResult": "bench._runner", "Runner": "bench._runner", "RunResult": "bench._runner",
    "SCHEMA": "bench._sequence", "Issue": "bench._sequence", "Sequence": "bench._sequence",
    "SequenceError": "bench._sequence", "Step": "bench._sequence",
    "SequenceLoader": "bench._sequence", "compose_yaml": "bench._sequence",
    "rerun_exe": "bench._live", "wait_port": "bench._live", "web_viewer_url": "bench._live",
    "PdoRecorder": "bench._session",
    "TelemetryReader": "bench._session",
    "EXTRACTORS": "bench._sequence", "plotly_page_parts": "bench._report",
    "load_sequence": "bench._sequence", "validate_sequence": "bench._sequence",
    "expand": "bench._sequence",
    "StoreError": "bench._results", "record_run": "bench._results",
    "station_fields": "bench._results",
    "Connection": "bench._session", "NoHardware": "bench._session",
    "connect": "bench._session", "open_sim": "bench._session",
    "run_sequence": "bench._session",
    "SimDrive": "sim_fallback",
    "SimLoad": "sim_fallback",
    "MotorUnits": "bench._units",
    "METRIC_NAMES": "sim_fallback.metrics", "compute_metrics": "sim_fallback.metrics",
}

__all__ = sorted(_EXPORTS, key=str.lower) + ["__version__"]


def __getattr__(name: str) -> Any:
    mod = _EXPORTS.get(name)
    if mod is None:
        raise AttributeError(f"module 'bench' has no attribute {name!r}")
    value = getattr(importlib.import_module(mod), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
