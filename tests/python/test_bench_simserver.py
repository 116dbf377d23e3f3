"""The simulated drive server (`bench sim start/stop/status`, --sim-server): its own
process behind python-can's socketcand interface, the same CANopen code path as
hardware, a non-volatile memory that survives stop/start (CiA 301 0x1010/0x1011), and
one-line errors with exit 3 when it is gone.

The other side of the wire is the canopen library over python-can's own socketcand
client, not the bench's code.
"""

from __future__ import annotations

import os
import random
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
EDS = REPO / "protocols" / "generated" / "pmlsm_drive.eds"
SAVE, LOAD = 0x65766173, 0x64616F6C


def bench(*args: str, env: dict[str, str]) -> tuple[int, str, str]:
    p = subprocess.run([sys.executable, "-m", "bench", *args], cwd=REPO, env=env,
                       capture_output=True, text=True, timeout=120)
    return p.returncode, p.stdout, p.stderr


@pytest.fixture
def env(tmp_path: Path) -> Iterator[dict[str, str]]:
    e = dict(os.environ)
    e["BENCH_SIM_DIR"] = str(tmp_path / "simstate")
    e["PYTHONPATH"] = str(REPO) + os.pathsep + e.get("PYTHONPATH", "")
    yield e
    bench("sim", "stop", env=e)


def _state(env: dict[str, str]) -> dict:
    import json

    return json.loads((Path(env["BENCH_SIM_DIR"]) / "simserver.json").read_text())


def _node(env: dict[str, str]):  # noqa: ANN202 - canopen objects
    import can
    import canopen

    st = _state(env)
    bus = can.Bus(interface="socketcand", channel=st["channel"], host=st["host"],
                  port=st["port"])
    net = canopen.Network(bus)
    net.connect()
    node = canopen.RemoteNode(st["node_id"], str(EDS))
    net.add_node(node)
    node.sdo.RESPONSE_TIMEOUT = 1.0
    return net, node


def _no_traceback(*texts: str) -> None:
    for t in texts:
        assert "Traceback" not in t, t


def test_successive_commands_see_the_same_drive_and_save_survives_restart(env):
    rc, out, err = bench("sim", "status", env=env)
    assert rc == 3 and "no simulated drive server running" in err
    rc, out, err = bench("sim", "start", env=env)
    assert rc == 0, err
    assert "socketcand: 127.0.0.1:" in out and "nothing stored: defaults" in out
    st = _state(env)
    assert st["host"] == "127.0.0.1"  # never another interface
    rc, out, err = bench("sim", "start", env=env)
    assert rc == 2 and "already running" in err and _state(env)["pid"] == st["pid"]
    rc, out, err = bench("param", "set", "u_inj_V", "25", "--sim-server", env=env)
    assert rc == 0, err
    # never presented as hardware: labelled from what the drive says, and named
    assert "connected to the SIMULATED drive host_sim" in err and "HARDWARE" not in err
    assert "simulated drive server pid" in err
    rc, out, _ = bench("param", "get", "u_inj_V", "--sim-server", env=env)
    assert rc == 0 and "= 25.0 V" in out, out  # a second process, the same drive
    rc, out, err = bench("config", "save", "--sim-server", env=env)
    assert rc == 0, err
    assert bench("sim", "stop", env=env)[0] == 0
    assert not (Path(env["BENCH_SIM_DIR"]) / "simserver.json").exists()
    rc, out, err = bench("sim", "start", env=env)
    assert rc == 0 and "stored parameters loaded" in out, out + err
    rc, out, _ = bench("param", "get", "u_inj_V", "--sim-server", env=env)
    assert "= 25.0 V" in out, out
    # erase: the running value stays, the defaults come back with the next start
    assert bench("config", "defaults", "--sim-server", env=env)[0] == 0
    assert "= 25.0 V" in bench("param", "get", "u_inj_V", "--sim-server", env=env)[1]
    bench("sim", "stop", env=env)
    rc, out, _ = bench("sim", "start", env=env)
    assert "nothing stored: defaults" in out
    assert "= 50.0 V" in bench("param", "get", "u_inj_V", "--sim-server", env=env)[1]


