"""Drift test: tests/c/ref_vectors.h must equal what gen_ref_vectors.py generates."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
GEN = ROOT / "tests" / "c" / "gen_ref_vectors.py"


def test_ref_vectors_up_to_date() -> None:
    proc = subprocess.run(
        [sys.executable, str(GEN), "--check"], capture_output=True, text=True, cwd=ROOT
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_check_detects_drift(tmp_path: Path) -> None:
    """--check must fail on a stale header (the drift test can fail)."""
    stale = tmp_path / "ref_vectors.h"
    good = (GEN.parent / "ref_vectors.h").read_text()
    stale.write_text(good.replace("REF_N_PI 240", "REF_N_PI 239"))
    proc = subprocess.run(
        [sys.executable, str(GEN), "--check", "--out", str(stale)],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert proc.returncode == 1
    assert "out of date" in proc.stderr
