"""``bench shell``: an IPython session with a connected drive.

Names in the session::

    drive                 Shell: the connected drive (hardware, --sim or --sim-server)
    drive.p.<TAB>         every object-dictionary parameter by name; reading one reads the
                          drive (the value shows its unit, address and range), assigning
                          writes it (numbers or text with a unit, checked like
                          ``bench param set``); ``drive.p.u_inj_V?`` shows the documentation
    drive.enable("speed"), drive.speed(0.1), drive.speed(100, "r/min"), drive.force(20),
    drive.disable(), drive.state, drive.actual(), drive.faults(), drive.reset_faults(),
    drive.save_config()
    drive.live("spawn")   stream the decoded telemetry to rerun while you type
                          (``"save"``, ``"serve"``, ``"connect"`` as ``--rerun``);
                          ``drive.live_stop()`` ends it
    steps = drive.stepper("sequences/paper_load_step.yaml"); next(steps)
                          one sequence step per ``next()``; ``steps.close()`` (or the end of
                          the sequence) puts the drive in its safe state; ``drive.last_result``
    conn                  the bench Connection (``conn.drive`` is :class:`bench.Drive`)

The simulated drive follows the wall clock in a shell (it runs while you type). Leaving the
shell disables the drive and closes the connection.
"""

from __future__ import annotations

import keyword
import math
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from canopen.sdo.exceptions import SdoError

from bench._drive import DriveError, Param
from bench._sequence import SequenceError


def ident(name: str) -> str:
    """A parameter name as a Python attribute: ``u_inj_V`` stays, ``Injection.Amplitude``
    -> ``Injection_Amplitude``, ``Target velocity`` -> ``Target_velocity``."""
    s = re.sub(r"\W+", "_", name).strip("_")
    if not s or s[0].isdigit() or keyword.iskeyword(s):
        s = "p_" + s
    return s


def _describe(p: Param) -> str:
    rng = ""
    if p.min is not None or p.max is not None:
        rng = f", range [{p.min}, {p.max}]"
    return (f"{p.name} ({p.address}, {p.type}, {p.access}{', unit ' + p.unit if p.unit else ''}"
            f"{rng}){': ' + p.doc if p.doc else ''}")


def value_of(v: Any, p: Param) -> Any:
    """The drive's value, still a number (or text), whose repr and ``?`` show the
    parameter's unit, address and range."""
    base: type = str if isinstance(v, str) else float if isinstance(v, float) else int
    cls = type(f"{base.__name__}Param", (base,), {
        "__doc__": _describe(p),
        "__repr__": lambda self: (f"{base.__repr__(self)} {p.unit}".rstrip()
                                  + f"  # {p.name} {p.address}"),
        "param": p})
    return cls(v)


class Params:
    """``drive.p``: the drive's parameters as attributes (tab completion lists them)."""

    def __init__(self, drive: Any) -> None:
        by: dict[str, Param] = {}
        for p in drive.params.values():
            by.setdefault(ident(p.name), p)
        object.__setattr__(self, "_drive", drive)
        object.__setattr__(self, "_by", by)

    def __dir__(self) -> list[str]:
        return sorted(self._by) + ["table"]

    def _param(self, name: str) -> Param:
        p = self._by.get(name)
        if p is None:
            from bench._drive import ParamInputError

            near = sorted(k for k in self._by if name.lower() in k.lower())[:6]
            raise ParamInputError(f"no parameter {name!r}" + (
                f"; did you mean: {', '.join(near)}" if near else "; drive.p.<TAB> lists them"))
        return p

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        p = self._param(name)
        v, _ = self._drive.get(p.address)
        return value_of(v, p)

    def __setattr__(self, name: str, value: Any) -> None:
        p = self._param(name)
        self._drive.set(p.address, value)

    def table(self, pattern: str = "") -> str:
        """Every parameter matching ``pattern`` (case-insensitive) with its present value
        (read from the drive), unit, access and range."""
        rows = []
        for k, p in sorted(self._by.items()):
            if pattern.lower() not in k.lower():
                continue
            if "r" in p.access or p.access == "const":
                try:
                    v = self._drive.read_raw(p.index, p.sub)
                    val = f"{v:.6g}" if isinstance(v, float) else str(v)
                except Exception:  # noqa: BLE001 - shown as unreadable, the table goes on
                    val = "(unreadable)"
            else:
                val = "(write-only)"
            rng = ("" if p.min is None and p.max is None else
                   f"[{'' if p.min is None else p.min}, {'' if p.max is None else p.max}]")
            rows.append(f"{k:<34} {p.address:>9}  {val:>12} {p.unit:<8} {p.access:<5} {rng}")
        return "\n".join(rows)

    def __repr__(self) -> str:
        return (f"<{len(self._by)} drive parameters: drive.p.<TAB>, drive.p.NAME? for the "
                "documentation, print(drive.p.table('inj')) for a list>")


