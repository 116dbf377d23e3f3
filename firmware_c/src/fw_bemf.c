/**
 * @file fw_bemf.c
 * @brief Back-EMF observer and the injection / back-EMF handover (fw_bemf.h).
 */
#include <math.h>
#include <stdbool.h>
#include <string.h>

#include "pmlsm/fw_bemf.h"

#define BEMF_HOLD_S 0.005f     /* the switching condition must hold this long */
#define BEMF_RAMP_S 0.010f     /* injection ramp down once on the back-EMF, full -> share */
#define BEMF_RAMP_BACK_S 0.002f /* injection back, share -> full: a load step brakes a light
                                 * mover through the band in ~10 ms (docs/bemf.md) */
#define BEMF_HF_SETTLE_S 0.002f /* HF path settling after the injection is back */

void fw_bemf_init(fw_bemf_t *b, const fw_config_t *cfg, float dt_s) {
  memset(b, 0, sizeof(*b));
  b->R_ohm = cfg->machine.R_ohm;
  b->L_d_H = cfg->machine.L_d_H;
  b->L_q_H = cfg->machine.L_q_H;
  b->psi_f_Wb = cfg->machine.psi_f_Wb;
  b->inv_psi = 1.0f / cfg->machine.psi_f_Wb;
  /* bemf_xc_comp: the saliency's rate term (fw_bemf_update); 0 = off, as before */
  b->dL_H = cfg->estimator.bemf_xc_comp ? cfg->machine.L_q_H - cfg->machine.L_d_H : 0.0f;
  b->dt_s = dt_s;
  b->a_f = 1.0f - expf(-dt_s / FW_BEMF_TAU_S);
  b->inv_dt = 1.0f / dt_s;
  b->w_on = cfg->estimator.bemf_e_on_V / cfg->machine.psi_f_Wb;
  b->w_off = cfg->estimator.bemf_e_off_V / cfg->machine.psi_f_Wb;
  b->e_on2 = cfg->estimator.bemf_e_on_V * cfg->estimator.bemf_e_on_V;
  b->e_off2 = cfg->estimator.bemf_e_off_V * cfg->estimator.bemf_e_off_V;
  b->e_min2 = 0.25f * b->e_off2; /* (half the switch-off level)^2 */
  b->inj_share = cfg->estimator.bemf_inj_share;
  b->step_down = dt_s / BEMF_RAMP_S * (1.0f - b->inj_share);
  b->step_back = dt_s / BEMF_RAMP_BACK_S * (1.0f - b->inj_share);
  fw_bemf_reset(b);
}

void fw_bemf_reset(fw_bemf_t *b) {
  b->active = 0u;
  b->going_up = 0u;
  b->t_cond_s = 0.0f;
  b->inj_scale = 1.0f;
  b->t_full_s = 0.0f;
  b->e_d_f = b->e_q_f = 0.0f;
  b->err_rad = 0.0f;
  b->err_fresh = 1u;
  b->w_neg = 0u;
  b->i_prev_A[0] = b->i_prev_A[1] = 0.0f;
}

void fw_bemf_catch(fw_bemf_t *b, float w0, const float i_dq_A[2]) {
  fw_bemf_reset(b);
  b->active = 1u;
  b->going_up = 1u;
  b->e_d_f = 0.0f;
  b->e_q_f = w0 * b->psi_f_Wb; /* signed: e_q = w psi_f cos(dtheta) */
  b->i_prev_A[0] = i_dq_A[0];
  b->i_prev_A[1] = i_dq_A[1];
}

/** |filtered back-EMF|^2 (V^2). */
static float mag2(const fw_bemf_t *b) { return b->e_d_f * b->e_d_f + b->e_q_f * b->e_q_f; }

float fw_bemf_angle_of(const fw_bemf_t *b, float e_d, float e_q, uint8_t w_neg) {
  if (e_d * e_d + e_q * e_q < b->e_min2) {
    return 0.0f;
  }
  const float ang = fw_atan2_inline_f32(-e_d, e_q); /* every period above the handover */
  return w_neg ? fw_wrap_pi_f32(ang + FW_PI_F32) : ang;
}

/** Angle error of the filtered back-EMF (0 below half the switch-off level). */
static float angle(const fw_bemf_t *b) {
  return fw_bemf_angle_of(b, b->e_d_f, b->e_q_f, b->w_neg);
}

