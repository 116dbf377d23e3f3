#!/usr/bin/env python3
"""Processor-in-the-loop: the Cortex-M4F build of the firmware core against the host build.

1. Closed-loop simulations of the shipped scenarios record what the drive's ADC
   delivered every period (phase currents, DC link) together with the commands
   it received (enable sequence, mode, speed references).
2. The same harness (benchmarks/cm4/harness.c, ``replay`` mode) is built from
   the same core sources twice: for this host with the host compiler, and for
   the Cortex-M4F with the real target flags (-mcpu=cortex-m4 -mfpu=fpv4-sp-d16
   -mfloat-abi=hard), run under QEMU (mps2-an386). Both replay the recorded
   inputs and write duties, angle estimate, fault code and PWM state per period.
3. The outputs are compared. Expected: identical fault codes and PWM states in
   every period; duties and angle within ``TOL`` (the two libms may differ in
   the last bit of expf, used for filter coefficients at configuration, and of
   atan2f, which the core's own atan2 leaves to zeros and non-finite input;
   the core has no other libm call on its signal path and C11 mode keeps the
   compilers from contracting a*b+c into FMA). In practice every shipped
   scenario replays bit for bit.

--cycles additionally measures, per scenario, the Cortex-M4F cost per period of
the control half (fw_step_into: ADC inputs to duties, the control interrupt's
core work) and of the supervision half (fw_supervise) in every regime the trace
goes through (start-up, injection, back-EMF observer, fault). QEMU's exec log
covers a whole run, so it is kept small with windows: the (untraced) M4 replay
saves the controller state at the start of every window (the start-up, the
first --cycles-startup seconds, contiguously: the alignment, the saliency check
and its judgement, the polarity test, the handover to closed loop or a flying
start; then [k0, k0 + W) every --cycles-every seconds, W = --cycles-window
steps; --cycles-window 0: the whole trace, in contiguous windows), and a traced
run (harness `window` mode, `-d exec,nochain`, one instruction per block)
continues each window from its saved state. Its outputs must equal the full
replay's bit for bit (checked). Instructions are counted and converted to
cycles with bench_cm4_estimate's walker and low/high/trm models.

The control interrupt is more than the control half: fw_app_isr's ADC
conversion (inputs_from_adc and fw_adc_convert, inside fw_step_into on that
path) and its hand-over to the supervision and the background (fw_app_control,
fw_app_slot), the glue, and the ISR entry/exit (22..56 cycles, ISR_OVERHEAD).
--cycles measures the glue once per run on the same image (bench_cm4_estimate's
control interrupt, locked mover, SPEED, by source: the cycles of fw_app.c's
functions and of the ADC path per period, high model) and judges each period's
control interrupt as control half - its physical inputs' loads (inputs_of: the
replay's path, which the interrupt does not take) + glue + entry/exit (with lazy
FP stacking).

Usage: python benchmarks/pil.py [--t-end 1.0] [--opt Os] [--scenario NAME ...]
       [--cycles [--cycles-window 100] [--cycles-every 0.05] [--cycles-startup 0.1]]
Exit 0 when every scenario agrees, 1 when one does not, 2 when tools are missing.
"""

from __future__ import annotations

import argparse
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_cm4_estimate as cm4  # noqa: E402

from protocols.generated import od_names as od  # noqa: E402

TOL_DUTY = 1e-4  # of the 0..1 duty range
TOL_THETA_RAD = 1e-3
EV_CW, EV_MODE, EV_SPEED, EV_IQ = 0, 1, 2, 3
OUT_DTYPE = np.dtype([("duty", "<f4", 3), ("theta", "<f4"), ("fault", "<u2"),
                      ("pwm", "u1"), ("state", "u1")])
IN_DTYPE = np.dtype([("i_abc", "<f4", 3), ("u_dc", "<f4")])
#: harness `window` mode, per step: the replay record, then the regime
WIN_DTYPE = np.dtype([("o", OUT_DTYPE), ("speed", "<f4"), ("phase", "u1"), ("bemf", "u1"),
                      ("pad", "u1", 2)])
