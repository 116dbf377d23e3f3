"""Programming a board's image and checking, over CANopen, that the drive came back.

:func:`flash` programs an ELF image with a standard tool through the board's debug
probe (the NUCLEO-G474RE's on-board ST-LINK), lets the drive reboot, and reads the
firmware version (0x2040) and what the drive says it runs on (0x2090:1 drive kind,
0x2090:2 board name) with the ``canopen`` library on a python-can bus the caller
passes. Every failure is one line and an exit code (:data:`EXIT`); nothing raises to
the caller for a foreseeable problem.

Tools (both are ordinary packages; the first found is used unless ``tool`` says):

* ``openocd`` (Debian/Ubuntu ``apt-get install openocd``, 0.12):
  ``openocd -f interface/stlink.cfg -f target/stm32g4x.cfg -c "program IMAGE verify
  reset exit"``; ``program`` erases and writes only the image's own flash pages (the
  parameter page at the end of the flash is not part of the image and survives) and
  reads them back (``verify``).
* ``pyocd`` (PyPI ``pip install pyocd``): ``pyocd load -t stm32g474retx IMAGE``, after
  a one-time ``pyocd pack install stm32g474re`` (the device's CMSIS pack; pyOCD has no
  built-in target for it). pyOCD erases by sector, compares what it writes by CRC and
  resets the target afterwards; the CANopen read-back is the end-to-end check.

Proposed CLI wiring (bench/cli.py is not changed here): ``bench flash IMAGE
[--tool openocd|pyocd] [--probe SERIAL] [--interface ... --channel ... --bitrate ...]
[--node-id 1] [--board nucleo_g474re] [--timeout 10]``, printing
:attr:`FlashResult.message` (stdout when ok, stderr otherwise) and exiting with
:attr:`FlashResult.code`.
"""

from __future__ import annotations

import os
import re
import shutil
import struct
import subprocess
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import canopen
from canopen.sdo.exceptions import SdoError

from protocols.generated import od_names as od

#: Exit codes a CLI returns for a :class:`FlashResult`: the bench's own set (``bench
#: --help``: 0 ok, 1 expectation failed, 2 invalid input, nothing written, 3 drive or
#: connection error), no new ones.
EXIT: dict[str, int] = {
    "ok": 0,            # programmed, rebooted, the expected version and board answered
    "mismatch": 1,      # the drive answered with another firmware version or board
    "input": 2,         # no such image, an unknown tool name, a bad node id
    "tool_missing": 2,  # neither openocd nor pyocd (nor the one asked for): nothing written
    "connection": 3,    # no debug probe / target, or the drive did not answer on CAN
    "verify": 3,        # programming or its verification failed
}

TOOLS = ("openocd", "pyocd")
#: pyOCD's target name for the NUCLEO-G474RE's part (from its CMSIS pack)
PYOCD_TARGET = "stm32g474retx"
#: OpenOCD's scripts for the NUCLEO's ST-LINK and the G4 family
OPENOCD_SCRIPTS = ("interface/stlink.cfg", "target/stm32g4x.cfg")

Runner = Callable[..., subprocess.CompletedProcess]


