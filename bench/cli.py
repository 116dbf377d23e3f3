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
import gc
import json
import logging
import os
import re
import signal
import sys
import time
import traceback
from pathlib import Path
from typing import Any

from bench import __version__
from protocols.generated.od_names import Extractor

#: --extractor choices (protocols/od.yaml enums:)
EXTRACTOR_KEYS = tuple(e.key for e in Extractor)

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
    g.add_argument("--sim-server", action="store_true",
                   help="the simulated drive server of `bench sim start` (its own process, "
                        "reached over python-can socketcand on 127.0.0.1 exactly as "
                        "hardware; successive commands see the same drive)")
    g.add_argument("--emu", action="store_true",
                   help="the emulated board of `bench emu start` (the firmware image on QEMU "
                        "with a virtual motor), reached exactly as hardware: python-can slcan "
                        "over 127.0.0.1, the serial link, its virtual load machine")
    g.add_argument("--require-hardware", action="store_true",
                   help="fail with exit 3 when no drive answers instead of falling back to "
                        "the simulated drive (for a rig's CI job)")
    g.add_argument("--interface", help="python-can interface: socketcan, pcan, slcan, kvaser, "
                                       "socketcand, ... (default: python-can configuration); "
                                       "a named interface never falls back to the simulated "
                                       "drive")
    g.add_argument("--channel", help="python-can channel, e.g. can0, PCAN_USBBUS1, "
                                     "/dev/ttyACM0 or socket://host:port for slcan")
    g.add_argument("--bitrate", type=int, help="CAN bitrate in bit/s, e.g. 1000000")
    g.add_argument("--host", help="socketcand: the server's host (e.g. 127.0.0.1)")
    g.add_argument("--port", type=int, dest="bus_port", metavar="PORT",
                   help="socketcand: the server's TCP port")
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
    g.add_argument("--extractor", choices=EXTRACTOR_KEYS,
                   help="simulated drive: HF extractor (default: the sequence's)")
    g.add_argument("--seed", type=int, help="simulated drive: noise seed (default: the "
                                            "sequence's)")
    g.add_argument("--sim-plant", metavar="MOTOR",
                   help="simulated drive: the motor it actually drives, when it is not the "
                        "one the drive is configured for (--motor): a motor name or file; its "
                        "machine parameters (R, L, psi_f, pole pitch, mass, friction, "
                        "cogging) replace the simulated plant's. For 'wrong motor' tests and "
                        "`bench identify` on a motor the drive does not know")
    g.add_argument("--realtime", action="store_true",
                   help="simulated drive: pace to the wall clock (default: as fast as possible)")