WIN_MAX_STEPS = 4000  # the harness's window buffer (N_MAX)
CTL_TARGET = cm4.ISR_TARGET  # cycles of the control interrupt, high model, every period
GLUE_WHAT = "fw_app_isr, fw_app_control, fw_app_slot, inputs_from_adc, fw_adc_convert"
#: by-source functions (the innermost, inlined) of the interrupt's ADC path (glue) and of
#: the replay's physical inputs (in the control half, not in the interrupt)
GLUE_CORE_FUNCS = ("fw_adc_convert (", "inputs_from_adc (")
INPUTS_FUNC = "inputs_of ("
# the two halves of a period as the harness's pil_period() calls them
cm4.KINDS.setdefault("pil_ctl", ("fw_step_into", "pil_period", "window"))
cm4.KINDS.setdefault("pil_sup", ("fw_supervise", "pil_period", "window"))

#: name -> (motor, speed schedule [(t_s, m/s)], load schedule [(t_s, N)], plant events)
SCENARIOS: dict[str, tuple[str, list, list, list]] = {
    "paper_load_step": ("paper_salient", [(0.0, 0.3)], [(0.0, 0.0), (0.5, 65.0)], []),
    "paper_speed_reversal": ("paper_salient", [(0.0, 0.3), (0.5, -0.3)], [(0.0, 0.0)], []),
    "paper_startup_random": ("paper_salient", [(0.0, 0.3)], [(0.0, 0.0)], []),
    "iron_core_linear_load": ("iron_core_linear", [(0.0, 0.5)], [(0.0, 0.0), (0.5, 20.0)], []),
    # the monitor's fault path: phase a opens at 0.4 s
    "paper_open_phase": ("paper_salient", [(0.0, 0.3)], [(0.0, 0.0)],
                         [(0.4, {"open_phase_mask": 1})]),
    # enabled while the mover coasts at 0.94 m/s (the fault matrix's
    # enable_moving_0.94mps): the flying start (the motion check, the catch on the
    # back-EMF), then slowed to 0.1 m/s, the way back from the back-EMF to injection
    "iron_core_flying_start": ("iron_core_linear", [(0.0, 0.1)], [(0.0, 0.0)], []),
}
#: scenario -> the mover's speed at the enable, m/s (0 when not listed)
V0_MPS: dict[str, float] = {"iron_core_flying_start": 0.94}


def make_trace(name: str, t_end: float, path: Path, seed: int = 3) -> np.ndarray:
    """Closed-loop run of a scenario; writes the PIL trace, returns the loop's duties."""
    from sim_fallback import SIM_REF_LOAD, SIM_REF_SPEED, Sim, load_motor

    motor, speed, load, events = SCENARIOS[name]
    mot = load_motor(motor)
    x0 = 0.37 * 2 * mot.tau_m if "random" in name else 0.0
    k_w = mot.mps_to_radps_e(1.0)
    with Sim(mot, seed=seed, x0_m=x0) as sim:
        if V0_MPS.get(name):
            sim.set_state(x0_m=x0, v0_mps=V0_MPS[name])
        n = int(round(t_end / sim.dt_s))
        sim.set_schedule(SIM_REF_SPEED, speed, k_w)
        sim.set_schedule(SIM_REF_LOAD, load)
        sim.enable("speed")
        ch = ["i_abc_meas_A", "u_dc_meas_V", "duty_abc"]
        parts, done = [], 0
        for t_ev, change in [*events, (t_end, None)]:
            k = min(n, int(round(t_ev / sim.dt_s)))
            if k > done:
                parts.append(sim.advance(k - done, channels=ch))
                done = k
            if change:
                sim.set_plant(**change)
        rec = {c: np.concatenate([p_[c] for p_ in parts]) for c in ch}
        # the samples as the drive converted them (its current zeros measured at boot)
        rec["i_abc_meas_A"], rec["u_dc_meas_V"] = sim.drive_inputs(rec["i_abc_meas_A"],
                                                                   rec["u_dc_meas_V"])
        cfg = bytes(sim.cfg)
    # the commands the drive got: the enable walk, then each speed breakpoint
    ev = [(0, EV_MODE, 0.0), (0, EV_CW, 0x06), (0, EV_CW, 0x07), (0, EV_CW, 0x0F)]
    for t, v in speed:
        ev.append((int(round(t / (1.0 / 24000.0))), EV_SPEED, v * k_w))
    ev = [e for e in ev if e[0] < n]
    inputs = np.zeros(n, IN_DTYPE)
    inputs["i_abc"] = rec["i_abc_meas_A"]
    inputs["u_dc"] = rec["u_dc_meas_V"]
    with path.open("wb") as f:
        f.write(struct.pack("<4I", 0x544C4950, n, len(ev), len(cfg)))
        f.write(cfg)
        for k, kind, val in ev:
            f.write(struct.pack("<IIf", k, kind, val))
        f.write(inputs.tobytes())
    return rec["duty_abc"]


