/**
 * @file fw_foc.c
 * @brief Speed and current loops, voltage limit, modulation (see fw_foc.h).
 */
#include <stddef.h>

#include "pmlsm/fw_foc.h"

void fw_foc_reset(fw_foc_t *f, const fw_foc_param_t *p) {
  f->p = *p;
  const float u_lim = 1.0f; /* real limits are set every period from u_dc */
  fw_pi_init_f32(&f->pi_d, p->cur_kp_V_per_A, p->cur_ki_V_per_As, -u_lim, u_lim);
  fw_pi_init_f32(&f->pi_q, p->cur_kp_V_per_A, p->cur_ki_V_per_As, -u_lim, u_lim);
  fw_pi_init_f32(&f->pi_spd, p->spd_kp_A_per_radps, p->spd_ki_A_per_rad, -p->i_max_A,
                 p->i_max_A);
  f->u_dq_prev_V[0] = 0.0f;
  f->u_dq_prev_V[1] = 0.0f;
}

void fw_foc_init(fw_foc_t *f, const fw_foc_param_t *p) {
  fw_foc_reset(f, p);
  f->i_q_ref_A = 0.0f;
}

float fw_foc_speed_update(fw_foc_t *f, float w_ref_radps, float w_radps, float dt_s) {
  return fw_pi_step_f32(&f->pi_spd, w_ref_radps - w_radps, 0.0f, dt_s);
}

void fw_foc_speed_bumpless(fw_foc_t *f) {
  f->pi_spd.integ = fw_clampf(f->i_q_ref_A, -f->p.i_max_A, f->p.i_max_A);
}

void fw_foc_speed_clear(fw_foc_t *f) { f->pi_spd.integ = 0.0f; }

fw_vec2_f32_t fw_foc_current_update(fw_foc_t *f, fw_vec2_f32_t i_ref, fw_vec2_f32_t i_dq, float w,
                                    float u_dc_V, float dt_s) {
  const float u_lim = FW_FOC_VOLTAGE_SHARE * u_dc_V * FW_INV_SQRT3_F32;
  f->pi_d.out_min = f->pi_q.out_min = -u_lim;
  f->pi_d.out_max = f->pi_q.out_max = u_lim;
  const float ff_d = -w * f->p.L_q_H * i_dq.y;
  const float ff_q = w * (f->p.L_d_H * i_dq.x + f->p.psi_f_Wb);
  fw_vec2_f32_t u;
  u.x = fw_pi_step_f32(&f->pi_d, i_ref.x - i_dq.x, ff_d, dt_s);
  u.y = fw_pi_step_f32(&f->pi_q, i_ref.y - i_dq.y, ff_q, dt_s);
  return u;
}

void fw_foc_commit(fw_foc_t *f, fw_vec2_f32_t u_dq_V) {
  f->u_dq_prev_V[0] = u_dq_V.x;
  f->u_dq_prev_V[1] = u_dq_V.y;
}

fw_sincos_f32_t fw_foc_output(fw_vec2_f32_t u_cmd, float theta_k, float w, float dt_s,
                              float u_dc_V, float duty_abc[3]) {
  const fw_sincos_f32_t sc_out = fw_sincos_f32(theta_k + 1.5f * w * dt_s);
  const fw_vec2_f32_t u_ab = fw_inv_park_f32(u_cmd, sc_out);
  (void)fw_svpwm_f32(u_ab, u_dc_V, duty_abc, NULL);
  return sc_out;
}