def _rerun_arg(p: argparse.ArgumentParser) -> None:
    """``--rerun MODE [ARGS]`` (parsed by :func:`bench._live.parse_rerun_spec` in
    :func:`_make_rerun`). ``nargs="+"`` takes every token up to the next option, so
    ``bench run --rerun spawn SEQ.yaml`` gives ``--rerun`` the file name: the sequence
    files become optional for argparse and :func:`_make_rerun` hands the tokens the mode
    does not take back to them (``cmd_run`` then requires at least one)."""
    p.add_argument("--rerun", nargs="+", metavar="MODE",
                   help="live telemetry to rerun (also recorded as .rrd, in the run folder "
                        "unless 'save PATH.rrd'): 'spawn' (native viewer; without a display: "
                        "recording only), 'save [PATH.rrd]', 'serve [GRPC_PORT [WEB_PORT]]' "
                        "(gRPC server and web viewer on 127.0.0.1, default 9876 9090; prints "
                        "the viewer URL), 'connect [URL|PORT]' (a running viewer, default "
                        "rerun+http://127.0.0.1:9876/proxy)")
    for a in p._actions:  # the positional sequence files (bench run): see above
        if a.dest == "sequences" and a.nargs == "+":
            a.nargs = "*"


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
    _record_args(p)

    p = sub.add_parser("validate", help="validate sequence files only",
                       description="Check sequence files against the schema; errors name the "
                                   "file, line and field.")
    p.add_argument("sequences", nargs="+", metavar="SEQ.yaml")
    _set_arg(p)

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
    p.add_argument("--tui", action="store_true",
                   help="a scope in this terminal instead of rerun (no display needed: ssh, "
                        "CI logs): state, fault, speed, position, thrust and the estimate "
                        "against the reference sensor, from the TPDOs")

    p = sub.add_parser("identify", help="measure the motor: R, L_d(i_d), L_q, psi_f, mass, "
                       "friction; write a motor file and the drive configuration",
                       description="The drive measures the motor it is connected to "
                       "(docs/identify.md): standstill starts (L_d, L_q), d-axis DC steps (R), "
                       "an HF bias sweep (L_d saturation), a speed profile in each direction "
                       "(psi_f, mass, friction). Writes RUNS/<stamp>_identify/ with "
                       "motor.toml, drive_config.json (for `bench config restore`), "
                       "report.html and summary.json. The drive's configuration is restored "
                       "afterwards unless --apply. The mover travels about --travel in each "
                       "direction: the axis must be free. With --clamped, step 7 follows: "
                       "the cross-saturation map on the mover held by a clamp or brake. "
                       "Exit 0 identified, 1 the identification stopped (a drive fault, "
                       "named; or the clamped mover moved: steps 1-6 kept), 2 bad input, 3 "
                       "connection error, 130 interrupted (drive disabled, configuration "
                       "restored).")
    _conn_args(p)
    p.add_argument("--travel", type=float, default=0.3, metavar="M",
                   help="free travel the motion runs may use (m, default 0.3)")
    p.add_argument("--starts", type=int, default=4,
                   help="standstill starts for L_d and L_q (default 4)")
    p.add_argument("--name", default="identified", help="motor name in motor.toml")
    p.add_argument("--apply", action="store_true",
                   help="leave the identified configuration in the drive (gains derived "
                        "from it); `bench config save` then stores it")
    p.add_argument("--clamped", action="store_true",
                   help="after the usual steps, step 7: the cross-saturation map (object "
                        "0x2057, motor file [controller] xsat_*) on a HELD mover: the bench "
                        "stops the drive and asks you to clamp or brake the mover (it applies "
                        "thrust up to 0.6 x i_max_A; the peak thrust is printed), Enter goes "
                        "on, 'skip' skips. Needs an operator at the terminal; on --sim the "
                        "simulated mover is locked instead. A mover that moves stops the step "
                        "(exit 1, drive disabled, steps 1-6 kept). Without it the map is not "
                        "measured (the motor file says so)")
    p.add_argument("--ripple", action="store_true",
                   help="after the usual steps (before --clamped's), steps 8 and 9: the "
                        "position ripple of the HF axis (object 0x2057 rip_*) and the cogging "
                        "thrust at 6 theta (rip6_a0_N, rip6_b0_N), motor file [controller], "
                        "from constant-speed passes at 0.1 m/s there and back within --travel "
                        "on the FREE mover, with the identified configuration; no position "
                        "sensor. A fault stops them (what was measured before is kept, noted)")
    p.add_argument("--runs", default="runs", metavar="DIR", help="run folder root")

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

    p = sub.add_parser("config", help="configuration backup / restore / save to the drive",
                       description="Back the drive's rw parameters up to a JSON file, "
                                   "restore them from one, or store the running "
                                   "configuration in the drive's non-volatile memory.")
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
    cs = csub.add_parser("save", help="store the running configuration in the drive",
                         description="Store the running configuration in the drive's "
                         "non-volatile memory (CiA 301 0x1010:1 'save'): the drive loads it "
                         "at power-up and NMT reset node. Refused while the power stage is "
                         "enabled. The in-process --sim drive has none: use `bench sim start` "
                         "and --sim-server.")
    _conn_args(cs)
    cd = csub.add_parser("defaults", help="erase the stored configuration",
                         description="Erase the configuration stored in the drive (CiA 301 "
                         "0x1011:1 'load'): the defaults apply from the next NMT reset node "
                         "or power-up; the running values stay until then.")
    _conn_args(cd)

    p = sub.add_parser("sim", help="the simulated drive as its own process (server)",
                       description="Start, stop or show the simulated drive server: one "
                       "simulated drive paced to the wall clock in a background process, "
                       "reached over python-can's socketcand interface on 127.0.0.1 "
                       "(--sim-server, or --interface socketcand --channel can0 --host "
                       "127.0.0.1 --port N). Successive commands see the same drive; its "
                       "non-volatile memory (bench config save) survives stop/start. State, "
                       "log and memory files: $BENCH_SIM_DIR, else "
                       "$XDG_STATE_HOME/pmlsm-bench, else ~/.local/state/pmlsm-bench.",
                       epilog="Exit codes: 0 ok (status: running), 2 bad option or already "
                              "running, 3 not running or it failed to start.")
    ssub = p.add_subparsers(dest="sim_cmd", metavar="ACTION", required=True)
    st = ssub.add_parser("start", help="start the server in the background",
                         description="Start the simulated drive server and wait until it "
                         "listens.")
    st.add_argument("--motor", default="paper_salient", help="motor file (default "
                                                             "paper_salient)")
    st.add_argument("--extractor", choices=EXTRACTOR_KEYS,
                    default="sogi_adaptive", help="HF extractor (default sogi_adaptive)")
    st.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    st.add_argument("--node-id", type=int, default=1, help="drive node id (default 1)")
    st.add_argument("--port", type=int, default=0,
                    help="TCP port on 127.0.0.1 (default 0: any free port)")
    ssub.add_parser("stop", help="stop the server", description="Stop the simulated drive "
                    "server (SIGTERM, SIGKILL after 5 s); a stale state file is removed.")
    ssub.add_parser("status", help="is it running, where, which motor",
                    description="Show the simulated drive server's state; exit 3 when none "
                    "is running.")

    p = sub.add_parser("emu", help="the emulated board: the drive's firmware image on QEMU",
                       description="Start, stop or show the emulated board: the drive's "
                       "firmware image (board port mps2_an386: the whole drive application) "
                       "on an emulated Cortex-M4F in qemu-system-arm, with the simulator's "
                       "plant compiled in as its virtual motor, bound to 127.0.0.1. Every "
                       "subcommand reaches it with --emu exactly as it reaches a rig (slcan "
                       "CAN adapter, serial telemetry link; load steps through its virtual "
                       "load machine); it runs paced by its own virtual clock, at a fraction "
                       "of real time, and every run is paced by the drive's clock. Its flash "
                       "page (bench config save) survives stop/start. State, log and flash "
                       "files: $BENCH_SIM_DIR, else $XDG_STATE_HOME/pmlsm-bench, else "
                       "~/.local/state/pmlsm-bench.",
                       epilog="Exit codes: 0 ok (status: running), 2 bad option or already "
                              "running, 3 not running, no image or QEMU, or it failed to "
                              "start (the board's own line from its log).")
    esub = p.add_subparsers(dest="emu_cmd", metavar="ACTION", required=True)
    es = esub.add_parser("start", help="boot the emulated board in the background",
                         description="Boot the emulated board and wait until it listens; "
                         "prints the connect line.")
    es.add_argument("--motor", default="paper_salient",
                    help="motor file the drive is configured for (default paper_salient)")
    es.add_argument("--plant", metavar="MOTOR",
                    help="the motor the virtual motor actually is, when not the configured "
                         "one (wrong-motor tests): a motor name or file")
    es.add_argument("--extractor", choices=EXTRACTOR_KEYS, default="sogi_adaptive",
                    help="HF extractor (default sogi_adaptive)")
    es.add_argument("--seed", type=int, default=0, help="ADC noise seed (default 0)")
    es.add_argument("--node-id", type=int, default=1, help="drive node id (default 1)")
    es.add_argument("--x0", type=float, default=0.0, metavar="M",
                    help="initial mover position (m, default 0)")
    es.add_argument("--no-ref-sensor", action="store_true",
                    help="no reference scale on the emulated rig (runs then say 'no reference "
                         "sensor: estimate metrics not judged')")
    es.add_argument("--image", metavar="ELF", help="firmware image (default: the installed "
                                                   "one)")
    esub.add_parser("stop", help="stop the emulated board",
                    description="Stop QEMU (SIGTERM, SIGKILL after 5 s); a stale state file "
                    "is removed.")
    et = esub.add_parser("status", help="is it running, where, how fast",
                         description="Show the emulated board's state and measure its speed "
                         "(drive seconds per wall second over 1 s); exit 3 when none runs.")
    et.add_argument("--no-measure", action="store_true", help="do not measure the speed")

    p = sub.add_parser("shell", help="IPython with a connected drive (parameters by name, "
                       "live set-points and telemetry, sequences step by step)",
                       description="Open IPython with `drive` connected: drive.p.<TAB> "
                       "completes every parameter (value with unit and range; assign to "
                       "write), drive.enable()/speed()/force()/disable(), drive.live() streams "
                       "telemetry to rerun while you type, drive.stepper(SEQ.yaml) runs a "
                       "sequence one step per next(). A simulated drive follows the wall "
                       "clock. Leaving the shell disables the drive.")
    p.add_argument("--runs", default="runs", metavar="DIR",
                   help="folder for live telemetry recordings (default runs/)")
    _conn_args(p)
    p = sub.add_parser("faults", help="read (and reset) faults",
                       description="Show the latched fault, error register, fault history "
                                   "and EMCY messages; --reset sends a fault reset.")
    p.add_argument("--reset", action="store_true", help="fault reset (controlword bit 7)")
    _conn_args(p)
    p = sub.add_parser("report", help="reports: the runs index, a standalone report",
                       description="Regenerate report pages from the run folders: `bench "
                       "report index` (RUNS/index.html), or `bench report --standalone "
                       "RUN_DIR` (a copy of the run's report.html with plotly.js embedded: "
                       "one file that works offline when copied alone; a report in a run "
                       "folder loads the runs folder's one copy of the library, "
                       "RUNS/plotly-<version>.min.js).")
    p.add_argument("--standalone", metavar="RUN_DIR",
                   help="write RUN_DIR/report_standalone.html (or --out): the run's report "
                        "with plotly.js embedded")
    p.add_argument("--out", metavar="FILE", help="with --standalone: where to write it")
    rsub = p.add_subparsers(dest="report_cmd", metavar="WHAT")
    ri = rsub.add_parser("index", help="write RUNS/index.html listing all runs",
                         description="Write RUNS/index.html: every run folder (sequence, "
                         "date, verdict, key metrics, link to its report) and a comparison "
                         "view of the runs ticked. Also done after every 'bench run'.")
    ri.add_argument("--runs", default="runs", metavar="DIR", help="run folder root (default "
                                                                  "runs/)")

    _results_parser(sub)

    p = sub.add_parser("flash", help="program a board's image and check the drive after "
                       "its reboot", description="Program a board's firmware image with the "
                       "board's debug probe (openocd or pyocd, the first installed unless "
                       "--tool), then - on the CAN bus given (--interface/--channel/--bitrate, "
                       "or python-can's configuration) - wait for the drive to answer and check "
                       "its firmware version (0x2040) against this bench's and its board name "
                       "(0x2090:2). The parameter page at the end of the flash is not part of "
                       "the image: a stored configuration survives. docs/hardware_bringup.md.",
                       epilog="Exit codes: 0 programmed, rebooted and the expected version "
                              "answered, 1 another version or board answered, 2 bad input or "
                              "no tool (nothing written), 3 no probe, programming or "
                              "verification failed, or no answer on CAN.")
    p.add_argument("image", metavar="IMAGE.elf", help="e.g. build/cm4/firmware_c/boards/"
                   "nucleo_g474re/pmlsm_nucleo_g474re.elf")
    p.add_argument("--tool", choices=("openocd", "pyocd"), help="programming tool")
    p.add_argument("--probe", metavar="SERIAL", help="the debug probe's serial number")
    p.add_argument("--board", default="nucleo_g474re",
                   help="the board name the drive must report (default nucleo_g474re)")
    p.add_argument("--timeout", type=float, default=10.0, metavar="S",
                   help="how long the drive may take to answer after the reset (default 10)")
    p.add_argument("--no-check", action="store_true",
                   help="program only; do not check the drive over CAN")
    p.add_argument("--interface", help="python-can interface of the drive's bus")
    p.add_argument("--channel", help="python-can channel")
    p.add_argument("--bitrate", type=int, help="CAN bitrate in bit/s")
    p.add_argument("--node-id", type=int, default=1, help="drive node id (default 1)")

    p = sub.add_parser("compare", help="two runs side by side against tolerances (twin "
                       "check: emulated vs simulated, hardware vs its simulation)",
                       description="Compare two run folders: every metric of both (their "
                       "default windows), the difference against the metric's tolerance, the "
                       "faults each drive raised (must be the same codes); writes a page "
                       "overlaying their signals (default: in RUN_B, compare_<RUN_A>.html).",
                       epilog="Exit codes: 0 within tolerances and the same faults, 1 a "
                              "difference beyond tolerance or other faults, 2 bad input.")
    p.add_argument("run_a", metavar="RUN_A")
    p.add_argument("run_b", metavar="RUN_B")
    p.add_argument("--tol", action="append", metavar="METRIC=VALUE",
                   help="tolerance of a metric: METRIC=10%% (relative to RUN_A) or "
                        "METRIC=0.002 (absolute, the metric's unit); repeatable")
    p.add_argument("--out", metavar="PAGE.html", help="where to write the comparison page")

    import simcampaign as _campaign
    _campaign.add_parser(sub)
    return ap


