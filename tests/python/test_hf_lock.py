"""The HF lock under high thrust current (docs/method.md section 6, "Bumpless SOGI gain").

The adaptive SOGI sees the fundamental current (a DC on a clamped mover) next to the
carrier; its quadrature state holds k times it, so each change of k rang the filter at
the carrier in proportion to the current, the ring demodulated into an angle error, the
error moved k again: above about 13 A the lock oscillated and was lost, on the ideal
iron_core_linear as on realistic_linear, with the fixed-k SOGI and the pseudo-filter
stable. ``sogi_bumpless`` moves the state with the gain; off by default (bit-identical)."""

from __future__ import annotations

import numpy as np
import pytest

from sim_fallback import Sim, fw_config, load_motor
from sim_fallback._sim import SIM_REF_FORCE

#: clamped-mover settings as identification step 7's (no thrust feed-forward, no witness,
#: no position-ripple correction: docs/method.md section 6)
CLAMP_FW = {"pll_accel_per_A": 0.0, "mon_bemf_min_mps": 1000.0,
            "rip_a2_rad": 0.0, "rip_b2_rad": 0.0}


def _clamped(motor: str, fw: dict, i_q_A: float) -> tuple[int, float]:
    """Fault code and the true angle error's standard deviation (rad el.) over the last
    0.1 s of 0.15 s at ``i_q_A`` in FORCE mode on a locked mover (ramped up in 20 ms)."""
    with Sim(motor, seed=1, plant={"locked": 1}, fw={**CLAMP_FW, **fw}, x0_m=0.0) as sim:
        sim.set_schedule(SIM_REF_FORCE, 0.0)
        sim.enable("force")
        sim.advance(int(0.3 / sim.dt_s))
        lib, h = sim._L, sim.firmware.handle
        for k in range(1, 21):
            lib.fw_set_iq_ref(h, i_q_A * k / 20)
            sim.advance(int(0.001 / sim.dt_s))
        d = sim.advance(int(0.15 / sim.dt_s),
                        channels=["theta_e_rad", "theta_hat_rad", "fault_code"])
    e = np.angle(np.exp(1j * (d["theta_e_rad"] - d["theta_hat_rad"])))
    return int(d["fault_code"].max()), float(np.std(e[len(e) // 3:]))


def test_default_off_and_realistic_linear_on() -> None:
    assert fw_config(load_motor("iron_core_linear")).sogi_bumpless == 0
    assert fw_config(load_motor("realistic_linear")).sogi_bumpless == 1


@pytest.mark.parametrize("motor", ["iron_core_linear", "realistic_linear"])
def test_lock_holds_at_16_A_only_with_the_bumpless_gain(motor: str) -> None:
    """16 A (1.6 x rated) on a clamped mover: without the bumpless gain the lock
    oscillates (std > 0.1 rad) or faults; with it the estimate stays within a std of
    0.02 rad, no fault."""
    fc0, s0 = _clamped(motor, {"sogi_bumpless": 0}, 16.0)
    assert fc0 != 0 or s0 > 0.1, (fc0, s0)
    fc1, s1 = _clamped(motor, {"sogi_bumpless": 1}, 16.0)
    assert fc1 == 0 and s1 < 0.02, (fc1, s1)
