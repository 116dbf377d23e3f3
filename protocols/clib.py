"""Load the firmware's protocol code as shared libraries (ctypes).

The libraries are built by the project's one CMake build (``pip install .``
installs them into this package; a development build leaves them under
``build/*/firmware_c/comm``):

* ``libpmlsm_co``   : the CANopen + serial stacks alone (vectors, tests);
* ``libpmlsm_comm`` : the whole drive application: core + CANopen + serial
  (``fw_app_*``), used by :class:`sim_fallback.DriveBridge` without a plant.

Search order: ``$PMLSM_CO_LIB`` / ``$PMLSM_COMM_LIB``, this package's folder
(wheel install), ``$PMLSM_BUILD_DIR/firmware_c/comm``, then
``<repo>/build/*/firmware_c/comm`` (newest first).
"""

from __future__ import annotations

import ctypes
import os
from pathlib import Path

_HERE = Path(__file__).resolve().parent
_REPO = _HERE.parent


def find(name: str, env: str) -> Path:
    """Path of ``lib<name>.so``; raises OSError naming every place looked at."""
    fname = f"lib{name}.so"
    tried: list[Path] = []
    if os.environ.get(env):
        tried.append(Path(os.environ[env]))
    tried.append(_HERE / fname)
    if os.environ.get("PMLSM_BUILD_DIR"):
        tried.append(Path(os.environ["PMLSM_BUILD_DIR"]) / "firmware_c" / "comm" / fname)
    builds = sorted(_REPO.glob(f"build/*/firmware_c/comm/{fname}"),
                    key=lambda p: p.stat().st_mtime, reverse=True)
    tried.extend(builds)
    for p in tried:
        if p.is_file():
            return p
    raise OSError(
        f"{fname} not found (looked in: {', '.join(map(str, tried)) or 'nowhere'}); "
        "build it with `pip install .` or `cmake -S . -B build/dev && cmake --build build/dev`, "
        f"or point ${env} at it")


def load_co() -> ctypes.CDLL:
    """The CANopen + serial stacks alone (no control core)."""
    return ctypes.CDLL(str(find("pmlsm_co", "PMLSM_CO_LIB")))


def load_app() -> ctypes.CDLL:
    """The whole drive application: core + CANopen + serial (fw_app_*)."""
    return ctypes.CDLL(str(find("pmlsm_comm", "PMLSM_COMM_LIB")))
