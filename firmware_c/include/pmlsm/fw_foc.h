/**
 * @file fw_foc.h
 * @brief Field-oriented control block: speed PI (i_q reference), d/q current
 *        PIs with decoupling feed-forward and a voltage limit from the DC
 *        link, the transforms between the stationary and the estimated frame,
 *        and the modulation (inverse Park at the advanced angle, SVPWM).
 *
 * Per period: fw_foc_measure() (Clarke is the caller's, once per sample;
 * Park into the estimated frame), fw_foc_speed_update() in closed loop,
 * fw_foc_current_update(), fw_foc_commit() once the voltage is applied, and
 * fw_foc_output() for the duties. No configuration pointer is kept: gains
 * come in at fw_foc_reset().
 *
 * Independent of fw_config_t: usable (and testable) on its own.
 */
#ifndef PMLSM_FW_FOC_H
#define PMLSM_FW_FOC_H

#include <stddef.h>
#include <stdint.h>

#include "fw_math.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Share of the linear modulation range u_dc / sqrt(3) given to the current
 *  PIs; the rest is headroom for the injection. */
#define FW_FOC_VOLTAGE_SHARE 0.9f

/** Gains and limits (copied in at reset). */
typedef struct {
  float cur_kp_V_per_A, cur_ki_V_per_As;
  float spd_kp_A_per_radps, spd_ki_A_per_rad;
  float i_max_A;          /**< speed PI output limit */
  float R_ohm, L_d_H, L_q_H, psi_f_Wb; /**< for the decoupling feed-forward */
  float dt_s;             /**< control period (the PIs' ki dt are precomputed) */
} fw_foc_param_t;

/** Loop state (caller-owned). */
typedef struct {
  fw_foc_param_t p;
  fw_pi_f32_t pi_d, pi_q, pi_spd;
  float u_dq_prev_V[2]; /**< fundamental voltage committed last period (applied now) */
  float i_q_ref_A;      /**< i_q reference of the last committed period (bumpless SPEED) */
} fw_foc_t;

/** Gains in, PIs and last voltage cleared (i_q_ref_A cleared too). */
void fw_foc_init(fw_foc_t *f, const fw_foc_param_t *p);
/** Closed loop (re)starts: PIs cleared with these gains, voltage history
 *  cleared; i_q_ref_A kept. */
void fw_foc_reset(fw_foc_t *f, const fw_foc_param_t *p);

/** Park of a stationary-frame current into the frame at angle sc. */
static inline fw_vec2_f32_t fw_foc_measure(fw_vec2_f32_t i_ab_A, fw_sincos_f32_t sc) {
  return fw_park_f32(i_ab_A, sc);
}

/** Speed PI: i_q reference from the speed error (A). */
float fw_foc_speed_update(fw_foc_t *f, float w_ref_radps, float w_radps);
/** Bumpless switch to SPEED mode: the speed integrator starts from the last
 *  i_q reference (clamped to i_max_A). */
void fw_foc_speed_bumpless(fw_foc_t *f);
/** Speed integrator to zero (flying start). */
void fw_foc_speed_clear(fw_foc_t *f);

/**
 * Current PIs: u_dq = PI(i_ref - i) + decoupling (-w L_q i_q, w (L_d i_d + psi_f)),
 * each clamped to +-FW_FOC_VOLTAGE_SHARE u_dc / sqrt(3).
 */
static inline fw_vec2_f32_t fw_foc_current_update(fw_foc_t *f, fw_vec2_f32_t i_ref_dq_A,
                                                  fw_vec2_f32_t i_dq_A, float w_radps,
                                                  float u_dc_V) {
  const float u_lim = FW_FOC_VOLTAGE_SHARE * FW_INV_SQRT3_F32 * u_dc_V;
  const float ff_d = -w_radps * f->p.L_q_H * i_dq_A.y;
  const float ff_q = w_radps * (f->p.L_d_H * i_dq_A.x + f->p.psi_f_Wb);
  fw_vec2_f32_t u;
  u.x = fw_pi_step_cfg_f32(&f->pi_d, i_ref_dq_A.x - i_dq_A.x, ff_d, u_lim);
  u.y = fw_pi_step_cfg_f32(&f->pi_q, i_ref_dq_A.y - i_dq_A.y, ff_q, u_lim);
  return u;
}
/** The fundamental voltage u_dq_V (without injection) is what gets applied. */
static inline void fw_foc_commit(fw_foc_t *f, fw_vec2_f32_t u_dq_V) {
  f->u_dq_prev_V[0] = u_dq_V.x;
  f->u_dq_prev_V[1] = u_dq_V.y;
}
/** The i_q reference in use this period (kept for a bumpless SPEED switch). */
static inline void fw_foc_commit_ref(fw_foc_t *f, float i_q_ref_A) { f->i_q_ref_A = i_q_ref_A; }
/** The i_q reference of the last committed period. */
static inline float fw_foc_i_q_ref(const fw_foc_t *f) { return f->i_q_ref_A; }
/** Fundamental voltage committed last period (acts over this one). */
static inline const float *fw_foc_u_applied(const fw_foc_t *f) { return f->u_dq_prev_V; }

/**
 * Output transform of one period: the voltage acts over [k+1, k+2] (one-period
 * update delay), so the inverse Park uses theta_k + 1.5 w dt; then SVPWM on
 * u_dc. sc_k = fw_sincos_f32(theta_k_rad), rotated by 1.5 w dt. Returns the
 * sine/cosine used (for other voltages of this period).
 */
static inline fw_sincos_f32_t fw_foc_output(fw_vec2_f32_t u_cmd_dq_V, fw_sincos_f32_t sc_k,
                                            float theta_k_rad, float w_radps, float dt_s,
                                            float u_dc_V, float duty_abc[3]) {
  const fw_sincos_f32_t sc_out = fw_sincos_add_f32(sc_k, theta_k_rad, 1.5f * w_radps * dt_s);
  const fw_vec2_f32_t u_ab = fw_inv_park_f32(u_cmd_dq_V, sc_out);
  (void)fw_svpwm_f32(u_ab, u_dc_V, duty_abc, NULL);
  return sc_out;
}

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_FOC_H */