def test_store_commands_from_a_canopen_master(env):
    """CiA 301 0x1010/0x1011 from the canopen library: bit 0 says 'saves on command', a
    wrong signature is refused with 0x08000020, 'save' with the power stage on with
    0x08000022; NMT reset node boots from the stored block."""
    from canopen.sdo.exceptions import SdoAbortedError

    assert bench("sim", "start", env=env)[0] == 0
    net, node = _node(env)
    try:
        assert node.sdo[0x1010][1].raw == 1 and node.sdo[0x1011][1].raw == 1
        with pytest.raises(SdoAbortedError) as e:
            node.sdo[0x1010][1].raw = 0x12345678
        assert e.value.code == 0x08000020
        with pytest.raises(SdoAbortedError) as e:
            node.sdo[0x1011][1].raw = SAVE  # 'save' is not the restore signature
        assert e.value.code == 0x08000020
        node.sdo[0x2010][1].raw = 30.0
        node.sdo[0x6060].raw = 9  # speed mode; enable: shutdown, switch on, enable
        for cw in (0x06, 0x07, 0x0F):
            node.sdo[0x6040].raw = cw
            time.sleep(0.05)
        deadline = time.monotonic() + 3.0
        while node.sdo[0x6041].raw & 0x6F != 0x27 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert node.sdo[0x6041].raw & 0x6F == 0x27  # OPERATION ENABLED
        with pytest.raises(SdoAbortedError) as e:
            node.sdo[0x1010][1].raw = SAVE
        assert e.value.code == 0x08000022
        node.sdo[0x6040].raw = 0x00
        time.sleep(0.05)
        node.sdo[0x1010][1].raw = SAVE
        node.sdo[0x2010][1].raw = 40.0
        node.nmt.state = "RESET"  # reset node: power-up behaviour
        time.sleep(0.5)
        assert node.sdo[0x2010][1].raw == pytest.approx(30.0)
        node.sdo[0x1011][1].raw = LOAD
        node.nmt.state = "RESET"
        time.sleep(0.5)
        assert node.sdo[0x2010][1].raw == pytest.approx(50.0)
    finally:
        net.disconnect()


def test_a_killed_server_is_a_one_line_error_with_exit_3(env):
    assert bench("sim", "start", env=env)[0] == 0
    pid = _state(env)["pid"]
    os.kill(pid, signal.SIGKILL)
    time.sleep(0.3)
    rc, out, err = bench("param", "get", "u_inj_V", "--sim-server", env=env)
    _no_traceback(out, err)
    assert rc == 3 and f"pid {pid}) is not running" in err, err
    assert len(err.strip().splitlines()) == 1
    rc, _, err = bench("sim", "status", env=env)
    assert rc == 3 and "stale" in err
    rc, _, err = bench("sim", "status", env=env)  # the stale file was removed
    assert rc == 3 and "no simulated drive server running" in err
    rc, out, err = bench("sim", "start", env=env)
    assert rc == 0, err


def test_bad_options_and_no_nvm_in_process(env):
    for args, needle in ((("sim", "start", "--port", "70000"), "--port 70000: allowed range"),
                         (("sim", "start", "--node-id", "0"), "--node-id 0: allowed range"),
                         (("sim", "start", "--motor", "no_such_motor"), "no_such_motor"),
                         (("param", "get", "u_inj_V", "--sim-server", "--sim"),
                          "contradict")):
        rc, out, err = bench(*args, env=env)
        _no_traceback(out, err)
        assert rc == 2 and needle in err, (args, err)
    rc, out, err = bench("config", "save", "--sim", env=env)
    _no_traceback(out, err)
    assert rc == 3 and "no non-volatile memory" in err and "bench sim start" in err


def _recv_until(s: socket.socket, needle: bytes, timeout_s: float = 2.0) -> bytes:
    s.settimeout(0.2)
    buf = b""
    deadline = time.monotonic() + timeout_s
    while needle not in buf and time.monotonic() < deadline:
        try:
            chunk = s.recv(65536)
        except TimeoutError:
            continue
        if not chunk:
            break
        buf += chunk
    return buf


