"""Drift test: tests/c/ref_vectors.h must hold what gen_ref_vectors.py generates,
number by number within the generator's stated tolerance (rtol 1e-9): numpy and libm
versions differ in the last printed digits of float64 references."""

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


def test_check_compares_numbers_not_digits(tmp_path: Path) -> None:
    """A change in the 13th digit (another numpy) passes; one in the 6th fails."""
    sys.path.insert(0, str(GEN.parent))
    import gen_ref_vectors as g

    good = (GEN.parent / "ref_vectors.h").read_text()
    tiny = good.replace("-1.703869501750e-01", "-1.703869501751e-01", 1)
    big = good.replace("-1.703869501750e-01", "-1.703879501750e-01", 1)
    assert tiny != good and big != good
    assert g.same_numbers(good, tiny)
    assert not g.same_numbers(good, big)
    assert not g.same_numbers(good, good.replace("static const", "static", 1))
