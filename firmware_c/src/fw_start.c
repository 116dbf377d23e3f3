/**
 * @file fw_start.c
 * @brief Start-up: flying-start observation and catch, saliency check,
 *        polarity test (see fw_start.h).
 */
#include <math.h>
#include <string.h>

#include "pmlsm/fw_ctrl.h"

void fw_start_init(fw_start_t *s, float dt_s) {
  memset(s, 0, sizeof(*s));
  s->fly_a = 1.0f - expf(-dt_s / FW_FLY_TAU_S);
  s->inv_dt = 1.0f / dt_s;
}

void fw_start_reset(fw_start_t *s) {
  const float fly_a = s->fly_a, inv_dt = s->inv_dt;
  memset(s, 0, sizeof(*s));
  s->fly_a = fly_a;
  s->inv_dt = inv_dt;
}

/* ---- ALIGN ---------------------------------------------------------------- */

void fw_start_fly_observe(fw_start_t *s, const fw_cfg_machine_t *mach, fw_vec2_f32_t i_f_ab,
                          float phase_time_s) {
  const float L = 0.5f * (mach->L_d_H + mach->L_q_H);
  const float inv_dt = s->inv_dt;
  float ea = s->u_ab_prev_V[0] - mach->R_ohm * i_f_ab.x -
             L * (i_f_ab.x - s->i_f_ab_prev_A[0]) * inv_dt;
  float eb = s->u_ab_prev_V[1] - mach->R_ohm * i_f_ab.y -
             L * (i_f_ab.y - s->i_f_ab_prev_A[1]) * inv_dt;
  s->i_f_ab_prev_A[0] = i_f_ab.x;
  s->i_f_ab_prev_A[1] = i_f_ab.y;
  const float a = s->fly_a;
  float pa = s->fly_e_ab_V[0], pb = s->fly_e_ab_V[1];
  s->fly_e_ab_V[0] += a * (ea - pa);
  s->fly_e_ab_V[1] += a * (eb - pb);
  if (phase_time_s >= FW_FLY_WINDOW_S) {
    /* angle step between successive filtered vectors (cross / dot) */
    float cr = pa * s->fly_e_ab_V[1] - pb * s->fly_e_ab_V[0];
    float dt = pa * s->fly_e_ab_V[0] + pb * s->fly_e_ab_V[1];
    s->fly_rot_rad += fw_atan2_f32(cr, dt);
  }
}

void fw_start_fly_set_u(fw_start_t *s, fw_vec2_f32_t u_f_ab) {
  s->u_ab_prev_V[0] = u_f_ab.x;
  s->u_ab_prev_V[1] = u_f_ab.y;
}

fw_fault_t fw_start_fly_catch(fw_start_t *s, const fw_config_t *cfg, float bemf_w_on,
                              float *theta_rad, float *w0_radps) {
  const float ea = s->fly_e_ab_V[0], eb = s->fly_e_ab_V[1];
  const float E = sqrtf(ea * ea + eb * eb);
  if (!(bemf_w_on > 0.0f) || E < cfg->estimator.bemf_e_off_V || fabsf(s->fly_rot_rad) < 0.05f) {
    return FW_FAULT_MOVING_AT_ENABLE; /* too slow for the back-EMF, too fast for injection */
  }
  const float w0 = (s->fly_rot_rad > 0.0f ? 1.0f : -1.0f) * E / cfg->machine.psi_f_Wb;
  /* e_ab = w psi_f (-sin theta, cos theta); the filter lags by about w tau */
  float th = fw_atan2_f32(-ea, eb) + (w0 < 0.0f ? FW_PI_F32 : 0.0f) + w0 * FW_FLY_TAU_S;
  *theta_rad = fw_wrap_pi_f32(th);
  *w0_radps = w0;
  s->flying = 1u;
  return FW_FAULT_NONE;
}

bool fw_start_align_done(const fw_cfg_estimator_t *est, float phase_time_s, uint32_t inj_idx,
                         uint32_t n_inj) {
  const uint32_t last_idx = n_inj / 4u > 0u ? n_inj / 4u - 1u : 0u;
  return phase_time_s >= est->align_time_s && inj_idx == last_idx;
}

/* ---- SALIENCY ------------------------------------------------------------- */

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
  const uint32_t pair = s->pol_k / per_pair;
  const uint32_t j = s->pol_k % per_pair;
  const uint32_t seg = j / n;
  const uint32_t in_seg = j % n;
  const float v = est->pol_pulse_V;

  if (pair >= est->pol_pulse_pairs) { /* decision */
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
