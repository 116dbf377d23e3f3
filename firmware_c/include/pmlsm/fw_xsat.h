/**
 * @file fw_xsat.h
 * @brief Compensation block: the cross-saturation angle map (the offset the
 *        observer subtracts from its HF angle error) and the inverter dead-time
 *        compensation of the modulation (docs/method.md section 6).
 *
 * Cross-saturation (L_dq != 0 under load) turns the HF saliency axis, which the
 * injection estimator locks onto, away from the d axis by an angle that grows
 * with the thrust current. The map gives, for the fundamental i_q, the HF angle
 * error eps the observer sees at the true angle,
 *
 *   off(i_q) = sgn(i_q) interp(|i_q|; (0, 0), (1 h, o_1), ..., (6 h, o_6)),
 *
 * linear between the points (h = xsat_di_A, o_k = xsat_offk_rad), held at o_6
 * beyond 6 h; the observer tracks eps - off (fw_obs_in_t.ang_off_rad), so its
 * estimate settles on the d axis instead of the HF axis. i_q is low-passed over
 * half an injection period (the HF error is a one-period average). h = 0: off
 * (off = 0 exactly, the observer as before).
 *
 * Dead time: each phase's pole voltage falls short of the command by
 * (t_d f_pwm u_dc + u_drop) sgn(i); the modulation adds
 *
 *   d_x += (dt_comp_s f_pwm + dt_comp_drop_V / u_dc) s(i_x),
 *   s(i) = i / sqrt(i^2 + b^2)  (b = dt_comp_band_A; b = 0: sgn(i))
 *
 * with i_x the phase's fundamental current (the HF extraction's), the duty
 * clamped to [0, 1]. dt_comp_s = dt_comp_drop_V = 0: off (the duties untouched).
 *
 * Position-periodic ripple: a secondary saliency of stator-frame order n moves the
 * HF axis at (n - 2) theta in the rotor frame, the end effect's fixed stator-frame
 * saliency (order 0) at 2 theta; both land at 2 theta for n = 4 (docs/method.md
 * section 6). The observer subtracts, besides the map's offset, the HF error it
 * sees at the true angle as a short series in the estimate,
 *
 *   rip(theta^) = a2 cos 2 theta^ + b2 sin 2 theta^ + a4 cos 4 theta^ + b4 sin 4 theta^
 *
 * (rip_a2_rad .. rip_b4_rad, in the error's units like the map), from the sine and
 * cosine of theta^ the period already has (double-angle formulas, no libm). All four
 * 0: off (nothing added, the observer as before).
 *
 * Needs the bottom layer (fw_types.h, fw_math.h) only.
 */
#ifndef PMLSM_FW_XSAT_H
#define PMLSM_FW_XSAT_H

#include <stdint.h>

#include "fw_math.h"
#include "fw_types.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Number of map points (besides the origin). */
#define FW_XSAT_POINTS 6u

/** Compensation state (caller-owned). */
typedef struct {
  /* cross-saturation map */
  uint8_t xsat_on;                 /**< xsat_di_A > 0 */
  float inv_di;                    /**< 1 / xsat_di_A */
  float off[FW_XSAT_POINTS + 1u];  /**< o_0 = 0, o_1 .. o_6 */
  float iq_alpha;                  /**< low-pass coefficient of i_q */
  float iq_f;                      /**< low-passed fundamental i_q (A) */
  float off_rad;                   /**< the offset of the next period (rad) */
  /* position-periodic ripple */
  uint8_t rip_on;                  /**< any of rip_a2_rad .. rip_b4_rad != 0 */
  float rip_c[4];                  /**< a2, b2, a4, b4 (rad) */
  /* dead time */
  uint8_t dt_on;                   /**< dt_comp_s > 0 or dt_comp_drop_V > 0 */
  float dt_duty;                   /**< dt_comp_s f_pwm */
  float drop_V;                    /**< dt_comp_drop_V */
  float band2;                     /**< dt_comp_band_A^2 */
} fw_xsat_t;

/** Constants from the configuration; the state cleared (fw_xsat_reset). */
void fw_xsat_init(fw_xsat_t *x, const fw_config_t *cfg, float dt_s);
/** i_q filter and offset to 0 (an enable). */
void fw_xsat_reset(fw_xsat_t *x);
/** The map at i_q (A): the offset off(i_q) of the header (0 when off). */
float fw_xsat_map(const fw_xsat_t *x, float i_q_A);
/** One period: the fundamental i_q measured in it; sets off_rad for the next. */
static inline void fw_xsat_update(fw_xsat_t *x, float i_q_A) {
  if (FW_UNLIKELY(x->xsat_on)) {
    x->iq_f += x->iq_alpha * (i_q_A - x->iq_f);
    x->off_rad = fw_xsat_map(x, x->iq_f);
  }
}
/** The offset the observer subtracts this period (rad). */
static inline float fw_xsat_offset(const fw_xsat_t *x) { return x->off_rad; }

/** The ripple correction rip(theta^) of the header at the estimate's cosine and sine
 *  (sc.c = cos theta^, sc.s = sin theta^); 0 when off. */
static inline float fw_xsat_ripple(const fw_xsat_t *x, fw_sincos_f32_t sc) {
  if (FW_LIKELY(!x->rip_on)) {
    return 0.0f;
  }
  const float c2 = sc.c * sc.c - sc.s * sc.s;
  const float s2 = 2.0f * sc.c * sc.s;
  const float c4 = c2 * c2 - s2 * s2;
  const float s4 = 2.0f * c2 * s2;
  return x->rip_c[0] * c2 + x->rip_c[1] * s2 + x->rip_c[2] * c4 + x->rip_c[3] * s4;
}
/** The offset the observer subtracts this period with the ripple correction at the
 *  estimate sc (rad): the map's offset, plus rip(theta^) when the ripple is on (the
 *  map's offset alone, bit for bit, when off). */
static inline float fw_xsat_offset_at(const fw_xsat_t *x, fw_sincos_f32_t sc) {
  return FW_UNLIKELY(x->rip_on) ? x->off_rad + fw_xsat_ripple(x, sc) : x->off_rad;
}

/** Dead-time compensation of the duties (header): i_ab_A the fundamental current
 *  in the stationary frame, u_dc_V the DC link. Nothing when off. */
void fw_xsat_deadtime(const fw_xsat_t *x, fw_vec2_f32_t i_ab_A, float u_dc_V,
                      float duty_abc[3]);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_XSAT_H */
