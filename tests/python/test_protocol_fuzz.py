"""Short libFuzzer runs (ASan + UBSan) of the SDO server, the PDO path and the
serial frame parser. Long run: ``tests/fuzz/run.sh 3600`` (docs/protocols.md).

Seconds per target: env PMLSM_FUZZ_SECONDS (default 10).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
RUN = ROOT / "tests" / "fuzz" / "run.sh"
TARGETS = ("fuzz_sdo", "fuzz_pdo", "fuzz_serial", "fuzz_app", "fuzz_slcan")


def _need_clang() -> None:
    if shutil.which(os.environ.get("FUZZ_CC", "clang")) is None:
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail("clang (with libFuzzer) is required in CI for the fuzz tests")
        pytest.skip("clang not installed: libFuzzer harnesses cannot be built "
                    "(apt-get install clang); set CI=true to make this a failure")


@pytest.mark.parametrize("target", TARGETS)
def test_fuzz_short_run(target):
    _need_clang()
    secs = int(os.environ.get("PMLSM_FUZZ_SECONDS", "10"))
    p = subprocess.run(["bash", str(RUN), str(secs), target], capture_output=True, text=True,
                       timeout=secs * 6 + 180)
    out = p.stdout + p.stderr
    m = re.search(rf"FUZZ {target} runs=(\d+) exec/s=(\d+) cov=(\d+) ft=(\d+) rc=(\d+)", out)
    assert m, out
    assert p.returncode == 0 and m.group(5) == "0", out
    runs, cov = int(m.group(1)), int(m.group(3))
    assert runs > 1000, out
    assert cov > 50, out
    print(m.group(0))
