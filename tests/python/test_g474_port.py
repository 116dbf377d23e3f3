"""The NUCLEO-G474RE image (firmware_c/boards/nucleo_g474re) links, fits the part,
places its handlers where RM0440's vector table says, and leaves the parameter
page out of the image.

Cross-builds the board alone (-DPMLSM_BOARD=nucleo_g474re) with the project's
toolchain file and reads the ELF with arm-none-eabi-nm / objdump / objcopy.
The port itself is NOT YET TESTED ON SILICON; its register values are checked
on the host by tests/c/test_g474_calc.c.
"""

from __future__ import annotations

import os
import re
import shutil
import struct
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
TOOLS = ("arm-none-eabi-gcc", "arm-none-eabi-nm", "arm-none-eabi-objdump", "arm-none-eabi-objcopy")

pytestmark = pytest.mark.skipif(
    any(shutil.which(t) is None for t in TOOLS) and os.environ.get("CI") != "true",
    reason="arm-none-eabi toolchain not installed (apt-get install gcc-arm-none-eabi); "
    "CI installs it",
)

#: STM32G474RE (RM0440 memory map; datasheet DS12288): 512 KB flash, 96 KB of SRAM1 + SRAM2
#: (the image does not use the 32 KB CCM SRAM)
FLASH_BASE = 0x0800_0000
FLASH_BYTES = 512 * 1024
SRAM_BASE = 0x2000_0000
SRAM_BYTES = 96 * 1024
#: the parameter page: the last 2 KB page of bank 2 (dual-bank, factory setting) or the
#: last 4 KB page (single-bank); the linker script keeps the last 4 KB out of the image
NVM_START_SINGLE = FLASH_BASE + FLASH_BYTES - 4096
NVM_START_DUAL = FLASH_BASE + FLASH_BYTES - 2048

#: RM0440 vector table: 16 core entries, then IRQ 0..101 (118 words); the positions this
#: image uses, as the manual numbers them
CORE = {1: "cm4_reset_handler", 2: "g474_nmi_handler", 3: "cm4_fault_handler",
        4: "cm4_fault_handler", 5: "cm4_fault_handler", 6: "cm4_fault_handler",
        14: "g474_pendsv_handler"}
IRQ = {11: "g474_dma_handler",   # DMA1_Channel1: LPUART1 transmission
       18: "g474_adc_handler",   # ADC1_2: the control interrupt
       21: "g474_can_handler",   # FDCAN1_IT0: receive FIFO 0
       24: "g474_brk_handler"}   # TIM1_BRK_TIM15: the power stage's trip
N_IRQ = 102


