"""The simulated drive server survives its clients (issue 31, item 4).

A client that stops reading is dropped (counted, logged) and never freezes the bus for the
others; a stopped server process pauses its drive's clock instead of faulting it on a lost
heartbeat; malformed frames are refused at the socket and never reach the bus; the
non-volatile memory is keyed by the motor's content, not its file name; an unusable state
folder is one line with a documented exit code. Each test starts its own server through
`bench sim start` (the worktree's sources: see ``test_bench_simserver.env``) and stops it
in teardown.
"""

from __future__ import annotations

import logging
import os
import re
import shutil
import signal
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_bench_simserver import REPO, SAVE, _no_traceback, _node, _recv_until, _state, bench

# python-can's socketcand client warns for every frame split across two TCP reads
logging.getLogger("can.interfaces.socketcand").setLevel(logging.ERROR)


@pytest.fixture
def sim_env(tmp_path: Path) -> Iterator[dict[str, str]]:
    e = dict(os.environ)
    e["BENCH_SIM_DIR"] = str(tmp_path / "simstate")
    e["PYTHONPATH"] = str(REPO) + os.pathsep + e.get("PYTHONPATH", "")
    yield e
    _cont(e)  # a test that failed with the server stopped: stop can only end a running one
    bench("sim", "stop", env=e)


def _cont(env: dict[str, str]) -> None:
    try:
        pid = _state(env)["pid"]
    except (OSError, ValueError, KeyError):
        return
    if pid > 0:
        try:
            os.kill(pid, signal.SIGCONT)
        except ProcessLookupError:
            pass


def _stats(env: dict[str, str]) -> dict:
    return _state(env).get("stats", {})


def _log(env: dict[str, str]) -> str:
    return (Path(env["BENCH_SIM_DIR"]) / "simserver.log").read_text(errors="replace")


def _wait_for(what, timeout_s: float, step_s: float = 0.1):  # noqa: ANN001, ANN202
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        v = what()
        if v:
            return v
        time.sleep(step_s)
    return what()


def _handshake(s: socket.socket) -> None:
    assert _recv_until(s, b"< hi >").startswith(b"< hi >")
    s.sendall(b"< open can0 >")
    assert b"< ok >" in _recv_until(s, b"< ok >")
    s.sendall(b"< rawmode >")
    assert b"< ok >" in _recv_until(s, b"< ok >")


# ---- a. a client that stops reading ----------------------------------------------------


def test_a_client_that_never_reads_is_dropped_and_never_freezes_the_bus(sim_env):
    """A raw client that does the handshake and then never reads (a tiny receive buffer:
    its kernel buffers fill at once) while a proper python-can client keeps reading the
    drive over SDO: every read succeeds, the silent client is dropped, counted (status)
    and logged with its address and why."""
    sim_env["BENCH_SIM_CLIENT_QUEUE"] = "32768"  # bytes queued for one client, at most
    assert bench("sim", "start", env=sim_env)[0] == 0
    st = _state(sim_env)
    net, node = _node(sim_env)
    node.sdo.RESPONSE_TIMEOUT = 3.0
    slow = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        slow.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        slow.connect((st["host"], st["port"]))
        _handshake(slow)
        slow_addr = f"127.0.0.1:{slow.getsockname()[1]}"
        deadline = time.monotonic() + 90.0
        while not _stats(sim_env).get("clients_dropped"):
            assert time.monotonic() < deadline, f"not dropped; stats {_stats(sim_env)}"
            # a frozen bus: canopen raises SdoCommunicationError (no response)
            assert node.sdo[0x1000].raw == 0x00020192
        for _ in range(20):  # and the bus goes on for the others
            assert node.sdo[0x1000].raw == 0x00020192
        stats = _stats(sim_env)
        assert stats["clients_dropped"] == 1 and slow_addr in stats["last_drop"], stats
        log = _log(sim_env)
        assert slow_addr in log and "dropped" in log and "not reading" in log, log
        rc, out, err = bench("sim", "status", env=sim_env)
        assert rc == 0 and "1 dropped" in out and slow_addr in out, out + err
        # the server closed its end: the silent client finds the end of its stream
        slow.settimeout(10.0)
        while slow.recv(65536):
            pass
    finally:
        slow.close()
        net.disconnect()


def test_a_client_that_disconnects_is_not_a_drop(sim_env):
    """A client that says goodbye is not counted as dropped; the server serves on."""
    assert bench("sim", "start", env=sim_env)[0] == 0
    st = _state(sim_env)
    for _ in range(3):
        with socket.create_connection((st["host"], st["port"])) as s:
            _handshake(s)
    net, node = _node(sim_env)
    try:
        assert node.sdo[0x1000].raw == 0x00020192
        # the three have gone (the server has seen it): none of them was dropped
        stats = _wait_for(lambda: _stats(sim_env).get("clients_connected") == 1
                          and _stats(sim_env), 10.0)
        assert stats and stats["clients_dropped"] == 0, _stats(sim_env)
    finally:
        net.disconnect()