def _record_args(p: argparse.ArgumentParser) -> None:
    """``bench run``'s test-record options and sequence parameters."""
    g = p.add_argument_group("test record (summary.json, meta.json, JUnit, RUNS/results.sqlite)")
    g.add_argument("--operator", help="who runs the test (default: $BENCH_OPERATOR, else the "
                                      "login name)")
    g.add_argument("--station", help="the test station (default: $BENCH_STATION, else the "
                                     "host name)")
    g.add_argument("--fixture", help="the fixture the drive is in (default: $BENCH_FIXTURE, "
                                     "else none)")
    _set_arg(p)


def _set_arg(p: argparse.ArgumentParser) -> None:
    """``--set NAME=VALUE`` (``bench run``, ``bench validate``: :func:`_parse_sets`)."""
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", dest="set_",
                   help="a value for the sequence's parameter NAME (its params:), e.g. --set "
                        "speed=150; repeatable")


def _results_parser(sub: Any) -> None:
    p = sub.add_parser(
        "results", help="the results store: runs across time, by motor, serial, sequence",
        description="List the runs recorded in RUNS/results.sqlite (written at the end of "
                    "every 'bench run'), newest first, or export them (--csv, --json with "
                    "their expectations). --rebuild re-creates the store from the run "
                    "folders' summary.json. Exit 2 for a bad filter, 3 when the store is "
                    "missing or unreadable.")
    p.add_argument("--runs", default="runs", metavar="DIR", help="run folder root (default "
                                                                 "runs/)")
    p.add_argument("--motor", metavar="M", help="only runs of this motor")
    p.add_argument("--serial", metavar="N", help="only this drive's runs (its serial number, "
                                                 "0x1018:4; decimal or 0x-hex)")
    p.add_argument("--sequence", metavar="S", help="only runs of this sequence (its name)")
    p.add_argument("--since", metavar="DATE", help="runs started at or after DATE (YYYY-MM-DD "
                                                   "or YYYY-MM-DDTHH:MM, UTC)")
    p.add_argument("--until", metavar="DATE", help="runs started at or before DATE (a day: "
                                                   "through its end)")
    p.add_argument("--verdict", metavar="V", help="passed, failed or aborted")
    p.add_argument("--limit", metavar="N", help="at most N runs (the newest)")
    out = p.add_mutually_exclusive_group()
    out.add_argument("--csv", metavar="FILE", help="write the runs as CSV to FILE ('-': "
                                                   "stdout)")
    out.add_argument("--json", action="store_true", help="print the runs and their "
                                                         "expectations as JSON")
    p.add_argument("--rebuild", action="store_true",
                   help="re-create the store from the run folders' summary.json first")


def _quiet_thread_errors(verbose: bool) -> None:
    """An exception that ends a background thread (python-can's periodic senders when
    the bus is gone, a receive thread) is one line, not a traceback; BENCH_DEBUG=1 or -v
    keep the traceback. What it means for the run is said by the run itself."""
    import threading

    default = threading.excepthook

    def hook(a: Any) -> None:
        if verbose or os.environ.get("BENCH_DEBUG"):
            default(a)
            return
        name = a.thread.name if a.thread is not None else "a background thread"
        print(f"bench: {name} stopped: {a.exc_type.__name__}: "
              f"{' '.join(str(a.exc_value).split())}", file=sys.stderr)

    threading.excepthook = hook


class _Console:
    """stdout or stderr that a closed pipe or a hung-up terminal cannot stop
    (``bench run ... | head -1``, ``bench live | tee log`` and Ctrl-C): the first failed
    write points the file descriptor at /dev/null and every later write succeeds, so
    console output never decides whether the drive is made safe, the run's files are
    written or which exit code the command ends with."""

    def __init__(self, stream: Any) -> None:
        self._stream = stream
        self.broken = False

    def _broke(self) -> None:
        self.broken = True
        try:
            fd = os.open(os.devnull, os.O_WRONLY)
            os.dup2(fd, self._stream.fileno())  # the interpreter's exit flush succeeds too
            os.close(fd)
        except (OSError, ValueError, AttributeError):
            pass

    def write(self, text: str) -> int:
        if not self.broken:
            try:
                return self._stream.write(text)
            except OSError:  # EPIPE, EIO of a closed terminal
                self._broke()
        return len(text)

    def flush(self) -> None:
        if not self.broken:
            try:
                self._stream.flush()
            except OSError:
                self._broke()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


def _guard_console() -> None:
    """Install :class:`_Console` on sys.stdout and sys.stderr (the console script only)."""
    for name in ("stdout", "stderr"):
        s = getattr(sys, name)
        if s is not None and not isinstance(s, _Console):
            setattr(sys, name, _Console(s))


def _sigterm_as_interrupt() -> None:
    """SIGTERM and SIGINT stop a run safely (the drive disabled, the run saved): SIGINT
    gets Python's own handler even when the process was started with it ignored (a
    background job of a non-interactive shell, a CI runner), so a runner's SIGINT is
    never ignored while a drive moves."""
    def handler(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt(f"signal {signum}")

    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGINT, signal.default_int_handler)


