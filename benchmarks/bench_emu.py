#!/usr/bin/env python3
"""The emulated board's figures: its speed against real time, CAN frames lost on its
serial-line CAN link, and the twin differences against the host simulated drive.

1. Speed: drive seconds per wall second (the board's period count over wall time),
   idle and during the main job (`bench run sequences/paper_load_step.yaml --emu`),
   with the board's own cost figures (instructions per period: plant, control,
   supervision, background; the load machine's `stats`).
2. CAN frames lost: a master of its own (python-can slcan + canopen) produces SYNC at
   100 Hz for --can-seconds of wall time and counts every frame the drive sends; the
   board counts every frame its slcan endpoint sends to the host (`can_frames_out`):
   lost = sent - received.
3. Twin: the main job on the emulated board and on the host simulated drive with the
   same seed (seeds --seeds, a fresh board per seed), every metric side by side
   (`bench compare`'s tolerances); the median relative difference per metric.

Prints figures; asserts nothing (a shared machine is not a timing reference).
Usage: python benchmarks/bench_emu.py [--seeds 1 4 7] [--can-seconds 10]
Exit 0, or 2 when QEMU or the image is missing.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from protocols.generated import od_names as od  # noqa: E402

SEQ = ROOT / "sequences" / "paper_load_step.yaml"


def bench(*args: str, env: dict[str, str]) -> tuple[int, str, str]:
    p = subprocess.run([sys.executable, "-m", "bench", *args], cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=600)
    return p.returncode, p.stdout, p.stderr


def _stats(st) -> dict[str, str]:
    ld = st.load_device()
    try:
        return dict(tok.partition("=")[::2] for tok in ld.command("stats").split()[2:])
    finally:
        ld.close()


def _run_dir(out: str) -> Path:
    return Path(next(x.split(": ", 1)[1] for x in out.splitlines()
                     if x.strip().startswith("run folder:")))


def can_loss(st, seconds: float) -> tuple[int, int, float]:
    """(frames the board sent, frames received, drive seconds covered)."""
    import can
    import canopen

    bus = can.Bus(**st.bus_config())
    net = canopen.Network(bus)
    got = [0]

    class Count(can.Listener):
        def on_message_received(self, msg: can.Message) -> None:
            got[0] += 1

    net.connect()
    net.notifier.add_listener(Count())
    node = net.add_node(st.node_id, str(ROOT / "protocols" / "generated" / "pmlsm_drive.eds"))
    hb = od.PRODUCER_HEARTBEAT_TIME.of(node.sdo)
    hb.raw = 0  # no heartbeat: after the last SYNC the drive sends nothing
    net.nmt.send_command(0x01)  # NMT start (all nodes): the TPDOs flow on SYNC
    time.sleep(0.3)
    got[0] = 0
    before = _stats(st)
    p0 = int(before["periods"])
    net.sync.start(0.01)
    time.sleep(seconds)
    net.sync.stop()
    time.sleep(1.0)  # the last answers
    after = _stats(st)
    n = got[0]
    hb.raw = 100
    net.disconnect()
    sent = int(after["can_frames_out"]) - int(before["can_frames_out"])
    return sent, n, (int(after["periods"]) - p0) / 24000.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 4, 7])
    ap.add_argument("--can-seconds", type=float, default=10.0)
    a = ap.parse_args()
    from sim_fallback import emu as E

    try:
        E.qemu_binary()
        E.find_image()
    except E.EmuError as e:
        print(f"bench_emu: {e}")
        return 2
    state = Path(tempfile.mkdtemp(prefix="bench_emu_"))
    env = dict(os.environ, BENCH_SIM_DIR=str(state))
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    os.environ["BENCH_SIM_DIR"] = str(state)
    rows: dict[str, list[tuple[float, float]]] = {}
    speeds = []
    try:
        # 1 + 2: speed idle, CAN loss, the board's cost figures
        rc, out, err = bench("emu", "start", "--seed", str(a.seeds[0]), env=env)
        assert rc == 0, err
        st = E.check_running(state)
        idle = E.speed(st, window_s=2.0)
        sent, got, drive_s = can_loss(st, a.can_seconds)
        cost = _stats(st)
        print(f"emulated board: idle {idle:.3f} drive s per wall s")
        print(f"CAN link: {a.can_seconds:g} s of wall time, SYNC at 100 Hz: the board sent "
              f"{sent} frames, the master received {got}: lost {sent - got} "
              f"({drive_s:.2f} drive s covered)")
        print("board cost (instructions, mean/max@period): " + " ".join(
            f"{k}={cost[k]}" for k in ("dilation", "plant", "control", "supervision",
                                       "background", "period", "overruns")))
        bench("emu", "stop", env=env)
        # 3: twin runs
        for seed in a.seeds:
            rc, out, err = bench("emu", "start", "--seed", str(seed), env=env)
            assert rc == 0, err
            t0 = time.monotonic()
            rc_e, out_e, err_e = bench("run", str(SEQ), "--emu", "--no-progress", "--runs",
                                       str(state / "runs"), env=env)
            wall = time.monotonic() - t0
            bench("emu", "stop", env=env)
            rc_s, out_s, err_s = bench("run", str(SEQ), "--sim", "--seed", str(seed),
                                       "--no-progress", "--runs", str(state / "runs"), env=env)
            de, ds = _run_dir(out_e), _run_dir(out_s)
            se = json.loads((de / "summary.json").read_text())
            ss = json.loads((ds / "summary.json").read_text())
            m = re.search(r"\(sequence ([0-9.]+) s, wall ([0-9.]+) s\)", out_e)
            if m:  # the sequence's drive time over the runner's wall time
                speeds.append(float(m.group(1)) / float(m.group(2)))
            rc_c, out_c, _ = bench("compare", str(ds), str(de), env=env)
            print(f"seed {seed}: emulated {'PASSED' if rc_e == 0 else 'rc ' + str(rc_e)}, "
                  f"host {'PASSED' if rc_s == 0 else 'rc ' + str(rc_s)}; compare rc {rc_c}; "
                  f"the emulated run took {wall:.1f} s of wall time")
            for k, v in se["metrics"].items():
                w = ss["metrics"].get(k)
                if isinstance(v, (int, float)) and isinstance(w, (int, float)):
                    rows.setdefault(k, []).append((float(w), float(v)))
    finally:
        bench("emu", "stop", env=env)
    print(f"\nemulated board during the main job: {statistics.median(speeds):.3f} drive s per "
          "wall s (median over the seeds; the runner's time: the enable, the sequence, the "
          "safe state)")
    print(f"\n{'metric':40s} {'host (median)':>14s} {'emulated':>10s} {'|rel diff| median':>18s}")
    for k, pairs in rows.items():
        h = statistics.median(p[0] for p in pairs)
        e = statistics.median(p[1] for p in pairs)
        rel = statistics.median(abs(p[1] - p[0]) / abs(p[0]) for p in pairs if p[0])
        print(f"{k:40s} {h:14.5g} {e:10.5g} {100 * rel:17.1f}%")
    return 0


if __name__ == "__main__":
    sys.exit(main())
