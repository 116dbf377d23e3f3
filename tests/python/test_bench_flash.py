"""bench/_flash.py: programming a board and checking it over CANopen, with fake tools.

A fake ``openocd`` / ``pyocd`` (a small script put first on PATH) records its command
line and answers as the real one does on success, a missing probe or a failed
verification; the drive after the reboot is a ``canopen`` LocalNode with the project's
EDS on a python-can virtual bus, answering 0x2040 and 0x2090 as the board would.
"""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
import uuid
from collections.abc import Iterator
from pathlib import Path

import can
import canopen
import pytest

from bench import _flash
from protocols.generated import od_names as od

ROOT = Path(__file__).resolve().parents[2]
EDS = ROOT / "protocols/generated/pmlsm_drive.eds"

FAKE = """#!{python}
import json, os, sys
with open(os.environ["FAKE_LOG"], "a") as f:
    f.write(json.dumps(sys.argv) + "\\n")
mode = os.environ.get("FAKE_MODE", "ok")
if mode == "ok":
    print("** Programming Finished **\\n** Verify Started **\\n** Verified OK **")
    print("** Resetting Target **")
    sys.exit(0)
if mode == "noprobe":
    print("Error: open failed", file=sys.stderr)
    sys.exit(1)
if mode == "verify":
    print("** Verify Failed **", file=sys.stderr)
    print("Error: checksum mismatch - attempting binary compare", file=sys.stderr)
    sys.exit(1)
if mode == "pyocd_noprobe":
    print("0000690 C No connected debug probes [__main__]", file=sys.stderr)
    sys.exit(1)
if mode == "pyocd_nopack":
    print("0000200 C Target type stm32g474retx not recognized. Use 'pyocd list --targets'",
          file=sys.stderr)
    sys.exit(1)
sys.exit(3)
"""


