"""``bench identify``: the drive measures the motor it is connected to.

The procedure is :func:`identification.run_identification` (one implementation;
docs/identify.md); here it runs on a drive over the wire, through :class:`WireProbe`:
CiA 402 commands, configuration and the d-axis current reference (0x2080:1) over SDO,
the measured inductances of each standstill start from 0x2080:2/3, and everything else
from the serial telemetry at 1 kHz. The same code runs on hardware and on the simulated
drive; on the simulated drive the plant's truth is added to the report, never used.

The drive is left as it was found: the configuration read at the start is written back
at the end (also after a fault or Ctrl-C), unless ``apply`` asks for the identified one.

Step 7 (``clamped``, ``bench identify --clamped``): the cross-saturation map
(:func:`identification.run_cross_saturation`) after the usual steps, on a mover held by a
clamp or a brake (``hold``: the operator's confirmation, or on the simulated drive the
plant's lock, the fixture's action). The thrust current goes to the drive as the CiA 402
target torque (0x6071, per mille of ``i_max_A`` in FORCE mode); the position estimate comes
from the telemetry, the speed estimate for the safety check from the TPDO (0x606C). A mover
that moves stops the step (:class:`identification.MoverMoved`); steps 1-6 are kept.

Steps 8 and 9 (``ripple``, ``bench identify --ripple``): the position ripple of the HF
axis (:func:`identification.run_ripple`, docs/method.md section 6) and the cogging thrust
at 6 theta (:func:`identification.run_thrust_ripple`, section 5) on a FREE mover, after
steps 1-6 and before step 7: constant-speed passes there and back within ``travel_m``,
with the identified configuration (its K_F, mass and friction), no position sensor. A
fault stops them; what was measured before is kept.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from identification import (
    IDENT_RESTORED,
    PROBE_SIGNALS,
    RIP6_FIELDS,
    RIP_ORDERS,
    START_WINDOWS,
    XSAT_POINTS,
    Identified,
    Probe,
    ident_overrides,
    rip_fields,
    run_cross_saturation,
    run_identification,
    run_ripple,
    run_thrust_ripple,
)
from protocols.generated import od_names as od
from protocols.generated.od_names import StartPhase
from protocols.units import force_constant_N_per_A
from sim_fallback import truth_of

#: Telemetry signals the probe asks for (one frame per millisecond).
TEL_SIGNALS = (*PROBE_SIGNALS, "fault_code", "start_phase")
#: The telemetry frame period the probe sets (s).
TEL_PERIOD_S = 1e-3


#: Units and descriptions of the identified values (report and motor file).
QUANTITIES: dict[str, tuple[str, str]] = {
    "R_ohm": ("ohm", "phase resistance"),
    "L_d_H": ("H", "d-axis inductance at zero current"),
    "L_q_H": ("H", "q-axis inductance"),
    "dL_sat_H": ("H", "d-axis saturation depth (L_d0 - L_d at large |i_d|)"),
    "I_sat_A": ("A", "d-axis saturation current"),
    "psi_f_Wb": ("Wb", "magnet flux linkage"),
    "mass_kg": ("kg", "mover mass"),
    "b_visc_Ns_per_m": ("N s/m", "viscous friction"),
    "F_coulomb_N": ("N", "Coulomb friction"),
}

#: The cross-saturation map (step 7, ``--clamped``; object 0x2057): value -> unit, what.
XSAT_QUANTITIES: dict[str, tuple[str, str]] = {
    "xsat_di_A": ("A", "cross-saturation map step (points at 1..6 x)"),
    **{f"xsat_off{k}_rad": ("rad", f"cross-saturation HF angle-error offset at {k} x step")
       for k in range(1, XSAT_POINTS + 1)},
    **{f"xsat_axis{k}_rad": ("rad", f"HF axis turn measured at {k} x step (map off)")
       for k in range(1, XSAT_POINTS + 1)}}

#: The position-ripple correction (step 8, ``--ripple``; object 0x2057): value -> unit, what.
RIP_QUANTITIES: dict[str, tuple[str, str]] = {
    **{name: ("rad", f"position-ripple correction, {name[4]} coefficient at {name[5]} theta")
       for name in rip_fields([0.0] * 2 * len(RIP_ORDERS))},
    **{name.replace("rip_", "rip_axis_"): ("rad", f"HF axis ripple measured, {name[4]} "
                                                  f"coefficient at {name[5]} theta")
       for name in rip_fields([0.0] * 2 * len(RIP_ORDERS))},
    "rip_slope": ("", "slope of the HF error per radian of axis ripple"),
    "rip6_a0_N": ("N", "cogging thrust at 6 theta, cos coefficient"),
    "rip6_b0_N": ("N", "cogging thrust at 6 theta, sin coefficient")}

#: Identified value -> drive configuration field (fw_config_t, the OD parameter name). The
#: map's and the ripple's fields only when steps 7 and 8 measured them (else the drive's
#: stay as they were).
CONFIG_FIELDS = {"R_ohm": "R_ohm", "L_d_H": "L_d_H", "L_q_H": "L_q_H", "psi_f_Wb": "psi_f_Wb",
                 "mass_kg": "mass_kg", "b_visc_Ns_per_m": "visc_Ns_per_m",
                 "F_coulomb_N": "coulomb_N", "xsat_di_A": "xsat_di_A",
                 **{f"xsat_off{k}_rad": f"xsat_off{k}_rad" for k in range(1, XSAT_POINTS + 1)},
                 **{k: k for k in rip_fields([0.0] * 2 * len(RIP_ORDERS))},
                 **{k: k for k in RIP6_FIELDS}}


class IdentifyError(RuntimeError):
    """Identification stopped (a drive fault, no closed loop, no telemetry): one line."""


class WireProbe(Probe):
    """:class:`identification.Probe` over CANopen + the serial telemetry link.

    ``logger`` (a :class:`bench._logging.RunLogger`) receives the telemetry as
    ``tel.<signal>`` (the reader thread appends it); windows are cut on the drive's own
    time base (control steps), so the bench's clock and SDO latency do not matter.
    """

    def __init__(self, conn: Any, logger: Any, wait_s: float = 2.0,
                 i_max_A: float | None = None) -> None:
        self.conn = conn
        self.drive = conn.drive
        self.clock = conn.drive.clock
        self.logger = logger
        self.wait_s = wait_s
        #: the drive's i_max_A: 1000 per mille of the target torque in FORCE mode (set_iq)
        self.i_max_A = i_max_A
        self._speed: list[float] = []  # speed estimates (m/s) from the TPDO, not yet returned
        self._speed_lock = threading.Lock()
        self._speed_maps: list[Any] = []

    # ---- the speed estimate from the TPDO (step 7's safety check) --------------------
    def watch_speed(self) -> bool:
        """Collect the drive's speed estimate (velocity actual value 0x606C) from the TPDO
        that carries it (SYNC-triggered: every millisecond on the simulated drive, every
        SYNC period on a rig); :meth:`run` then adds ``speed_hat_mps``: every sample
        received since the last window. False if no enabled TPDO maps it."""
        e = od.VELOCITY_ACTUAL_VALUE
        for tpdo in self.drive.node.tpdo.values():
            if tpdo.enabled and any(v.index == e.index and v.subindex == e.sub for v in tpdo):
                tpdo.add_callback(self._on_speed)
                self._speed_maps.append(tpdo)
        self.conn.start_sync()  # a rig's TPDOs are SYNC-triggered (idempotent)
        return bool(self._speed_maps)

    def unwatch_speed(self) -> None:
        for tpdo in self._speed_maps:
            if self._on_speed in tpdo.callbacks:
                tpdo.callbacks.remove(self._on_speed)
        self._speed_maps = []

    def _on_speed(self, pdo_map: Any) -> None:
        from bench._units import wire_to_si

        e = od.VELOCITY_ACTUAL_VALUE
        for v in pdo_map:
            if v.index == e.index and v.subindex == e.sub:
                val = float(wire_to_si(e, int(v.raw)))
                with self._speed_lock:
                    self._speed.append(val)

    # ---- telemetry windows ----------------------------------------------------------
    def _t_last(self) -> float:
        t, _ = self.logger.channel("tel.fault_code")
        return float(t[-1]) if t.size else -math.inf

    def _await(self, t_end: float) -> None:
        """Until the bench has read telemetry up to ``t_end``. A link that stops is an
        error after :attr:`wait_s` without progress; a reader that is behind but reading
        (a busy host) is waited for."""
        last = self._t_last()
        deadline = time.monotonic() + self.wait_s
        while last < t_end - 1e-6:
            if time.monotonic() > deadline:
                raise IdentifyError(f"no telemetry up to t = {t_end:.3f} s on the serial "
                                    f"link (last {last:.3f} s, none for {self.wait_s:g} s)")
            time.sleep(0.001)
            now = self._t_last()
            if now > last:
                last, deadline = now, time.monotonic() + self.wait_s

    def _window(self, t0: float, t1: float) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        for s in TEL_SIGNALS:
            t, v = self.logger.channel("tel." + s)
            k = (t > t0 + 1e-9) & (t <= t1 + 1e-9)
            out[s] = np.asarray(v[k], dtype=np.float64)
        n = {a.size for a in out.values()}
        if len(n) != 1:
            raise IdentifyError(f"telemetry signals of unequal length in [{t0:.3f}, {t1:.3f}] "
                                "s (frames lost on the serial link)")
        codes = out["fault_code"][out["fault_code"] != 0]
        if codes.size:
            from bench._drive import DriveFault, fault_text

            raise DriveFault(f"drive fault {fault_text(int(codes[0]))} during "
                             "identification", int(codes[0]))
        if self._speed_maps:
            with self._speed_lock:
                got, self._speed = self._speed, []
            out["speed_hat_mps"] = np.asarray(got, dtype=np.float64)
        return out

    def run(self, seconds: float) -> dict[str, np.ndarray]:
        # the window is cut on the drive's clock, where the command that precedes it took
        # effect; not at the last telemetry sample the bench has read, which lags the
        # drive by however busy the host is (and would make the result depend on it)
        t0 = self.clock.now()
        self._settle(t0 + seconds)
        return self._window(t0, t0 + seconds)

    def _settle(self, t_end: float) -> None:
        """Wait until the drive's clock is past ``t_end`` by two telemetry frames (the
        frame that covers ``t_end`` is sent after it), then until the bench has read
        telemetry up to it."""
        self.drive.wait_until(t_end + 2 * TEL_PERIOD_S)
        self._await(t_end)

    # ---- commands ---------------------------------------------------------------------
    def _enable_force(self) -> None:
        d = self.drive
        d.enable("force")
        d.set_force_N(0.0)
        self.id_ref_A = 0.0
        # The start-up (alignment, polarity, saliency check) takes about 0.1 s of drive
        # time. A window begins at the last telemetry sample the bench has, which lags
        # the drive when the host is busy: wait for RUN over up to START_WINDOWS windows
        # of drive time instead of judging the first one alone.
        for _ in range(START_WINDOWS):
            r = self.run(0.15)
            if r["start_phase"].size and int(r["start_phase"][-1]) == StartPhase.RUN:
                return
        raise IdentifyError(f"start-up did not reach closed loop in {0.15 * START_WINDOWS:.2f} s"
                            " of drive time")

    def standstill_start(self, k: int) -> tuple[float, float]:
        self._enable_force()
        small = float(self.drive.read(od.IDENTIFICATION__MEASURED_SMALLER_INDUCTANCE))
        large = float(self.drive.read(od.IDENTIFICATION__MEASURED_LARGER_INDUCTANCE))
        self.drive.disable()
        self.run(0.02)
        return small, large

    def start(self) -> None:
        self._enable_force()

    def set_id(self, amps: float) -> None:
        self.drive.write(od.IDENTIFICATION__D_AXIS_CURRENT_REFERENCE, float(amps))

    def set_iq(self, amps: float) -> None:
        """The thrust current as the CiA 402 target torque (0x6071): in FORCE mode the
        drive takes it as per mille of its i_max_A (i_q reference; 0.1 % steps). Written
        in per mille of i_max_A, not through :meth:`Drive.set_force_N`, whose rated force
        uses the drive's psi_f (changed while identifying)."""
        from bench._units import si_to_wire

        if not self.i_max_A:
            raise IdentifyError("set_iq: the drive's i_max_A is not known to the probe")
        pm = si_to_wire(od.TARGET_TORQUE, float(amps) / float(self.i_max_A))
        if not -1000 <= pm <= 1000:
            raise IdentifyError(f"thrust current {amps:.3g} A beyond i_max_A {self.i_max_A:g} A")
        self.drive.write(od.TARGET_TORQUE, pm)
        self.drive._sync_rpdo_cache(od.TARGET_TORQUE, pm)  # canopen's RPDO image

    def reconfigure(self, fields: dict[str, float]) -> None:
        self.drive.disable()
        self.run(0.01)
        self.drive.set_many({k: float(v) for k, v in fields.items()})
        self._enable_force()

    def follow_speed(self, t_s: np.ndarray, v_mps: np.ndarray) -> dict[str, np.ndarray]:
        """The profile as a staircase of its points (the bench sends one target per
        point, at the point's time on the drive clock)."""
        d = self.drive
        d.set_mode("speed")
        c0 = self.clock.now()  # the drive's time: the window does not depend on reader lag
        for k in range(len(t_s) - 1):
            d.set_speed_mps(float(v_mps[k]))
            d.wait_until(c0 + float(t_s[k + 1]))
        T = float(t_s[-1])
        self._settle(c0 + T)
        return self._window(c0, c0 + T)

    def ramp_speed(self, v_from: float, v_to: float, seconds: float) -> None:
        n = max(1, int(round(seconds / 0.01)))
        c0 = self.clock.now()
        for k in range(1, n + 1):
            self.drive.set_speed_mps(v_from + (v_to - v_from) * k / n)
            self.drive.wait_until(c0 + seconds * k / n)