# ---- b. a stopped server process --------------------------------------------------------


def test_a_stopped_server_pauses_its_drive_instead_of_losing_the_heartbeat(sim_env):
    """The drive watches a client's heartbeat (0x1016, 500 ms); the server process is
    stopped for 1 s (SIGSTOP, SIGCONT): the drive's time stopped with it, so no 0x8130
    (heartbeat lost); the stall is logged and counted."""
    assert bench("sim", "start", env=sim_env)[0] == 0
    pid = _state(sim_env)["pid"]
    net, node = _node(sim_env)
    emcy: list[int] = []
    node.emcy.add_callback(lambda e: emcy.append(e.code))
    hb = net.send_periodic(0x700 + 0x7F, bytes([0x05]), 0.1)
    try:
        time.sleep(0.3)
        node.sdo[0x1016][1].raw = (0x7F << 16) | 500
        time.sleep(0.7)
        assert node.sdo[0x603F].raw == 0 and not emcy
        os.kill(pid, signal.SIGSTOP)
        try:
            time.sleep(1.0)
        finally:
            os.kill(pid, signal.SIGCONT)
        # the time the drive's clock stood still (the stop, and any starvation before)
        stats = _wait_for(lambda: _stats(sim_env).get("stalled_s", 0.0) >= 0.9
                          and _stats(sim_env), 20.0)
        time.sleep(1.0)  # time for a fault to show, and for its EMCY to arrive
        assert node.sdo[0x603F].raw == 0 and 0x8130 not in emcy, (hex(node.sdo[0x603F].raw),
                                                                   emcy)
        assert stats and stats["stalls"] >= 1 and stats["last_stall_s"] >= 0.9, \
            _stats(sim_env)
        assert "clock paused" in _log(sim_env)
        rc, out, _ = bench("sim", "status", env=sim_env)
        assert rc == 0 and re.search(r"drive clock: paused \d+ times?, ", out), out
        node.sdo[0x1016][1].raw = 0
    finally:
        hb.stop()
        net.disconnect()


# ---- c. the non-volatile memory belongs to a motor, not to a file name -------------------


def _motor_file(folder: Path, r_ohm: float) -> Path:
    src = (REPO / "sim_fallback" / "motors" / "paper_salient.toml").read_text()
    assert "R_ohm = 0.958" in src
    folder.mkdir(parents=True)
    f = folder / "motor.toml"
    f.write_text(src.replace("R_ohm = 0.958", f"R_ohm = {r_ohm}"))
    return f


def test_two_motor_files_of_one_name_keep_their_own_stored_configuration(sim_env, tmp_path):
    """Two different motors, both motor.toml (as `bench identify` writes them): a
    configuration saved on the first is not loaded with the second, and is with the
    first again; `bench sim status` names each one's file."""
    a = _motor_file(tmp_path / "a", 0.958)
    b = _motor_file(tmp_path / "b", 1.5)
    rc, out, err = bench("sim", "start", "--motor", str(a), env=sim_env)
    assert rc == 0 and "nothing stored: defaults" in out, out + err
    nvm_a = _state(sim_env)["nvm"]
    net, node = _node(sim_env)
    try:
        assert node.sdo[0x2050][2].raw == pytest.approx(0.958)
        node.sdo[0x2010][1].raw = 30.0  # u_inj_V
        node.sdo[0x1010][1].raw = SAVE
    finally:
        net.disconnect()
    assert bench("sim", "stop", env=sim_env)[0] == 0
    rc, out, err = bench("sim", "start", "--motor", str(b), env=sim_env)
    assert rc == 0 and "nothing stored: defaults" in out, out + err
    nvm_b = _state(sim_env)["nvm"]
    assert nvm_b != nvm_a and Path(nvm_a).name.startswith("nvm_motor_")
    assert bench("sim", "status", env=sim_env)[1].count(nvm_b) == 1
    net, node = _node(sim_env)
    try:
        assert node.sdo[0x2050][2].raw == pytest.approx(1.5)  # its own R
        assert node.sdo[0x2010][1].raw == pytest.approx(50.0)  # not the first one's 30 V
    finally:
        net.disconnect()
    assert bench("sim", "stop", env=sim_env)[0] == 0
    rc, out, err = bench("sim", "start", "--motor", str(a), env=sim_env)
    assert rc == 0 and "stored parameters loaded" in out and nvm_a in out, out + err
    net, node = _node(sim_env)
    try:
        assert node.sdo[0x2010][1].raw == pytest.approx(30.0)
        assert node.sdo[0x2050][2].raw == pytest.approx(0.958)
    finally:
        net.disconnect()


# ---- d. malformed frames ----------------------------------------------------------------

