"""Command-line entry point ``bench``.

Exit codes: 0 success / all expectations passed, 1 an expectation failed,
2 invalid input (sequence, motor file, parameter value, backup file, options;
nothing was moved or written), 3 drive or connection error, 4 internal error
(a bug: one line on stderr, the traceback in ``runs/bench_error_<time>.txt``
or on stderr with ``BENCH_DEBUG=1``), 130 interrupted (Ctrl-C / SIGTERM; the
drive was brought to the safe state first).

A user's mistake never shows a traceback: it ends with one line per problem
naming the file, line and field, or the parameter and its allowed range.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import time
import traceback
from pathlib import Path
from typing import Any

from bench import __version__

EXIT_OK, EXIT_FAIL, EXIT_USAGE, EXIT_DRIVE, EXIT_INTERNAL, EXIT_INTERRUPT = 0, 1, 2, 3, 4, 130
EXIT_CODES_TEXT = ("Exit codes: 0 ok, 1 expectation failed, 2 invalid input (sequence, motor "
                   "file, parameter, backup, options; nothing moved or written), 3 drive/"
                   "connection error, 4 internal error (traceback saved under runs/, or "
                   "BENCH_DEBUG=1), 130 interrupted (drive disabled first).")


class UserError(Exception):
    """A mistake in the user's input: printed as ``bench: <message>``, exit ``code``."""

    def __init__(self, message: str, code: int = EXIT_USAGE) -> None:
        super().__init__(message)
        self.code = code


def _conn_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("connection (hardware if found, else the simulated drive)")
    g.add_argument("--sim", action="store_true",
                   help="use the simulated drive (python-can virtual bus, same CANopen)")
    g.add_argument("--require-hardware", action="store_true",
                   help="fail with exit 3 when no drive answers instead of falling back to "
                        "the simulated drive (for a rig's CI job)")
    g.add_argument("--interface", help="python-can interface: socketcan, pcan, slcan, kvaser, "
                                       "... (default: python-can configuration)")
    g.add_argument("--channel", help="python-can channel, e.g. can0, PCAN_USBBUS1, "
                                     "/dev/ttyACM0 or socket://host:port for slcan")
    g.add_argument("--bitrate", type=int, help="CAN bitrate in bit/s, e.g. 1000000")
    g.add_argument("--serial", metavar="URL",
                   help="serial telemetry link (pyserial URL: /dev/ttyUSB0, socket://host:port,"
                        " loop://)")
    g.add_argument("--node-id", type=int, default=1, help="drive node id (default 1)")
    g.add_argument("--load-node", type=int, help="node id of the load machine (hardware)")
    g.add_argument("--sync-period-ms", type=int, default=10,
                   help="hardware: SYNC period the bench produces (default 10; 0 = another "
                        "node on the bus produces SYNC)")
    g.add_argument("--motor", default=None,
                   help="motor file (sim, and unit conversion on hardware); default: the "
                        "sequence's, else paper_salient")
    g.add_argument("--extractor", choices=("pseudo", "sogi", "sogi_adaptive"),
                   help="simulated drive: HF extractor (default: the sequence's)")
    g.add_argument("--seed", type=int, help="simulated drive: noise seed (default: the "
                                            "sequence's)")
    g.add_argument("--realtime", action="store_true",
                   help="simulated drive: pace to the wall clock (default: as fast as possible)")


def _rerun_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rerun", nargs="+", metavar="MODE",
                   help="live telemetry with rerun: 'spawn' (viewer; headless -> .rrd), "
                        "'save PATH' (.rrd file), 'serve' (gRPC server, prints the URL), "
                        "'connect URL'")