@dataclass
class IdentifyOutput:
    """What ``bench identify`` produced."""

    result: Identified | None
    run_dir: Path
    error: str | None = None
    truth: dict[str, float] | None = None
    files: dict[str, str] = field(default_factory=dict)
    interrupted: bool = False
    #: the drive stopped it (a fault, lost, switched by another master): exit 3, not 1
    drive_error: bool = False


def _cfg_view(drive: Any) -> SimpleNamespace:
    """The drive's configuration fields the procedure needs, read by SDO (the
    identification overrides do not touch them)."""
    return SimpleNamespace(**{
        name: float(drive.get(name)[0])
        for name in ("i_max_A", "f_pwm_Hz", "u_inj_V", "L_d_H", "L_q_H", "spd_bw_radps",
                     "spd_kp_A_per_radps", "spd_ki_A_per_rad", "pole_pitch_m", "v_max_mps",
                     "psi_f_Wb", "mass_kg", "visc_Ns_per_m")})


def _telemetry_on(drive: Any, f_pwm_Hz: float) -> None:
    """The probe's telemetry: :data:`TEL_SIGNALS`, one frame per :data:`TEL_PERIOD_S`."""
    from protocols.serial_link import signal_names

    names = signal_names()
    ids = [names.index(s) for s in TEL_SIGNALS]
    drive.write(od.TELEMETRY__DECIMATION, 0)  # telemetry off while it is reconfigured
    drive.write(od.TELEMETRY__SIGNAL_COUNT, len(ids))
    for k, i in enumerate(ids):
        drive.write_raw(od.INDEX_TELEMETRY, od.TELEMETRY__SIGNAL_1.sub + k, i)
    drive.write(od.TELEMETRY__DECIMATION, max(1, int(round(f_pwm_Hz * TEL_PERIOD_S))))