def _bus_options(args: argparse.Namespace) -> tuple[tuple[str, Any], ...]:
    """The options that choose a bus and its pacing, with their values."""
    return (("--interface", args.interface), ("--channel", args.channel),
            ("--bitrate", args.bitrate), ("--host", args.host), ("--port", args.bus_port),
            ("--realtime", args.realtime))


def _refuse_beside(flag: str, why: str, options: Any) -> None:
    """``flag`` names its own drive: any of ``options`` (name, value) given is refused."""
    for opt, val in options:
        if val:
            raise UserError(f"{flag} and {opt} contradict each other ({why}); drop one")


def _emu_state(args: argparse.Namespace) -> Any:
    """The running emulated board for ``--emu`` (None without it)."""
    if not getattr(args, "emu", False):
        return None
    _refuse_beside("--emu", "the emulated board is reached on its own ports, paced by its "
                   "own clock; its motor is chosen by `bench emu start`",
                   (("--sim", args.sim), ("--sim-server", getattr(args, "sim_server", False)),
                    *_bus_options(args), ("--sim-plant", getattr(args, "sim_plant", None))))
    if args.serial:
        raise UserError(f"--emu and --serial {args.serial} contradict each other (the "
                        "emulated board's serial link is used); drop one")
    from sim_fallback.emu import EmuError, check_running

    try:
        st = check_running()
    except EmuError as e:  # its own exit code where it has one (a bad state folder: 2)
        raise UserError(str(e), getattr(e, "exit_code", EXIT_DRIVE)) from None
    if args.node_id != st.node_id:
        raise UserError(f"--node-id {args.node_id}: the emulated board's drive is node "
                        f"{st.node_id}")
    return st


def _sim_server_state(args: argparse.Namespace) -> Any:
    """The running simulated drive server for ``--sim-server`` (None without it)."""
    if not getattr(args, "sim_server", False):
        return None
    _refuse_beside("--sim-server", "the server's drive is paced to the wall clock on its "
                   "own bus", (("--sim", args.sim), *_bus_options(args)))
    from sim_fallback.server import SimServerError, check_running

    try:
        st = check_running()
    except SimServerError as e:  # its own exit code where it has one (a bad state folder: 2)
        raise UserError(str(e), getattr(e, "exit_code", EXIT_DRIVE)) from None
    if args.node_id != st.node_id:
        raise UserError(f"--node-id {args.node_id}: the simulated drive server's drive is "
                        f"node {st.node_id}")
    return st


def _connect(args: argparse.Namespace, seq: Any = None) -> Any:
    from bench._session import connect

    server = _sim_server_state(args)
    emu = _emu_state(args)
    if server is not None and not args.motor and (seq is None or seq.motor == server.motor):
        args.motor = server.motor  # units from the motor the server simulates
    if emu is not None and not args.motor and (seq is None or seq.motor == emu.motor):
        args.motor = emu.motor  # units from the motor the emulated board is configured for
    bus_kw: dict[str, Any] = {}
    if args.host is not None or args.bus_port is not None:
        if (args.interface or "") != "socketcand":
            raise UserError(f"--host/--port are socketcand's (--interface socketcand); with "
                            f"--interface {args.interface or '(none)'} give the channel "
                            "instead")
        if args.host is None or args.bus_port is None:
            raise UserError("--interface socketcand needs both --host and --port")
        if not 1 <= args.bus_port <= 65535:
            raise UserError(f"--port {args.bus_port}: allowed range [1, 65535]")
        bus_kw = {"host": args.host, "port": args.bus_port}

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
    if args.sim and args.interface:
        raise UserError(f"--sim and --interface {args.interface} contradict each other; drop "
                        "one of them")
    if args.sim and args.serial:
        raise UserError(f"--serial {args.serial} cannot be used with --sim (the simulated drive "
                        "has its own in-process serial link); drop one of them")
    if args.seed is not None and args.seed < 0:
        raise UserError(f"--seed {args.seed}: allowed range >= 0")
    where = f"--motor {motor}" if args.motor or seq is None else f"{seq.path}: motor"
    if server is not None and motor != server.motor:
        raise UserError(f"{where} is {motor!r}, the simulated drive server simulates "
                        f"{server.motor!r}: restart it with `bench sim start --motor {motor}`")
    if emu is not None and motor != emu.motor:
        raise UserError(f"{where} is {motor!r}, the emulated board is configured for "
                        f"{emu.motor!r}: restart it with `bench emu start --motor {motor}`")
    refusal = _check_motor(motor, extractor, where, sim_only=args.sim)
    sim_plant = None
    if getattr(args, "sim_plant", None):
        if not args.sim or server is not None or emu is not None:
            raise UserError(f"--sim-plant {args.sim_plant}: only with --sim (the in-process "
                            "simulated drive)")
        from sim_fallback import load_motor, machine_params

        try:
            sim_plant = machine_params(load_motor(args.sim_plant))
        except Exception as e:  # noqa: BLE001 - unknown name, broken file: one line
            raise UserError(f"--sim-plant {args.sim_plant}: {' '.join(str(e).split())}"
                            ) from None
    try:
        conn = connect(sim=args.sim, interface=args.interface, channel=args.channel,
                       bitrate=args.bitrate, serial_url=args.serial, realtime=args.realtime,
                       motor=motor, extractor=extractor, seed=seed, x0=x0,
                       node_id=args.node_id, load_node=args.load_node,
                       require_hardware=getattr(args, "require_hardware", False),
                       sim_server=server, sim_plant=sim_plant, emu=emu, bus_kw=bus_kw,
                       sync_period_ms=args.sync_period_ms)
    except UserError:
        raise
    except Exception as e:  # noqa: BLE001 - the bus, the drive or the simulator library
        if refusal and "fw_app_init" in str(e):  # fell back to the simulated drive
            raise UserError(refusal + "; the simulated drive (fallback: no hardware found) "
                            "cannot run this motor") from None
        raise UserError(f"cannot connect: {' '.join(str(e).split())}", EXIT_DRIVE) from e
    if seq is not None and not conn.is_sim and seq.x0 not in (0, 0.0):
        print(f"bench: {seq.path}: x0 {seq.x0} applies to the in-process simulated drive only; "
              "on this drive the mover starts where it is", file=sys.stderr)
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


def _make_rerun(tokens: list[str] | None, args: argparse.Namespace | None = None) -> Any:
    """``--rerun`` tokens -> a :class:`bench._live.RerunSpec` (None without ``--rerun``).

    Tokens the mode does not take go back to ``args.sequences`` (``bench run --rerun spawn
    SEQ.yaml``); where there are none to take them (``bench live``) they are an error. A
    bad specification is a :class:`UserError` (one line, exit 2), raised before anything
    connects or moves.
    """
    if not tokens:
        return None
    from bench._live import RerunSpecError, check_spec, parse_rerun_spec

    try:
        spec, rest = parse_rerun_spec(list(tokens))
        check_spec(spec)  # serve: both ports free on 127.0.0.1
    except RerunSpecError as e:
        raise UserError(str(e)) from None
    if rest:
        if args is not None and hasattr(args, "sequences"):
            args.sequences = [*(args.sequences or []), *rest]
        else:
            raise UserError(f"--rerun {' '.join(tokens)}: unexpected {' '.join(rest)!r}; "
                            "allowed: " + ", ".join(spec.FORMS))
    return spec


