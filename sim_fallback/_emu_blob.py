"""The emulated board's boot block: what the board's "hardware" is on this power-up.

The emulated board (``firmware_c/boards/mps2_an386``, docs/boards.md) runs the firmware
image in QEMU with the simulator's plant compiled in as its virtual motor. What a real
board has in copper and silicon - the motor on the rig, its initial position, the noise
of the ADC, the scale, the drive's factory configuration, its node id, where its flash
page is kept - it reads at boot from this block, which QEMU loads into PSRAM
(``-device loader,file=BLOCK,addr=0x21000000``) before the first instruction.

Layout (little endian; the board checks every field and refuses to start otherwise,
exit code 2 with one line on its semihosting console)::

    0    u32  magic 0x424D4550 ('PEMB')
    4    u32  format (EMU_BLOB_FORMAT)
    8    u32  total length in bytes
    12   u32  CRC-32 (IEEE 802.3, as fw_app_crc32 and zlib.crc32) of bytes [16, total)
    16   u32  sizeof(sim_plant_params_t) as written here
    20   u32  sizeof(fw_config_t) as written here
    24   u32  firmware version the block is for (FW_VERSION_U32; another image refuses it)
    28   u8   CANopen node id (1..127)
    29   u8[3] reserved, 0
    32   f64  initial mover position x0 (m)
    40   f64  initial load force (N, opposes +x)
    48   char[128] the flash page's backing file on the host (NUL-terminated; relative to
              QEMU's working directory; empty: no non-volatile memory)
    176  sim_plant_params_t  the virtual motor (pmlsm_sim.h)
    176+P fw_config_t        the drive's power-up configuration (before its stored block)
"""

from __future__ import annotations

import ctypes as C
import struct
import zlib
from pathlib import Path
from typing import Any

from protocols.generated import od_names

from ._lib import FwConfig, SimPlantParams
from ._sim import drive_params

EMU_BLOB_MAGIC = 0x424D4550
EMU_BLOB_FORMAT = 1
EMU_BLOB_ADDR = 0x21000000  #: where QEMU loads it (the mps2's PSRAM)
EMU_BLOB_HEADER = 176
NVM_PATH_MAX = 127


def firmware_version_u32(text: str = od_names.FW_VERSION_STRING) -> int:
    """``MAJOR.MINOR.PATCH`` -> 0x00MMmmpp (FW_VERSION_U32)."""
    a, b, c = (int(x) for x in text.split("."))
    return (a << 16) | (b << 8) | c


def emu_boot_blob(motor: Any = "paper_salient", extractor: int | str = "sogi_adaptive",
                  seed: int = 0, x0_m: float = 0.0, node_id: int = 1, nvm_path: str = "",
                  load_N: float = 0.0, noise: float = 1.0,
                  plant: dict[str, Any] | None = None, fw: dict[str, float] | None = None
                  ) -> bytes:
    """The boot block for one emulated drive (see the module text).

    The plant and the configuration are :func:`sim_fallback._sim.drive_params`'s: the
    same drive as the host simulated drive for the same motor, extractor and seed.

    Raises ValueError for a node id outside 1..127, a non-finite position or load, a
    path too long for the block, or a plant parameter the simulator refuses.
    """
    if not 1 <= int(node_id) <= 127:
        raise ValueError(f"node id {node_id}: allowed range [1, 127]")
    for name, v in (("x0_m", x0_m), ("load_N", load_N)):
        if not (isinstance(v, (int, float)) and abs(float(v)) < float("inf")):
            raise ValueError(f"{name} {v!r}: not a finite number")
    raw_path = str(nvm_path).encode("utf-8")
    if len(raw_path) > NVM_PATH_MAX or b"\0" in raw_path:
        raise ValueError(f"non-volatile memory file {nvm_path!r}: at most {NVM_PATH_MAX} "
                         "bytes of UTF-8 without NUL (use a shorter or relative path)")
    # the emulated board's plant has no realism block (sim_realism_t) in its boot block
    # yet: a motor that sets one would run a simpler plant there than on the host, silently
    from ._motors import load_motor, split_plant_overrides

    mot = motor if not isinstance(motor, (str, Path)) else load_motor(motor)
    plant, real_ov = split_plant_overrides(plant)
    real = {**mot.realism, **real_ov}
    on = sorted(k for k, v in real.items() if k != "sal2_order" and float(v) != 0.0)
    if on:
        raise ValueError(f"motor {mot.name}: the emulated board's plant has no plant realism "
                         f"yet ({', '.join(on)} set); run it on the host's simulated drive "
                         "(--sim or --sim-server)")
    motor = mot
    # as the bench's host simulated drive (sim_fallback.SimDrive's BENCH_PLANT): the noise
    # restarts from the seed at every switch-on of the inverter
    params, cfg = drive_params(motor, extractor, seed, noise, {"noise_restart": 1,
                                                               **(plant or {})}, fw)
    body = (struct.pack("<II", C.sizeof(SimPlantParams), C.sizeof(FwConfig))
            + struct.pack("<I", firmware_version_u32())
            + struct.pack("<B3x", int(node_id))
            + struct.pack("<dd", float(x0_m), float(load_N))
            + raw_path.ljust(128, b"\0")
            + bytes(params) + bytes(cfg))
    total = 16 + len(body)
    head = struct.pack("<III", EMU_BLOB_MAGIC, EMU_BLOB_FORMAT, total)
    crc = zlib.crc32(body) & 0xFFFFFFFF
    return head + struct.pack("<I", crc) + body


def write_emu_boot_blob(path: str | Path, **kw: Any) -> Path:
    """:func:`emu_boot_blob` written to ``path`` (atomically: a QEMU started meanwhile
    never loads half a block)."""
    p = Path(path)
    tmp = p.with_name(f".{p.name}.tmp")
    tmp.write_bytes(emu_boot_blob(**kw))
    tmp.replace(p)
    return p
