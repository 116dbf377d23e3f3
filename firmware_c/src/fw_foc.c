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
  fw_pi_set_dt_f32(&f->pi_d, p->dt_s); /* ki dt once, not every period */
  fw_pi_set_dt_f32(&f->pi_q, p->dt_s);
  fw_pi_set_dt_f32(&f->pi_spd, p->dt_s);
  f->u_dq_prev_V[0] = 0.0f;
  f->u_dq_prev_V[1] = 0.0f;
}

void fw_foc_init(fw_foc_t *f, const fw_foc_param_t *p) {
  fw_foc_reset(f, p);
  f->i_q_ref_A = 0.0f;
}

float fw_foc_speed_update(fw_foc_t *f, float w_ref_radps, float w_radps) {
  return fw_pi_step_cfg_f32(&f->pi_spd, w_ref_radps - w_radps, 0.0f, f->p.i_max_A);
}

void fw_foc_speed_bumpless(fw_foc_t *f) {
  f->pi_spd.integ = fw_clampf(f->i_q_ref_A, -f->p.i_max_A, f->p.i_max_A);
}

void fw_foc_speed_clear(fw_foc_t *f) { f->pi_spd.integ = 0.0f; }