def cmd_validate(args: argparse.Namespace) -> int:
    from bench._sequence import SequenceError, load_sequence

    rc = EXIT_OK
    overrides = _parse_sets(args.set_)
    for f in args.sequences:
        try:
            s = load_sequence(f, overrides or None)
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
    from bench._mf4writer import Mf4Writer

    Mf4Writer.shared()  # its asammdf import runs in a child process beside ours
    import can
    from canopen.sdo.exceptions import SdoCommunicationError

    from bench._drive import DriveError
    from bench._live import RerunStartError
    from bench._report import summary, write_junit
    from bench._sequence import SequenceError, load_sequence
    from bench._session import run_sequence

    rerun = _make_rerun(args.rerun, args)  # may hand file names back to args.sequences
    if not args.sequences:
        raise UserError("run: SEQ.yaml: at least one sequence file is required")
    if rerun is not None and rerun.path is not None and len(args.sequences) > 1:
        raise UserError(f"--rerun save {rerun.path}: one file for {len(args.sequences)} "
                        "sequences; give no PATH (each run folder gets its telemetry.rrd)")
    from bench._results import RecordFieldError, add_junit_properties, station_fields

    try:
        who = station_fields(args.operator, args.station, args.fixture)
    except RecordFieldError as e:
        raise UserError(str(e)) from None
    overrides = _parse_sets(args.set_)
    seqs = []
    bad = False
    for f in args.sequences:  # validate everything before anything moves
        try:
            seqs.append(load_sequence(f, overrides))
        except SequenceError as e:
            _print_issues(e)
            bad = True
    if bad:
        return EXIT_USAGE
    from bench._session import drive_kind

    results = []
    summaries = []
    records: list[dict[str, Any]] = []
    kinds: list[dict[str, Any]] = []
    rc = EXIT_OK
    for seq in seqs:
        conn = _connect(args, seq)
        try:  # rerun: telemetry.rrd in the run folder (or the 'save PATH.rrd' given)
            out = run_sequence(seq, conn, runs_root=args.runs, progress=not args.no_progress,
                               rerun=rerun, trace_format=args.trace_format, station_info=who)
        except RerunStartError as e:  # before the sequence started: nothing moved
            raise UserError(f"--rerun {rerun.mode}: {e}", EXIT_DRIVE) from None
        except (DriveError, SdoCommunicationError, can.CanError, OSError) as e:
            # the drive or its bus went away while the run was being set up (the run itself
            # ends on a lost drive with its result)
            raise UserError(f"run: the drive stopped answering before the sequence started: "
                            f"{' '.join(str(e).split())}", EXIT_DRIVE) from None
        finally:
            conn.close()
        r = out.result
        results.append(r)
        kind = drive_kind(conn)
        kinds.append(kind)
        extra = {"run_dir": str(out.run_dir), "lost_frames": out.logstats["lost_frames"],
                 **kind, **out.record}
        records.append(out.record)
        summaries.append(summary(r, extra))
        _print_result(r, out, kind)
        if out.interrupted is not None:
            if isinstance(out.interrupted, KeyboardInterrupt):
                print(f"bench: interrupted; drive safe state: {r.safe_state}", file=sys.stderr)
                rc = EXIT_INTERRUPT
            else:
                why = r.error or " ".join(
                    f"{type(out.interrupted).__name__}: {out.interrupted}".split())
                print(f"bench: run aborted: {why}; drive safe state: {r.safe_state or 'n/a'}",
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
        add_junit_properties(args.junit, records)
    return rc


def _parse_sets(items: list[str]) -> dict[str, float]:
    """``--set NAME=VALUE`` options: each a parameter name and a finite number, once."""
    from bench._sequence import PARAM_NAME, SequenceLoader

    out: dict[str, float] = {}
    for item in items:
        name, eq, text = item.partition("=")
        name = name.strip()
        if not eq or not re.match(PARAM_NAME, name):
            raise UserError(f"--set {item}: give NAME=VALUE with NAME a parameter of the "
                            "sequence (its params:), e.g. --set speed=150")
        if name in out:
            raise UserError(f"--set {name}: given twice")
        try:
            import yaml

            v = yaml.load(text.strip() or "~", Loader=SequenceLoader)  # noqa: S506 - safe
        except Exception:  # noqa: BLE001 - any text that is not a YAML scalar
            v = None
        if not isinstance(v, (int, float)) or isinstance(v, bool) or v != v or \
                v in (float("inf"), float("-inf")):
            raise UserError(f"--set {name}={text}: not a number (parameters are numbers, "
                            f"e.g. --set {name}=150)")
        out[name] = v
    return out


def cmd_results(args: argparse.Namespace) -> int:
    from bench import _results as R

    def check(opt: str, text: str | None, parse: Any) -> Any:
        try:
            return None if text is None else parse(text)
        except ValueError as e:
            raise UserError(f"{opt} {e}") from None

    # every filter is checked before the store is opened
    serial = check("--serial", args.serial, R.parse_serial)
    since = check("--since", args.since, R.parse_when)
    until = check("--until", args.until, lambda t: R.parse_when(t, end=True))
    if args.verdict is not None and args.verdict not in R.VERDICTS:
        raise UserError(f"--verdict {args.verdict!r}: allowed: {', '.join(R.VERDICTS)}")
    if since is not None and until is not None and since > until:
        raise UserError(f"--since {args.since} is after --until {args.until}")
    limit = None
    if args.limit is not None:
        if not args.limit.isdigit() or int(args.limit) < 1:
            raise UserError(f"--limit {args.limit!r}: a whole number of runs, at least 1")
        limit = int(args.limit)
    if args.rebuild:
        try:
            n, skipped, moved = R.rebuild(args.runs)
        except FileNotFoundError:
            raise UserError(f"--runs {args.runs}: no such folder") from None
        except (OSError, R.sqlite3.Error, R.StoreError) as e:
            raise UserError(f"{R.store_path(args.runs)}: cannot be rebuilt: "
                            f"{' '.join(str(e).split())}", EXIT_DRIVE) from None
        if moved is not None:
            print(f"bench: the unreadable store was moved to {moved}", file=sys.stderr)
        for why in skipped:
            print(f"bench: skipped {why}", file=sys.stderr)
        print(f"bench: rebuilt {R.store_path(args.runs)}: {n} run(s) from the run folders"
              + (f", {len(skipped)} skipped" if skipped else ""), file=sys.stderr)
    try:
        rows = R.query(args.runs, motor=args.motor, serial=serial, sequence=args.sequence,
                       since=since, until=until, verdict=args.verdict, limit=limit,
                       expectations=bool(args.json))
    except R.StoreError as e:
        raise UserError(str(e), EXIT_DRIVE) from None
    except (OSError, R.sqlite3.Error) as e:
        raise UserError(f"{R.store_path(args.runs)}: {' '.join(str(e).split())}",
                        EXIT_DRIVE) from None
    if args.json:
        sys.stdout.write(R.to_json(rows))
    elif args.csv:
        text = R.to_csv(rows)
        if args.csv == "-":
            sys.stdout.write(text)
        else:
            try:
                Path(args.csv).write_text(text, encoding="utf-8")
            except OSError as e:
                raise UserError(f"--csv {args.csv}: cannot write: {e.strerror}",
                                EXIT_DRIVE) from None
            print(f"{args.csv}: {len(rows)} run(s)")
    elif rows:
        print(R.table(rows))
    else:
        print(f"no runs in {R.store_path(args.runs)} match")
    return EXIT_OK


def _update_index(runs_root: str) -> None:
    """Refresh RUNS/index.html after a run; a failure is one line, never the run's result."""
    from bench._report import write_index

    try:
        print(f"  runs index: {write_index(runs_root)}")
    except Exception as e:  # noqa: BLE001 - the run itself is complete and saved
        print(f"bench: runs index not updated: {e}", file=sys.stderr)


def cmd_report(args: argparse.Namespace) -> int:
    from bench._report import write_index, write_standalone

    standalone = getattr(args, "standalone", None)
    if standalone is not None and args.report_cmd is not None:
        raise UserError(f"bench report {args.report_cmd} --standalone {standalone}: give one "
                        "of them (`bench report index` or `bench report --standalone "
                        "RUN_DIR`)")
    if standalone is not None:
        if args.out is not None and not Path(args.out).parent.is_dir():
            raise UserError(f"--out {args.out}: no such folder {Path(args.out).parent}")
        try:
            out = write_standalone(standalone, args.out)
        except (FileNotFoundError, ValueError) as e:
            raise UserError(f"--standalone {standalone}: {str(e).split(': ', 1)[-1]}"
                            ) from None
        print(f"{out} (standalone: plotly.js embedded, {out.stat().st_size / 1e6:.1f} MB)")
        return EXIT_OK
    if args.out is not None:
        raise UserError(f"--out {args.out}: only with --standalone RUN_DIR")
    if args.report_cmd is None:
        raise UserError("bench report: give what to write: `index` (RUNS/index.html) or "
                        "--standalone RUN_DIR")
    try:
        out = write_index(args.runs)
    except FileNotFoundError:
        raise UserError(f"--runs {args.runs}: no such folder (run 'bench run ...' first, or "
                        "give the folder that holds the run folders)") from None
    n = out.read_text(encoding="utf-8").count("class='pick'")
    print(f"{out} ({n} run(s))")
    return EXIT_OK


def _print_result(r: Any, out: Any, kind: dict[str, Any] | None = None) -> None:
    """The verdict lines of a run: each measured value with its unit, in the motor's
    units (a linear motor's m/s beside an expectation written in r/min)."""
    from bench._report import value_text
    from bench._session import KIND_LABEL
    from bench._units import run_units

    try:
        meta = json.loads((Path(out.run_dir) / "meta.json").read_text(encoding="utf-8"))
    except (OSError, ValueError, TypeError):
        meta = {}
    units = run_units(meta if isinstance(meta, dict) else {})
    sim = ""
    if kind:
        sim = f" [{KIND_LABEL.get(kind.get('drive', 'unknown'), 'UNKNOWN')} drive" + (
            ", fallback: no hardware found]" if kind.get("fallback") else "]")
    print(f"\n{r.sequence}: {'PASSED' if r.passed else 'FAILED'}{sim}  "
          f"(sequence {r.duration_s:.3f} s, wall {r.wall_s:.2f} s)")
    ev = getattr(r, "evidence", None) or {}
    if ev.get("description"):
        print(f"  judged on: {ev['description']}")
    for e in r.expectations:
        m = value_text(units, e.metric, e.measured)
        if not e.judged:
            print(f"  [NOT JUDGED] {e.name}: {e.message}")
            continue
        paper = ""
        if e.paper is not None:
            paper = f"; paper {e.paper:g}: {'reproduced' if e.paper_met else 'NOT reproduced'}"
        print(f"  [{e.status}] {e.name}: {m} (required {e.criterion}{paper})")
    lost = out.logstats.get("lost_frames", {}) or {}
    lost_text = ", ".join(f"{k}: {v}" for k, v in lost.items()) if lost else "none"
    print(f"  CAN frames logged: {out.logstats.get('frames_logged')}, lost frames: "
          f"{lost_text}")
    if out.logstats.get("receive_errors"):
        print(f"  receive-thread errors: {out.logstats['receive_errors']}")
    print(f"  run folder: {out.run_dir}")
    if out.report:
        print(f"  report: {out.report}")


def cmd_live(args: argparse.Namespace) -> int:
    """``bench live``: :func:`bench._session.run_live` (the same code for hardware and the
    simulated drive). Exit 0, 2 bad input (before anything connects), 3 connection error or
    drive fault, 130 interrupted (the drive was disabled first)."""
    import math

    from bench._live import RerunStartError
    from bench._session import run_live

    if not math.isfinite(args.speed):
        raise UserError(f"--speed {args.speed}: not a finite number")
    if not (math.isfinite(args.duration) and 0 <= args.duration <= 86400):
        raise UserError(f"--duration {args.duration}: allowed range [0, 86400] s")
    if args.tui and args.rerun:
        raise UserError("--tui with --rerun: choose one view (the terminal scope or rerun)")
    # bad --rerun: exit 2 before connecting
    spec = None if args.tui else _make_rerun(args.rerun or ["spawn"])
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
    if args.sim:
        args.realtime = True  # live: the in-process simulated drive is paced to the wall clock
    conn = _connect(args)
    try:
        scope = None
        if args.tui:
            from bench._scope import TerminalScope

            scope = TerminalScope(conn.drive, conn.units.pole_pitch_m)
        out = run_live(conn, spec, conn.units.speed_to_mps(args.speed, args.unit),
                       duration_s=args.duration, scope=scope)
    except RerunStartError as e:  # the viewer/server did not start; the drive is disabled
        raise UserError(f"--rerun {spec.mode}: {e}", EXIT_DRIVE) from None
    finally:
        conn.close()
    rec = out.stats.get("recording")
    if rec:
        print(f"  recording: {rec['path']} ({rec['bytes'] / 1e6:.2f} MB, drive time "
              f"{out.drive_time_s:.2f} s)")
    if out.interrupted:
        print("bench: interrupted; drive disabled", file=sys.stderr)
        return EXIT_INTERRUPT
    if out.fault is not None:
        return EXIT_DRIVE
    return EXIT_OK


def cmd_identify(args: argparse.Namespace) -> int:
    """``bench identify``: :func:`bench._identify.identify_drive` (the same code for
    hardware and the simulated drive)."""
    import math

    from bench._identify import IdentifyError, identify_drive

    if not (math.isfinite(args.travel) and 0.05 <= args.travel <= 10.0):
        raise UserError(f"--travel {args.travel}: allowed range [0.05, 10] m")
    if not 1 <= args.starts <= 20:
        raise UserError(f"--starts {args.starts}: allowed range [1, 20]")
    if not re.fullmatch(r"[A-Za-z0-9_.-]{1,64}", args.name):
        raise UserError(f"--name {args.name!r}: 1-64 letters, digits, '_', '.', '-'")
    if args.clamped:
        for flag, on, what in (("--sim-server", getattr(args, "sim_server", False),
                                "the simulated drive server"),
                               ("--emu", getattr(args, "emu", False), "the emulated board")):
            if on:
                raise UserError(f"--clamped with {flag}: {what}'s mover cannot be held from "
                                "the bench (no remote plant lock); use --sim, or a rig with a "
                                "clamp")
    conn = _connect(args)
    try:
        hold = _clamp_fixture(args, conn) if args.clamped else None
        out = identify_drive(conn, runs_root=args.runs, travel_m=args.travel,
                             name=args.name, apply=args.apply, n_starts=args.starts,
                             clamped=args.clamped, hold=hold, ripple=args.ripple)
    except IdentifyError as e:
        raise UserError(f"identify: {e}", EXIT_USAGE) from None
    finally:
        conn.close()
    res = out.result
    if res is not None:
        from bench._identify import QUANTITIES, RIP_QUANTITIES, XSAT_QUANTITIES

        sim = out.truth is not None
        print(f"identified{' [SIMULATED drive]' if sim else ''}: {out.run_dir}")
        shown = {**QUANTITIES, **{k: v for k, v in XSAT_QUANTITIES.items()
                                  if not k.startswith("xsat_axis")},
                 **{k: v for k, v in RIP_QUANTITIES.items() if k.startswith(("rip_", "rip6_"))
                    and not k.startswith("rip_axis")}}
        if "xsat_di_A" not in res.values:
            print("  cross-saturation map not measured (" + (
                "step 7 did not complete" if args.clamped else "step 7 needs --clamped") + ")")
        if args.ripple and "rip6_b0_N" not in res.values:
            print("  position ripple / cogging not measured (steps 8-9 did not complete; see "
                  "the report)")
        for k, (unit, _what) in shown.items():
            if k not in res.values:
                continue
            sig = res.sigma.get(k)
            line = f"  {k:16s} {res.values[k]:12.5g} {unit:6s}" + (
                f" +- {sig:<8.2g}" if sig is not None else " " * 12)
            if sim and out.truth and out.truth.get(k) and k.startswith("xsat_off"):
                line += f"   (closed form {out.truth[k]:.4f}, " \
                        f"{res.values[k] - out.truth[k]:+.4f} rad)"
            elif sim and out.truth and out.truth.get(k):
                line += f"   (simulator truth {out.truth[k]:.5g}, " \
                        f"{100 * (res.values[k] / out.truth[k] - 1):+.2f} %)"
            print(line)
        print(f"  motor file: {out.files['motor']}\n  drive configuration: "
              f"{out.files['config']} ({'applied' if args.apply else 'not applied'})")
    if out.interrupted:
        print("bench: interrupted; drive disabled, configuration restored", file=sys.stderr)
        return EXIT_INTERRUPT
    if out.error is not None:
        tail = "" if "NOT restored" in out.error else (
            "; drive disabled, configuration " + (
                "restored" if "restoring" not in out.error else "NOT restored"))
        print(f"bench: identify: {out.error}{tail} ({out.run_dir})", file=sys.stderr)
        return EXIT_DRIVE if out.drive_error else EXIT_FAIL
    return EXIT_OK


def _clamp_fixture(args: argparse.Namespace, conn: Any) -> Any:
    """``bench identify --clamped``: what holds the mover before step 7. The in-process
    simulated drive: its plant's lock (:func:`sim_fallback.hold_mover`, the fixture's
    action, never read by the probe). A rig: the operator, asked on the terminal once
    steps 1-6 are done and the drive is off (refused up front without a terminal)."""
    if conn.sim is not None:
        from sim_fallback import hold_mover

        def lock() -> bool:
            hold_mover(conn.sim, True)
            print("bench: identify: step 7: the simulated mover is held (plant locked)",
                  file=sys.stderr)
            return True
        return lock
    if not sys.stdin.isatty():
        raise UserError("--clamped on a drive needs an operator at the terminal to confirm "
                        "the clamp before step 7 (stdin is not a terminal); nothing was moved")
    from bench._identify import _cfg_view, peak_thrust_N

    peak = peak_thrust_N(_cfg_view(conn.drive))

    def ask() -> bool:
        print(f"bench: identify: steps 1-6 done, the drive is off. Step 7 applies thrust up "
              f"to {peak:.0f} N in both directions: clamp or brake the mover now so that it "
              "holds that, then press Enter ('skip' + Enter skips the step, Ctrl-C stops)",
              file=sys.stderr)
        try:
            ans = input()
        except EOFError:
            return False
        return ans.strip().lower() not in ("skip", "s", "n", "no")
    return ask


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
    from bench._drive import COMMUNICATION_AREA, ParamError, ParamInputError, param_table

    if args.action not in ("get", "set", "list"):
        raise UserError("param: choose get, set or list (see bench param --help)")
    if args.action == "list":
        conn = None if args.offline else _connect(args)
        try:
            seen = set()
            for p in param_table().values():
                if p.address in seen or (not args.all and p.index in COMMUNICATION_AREA):
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

    if args.action not in ("backup", "restore", "save", "defaults"):
        raise UserError("config: choose backup, restore, save or defaults (see bench config "
                        "--help)")
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
        if args.action in ("save", "defaults") and conn.is_sim:
            raise UserError("the in-process simulated drive (--sim) has no non-volatile "
                            "memory: start the simulated drive server (`bench sim start`) "
                            "and use --sim-server", EXIT_DRIVE)
        if args.action == "save":
            d.save_config()
            print("bench: configuration stored in the drive's non-volatile memory (loaded at "
                  "power-up and NMT reset node)")
            return EXIT_OK
        if args.action == "defaults":
            d.erase_saved_config()
            print("bench: stored configuration erased; the defaults apply from the next NMT "
                  "reset node or power-up")
            return EXIT_OK
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


def cmd_shell(args: argparse.Namespace) -> int:
    try:
        import IPython  # noqa: F401 - checked before connecting
    except ImportError:
        raise UserError("bench shell needs IPython: python3 -m pip install ipython") from None
    from bench import _shell

    if args.sim:
        args.realtime = True  # the simulated drive runs while the user types
    conn = _connect(args)
    conn.start_heartbeat()  # a shell that dies stops the drive (consumer heartbeat)
    return _shell.start(conn, args.runs)


def _status_or_stop(action: str, mod: Any, error: type[Exception], alive: Any, what: str,
                    pid_word: str, describe: Any) -> int:
    """``bench sim|emu status|stop``: a background process and its state file (``mod``:
    sim_fallback.server or sim_fallback.emu). Status of none or a dead one: exit 3, one
    line (a stale state file is removed)."""
    if action == "status":
        try:
            st = mod.check_running()
        except error as e:
            stale = mod.read_state()
            if stale is not None and not alive(stale.pid):
                mod.stop()  # removes the stale state file
            raise UserError(str(e), EXIT_DRIVE) from None
        print(describe(st))
        return EXIT_OK
    how, pid = mod.stop()
    print({"none": f"bench: no {what} running",
           "stale": f"bench: removed a stale state file ({pid_word} {pid} was not running)",
           "stopped": f"bench: {what} stopped ({pid_word} {pid})",
           "killed": f"bench: {what} killed ({pid_word} {pid}: no exit within 5 s of "
                     "SIGTERM)"}[how])
    return EXIT_OK


def cmd_sim(args: argparse.Namespace) -> int:
    """``bench sim start|stop|status``; a state folder that cannot be used is one line,
    exit 2 (a regular file on its path, ...) or 3 (the system refuses it): its
    ``SetupError`` carries the code, which :func:`exit_code_for` keeps."""
    from sim_fallback import server as S

    if args.sim_cmd in ("status", "stop"):
        return _status_or_stop(args.sim_cmd, S, S.SimServerError, S.pid_is_server,
                               "simulated drive server", "pid", S.describe)
    if not 1 <= args.node_id <= 127:
        raise UserError(f"--node-id {args.node_id}: allowed range [1, 127]")
    if not 0 <= args.port <= 65535:
        raise UserError(f"--port {args.port}: allowed range [0, 65535] (0: any free port)")
    if args.seed < 0:
        raise UserError(f"--seed {args.seed}: allowed range >= 0")
    _check_motor(args.motor, args.extractor, f"--motor {args.motor}", sim_only=True)
    try:
        st = S.start(args.motor, args.extractor, args.seed, args.node_id, args.port,
                     say=lambda m: print(m, file=sys.stderr))
    except S.AlreadyRunning as e:
        raise UserError(str(e)) from None
    except S.SetupError:
        raise  # its own exit code (exit_code_for)
    except S.SimServerError as e:
        raise UserError(str(e), EXIT_DRIVE) from None
    print(S.describe(st))
    return EXIT_OK


def cmd_emu(args: argparse.Namespace) -> int:
    """``bench emu start|stop|status``."""
    import math

    from sim_fallback import emu as E

    if args.emu_cmd in ("status", "stop"):
        return _status_or_stop(args.emu_cmd, E, E.EmuError, E.pid_is_emu, "emulated board",
                               "QEMU pid", lambda st: E.describe(st, not args.no_measure))
    if not 1 <= args.node_id <= 127:
        raise UserError(f"--node-id {args.node_id}: allowed range [1, 127]")
    if args.seed < 0:
        raise UserError(f"--seed {args.seed}: allowed range >= 0")
    if not (math.isfinite(args.x0) and abs(args.x0) <= 1000.0):
        raise UserError(f"--x0 {args.x0}: allowed range [-1000, 1000] m")
    _check_motor(args.motor, args.extractor, f"--motor {args.motor}", sim_only=True)
    if args.plant:
        try:
            from sim_fallback import load_motor

            load_motor(args.plant)
        except Exception as e:  # noqa: BLE001 - unknown name, broken file: one line
            raise UserError(f"--plant {args.plant}: {' '.join(str(e).split())}") from None
    try:
        st = E.start(args.motor, args.extractor, args.seed, args.node_id, args.x0,
                     plant_motor=args.plant, ref_sensor=not args.no_ref_sensor,
                     image=args.image, say=lambda m: print(m, file=sys.stderr))
    except E.AlreadyRunning as e:
        raise UserError(str(e)) from None
    except E.EmuError as e:  # the user's choice it cannot run (EmuRefused): 2; else 3
        raise UserError(str(e), getattr(e, "exit_code", EXIT_DRIVE)) from None
    except ValueError as e:  # the boot block: a value it cannot hold
        raise UserError(f"bench emu start: {e}") from None
    print(E.describe(st))
    return EXIT_OK


def cmd_flash(args: argparse.Namespace) -> int:
    """``bench flash IMAGE``: :func:`bench._flash.flash`, checked over CANopen."""
    import math

    from bench._flash import flash
    from bench._session import NoHardware, bus_args, open_bus

    if not 1 <= args.node_id <= 127:
        raise UserError(f"--node-id {args.node_id}: allowed range [1, 127]")
    if not (math.isfinite(args.timeout) and 0.1 <= args.timeout <= 600):
        raise UserError(f"--timeout {args.timeout}: allowed range [0.1, 600] s")
    bus = None
    if not args.no_check:
        kw = bus_args(args.interface, args.channel, args.bitrate)
        if kw is None:
            raise UserError("flash: no CAN bus to check the drive on after its reboot: "
                            "give --interface/--channel (or python-can's configuration), "
                            "or --no-check to program only")
        try:
            bus, _ = open_bus(kw)
        except NoHardware as e:
            raise UserError(f"flash: {e}", EXIT_DRIVE) from None
    try:
        res = flash(args.image, bus, node_id=args.node_id, tool=args.tool, probe=args.probe,
                    board=args.board, timeout_s=args.timeout)
    finally:
        if bus is not None:
            bus.shutdown()
    print(res.message, file=sys.stdout if res.ok else sys.stderr)
    return int(res.code)


def cmd_compare(args: argparse.Namespace) -> int:
    """``bench compare RUN_A RUN_B``: :func:`bench._compare.compare`."""
    from bench._compare import CompareError, compare

    try:
        rc, text, _ = compare(args.run_a, args.run_b, args.tol, args.out)
    except CompareError as e:
        raise UserError(str(e)) from None
    print(text)
    return EXIT_OK if rc == 0 else EXIT_FAIL


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
    from simcampaign import cmd

    return cmd(args)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``bench`` console script."""
    ap = build_parser()
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING - 10 * min(args.verbose, 2),
                        format="%(levelname)s %(name)s: %(message)s")
    if not args.verbose:
        logging.getLogger("canopen").setLevel(logging.ERROR)
        # python-can's interfaces warn about optional libraries at import (e.g. pcan's
        # "uptime library not available"): not the user's business unless -v
        logging.getLogger("can").setLevel(logging.ERROR)
        # python-can's periodic senders (SYNC, heartbeat) log a traceback per failed send
        # when the bus is gone; the run's result names the lost drive in one line
        logging.getLogger("can.bcm").setLevel(logging.CRITICAL)
        # python-can's socketcand client warns for every frame split across two TCP reads
        logging.getLogger("can.interfaces.socketcand").setLevel(logging.ERROR)
    _quiet_thread_errors(args.verbose > 0)
    if args.cmd is None:
        ap.print_help()
        return EXIT_USAGE
    _sigterm_as_interrupt()
    handlers = {"run": cmd_run, "validate": cmd_validate, "live": cmd_live, "info": cmd_info,
                "identify": cmd_identify,
                "param": cmd_param, "config": cmd_config, "faults": cmd_faults,
                "campaign": _campaign_cmd, "report": cmd_report, "sim": cmd_sim,
                "emu": cmd_emu, "compare": cmd_compare, "flash": cmd_flash,
                "shell": cmd_shell, "results": cmd_results}
    try:
        return handlers[args.cmd](args)
    except Exception as e:  # noqa: BLE001 - every exit code is decided in exit_code_for
        code, line = exit_code_for(e)
        if code == EXIT_INTERNAL:
            return _internal_error(e, getattr(args, "runs", "runs"))
        print(f"bench: {line}", file=sys.stderr)
        return code
    except KeyboardInterrupt:
        print("bench: interrupted", file=sys.stderr)
        return EXIT_INTERRUPT


def exit_code_for(e: BaseException) -> tuple[int, str]:
    """The one place an exception that ends a command becomes its exit code and line
    (the table in docs/bench.md): a :class:`UserError` carries its code; the drive or its
    bus failing (a refused command, a fault, a lost drive, the drive switched by another
    master, a CAN or SDO error, a refused connection) is 3; Ctrl-C / SIGTERM is 130;
    anything else is a bug, 4."""
    if isinstance(e, KeyboardInterrupt):
        return EXIT_INTERRUPT, "interrupted"
    if isinstance(e, UserError):
        return e.code, str(e)
    drv = sys.modules.get("bench._drive")
    if drv is not None and isinstance(e, drv.ParamInputError):  # a parameter the user gave
        return EXIT_USAGE, str(e)
    own = getattr(e, "exit_code", None)  # an error that knows whose it is (SetupError)
    if own in (EXIT_USAGE, EXIT_DRIVE):
        return own, " ".join(str(e).split())
    # what was never imported cannot have been raised: look the classes up, not import
    drive_errors = (ConnectionError, *(
        cls for mod, name in (("bench._drive", "DriveError"),
                              ("canopen.sdo.exceptions", "SdoError"), ("can", "CanError"))
        if (cls := getattr(sys.modules.get(mod), name, None)) is not None))
    if isinstance(e, drive_errors):
        return EXIT_DRIVE, " ".join(str(e).split()) or type(e).__name__
    return EXIT_INTERNAL, " ".join(f"{type(e).__name__}: {e}".split())


def console_main() -> int:
    """The ``bench`` console script and ``python -m bench``: :func:`main`, then the
    process ends, so what is left needs no collection (the interpreter's final
    collection of a run's objects costs 50-100 ms). Not for in-process callers."""
    _guard_console()
    rc = main()
    gc.freeze()
    sys.stdout.flush()
    return rc


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