@pytest.fixture(scope="module")
def g474_build(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    build = tmp_path_factory.mktemp("g474")
    subprocess.run(
        ["cmake", "-S", str(ROOT), "-B", str(build), "-G", "Ninja",
         "-DPMLSM_TARGET_CM4=ON", "-DCMAKE_BUILD_TYPE=MinSizeRel", "-DPMLSM_BOARD=nucleo_g474re",
         f"-DCMAKE_TOOLCHAIN_FILE={ROOT / 'firmware_c/cmake/arm-none-eabi.cmake'}"],
        check=True, capture_output=True, text=True,
    )
    res = subprocess.run(["cmake", "--build", str(build), "--target", "pmlsm_nucleo_g474re.elf"],
                         check=True, capture_output=True, text=True)
    return build / "firmware_c/boards/nucleo_g474re", res.stdout


def _elf(d: Path) -> Path:
    return d / "pmlsm_nucleo_g474re.elf"


def _symbols(elf: Path) -> dict[str, int]:
    out = subprocess.run(["arm-none-eabi-nm", str(elf)], check=True, capture_output=True,
                         text=True).stdout
    syms: dict[str, int] = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 3:
            syms.setdefault(parts[2], int(parts[0], 16))
    return syms


def _sections(elf: Path) -> list[tuple[str, int, int, int, str]]:
    """(name, size, vma, lma, flags) of every section."""
    out = subprocess.run(["arm-none-eabi-objdump", "-h", str(elf)], check=True,
                         capture_output=True, text=True).stdout
    lines = out.splitlines()
    secs = []
    for i, line in enumerate(lines):
        m = re.match(r"\s*\d+\s+(\S+)\s+([0-9a-f]+)\s+([0-9a-f]+)\s+([0-9a-f]+)", line)
        if m:
            flags = lines[i + 1].strip() if i + 1 < len(lines) else ""
            secs.append((m.group(1), int(m.group(2), 16), int(m.group(3), 16),
                         int(m.group(4), 16), flags))
    return secs


def test_image_fits_the_part(g474_build: tuple[Path, str]) -> None:
    d, log = g474_build
    m = re.search(r"^\s*(\d+)\s+(\d+)\s+(\d+)\s+\d+\s+[0-9a-f]+\s+\S*pmlsm_nucleo_g474re\.elf",
                  log, re.M)
    assert m, f"no Berkeley size line in the build output:\n{log}"
    text, data, bss = (int(g) for g in m.groups())
    print(f"nucleo_g474re: text={text} data={data} bss={bss}")
    assert 20_000 < text + data <= FLASH_BYTES - 4096
    assert data + bss <= SRAM_BYTES
    binary = d / "pmlsm_nucleo_g474re.bin"
    assert binary.exists() and (d / "pmlsm_nucleo_g474re.hex").exists()
    # vectors + code + constants + the .data image, with the alignment padding between them
    assert text + data <= binary.stat().st_size <= text + data + 256
    # the port's own board name, published in 0x2090:2, is in the image
    assert b"nucleo_g474re\x00" in binary.read_bytes()


def test_vector_table_places_the_handlers(g474_build: tuple[Path, str]) -> None:
    d, _ = g474_build
    elf = _elf(d)
    syms = _symbols(elf)
    raw = d / "vectors.bin"
    subprocess.run(["arm-none-eabi-objcopy", "-O", "binary", "--only-section=.isr_vector",
                    str(elf), str(raw)], check=True)
    words = struct.unpack(f"<{len(raw.read_bytes()) // 4}I", raw.read_bytes())
    assert len(words) == 16 + N_IRQ
    sec = {s[0]: s for s in _sections(elf)}
    assert sec[".isr_vector"][2] == FLASH_BASE  # at the boot address
    assert words[0] == SRAM_BASE + SRAM_BYTES == syms["__stack_top"]
    for pos, name in CORE.items():
        assert words[pos] == syms[name] | 1, (pos, name)  # Thumb bit set
    for pos in (7, 8, 9, 10, 13):
        assert words[pos] == 0  # reserved
    default = syms["cm4_default_handler"] | 1
    for irq in range(N_IRQ):
        want = syms[IRQ[irq]] | 1 if irq in IRQ else default
        assert words[16 + irq] == want, f"IRQ {irq}"


def test_parameter_page_is_outside_the_image(g474_build: tuple[Path, str]) -> None:
    d, _ = g474_build
    elf = _elf(d)
    loaded = [s for s in _sections(elf) if "LOAD" in s[4] and s[1] > 0]
    assert loaded
    for name, size, _vma, lma, _flags in loaded:
        if FLASH_BASE <= lma < FLASH_BASE + FLASH_BYTES:
            assert lma + size <= NVM_START_SINGLE, f"{name} reaches the parameter page"
    end = max(lma + size for _n, size, _v, lma, _f in loaded
              if FLASH_BASE <= lma < FLASH_BASE + FLASH_BYTES)
    assert end <= NVM_START_SINGLE < NVM_START_DUAL
    # the RAM sections (data, bss, the stack reserve) stay inside SRAM1 + SRAM2
    for name, size, vma, _lma, flags in _sections(elf):
        if "ALLOC" in flags and SRAM_BASE <= vma < SRAM_BASE + 0x1000_0000:
            assert vma + size <= SRAM_BASE + SRAM_BYTES, name