def test_socketcand_server_survives_garbage_and_bridges_clients(env):
    """Malformed commands get '< error ... >', random bytes never stop the server, a
    frame sent by one client reaches the other (as on a bus) and the drive answers it."""
    assert bench("sim", "start", env=env)[0] == 0
    st = _state(env)
    addr = (st["host"], st["port"])
    a, b = socket.create_connection(addr), socket.create_connection(addr)
    try:
        for s in (a, b):
            assert _recv_until(s, b"< hi >").startswith(b"< hi >")
            s.sendall(b"< open can0 >")
            assert b"< ok >" in _recv_until(s, b"< ok >")
            s.sendall(b"< rawmode >")
            assert b"< ok >" in _recv_until(s, b"< ok >")
        a.sendall(b"< send 601 9 40 00 10 00 00 00 00 00 00 >")  # dlc 9
        assert b"< error" in _recv_until(a, b"< error")
        a.sendall(b"< send 7FF0 1 00 >")  # an 11-bit id too large, not extended
        a.sendall(b"< open can9 >")
        assert b"could not open bus" in _recv_until(a, b"could not open bus")
        rng = random.Random(7)
        for _ in range(50):  # random garbage on a throw-away connection
            with socket.create_connection(addr) as g:
                g.sendall(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 300))))
        # SDO upload of 0x1000 from client a: client b sees the request and the answer
        a.sendall(b"< send 601 8 40 00 10 00 00 00 00 00 >")
        # the request (forwarded by a's reader) and the answer (from the bus) reach b by
        # two threads: in either order, so read until both are there
        seen = _recv_until(b, b"< frame 581 ")
        if b"< frame 601 " not in seen:
            seen += _recv_until(b, b"< frame 601 ")
        assert b"< frame 601 " in seen and b"< frame 581 " in seen
        ans = seen[seen.index(b"< frame 581 "):].split(b">")[0].split()
        data = bytes.fromhex(ans[-1].decode())
        assert data[0] == 0x43 and int.from_bytes(data[4:8], "little") == 0x00020192
    finally:
        a.close()
        b.close()
    rc, out, _ = bench("sim", "status", env=env)
    assert rc == 0 and "running" in out


def test_two_concurrent_starts_leave_one_server(env):
    """Two `bench sim start` at once on one state folder: one server, the other start
    refused (exit 2, one line); `bench sim stop` stops it - no orphan left running."""
    ps = [subprocess.Popen([sys.executable, "-m", "bench", "sim", "start"], cwd=REPO, env=env,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
          for _ in range(2)]
    res = [(p.wait(timeout=120), *p.communicate()) for p in ps]
    assert sorted(r[0] for r in res) == [0, 2], res
    refused = next(r for r in res if r[0] == 2)
    assert "already running" in refused[2] and refused[2].count("\n") == 1
    pid = _state(env)["pid"]
    assert bench("sim", "stop", env=env)[0] == 0
    pattern = f"sim_fallback.server --state-dir {env['BENCH_SIM_DIR']}"
    servers = subprocess.run(["pgrep", "-f", pattern], capture_output=True,
                             text=True).stdout.split()
    assert servers == [] and pid > 0


def test_the_server_has_a_load_machine_coupled_to_its_drive(env, monkeypatch):
    """`--sim-server` load steps: the server's load machine (node 2, CiA 402 torque mode)
    is reached as a rig's load drive is (bench.CanopenLoad, by default with
    --sim-server); 200 N of it on the mover makes the drive holding it at rest produce
    200 N less static friction more thrust (its own estimate, 0x6077), and none beyond the
    friction once it is removed."""
    import time

    from bench._session import connect
    from sim_fallback.server import read_state

    rc, out, err = bench("sim", "start", env=env)
    assert rc == 0, err
    rc, out, _ = bench("sim", "status", env=env)
    assert "load machine: node 2, CiA 402 torque mode" in out
    monkeypatch.setenv("BENCH_SIM_DIR", env["BENCH_SIM_DIR"])
    st = read_state(Path(env["BENCH_SIM_DIR"]))
    conn = connect(sim_server=st, say=lambda _m: None)
    try:
        assert conn.load.name == "canopen" and conn.load.drive.node_id == 2
        d = conn.drive
        conn.start_heartbeat()
        d.enable("speed")
        d.set_speed_mps(0.0)

        def thrust(seconds: float) -> float:
            t_end, vals = time.monotonic() + seconds, []
            while time.monotonic() < t_end:
                vals.append(d.actual()["force_hat_N"])
                time.sleep(0.02)
            return sum(vals[len(vals) // 2:]) / len(vals[len(vals) // 2:])

        f0 = thrust(0.6)
        conn.load.enable()
        conn.load.set_force_N(200.0)
        f1 = thrust(1.0)
        conn.load.set_force_N(0.0)
        conn.load.disable()
        f2 = thrust(1.0)
        d.disable()
    finally:
        conn.close()
    # held at standstill, static friction takes its share of the load (the motor file's
    # 1.5 N m rotary-equivalent: F_s = T / r, r = p tau / pi)
    from sim_fallback import load_motor

    f_s = float(load_motor("paper_salient").plant["F_static_N"])
    assert 40.0 < f_s < 60.0
    assert abs((f1 - f0) - (200.0 - f_s)) < 25.0, (f0, f1, f2, f_s)
    assert abs(f2) < f_s + 20.0, (f0, f1, f2, f_s)