#: each malformed in one way; those with an otherwise valid id have an id of their own, which
#: the proper client must never see
BAD_FRAMES = (
    (b"< send -1 0 >", None),
    (b"< send 800 0 >", None),  # an 11-bit id above 0x7FF
    (b"< send 20000000 0 >", None),  # a 29-bit id above 0x1FFFFFFF
    (b"< send 0012A 1 00 >", 0x12A),  # neither 3 (11-bit) nor 8 (29-bit) digits
    (b"< send 12B 9 0 0 0 0 0 0 0 0 0 >", 0x12B),  # dlc 9
    (b"< send 12C 2 01 >", 0x12C),  # dlc 2, one byte
    (b"< send 12D 1 0x1 >", 0x12D),  # not hex digits
    (b"< send 12E 1 +1 >", 0x12E),
    (b"< send 1_2F 0 >", 0x12F),
    (b"< send 130 1 100 >", 0x130),  # a byte above FF
    (b"< send 131 -1 >", 0x131),
    (b"< send 132 x >", 0x132),
    (b"< send 133 >", 0x133),  # no dlc
    (b"< send 134 1 \xff >", 0x134),  # not ASCII
    (b"< send 135 1 1 2 >", 0x135),  # more bytes than the dlc
)


def test_malformed_frames_are_refused_at_the_socket_and_never_reach_the_bus(sim_env):
    """Each malformed `send` gets one '< error ... >', is counted, and neither the drive
    nor another client sees it; a valid frame sent after them reaches the other client."""
    import can

    assert bench("sim", "start", env=sim_env)[0] == 0
    st = _state(sim_env)
    other = can.Bus(interface="socketcand", channel=st["channel"], host=st["host"],
                    port=st["port"])
    try:
        with socket.create_connection((st["host"], st["port"])) as a:
            _handshake(a)
            for frame, _ in BAD_FRAMES:
                a.sendall(frame)
            a.sendall(b"< send 1ABCDEF0 2 1 ff >")  # valid 29-bit, as python-can writes it
            a.sendall(b"< send 7EF 1 AA >")  # valid (no CANopen meaning): the sentinel
            errors = b""
            deadline = time.monotonic() + 10.0
            while errors.count(b"< error") < len(BAD_FRAMES) and time.monotonic() < deadline:
                errors += _recv_until(a, b"< error", 0.5)
            assert errors.count(b"< error") == len(BAD_FRAMES), errors
            seen = []
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline:
                m = other.recv(0.5)
                if m is None:
                    continue
                seen.append(m)
                if m.arbitration_id == 0x7EF:
                    break
            assert seen and seen[-1].arbitration_id == 0x7EF and bytes(seen[-1].data) == b"\xaa"
            ext = [m for m in seen if m.is_extended_id]
            assert len(ext) == 1 and ext[0].arbitration_id == 0x1ABCDEF0 and \
                bytes(ext[0].data) == b"\x01\xff", ext
            bad_ids = {i for _, i in BAD_FRAMES if i is not None}
            for m in seen:
                assert m is ext[0] or 0 <= m.arbitration_id <= 0x7FF, m
                assert m.arbitration_id not in bad_ids, m
        stats = _wait_for(lambda: _stats(sim_env).get("frames_refused") == len(BAD_FRAMES)
                          and _stats(sim_env), 10.0)
        assert stats and stats["frames_refused"] == len(BAD_FRAMES), _stats(sim_env)
        assert "Traceback" not in _log(sim_env)
        rc, out, _ = bench("sim", "status", env=sim_env)
        assert rc == 0 and f"{len(BAD_FRAMES)} refused" in out, out
    finally:
        other.shutdown()


# ---- e. an unusable state folder ----------------------------------------------------------


@pytest.mark.parametrize("action", ["start", "status", "stop"])
def test_a_state_folder_under_a_regular_file_is_one_line_with_exit_2(tmp_path, action):
    f = tmp_path / "somefile"
    f.write_text("not a folder\n")
    for where in (f / "x", f):
        e = dict(os.environ, BENCH_SIM_DIR=str(where),
                 PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        rc, out, err = bench("sim", action, env=e)
        _no_traceback(out, err)
        assert rc == 2, (where, rc, out, err)
        assert len(err.strip().splitlines()) == 1 and str(where) in err, err
        assert "BENCH_SIM_DIR" in err and "not a folder" in err, err
        assert "removed" not in out + err and "internal error" not in err, out + err
    assert f.read_text() == "not a folder\n"


def test_a_state_file_that_is_a_folder_is_one_line_with_exit_2(sim_env):
    (Path(sim_env["BENCH_SIM_DIR"]) / "simserver.json").mkdir(parents=True)
    for action in ("start", "status", "stop"):
        rc, out, err = bench("sim", action, env=sim_env)
        _no_traceback(out, err)
        assert rc == 2 and "simserver.json" in err and "removed" not in out + err, (
            action, rc, out, err)
        assert len(err.strip().splitlines()) == 1, err
    shutil.rmtree(Path(sim_env["BENCH_SIM_DIR"]) / "simserver.json")
