"""The drive under test and the load, reached through CANopen (canopen library).

:class:`Drive` wraps a ``canopen.BaseNode402`` built from the EDS generated
from ``protocols/od.yaml``. It is the same code for hardware and for the
simulated drive: only the python-can bus underneath differs. Time is read
from a :class:`Clock`: the drive's own clock over the bus
(:class:`bench._clock.DriveClock`, its period count in TPDO4) on a bus, the
simulation clock for the in-process simulated drive, the wall clock for a drive
that does not publish its time.

Units: the drive's CiA 402 objects use um, um/s and per mille of the rated
force (see od.yaml); this module converts to and from m/s and N.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import canopen
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from bench._units import si_to_wire, wire_to_si
from protocols import EDS_PATH
from protocols.generated import od_names as od
from protocols.generated.od_names import FAULTS as _OD_FAULTS

log = logging.getLogger("bench.drive")

#: CiA 301 areas of the object dictionary (index ranges, not objects): the
#: communication area, and within it the PDO communication and mapping parameters
COMMUNICATION_AREA = range(0x1000, 0x2000)
PDO_PARAMETER_AREA = range(0x1400, 0x1C00)

ROOT = Path(__file__).resolve().parent.parent
#: EDS generated from protocols/od.yaml.
DEFAULT_EDS = EDS_PATH  # the generated EDS (protocols)

#: CiA 402 modes of operation used by the drive.
MODES: dict[str, int] = {"speed": 9, "force": 10}
#: canopen names of the modes.
_MODE_NAMES = {"speed": "CYCLIC SYNCHRONOUS VELOCITY", "force": "CYCLIC SYNCHRONOUS TORQUE"}

#: CiA 301 SDO abort codes -> plain explanation (protocols/od.yaml, sdo_aborts: the codes the
#: drive answers with are the same list).
SDO_ABORTS: dict[int, str] = {code: text for code, (_, text) in od.SDO_ABORTS.items()}

#: Fault codes, names and texts: one source, protocols/od.yaml (generated module).
FAULTS: dict[int, str] = {0x0000: "no fault",
                          **{code: f"{name}: {text}" for code, (name, text) in _OD_FAULTS.items()}}


def fault_text(code: int) -> str:
    """Readable text of a drive fault code (name and meaning from protocols/od.yaml)."""
    return f"0x{code:04X} {FAULTS.get(code, 'unknown fault')}"


def state_of(statusword: int) -> str:
    """CiA 402 state name of a statusword (canopen's masks); ``UNKNOWN`` if none fits."""
    for name, (mask, bits) in canopen.profiles.p402.State402.SW_MASK.items():
        if statusword & mask == bits:
            return name
    return "UNKNOWN"


class DriveError(RuntimeError):
    """The drive refused a command or did not reach the requested state."""


class DriveFault(DriveError):
    """The drive latched a fault while the bench was running something (``code``: 0x603F)."""

    def __init__(self, msg: str, code: int) -> None:
        super().__init__(msg)
        self.code = code


class DriveLost(DriveError):
    """The drive stopped answering mid-run: its time (0x2090:3) stopped, or its bus
    failed. Nothing the bench sends reaches it any more; the drive's own supervision
    (the bench's heartbeat it watches, 0x1016) switches its power stage off."""


class DriveLeftState(DriveError):
    """The drive left the state the bench put it in (OPERATION ENABLED) without a fault:
    another master on the bus (a second bench, a shell left open) or a local stop
    switched it. A run that went on would judge a drive that no longer follows it."""


class ParamError(DriveError):
    """A parameter read/write failed; the message explains the SDO abort code."""


class ParamInputError(ParamError):
    """A parameter name, value or backup file given by the user is wrong (nothing written)."""


class Clock(Protocol):
    """Time base of a drive (s)."""

    def now(self) -> float:
        """Current time (s)."""

    def sleep_until(self, t_s: float) -> None:
        """Block until :meth:`now` >= ``t_s``."""


class WallClock:
    """The host's monotonic clock (hardware runs)."""

    def now(self) -> float:
        return time.monotonic()

    def sleep_until(self, t_s: float) -> None:
        while True:
            dt = t_s - time.monotonic()
            if dt <= 0:
                return
            time.sleep(min(dt, 0.05))


# ---- parameters by name ---------------------------------------------------------------


@dataclass(frozen=True)
class Param:
    """One parameter of the object dictionary.

    Attributes
    ----------
    name : str
        Canonical name (``fw_config`` field name when the object mirrors one,
        else ``Object.Sub`` as in the EDS).
    index, sub : int
    unit : str
        Unit on the wire ("" when dimensionless).
    type : str
        CiA 301 type name.
    access : str
        ``ro``, ``rw``, ``wo`` or ``const``.
    min, max : float or None
        Documented limits.
    doc : str
    command : bool
        An action or set-point (od.yaml ``command``), not configuration.
    """

    name: str
    index: int
    sub: int
    unit: str
    type: str
    access: str
    min: float | None
    max: float | None
    doc: str
    command: bool = False

    @property
    def address(self) -> str:
        """``0xIIII:SS``."""
        return f"0x{self.index:04X}:{self.sub}"


def param_table() -> dict[str, Param]:
    """All parameters from ``protocols/od.yaml`` keyed by every accepted name.

    Accepted names: the fw_config field (``u_inj_V``), ``Object.Sub``
    (``Injection.Amplitude``), the object name for variables
    (``Target velocity``) and the address (``0x2010:1``).
    """
    from protocols import load_od

    od = load_od()
    cfg = od.fw_config
    out: dict[str, Param] = {}
    for e in od.entries:
        lo, hi = e.min, e.max
        if e.fw_config and e.fw_config in cfg and cfg[e.fw_config].get("unit", e.unit) == e.unit:
            # the firmware's range applies where the object is in the firmware's unit
            # (0x6080 carries v_max_mps in um/s: its own range)
            lo = cfg[e.fw_config].get("min", lo)
            hi = cfg[e.fw_config].get("max", hi)
        dotted = e.name if e.kind == "var" else f"{e.object_name}.{e.name}"
        # the firmware field's name only where the object carries it in the field's own
        # unit: 0x607D:2 (um) is not pos_limit_max_m (m, 0x2051:3), whose name it was too
        same = bool(e.fw_config) and getattr(e, "scale", 1.0) == 1.0 and \
            cfg.get(e.fw_config, {}).get("unit", e.unit) == e.unit
        canon = e.fw_config if same else dotted
        # the object's own text, else the firmware field's (od.yaml fw_config section)
        doc = e.doc or str(cfg.get(e.fw_config or "", {}).get("doc", "") or "")
        p = Param(canon, e.index, e.sub, e.unit or "", e.type, e.access, lo, hi, doc,
                  e.command)
        for key in {canon, dotted, f"0x{e.index:04X}:{e.sub}", f"0x{e.index:04x}:{e.sub}"}:
            out.setdefault(key, p)
        if e.kind == "var":
            out.setdefault(f"0x{e.index:04X}", p)
    return out


def explain_abort(err: SdoAbortedError, p: Param | None = None, value: Any = None) -> str:
    """Human-readable text for an SDO abort, with the allowed range when known."""
    code = int(err.code)
    what = SDO_ABORTS.get(code, "unknown abort code")
    msg = f"drive refused: SDO abort 0x{code:08X} ({what})"
    if p is not None:
        msg = f"{p.name} ({p.address}): {msg}"
        if code in (0x06090030, 0x06090031, 0x06090032) and (p.min is not None
                                                             or p.max is not None):
            msg += f"; allowed range [{p.min}, {p.max}] {p.unit}".rstrip()
            if value is not None:
                msg += f", got {value}"
    if code == 0x08000022:  # e.g. a motor parameter written while the PWM is on
        msg += "; disable the drive first (it takes this only with the power stage off)"
    return msg


# ---- the drive ------------------------------------------------------------------------


class Drive:
    """A CiA 402 drive through canopen (hardware or simulated, same code).

    Parameters
    ----------
    network : canopen.Network
        Connected network (its notifier running).
    node_id : int
        Node id of the drive (1..127).
    eds : str or Path
        EDS file (default: the generated ``pmlsm_drive.eds``).
    force_rated_N : float
        Force that 1000 per mille of 0x6071/0x6077 means (N); read from the
        drive when None (K_f * i_max_A).
    clock : Clock
        Time base; :class:`WallClock` by default.
    sdo_timeout_s : float
        SDO response timeout (s).

    Notes
    -----
    References are written by SDO (expedited, one round trip), which keeps
    the drive's PDO mapping free for telemetry and works on every transport.
    """

    def __init__(self, network: canopen.Network, node_id: int = 1,
                 eds: str | Path = DEFAULT_EDS, force_rated_N: float | None = None,
                 clock: Clock | None = None, sdo_timeout_s: float = 0.5) -> None:
        self.network = network
        self.node_id = node_id
        self.node = canopen.BaseNode402(node_id, str(eds))
        self.node.sdo.RESPONSE_TIMEOUT = sdo_timeout_s
        network.add_node(self.node)
        self.clock: Clock = clock or WallClock()
        self._force_rated_N = force_rated_N
        self._params: dict[str, Param] | None = None
        self.enabled = False
        self.mode = "speed"
        #: the watch (:meth:`check`): the state the bench put the drive in and expects it
        #: to stay in (None: none), and the statusword TPDOs received since
        self._expect: str | None = None
        self._sw_seen = 0  # statusword TPDOs received (the callback's count)
        self._sw_mark = 0  # ... when the expectation was set
        self._sw_last = 0
        self._hb_period_s: float | None = None

    # ---- identity ---------------------------------------------------------------------
    def identity(self) -> dict[str, Any]:
        """Identity (0x1018), names, firmware version (0x2040) and build id (0x2041)."""
        v = self.var
        fw = int(v(od.FIRMWARE_VERSION).raw)
        out: dict[str, Any] = {
            "node_id": self.node_id,
            "device_name": str(v(od.MANUFACTURER_DEVICE_NAME).raw),
            "software_version": str(v(od.MANUFACTURER_SOFTWARE_VERSION).raw),
            "vendor_id": int(v(od.IDENTITY_OBJECT__VENDOR_ID).raw),
            "product_code": int(v(od.IDENTITY_OBJECT__PRODUCT_CODE).raw),
            "revision": int(v(od.IDENTITY_OBJECT__REVISION_NUMBER).raw),
            "serial": int(v(od.IDENTITY_OBJECT__SERIAL_NUMBER).raw),
            "firmware_version": f"{(fw >> 16) & 0xFF}.{(fw >> 8) & 0xFF}.{fw & 0xFF}",
            "firmware_version_u32": fw,
            "build_id": str(v(od.BUILD_ID).raw),
        }
        return out

    def kind(self) -> tuple[str, str]:
        """What the drive says it is (0x2090:1, set by its port, never by the bench) and
        its board's name (0x2090:2): ``("hardware" | "simulated" | "emulated" | "no_io",
        board)``; ``("unknown", "")`` when it does not say (a firmware without 0x2090).
        Every result is labelled from this, whatever interface reached the drive."""
        try:
            k = int(self.var(od.BOARD__DRIVE_KIND).raw)
        except Exception:  # noqa: BLE001 - an SDO abort or no answer: it does not say
            return "unknown", ""
        try:
            board = str(self.var(od.BOARD__BOARD_NAME).raw)
        except Exception:  # noqa: BLE001 - an empty or unreadable name: the kind stands
            board = ""
        try:
            return od.DriveKind(k).key, board
        except ValueError:
            return "unknown", board

    def check_firmware(self, ident: dict[str, Any] | None = None) -> list[str]:
        """Compare the drive's identity with the EDS; return the mismatches (empty: ok)."""
        ident = ident or self.identity()
        eds = self.node.object_dictionary

        def default(e: od.Entry) -> int:
            return int(e.of(eds).default)

        problems = []
        exp_prod = default(od.IDENTITY_OBJECT__PRODUCT_CODE)
        exp_rev = default(od.IDENTITY_OBJECT__REVISION_NUMBER)
        exp_fw = default(od.FIRMWARE_VERSION)
        if ident["product_code"] != exp_prod:
            problems.append(f"product code 0x{ident['product_code']:08X} != EDS 0x{exp_prod:08X}")
        if ident["revision"] != exp_rev:
            problems.append(f"revision 0x{ident['revision']:08X} != EDS 0x{exp_rev:08X}")
        if ident["firmware_version_u32"] != exp_fw:
            problems.append(f"firmware 0x{ident['firmware_version_u32']:06X} != EDS "
                            f"0x{exp_fw:06X}")
        return problems

    # ---- setup ------------------------------------------------------------------------
    def setup(self, read_pdos: bool = True, operational: bool = True) -> None:
        """Read the PDO configuration, register the 402 callbacks, go OPERATIONAL.

        Parameters
        ----------
        read_pdos : bool
            Upload the PDO configuration by SDO (True) or trust the EDS defaults.
        operational : bool
            Send NMT start so the drive transmits its TPDOs.
        """
        if read_pdos:
            self.node.tpdo.read()
            self.node.rpdo.read()
        else:
            self.node.tpdo.read(from_od=True)
            self.node.rpdo.read(from_od=True)
        self.node.setup_pdos(upload=False)
        sw = self.node.tpdo_pointers.get(od.STATUSWORD.index)
        if sw is not None:  # the watch's view of the state machine, no bus traffic
            sw.pdo_parent.add_callback(self._on_status_pdo)
        if operational:
            self.node.nmt.state = "OPERATIONAL"

    # ---- state machine ----------------------------------------------------------------
    @property
    def statusword(self) -> int:
        """Statusword (0x6041) read by SDO."""
        return int(self.var(od.STATUSWORD).raw)

    @property
    def state(self) -> str:
        """CiA 402 state name, from a fresh SDO read of the statusword."""
        return state_of(self.statusword)

    # ---- the watch --------------------------------------------------------------------
    def _on_status_pdo(self, pdo_map: Any) -> None:
        v = self.node.tpdo_values.get(od.STATUSWORD.index)
        if v is not None:
            self._sw_last = int(v)
            self._sw_seen += 1

    def _expect_state(self, state: str | None) -> None:
        self._expect = state
        self._sw_mark = self._sw_seen

    def check(self) -> None:
        """The bench's one watch over its drive while a command runs (``bench run``,
        ``live``, ``identify``, the shell): cheap (no bus traffic unless something looks
        wrong), called once per wait slice. Raises

        - :class:`DriveLost`: its time stopped (the clock's consumer: no TPDO4 for
          ``lost_s``) or its bus failed; on a drive without published time, its CiA 301
          heartbeat (0x1017) is missing for three periods;
        - :class:`DriveFault`: it announced a fault (EMCY), or its statusword shows one;
        - :class:`DriveLeftState`: it left OPERATION ENABLED without a fault (another
          master, a local stop); the statusword TPDO raises the suspicion, an SDO read
          confirms it (a TPDO sent before the transition cannot cause a false abort).
        """
        lost = getattr(self.clock, "lost", None)
        why = lost() if lost is not None else self._heartbeat_lost()
        if why:
            raise DriveLost(why)
        code = self.active_fault()
        if code:
            raise DriveFault(f"drive fault {fault_text(code)}", code)
        if self._expect is None or self._sw_seen == self._sw_mark:
            return
        if state_of(self._sw_last) == self._expect:
            return
        sw = self.statusword  # confirm by SDO
        state = state_of(sw)
        if state == self._expect:
            self._sw_mark = self._sw_seen
            return
        if state in ("FAULT", "FAULT REACTION ACTIVE"):
            code = self.active_fault() or self.fault_code()
            raise DriveFault(f"drive fault {fault_text(code)}", code)
        expected, self._expect = self._expect, None
        self.enabled = False
        raise DriveLeftState(
            f"the drive left {expected} without a fault: statusword 0x{sw:04X} ({state}); "
            "another master on the bus (a second bench or shell) or a local stop switched it")

    def _heartbeat_lost(self) -> str | None:
        """A CiA 301 heartbeat consumer for a drive that publishes no time (the host's
        clock): None while its heartbeat comes (or it sends none)."""
        if getattr(self.clock, "exact_steps", False):
            return None  # the in-process simulated drive: its time is the bench's steps
        if self._hb_period_s is None:
            try:
                self._hb_period_s = float(self.read(od.PRODUCER_HEARTBEAT_TIME)) / 1000.0
            except Exception:  # noqa: BLE001 - no heartbeat to consume
                self._hb_period_s = 0.0
        last = self.node.nmt.timestamp
        if not self._hb_period_s or last is None:
            return None
        age = time.time() - float(last)
        if age > 3 * self._hb_period_s + 0.1:
            return (f"drive node {self.node_id} lost: no heartbeat for {age:.2f} s "
                    f"(0x1017 = {self._hb_period_s * 1000:.0f} ms; its bus or its process is "
                    "gone)")
        return None

    def wait_until(self, t_s: float, slice_s: float | None = None) -> None:
        """Sleep on the drive's clock until ``t_s``, watching the drive (:meth:`check`)
        every slice (the clock's ``slice_s``, 10 ms on a bus)."""
        step = slice_s or getattr(self.clock, "slice_s", 0.01)
        while True:
            self.check()
            now = self.clock.now()
            if now >= t_s - 1e-9:
                return
            self.clock.sleep_until(min(t_s, now + step))

    def _goto(self, target: str, timeout_s: float) -> None:
        """Walk the CiA 402 state machine to ``target`` with confirmed steps.

        Uses BaseNode402's transition tables (``State402.TRANSITIONTABLE``,
        ``next_state_indirect``); each controlword is an SDO download (so the
        drive acknowledged it) and each new state is confirmed by an SDO read
        of the statusword. This does not depend on when an event-driven TPDO
        arrives, which keeps the walk's traffic identical from run to run
        (and the simulated drive's timeline reproducible).
        """
        from canopen.profiles.p402 import State402

        deadline = time.monotonic() + timeout_s
        state = self.state
        for _ in range(8):
            if state == target:
                return
            if state == "FAULT":
                raise DriveError(f"drive in FAULT ({fault_text(self.fault_code())}) while "
                                 f"going to {target}")
            nxt = target if (state, target) in State402.TRANSITIONTABLE else \
                State402.next_state_indirect(state)
            cw = State402.TRANSITIONTABLE.get((state, nxt))
            if cw is None:
                raise DriveError(f"no CiA 402 transition from {state} towards {target}")
            self._sync_rpdo_cache(od.CONTROLWORD, cw)
            self.write(od.CONTROLWORD, cw)
            while (state := self.state) != nxt:
                if state == "FAULT" or time.monotonic() > deadline:
                    break
                time.sleep(0.001)
            if time.monotonic() > deadline and state != target:
                break
        if state != target:
            if state == "FAULT":
                raise DriveError(f"drive in FAULT ({fault_text(self.fault_code())}) while "
                                 f"going to {target}")
            raise DriveError(f"drive did not reach {target} within {timeout_s} s (now {state})")

    def set_mode(self, mode: str) -> None:
        """Select ``speed`` (CSV, 9) or ``force`` (CST, 10) and check 0x6061."""
        if mode not in MODES:
            raise ValueError(f"mode {mode!r}; allowed: {sorted(MODES)}")
        self.write(od.MODES_OF_OPERATION, MODES[mode])
        deadline = time.monotonic() + 1.0
        while int(self.var(od.MODES_OF_OPERATION_DISPLAY).raw) != MODES[mode]:
            if time.monotonic() > deadline:
                raise DriveError(f"drive did not confirm mode {mode} (0x6061)")
            time.sleep(0.001)
        self.mode = mode

    def enable(self, mode: str = "speed", timeout_s: float = 2.0) -> None:
        """Zero the references, select ``mode`` and go to OPERATION ENABLED."""
        if self.state == "FAULT":
            raise DriveError(f"drive in FAULT ({fault_text(self.fault_code())}); "
                             "run `bench faults --reset` first")
        self.set_speed_mps(0.0)
        self.write(od.TARGET_TORQUE, 0)
        self._sync_rpdo_cache(od.TARGET_TORQUE, 0)
        self.set_mode(mode)
        self._expect_state(None)
        self._goto("OPERATION ENABLED", timeout_s)
        self.enabled = True
        self._expect_state("OPERATION ENABLED")

    def disable(self, timeout_s: float = 1.0) -> None:
        """Zero the references and go to SWITCH ON DISABLED (PWM off).

        Falls back to a direct SDO write of the controlword if the state walk
        fails, and raises :class:`DriveError` only when the drive still reports
        OPERATION ENABLED afterwards.
        """
        self._expect_state(None)
        for ref in (od.TARGET_VELOCITY, od.TARGET_TORQUE):
            try:
                self._sync_rpdo_cache(ref, 0)
                self.var(ref).raw = 0
            except Exception as e:  # keep going: disabling matters more
                log.warning("zeroing 0x%04X failed: %s", ref.index, e)
        try:
            if self.state == "FAULT":  # power stage already off; a reset is the user's call
                self.enabled = False
                return
        except Exception:  # noqa: BLE001, S110 - the walk below reports what is wrong
            pass
        try:
            self._goto("SWITCH ON DISABLED", timeout_s)
        except Exception as e:
            log.warning("state walk to SWITCH ON DISABLED failed (%s); writing controlword", e)
            self.var(od.CONTROLWORD).raw = 0x0000  # DISABLE VOLTAGE
            if self.state in ("OPERATION ENABLED", "QUICK STOP ACTIVE"):
                raise DriveError("drive still enabled after DISABLE VOLTAGE") from e
        self.enabled = False

    def quick_stop(self) -> None:
        """Controlword QUICK STOP (0x0002): decelerate, then PWM off."""
        self._expect_state(None)
        self.var(od.CONTROLWORD).raw = 0x0002

    # ---- references -------------------------------------------------------------------
    def set_speed_mps(self, v_mps: float) -> None:
        """Target velocity (0x60FF, um/s) from m/s."""
        raw = si_to_wire(od.TARGET_VELOCITY, v_mps)
        self.write(od.TARGET_VELOCITY, raw)
        self._sync_rpdo_cache(od.TARGET_VELOCITY, raw)

    @property
    def force_rated_N(self) -> float:
        """Force (N) meant by 1000 per mille of 0x6071/0x6077: K_f i_max_A."""
        if self._force_rated_N is None:
            i_max = float(self.var(od.DRIVE_CONFIGURATION__I_MAX_A).raw)
            psi = float(self.var(od.DRIVE_CONFIGURATION__PSI_F_WB).raw)
            tau = float(self.var(od.DRIVE_CONFIGURATION__POLE_PITCH_M).raw)
            from protocols.units import force_constant_N_per_A
            self._force_rated_N = force_constant_N_per_A(psi, tau) * i_max
        return self._force_rated_N

    def set_force_N(self, force_N: float) -> None:
        """Target torque (0x6071, per mille of :attr:`force_rated_N`) from N."""
        pm = si_to_wire(od.TARGET_TORQUE, force_N / self.force_rated_N)
        if not -1000 <= pm <= 1000:
            raise DriveError(f"force {force_N:.3g} N is {pm} per mille of the rated "
                             f"{self.force_rated_N:.3g} N; allowed [-1000, 1000]")
        self.write(od.TARGET_TORQUE, pm)
        self._sync_rpdo_cache(od.TARGET_TORQUE, pm)

    def _sync_rpdo_cache(self, e: od.Entry, raw: int) -> None:
        """Keep canopen's RPDO image equal to what was written by SDO.

        BaseNode402 sends the controlword in RPDO1, which also carries the
        target velocity: a stale image would overwrite the reference.
        """
        ptr = self.node.rpdo_pointers.get(e.index)
        if ptr is not None:
            ptr.raw = raw
    def actual(self) -> dict[str, float]:
        """Estimated position (m), speed (m/s) and force (N) read by SDO."""
        def si(e: od.Entry) -> float:
            return wire_to_si(e, int(self.var(e).raw))

        return {"pos_hat_m": si(od.POSITION_ACTUAL_VALUE),
                "speed_hat_mps": si(od.VELOCITY_ACTUAL_VALUE),
                "force_hat_N": si(od.TORQUE_ACTUAL_VALUE) * self.force_rated_N}

    # ---- parameters -------------------------------------------------------------------
    @property
    def params(self) -> dict[str, Param]:
        if self._params is None:
            self._params = param_table()
        return self._params

    def param(self, name: str) -> Param:
        """Look a parameter up by any accepted name (see :func:`param_table`)."""
        try:
            return self.params[name]
        except KeyError:
            near = sorted(k for k in self.params if name.lower() in k.lower())[:8]
            hint = f"; did you mean: {', '.join(near)}" if near else ""
            raise ParamInputError(f"unknown parameter {name!r}{hint}") from None

    def write_raw(self, index: int, sub: int, value: Any) -> None:
        """SDO download with SDO aborts turned into :class:`ParamError`."""
        obj = self.node.sdo[index] if sub == 0 and not isinstance(
            self.node.object_dictionary[index], (canopen.objectdictionary.ODRecord,
                                                 canopen.objectdictionary.ODArray)) \
            else self.node.sdo[index][sub]
        try:
            obj.raw = value
        except SdoAbortedError as e:
            p = next((q for q in self.params.values() if q.index == index and q.sub == sub),
                     None)
            raise ParamError(explain_abort(e, p, value)) from e
        except SdoCommunicationError as e:
            raise ParamError(f"0x{index:04X}:{sub}: no answer from the drive ({e})") from e

    def var(self, e: od.Entry) -> Any:
        """The canopen SDO variable of an OD entry named in :mod:`protocols.generated.od_names`
        (``drive.var(od.STATUSWORD).raw``)."""
        return e.of(self.node.sdo)

    def write(self, e: od.Entry, value: Any) -> None:
        """:meth:`write_raw` of an OD entry by name (``drive.write(od.CONTROLWORD, 0)``)."""
        self.write_raw(e.index, e.sub, value)

    def read(self, e: od.Entry) -> Any:
        """:meth:`read_raw` of an OD entry by name."""
        return self.read_raw(e.index, e.sub)

    def read_raw(self, index: int, sub: int = 0) -> Any:
        """SDO upload with aborts turned into :class:`ParamError`."""
        ent = self.node.object_dictionary[index]
        obj = self.node.sdo[index] if not isinstance(
            ent, (canopen.objectdictionary.ODRecord, canopen.objectdictionary.ODArray)) \
            else self.node.sdo[index][sub]
        try:
            return obj.raw
        except SdoAbortedError as e:
            raise ParamError(explain_abort(e)) from e
        except SdoCommunicationError as e:
            raise ParamError(f"0x{index:04X}:{sub}: no answer from the drive ({e})") from e

    def get(self, name: str) -> tuple[Any, Param]:
        """Read a parameter by name; returns (value, Param)."""
        p = self.param(name)
        return self.read_raw(p.index, p.sub), p

    def set(self, name: str, value: str | float | int) -> Param:
        """Write a parameter by name; ``value`` may carry the unit (``"20 V"``).

        Raises
        ------
        ParamError
            Unknown name, wrong unit, not writable, or refused by the drive
            (the SDO abort code is explained, with the allowed range).
        """
        p = self.param(name)
        v = parse_value(value, p)
        if p.access in ("ro", "const"):
            raise ParamInputError(f"{p.name} ({p.address}) is read-only")
        try:
            self.write_raw(p.index, p.sub, v)
        except ParamError as e:
            cause = e.__cause__
            if isinstance(cause, SdoAbortedError):
                raise ParamError(explain_abort(cause, p, value)) from cause
            raise
        return p

    def set_many(self, fields: dict[str, str | float | int]) -> None:
        """Write several parameters that the drive checks together (``pll_kd < pll_kp
        pll_ki``, speeds below their limits, ...): in the order given, a value the drive
        refuses as a combination (SDO abort 0x06090030) is tried again after the others,
        so that every intermediate configuration is one the drive accepts, whichever way
        the values move. Raises the first refusal that no order resolves."""
        todo = list(fields.items())
        while todo:
            left: list[tuple[str, str | float | int]] = []
            first: ParamError | None = None
            for name, value in todo:
                try:
                    self.set(name, value)
                except ParamError as e:
                    cause = e.__cause__
                    if not (isinstance(cause, SdoAbortedError) and cause.code == 0x06090030):
                        raise
                    left.append((name, value))
                    first = first or e
            if len(left) == len(todo):
                assert first is not None
                raise first
            todo = left

    # ---- configuration backup / restore ----------------------------------------------
    def backup(self) -> dict[str, Any]:
        """Every readable ``rw`` parameter, by canonical name, with units."""
        out: dict[str, Any] = {}
        seen = set()
        for p in self.params.values():
            if p.access != "rw" or (p.index, p.sub) in seen or p.index in PDO_PARAMETER_AREA:
                continue
            if p.command:  # od.yaml `command`: an action or set-point, not configuration
                continue
            seen.add((p.index, p.sub))
            v = self.read_raw(p.index, p.sub)
            out[p.name] = {"value": v, "unit": p.unit, "address": p.address}
        return out

    def restore_plan(self, doc: Any, source: str = "backup") -> list[tuple[Param, Any]]:
        """Check a backup document completely, before anything is written.

        Parameters
        ----------
        doc : Any
            The parsed backup (``{"drive": identity, "parameters": {...}}``).
        source : str
            File name for messages.

        Returns
        -------
        list of (Param, value)
            What to write, parsed and range-checked.

        Raises
        ------
        ParamInputError
            Not a backup, from another product or firmware version, or any
            value unknown, read-only, of the wrong unit or out of range; the
            message lists every problem (one per line).
        """
        if not isinstance(doc, dict) or not isinstance(doc.get("parameters"), dict):
            raise ParamInputError(f"{source}: not a bench configuration backup (expected a JSON "
                                  "object with 'drive' and 'parameters' from `bench config "
                                  "backup`)")
        problems: list[str] = []
        ident = self.identity()
        drv = doc.get("drive")
        if not isinstance(drv, dict):
            problems.append(f"{source}: drive: missing; cannot check product and firmware")
        else:
            for key in ("vendor_id", "product_code", "firmware_version"):
                if drv.get(key) != ident[key]:
                    problems.append(f"{source}: drive.{key}: backup has {drv.get(key)!r}, the "
                                    f"connected drive {ident[key]!r}")
        plan: list[tuple[Param, Any]] = []
        for name, ent in doc["parameters"].items():
            v = ent.get("value") if isinstance(ent, dict) else ent
            try:
                # the address recorded by backup() is exact; names can be shared
                addr = ent.get("address") if isinstance(ent, dict) else None
                p = self.param(addr if isinstance(addr, str) else name)
                if p.access in ("ro", "const"):
                    raise ParamInputError(f"{p.name} ({p.address}) is read-only")
                if isinstance(ent, dict) and ent.get("unit", p.unit) != p.unit:
                    raise ParamInputError(f"{p.name}: unit {ent.get('unit')!r}, the parameter "
                                          f"is in {p.unit!r}")
                if isinstance(v, bool) or not isinstance(v, (int, float, str)):
                    raise ParamInputError(f"{name}: value {v!r} is not a number")
                plan.append((p, parse_value(v, p, check_range=True)))
            except (ParamInputError, ParamError) as e:
                problems.append(f"{source}: parameters.{name}: {e}")
        if problems:
            raise ParamInputError("\n".join(problems))
        return plan

    def restore(self, doc: Any, progress: Callable[[str], None] | None = None,
                source: str = "backup") -> int:
        """Write a :meth:`backup` back, all or nothing as far as checking goes.

        Everything is checked first (:meth:`restore_plan`); only then are the
        values written. Returns the number written; raises
        :class:`ParamInputError` (nothing written) or :class:`ParamError` (the
        drive refused a value it was expected to accept).
        """
        plan = self.restore_plan(doc, source)
        for p, v in plan:
            self.write_raw(p.index, p.sub, v)
            if progress:
                progress(p.name)
        return len(plan)

    # ---- non-volatile memory (CiA 301 0x1010 / 0x1011) -------------------------------
    SAVE_SIGNATURE = 0x65766173  #: 'save' in ASCII, written to 0x1010:1
    LOAD_SIGNATURE = 0x64616F6C  #: 'load' in ASCII, written to 0x1011:1

    def _nvm_command(self, e: od.Entry, signature: int, what: str) -> None:
        index = e.index
        if not int(self.read(e)) & 1:
            raise ParamError(f"the drive has no non-volatile memory (0x{index:04X}:1 reads 0): "
                             f"nothing {what}")
        try:
            self.write(e, signature)
        except ParamError as e:
            cause = e.__cause__
            code = int(cause.code) if isinstance(cause, SdoAbortedError) else None
            if code == 0x08000022:
                raise ParamError(f"0x{index:04X}:1: refused while the power stage is enabled "
                                 f"(SDO abort 0x08000022); disable the drive first: nothing "
                                 f"{what}") from e
            if code == 0x08000020:
                raise ParamError(f"0x{index:04X}:1: the drive could not write its "
                                 f"non-volatile memory (SDO abort 0x08000020): nothing "
                                 f"{what}") from e
            raise

    def save_config(self) -> None:
        """Store the running configuration in the drive's non-volatile memory (CiA 301
        0x1010:1 'save'); it is loaded at power-up and NMT reset node. Raises
        :class:`ParamError` (the drive has none, the power stage is on, the medium failed)."""
        self._nvm_command(od.STORE_PARAMETERS__SAVE_ALL_PARAMETERS, self.SAVE_SIGNATURE, "saved")

    def erase_saved_config(self) -> None:
        """Erase the stored configuration (CiA 301 0x1011:1 'load'): the defaults apply from
        the next NMT reset node or power-up; the running values stay until then."""
        self._nvm_command(od.RESTORE_DEFAULT_PARAMETERS__RESTORE_ALL_DEFAULT_PARAMETERS,
                          self.LOAD_SIGNATURE, "erased")

    # ---- trace buffer (scope) ---------------------------------------------------------
    def trace_capture(self, signals: list[str], pre_s: float, f_pwm_Hz: float) -> dict[str, Any]:
        """Arm the drive's trace buffer with ``signals`` and trigger it now.

        The capture runs at the full control rate; its length is the buffer
        capacity (``protocols.serial_link.TRACE_FLOATS``, from the firmware's
        FW_APP_TRACE_FLOATS) divided by the number of signals (4096 / 4 = 1024
        samples, 43 ms at 24 kHz). Returns what was configured and ``t_trigger_clock``,
        the drive-clock time (s) at which the trigger command was acknowledged.
        The data comes back over the serial link after :meth:`trace_upload`.
        """
        from protocols import serial_link

        names = serial_link.signal_names()
        ids = [names.index(sig) for sig in signals]
        per_sig = serial_link.TRACE_FLOATS // max(1, len(ids))
        pre = min(int(round(pre_s * f_pwm_Hz)), per_sig // 2)
        self.write(od.TRACE__COMMAND, 0)  # stop
        self.write(od.TRACE__SIGNAL_COUNT, len(ids))
        for k, i in enumerate(ids):
            self.write_raw(od.INDEX_TRACE, od.TRACE__SIGNAL_1.sub + k, i)
        self.write(od.TRACE__PRE_TRIGGER_SAMPLES, pre)
        self.write(od.TRACE__COMMAND, 1)  # arm
        self.write(od.TRACE__COMMAND, 2)  # force trigger
        t_trigger = self.clock.now()
        state = int(self.read(od.TRACE__STATE))
        if state not in (2, 3):
            raise DriveError(f"trace did not trigger (0x2070:2 state {state})")
        return {"ids": ids, "pre_samples": pre, "samples": per_sig, "t_trigger_clock": t_trigger}

    def trace_upload(self) -> None:
        """Ask the drive to send the last capture over the serial link (0x2070:1 = 3)."""
        self.write(od.TRACE__COMMAND, 3)

    # ---- faults -----------------------------------------------------------------------
    def active_fault(self) -> int:
        """The newest fault the drive announced by EMCY and has not reset (0 if none):
        no bus traffic (canopen's EMCY consumer keeps the list), so it can be asked
        often while a sequence runs."""
        active = list(getattr(self.node.emcy, "active", ()) or ())
        return int(active[-1].code) if active else 0

    def fault_code(self) -> int:
        """Latched fault (0x603F), 0 if none."""
        return int(self.var(od.ERROR_CODE).raw)

    def faults(self) -> dict[str, Any]:
        """Current fault, error register and fault history (newest first)."""
        hist = []
        for sub in range(od.FAULT_HISTORY__FAULT_1.sub, od.FAULT_HISTORY__FAULT_8.sub + 1):
            c = int(self.read_raw(od.INDEX_FAULT_HISTORY, sub))
            if c:
                hist.append(c)
        return {"state": self.state, "error_code": self.fault_code(),
                "error_register": int(self.var(od.ERROR_REGISTER).raw), "history": hist,
                "emcy": [(int(e.code), e.register) for e in self.node.emcy.log]}

    def reset_faults(self, timeout_s: float = 1.0) -> str:
        """Fault reset (controlword bit 7 rising edge); returns the new state."""
        self.var(od.CONTROLWORD).raw = 0x0000
        self.var(od.CONTROLWORD).raw = 0x0080
        deadline = time.monotonic() + timeout_s
        while self.state == "FAULT":
            if time.monotonic() > deadline:
                raise DriveError(f"fault reset refused; fault {fault_text(self.fault_code())}")
            time.sleep(0.01)
        self.var(od.CONTROLWORD).raw = 0x0000
        return self.state


def parse_value(value: str | float | int, p: Param, check_range: bool = False) -> Any:
    """Parse ``"20"``, ``"20 V"``, ``"0x10"`` for a parameter.

    Checks the unit and that the number is finite; with ``check_range`` also
    the documented range (otherwise the drive is the judge: its SDO abort is
    explained). Raises :class:`ParamInputError`.
    """
    if isinstance(value, (int, float)):
        v: Any = value
    else:
        text = value.strip()
        num, _, unit = text.partition(" ")
        unit = unit.strip()
        if unit and p.unit and unit != p.unit:
            raise ParamInputError(f"{p.name}: unit {unit!r} given, the parameter is in "
                                  f"{p.unit!r}")
        if p.type == "VISIBLE_STRING":
            return text
        try:
            v = int(num, 0) if p.type != "REAL32" else float(num)
        except ValueError:
            try:
                v = float(num)
            except ValueError:
                raise ParamInputError(f"{p.name}: {value!r} is not a number") from None
    if p.type == "VISIBLE_STRING":
        return str(v)
    rng = f"allowed range [{p.min}, {p.max}] {p.unit}".rstrip()
    if not math.isfinite(float(v)):
        raise ParamInputError(f"{p.name} ({p.address}): {value!r} is not a finite number; {rng}")
    if check_range and ((p.min is not None and float(v) < p.min)
                        or (p.max is not None and float(v) > p.max)):
        raise ParamInputError(f"{p.name} ({p.address}): {value!r} out of range; {rng}")
    if p.type == "REAL32":
        return float(v)
    if float(v) != int(v):
        raise ParamInputError(f"{p.name} is an integer ({p.type}); got {value!r}")
    return int(v)
