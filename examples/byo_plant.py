"""Bring your own plant: the firmware core stepped from Python against a small
numpy PMLSM model (d-axis saturation, viscous friction only, forward-Euler
sub-steps). The saturation matters: the firmware decides the magnet polarity
from the different response to +i_d and -i_d pulses; a model without it is
refused at start-up with fault 0xFF04 (POLARITY_UNDETERMINED).

Replace `NumpyPlant` by your own model (motulator, an FMU exported from
Simulink, a measured model): the firmware only needs the sampled phase
currents (A) and the DC-link voltage (V) once per PWM period, and returns the
duty cycles (0..1) to apply over the NEXT period.

The drive is commanded in linear units (m/s, N): ``Firmware.set_speed_ref_mps``;
force mode would use ``set_force_ref_N``. A configuration the firmware refuses
raises ``sim_fallback.ConfigError`` naming the field, its value and its range.

    python examples/byo_plant.py            # 0.5 s at 0.32 m/s, 65 N load at 0.35 s
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

try:
    from sim_fallback import Firmware, fw_config, load_motor
except ImportError:  # run from a source checkout without installing
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from sim_fallback import Firmware, fw_config, load_motor


class NumpyPlant:
    """dq model in the true rotor frame, linear mechanics, ideal average inverter."""

    def __init__(self, R=0.958, L_d=0.012, L_q=0.018, psi_f=0.1827, dL=0.0012, I_sat=5.0,
                 tau=0.024, mass=32.1, b=8.57, u_dc=300.0, x0=0.0):
        self.R, self.L_d, self.L_q, self.psi_f = R, L_d, L_q, psi_f
        self.dL, self.I_sat = dL, I_sat
        self.k = math.pi / tau  # theta_e = k x
        self.mass, self.b, self.u_dc = mass, b, u_dc
        self.i_dq = np.zeros(2)
        self.x, self.v = x0, 0.0

    def phase_currents(self) -> np.ndarray:
        th = self.k * self.x
        c, s = math.cos(th), math.sin(th)
        i_a = c * self.i_dq[0] - s * self.i_dq[1]
        i_b = s * self.i_dq[0] + c * self.i_dq[1]
        return np.array([i_a, -0.5 * i_a + 0.5 * math.sqrt(3) * i_b,
                         -0.5 * i_a - 0.5 * math.sqrt(3) * i_b])

    def step(self, duty_abc: np.ndarray, on: bool, dt: float, n_sub: int = 8,
             load_N: float = 0.0) -> None:
        u = duty_abc * self.u_dc if on else np.full(3, self.u_dc / 2)
        u_a = 2 / 3 * (u[0] - 0.5 * u[1] - 0.5 * u[2])
        u_b = (u[1] - u[2]) / math.sqrt(3)
        h = dt / n_sub
        for _ in range(n_sub):
            th = self.k * self.x
            c, s = math.cos(th), math.sin(th)
            u_d, u_q = c * u_a + s * u_b, -s * u_a + c * u_b
            w = self.k * self.v
            i_d, i_q = self.i_dq
            z = i_d / self.I_sat
            L_dd = self.L_d - self.dL * math.tanh(z)  # incremental d inductance
            psi_d = self.psi_f + self.L_d * i_d - self.dL * self.I_sat * math.log(math.cosh(z))
            di_d = (u_d - self.R * i_d + w * self.L_q * i_q) / L_dd
            di_q = (u_q - self.R * i_q - w * psi_d) / self.L_q
            F = 1.5 * self.k * (psi_d * i_q - self.L_q * i_q * i_d)
            self.i_dq += h * np.array([di_d, di_q])
            self.x += h * self.v
            self.v += h * (F - self.b * self.v - load_N) / self.mass


def main(t_end: float = 0.5, v_mps: float = 0.32, load_N: float = 65.0, t_load: float = 0.35,
         x0: float = 0.0073) -> dict[str, float]:
    motor = load_motor("paper_salient")
    cfg = fw_config(motor, "sogi_adaptive")   # nominal parameters + gains
    fw = Firmware(cfg)                        # raises ConfigError on a refused field
    plant = NumpyPlant(x0=x0, u_dc=300.0)
    dt = 1.0 / cfg.f_pwm_Hz
    fw.enable("speed")
    fw.set_speed_ref_mps(v_mps)
    duty, on = np.full(3, 0.5), False         # latched duties (one-period delay)
    rng = np.random.default_rng(0)
    err = []
    for k in range(int(t_end / dt)):
        i_meas = plant.phase_currents() + rng.normal(0.0, 0.012, 3)  # your ADC here
        new_duty, new_on = fw.step(i_meas, plant.u_dc)
        plant.step(duty, on, dt, load_N=load_N if k * dt >= t_load else 0.0)  # previous duties
        duty, on = new_duty, new_on
        if k * dt > 0.3:
            snap = fw.snapshot()
            e = (plant.k * plant.x - snap["theta_hat_rad"] + math.pi) % (2 * math.pi) - math.pi
            err.append(e)
    err = np.asarray(err)
    out = {"position_error_rms_rad": float(np.sqrt(np.mean(err**2))),
           "position_error_max_rad": float(np.max(np.abs(err))),
           "speed_mps": float(plant.v),
           "speed_rpm": float(plant.v * plant.k * 60 / (2 * math.pi * cfg.pole_pairs)),
           "fault_code": fw.fault_code()}
    return out


if __name__ == "__main__":
    print(main())
