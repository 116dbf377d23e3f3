"""Live telemetry with rerun-sdk 0.41: viewer spawn/connect/serve, or an .rrd file.

Entities (all scalars on the ``drive_time`` timeline, s)::

    position/true, position/estimate     electrical angle (rad, wrapped)
    position_error                       theta_e - theta_hat (rad el.)
    speed/true, speed/estimate, speed/reference   (r/min, rotary equivalent)
    current/i_d, current/i_q             estimated-frame currents (A)
    pll/error                            PLL error (rad)
    hf/amplitude                         demodulated HF amplitude (A)
    state/cia402, state/start_phase, state/fault_code
    load                                 external load (N)

High-rate data goes in with ``rr.send_columns`` (one call per chunk and
entity). Truth entities exist only for the simulated drive.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

TIMELINE = "drive_time"


def blueprint() -> Any:
    """The bench's default rerun blueprint."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                rrb.TimeSeriesView(origin="/position", name="position: true vs estimate"),
                rrb.TimeSeriesView(origin="/position_error", name="position error (rad el.)"),
            ),
            rrb.Horizontal(
                rrb.TimeSeriesView(origin="/speed", name="speed vs estimate (r/min)"),
                rrb.TimeSeriesView(origin="/current", name="i_d / i_q (A)"),
            ),
            rrb.Horizontal(
                rrb.TimeSeriesView(origin="/pll", name="PLL error (rad)"),
                rrb.TimeSeriesView(origin="/hf", name="HF amplitude (A)"),
                rrb.TimeSeriesView(origin="/state", name="drive state"),
            ),
        ),
        collapse_panels=True,
    )


class RerunSink:
    """Streams drive signals to rerun.

    Parameters
    ----------
    mode : {"spawn", "save", "serve", "connect"}
        ``spawn`` a viewer, ``save`` to an .rrd file (headless), ``serve`` a
        gRPC server (viewers connect to the printed URL), ``connect`` to a
        running viewer at ``target`` (URL).
    target : str or Path, optional
        File for ``save``; URL for ``connect``.
    pole_pairs : float
        For r/min (rotary equivalent).
    decimation : int
        Keep every n-th sample of the simulated drive's full-rate record
        (12: 2 kHz at 24 kHz PWM).
    """

    def __init__(self, mode: str, target: str | Path | None = None, pole_pairs: float = 4.0,
                 decimation: int = 12, app_id: str = "pmlsm_bench") -> None:
        import rerun as rr

        self.rr = rr
        self.mode = mode
        self.decimation = max(1, int(decimation))
        self.rpm = 60.0 / (2.0 * math.pi * pole_pairs)
        self.url: str | None = None
        self.path: Path | None = None
        self._last_state: tuple[int, int, int] | None = None
        rr.init(app_id, spawn=False)
        bp = blueprint()
        if mode == "spawn" and not os.environ.get("DISPLAY") and not os.environ.get(
                "WAYLAND_DISPLAY"):
            mode = "save"  # headless: no viewer to spawn
            self.mode = mode
        if mode == "spawn":
            rr.spawn(default_blueprint=bp)
        elif mode == "serve":
            self.url = rr.serve_grpc(default_blueprint=bp)
        elif mode == "connect":
            rr.connect_grpc(str(target) if target else None, default_blueprint=bp)
        elif mode == "save":
            self.path = Path(target or "telemetry.rrd")
            self.path.parent.mkdir(parents=True, exist_ok=True)
            rr.save(self.path, default_blueprint=bp)
        else:
            raise ValueError(f"rerun mode {mode!r}; allowed: spawn, save, serve, connect")
        rr.send_blueprint(bp)

    def set_time_hint(self, t_s: float) -> None:
        """Unused hook (progress); kept for symmetry with the runner."""

    def _col(self, entity: str, t: np.ndarray, v: np.ndarray) -> None:
        rr = self.rr
        rr.send_columns(entity, indexes=[rr.TimeColumn(TIMELINE, duration=t)],
                        columns=rr.Scalars.columns(scalars=np.asarray(v, dtype=np.float64)))

    def log_sim_chunk(self, t: np.ndarray, values: dict[str, np.ndarray],
                      units: dict[str, str]) -> None:
        """Log one chunk of the simulated drive's record (truth + firmware signals)."""
        k = self.decimation
        t = np.asarray(t)[::k]
        if t.size == 0:
            return

        def g(name: str) -> np.ndarray | None:
            v = values.get(name)
            return None if v is None else np.asarray(v)[::k]

        th, thh = g("theta_e_rad"), g("theta_hat_rad")
        wrap = lambda x: (x + np.pi) % (2 * np.pi) - np.pi  # noqa: E731
        if th is not None:
            self._col("position/true", t, wrap(th))
        if thh is not None:
            self._col("position/estimate", t, wrap(thh))
        if th is not None and thh is not None:
            self._col("position_error", t, wrap(th - thh))
        for src, ent, scale in (("omega_e_radps", "speed/true", self.rpm),
                                ("omega_hat_radps", "speed/estimate", self.rpm),
                                ("speed_ref_radps_e", "speed/reference", self.rpm),
                                ("pll_err_rad", "pll/error", 1.0),
                                ("hf_amp_A", "hf/amplitude", 1.0),
                                ("load_N", "load", 1.0),
                                ("cia402_state", "state/cia402", 1.0),
                                ("start_phase", "state/start_phase", 1.0),
                                ("fault_code", "state/fault_code", 1.0)):
            v = g(src)
            if v is not None:
                self._col(ent, t, v.astype(np.float64) * scale)
        idq = g("i_dq_hat_A")
        if idq is not None and idq.ndim == 2:
            self._col("current/i_d", t, idq[:, 0])
            self._col("current/i_q", t, idq[:, 1])

    def log_signal(self, entity: str, t: np.ndarray, v: np.ndarray) -> None:
        """Log any signal (e.g. decoded PDO or serial telemetry on hardware)."""
        if np.size(t):
            self._col(entity, np.asarray(t), np.asarray(v))

    def close(self) -> None:
        """Flush and disconnect (closes the .rrd file)."""
        try:
            self.rr.disconnect()
        except Exception:  # noqa: BLE001 - best effort at exit
            pass