def _finite(value: Any, call: str, what: str) -> None:
    """A number the shell sends: finite, else a one-line ValueError naming the call."""
    if not isinstance(value, (int, float)) or not math.isfinite(float(value)):
        raise ValueError(f"{call}: not a finite number ({what})")


class _Speed(float):
    """A speed in m/s that says so when shown (``drive.speed(100, "r/min")`` -> 0.32 m/s)."""

    def __repr__(self) -> str:
        return f"{float(self):.6g} m/s"


class Shell:
    """The ``drive`` object of ``bench shell`` (see the module documentation)."""

    def __init__(self, conn: Any, runs_root: str = "runs") -> None:
        self.conn = conn
        self.d = conn.drive
        self.units = conn.units
        self.p = Params(conn.drive)
        self.runs_root = runs_root
        self.last_result: Any = None
        self._live: Any = None
        self._tap: Any = None
        self._said = ""
        self._speed_mps = 0.0

    def _watch(self) -> str:
        """What happened to the drive since the last command (Drive.check, the bench's
        one watch: a fault, switched off by another master, lost), said once on stderr."""
        import sys

        try:
            self.d.check()
        except DriveError as e:
            msg = " ".join(str(e).split())
            if msg != self._said:
                print(f"bench: {msg}", file=sys.stderr)
                self._said = msg
            return msg
        self._said = ""
        return ""

    # ---- state and set-points ----------------------------------------------------------
    @property
    def state(self) -> str:
        """CiA 402 state (from the statusword)."""
        self._watch()
        return self.d.state

    def enable(self, mode: str = "speed") -> str:
        """Enable the power stage in ``speed`` or ``force`` mode."""
        self._watch()
        self.d.enable(mode)
        return self.d.state

    def disable(self) -> str:
        self.d.disable()
        return self.d.state

    def speed(self, value: float, unit: str = "m/s") -> float:
        """Speed set-point in ``unit`` (m/s by default; mm/s, r/min); returns what was
        sent, in m/s (shown with its unit)."""
        _finite(value, f"drive.speed({value!r})", f"a speed in {unit}")
        v = self.units.speed_to_mps(float(value), unit)
        self._watch()
        self.d.set_speed_mps(v)
        self._speed_mps = v
        return _Speed(v)

    def scope(self, seconds: float = 10.0) -> str:
        """The terminal scope of ``bench live --tui`` for ``seconds`` of drive time (Ctrl-C
        ends it sooner): state, fault, speed against its reference, position, thrust and
        the estimate against the reference sensor, from the TPDOs; the drive runs on as it
        is."""
        from bench._scope import TerminalScope

        sc = TerminalScope(self.d, self.units.pole_pitch_m)
        sc.speed_ref_mps = self._speed_mps
        clock = self.d.clock
        t0 = clock.now()
        sc.start()
        try:
            while clock.now() - t0 < seconds:
                self.d.wait_until(clock.now() + 0.1)
                sc.sample(clock.now() - t0)
                sc.draw()
        except KeyboardInterrupt:
            pass
        finally:
            sc.close()
        return sc.status()

    def force(self, force_N: float) -> None:
        """Force set-point (N, force mode)."""
        self._watch()
        self.d.set_force_N(float(force_N))

    def load(self, force_N: float) -> str:
        """The load machine's force (N; the simulated drive's plant load, or a load drive
        on the bus given with ``--load-node``); 0 removes it. Leaving the shell removes it
        too."""
        _finite(force_N, f"drive.load({force_N!r})", "a force in N")
        ld = self.conn.load
        if getattr(ld, "name", "none") == "none":
            raise ValueError("drive.load: no load machine on this connection (the in-process "
                             "simulated drive has one, --sim; a rig's load drive: "
                             "--load-node N)")
        self._watch()
        if force_N:
            ld.enable()
        ld.set_force_N(float(force_N))
        return f"load {float(force_N):g} N ({ld.name})"

    def actual(self) -> dict[str, float]:
        """Estimated position, speed, force (what the drive reports)."""
        self._watch()
        return self.d.actual()

    def faults(self) -> dict[str, Any]:
        return self.d.faults()

    def reset_faults(self) -> str:
        return self.d.reset_faults()

    def save_config(self) -> None:
        """Store the running configuration in the drive (CiA 301 0x1010)."""
        self.d.save_config()

    # ---- sequences one step at a time ---------------------------------------------------
    def stepper(self, path: str | Path) -> Iterator[Any]:
        """Run a sequence file one step per ``next()`` (each returns the step done).

        The drive goes to its safe state when the sequence ends or the iterator is closed;
        ``drive.last_result`` then holds the run's result (expectations, verdict). Nothing
        is logged: ``bench run`` records and reports.
        """
        from bench._runner import Runner
        from bench._sequence import load_sequence

        seq = load_sequence(path)
        # without the control rate, trace steps only mark their window
        runner = Runner(self.d, self.units, self.conn.load,
                        f_pwm_Hz=self.conn.control_rate_Hz())

        def gen() -> Iterator[Any]:
            try:
                yield from runner.iter_steps(seq)
            finally:
                self.last_result = getattr(runner, "result", None)

        return gen()

    # ---- live telemetry -----------------------------------------------------------------
    def live(self, *rerun: str) -> str:
        """Stream the decoded telemetry (and the simulator's truth) to rerun while the
        session goes on; arguments as ``--rerun`` (default ``spawn``)."""
        from bench._live import parse_rerun_spec
        from bench._logging import run_dir_for
        from bench._session import LiveTap, open_live

        if self._live is not None:
            return "live telemetry already running (drive.live_stop() ends it)"
        spec, rest = parse_rerun_spec(list(rerun) or ["spawn"])
        if rest:
            raise ValueError(f"drive.live{tuple(rerun)}: unexpected {rest[0]!r}")
        run_dir = run_dir_for("shell", self.runs_root) if spec.path is None else None
        self._live = open_live(spec, self.conn, run_dir, "shell")
        self._tap = LiveTap(self.conn, self._live.feed)
        return f"live telemetry -> {self._live.sink.path}"

    def live_stop(self) -> dict[str, Any] | None:
        """End live telemetry; its statistics (drops, latency, recording size)."""
        from bench._session import close_live

        if self._live is None:
            return None
        if self._tap is not None:
            self._tap.close()
            self._tap = None
        live, self._live = self._live, None
        return close_live(live)

    def close(self) -> None:
        """Safe state, end live telemetry, close the connection."""
        import sys

        try:
            try:
                self.conn.load.set_force_N(0.0)
                self.conn.load.disable()
            except Exception as e:  # noqa: BLE001 - said; the drive is disabled regardless
                print(f"bench: load not removed: {' '.join(str(e).split())}", file=sys.stderr)
            self.d.disable()
            print("bench: drive disabled", file=sys.stderr)
        except Exception as e:  # noqa: BLE001 - said, then the connection still closes
            print(f"bench: SAFE STATE FAILED: {' '.join(str(e).split())}", file=sys.stderr)
        finally:
            try:
                self.live_stop()
            finally:
                self.conn.close()

    def __repr__(self) -> str:
        return (f"<drive: {self.conn.description}; state {self.d.state}; drive.p.<TAB> for "
                "parameters, help(drive) for the rest>")


