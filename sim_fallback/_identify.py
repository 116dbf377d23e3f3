"""Motor identification run by the drive: R, L_d (with its saturation), L_q, psi_f,
mover mass and friction, from what the drive measures.

The procedure uses only the drive's own signals (the firmware snapshot: the
fundamental voltage it commands, the fundamental currents it measures, its speed
and position estimates and the HF response), the way it would on hardware; the
simulator's truth is used by the tests only, to judge the result.

1. Start-up at standstill (FORCE mode, no thrust): the standstill saliency check
   measures the two inductances (eigenvalues of the HF admittance), repeated over
   several starts.
2. R: two d-axis DC current levels along the magnet (no thrust), R = du_d / di_d.
3. L_d(i_d): the raw HF response along d^ (pseudo-filter extraction:
   E_d = T_s u_inj / L_dd) at five d-axis bias currents; L_d0, dL and I_sat of
   L_dd = L_d0 - dL tanh(i_d / I_sat) by least squares.
4. psi_f: the speed loop runs the mover at +v and -v; psi_f = (u_q - R i_q)/w
   from the two steady windows (offsets cancel in the difference).
5. Mass and friction: thrust-current steps back and forth within the travel;
   K_F i_q = m a + b v + F_c sgn(v), with v and a from local quadratic fits of
   the position estimate, solved by least squares.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ._motors import Motor, fw_config
from ._sim import SIM_REF_FORCE, SIM_REF_SPEED, Sim

#: Relaxed monitor settings while identifying an unknown motor: the saliency
#: check must measure, not judge, and the start must not depend on guessed gains.
IDENT_FW = {"mon_sal_tol": 10.0, "saliency_min": 0.05}


@dataclass
class Identified:
    """Identified parameters (SI, linear) with one-sigma uncertainties."""

    values: dict[str, float] = field(default_factory=dict)
    sigma: dict[str, float] = field(default_factory=dict)
    log: list[str] = field(default_factory=list)

    def rel_error(self, truth: dict[str, float]) -> dict[str, float]:
        return {k: (v - truth[k]) / truth[k] for k, v in self.values.items() if k in truth}

    def motor_toml(self, name: str, base: Motor) -> str:
        """A linear motor file with the identified values (controller section from base)."""
        v = self.values
        c = base.controller
        return "\n".join([
            "# Identified by the drive (sim_fallback/_identify.py); sigma in comments.",
            "[motor]", f'name = "{name}"', 'parameterization = "linear"',
            f'description = "identified from {base.name}"', "",
            "[electrical]",
            f"R_ohm = {v['R_ohm']:.6g}  # +- {self.sigma['R_ohm']:.2g}",
            f"L_d_H = {v['L_d_H']:.6g}  # +- {self.sigma['L_d_H']:.2g}",
            f"L_q_H = {v['L_q_H']:.6g}  # +- {self.sigma['L_q_H']:.2g}",
            f"psi_f_Wb = {v['psi_f_Wb']:.6g}  # +- {self.sigma['psi_f_Wb']:.2g}",
            f"dL_sat_H = {max(v['dL_sat_H'], 0.0):.6g}",
            f"I_sat_A = {max(v['I_sat_A'], 0.01):.6g}", "",
            "[mechanical]",
            f"pole_pitch_m = {base.tau_m:.6g}",
            f"mass_kg = {v['mass_kg']:.6g}  # +- {self.sigma['mass_kg']:.2g}",
            f"viscous_Ns_per_m = {max(v['b_visc_Ns_per_m'], 0.0):.6g}",
            f"coulomb_friction_N = {max(v['F_coulomb_N'], 0.0):.6g}",
            f"static_friction_N = {max(v['F_coulomb_N'], 0.0):.6g}",
            f"pole_pairs = {base.pole_pairs:g}", "",
            "[controller]",
            *[f"{k} = {val!r}" for k, val in c.items() if isinstance(val, (int, float))],
            "",
        ])


class _Probe:
    """The drive as identification sees it: commands in, averaged snapshot out."""

    def __init__(self, sim: Sim) -> None:
        self.sim = sim
        self.L = sim._L
        self.h = sim.firmware.handle

    def run(self, seconds: float) -> list[dict[str, Any]]:
        """Advance, one snapshot per millisecond (what telemetry would deliver)."""
        out = []
        n = max(1, int(round(seconds / 0.001)))
        for _ in range(n):
            self.sim.advance(int(round(0.001 / self.sim.dt_s)), channels=["fault_code"])
            out.append(self.sim.snapshot())
        if out[-1]["fault_code"]:
            raise RuntimeError(f"drive fault 0x{out[-1]['fault_code']:04X} during identification")
        return out

    def ramp_id(self, target_A: float, seconds: float = 0.03) -> None:
        """Move the d-axis current reference in small steps: a current step of several
        amperes within one injection period would swamp the HF response."""
        s = self.sim.snapshot()
        start = float(s["i_dq_ref_A"][0])
        n = max(1, int(round(seconds / 0.001)))
        for k in range(1, n + 1):
            self.L.fw_set_id_ref(self.h, start + (target_A - start) * k / n)
            self.run(0.001)

    def mean(self, snaps: list[dict[str, Any]], key: str, idx: int | None = None) -> float:
        v = [s[key][idx] if idx is not None else s[key] for s in snaps]
        return float(np.mean(v))


def _start(sim: Sim) -> dict[str, Any]:
    sim.set_schedule(SIM_REF_FORCE, 0.0)
    sim.enable("force")
    p = _Probe(sim)
    p.run(0.15)
    s = sim.snapshot()
    if s["start_phase"] != 3:
        raise RuntimeError("start-up did not reach closed loop")
    return s


def identify(motor: Motor, seed: int = 0, travel_m: float = 0.3, n_starts: int = 4,
             plant: dict[str, Any] | None = None, guess: dict[str, float] | None = None
             ) -> Identified:
    """Identify a motor on the simulated drive.

    ``guess`` holds the configuration the user starts from (fw_config_t fields,
    e.g. a datasheet's values); by default the motor file's own. ``plant``
    overrides what the simulated motor *is* (the truth to be found).
    """
    res = Identified()
    fw = dict(IDENT_FW)
    fw.update(guess or {})
    cfg0 = fw_config(motor, "pseudo", **fw)
    i_max = float(cfg0.i_max_A)
    Ts, u_inj = 1.0 / float(cfg0.f_pwm_Hz), float(cfg0.u_inj_V)
    q_larger = float(cfg0.L_q_H) > float(cfg0.L_d_H)

    # 1. inductances from the standstill saliency check, several starts
    Ls, Ll = [], []
    for k in range(n_starts):
        with Sim(motor, extractor="pseudo", seed=seed * 100 + k, plant=plant, fw=fw,
                 x0_m=(0.13 + 0.37 * k) * motor.tau_m) as sim:
            s = _start(sim)
            Ls.append(s["L_small_meas_H"])
            Ll.append(s["L_large_meas_H"])
    L_d_ss = float(np.mean(Ls if q_larger else Ll))
    L_q_ss = float(np.mean(Ll if q_larger else Ls))

    with Sim(motor, extractor="pseudo", seed=seed * 100 + 99, plant=plant, fw=fw) as sim:
        p = _Probe(sim)
        _start(sim)
        # 2. resistance: two d-axis current levels along the magnet (no thrust)
        pts = []
        for frac in (0.2, 0.4, 0.2, 0.4):
            p.ramp_id(frac * i_max)
            p.run(0.03)
            snaps = p.run(0.04)
            pts.append((p.mean(snaps, "i_dq_A", 0), p.mean(snaps, "u_dq_V", 0)))
        i_arr, u_arr = np.array(pts).T
        A = np.vstack([i_arr, np.ones_like(i_arr)]).T
        (R, u0), resid, *_ = np.linalg.lstsq(A, u_arr, rcond=None)
        res.values["R_ohm"] = float(R)
        res.sigma["R_ohm"] = float(np.std(u_arr - A @ np.array([R, u0])) /
                                   max(np.ptp(i_arr), 1e-9) * 2.0)

        # 3. L_d(i_d): raw HF response on d^ at bias currents
        ids, lds = [], []
        for frac in (-0.4, -0.2, 0.0, 0.2, 0.4):
            p.ramp_id(frac * i_max)
            p.run(0.02)
            snaps = p.run(0.03)
            ids.append(p.mean(snaps, "i_dq_A", 0))
            lds.append(Ts * u_inj / p.mean(snaps, "hf_amp_A"))
        p.ramp_id(0.0)
        ids_a, lds_a = np.array(ids), np.array(lds)
        best = None
        for i_sat in np.geomspace(0.2, 50.0, 120) * max(i_max, 1e-3) / 10.0:
            B = np.vstack([np.ones_like(ids_a), -np.tanh(ids_a / i_sat)]).T
            coef, *_ = np.linalg.lstsq(B, lds_a, rcond=None)
            err = float(np.sum((B @ coef - lds_a) ** 2))
            if best is None or err < best[0]:
                best = (err, coef, i_sat)
        _, (L_d0, dL), i_sat = best
        res.values["L_d_H"] = float(L_d0)
        res.values["dL_sat_H"] = float(dL)
        res.values["I_sat_A"] = float(i_sat)
        res.sigma["L_d_H"] = float(abs(L_d0 - L_d_ss))  # two methods disagree by this
        res.values["L_q_H"] = L_q_ss
        res.sigma["L_q_H"] = float(np.std(Ll if q_larger else Ls) / math.sqrt(n_starts))
        res.log.append(f"L_d from the saliency check {L_d_ss * 1e3:.3f} mH, from the bias "
                       f"sweep {L_d0 * 1e3:.3f} mH")

        # the motion experiments run on what was measured at standstill: the drive is
        # reconfigured with R, L_d, L_q and the current loop tuned to them, then restarts
        import ctypes as C

        from . import _lib
        p.L.fw_controlword(p.h, 0x00)  # disable voltage
        p.run(0.01)
        cfg = _lib.FwConfig.from_buffer_copy(bytes(sim.cfg))
        cfg.R_ohm, cfg.L_d_H, cfg.L_q_H = float(R), float(L_d0), float(L_q_ss)
        cfg.cur_kp_V_per_A = float(L_d0) * 1100.0
        cfg.cur_ki_V_per_As = float(R) * 1100.0
        issue = _lib.FwConfigIssue()
        if p.L.fw_set_config(p.h, C.byref(cfg), C.byref(issue)) != 0:
            raise RuntimeError("the drive refused the identified electrical parameters")
        sim.set_schedule(SIM_REF_FORCE, 0.0)
        sim.enable("force")
        p.run(0.15)

        # 4. psi_f: speed loop at +v and -v
        v_test = min(0.3, 0.25 * travel_m / 0.4)
        k_w = motor.mps_to_radps_e(1.0)
        p.L.fw_set_mode(p.h, 0)
        win = {}
        for sgn in (1.0, -1.0, 1.0):
            sim.set_schedule(SIM_REF_SPEED, sgn * v_test, k_w)
            p.run(0.25)
            snaps = p.run(0.1)
            win.setdefault(sgn, []).append((p.mean(snaps, "u_dq_V", 1), p.mean(snaps, "i_dq_A", 1),
                                            p.mean(snaps, "omega_hat_radps")))
        sim.set_schedule(SIM_REF_SPEED, 0.0, k_w)
        p.run(0.3)
        up = np.mean(win[1.0], axis=0)
        dn = np.mean(win[-1.0], axis=0)
        psi = ((up[0] - dn[0]) - R * (up[1] - dn[1])) / (up[2] - dn[2])
        psi_single = [(w[0] - R * w[1]) / w[2] for w in win[1.0] + win[-1.0]]
        res.values["psi_f_Wb"] = float(psi)
        res.sigma["psi_f_Wb"] = float(np.std(psi_single))

        # 5. mass and friction: the speed loop drives a sinusoidal speed profile in one
        # direction, then in the other (the Coulomb term has one sign per run and the
        # mover never sticks mid-run), the fit uses the thrust current it needed
        K_F = 1.5 * math.pi / motor.tau_m * psi
        v_mid = min(0.5, travel_m / 1.6)
        x_all, i_all, psi_rows = [], [], []
        for sgn in (1.0, -1.0):
            t_pts = np.arange(0.0, 0.9001, 0.01)
            prof = sgn * v_mid * (1.0 + 0.6 * np.sin(2 * math.pi * 3.0 * t_pts)) * np.minimum(
                1.0, t_pts / 0.1)
            t0 = sim.t_s
            sim.set_schedule(SIM_REF_SPEED, {"t_s": list(t0 + t_pts), "value": list(prof),
                                             "ramp": True}, k_w)
            snaps = p.run(0.9)
            x_all.append(np.array([q["pos_hat_m"] for q in snaps]))
            i_all.append(np.array([q["i_dq_A"][1] for q in snaps]))
            psi_rows += [(q["omega_hat_radps"], q["u_dq_V"][1] - R * q["i_dq_A"][1])
                         for q in snaps[100:]]
            sim.set_schedule(SIM_REF_SPEED, {"t_s": [sim.t_s, sim.t_s + 0.2],
                                             "value": [prof[-1], 0.0], "ramp": True}, k_w)
            p.run(0.45)  # back to rest under control
    # psi_f again, from the whole speed range of both runs: u_q - R i_q = psi w + c
    w_arr, y_arr = np.array(psi_rows).T
    (psi_r, _c0), *_ = np.linalg.lstsq(np.vstack([w_arr, np.ones_like(w_arr)]).T, y_arr,
                                       rcond=None)
    # a second estimate (whole speed sweep, dynamics included) widens the uncertainty
    res.log.append(f"psi_f from +-v windows {psi:.5f} Wb, from the speed sweep {psi_r:.5f} Wb")
    res.sigma["psi_f_Wb"] = max(res.sigma["psi_f_Wb"], abs(psi_r - psi) / 2.0)
    half = 15  # local quadratic fits over 31 ms
    rows, rhs = [], []
    t = (np.arange(-half, half + 1)) * 0.001
    V = np.vstack([np.ones_like(t), t, 0.5 * t * t]).T
    pinv = np.linalg.pinv(V)
    for x, iq in zip(x_all, i_all, strict=True):
        for k in range(half + 100, len(x) - half):  # after the initial ramp
            c = pinv @ x[k - half:k + half + 1]
            v, a = c[1], c[2]
            if abs(v) < 0.05:
                continue  # near standstill the Coulomb term's sign is undefined
            rows.append([a, v, math.copysign(1.0, v)])
            rhs.append(K_F * np.mean(iq[k - 2:k + 3]))
    M, y = np.array(rows), np.array(rhs)
    coef, *_ = np.linalg.lstsq(M, y, rcond=None)
    r = y - M @ coef
    cov = np.linalg.inv(M.T @ M) * float(np.var(r))
    res.values["mass_kg"] = float(coef[0])
    res.values["b_visc_Ns_per_m"] = float(coef[1])
    res.values["F_coulomb_N"] = float(coef[2])
    res.sigma["mass_kg"] = float(math.sqrt(cov[0, 0]))
    res.sigma["b_visc_Ns_per_m"] = float(math.sqrt(cov[1, 1]))
    res.sigma["F_coulomb_N"] = float(math.sqrt(cov[2, 2]))
    res.log.append(f"mass/friction fit over {len(y)} samples, K_F = {K_F:.3f} N/A")
    return res


def truth_of(motor: Motor, plant: dict[str, Any] | None = None) -> dict[str, float]:
    """The simulated motor's parameters in the identified names (test verdicts only)."""
    pl = dict(motor.plant)
    pl.update(plant or {})
    return {"R_ohm": pl["R_ohm"], "L_d_H": pl["L_d0_H"], "L_q_H": pl["L_q_H"],
            "psi_f_Wb": pl["psi_f_Wb"], "mass_kg": pl["mass_kg"],
            "b_visc_Ns_per_m": pl["b_visc_Ns_per_m"], "F_coulomb_N": pl["F_coulomb_N"],
            "dL_sat_H": pl["dL_sat_H"], "I_sat_A": pl["I_sat_A"]}
