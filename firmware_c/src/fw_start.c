/**
 * @file fw_start.c
 * @brief Start-up: flying-start observation and catch, saliency check and its
 *        judgement, polarity test and its decision (see fw_start.h).
 */
#include <math.h>
#include <string.h>

#include "pmlsm/fw_start.h"

void fw_start_init(fw_start_t *s, float dt_s) {
  memset(s, 0, sizeof(*s));
  s->fly_a = 1.0f - expf(-dt_s / FW_FLY_TAU_S);
  s->inv_dt = 1.0f / dt_s;
}

/* fw_start_reset clears every field but the two configured ones, one by one: a
 * field added to fw_start_t must be cleared there too (this size then changes). */
_Static_assert(sizeof(fw_start_t) == 96u, "fw_start_reset: clear the new field");

void fw_start_reset(fw_start_t *s) {
  /* field by field, not memset (GCC turns a whole-struct clear, a compound
   * literal included, into a call of newlib's memset: about 120 cycles on the
   * Cortex-M4F in the control interrupt's handover to closed loop) */
  s->pol_k = 0u;
  s->pol_base = s->pol_ext = 0.0f;
  s->pol_sum_pos = s->pol_sum_neg = 0.0f;
  s->sal_acc[0] = s->sal_acc[1] = s->sal_acc[2] = s->sal_acc[3] = 0.0f;
  s->sal_k = 0u;
  s->u_ab_prev_V[0] = s->u_ab_prev_V[1] = 0.0f;
  s->i_f_ab_prev_A[0] = s->i_f_ab_prev_A[1] = 0.0f;
  s->fly_e_ab_V[0] = s->fly_e_ab_V[1] = 0.0f;
  s->fly_rot_rad = 0.0f;
  s->fly_cr = s->fly_dot = 0.0f;
  s->fly_rot_margin = 0.0f; /* rotation 0: no margin */
  s->fly_due = 0u;
  s->flying = 0u;
  s->sal_retries = 0u;
}

/* ---- ALIGN ---------------------------------------------------------------- */

void fw_start_fly_add(fw_start_t *s) {
  s->fly_rot_rad += fw_atan2_f32(s->fly_cr, s->fly_dot);
  s->fly_due = 0u;
  /* for fw_start_fly_catch_speed: half the margin to FW_FLY_ROT_MIN_RAD, or 0
   * (also for NaN) */
  const float m = fabsf(s->fly_rot_rad) - FW_FLY_ROT_MIN_RAD;
  s->fly_rot_margin = m > 1e-3f ? 0.5f * m : 0.0f;
}

fw_fault_t fw_start_fly_catch(fw_start_t *s, const fw_config_t *cfg, float bemf_w_on,
                              float *theta_rad, float *w0_radps) {
  fw_start_fly_flush(s); /* this period's step of the rotation */
  const fw_fault_t f = fw_start_fly_catch_speed(s, cfg, bemf_w_on, w0_radps);
  if (f == FW_FAULT_NONE) {
    *theta_rad = fw_start_fly_catch_angle(s, *w0_radps);
  }
  return f;
}

float fw_start_fly_catch_angle(const fw_start_t *s, float w0) {
  const float ea = s->fly_e_ab_V[0], eb = s->fly_e_ab_V[1];
  /* e_ab = w psi_f (-sin theta, cos theta); the filter lags by about w tau */
  float th = fw_atan2_f32(-ea, eb) + (w0 < 0.0f ? FW_PI_F32 : 0.0f) + w0 * FW_FLY_TAU_S;
  return fw_wrap_pi_f32(th);
}

/* ---- SALIENCY ------------------------------------------------------------- */

fw_fault_t fw_start_fly_catch_begin(fw_start_t *s, const fw_config_t *cfg, float bemf_w_on,
                                    fw_obs_t *obs, fw_foc_t *foc) {
  float w0;
  const fw_fault_t f = fw_start_fly_catch_speed(s, cfg, bemf_w_on, &w0);
  if (f != FW_FAULT_NONE) {
    return f;
  }
  fw_obs_catch_speed(obs, w0);
  fw_foc_speed_clear(foc);
  return FW_FAULT_NONE;
}

void fw_start_fly_catch_finish(const fw_start_t *s, fw_obs_t *obs, fw_bemf_t *bemf,
                               fw_mon_t *mon) {
  const float w0 = obs->omega_f; /* the catch's speed (fw_obs_catch_speed), as it left it */
  fw_obs_catch_angle(obs, fw_start_fly_catch_angle(s, w0));
  const float i0[2] = {0.0f, 0.0f};
  fw_bemf_catch(bemf, w0, i0);
  fw_mon_run_start(mon);
}

void fw_start_saliency_begin(fw_start_t *s) {
  s->sal_k = 0u;
  memset(s->sal_acc, 0, sizeof(s->sal_acc));
}

