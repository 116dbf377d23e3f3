/**
 * @file fw_pll.h
 * @brief Quadrature phase-locked loop (paper eq. 9) for angle and speed.
 *
 * Type-2 loop with a PI regulator on the angle error e (rad):
 *   w_i(k+1)     = clamp(w_i(k) + ki * e(k) * dt, -w_max, w_max)
 *   w_hat(k)     = w_i(k+1) + kp * e(k)
 *   theta(k+1)   = wrap(theta(k) + w_hat(k) * dt)
 * With e = theta - theta_hat for small errors, the linearised closed loop is
 *   theta_hat/theta = (kp s + ki) / (s^2 + kp s + ki)
 * so a position ramp is tracked with zero steady-state error. The speed
 * estimate reported is the integrator w_i (free of the kp*e noise term).
 */
#ifndef PMLSM_FW_PLL_H
#define PMLSM_FW_PLL_H

#include "fw_math.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
  float kp;          /**< proportional gain (1/s) */
  float ki;          /**< integral gain (1/s^2) */
  float w_max_radps; /**< integrator (speed) limit */
  float theta_rad;   /**< angle estimate, [-pi, pi) */
  float w_i_radps;   /**< integrator = speed estimate */
  float w_hat_radps; /**< kp*e + w_i, the angle rate actually integrated */
} fw_pll_f32_t;

void fw_pll_init_f32(fw_pll_f32_t *p, float kp, float ki, float w_max_radps);

/** Set the state (angle wrapped to [-pi, pi)): fw_pll_set_angle_f32 and
 *  fw_pll_set_speed_f32. */
void fw_pll_reset_f32(fw_pll_f32_t *p, float theta_rad, float w_radps);
/** The angle part of fw_pll_reset_f32 (wrapped; non-finite -> 0). Inline: a
 *  flying start sets the speed in the control interrupt. */
static inline void fw_pll_set_angle_f32(fw_pll_f32_t *p, float theta_rad) {
  p->theta_rad = fw_wrap_pi_f32(theta_rad); /* non-finite -> 0 */
}
/** The speed part of fw_pll_reset_f32: integrator and w_hat at w (clamped to
 *  +-w_max; non-finite -> 0). */
static inline void fw_pll_set_speed_f32(fw_pll_f32_t *p, float w_radps) {
  p->w_i_radps =
      fw_isfinite_f32(w_radps) ? fw_clampf(w_radps, -p->w_max_radps, p->w_max_radps) : 0.0f;
  p->w_hat_radps = p->w_i_radps;
}

/** Advance one sample with angle error e_rad. */
void fw_pll_step_f32(fw_pll_f32_t *p, float e_rad, float dt_s);

/**
 * Quadrature error of eq. 9: i_sin cos(theta_hat) - i_cos sin(theta_hat),
 * which equals sin(theta - theta_hat) for i_cos = cos theta, i_sin = sin theta.
 */
static inline float fw_pll_quad_error_f32(float i_sin, float i_cos,
                                          fw_sincos_f32_t sc_hat) {
  return i_sin * sc_hat.c - i_cos * sc_hat.s;
}

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_PLL_H */
