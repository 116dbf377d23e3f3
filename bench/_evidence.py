"""What a run is judged on: the simulator's truth, a reference sensor, or nothing.

Every metric (:mod:`sim_fallback.metrics`) is computed from one set of channels in
sequence time. Where they come from depends on the drive:

* the in-process simulated drive: its record (the plant's truth beside the firmware's
  signals) - *simulator* truth, exact, at the full control rate;
* a drive on a bus with a reference position sensor (0x2091: a quadrature scale on a
  linear rig; the simulated drive server's and the emulated board's modelled one): the
  sensor's position, read by the drive at its ADC sampling instant and sent beside the
  estimate of the same period - over the serial telemetry link when there is one
  (configured for the run: the estimate, the reference, the speeds, the PLL error and
  i_q at about 1 kHz of drive time), else over the TPDOs (the estimated angle in TPDO3,
  the count in TPDO4, every SYNC);
* without one: no truth. The run says once - console, report, summary - "no reference
  sensor: estimate metrics not judged", and still judges what needs none (the drive's
  own speed tracking, the settling of its PLL error, its current, its faults).

The choice is made once per run (:func:`plan_evidence`) and said in the report.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from protocols.generated import od_names as od
from sim_fallback.metrics import TRUTH_CHANNELS, truth_from_reference

NO_SENSOR = "no reference sensor: estimate metrics not judged"

#: telemetry signals a judged run needs (<= 8, the frame's limit), by name
JUDGE_SIGNALS = ("theta_hat_rad", "omega_hat_radps", "omega_f_radps", "speed_ref_radps_e",
                 "pll_err_rad", "i_q_A", "ref_pos_m", "hf_amp_A")
#: telemetry rate for a judged run (Hz of drive time)
JUDGE_RATE_HZ = 1000.0


@dataclass
class Evidence:
    """How one run is judged.

    Attributes
    ----------
    source : {"simulator", "reference sensor", "none"}
        Where the truth comes from ("none": no truth; what needs none is judged).
    path : str
        What carried it: ``simulator record``, ``serial telemetry``, ``TPDO``.
    description : str
        One line for the report and the summary.
    note : str
        Said once when estimate metrics cannot be judged (:data:`NO_SENSOR`, or why).
    """

    source: str
    path: str
    description: str
    note: str = ""
    pole_pitch_m: float = 0.0
    ref_res_m: float = 0.0
    ref_zero_m: float = 0.0
    f_pwm_Hz: float = 0.0
    restore: list[tuple[Any, Any]] = field(default_factory=list)

    @property
    def has_truth(self) -> bool:
        return self.source != "none"

    def to_dict(self) -> dict[str, Any]:
        return {"source": self.source, "path": self.path, "description": self.description,
                "note": self.note or None}

    # ---- the channels ------------------------------------------------------------------
    def collect(self, logger: Any, t_origin_s: float, until_s: float | None = None,
                wait_s: float = 1.0) -> dict[str, np.ndarray] | None:
        """The metric channels in sequence time (``t_s`` first), or None when nothing
        was recorded. ``until_s``: wait up to ``wait_s`` (host s) for the channels to
        cover that sequence time (a link's latency), then take what is there."""
        if self.path == "simulator record":
            return logger.truth()
        name = "tel.theta_hat_rad" if self.path == "serial telemetry" else "pdo.theta_hat_rad"
        if until_s is not None:
            deadline = time.monotonic() + wait_s
            while time.monotonic() < deadline:
                t, _ = logger.channel(name)
                if t.size and t[-1] - t_origin_s >= until_s - 1.5 / JUDGE_RATE_HZ:
                    break
                time.sleep(0.01)
        if self.path == "serial telemetry":
            return self._from_telemetry(logger, t_origin_s)
        return self._from_pdos(logger, t_origin_s)

    def _from_telemetry(self, logger: Any, t0: float) -> dict[str, np.ndarray] | None:
        t, th = logger.channel("tel.theta_hat_rad")
        if t.size == 0:
            return None
        out: dict[str, np.ndarray] = {"t_s": t - t0, "theta_hat_rad": th}

        def on_t(name: str) -> np.ndarray | None:
            tt, v = logger.channel("tel." + name)
            if tt.size == 0:
                return None
            if tt.shape == t.shape and np.array_equal(tt, t):
                return np.asarray(v, dtype=float)
            i = np.searchsorted(tt, t).clip(0, tt.size - 1)  # frames lost mid-read: exact
            return np.where(tt[i] == t, v[i], np.nan)       # matches only

        for n in ("omega_hat_radps", "omega_f_radps", "speed_ref_radps_e", "pll_err_rad"):
            v = on_t(n)
            if v is not None:
                out[n] = v
        iq = on_t("i_q_A")
        if iq is not None:
            out["i_dq_hat_A"] = np.column_stack([np.full(iq.shape, np.nan), iq])
        if self.source == "reference sensor":
            x = on_t("ref_pos_m")
            if x is not None:
                out.update(truth_from_reference(t, x, self.pole_pitch_m))
        return out

    def _from_pdos(self, logger: Any, t0: float) -> dict[str, np.ndarray] | None:
        t, th = logger.channel("pdo.theta_hat_rad")
        if t.size == 0:
            return None
        out: dict[str, np.ndarray] = {"t_s": t - t0, "theta_hat_rad": th}
        k = math.pi / self.pole_pitch_m

        def nearest(name: str) -> np.ndarray | None:
            """The value of the same SYNC's other TPDO (nearest in time, within half a
            SYNC period's worth of drive time)."""
            tt, v = logger.channel("pdo." + name)
            if tt.size == 0:
                return None
            i = np.searchsorted(tt, t).clip(1, tt.size - 1)
            j = np.where(np.abs(tt[i - 1] - t) <= np.abs(tt[i] - t), i - 1, i)
            near = np.abs(tt[j] - t) <= 0.5 * max(float(np.median(np.diff(t))), 1e-4) \
                if t.size > 1 else np.ones(t.shape, bool)
            return np.where(near, np.asarray(v, dtype=float)[j], np.nan)

        v = nearest("speed_hat_mps")
        if v is not None:
            out["omega_hat_radps"] = k * v
        if self.source == "reference sensor":
            c = nearest("ref_count")
            if c is not None:
                x = np.where(c == float(-2**31), np.nan, c * self.ref_res_m - self.ref_zero_m)
                out.update(truth_from_reference(t, x, self.pole_pitch_m))
        return out


def plan_evidence(conn: Any, serial: bool, say: Any) -> Evidence:
    """How this run is judged (see the module text); configures the drive's telemetry
    for it when judged over the serial link (restored by :func:`finish_evidence`).
    Says once what cannot be judged. Never raises for a drive that stops answering
    while it asks: the run itself then ends on the lost drive, with its result."""
    try:
        return _plan(conn, serial, say)
    except Exception as e:  # noqa: BLE001 - a lost drive, an SDO timeout
        why = " ".join(f"{type(e).__name__}: {e}".split())
        return Evidence("none", "none", f"not determined: the drive did not answer ({why})",
                        note=f"not judged: the drive did not answer ({why})",
                        pole_pitch_m=conn.units.pole_pitch_m)


def _plan(conn: Any, serial: bool, say: Any) -> Evidence:
    tau = conn.units.pole_pitch_m
    if conn.sim is not None:
        return Evidence("simulator", "simulator record",
                        "the simulator's truth (the plant's state), at the full control rate",
                        pole_pitch_m=tau)
    d = conn.drive
    try:
        status = int(d.read(od.REFERENCE_SENSOR__STATUS))
    except Exception:  # noqa: BLE001 - a firmware without 0x2091: no sensor it knows of
        status = int(od.RefStatus.NONE)
    has_ref = status != int(od.RefStatus.NONE)
    res = zero = 0.0
    if has_ref:
        res = float(d.read(od.REFERENCE_SENSOR__RESOLUTION))
        zero = float(d.read(od.REFERENCE_SENSOR__ELECTRICAL_ZERO))
    f_pwm = conn.control_rate_Hz() or 24000.0
    if serial:
        ev = Evidence("reference sensor" if has_ref else "none", "serial telemetry", "",
                      pole_pitch_m=tau, ref_res_m=res, ref_zero_m=zero, f_pwm_Hz=f_pwm)
        try:
            _configure_telemetry(d, ev)
        except Exception:
            finish_evidence(conn, ev)  # what was changed goes back, if the drive answers
            raise
        rate = f_pwm / max(1, round(f_pwm / JUDGE_RATE_HZ))
        path = f"serial telemetry at {rate:g} Hz"
    else:
        ev = Evidence("reference sensor" if has_ref else "none", "TPDO", "",
                      pole_pitch_m=tau, ref_res_m=res, ref_zero_m=zero, f_pwm_Hz=f_pwm)
        path = f"TPDOs every SYNC ({conn.sync_period_ms} ms of host time)"
    if has_ref:
        ev.description = (f"reference sensor (0x2091: {res * 1e6:g} um per count, electrical "
                          f"zero {zero:g} m; speed: its position differentiated over "
                          f"{2:g} ms), beside the estimate, {path}")
        if status != int(od.RefStatus.OK):
            say(f"bench: the reference sensor reports {od.RefStatus(status).key} at the start "
                "of the run: estimate metrics over invalid readings are not judged")
    else:
        ev.note = NO_SENSOR
        ev.description = f"no reference sensor: the drive's own signals only, {path}"
        say(f"bench: {NO_SENSOR} (what needs no truth is: the drive's speed tracking, the "
            "settling of its PLL error, its current, its faults)")
    if not serial:
        ev.description += ("; not on CAN: the filtered speed, the speed reference and the "
                           "PLL error (give the serial link to judge what needs them)")
    return ev


def _configure_telemetry(d: Any, ev: Evidence) -> None:
    """The drive's telemetry for judging (0x2060), the previous values kept to restore."""
    from protocols import serial_link

    names = serial_link.signal_names()
    ids = [names.index(n) for n in JUDGE_SIGNALS if n in names]
    subs = [od.TELEMETRY__SIGNAL_1, od.TELEMETRY__SIGNAL_2, od.TELEMETRY__SIGNAL_3,
            od.TELEMETRY__SIGNAL_4, od.TELEMETRY__SIGNAL_5, od.TELEMETRY__SIGNAL_6,
            od.TELEMETRY__SIGNAL_7, od.TELEMETRY__SIGNAL_8]
    dec = max(1, round(ev.f_pwm_Hz / JUDGE_RATE_HZ))
    plan = [(od.TELEMETRY__DECIMATION, 0), *zip(subs, ids, strict=False),
            (od.TELEMETRY__SIGNAL_COUNT, len(ids)), (od.TELEMETRY__DECIMATION, dec)]
    for e, _ in plan:
        if all(e is not r for r, _ in ev.restore):
            ev.restore.append((e, d.read(e)))
    for e, v in plan:
        d.write(e, v)


def finish_evidence(conn: Any, ev: Evidence) -> None:
    """Give the drive its telemetry configuration back (decimation last: the stream
    restarts with a consistent signal list)."""
    d = conn.drive
    dec = [(e, v) for e, v in ev.restore if e is od.TELEMETRY__DECIMATION]
    rest = [(e, v) for e, v in ev.restore if e is not od.TELEMETRY__DECIMATION]
    for e, v in [(od.TELEMETRY__DECIMATION, 0), *rest, *dec]:
        try:
            d.write(e, v)
        except Exception:  # noqa: BLE001 - a lost drive: nothing to give back to
            return
    ev.restore.clear()


__all__ = ["NO_SENSOR", "TRUTH_CHANNELS", "Evidence", "finish_evidence", "plan_evidence"]