@pytest.fixture
def tools(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A PATH with fake openocd and pyocd only; returns the log of their command lines."""
    bindir = tmp_path / "bin"
    bindir.mkdir()
    for name in ("openocd", "pyocd"):
        p = bindir / name
        p.write_text(FAKE.replace("{python}", sys.executable))
        p.chmod(p.stat().st_mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)
    log = tmp_path / "calls.jsonl"
    monkeypatch.setenv("PATH", str(bindir))
    monkeypatch.setenv("FAKE_LOG", str(log))
    monkeypatch.setenv("FAKE_MODE", "ok")
    return log


@pytest.fixture
def image(tmp_path: Path) -> Path:
    p = tmp_path / "pmlsm_nucleo_g474re.elf"
    p.write_bytes(b"\x7fELF fake")
    return p


def _calls(log: Path) -> list[list[str]]:
    return [json.loads(ln) for ln in log.read_text().splitlines()] if log.exists() else []


@pytest.fixture
def bus_pair() -> Iterator[tuple[can.BusABC, can.BusABC]]:
    """The bench's bus and the drive's, one virtual channel."""
    ch = f"flash-{uuid.uuid4().hex}"
    a = can.Bus(interface="virtual", channel=ch)
    b = can.Bus(interface="virtual", channel=ch)
    yield a, b
    a.shutdown()
    b.shutdown()


class Drive:
    """The rebooted board: a LocalNode with the project's EDS, boot-up on demand."""

    def __init__(self, bus: can.BusABC, node_id: int = 1, version: int | None = None,
                 kind: int = 0, board: str = "nucleo_g474re") -> None:
        self.bus = bus
        self.node_id = node_id
        self.net = canopen.Network(bus)
        self.net.connect()
        self.node = canopen.LocalNode(node_id, str(EDS))
        self.net.add_node(self.node)
        if version is not None:
            self.node.sdo[od.FIRMWARE_VERSION.index].raw = version
        self.node.sdo[0x2090][1].raw = kind
        self.node.sdo[0x2090][2].raw = board

    def boot_up(self) -> None:
        self.bus.send(can.Message(arbitration_id=0x700 + self.node_id, data=b"\x00",
                                  is_extended_id=False))

    def close(self) -> None:
        assert self.net.notifier is not None
        self.net.notifier.stop()


def _run_then(drive: Drive | None):  # noqa: ANN202 - a subprocess.run stand-in
    """subprocess.run, then the board boots (sends its boot-up message)."""
    def run(cmd: list[str], **kw: object) -> subprocess.CompletedProcess:
        res = subprocess.run(cmd, **kw)  # type: ignore[call-overload]
        if drive is not None and res.returncode == 0:
            drive.boot_up()
        return res
    return run


def _version_u32(s: str) -> int:
    a, b, c = (int(x) for x in s.split("."))
    return (a << 16) | (b << 8) | c


def test_command_lines() -> None:
    img = Path("/tmp/build dir/x.elf")
    cmd = _flash.flash_command("openocd", img)
    assert cmd[:5] == ["openocd", "-f", "interface/stlink.cfg", "-f", "target/stm32g4x.cfg"]
    assert cmd[-1] == "program /tmp/build dir/x.elf verify reset exit"
    assert "adapter serial 0670FF" in _flash.flash_command("openocd", img, "0670FF")
    cmd = _flash.flash_command("pyocd", img, "0670FF")
    assert cmd == ["pyocd", "load", "-t", "stm32g474retx", "-u", "0670FF", str(img)]
    with pytest.raises(ValueError):
        _flash.flash_command("stlink", img)


def test_bad_input_is_one_line_exit_2(tools: Path, image: Path) -> None:
    r = _flash.flash(image.parent / "missing.elf")
    assert (r.ok, r.code) == (False, 2) and "no image at" in r.message and "\n" not in r.message
    r = _flash.flash(image, tool="jlink")
    assert r.code == 2 and "unknown tool 'jlink'" in r.message
    r = _flash.flash(image, node_id=0)
    assert r.code == 2
    assert _calls(tools) == []  # nothing was run


def test_tool_missing_exit_2(image: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    monkeypatch.setenv("PATH", str(empty))
    r = _flash.flash(image)
    assert r.code == 2 and "neither openocd nor pyocd" in r.message and "\n" not in r.message
    r = _flash.flash(image, tool="pyocd")
    assert r.code == 2 and "no pyocd found" in r.message


@pytest.mark.parametrize(("tool", "mode", "code", "needle"), [
    ("openocd", "noprobe", 3, "no ST-LINK probe"),
    ("openocd", "verify", 3, "verification after programming failed"),
    ("openocd", "other", 3, "openocd failed (exit 3)"),
    ("pyocd", "pyocd_noprobe", 3, "no debug probe"),
    ("pyocd", "pyocd_nopack", 2, "pyocd pack install stm32g474re"),
])
def test_tool_failures_are_one_line(tools: Path, image: Path, monkeypatch: pytest.MonkeyPatch,
                                    tool: str, mode: str, code: int, needle: str) -> None:
    monkeypatch.setenv("FAKE_MODE", mode)
    r = _flash.flash(image, tool=tool)
    assert (r.ok, r.code) == (False, code), r
    assert needle in r.message and r.message.startswith("bench: flash: ")
    assert "\n" not in r.message
    assert len(_calls(tools)) == 1


def test_programs_without_a_bus(tools: Path, image: Path) -> None:
    r = _flash.flash(image)
    assert (r.ok, r.code, r.tool) == (True, 0, "openocd")  # the first of the two found
    (argv,) = _calls(tools)
    assert argv[-1] == f"program {image.as_posix()} verify reset exit"
    assert "not checked over CAN" in r.message


def test_checks_version_and_board_over_canopen(tools: Path, image: Path,
                                                bus_pair: tuple[can.BusABC, can.BusABC]) -> None:
    bench_bus, drive_bus = bus_pair
    drive = Drive(drive_bus, node_id=5, version=_version_u32(od.FW_VERSION_STRING))
    try:
        r = _flash.flash(image, bench_bus, node_id=5, run=_run_then(drive), timeout_s=3.0)
    finally:
        drive.close()
    assert (r.ok, r.code) == (True, 0), r.message
    assert r.firmware_version == od.FW_VERSION_STRING
    assert (r.drive_kind, r.board) == ("hardware", "nucleo_g474re")
    assert r.boot_up_seen
    assert "node 5 is back" in r.message
    json.dumps(r.as_dict())  # printable by the CLI
    # the caller's bus is still usable
    bench_bus.send(can.Message(arbitration_id=0x123, data=b"", is_extended_id=False))


def test_other_firmware_or_board_is_a_mismatch(tools: Path, image: Path,
                                               bus_pair: tuple[can.BusABC, can.BusABC]) -> None:
    bench_bus, drive_bus = bus_pair
    drive = Drive(drive_bus, version=0x000100, kind=3, board="blank")
    try:
        r = _flash.flash(image, bench_bus, run=_run_then(drive), timeout_s=3.0)
    finally:
        drive.close()
    assert (r.ok, r.code) == (False, 1)
    assert "firmware 0.1.0 on 'blank' (no_io)" in r.message


def test_no_answer_after_the_reset(tools: Path, image: Path,
                                   bus_pair: tuple[can.BusABC, can.BusABC]) -> None:
    bench_bus, _ = bus_pair
    r = _flash.flash(image, bench_bus, run=_run_then(None), timeout_s=0.6)
    assert (r.ok, r.code) == (False, 3)
    assert "did not answer on CAN within 0.6 s" in r.message and "\n" not in r.message


def test_tool_timeout(tools: Path, image: Path) -> None:
    def slow(cmd: list[str], **kw: object) -> subprocess.CompletedProcess:
        raise subprocess.TimeoutExpired(cmd, 1.0)
    r = _flash.flash(image, run=slow, tool_timeout_s=1.0)
    assert r.code == 3 and "did not finish within 1 s" in r.message


def test_environment_untouched() -> None:
    # the module reads nothing from the environment at import (PATH is searched per call)
    assert "FAKE_LOG" not in os.environ