def peak_thrust_N(cfg0: Any) -> float:
    """The thrust step 7 applies at its last point (N): the map's top current
    (:data:`identification.XSAT_TOP` x i_max_A) x K_F from the drive's configured psi_f;
    what the clamp must hold, for the operator's prompt."""
    from identification import XSAT_TOP

    return XSAT_TOP * float(cfg0.i_max_A) * force_constant_N_per_A(float(cfg0.psi_f_Wb),
                                                                   float(cfg0.pole_pitch_m))


def _run_identified(drive: Any, cfg0: Any, backup: dict[str, Any], res: Identified,
                    step: str) -> None:
    """Before an optional step, the drive off: a fault latched in steps 1-6 (step 6 keeps
    what it measured before one, see its note) reset and noted, the identified
    configuration (gains derived from it, the user's extractor) written, the probe's
    telemetry on again."""
    code = drive.fault_code()
    if code:
        from bench._drive import fault_text

        drive.reset_faults()
        res.log.append(f"{step}: the drive's fault {fault_text(code)} from steps 1-6 reset "
                       "before it")
    drive.restore(identified_config(backup, res))
    _telemetry_on(drive, cfg0.f_pwm_Hz)


def _cross_saturation(conn: Any, probe: WireProbe, cfg0: Any, backup: dict[str, Any],
                      res: Identified, hold: Callable[[], bool] | None) -> None:
    """Step 7 over the wire, after steps 1-6 (the drive off in between): ``hold`` (the
    fixture: an operator's confirmation or the simulated plant's lock) may decline (False:
    skipped, noted); then the drive runs the identified configuration (the motor file's,
    gains derived from it, the user's extractor) with the map being measured, and the
    result joins ``res``. :class:`identification.MoverMoved` or a fault leave ``res`` as
    steps 1-6 made it."""
    drive = conn.drive
    drive.disable()
    if hold is not None and not hold():
        res.log.append("step 7 (cross-saturation map) skipped: the mover was not clamped")
        return
    _run_identified(drive, cfg0, backup, res, "step 7")
    watched = probe.watch_speed()
    try:
        probe.run(0.02)  # telemetry flowing again
        xs = run_cross_saturation(probe, cfg0, float(cfg0.pole_pitch_m))
    finally:
        probe.unwatch_speed()
    res.values.update(xs.values)
    res.sigma.update(xs.sigma)
    res.log += xs.log
    if not watched:
        res.log.append("step 7's safety check had the position estimate only (no TPDO "
                       "maps the speed estimate 0x606C)")


