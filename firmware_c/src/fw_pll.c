/**
 * @file fw_pll.c
 * @brief Type-2 quadrature PLL (difference equations in fw_pll.h).
 */
#include "pmlsm/fw_pll.h"

void fw_pll_init_f32(fw_pll_f32_t *p, float kp, float ki, float w_max_radps) {
  p->kp = kp;
  p->ki = ki;
  /* a negative or non-finite limit would make the clamp meaningless */
  p->w_max_radps = (fw_isfinite_f32(w_max_radps) && w_max_radps > 0.0f)
                       ? w_max_radps
                       : 0.0f;
  fw_pll_reset_f32(p, 0.0f, 0.0f);
}

void fw_pll_reset_f32(fw_pll_f32_t *p, float theta_rad, float w_radps) {
  fw_pll_set_angle_f32(p, theta_rad);
  fw_pll_set_speed_f32(p, w_radps);
}

void fw_pll_step_f32(fw_pll_f32_t *p, float e_rad, float dt_s) {
  /* A non-finite error or time step holds the state (coasting would need a
   * valid dt; the caller sees the fault upstream). */
  const float nf = (e_rad - e_rad) + (dt_s - dt_s); /* 0 when both are finite, else NaN */
  if (!(nf == 0.0f && dt_s >= 0.0f)) {
    return;
  }
  /* w_i(k+1) = clamp(w_i(k) + ki e dt, +-w_max)   (rad/s) */
  p->w_i_radps = fw_clampf(p->w_i_radps + p->ki * e_rad * dt_s,
                           -p->w_max_radps, p->w_max_radps);
  /* w_hat(k) = w_i(k+1) + kp e                    (rad/s) */
  p->w_hat_radps = p->w_i_radps + p->kp * e_rad;
  /* theta(k+1) = wrap(theta(k) + w_hat dt)         (rad) */
  p->theta_rad = fw_wrap_pi_f32(p->theta_rad + p->w_hat_radps * dt_s);
}