void fw_bemf_update(fw_bemf_t *b, const float u_dq_V[2], const float i_dq_A[2], float w_hat,
                    float w_frame) {
  if (!b->active && fabsf(w_hat) < 0.5f * b->w_off) {
    b->e_d_f = b->e_q_f = 0.0f; /* far below the handover: nothing to observe */
    b->err_rad = 0.0f;
    b->err_fresh = 1u;
    b->i_prev_A[0] = i_dq_A[0]; /* the residual's L di/dt needs only the last current */
    b->i_prev_A[1] = i_dq_A[1];
    return;
  }
  float e[2];
  fw_bemf_residual(u_dq_V, i_dq_A, b->i_prev_A, b->inv_dt, w_frame, b->R_ohm, b->L_d_H,
                   b->L_q_H, e);
  if (b->dL_H != 0.0f) {
    /* Saliency (bemf_xc_comp): the inductance seen in the estimated frame turns with
     * the angle error dtheta, and its rate d(dtheta)/dt = w - w_frame leaves
     * -(L_q - L_d) i (w - w_frame) in the residual (the cross terms above take the
     * frame's speed, exact only for L_d = L_q). Divided by w psi_f that is a lag or lead
     * of (L_q - L_d) i_q / (w psi_f) on the angle error: a lag when the thrust brakes
     * (i_q w < 0), 3 ms at 10 A and 0.25 m/s on iron_core_linear, and the observer
     * oscillated and lost the angle there. The mover's speed w from the residual's own
     * e_q = w psi_f cos dtheta (its L di/dt ripple is low-passed below with the rest). */
    const float dw = e[1] * b->inv_psi - w_frame;
    e[0] += b->dL_H * i_dq_A[1] * dw;
    e[1] += b->dL_H * i_dq_A[0] * dw;
  }
  b->e_d_f += b->a_f * (e[0] - b->e_d_f);
  b->e_q_f += b->a_f * (e[1] - b->e_q_f);
  b->w_neg = (uint8_t)(w_hat < 0.0f);
  /* the angle error for this period: fw_bemf_prepare (the supervision) forms it
   * when the PLL uses it (next period), else on demand (fw_bemf_error;
   * fw_bemf_schedule when it hands over) */
  b->err_fresh = 0u;
}

void fw_bemf_prepare(fw_bemf_t *b) {
  if (b->active && !b->err_fresh) {
    b->err_rad = angle(b);
    b->err_fresh = 1u;
  }
}

float fw_bemf_error(const fw_bemf_t *b) { return b->err_fresh ? b->err_rad : angle(b); }

void fw_bemf_schedule(fw_bemf_t *b, float w_hat, uint8_t hf_settled) {
  const float w = fabsf(w_hat);
  if (b->w_on <= 0.0f) {
    return; /* handover off: injection only */
  }
  bool lost = false; /* the back-EMF is too small to give an angle */
  if (!b->active) {
    if (!(w > b->w_on)) {
      b->t_cond_s = 0.0f;
      return; /* on injection, at full amplitude (it is restored before leaving) */
    }
    b->t_cond_s += b->dt_s;
    if (b->t_cond_s >= BEMF_HOLD_S) {
      b->active = 1u; /* both estimates valid here: switch the PLL, then reduce injection */
      /* the angle error the PLL reads next period: fw_bemf_prepare forms it now
       * that the observer is active (or fw_bemf_error on demand), from the
       * filters of this update, which nothing changes before (its atan2 was the
       * control interrupt's worst period in the back-EMF regime) */
      b->err_fresh = 0u;
      b->going_up = 1u;
      b->t_cond_s = 0.0f;
    }
  } else {
    /* Going down, the measured back-EMF |e| = |w| psi_f below the band counts as much as
     * the speed estimate: a load step can brake the mover faster than the observer
     * follows, and then the back-EMF falls first. Going up from injection the estimate
     * decides (there |e| carries the HF ripple's L di/dt, +-0.5 V: it would hold the
     * handover back). */
    const float e2 = mag2(b);
    lost = e2 < b->e_min2;
    if (w < b->w_off || e2 < b->e_off2) {
      b->going_up = 0u; /* injection back first, PLL follows when the HF path has settled */
    } else if (!b->going_up && w > b->w_on && e2 > b->e_on2) {
      b->going_up = 1u; /* changed its mind on the way down */
    }
  }
  if (b->active && b->going_up) {
    /* a compare, not fmaxf: newlib's is a call that classifies both operands
     * (about 60 cycles per period on the M4 in the back-EMF regime); both are
     * finite here, where the two agree */
    const float down = b->inj_scale - b->step_down;
    b->inj_scale = down > b->inj_share ? down : b->inj_share;
    b->t_full_s = 0.0f;
  } else {
    const float up = b->inj_scale + b->step_back;
    b->inj_scale = up < 1.0f ? up : 1.0f; /* as above, fminf */
    b->t_full_s = b->inj_scale >= 1.0f ? b->t_full_s + b->dt_s : 0.0f;
    /* the PLL returns to the HF error once the extraction has settled at full injection,
     * or at once, at whatever injection, when the back-EMF is too small to give an angle
     * (it would coast on a zero error; E_q / E_d does not depend on the amplitude) */
    if (b->active && hf_settled && (b->t_full_s >= BEMF_HF_SETTLE_S || lost)) {
      b->active = 0u;
    }
  }
}