def build_parser() -> argparse.ArgumentParser:
    """The ``bench`` argument parser (``--help`` on every subcommand)."""
    ap = argparse.ArgumentParser(
        prog="bench", description="HIL bench for the sensorless PMLSM drive: run test "
        "sequences, live telemetry, parameters, configuration and faults, on hardware or "
        "on the simulated drive.",
        epilog=EXIT_CODES_TEXT)
    ap.add_argument("--version", action="version", version=f"bench {__version__}")
    ap.add_argument("-v", "--verbose", action="count", default=0, help="more logging")
    sub = ap.add_subparsers(dest="cmd", metavar="COMMAND")

    p = sub.add_parser("run", help="run test sequence(s) and write logs and a report",
                       description="Validate SEQ.yaml files (before anything moves), run them "
                       "on the drive, log (CAN BLF, MF4 signals, metadata) into runs/, and "
                       "write an HTML report. Exit 1 when an expectation fails.")
    p.add_argument("sequences", nargs="+", metavar="SEQ.yaml")
    _conn_args(p)
    p.add_argument("--summary-json", metavar="PATH",
                   help='write {"sequence", "passed", "metrics": {...}} (a list for several '
                        "sequences)")
    p.add_argument("--junit", metavar="PATH", help="write JUnit XML (one testcase per "
                                                   "expectation)")
    p.add_argument("--runs", default="runs", metavar="DIR", help="run folder root (default "
                                                                 "runs/)")
    p.add_argument("--trace-format", choices=("blf", "asc"), default="blf",
                   help="raw CAN trace format")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    _rerun_arg(p)

    p = sub.add_parser("validate", help="validate sequence files only",
                       description="Check sequence files against the schema; errors name the "
                                   "file, line and field.")
    p.add_argument("sequences", nargs="+", metavar="SEQ.yaml")

    p = sub.add_parser("live", help="enable the drive and stream live telemetry to rerun",
                       description="Enable the drive in speed mode at --speed and stream "
                       "telemetry to rerun until Ctrl-C or --duration; the drive is disabled "
                       "on exit. Headless (no viewer) writes an .rrd file.")
    _conn_args(p)
    _rerun_arg(p)
    p.add_argument("--speed", type=float, default=100.0, help="speed reference (default 100)")
    p.add_argument("--unit", default="r/min", choices=("r/min", "rpm", "m/s", "mm/s"),
                   help="unit of --speed")
    p.add_argument("--duration", type=float, default=0.0,
                   help="stop after this many seconds of drive time (0 = until Ctrl-C)")

    p = sub.add_parser("info", help="connection, identity, firmware check, state",
                       description="Show what the bench is connected to, the drive identity, "
                                   "the firmware version checked against the EDS and the state.")
    _conn_args(p)

    p = sub.add_parser("param", help="read or write a parameter by name",
                       description="Parameters by name (fw_config field such as u_inj_V, "
                       "'Object.Sub' such as 'Injection.Amplitude', or 0xIIII:S), with units. "
                       "Values may carry the unit: `bench param set u_inj_V '20 V'`.")
    psub = p.add_subparsers(dest="action", metavar="ACTION")
    pg = psub.add_parser("get", help="read a parameter", description="Read a parameter.")
    pg.add_argument("name")
    _conn_args(pg)
    ps = psub.add_parser("set", help="write a parameter", description="Write a parameter; "
                         "the drive's SDO abort code is explained (range, read-only, state).")
    ps.add_argument("name")
    ps.add_argument("value")
    _conn_args(ps)
    pl = psub.add_parser("list", help="list parameters with their values",
                         description="List the parameters (address, name, access, unit, range) "
                                     "with the drive's current values.")
    pl.add_argument("--all", action="store_true", help="include CiA 301 communication objects")
    pl.add_argument("--offline", action="store_true",
                    help="do not connect: the table from the object dictionary, no values")
    _conn_args(pl)

    p = sub.add_parser("config", help="configuration backup / restore",
                       description="Back the drive's rw parameters up to a JSON file, or "
                                   "restore them from one.")
    csub = p.add_subparsers(dest="action", metavar="ACTION")
    cb = csub.add_parser("backup", help="write the configuration to FILE",
                         description="Write every rw parameter (with units) to FILE (JSON).")
    cb.add_argument("file")
    _conn_args(cb)
    cr = csub.add_parser("restore", help="write the configuration from FILE",
                         description="Write the parameters in FILE (JSON from backup). "
                         "Everything is checked first (product, firmware version, every name, "
                         "unit and range); if anything is wrong nothing is written (exit 2).")
    cr.add_argument("file")
    _conn_args(cr)

    p = sub.add_parser("faults", help="read (and reset) faults",
                       description="Show the latched fault, error register, fault history "
                                   "and EMCY messages; --reset sends a fault reset.")
    p.add_argument("--reset", action="store_true", help="fault reset (controlword bit 7)")
    _conn_args(p)
    p = sub.add_parser("report", help="reports: the runs index",
                       description="Regenerate report pages from the run folders.")
    rsub = p.add_subparsers(dest="report_cmd", metavar="WHAT", required=True)
    ri = rsub.add_parser("index", help="write RUNS/index.html listing all runs",
                         description="Write RUNS/index.html: every run folder (sequence, "
                         "date, verdict, key metrics, link to its report) and a comparison "
                         "view of the runs ticked. Also done after every 'bench run'.")
    ri.add_argument("--runs", default="runs", metavar="DIR", help="run folder root (default "
                                                                  "runs/)")

    from bench import _campaign
    _campaign.add_parser(sub)
    return ap