BANNER = """bench shell: `drive` is connected ({desc}).
  drive.p.<TAB>  parameters (drive.p.u_inj_V, drive.p.u_inj_V = 25, drive.p.u_inj_V?)
  drive.enable(); drive.speed(0.1); drive.actual(); drive.disable(); drive.faults()
  drive.live()   telemetry to rerun while you type; drive.live_stop()
  drive.scope(5) a scope in this terminal for 5 s (no display needed)
  drive.load(20) the load machine's force in N (simulated drive, --load-node)
  steps = drive.stepper("sequences/paper_load_step.yaml"); next(steps)
Leaving the shell (exit) disables the drive.
"""


#: what the shell shows as one line (its message) instead of a traceback
USER_ERRORS: tuple[type[BaseException], ...] = (DriveError, SdoError, SequenceError, ValueError)


def one_line_error(shell: Any, etype: type, value: BaseException, tb: Any,
                   tb_offset: Any = None) -> None:
    """IPython's handler for :data:`USER_ERRORS`: ``bench: <message>`` on one line."""
    import sys

    msg = " ".join(str(value).split()) or etype.__name__
    print(f"bench: {msg}", file=sys.stderr)
    return None


def namespace(conn: Any, runs_root: str = "runs") -> dict[str, Any]:
    """The session's names (also what the tests use)."""
    sh = Shell(conn, runs_root)
    return {"drive": sh, "conn": conn}


def start(conn: Any, runs_root: str = "runs") -> int:
    """Run IPython with :func:`namespace` until the user leaves; then the safe state."""
    import IPython
    from traitlets.config import Config

    ns = namespace(conn, runs_root)
    shell = ns["drive"]  # IPython clears its namespace on exit
    cfg = Config()
    cfg.TerminalInteractiveShell.banner1 = BANNER.format(desc=conn.description)
    cfg.TerminalInteractiveShell.confirm_exit = False
    cfg.HistoryManager.enabled = False  # no sqlite history file in the user's home
    # a user's mistake (a value out of range, a unit, a refused command) is one line, not
    # a traceback through canopen's internals
    ns["_bench_one_line"] = (USER_ERRORS, one_line_error)
    cfg.InteractiveShellApp.exec_lines = [
        "get_ipython().set_custom_exc(*_bench_one_line); del _bench_one_line"]
    try:
        IPython.start_ipython(argv=["--no-autoindent"], user_ns=ns, config=cfg)
    finally:
        shell.close()
    return 0
