"""Build and load the firmware's protocol code as a shared library (ctypes).

Used by the Python tests (vectors against the C implementation) and by
:mod:`protocols.sim_bridge`. The library is compiled straight from the
sources with the system C compiler into ``build/comm/py`` and rebuilt when a
source is newer.
"""

from __future__ import annotations

import ctypes
import os
import shutil
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FW = ROOT / "firmware_c"
COMM = FW / "comm"
OUT = ROOT / "build" / "comm" / "py"

CO_SOURCES = [
    COMM / "src" / "co_od.c",
    COMM / "src" / "co_node.c",
    COMM / "src" / "fw_serial.c",
    COMM / "generated" / "co_od_table.c",
    COMM / "generated" / "fw_serial_signals.c",
]


def _core_sources() -> list[Path]:
    return sorted((FW / "src").glob("*.c"))


def _compiler() -> str:
    for cc in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if cc and shutil.which(cc):
            return cc
    raise OSError("no C compiler found (set CC)")


def build(name: str, with_app: bool, out_dir: Path = OUT) -> Path:
    """Compile lib<name>.so; with_app adds the core and fw_app.c."""
    srcs = list(CO_SOURCES)
    if with_app:
        srcs += _core_sources() + [COMM / "src" / "fw_app.c"]
    headers = list((COMM / "include" / "pmlsm").glob("*.h")) + list(
        (COMM / "generated").glob("*.h")) + list((FW / "include" / "pmlsm").glob("*.h"))
    out_dir.mkdir(parents=True, exist_ok=True)
    lib = out_dir / f"lib{name}.so"
    newest = max(p.stat().st_mtime for p in srcs + headers)
    if lib.exists() and lib.stat().st_mtime >= newest:
        return lib
    tmp = lib.with_suffix(f".{os.getpid()}.tmp")
    cmd = [_compiler(), "-std=c11", "-O2", "-g", "-shared", "-fPIC",
           f"-I{COMM / 'include'}", f"-I{COMM / 'generated'}", f"-I{FW / 'include'}",
           "-o", str(tmp), *map(str, srcs), "-lm"]
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    os.replace(tmp, lib)
    return lib


def load_co() -> ctypes.CDLL:
    """The CANopen + serial stacks alone (no control core)."""
    return ctypes.CDLL(str(build("pmlsm_co_py", with_app=False)))


def load_app() -> ctypes.CDLL:
    """The whole drive application: core + CANopen + serial (fw_app_*)."""
    return ctypes.CDLL(str(build("pmlsm_app_py", with_app=True)))