def _ripple(conn: Any, probe: WireProbe, cfg0: Any, backup: dict[str, Any],
            res: Identified, travel_m: float) -> None:
    """Steps 8 and 9 over the wire, after steps 1-6 (the drive off in between): the drive
    runs the identified configuration and :func:`identification.run_ripple`, then
    :func:`identification.run_thrust_ripple`, measure with the identified psi_f (K_F),
    mass and viscous friction; the results join ``res``. A fault leaves ``res`` as the
    steps before made it (noted)."""
    drive = conn.drive
    drive.disable()
    _run_identified(drive, cfg0, backup, res, "step 8")
    probe.run(0.02)  # telemetry flowing again
    v = res.values
    # cfg0 with the identified values the steps take their defaults from
    cfg = SimpleNamespace(**{
        **vars(cfg0), "psi_f_Wb": float(v.get("psi_f_Wb", cfg0.psi_f_Wb)),
        "mass_kg": float(v["mass_kg"]) if v.get("mass_kg", 0.0) > 0.0 else float(cfg0.mass_kg),
        "visc_Ns_per_m": max(float(v.get("b_visc_Ns_per_m", cfg0.visc_Ns_per_m)), 0.0)})
    for step, what, fn in ((8, "position ripple", run_ripple),
                           (9, "cogging thrust", run_thrust_ripple)):
        try:
            rp = fn(probe, cfg, float(cfg0.pole_pitch_m), travel_m)
        except RuntimeError as e:  # a fault: what was measured before stands
            res.log.append(f"step {step} ({what}) stopped: {' '.join(str(e).split())}; "
                           f"steps before it kept")
            drive.disable()
            return
        res.values.update(rp.values)
        res.sigma.update(rp.sigma)
        res.log += rp.log