void fw_start_saliency_update(fw_start_t *s, uint32_t n_inj, fw_vec2_f32_t e_raw) {
  const uint32_t col_len = FW_SAL_PERIODS * n_inj;
  if (s->sal_k % col_len >= n_inj) {
    const uint32_t col = s->sal_k / col_len; /* 0: square wave on d^, 1: on q^ */
    s->sal_acc[2u * col] += e_raw.x;
    s->sal_acc[2u * col + 1u] += e_raw.y;
  }
}

bool fw_start_saliency_on_q(const fw_start_t *s, uint32_t n_inj) {
  return s->sal_k >= FW_SAL_PERIODS * n_inj;
}

bool fw_start_saliency_advance(fw_start_t *s, uint32_t n_inj) {
  return ++s->sal_k == 2u * FW_SAL_PERIODS * n_inj;
}

void fw_start_saliency_means(const fw_start_t *s, uint32_t n_inj, float y[4]) {
  const float n_avg = (float)((FW_SAL_PERIODS - 1u) * n_inj);
  const float inv = 1.0f / n_avg;
  for (int i = 0; i < 4; i++) {
    y[i] = s->sal_acc[i] * inv;
  }
}

/* ---- POLARITY ------------------------------------------------------------- */

void fw_start_polarity_begin(fw_start_t *s) {
  s->pol_k = 0u;
  s->pol_sum_pos = s->pol_sum_neg = 0.0f;
}

float fw_start_polarity_step(fw_start_t *s, const fw_cfg_estimator_t *est, float i_d,
                             fw_pol_result_t *res) {
  const uint32_t n = est->pol_pulse_samples;
  const uint32_t per_pair = 6u * n;

  /* pol_k / per_pair >= pol_pulse_pairs, without the division (in 64 bits: the
   * product does not wrap) */
  if ((uint64_t)s->pol_k >= (uint64_t)est->pol_pulse_pairs * per_pair) { /* decision */
    const float p = s->pol_sum_pos, m = s->pol_sum_neg;
    if (p > m * (1.0f + est->pol_margin)) {
      *res = FW_POL_ALIGNED;
    } else if (m > p * (1.0f + est->pol_margin)) {
      *res = FW_POL_FLIPPED;
    } else {
      *res = FW_POL_UNDETERMINED;
    }
    return 0.0f;
  }
  *res = FW_POL_BUSY;
  const uint32_t j = s->pol_k % per_pair;
  const uint32_t seg = j / n;
  const uint32_t in_seg = j % n;
  const float v = est->pol_pulse_V;

  /* Per pair: 0 (settle, lets the last command take effect), +V, -V, 0, -V, +V.
   * The baseline is sampled at the start of each excursion, the extreme over
   * the pulse and the return (the one-period delay puts the peak one sample
   * into the return segment). */
  if (in_seg == 0u && (seg == 1u || seg == 4u)) {
    s->pol_base = i_d;
    s->pol_ext = i_d;
  }
  if (seg == 1u || seg == 2u) {
    s->pol_ext = i_d > s->pol_ext ? i_d : s->pol_ext;
  } else if (seg == 4u || seg == 5u) {
    s->pol_ext = i_d < s->pol_ext ? i_d : s->pol_ext;
  }
  if (in_seg == n - 1u && seg == 2u) {
    s->pol_sum_pos += s->pol_ext - s->pol_base;
  } else if (in_seg == n - 1u && seg == 5u) {
    s->pol_sum_neg += s->pol_base - s->pol_ext;
  }
  s->pol_k++;
  switch (seg) {
  case 1u:
  case 5u:
    return v;
  case 2u:
  case 4u:
    return -v;
  default:
    return 0.0f;
  }
}

fw_fault_t fw_start_saliency_done(fw_start_t *s, const fw_config_t *cfg, uint32_t n_inj,
                                  float dt_s, fw_mon_t *mon, fw_obs_t *obs, bool *again) {
  float y[4];
  fw_start_saliency_means(s, n_inj, y);
  const fw_fault_t f =
      fw_mon_saliency(mon, cfg, y[0], y[1], y[2], y[3], dt_s * cfg->estimator.u_inj_V);
  *again = false;
  if (f == FW_FAULT_EST_HF_ANGLE && s->sal_retries < FW_SAL_RETRIES) {
    /* The check measured the angle error (mod pi) from the full HF admittance:
     * turn the estimate by it; the orchestrator aligns and checks again, and a
     * second miss is the fault. */
    s->sal_retries++;
    fw_obs_rotate(obs, mon->sal_axis_rad);
    *again = true;
    return FW_FAULT_NONE;
  }
  if (f == FW_FAULT_NONE) {
    fw_start_polarity_begin(s);
  }
  return f;
}

fw_pol_result_t fw_start_polarity(fw_start_t *s, const fw_cfg_estimator_t *est, fw_obs_t *obs,
                                  float i_d_A, float *u_d_V, uint8_t *flipped) {
  fw_pol_result_t res;
  *u_d_V = fw_start_polarity_step(s, est, i_d_A, &res);
  if (res == FW_POL_ALIGNED) {
    *flipped = 0u;
  } else if (res == FW_POL_FLIPPED) {
    *flipped = 1u;
    fw_obs_flip(obs);
  }
  return res;
}
