/**
 * @file fw_obs.h
 * @brief Observer block: angle error from the demodulated HF response (or the
 *        back-EMF above injection speeds), its low-passed signed version, the
 *        quadrature PLL with bandwidth scheduling and the mechanical extension
 *        (thrust feed-forward + disturbance integrator), the unwrapped
 *        position, the filtered speed for the loops, and the estimator
 *        supervision (HF loss, persistent PLL error).
 *
 *   eps = (E_q / E_d) L_q / (L_q - L_d)  ~ theta - theta_hat for small errors
 *   (eq. 8-9 with the scale L_d/(T u) replaced by the measured d^ response,
 *   so the loop gain depends neither on u_inj, nor on the extractor's gain,
 *   nor on errors in L_d).
 *
 * fw_obs_update() runs once per sample after the extraction; the estimate it
 * leaves (pll.theta_rad) belongs to the next sampling instant.
 *
 * Included by fw_ctrl.h (needs fw_config_t).
 */
#ifndef PMLSM_FW_OBS_H
#define PMLSM_FW_OBS_H

#include <stdbool.h>
#include <stdint.h>

#ifndef PMLSM_FW_CTRL_H
#error "include pmlsm/fw_ctrl.h"
#endif

#ifdef __cplusplus
extern "C" {
#endif

/** Observer state (caller-owned). pll and err_f come first: fw_ctrl_t keeps
 *  their old names as aliases (see there). */
typedef struct {
  fw_pll_f32_t pll;
  float err_f;            /**< low-passed signed PLL error */
  /* constants from the configuration */
  float dt_s;
  float spd_alpha;        /**< speed filter coefficient */
  float err_alpha;        /**< |PLL error| filter coefficient */
  float eps_gain;         /**< L_q / (L_q - L_d): ratio -> angle error */
  float inv_adapt_err;    /**< 1 / sogi_adapt_err_rad */
  float hf_min_A;         /**< HF-loss threshold hf_min_ratio T u_inj / L_q */
  float bw_min, bw_span;  /**< pll_bw_min and 1 - pll_bw_min (bandwidth scheduling) */
  float kp0, ki0, ki0_dt; /**< pll_kp, pll_ki, pll_ki dt (scaled by lambda, lambda^2) */
  float kd_dt;            /**< dt pll_kd (scaled by lambda^3) */
  float accel_per_A;      /**< pll_accel_per_A */
  /* state */
  float est_hold_s;       /**< the error is held at 0 while > 0 (after an extractor switch) */
  float accel_dist;       /**< estimated disturbance acceleration (el. rad/s^2) */
  float pll_err_time_s;   /**< time with |err_f| above pll_err_max_rad */
  float omega_f;          /**< filtered speed for the loops */
  float i_q_ff_A;         /**< fundamental i_q of the last full period (thrust feed-forward) */
  float pos_unwrapped_e;  /**< unwrapped electrical angle estimate: remainder in [-pi, pi) ... */
  int32_t pos_turns;      /**< ... plus this many whole electrical turns (2 pi) */
  float theta_prev;
} fw_obs_t;

/** Inputs of one sample. */
typedef struct {
  float E_d_A, E_q_A;     /**< demodulated one-period HF averages */
  float bemf_err_rad;     /**< back-EMF angle error (read when bemf_active) */
  uint8_t hold;           /**< 1: estimate held (saliency check: injection on q^) */
  uint8_t bemf_active;    /**< 1: track the back-EMF error instead of the HF one */
  uint8_t settled;        /**< 0: extraction still settling: extrapolate, do not correct */
  uint8_t running;        /**< 1: closed loop: mechanical extension on */
} fw_obs_in_t;

/** Constants from the configuration (the state is left as it is). */
void fw_obs_init(fw_obs_t *o, const fw_config_t *cfg, float dt_s);
/** Observer restarts at angle 0, speed 0: PLL, error filter, disturbance,
 *  supervision timer and filtered speed cleared. The position is not touched:
 *  call fw_obs_keep_position first when the estimate restarts from 0. */
void fw_obs_reset(fw_obs_t *o, const fw_config_t *cfg);
/** The estimate is about to restart from 0: its present angle moves into the
 *  unwrapped position, so the position does not jump. */
void fw_obs_keep_position(fw_obs_t *o);
/** Estimate set to (theta, w) without moving the position (a hand-over). */
void fw_obs_set(fw_obs_t *o, float theta_rad, float w_radps);
/** Flying start: estimate set on a moving mover; filtered speed w0, no disturbance. */
void fw_obs_catch(fw_obs_t *o, float theta_rad, float w0_radps);
/** Polarity: pi added to the estimate and to the position. */
void fw_obs_flip(fw_obs_t *o);
/** Turn the estimate by d_rad (|d_rad| <= pi/2, an angle error the standstill
 *  saliency check measured): the PLL restarts from the corrected angle at zero
 *  speed, the position estimate moves with it. */
void fw_obs_rotate(fw_obs_t *o, float d_rad);
/** Hold the error at 0 for this long (an extractor switch settles). */
void fw_obs_hold(fw_obs_t *o, float t_s);
/** Fundamental i_q of this period (for the next period's thrust feed-forward). */
static inline void fw_obs_set_iq(fw_obs_t *o, float i_q_A) { o->i_q_ff_A = i_q_A; }

/**
 * One sample: error, low-pass, bandwidth scheduling, PLL step, mechanical
 * extension, position and filtered speed. Returns the error used (rad);
 * *adapt_r: |filtered error| / sogi_adapt_err_rad clamped to [0, 1], the
 * adaptation signal for the SOGI.
 */
float fw_obs_update(fw_obs_t *o, const fw_obs_in_t *in, float *adapt_r);

/** Loss of lock: HF amplitude below hf_min_A * inj_scale, or (running) the
 *  filtered error above pll_err_max_rad for longer than pll_err_time_s. */
fw_fault_t fw_obs_supervise(fw_obs_t *o, const fw_config_t *cfg, float hf_amp_A,
                            float inj_scale, bool running);

/** Unwrapped electrical position, rad, from the observer's two parts. */
static inline float fw_obs_pos_e_of(int32_t pos_turns, float pos_unwrapped_e) {
  return (float)pos_turns * FW_TWO_PI_F32 + pos_unwrapped_e;
}

/** Unwrapped electrical position, rad. */
static inline float fw_obs_pos_e(const fw_obs_t *o) {
  return fw_obs_pos_e_of(o->pos_turns, o->pos_unwrapped_e);
}

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_OBS_H */