@dataclass
class FlashResult:
    """What :func:`flash` did.

    Attributes
    ----------
    ok : bool
        Programmed, verified and (when a bus was given) the drive answered with the
        expected firmware version and board.
    code : int
        Exit code (:data:`EXIT`).
    message : str
        One line for the user (``bench: flash: ...``).
    tool : str
        The tool used ("" when none was found).
    image : Path
        The image programmed.
    firmware_version : str or None
        0x2040 as ``M.m.p`` (None when not read).
    drive_kind : str or None
        0x2090:1 as its key (``hardware``, ...).
    board : str or None
        0x2090:2.
    boot_up_seen : bool
        The drive's boot-up message (0x700 + node id, data 00) was seen after programming.
    command : list of str
        The tool's command line.
    tool_output : str
        The tool's last output lines (for ``-v``).
    """

    ok: bool
    code: int
    message: str
    tool: str = ""
    image: Path = Path()
    firmware_version: str | None = None
    drive_kind: str | None = None
    board: str | None = None
    boot_up_seen: bool = False
    command: list[str] = field(default_factory=list)
    tool_output: str = ""

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly view (paths as strings)."""
        d = dict(self.__dict__)
        d["image"] = str(self.image)
        return d


def find_tool(prefer: str | None = None) -> str | None:
    """The flashing tool to use: ``prefer`` if installed, else the first of :data:`TOOLS`
    on PATH; None when none is."""
    for name in ([prefer] if prefer else list(TOOLS)):
        if shutil.which(name):
            return name
    return None


def flash_command(tool: str, image: Path, probe: str | None = None) -> list[str]:
    """The command line that programs ``image`` (an ELF: addresses included) with ``tool``."""
    if tool == "openocd":
        cmd = ["openocd"]
        for script in OPENOCD_SCRIPTS:
            cmd += ["-f", script]
        if probe:
            cmd += ["-c", f"adapter serial {probe}"]
        # forward slashes: OpenOCD's Tcl reads backslashes as escapes
        return cmd + ["-c", f"program {image.as_posix()} verify reset exit"]
    if tool == "pyocd":
        cmd = ["pyocd", "load", "-t", PYOCD_TARGET]
        if probe:
            cmd += ["-u", probe]
        return cmd + [str(image)]
    raise ValueError(f"unknown flashing tool '{tool}' (one of {', '.join(TOOLS)})")


#: (exit key, pattern, what to say) per tool, first match wins; searched case-insensitively
_DIAGNOSES: dict[str, list[tuple[str, str, str]]] = {
    "openocd": [
        ("connection", r"open failed|unable to open|no device found|libusb_open\(\) failed|"
                       r"could not find.*st-?link|init mode failed|target voltage may be too low",
         "no ST-LINK probe or no target found (USB cable, probe serial, board powered?)"),
        ("verify", r"verify failed|verification failed|checksum mismatch|contents differ",
         "verification after programming failed"),
        ("verify", r"error.*(erase|write|program)|flash .*failed",
         "programming failed"),
    ],
    "pyocd": [
        ("connection", r"no (available|connected) debug probes|no probe|unable to open|"
                       r"failed to open probe|no target connected",
         "no debug probe or no target found (USB cable, probe id, board powered?)"),
        ("input", r"target type .* not recognized|unknown target|pack",
         f"pyOCD does not know '{PYOCD_TARGET}': run 'pyocd pack install stm32g474re' once"),
        ("verify", r"verify|crc|mismatch", "verification after programming failed"),
    ],
}


def diagnose(tool: str, returncode: int, output: str) -> tuple[str, str] | None:
    """Classify a tool run: None when it succeeded, else (exit key, one-line reason)."""
    text = output.lower()
    if returncode == 0:
        # OpenOCD's ``program ... verify`` exits non-zero on a failed verification; a
        # zero exit that still says so is taken at its word
        if re.search(r"verify failed|verification failed", text):
            return "verify", "verification after programming failed"
        return None
    for key, pattern, what in _DIAGNOSES.get(tool, []):
        if re.search(pattern, text):
            return key, what
    errs = [ln.strip() for ln in output.splitlines() if "error" in ln.lower()]
    last = errs[-1] if errs else (output.strip().splitlines() or ["no output"])[-1]
    return "verify", f"{tool} failed (exit {returncode}): {last[:160]}"


def _version(u32: int) -> str:
    return f"{(u32 >> 16) & 0xFF}.{(u32 >> 8) & 0xFF}.{u32 & 0xFF}"


class _Watcher(can.Listener):
    """Sees the drive's boot-up message (0x700 + node id, one byte 0x00)."""

    def __init__(self, node_id: int) -> None:
        self.cob = 0x700 + node_id
        self.seen = threading.Event()

    def on_message_received(self, msg: can.Message) -> None:
        if msg.arbitration_id == self.cob and not msg.is_extended_id and bytes(msg.data) == b"\x00":
            self.seen.set()


def read_identity(network: canopen.Network, node_id: int, timeout_s: float,
                  sdo_timeout_s: float = 0.3) -> dict[str, Any] | None:
    """0x2040 and 0x2090:1/2 of ``node_id`` over SDO, retried until ``timeout_s``; None
    when the drive never answers."""
    node = canopen.RemoteNode(node_id, None)
    node.sdo.RESPONSE_TIMEOUT = sdo_timeout_s
    network.add_node(node)
    deadline = time.monotonic() + timeout_s
    try:
        while True:
            try:
                fw = struct.unpack("<I", node.sdo.upload(od.FIRMWARE_VERSION.index, 0)[:4])[0]
                kind = node.sdo.upload(od.BOARD__DRIVE_KIND.index, od.BOARD__DRIVE_KIND.sub)[0]
                name = node.sdo.upload(od.BOARD__BOARD_NAME.index, od.BOARD__BOARD_NAME.sub)
                try:
                    kind_key = od.DriveKind(kind).key
                except ValueError:
                    kind_key = f"unknown ({kind})"
                return {"firmware_version": _version(fw), "firmware_version_u32": fw,
                        "drive_kind": kind_key,
                        "board": name.rstrip(b"\x00").decode("ascii", "replace")}
            except (SdoError, struct.error, IndexError):
                if time.monotonic() >= deadline:
                    return None
                time.sleep(0.1)
    finally:
        network.nodes.pop(node_id, None)


