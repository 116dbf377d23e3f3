"""The bench's hardware path from the command line: a named interface never falls back
to a simulated drive, the connect line `bench sim start` prints works as printed, and
`bench live --sim-server` runs. Each case through `bench` as a user types it."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def bench(*args: str, env: dict[str, str], timeout: float = 120) -> tuple[int, str, str]:
    p = subprocess.run([sys.executable, "-m", "bench", *args], cwd=REPO, env=env,
                       capture_output=True, text=True, timeout=timeout)
    return p.returncode, p.stdout, p.stderr


@pytest.fixture
def env(tmp_path: Path) -> Iterator[dict[str, str]]:
    e = dict(os.environ)
    e["BENCH_SIM_DIR"] = str(tmp_path / "state")
    e["PYTHONPATH"] = str(REPO) + os.pathsep + e.get("PYTHONPATH", "")
    e["HOME"] = str(tmp_path)  # no ~/.canrc
    for k in ("CAN_INTERFACE", "CAN_CHANNEL", "CAN_CONFIG"):
        e.pop(k, None)
    yield e
    bench("sim", "stop", env=e)


@pytest.mark.parametrize("args", [
    ["param", "set", "u_inj_V", "30"],
    ["config", "restore", "BACKUP"],
    ["faults", "--reset"],
    ["run", str(REPO / "sequences" / "paper_startup.yaml"), "--no-progress"],
])
def test_a_named_interface_never_falls_back(args: list[str], env: dict[str, str],
                                            tmp_path: Path) -> None:
    """`--interface pcan --channel PCAN_USBBUS1` with no adapter: exit 3, one line that
    names the interface, nothing written anywhere (no simulated drive was used)."""
    backup = tmp_path / "backup.json"
    backup.write_text(json.dumps({"parameters": {}}))
    args = [str(backup) if a == "BACKUP" else a for a in args]
    rc, out, err = bench(*args, "--interface", "pcan", "--channel", "PCAN_USBBUS1",
                         "--runs", str(tmp_path / "runs"), env=env) if args[0] == "run" else \
        bench(*args, "--interface", "pcan", "--channel", "PCAN_USBBUS1", env=env)
    lines = err.strip().splitlines()
    assert rc == 3, out + err
    assert len(lines) == 1 and lines[0].startswith("bench: "), err
    assert "--interface pcan was named: no fallback to the simulated drive" in lines[0]
    assert "SIMULATED" not in out + err and "Traceback" not in err
    assert not (tmp_path / "runs").exists()  # nothing ran, nothing written


def test_the_printed_socketcand_connect_line_works(env: dict[str, str]) -> None:
    rc, out, err = bench("sim", "start", env=env)
    assert rc == 0, err
    m = re.search(r"--interface socketcand --channel (\S+) --host (\S+) --port (\d+)", out)
    assert m, out
    rc, out, err = bench("param", "get", "u_inj_V", "--interface", "socketcand", "--channel",
                         m.group(1), "--host", m.group(2), "--port", m.group(3), env=env)
    assert rc == 0 and "= 50.0 V" in out, out + err
    # what the drive says it is, whatever reached it: never HARDWARE
    assert "connected to the SIMULATED drive host_sim" in err and "HARDWARE" not in err
    # half a socketcand address is refused in one line
    rc, out, err = bench("param", "get", "u_inj_V", "--interface", "socketcand", "--channel",
                         m.group(1), "--host", m.group(2), env=env)
    assert rc == 2 and err.count("\n") == 1 and "both --host and --port" in err


def test_live_on_the_simulated_drive_server(env: dict[str, str], tmp_path: Path) -> None:
    rc, out, err = bench("sim", "start", env=env)
    assert rc == 0, err
    rrd = tmp_path / "live.rrd"
    rc, out, err = bench("live", "--sim-server", "--speed", "0.1", "--unit", "m/s",
                         "--duration", "0.3", "--rerun", "save", str(rrd), env=env)
    assert rc == 0, out + err
    assert "contradict" not in err and "drive disabled" in err
    assert rrd.is_file() and rrd.stat().st_size > 0


def test_the_emulated_board_keys_its_flash_by_the_motor(tmp_path: Path) -> None:
    """Two motor files of one name (every `bench identify` writes a motor.toml) get their
    own flash page on the emulated board, as on the simulated drive server; the same
    content, the same page."""
    from sim_fallback.emu import nvm_file

    root = Path(__file__).resolve().parents[2]
    src = (root / "sim_fallback/motors/iron_core_linear.toml").read_text()
    other = "\n".join("R_ohm = 3.3" if ln.startswith("R_ohm") else ln
                      for ln in src.splitlines()) + "\n"
    a, b, c = (tmp_path / d / "motor.toml" for d in ("a", "b", "c"))
    for f, text in ((a, src), (b, other), (c, src)):
        f.parent.mkdir()
        f.write_text(text)
    pa, pb, pc = (nvm_file(tmp_path, str(f)) for f in (a, b, c))
    assert pa != pb and pa == pc
    assert pa.name.startswith("emu_nvm_motor_")
