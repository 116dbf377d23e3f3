/**
 * @file locked_mover.h
 * @brief Shared by the step benchmarks (host and Cortex-M4F harness): drive
 *        the core into closed loop against a locked mover at 0.4 rad
 *        (paper_salient dq model with d-axis saturation, 10 Euler sub-steps,
 *        one-period PWM delay) and record the last n_rec input samples.
 *        Header-only so that each harness compiles it with its own flags.
 */
#ifndef PMLSM_BENCH_LOCKED_MOVER_H
#define PMLSM_BENCH_LOCKED_MOVER_H

#include <math.h>

#include "pmlsm/fw_ctrl.h"

/** speed_mode: speed loop active (reference 0) instead of a 2 A force command. */
static void locked_mover_warm_up(fw_ctrl_t *c, int speed_mode, fw_inputs_t *rec, int n_rec) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  fw_init(c, &cfg);
  fw_current_zero_external(c); /* stepped in physical units: no raw samples */
  fw_set_mode(c, FW_MODE_FORCE);
  fw_set_iq_ref(c, 2.0f);
  if (speed_mode) {
    fw_set_mode(c, FW_MODE_SPEED);
    fw_set_speed_ref(c, 0.0f);
  }
  fw_controlword(c, FW_CW_SHUTDOWN);
  fw_controlword(c, FW_CW_ENABLE_OPERATION);
  double th = 0.4, id = 0, iq = 0, duty[3] = {0.5, 0.5, 0.5};
  int en = 0;
  const double dt = 1.0 / 24000.0, udc = 300.0;
  int n_total = (int)(0.2 * 24000) + n_rec;
  for (int k = 0; k < n_total; k++) {
    fw_inputs_t in;
    double cs = cos(th), sn = sin(th);
    double ia = id * cs - iq * sn, ib = id * sn + iq * cs;
    in.i_abc_A[0] = (float)ia;
    in.i_abc_A[1] = (float)(-0.5 * ia + 0.8660254 * ib);
    in.i_abc_A[2] = (float)(-0.5 * ia - 0.8660254 * ib);
    in.u_dc_V = (float)udc;
    if (k >= n_total - n_rec) {
      rec[k - (n_total - n_rec)] = in;
    }
    fw_outputs_t out;
    fw_step(c, &in, &out);
    if (en) {
      double va = duty[0] * udc, vb = duty[1] * udc, vc = duty[2] * udc;
      double ua = (2 * va - vb - vc) / 3, ub = (vb - vc) / sqrt(3.0);
      double ud = ua * cs + ub * sn, uq = -ua * sn + ub * cs;
      for (int j = 0; j < 10; j++) {
        double Ldd = 0.012 - 0.0012 * tanh(id / 5.0);
        id += dt / 10 * (ud - 0.958 * id) / Ldd;
        iq += dt / 10 * (uq - 0.958 * iq) / 0.018;
      }
    }
    duty[0] = out.duty_abc[0];
    duty[1] = out.duty_abc[1];
    duty[2] = out.duty_abc[2];
    en = out.pwm_enable;
  }
}

#endif