def flash(image: str | os.PathLike[str], bus: can.BusABC | None = None, *, node_id: int = 1,
          tool: str | None = None, probe: str | None = None, board: str = "nucleo_g474re",
          expected_version: str = od.FW_VERSION_STRING, timeout_s: float = 10.0,
          tool_timeout_s: float = 180.0, run: Runner = subprocess.run,
          extra_args: Sequence[str] = ()) -> FlashResult:
    """Program ``image``, then (with ``bus``) check the drive's version and board over CAN.

    Parameters
    ----------
    image : path
        The ELF image (e.g. ``build/cm4/firmware_c/boards/nucleo_g474re/pmlsm_nucleo_g474re.elf``).
    bus : can.BusABC, optional
        An open python-can bus the drive is on (the caller owns it; it is not shut down).
        None: programming only, the drive is not asked.
    node_id : int
        The drive's CANopen node id (1..127).
    tool : {"openocd", "pyocd"}, optional
        The tool; default the first installed.
    probe : str, optional
        The probe's serial number (several probes on one PC).
    board : str
        The board name 0x2090:2 must report.
    expected_version : str
        The firmware version 0x2040 must report (default: this checkout's).
    timeout_s : float
        How long the drive may take to answer after the reset (s).
    tool_timeout_s : float
        How long the tool may run (s).
    run : callable
        ``subprocess.run`` (tests pass their own).
    extra_args : sequence of str
        Appended to the tool's command line.

    Returns
    -------
    FlashResult
        Never raises for a missing tool, probe, image or answer: see ``code``.
    """
    img = Path(image)
    if tool is not None and tool not in TOOLS:
        return FlashResult(False, EXIT["input"], f"bench: flash: unknown tool '{tool}' "
                           f"(one of {', '.join(TOOLS)})", image=img)
    if not img.is_file():
        return FlashResult(False, EXIT["input"], f"bench: flash: no image at {img} (build it: "
                           "cmake -DPMLSM_TARGET_CM4=ON -DPMLSM_BOARD=nucleo_g474re ...)",
                           image=img)
    if not 1 <= node_id <= 127:
        return FlashResult(False, EXIT["input"], f"bench: flash: node id {node_id} outside 1..127",
                           image=img)
    name = find_tool(tool)
    if name is None:
        wanted = tool or " nor ".join(TOOLS)
        return FlashResult(False, EXIT["tool_missing"],
                           f"bench: flash: {'no' if tool else 'neither'} {wanted} found on PATH "
                           "(apt-get install openocd, or pip install pyocd)", image=img)
    cmd = [*flash_command(name, img, probe), *extra_args]
    res = FlashResult(False, EXIT["verify"], "", tool=name, image=img, command=cmd)

    network: canopen.Network | None = None
    watcher = _Watcher(node_id)
    if bus is not None:
        # listen before the reset, so that the boot-up message is not missed
        network = canopen.Network(bus)
        network.listeners.append(watcher)
        network.connect()
    try:
        try:
            proc = run(cmd, capture_output=True, text=True, timeout=tool_timeout_s)
        except FileNotFoundError:
            res.code, res.message = EXIT["tool_missing"], f"bench: flash: {name} not found"
            return res
        except subprocess.TimeoutExpired:
            res.code = EXIT["connection"]
            res.message = f"bench: flash: {name} did not finish within {tool_timeout_s:g} s"
            return res
        out = (proc.stdout or "") + (proc.stderr or "")
        res.tool_output = "\n".join(out.splitlines()[-40:])
        bad = diagnose(name, proc.returncode, out)
        if bad is not None:
            key, what = bad
            res.code, res.message = EXIT[key], f"bench: flash: {what}"
            return res
        if network is None:
            res.ok, res.code = True, EXIT["ok"]
            res.message = f"bench: flash: {img.name} programmed and verified with {name} " \
                          "(not checked over CAN: no bus)"
            return res
        ident = read_identity(network, node_id, timeout_s)
        res.boot_up_seen = watcher.seen.is_set()
        if ident is None:
            res.code = EXIT["connection"]
            res.message = (f"bench: flash: programmed, but node {node_id} did not answer on CAN "
                           f"within {timeout_s:g} s (bitrate, termination, node id?)")
            return res
        res.firmware_version = ident["firmware_version"]
        res.drive_kind = ident["drive_kind"]
        res.board = ident["board"]
        if res.firmware_version != expected_version or res.board != board:
            res.code = EXIT["mismatch"]
            res.message = (f"bench: flash: node {node_id} answers firmware "
                           f"{res.firmware_version} on '{res.board}' ({res.drive_kind}), expected "
                           f"{expected_version} on '{board}'")
            return res
        res.ok, res.code = True, EXIT["ok"]
        res.message = (f"bench: flash: {img.name} programmed with {name}; node {node_id} is back: "
                       f"firmware {res.firmware_version} on {res.board} ({res.drive_kind})"
                       f"{'' if res.boot_up_seen else ', no boot-up message seen'}")
        return res
    finally:
        if network is not None and network.notifier is not None:
            network.notifier.stop()  # the bus is the caller's: not shut down
