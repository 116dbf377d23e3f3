"""Processor-in-the-loop (short case for CI): the Cortex-M4F build of the core,
run under QEMU on ADC inputs recorded from closed-loop simulations, agrees with
the host build of the same sources (benchmarks/pil.py; docs/firmware.md)."""

import shutil
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))

TOOLS = ("arm-none-eabi-gcc", "qemu-system-arm", "cc")
pytestmark = pytest.mark.skipif(
    any(shutil.which(t) is None for t in TOOLS) and not __import__("os").environ.get("CI"),
    reason="needs arm-none-eabi-gcc and qemu-system-arm (installed by .ci/run)")


def test_m4_replay_agrees_with_host(tmp_path):
    import pil

    res = pil.run(["paper_startup_random", "paper_open_phase"], t_end=0.6, opt="Os",
                  work=tmp_path)
    for c in res:
        assert c["ok"], c
        assert c["closed_loop_steps"] > 5000, c  # really drove (0.2 s and more)
    by = {c["name"]: c for c in res}
    assert by["paper_startup_random"]["final_fault"] == 0
    assert by["paper_open_phase"]["final_fault"] != 0  # the fault path agrees too


def test_compare_detects_a_difference():
    import numpy as np
    import pil

    a = np.zeros(100, pil.OUT_DTYPE)
    a["pwm"] = 1
    b = a.copy()
    assert pil.agrees(pil.compare(a, b))
    b["duty"][50, 1] = 2e-4
    assert not pil.agrees(pil.compare(a, b))
    b = a.copy()
    b["fault"][99] = 0xFF09
    assert not pil.agrees(pil.compare(a, b))


def test_cycle_windows_and_regimes():
    import pil

    assert pil.cycle_windows(1000, 100, 400) == [(0, 100), (400, 500), (800, 900)]
    assert pil.cycle_windows(9000, 0, 0) == [(0, 4000), (4000, 8000), (8000, 9000)]
    assert pil.regime(3, 1, 0) == "RUN/bemf"
    assert pil.regime(3, 0, 0) == "RUN/inj"
    assert pil.regime(1, 0, 0) == "ALIGN"
    assert pil.regime(0, 0, 0x6100) == "FAULT"


def test_cycles_windows_continue_the_replay(tmp_path):
    """--cycles: the traced windows, each continued from the state the M4 replay saved
    at its start, reproduce the full replay bit for bit, and every period of every
    window is counted (both halves)."""
    import pil

    (c,) = pil.run(["paper_startup_random"], t_end=0.1, opt="Os", work=tmp_path,
                   cycles=(40, 0.05))
    cy = c["cycles"]
    assert c["ok"] and cy["windows_exact"], c
    assert cy["windows"] == [(0, 40), (1200, 1240)]
    assert cy["step"].size == 80
    assert (cy["ctl_insns"] > 100).all() and (cy["sup_insns"] > 0).all()
    assert (cy["ctl_high"] >= cy["ctl_low"]).all()