def build_host(outdir: Path) -> Path:
    """The replay harness for this host, from the same sources as the M4 image."""
    outdir.mkdir(parents=True, exist_ok=True)
    exe = outdir / "harness_host"
    srcs, incs = cm4.harness_sources()
    r = subprocess.run(["cc", "-O2", "-std=c11", "-DNDEBUG", "-Wall", "-Wextra", *incs, *srcs,
                        "-lm", "-o", str(exe)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"host build failed:\n{r.stderr}")
    return exe


def replay_host(exe: Path, trace: Path, out: Path) -> np.ndarray:
    r = subprocess.run([str(exe), "replay", str(trace), str(out)], capture_output=True,
                       text=True, timeout=600)
    if r.returncode != 0:
        raise RuntimeError(f"host replay failed: {r.stdout}{r.stderr}")
    return np.fromfile(out, OUT_DTYPE)


def write_windows(path: Path, windows: list[tuple[int, int]]) -> Path:
    """The harness's windows file: uint32 pairs k0, k1."""
    np.asarray(windows, "<u4").reshape(-1, 2).tofile(path)
    return path


def replay_cm4(elf: Path, trace: Path, out: Path, states: Path | None = None,
               windows: list[tuple[int, int]] | None = None) -> tuple[np.ndarray, float]:
    """The M4 replay; with states and windows also the controller state at the start
    of each window (k0 ascending) into the file states (for cycle windows)."""
    t0 = time.perf_counter()
    # file names relative to the trace's directory (semihosting's command line is short)
    extra = ([states.name, write_windows(states.with_suffix(".ks"), windows).name]
             if states is not None and windows else [])
    r = cm4.qemu(elf, ["replay", trace.name, str(out.relative_to(trace.parent)), *extra], [],
                 timeout=900, cwd=trace.parent)
    if r.returncode != 0 or "replay ok" not in r.stdout:
        raise RuntimeError(f"M4 replay failed: {r.stdout}{r.stderr}")
    return np.fromfile(out, OUT_DTYPE), time.perf_counter() - t0


def compare(a: np.ndarray, b: np.ndarray) -> dict[str, float | int | bool]:
    """Agreement of two replays (host a, M4 b)."""
    on = a["pwm"] == 1
    dd = np.abs(a["duty"] - b["duty"])[on]
    dth = np.abs((a["theta"].astype(float) - b["theta"] + np.pi) % (2 * np.pi) - np.pi)
    return {
        "steps": int(a.size),
        "bit_identical": bool(a.tobytes() == b.tobytes()),
        "pwm_equal": bool(np.array_equal(a["pwm"], b["pwm"])),
        "fault_equal": bool(np.array_equal(a["fault"], b["fault"])),
        "state_equal": bool(np.array_equal(a["state"], b["state"])),
        "duty_max_abs": float(dd.max()) if dd.size else 0.0,
        "theta_max_abs_rad": float(dth.max()) if dth.size else 0.0,
        "final_fault": int(a["fault"][-1]),
        "closed_loop_steps": int(np.count_nonzero(on)),
    }


def agrees(c: dict) -> bool:
    return (c["pwm_equal"] and c["fault_equal"] and c["state_equal"]
            and c["duty_max_abs"] <= TOL_DUTY and c["theta_max_abs_rad"] <= TOL_THETA_RAD)


def cycle_windows(n: int, window: int, every_steps: int,
                  start_steps: int = 0) -> list[tuple[int, int]]:
    """[k0, k1) windows of a trace of n steps: the first start_steps contiguously
    (in windows of at most WIN_MAX_STEPS), then `window` steps every `every_steps`
    steps from 0 (those starting at or after start_steps); window 0: the whole
    trace in contiguous windows of at most WIN_MAX_STEPS."""
    if window <= 0:
        return [(k, min(n, k + WIN_MAX_STEPS)) for k in range(0, n, WIN_MAX_STEPS)]
    start = min(max(start_steps, 0), n)
    out = [(k, min(start, k + WIN_MAX_STEPS)) for k in range(0, start, WIN_MAX_STEPS)]
    window = min(window, WIN_MAX_STEPS)
    return out + [(k, min(n, k + window)) for k in range(0, n, max(every_steps, window))
                  if k >= start]


def phase_name(phase: int) -> str:
    """The start phase's name (the generated StartPhase, fw_start_phase_t)."""
    try:
        return od.StartPhase(int(phase)).name
    except ValueError:
        return str(phase)


def regime(phase: int, bemf: int, fault: int) -> str:
    """A period's regime from the replay's outputs after it."""
    if fault:
        return "FAULT"
    name = phase_name(phase)
    return f"RUN/{'bemf' if bemf else 'inj'}" if name == "RUN" else name


def measure_cycles(elf: Path, trace: Path, full: np.ndarray, windows: list[tuple[int, int]],
                   states: Path, work: Path) -> dict:
    """Count the two halves per period over the windows (states: the M4 replay's saved
    state at every window's k0). The windows run in groups of at most WIN_MAX_STEPS
    steps, one traced QEMU run each; every window's outputs must equal the full
    replay's (full). -> per measured period: step, regime, speed and per half
    insns/low/high/trm cycles."""
    blob = states.read_bytes()
    size = len(blob) // len(windows)
    syms, insns = cm4.symbols(elf), cm4.disassemble(elf)
    groups: list[list[int]] = [[]]
    for i, (k0, k1) in enumerate(windows):
        if groups[-1] and sum(windows[j][1] - windows[j][0] for j in groups[-1]) + k1 - k0 \
                > WIN_MAX_STEPS:
            groups.append([])
        groups[-1].append(i)
    cols: dict[str, list] = {k: [] for k in ("step", "regime", "speed", "phase")}
    for half in ("ctl", "sup"):
        for m in ("insns", "low", "high", "trm"):
            cols[f"{half}_{m}"] = []
    exact = True
    inputs_cy, inputs_n = 0.0, 0  # the physical inputs' loads (INPUTS_FUNC), high model
    for g, idx in enumerate(groups):
        st = work / f"{trace.stem}.states{g}"
        st.write_bytes(b"".join(blob[i * size:(i + 1) * size] for i in idx))
        wout, log = work / f"{trace.stem}.win{g}.out", work / f"{trace.stem}.exec{g}.log"
        ks = write_windows(work / f"{trace.stem}.ks{g}", [windows[i] for i in idx])
        r = cm4.qemu(elf, ["window", trace.name, st.name, wout.name, ks.name],
                     [*cm4.one_insn_per_tb_args(), "-d", "exec,nochain", "-D", str(log)],
                     timeout=1800, cwd=work)
        if r.returncode != 0 or "window ok" not in r.stdout:
            raise RuntimeError(f"M4 window run failed: {r.stdout}{r.stderr}")
        w = np.fromfile(wout, WIN_DTYPE)
        steps = np.concatenate([np.arange(*windows[i]) for i in idx])
        exact &= w["o"].tobytes() == full[steps].tobytes()
        nsteps = int(steps.size)
        for half in ("ctl", "sup"):
            sn, slo, shi, strm, *rest = cm4.parse_trace(log, insns, syms, nsteps, 1,
                                                        f"pil_{half}")
            cols[f"{half}_insns"] += sn
            cols[f"{half}_low"] += slo
            cols[f"{half}_high"] += shi
            cols[f"{half}_trm"] += strm
            if half == "ctl":  # the same path every period: its mean is every period's
                pc_count, pc_cyc = rest[-2], rest[-1]
                for fn, _n, _lo, hi, _t in cm4.by_source(elf, pc_count, pc_cyc, nsteps):
                    if fn.startswith(INPUTS_FUNC):
                        inputs_cy += hi * nsteps
                inputs_n += nsteps
        log.unlink()
        cols["step"] += steps.tolist()
        cols["speed"] += w["speed"].tolist()
        cols["phase"] += [phase_name(p) for p in w["phase"]]
        cols["regime"] += [regime(p, b, f) for p, b, f in
                           zip(w["phase"], w["bemf"], w["o"]["fault"], strict=True)]
    res = {k: np.asarray(v) for k, v in cols.items()}
    res["inputs_high"] = inputs_cy / inputs_n if inputs_n else 0.0
    res["windows_exact"] = bool(exact)
    res["windows"] = windows
    return res


def cycle_stats(cy: dict, sel: np.ndarray | None = None) -> dict[str, dict[str, float]]:
    """median and max per half and measure (insns, low, high, trm) over the periods sel."""
    out = {}
    for half in ("ctl", "sup"):
        for m in ("insns", "low", "high", "trm"):
            v = cy[f"{half}_{m}"] if sel is None else cy[f"{half}_{m}"][sel]
            out.setdefault(half, {})[m] = (float(np.median(v)), int(v.max())) if v.size \
                else (0.0, 0)
    return out


def measure_glue(elf: Path, opt: str) -> dict[str, float]:
    """The control interrupt's glue around the core, per period, on the image elf:
    bench_cm4_estimate's control interrupt (fw_app_isr, locked mover, SPEED mode,
    800 periods) by source, the cycles of fw_app.c's functions (fw_app_isr,
    fw_app_control, fw_app_slot: the null checks, the ring slot, the hand-over to
    the supervision, the period count) and of fw_adc_convert (the ADC conversion,
    inlined into fw_step_into on that path). -> {"low", "high", "trm"} cycles per
    period, and "isr_high" the whole interrupt's median (high)."""
    res = cm4.measure(opt, "speed", elf, 80, 10, False, "isr", True)
    glue = {"low": 0.0, "high": 0.0, "trm": 0.0, "isr_high": res["cycles_high_median"]}
    for e in res["source_functions_per_step"]:
        if "(fw_app.c)" in e["function"] or e["function"].startswith(GLUE_CORE_FUNCS):
            for m in ("low", "high", "trm"):
                glue[m] += e[f"cycles_{m}"]
    return glue


def run(names: list[str], t_end: float, opt: str, work: Path,
        cycles: tuple | None = None, glue: bool = False) -> list[dict]:
    """PIL comparison of the scenarios; with cycles = (window steps, every s[, start-up
    s]) also the M4 cost of the two halves per period (measure_cycles) in c["cycles"];
    with glue the control interrupt's glue (measure_glue) in c["glue"]."""
    cm4.check_tools()
    elf = cm4.build(opt, work / f"m4-{opt}")
    exe = build_host(work / "host")
    glue_cy = measure_glue(elf, opt) if glue else None
    results = []
    for name in names:
        trace = work / f"{name}.pilt"
        loop_duty = make_trace(name, t_end, trace)
        a = replay_host(exe, trace, work / f"{name}.host.out")
        windows, states = [], None
        if cycles is not None:
            start = int(round(cycles[2] * 24000.0)) if len(cycles) > 2 else 0
            windows = cycle_windows(a.size, cycles[0], int(round(cycles[1] * 24000.0)), start)
            states = work / f"{name}.states"
        b, wall = replay_cm4(elf, trace, work / f"{name}.m4.out", states, windows)
        c = compare(a, b)
        # the replay reproduces the closed loop it was recorded from (the host library
        # is built by CMake with other flags, so within the same tolerance)
        on = ~np.isnan(loop_duty[:, 0])
        c["loop_duty_max_abs"] = float(np.abs(loop_duty[on] - a["duty"][on]).max()) if np.any(
            on) else 0.0
        c.update(name=name, opt=opt, qemu_wall_s=wall, ok=agrees(c))
        if cycles is not None:
            t0 = time.perf_counter()
            c["cycles"] = measure_cycles(elf, trace, b, windows, states, work)
            c["cycles_wall_s"] = time.perf_counter() - t0
            c["ok"] = c["ok"] and c["cycles"]["windows_exact"]
        if glue_cy is not None:
            c["glue"] = glue_cy
        results.append(c)
    return results


def fmt_stats(st: dict) -> str:
    def one(half: str) -> str:
        d = st[half]
        return (f"insns {d['insns'][0]:.0f}/{d['insns'][1]}, cycles low {d['low'][0]:.0f}/"
                f"{d['low'][1]}, high {d['high'][0]:.0f}/{d['high'][1]}, trm "
                f"{d['trm'][0]:.0f}/{d['trm'][1]}")
    return f"control half {one('ctl')} | supervision half {one('sup')}"


def isr_extra(c: dict) -> int:
    """Cycles the control interrupt adds to the control half (high model): the
    glue measured on the image (c["glue"], measure_glue) and the ISR entry/exit with
    lazy FP stacking, less the replay's physical inputs' loads (the interrupt's
    ADC path is in the glue); 0 when the glue was not measured."""
    g = c.get("glue")
    if not g:
        return 0
    return int(round(g["high"] - c["cycles"].get("inputs_high", 0.0))) + cm4.ISR_OVERHEAD[1]


def report_cycles(c: dict) -> bool:
    """Prints the cycle summary of one scenario; -> the control interrupt (control half
    + glue + entry/exit, isr_extra; the control half alone when the glue was not
    measured) within CTL_TARGET in every measured period."""
    cy = c["cycles"]
    n = cy["step"].size
    extra = isr_extra(c)
    print(f"\n{c['name']} -{c['opt']}: {n} periods measured in {len(cy['windows'])} windows "
          f"of {c['steps']} (window outputs equal the full replay: {cy['windows_exact']}); "
          f"median/max per period, ISR entry/exit not included; regime = start phase "
          f"after the period (RUN/inj: HF injection, RUN/bemf: back-EMF observer), "
          f"speed = the estimate:")
    print(f"  all           {fmt_stats(cycle_stats(cy))}")
    for reg in dict.fromkeys(cy["regime"].tolist()):
        sel = cy["regime"] == reg
        sp = cy["speed"][sel]
        print(f"  {reg:<13} {fmt_stats(cycle_stats(cy, sel))}  [{int(sel.sum())} periods, "
              f"speed {sp.min():+.2f}..{sp.max():+.2f} m/s]")
    # the five worst periods, the earliest first among equals
    top = np.lexsort((cy["step"], -cy["ctl_high"]))[:5]
    print("  worst control halves (high model): " + ", ".join(
        f"{int(cy['ctl_high'][j])} at step {int(cy['step'][j])} ({cy['regime'][j]})"
        for j in top))
    i = int(top[0])
    worst = int(cy["ctl_high"][i])
    where = (f"max {worst} at step {int(cy['step'][i])} (phase {cy['regime'][i]}, speed "
             f"estimate {cy['speed'][i]:+.3f} m/s)")
    if extra:
        g = c["glue"]
        ok = worst + extra <= CTL_TARGET
        print(f"  {c['name']}: control interrupt (control half - inputs "
              f"{cy['inputs_high']:.0f} + glue {g['high']:.0f} + ISR entry/exit "
              f"{cm4.ISR_OVERHEAD[1]}) <= {CTL_TARGET} cycles (high model) in every measured "
              f"period: {'yes' if ok else 'no'}, control half {where}: {worst + extra}")
    else:
        ok = worst <= CTL_TARGET
        print(f"  {c['name']}: control half <= {CTL_TARGET} cycles (high model) in every "
              f"measured period: {'yes' if ok else 'no'}, {where}; with ISR entry/exit "
              f"+{cm4.ISR_OVERHEAD[1]}: {worst + cm4.ISR_OVERHEAD[1]}")
    return ok


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t-end", type=float, default=1.0)
    ap.add_argument("--opt", default="Os", help="M4 optimisation level (Os is the shipped one)")
    ap.add_argument("--scenario", nargs="*", default=list(SCENARIOS), choices=list(SCENARIOS))
    ap.add_argument("--cycles", action="store_true",
                    help="also measure the M4 cycles per period of the control half "
                    "(fw_step_into) and of the supervision half (fw_supervise)")
    ap.add_argument("--cycles-window", type=int, default=100,
                    help="steps per measured window (0: the whole trace; default 100)")
    ap.add_argument("--cycles-every", type=float, default=0.05,
                    help="a window starts every this many seconds (default 0.05)")
    ap.add_argument("--cycles-startup", type=float, default=0.1,
                    help="the first this many seconds traced contiguously: the start-up "
                    "(default 0.1; 0: windows only)")
    a = ap.parse_args()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        res = run(a.scenario, a.t_end, a.opt, Path(tmp),
                  (a.cycles_window, a.cycles_every, a.cycles_startup) if a.cycles else None,
                  glue=a.cycles)
    for c in res:
        print(f"{c['name']:24s} -{c['opt']}: {c['steps']} steps "
              f"({c['closed_loop_steps']} with PWM), "
              f"bit-identical {c['bit_identical']}, duty max |diff| {c['duty_max_abs']:.2e}, "
              f"theta max |diff| {c['theta_max_abs_rad']:.2e} rad, faults/PWM/states equal "
              f"{c['fault_equal'] and c['pwm_equal'] and c['state_equal']}, replay vs loop "
              f"{c['loop_duty_max_abs']:.1e}, QEMU {c['qemu_wall_s']:.1f} s -> "
              f"{'AGREE' if c['ok'] else 'DIFFER'}")
    if a.cycles:
        g = res[0]["glue"]
        print(f"\nthe control interrupt's glue (fw_app_isr around the core: {GLUE_WHAT}), "
              f"measured on this image: {g['low']:.0f} .. {g['high']:.0f} cycles per period "
              f"(low .. high), trm {g['trm']:.0f}; the whole interrupt, locked mover, "
              f"median {g['isr_high']:.0f} (high)")
        verdicts = [report_cycles(c) for c in res]
        print(f"\nverdict: control interrupt (control half - inputs + glue {g['high']:.0f} + "
              f"ISR entry/exit {cm4.ISR_OVERHEAD[1]}) <= {CTL_TARGET} cycles (high model) in "
              f"every measured period of every scenario: {'yes' if all(verdicts) else 'no'}; "
              f"--cycles run {time.perf_counter() - t0:.0f} s")
    return 0 if all(c["ok"] for c in res) else 1


if __name__ == "__main__":
    raise SystemExit(main())