def identify_drive(conn: Any, runs_root: str = "runs", travel_m: float = 0.3,
                   name: str = "identified", apply: bool = False, n_starts: int = 4,
                   clamped: bool = False, hold: Callable[[], bool] | None = None,
                   ripple: bool = False) -> IdentifyOutput:
    """Run the identification on a connected drive; write the run folder (motor file,
    drive configuration, report, summary, logs). The drive's configuration is restored
    at the end unless ``apply`` (then the identified configuration stays).

    ``ripple``: step 8, the position ripple, on the free mover after the usual steps.
    ``clamped``: step 7, the cross-saturation map, after the usual steps; ``hold`` is
    called first with the drive off, the fixture's action that holds the mover (True: go
    on, False: skip the step). A mover that moves during it stops the step with a one-line
    error (``out.error``; the drive is disabled; steps 1-6 are kept and written)."""
    from bench._drive import DriveError, DriveLost
    from bench._logging import RunLogger, run_dir_for
    from bench._session import TelemetryReader
    from sim_fallback import extractor_id

    if conn.serial is None:
        raise IdentifyError("identification needs the serial telemetry link (--serial PORT)")
    run_dir = run_dir_for("identify", runs_root)
    if conn.sim is not None:
        conn.sim.wait_idle()
    logger = RunLogger(run_dir, conn.network)
    drive = conn.drive
    out = IdentifyOutput(None, run_dir)
    backup = {"drive": drive.identity(), "parameters": drive.backup()}
    (run_dir / "config_before.json").write_text(json.dumps(backup, indent=2, default=float)
                                                + "\n")
    cfg0 = _cfg_view(drive)
    tel = TelemetryReader(conn.serial, logger, cfg0.f_pwm_Hz)
    tel.start()
    conn.start_heartbeat()
    keep = backup
    lost = False
    try:
        _telemetry_on(drive, cfg0.f_pwm_Hz)
        # the bias sweep reads the raw HF response (E_d = T_s u_inj / L_dd): the
        # pseudo-filter extraction, whatever the drive normally uses
        drive.set("extractor", float(extractor_id("pseudo")))
        restore = {k: float(backup["parameters"][k]["value"]) for k in IDENT_RESTORED}
        drive.set_many({k: float(v) for k, v in ident_overrides(cfg0).items()})
        probe = WireProbe(conn, logger, i_max_A=cfg0.i_max_A)
        probe.run(0.02)  # telemetry flowing
        res = run_identification(probe, cfg0, cfg0.pole_pitch_m, travel_m, n_starts,
                                 restore)
        out.result = res
        if ripple:
            _ripple(conn, probe, cfg0, backup, res, travel_m)
        else:
            res.log.append("steps 8-9 (position ripple, cogging) not run: --ripple asks for "
                           "them (a free mover, constant-speed passes within --travel)")
        if clamped:
            _cross_saturation(conn, probe, cfg0, backup, res, hold)
        else:
            res.log.append("step 7 (cross-saturation map) not run: it needs a clamped mover "
                           "(--clamped)")
    except (IdentifyError, DriveError, RuntimeError) as e:
        out.error = " ".join(str(e).split())
        out.drive_error = isinstance(e, DriveError)
        lost = isinstance(e, DriveLost)
    except KeyboardInterrupt:
        out.interrupted = True
        out.error = "interrupted"
    finally:
        if lost:  # nothing sent reaches it; its heartbeat consumer switches it off
            out.error = (out.error or "") + "; drive not disabled and configuration NOT " \
                "restored (the drive is lost)"
        else:
            try:
                drive.disable()
            except Exception as e:  # noqa: BLE001 - reported; the restore below still runs
                out.error = (out.error + "; " if out.error else "") + f"disable failed: {e}"
            if out.result is not None and apply:
                keep = identified_config(backup, out.result)
            try:
                drive.restore(keep)
            except Exception as e:  # noqa: BLE001 - one line in the result
                out.error = (out.error + "; " if out.error else "") + (
                    f"restoring the drive configuration failed: {e}")
        tel.stop()
        logstats = logger.close()
        logger.write_meta({"identify": {"travel_m": travel_m, "apply": apply,
                                        "error": out.error}, "logging": logstats})
    if conn.sim is not None:
        out.truth = truth_of(conn.sim.motor, conn.sim.plant_overrides)
        if out.result is not None and "xsat_di_A" in out.result.values:
            out.truth.update(xsat_truth(conn.sim, out.result))
    _write_outputs(out, backup, name, conn)
    return out


