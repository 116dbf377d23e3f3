"""Logging throughput: the bench logs every frame of a drive streaming at CAN line rate.

The simulated drive (plant + firmware + C CANopen slave) runs paced to the wall
clock with SYNC every 0.5 ms; TPDO2 (position, velocity), TPDO3 (torque, error
code) and a remapped TPDO4 (estimated angle, PLL error) answer every SYNC, so the
bus carries about 8,000 frames/s (a 1 Mbit/s CAN bus is full at ~8,000 8-byte
frames/s). The bench side is the production path: canopen network + notifier,
python-can BLF logger, TPDO decoding into MF4 chunks, serial telemetry reader.

Printed: frames/s on the bus, frames logged, lost frames (sent by the drive but
missing from the trace), CPU use of the process, of the simulated drive's
thread and of the rest (the bench).

``--synthetic`` replaces the simulated drive with a producer thread sending
8-byte frames with a sequence counter at ``--rate`` frames/s (for machines
where the simulator library is not built).

Usage::

    python benchmarks/bench_logging.py [--duration 60] [--synthetic] [--rate 8000]
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import can  # noqa: E402
import canopen  # noqa: E402

from bench import RunLogger  # noqa: E402
from protocols.generated import od_names as od  # noqa: E402


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def run_sim(duration_s: float, out: Path) -> dict[str, float]:
    """Simulated drive at ~8 kframes/s, paced to the wall clock."""
    from bench import PdoRecorder, TelemetryReader, open_sim

    conn = open_sim(realtime=True, chunk_s=0.5e-3, record_decimation=24)
    try:
        node = conn.drive.node
        node.nmt.state = "PRE-OPERATIONAL"
        tp = node.tpdo[4]
        tp.clear()
        tp.add_variable(od.ESTIMATOR__ESTIMATED_ANGLE.index, od.ESTIMATOR__ESTIMATED_ANGLE.sub)
        tp.add_variable(od.ESTIMATOR__PLL_ERROR.index, od.ESTIMATOR__PLL_ERROR.sub)
        tp.trans_type = 1
        tp.enabled = True
        tp.save()
        node.tpdo.read()
        node.nmt.state = "OPERATIONAL"
        # pause the simulation while the logger attaches, so every frame is accounted for
        conn.sim.set_realtime(False)
        conn.sim.wait_idle()
        time.sleep(0.2)
        logger = RunLogger(out, conn.network)
        sent0 = conn.sim.frames_sent
        by_id0 = {**conn.sim.sent_by_id, 0x080: conn.sim.syncs_sent}
        pdo = PdoRecorder(conn, logger)
        tel = TelemetryReader(conn.serial, logger, float(conn.sim.sim.cfg.f_pwm_Hz))
        tel.start()
        conn.drive.enable("speed")
        conn.drive.set_speed_mps(conn.units.speed_to_mps(100.0, "r/min"))
        conn.sim.set_realtime(True)
        cpu0, sim_cpu0, w0 = _cpu(), conn.sim.cpu_s, time.monotonic()
        n_prev, t_prev = logger.trace.count if logger.trace else 0, w0
        while (now := time.monotonic()) - w0 < duration_s:
            time.sleep(min(1.0, duration_s - (now - w0)))
            pdo.drain()
            n = logger.trace.count if logger.trace else 0
            t = time.monotonic()
            print(f"  t={t - w0:5.1f} s  {(n - n_prev) / (t - t_prev):7.0f} frames/s", flush=True)
            n_prev, t_prev = n, t
        wall = time.monotonic() - w0
        cpu, sim_cpu = _cpu() - cpu0, conn.sim.cpu_s - sim_cpu0
        conn.sim.set_realtime(False)
        conn.drive.disable()
        conn.sim.wait_idle()
        time.sleep(0.5)
        pdo.drain()
        tel.stop()
        stats = logger.close(join_mf4=False)
        sent = conn.sim.frames_sent - sent0
        by_id = {k: v - by_id0.get(k, 0) for k, v in
                 {**conn.sim.sent_by_id, 0x080: conn.sim.syncs_sent}.items()}
        diff = {hex(k): (by_id.get(k, 0), stats["frames_by_id"].get(k, 0))
                for k in set(by_id) | set(stats["frames_by_id"])
                if by_id.get(k, 0) != stats["frames_by_id"].get(k, 0)}
        if diff:
            print(f"  per-COB-ID (sent, logged) mismatches: {diff}")
        return {"wall_s": wall, "sent": sent, "logged": stats["frames_logged"],
                "lost": sent - stats["frames_logged"], "cpu_s": cpu, "sim_cpu_s": sim_cpu,
                "receive_errors": len(stats["receive_errors"]),
                "telemetry_lost": tel.rx.frames_lost, "realtime_factor":
                    conn.sim.t_s / max(wall, 1e-9)}
    finally:
        conn.close()


def run_synthetic(duration_s: float, rate: float, out: Path) -> dict[str, float]:
    """A producer thread at ``rate`` frames/s on a virtual bus, counter in the payload."""
    ch = f"bench-log-{uuid.uuid4().hex[:6]}"
    net = canopen.Network(can.Bus(interface="virtual", channel=ch))
    net.connect()
    logger = RunLogger(out, net)
    counter = logger.counter("synthetic", 2**32)

    class Seq(can.Listener):
        def on_message_received(self, msg: can.Message) -> None:
            counter.update(int.from_bytes(msg.data[:4], "little"))

    net.notifier.add_listener(Seq())
    tx = can.Bus(interface="virtual", channel=ch)
    stop = threading.Event()
    sent = [0]

    def produce() -> None:
        t0 = time.monotonic()
        k = 0
        while not stop.is_set():
            due = int((time.monotonic() - t0) * rate)
            while k < due:
                tx.send(can.Message(arbitration_id=0x281, is_extended_id=False,
                                    data=k.to_bytes(4, "little") + b"\0\0\0\0"))
                k += 1
            sent[0] = k
            time.sleep(0.0005)

    th = threading.Thread(target=produce, daemon=True)
    cpu0, w0 = _cpu(), time.monotonic()
    th.start()
    n_prev, t_prev = 0, w0
    while (now := time.monotonic()) - w0 < duration_s:
        time.sleep(min(1.0, duration_s - (now - w0)))
        n, t = logger.trace.count, time.monotonic()
        print(f"  t={t - w0:5.1f} s  {(n - n_prev) / (t - t_prev):7.0f} frames/s", flush=True)
        n_prev, t_prev = n, t
    stop.set()
    th.join()
    wall = time.monotonic() - w0
    time.sleep(0.5)
    cpu = _cpu() - cpu0
    stats = logger.close(join_mf4=False)
    net.disconnect()
    tx.shutdown()
    return {"wall_s": wall, "sent": sent[0], "logged": stats["frames_logged"],
            "lost": sent[0] - stats["frames_logged"], "seq_gaps": counter.lost, "cpu_s": cpu,
            "sim_cpu_s": 0.0, "receive_errors": len(stats["receive_errors"])}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=60.0, help="seconds (default 60)")
    ap.add_argument("--synthetic", action="store_true",
                    help="synthetic producer instead of the simulated drive")
    ap.add_argument("--rate", type=float, default=8000.0, help="synthetic frames/s")
    ap.add_argument("--out", default=None, help="run folder (default: a temp dir)")
    a = ap.parse_args(argv)
    out = Path(a.out or tempfile.mkdtemp(prefix="bench_logging_"))
    mode = "synthetic producer" if a.synthetic else "simulated drive (real time, SYNC 2 kHz)"
    print(f"bench_logging: {mode}, {a.duration:g} s, logging into {out}")
    r = run_synthetic(a.duration, a.rate, out) if a.synthetic else run_sim(a.duration, out)
    fps = r["logged"] / r["wall_s"]
    cpu_pct = 100.0 * r["cpu_s"] / r["wall_s"]
    sim_pct = 100.0 * r["sim_cpu_s"] / r["wall_s"]
    print(f"frames/s logged : {fps:.0f}")
    print(f"frames sent     : {r['sent']}")
    print(f"frames logged   : {r['logged']}")
    print(f"lost frames     : {r['lost']}")
    for k in ("seq_gaps", "telemetry_lost", "realtime_factor", "receive_errors"):
        if k in r:
            print(f"{k:<16}: {r[k]:.3g}" if isinstance(r[k], float) else f"{k:<16}: {r[k]}")
    print(f"CPU (process)   : {cpu_pct:.0f} % of one core")
    if r["sim_cpu_s"]:
        print(f"CPU (sim thread): {sim_pct:.0f} %   CPU (bench, rest): {cpu_pct - sim_pct:.0f} %")
    print(f"files           : {sorted(os.listdir(out))}")
    return 0 if r["lost"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
