"""pmlsm-bench supervisor: drive control, sequences, logging, telemetry, reports."""

__version__ = "0.1.0"