def xsat_truth(sim: Any, res: Identified) -> dict[str, float]:
    """The simulated plant's closed forms at the map's points (report only, never used):
    the HF axis turn and the HF angle error at the true angle with the identified L_d, L_q
    (the configuration step 7 ran with)."""
    from sim_fallback import cross_saturation_truth

    levels = float(res.values["xsat_di_A"]) * np.arange(1, XSAT_POINTS + 1)
    delta, eps = cross_saturation_truth(sim.motor, levels, sim.plant_overrides,
                                        L_d_cfg=res.values.get("L_d_H"),
                                        L_q_cfg=res.values.get("L_q_H"))
    return {**{f"xsat_axis{k + 1}_rad": float(delta[k]) for k in range(XSAT_POINTS)},
            **{f"xsat_off{k + 1}_rad": float(eps[k]) for k in range(XSAT_POINTS)}}


def identified_config(backup: dict[str, Any], res: Identified) -> dict[str, Any]:
    """The drive configuration document (``bench config restore``) with the identified
    values and the gains derived from them (gains_auto 1)."""
    doc = json.loads(json.dumps(backup, default=float))
    params = doc["parameters"]
    for k, f in CONFIG_FIELDS.items():
        if k in res.values and f in params:
            v = float(res.values[k])
            params[f]["value"] = max(v, 0.0) if k in ("b_visc_Ns_per_m", "F_coulomb_N") else v
    if "gains_auto" in params:
        params["gains_auto"]["value"] = 1
    return doc


