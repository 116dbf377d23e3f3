"""Live telemetry to rerun: headless recording to an .rrd file with the blueprint."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench._live import RerunSink


def test_headless_rerun_writes_rrd(tmp_path: Path) -> None:
    path = tmp_path / "t.rrd"
    sink = RerunSink("save", path, pole_pairs=4, decimation=1)
    t = np.arange(2400) / 24000
    sink.log_sim_chunk(t, {"theta_e_rad": 40 * t, "theta_hat_rad": 40 * t + 0.01,
                           "omega_e_radps": np.full_like(t, 40.0),
                           "omega_hat_radps": np.full_like(t, 40.5),
                           "i_dq_hat_A": np.c_[0 * t, 1 + 0 * t],
                           "pll_err_rad": 0 * t, "hf_amp_A": 0 * t + 0.1,
                           "cia402_state": np.full(t.size, 4, np.uint8)}, {})
    sink.log_signal("pdo/speed_hat_mps", t[:10], np.ones(10))
    sink.close()
    assert path.stat().st_size > 10_000
    assert path.read_bytes()[:4] in (b"RRF2", b"RRF0", b"RRF1")
