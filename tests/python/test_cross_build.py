"""The firmware core cross-compiles for a Cortex-M4F and stays float32.

Builds the Cortex-M4F image with arm-none-eabi-gcc (hard float, fpv4-sp-d16),
checks the size report, and disassembles the core objects to prove that no
double-precision helper (__aeabi_d*, soft double) is ever called: the M4F FPU
is single precision only, so a stray double would cost ~100x.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.skipif(
    shutil.which("arm-none-eabi-gcc") is None and os.environ.get("CI") != "true",
    reason="arm-none-eabi-gcc not installed (apt-get install gcc-arm-none-eabi); CI installs it",
)


@pytest.fixture(scope="module")
def cm4_build(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    build = tmp_path_factory.mktemp("cm4")
    subprocess.run(
        [
            "cmake", "-S", str(ROOT), "-B", str(build), "-G", "Ninja",
            "-DPMLSM_TARGET_CM4=ON", "-DCMAKE_BUILD_TYPE=MinSizeRel",
            f"-DCMAKE_TOOLCHAIN_FILE={ROOT / 'firmware_c/cmake/arm-none-eabi.cmake'}",
        ],
        check=True, capture_output=True, text=True,
    )
    res = subprocess.run(
        ["cmake", "--build", str(build)], check=True, capture_output=True, text=True
    )
    return build, res.stdout


def test_cm4_image_links_and_fits(cm4_build: tuple[Path, str]) -> None:
    _, log = cm4_build
    m = re.search(r"^\s*(\d+)\s+(\d+)\s+(\d+)\s+\d+\s+[0-9a-f]+\s+\S*pmlsm_fw_cm4\.elf", log, re.M)
    assert m, f"no Berkeley size line in build output:\n{log}"
    text, data, bss = (int(g) for g in m.groups())
    print(f"cortex-m4f drive application: text={text} data={data} bss={bss}")
    # The whole application (core + CANopen + serial link + 16 KiB trace buffer) on a
    # 128 KiB-flash / 32 KiB-RAM part (e.g. STM32G431), with room to spare: 3 KiB left
    # for the stack (the board ports' images are checked against their own parts).
    assert 20_000 < text < 96 * 1024
    assert data + bss < 29 * 1024
    # const tables (object dictionary, configuration fields) stay in flash: with PIC
    # they would land in .data.rel.ro, i.e. RAM (15.6 KB measured before the fix)
    assert data < 1024


def test_core_uses_no_double_precision(cm4_build: tuple[Path, str]) -> None:
    build, _ = cm4_build
    objdump = shutil.which("arm-none-eabi-objdump")
    assert objdump
    objs = sorted(p for p in (build / "firmware_c").rglob("*") if p.suffix in (".o", ".obj"))
    core = [o for o in objs if o.name.startswith(("fw_", "co_"))]
    assert len(core) >= 9, objs
    for obj in core:
        dis = subprocess.run([objdump, "-dr", str(obj)], capture_output=True, text=True,
                             check=True).stdout
        bad = re.findall(r"__aeabi_d\w+|__(?:add|sub|mul|div)df3|\bvmov\.f64|\bvadd\.f64", dis)
        assert not bad, f"{obj.name} uses double precision: {sorted(set(bad))}"


def test_control_path_sources_at_o2(cm4_build: tuple[Path, str]) -> None:
    """The MinSizeRel image compiles the control interrupt's sources at -O2 (the
    last -O on their command lines), the rest at -Os; the cycle benchmark
    (benchmarks/bench_cm4_estimate.py) compiles the same sources at the same levels."""
    import importlib.util

    build, _ = cm4_build
    cmds = subprocess.run(["cmake", "--build", str(build), "--", "-t", "commands"],
                          capture_output=True, text=True, check=True).stdout.splitlines()
    spec = importlib.util.spec_from_file_location(
        "bench_cm4_estimate", ROOT / "benchmarks" / "bench_cm4_estimate.py")
    bench = importlib.util.module_from_spec(spec)
    assert spec.loader is not None
    spec.loader.exec_module(bench)
    fast = {Path(p).name for p in bench.speed_sources("Os")}
    assert {"fw_ctrl.c", "fw_obs.c", "fw_inj.c", "fw_mon.c", "fw_math.c"} <= fast
    levels = {}
    for line in cmds:
        m = re.search(r"-c (\S+\.c)\s*$", line)
        if m and "-O" in line:
            levels[Path(m.group(1)).name] = re.findall(r"\s-O(\w)", line)[-1]
    for name in fast:
        assert levels.get(name) == "2", (name, levels.get(name))
    for name in ("fw_config.c", "fw_app.c"):
        assert levels.get(name) == "s", (name, levels.get(name))