def _write_outputs(out: IdentifyOutput, backup: dict[str, Any], name: str, conn: Any
                   ) -> None:
    d = out.run_dir
    res = out.result
    rows = []
    if res is not None:
        ctrl = dict(conn.sim.motor.controller) if conn.sim is not None else {}
        src = (f"{conn.sim.motor.name} on the simulated drive" if conn.sim is not None
               else "the connected drive")
        toml = res.motor_file(name, conn.units.pole_pitch_m, conn.units.pole_pairs, src, ctrl)
        (d / "motor.toml").write_text(toml)
        (d / "drive_config.json").write_text(
            json.dumps(identified_config(backup, res), indent=2) + "\n")
        out.files = {"motor": str(d / "motor.toml"), "config": str(d / "drive_config.json")}
        for k, (unit, what) in {**QUANTITIES, **XSAT_QUANTITIES, **RIP_QUANTITIES}.items():
            if k not in res.values:
                continue
            row = {"quantity": k, "what": what, "value": res.values[k],
                   "sigma": res.sigma.get(k), "unit": unit}
            if out.truth is not None and k in out.truth and out.truth[k]:
                row["truth"] = out.truth[k]
                row["error_pct"] = 100.0 * (res.values[k] - out.truth[k]) / out.truth[k]
            rows.append(row)
    summary = {"kind": "identify", "passed": res is not None and out.error is None,
               "error": out.error, "simulated": out.truth is not None, "values": rows,
               "log": res.log if res is not None else [], "files": out.files}
    (d / "summary.json").write_text(json.dumps(summary, indent=2, default=float) + "\n")
    _write_report(d / "report.html", summary)