def _sigterm_as_interrupt() -> None:
    def handler(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt(f"signal {signum}")

    signal.signal(signal.SIGTERM, handler)


def _connect(args: argparse.Namespace, seq: Any = None) -> Any:
    from bench._session import connect

    motor = args.motor or (seq.motor if seq is not None else "paper_salient")
    extractor = args.extractor or (seq.extractor if seq is not None else "sogi_adaptive")
    seed = args.seed if args.seed is not None else (seq.seed if seq is not None else 0)
    x0 = seq.x0 if seq is not None else 0.0
    if args.sync_period_ms < 0:
        raise UserError(f"--sync-period-ms {args.sync_period_ms}: allowed range >= 0 (ms)")
    if not 1 <= args.node_id <= 127:
        raise UserError(f"--node-id {args.node_id}: allowed range [1, 127]")
    if args.sim and getattr(args, "require_hardware", False):
        raise UserError("--sim and --require-hardware contradict each other; drop one of them")
    if args.sim and args.serial:
        raise UserError(f"--serial {args.serial} cannot be used with --sim (the simulated drive "
                        "has its own in-process serial link); drop one of them")
    if args.seed is not None and args.seed < 0:
        raise UserError(f"--seed {args.seed}: allowed range >= 0")
    where = f"--motor {motor}" if args.motor or seq is None else f"{seq.path}: motor"
    refusal = _check_motor(motor, extractor, where, sim_only=args.sim)
    try:
        conn = connect(sim=args.sim, interface=args.interface, channel=args.channel,
                       bitrate=args.bitrate, serial_url=args.serial, realtime=args.realtime,
                       motor=motor, extractor=extractor, seed=seed, x0=x0,
                       node_id=args.node_id, load_node=args.load_node,
                       require_hardware=getattr(args, "require_hardware", False))
    except UserError:
        raise
    except Exception as e:  # noqa: BLE001 - the bus, the drive or the simulator library
        if refusal and "fw_app_init" in str(e):  # fell back to the simulated drive
            raise UserError(refusal + "; the simulated drive (fallback: no hardware found) "
                            "cannot run this motor") from None
        raise UserError(f"cannot connect: {' '.join(str(e).split())}", EXIT_DRIVE) from e
    conn.sync_period_ms = args.sync_period_ms
    return conn


def _check_motor(motor: str, extractor: str, where: str, sim_only: bool) -> str | None:
    """Load the motor file and run the firmware's configuration check on it.

    Raises :class:`UserError` (exit 2) naming the file, line and field; a motor
    whose saliency the firmware refuses is an error for the simulated drive
    (``--sim``), which cannot start it. On hardware the motor file only gives
    the geometry for unit conversions; the refusal text is returned for the
    case where the bench falls back to the simulated drive.
    """
    try:
        from sim_fallback import firmware_check, fw_config, load_motor
    except ImportError:  # pragma: no cover - bench-only install: units fall back
        return None
    try:
        m = load_motor(motor)
    except FileNotFoundError as e:
        raise UserError(f"{where}: {e}") from None
    except ValueError as e:  # MotorFileError: file:line: field: message
        raise UserError(str(e)) from None
    try:
        st, msg = firmware_check(fw_config(m, extractor))
    except OSError:  # no simulator library: the hardware drive checks its own config
        return None
    if st == 4:
        text = f"{where} ({m.path}): {msg}"
        if sim_only:
            raise UserError(text + "; the simulated drive cannot run this motor")
        return text
    if st != 0:
        raise UserError(f"{where} ({m.path}): {msg}")
    return None


def _make_rerun(spec: list[str] | None, default_dir: Path, pole_pairs: float) -> Any:
    if not spec:
        return None
    from bench._live import RerunSink

    mode = spec[0]
    target = spec[1] if len(spec) > 1 else None
    if mode == "save" and target is None:
        target = str(default_dir / "telemetry.rrd")
    if mode == "spawn":
        target = str(default_dir / "telemetry.rrd")
    sink = RerunSink(mode, target, pole_pairs=pole_pairs)
    if sink.url:
        print(f"bench: rerun gRPC server at {sink.url} (rerun --connect {sink.url})",
              file=sys.stderr)
    if sink.path:
        print(f"bench: rerun recording -> {sink.path}", file=sys.stderr)
    return sink


def cmd_validate(args: argparse.Namespace) -> int:
    from bench._sequence import SequenceError, load_sequence

    rc = EXIT_OK
    for f in args.sequences:
        try:
            s = load_sequence(f)
            print(f"{f}: ok ({s.name}, {len(s.steps)} steps, {s.duration_s:g} s, "
                  f"{len(s.expectations)} expectations)")
        except SequenceError as e:
            _print_issues(e)
            rc = EXIT_USAGE
    return rc


def _print_issues(e: Any) -> None:
    """One line per problem: ``file:line:column: field: message``."""
    for i in e.issues:
        print(i, file=sys.stderr)


def cmd_run(args: argparse.Namespace) -> int:
    from bench._report import summary, write_junit
    from bench._sequence import SequenceError, load_sequence
    from bench._session import run_sequence

    seqs = []
    bad = False
    for f in args.sequences:  # validate everything before anything moves
        try:
            seqs.append(load_sequence(f))
        except SequenceError as e:
            _print_issues(e)
            bad = True
    if bad:
        return EXIT_USAGE
    from bench._session import drive_kind

    _prefetch("asammdf")  # the MF4 writer's ~0.9 s import, overlapped with the run

    results = []
    summaries = []
    kinds: list[dict[str, Any]] = []
    rc = EXIT_OK
    for seq in seqs:
        conn = _connect(args, seq)
        rerun = None
        try:
            rerun = _make_rerun(args.rerun, Path(args.runs), conn.units.pole_pairs)
            out = run_sequence(seq, conn, runs_root=args.runs, progress=not args.no_progress,
                               rerun=rerun, trace_format=args.trace_format)
        finally:
            if rerun is not None:
                rerun.close()
            conn.close()
        r = out.result
        results.append(r)
        kind = drive_kind(conn)
        kinds.append(kind)
        extra = {"run_dir": str(out.run_dir), "lost_frames": out.logstats["lost_frames"],
                 **kind}
        summaries.append(summary(r, extra))
        _print_result(r, out, kind)
        if out.interrupted is not None:
            if isinstance(out.interrupted, KeyboardInterrupt):
                print(f"bench: interrupted; drive safe state: {r.safe_state}", file=sys.stderr)
                rc = EXIT_INTERRUPT
            else:
                print(f"bench: run aborted: {r.error}; drive safe state: {r.safe_state}",
                      file=sys.stderr)
                rc = EXIT_DRIVE
            break
        if not r.passed and rc == EXIT_OK:
            rc = EXIT_FAIL
    _update_index(args.runs)
    if args.summary_json:
        doc: Any = summaries[0] if len(summaries) == 1 else summaries
        Path(args.summary_json).write_text(json.dumps(doc, indent=2) + "\n")
    if args.junit:
        write_junit(args.junit, results, kinds[0] if kinds else None)
    return rc


def _update_index(runs_root: str) -> None:
    """Refresh RUNS/index.html after a run; a failure is one line, never the run's result."""
    from bench._report import write_index

    try:
        print(f"  runs index: {write_index(runs_root)}")
    except Exception as e:  # noqa: BLE001 - the run itself is complete and saved
        print(f"bench: runs index not updated: {e}", file=sys.stderr)


def cmd_report(args: argparse.Namespace) -> int:
    from bench._report import write_index

    try:
        out = write_index(args.runs)
    except FileNotFoundError:
        raise UserError(f"--runs {args.runs}: no such folder (run 'bench run ...' first, or "
                        "give the folder that holds the run folders)") from None
    n = out.read_text(encoding="utf-8").count("class='pick'")
    print(f"{out} ({n} run(s))")
    return EXIT_OK


def _prefetch(module: str) -> None:
    """Import ``module`` in a background thread (the run waits on the simulated drive
    most of the time, so a slow import costs little wall time there). A failure is
    left for the real import to report."""
    import threading

    if module in sys.modules:
        return

    def imp() -> None:
        try:
            __import__(module)
        except Exception:  # noqa: BLE001, S110 - reported where it is really imported
            pass

    threading.Thread(target=imp, name=f"bench-prefetch-{module}").start()


def _print_result(r: Any, out: Any, kind: dict[str, Any] | None = None) -> None:
    sim = ""
    if kind and kind.get("simulated"):
        sim = " [SIMULATED drive" + (", fallback: no hardware found]" if kind.get("fallback")
                                     else "]")
    print(f"\n{r.sequence}: {'PASSED' if r.passed else 'FAILED'}{sim}  "
          f"(sequence {r.duration_s:.3f} s, wall {r.wall_s:.2f} s)")
    for e in r.expectations:
        m = "n/a" if e.measured != e.measured else f"{e.measured:.5g}"
        paper = ""
        if e.paper is not None:
            paper = f"; paper {e.paper:g}: {'reproduced' if e.paper_met else 'NOT reproduced'}"
        print(f"  [{'PASS' if e.passed else 'FAIL'}] {e.name}: {m} "
              f"(required {e.criterion}{paper})")
    lost = out.logstats.get("lost_frames", {})
    print(f"  CAN frames logged: {out.logstats.get('frames_logged')}, lost frames: {lost}")
    if out.logstats.get("receive_errors"):
        print(f"  receive-thread errors: {out.logstats['receive_errors']}")
    print(f"  run folder: {out.run_dir}")
    if out.report:
        print(f"  report: {out.report}")


def cmd_live(args: argparse.Namespace) -> int:
    import math

    from bench._logging import run_dir_for

    if not math.isfinite(args.speed):
        raise UserError(f"--speed {args.speed}: not a finite number")
    if not (math.isfinite(args.duration) and 0 <= args.duration <= 86400):
        raise UserError(f"--duration {args.duration}: allowed range [0, 86400] s")
    lim = None
    try:
        from bench._sequence import drive_envelope
        from bench._units import MotorUnits

        env = drive_envelope(args.motor or "paper_salient")
        units = MotorUnits(env["pole_pitch_m"], env["pole_pairs"])
        lim = env["speed_max_mps"] / units.speed_to_mps(1.0, args.unit)
    except Exception:  # noqa: BLE001 - motor problems are reported by _connect
        pass
    if lim is not None and abs(args.speed) > lim:
        raise UserError(f"--speed {args.speed:g} {args.unit}: allowed range [{-lim:.4g}, "
                        f"{lim:.4g}] {args.unit} (the drive's speed limit)")
    conn = _connect(args)
    d = conn.drive
    out_dir = run_dir_for("live", "runs")
    rerun = _make_rerun(args.rerun or ["spawn"], out_dir, conn.units.pole_pairs)
    if conn.sim is not None:
        conn.sim.sink = rerun.log_sim_chunk
        conn.sim.set_realtime(True)  # live viewing: the simulated drive follows the wall clock
    interrupted = False
    conn.start_heartbeat()
    try:
        d.enable("speed")
        d.set_speed_mps(conn.units.speed_to_mps(args.speed, args.unit))
        t0 = d.clock.now()
        print("bench: live; Ctrl-C to stop (the drive is disabled on exit)", file=sys.stderr)
        while args.duration <= 0 or d.clock.now() - t0 < args.duration:
            d.clock.sleep_until(d.clock.now() + 0.1)
            if d.state == "FAULT":
                from bench._drive import fault_text

                print(f"bench: drive FAULT {fault_text(d.fault_code())}", file=sys.stderr)
                break
    except KeyboardInterrupt:
        interrupted = True
    finally:
        try:
            d.disable()
            print("bench: drive disabled", file=sys.stderr)
        except Exception as e:  # noqa: BLE001
            print(f"bench: SAFE STATE FAILED: {e}", file=sys.stderr)
        if conn.sim is not None:
            conn.sim.sink = None
        rerun.close()
        conn.close()
    return EXIT_INTERRUPT if interrupted else EXIT_OK


def cmd_info(args: argparse.Namespace) -> int:
    conn = _connect(args)
    try:
        d = conn.drive
        ident = d.identity()
        print(f"connection: {conn.description}")
        for k, v in ident.items():
            print(f"  {k}: {v:#x}" if isinstance(v, int) and k in (
                "vendor_id", "product_code", "revision", "firmware_version_u32")
                else f"  {k}: {v}")
        probs = d.check_firmware(ident)
        print("firmware vs EDS: " + ("matches" if not probs else "MISMATCH: " + "; ".join(probs)))
        print(f"state: {d.state}  fault: {d.fault_code():#06x}")
        print(f"units: pole pitch {conn.units.pole_pitch_m} m, pole pairs "
              f"{conn.units.pole_pairs:g}")
        return EXIT_OK if not probs else EXIT_DRIVE
    finally:
        conn.close()


def cmd_param(args: argparse.Namespace) -> int:
    from bench._drive import ParamError, ParamInputError, param_table

    if args.action not in ("get", "set", "list"):
        raise UserError("param: choose get, set or list (see bench param --help)")
    if args.action == "list":
        conn = None if args.offline else _connect(args)
        try:
            seen = set()
            for p in param_table().values():
                if p.address in seen or (not args.all and 0x1000 <= p.index < 0x2000):
                    continue
                seen.add(p.address)
                rng = f"[{p.min}, {p.max}]" if p.min is not None or p.max is not None else ""
                val = ""
                if conn is not None and p.access in ("ro", "rw", "const"):
                    try:
                        v = conn.drive.read_raw(p.index, p.sub)
                        val = f"{v:.6g}" if isinstance(v, float) else str(v)
                    except (ParamError, KeyError) as e:
                        val = f"<{' '.join(str(e).split())[:40]}>"
                print(f"{p.address:>10}  {p.name:<34} {p.access:<5} {val:>14} {p.unit:<10} "
                      f"{rng}".rstrip())
            return EXIT_OK
        finally:
            if conn is not None:
                conn.close()
    conn = _connect(args)
    try:
        d = conn.drive
        if args.action == "get":
            v, p = d.get(args.name)
        else:
            p = d.set(args.name, args.value)
            v, p = d.get(args.name)
        print(f"{p.name} ({p.address}) = {v} {p.unit}".rstrip())
        return EXIT_OK
    except ParamInputError as e:
        raise UserError(str(e)) from None
    except ParamError as e:
        raise UserError(str(e), EXIT_DRIVE) from None
    finally:
        conn.close()


def cmd_config(args: argparse.Namespace) -> int:
    from bench._drive import ParamError, ParamInputError

    if args.action not in ("backup", "restore"):
        raise UserError("config: choose backup or restore (see bench config --help)")
    doc: Any = None
    if args.action == "restore":  # read and parse the file before connecting
        try:
            text = Path(args.file).read_text(encoding="utf-8")
        except OSError as e:
            raise UserError(f"{args.file}: cannot read: {e.strerror}") from None
        except UnicodeDecodeError as e:
            raise UserError(f"{args.file}: not UTF-8 text (byte offset {e.start})") from None
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as e:
            raise UserError(f"{args.file}:{e.lineno}:{e.colno}: not valid JSON: {e.msg}") from None
    conn = _connect(args)
    try:
        d = conn.drive
        if args.action == "backup":
            doc = {"bench_version": __version__, "drive": d.identity(),
                   "parameters": d.backup()}
            Path(args.file).write_text(json.dumps(doc, indent=2) + "\n")
            print(f"bench: {len(doc['parameters'])} parameters -> {args.file}")
            return EXIT_OK
        try:
            n = d.restore(doc, source=args.file)
        except ParamInputError as e:
            for line in str(e).splitlines():
                print(f"bench: {line}", file=sys.stderr)
            print("bench: nothing written", file=sys.stderr)
            return EXIT_USAGE
        print(f"bench: restored {n} parameters from {args.file}")
        return EXIT_OK
    except ParamError as e:
        raise UserError(str(e), EXIT_DRIVE) from None
    except OSError as e:
        raise UserError(f"{args.file}: {e.strerror}", EXIT_USAGE) from None
    finally:
        conn.close()


def cmd_faults(args: argparse.Namespace) -> int:
    from bench._drive import DriveError, fault_text

    conn = _connect(args)
    try:
        d = conn.drive
        f = d.faults()
        print(f"state: {f['state']}")
        print(f"error code (0x603F): {fault_text(f['error_code'])}")
        print(f"error register (0x1001): {f['error_register']:#04x}")
        print("history (newest first): " + (", ".join(fault_text(c) for c in f["history"])
                                            or "empty"))
        for code, reg in f["emcy"]:
            print(f"EMCY: {fault_text(code)} register {reg:#04x}")
        if args.reset:
            print(f"fault reset -> {d.reset_faults()}")
        return EXIT_OK
    except DriveError as e:
        print(f"bench: {e}", file=sys.stderr)
        return EXIT_DRIVE
    finally:
        conn.close()


def _campaign_cmd(args: argparse.Namespace) -> int:
    from bench._campaign import cmd

    return cmd(args)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``bench`` console script."""
    ap = build_parser()
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING - 10 * min(args.verbose, 2),
                        format="%(levelname)s %(name)s: %(message)s")
    if not args.verbose:
        logging.getLogger("canopen").setLevel(logging.ERROR)
    if args.cmd is None:
        ap.print_help()
        return EXIT_USAGE
    _sigterm_as_interrupt()
    handlers = {"run": cmd_run, "validate": cmd_validate, "live": cmd_live, "info": cmd_info,
                "param": cmd_param, "config": cmd_config, "faults": cmd_faults,
                "campaign": _campaign_cmd, "report": cmd_report}
    try:
        return handlers[args.cmd](args)
    except KeyboardInterrupt:
        print("bench: interrupted", file=sys.stderr)
        return EXIT_INTERRUPT
    except UserError as e:
        print(f"bench: {e}", file=sys.stderr)
        return e.code
    except Exception as e:  # noqa: BLE001 - last resort: one line, traceback kept
        return _internal_error(e, getattr(args, "runs", "runs"))


def _internal_error(e: BaseException, runs_root: str) -> int:
    """An unexpected exception (a bug): one line, and where the traceback is."""
    tb = traceback.format_exc()
    what = " ".join(f"{type(e).__name__}: {e}".split())[:300]
    if os.environ.get("BENCH_DEBUG"):
        sys.stderr.write(tb)
        print(f"bench: internal error: {what}", file=sys.stderr)
        return EXIT_INTERNAL
    where = "set BENCH_DEBUG=1 to print it"
    try:
        d = Path(runs_root)
        d.mkdir(parents=True, exist_ok=True)
        f = d / f"bench_error_{time.strftime('%Y%m%dT%H%M%S', time.gmtime())}.txt"
        f.write_text(tb, encoding="utf-8")
        where = f"traceback in {f} (BENCH_DEBUG=1 prints it)"
    except OSError:
        pass
    print(f"bench: internal error: {what}; {where}", file=sys.stderr)
    return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