def _write_report(path: Path, summary: dict[str, Any]) -> None:
    import html

    def num(x: Any, fmt: str = ".5g") -> str:
        return "" if x is None or (isinstance(x, float) and not math.isfinite(x)) else \
            format(float(x), fmt)

    sim = summary["simulated"]
    head = ("<tr><th>quantity</th><th>what</th><th>value</th><th>&plusmn; 1&sigma;</th>"
            "<th>unit</th>" + ("<th>simulator truth</th><th>error</th>" if sim else "") +
            "</tr>")
    body = "".join(
        f"<tr><td>{html.escape(r['quantity'])}</td><td>{html.escape(r['what'])}</td>"
        f"<td class=num>{num(r['value'])}</td><td class=num>{num(r['sigma'], '.2g')}</td>"
        f"<td>{html.escape(r['unit'])}</td>"
        + (f"<td class=num>{num(r.get('truth'))}</td><td class=num>"
           f"{num(r.get('error_pct'), '+.2f')} %</td>" if sim else "") + "</tr>"
        for r in summary["values"])
    verdict = "identified" if summary["passed"] else "FAILED"
    why = ("" if summary["passed"] else
           f"<p class=fail>{html.escape(str(summary['error']))}. "
           + ("Nothing was identified; " if not summary["values"] else "")
           + ("the power stage is off; the configuration could NOT be restored: restore "
              "config_before.json with `bench config restore`."
              if "restoring the drive configuration failed" in str(summary["error"]) else
              "the power stage is off and the drive's configuration restored (config_before.json).")
           + "</p>")
    banner = ("<p class=sim>SIMULATED DRIVE: the values come from the simulator; the "
              "truth columns are the simulated plant's parameters (never used by the "
              "procedure).</p>" if sim else "")
    log = "".join(f"<li>{html.escape(x)}</li>" for x in summary["log"])
    files = "".join(f"<li>{html.escape(k)}: <code>{html.escape(Path(v).name)}</code></li>"
                    for k, v in summary["files"].items())
    path.write_text(
        "<!doctype html><meta charset=utf-8><title>bench identify</title><style>"
        "body{font-family:sans-serif;margin:2em}td,th{border:1px solid #ccc;padding:4px 8px}"
        "table{border-collapse:collapse}.num{text-align:right}.sim{background:#ffe08a;"
        "padding:8px;border:2px solid #c80}.fail{background:#fdd;padding:8px;"
        "border:2px solid #c00}</style>"
        f"<h1>Motor identification: {verdict}</h1>{banner}{why}"
        + (f"<table>{head}{body}</table>" if body else "")
        + (f"<h2>Notes</h2><ul>{log}</ul>" if log else "")
        + (f"<h2>Files</h2><ul>{files}</ul>" if files else "") +
        "<p>Method: docs/identify.md. 1&sigma;: the fit's standard error (R, mass, "
        "friction, &psi;<sub>f</sub>), the spread over the standstill starts (L<sub>q</sub>), "
        "the difference between two methods (L<sub>d</sub>).</p>\n", encoding="utf-8")
