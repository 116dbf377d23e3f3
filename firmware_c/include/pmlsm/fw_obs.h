/**
 * @file fw_obs.h
 * @brief Observer block: angle error from the demodulated HF response (or the
 *        back-EMF above injection speeds), its low-passed signed version, the
 *        quadrature PLL with bandwidth scheduling and the mechanical extension
 *        (thrust feed-forward, the configured 6 theta thrust ripple, disturbance
 *        integrator), the unwrapped
 *        position, the filtered speed for the loops, and the estimator
 *        supervision (HF loss, persistent PLL error).
 *
 *   eps = (E_q / E_d) L_q / (L_q - L_d)  ~ theta - theta_hat for small errors
 *   (eq. 8-9 with the scale L_d/(T u) replaced by the measured d^ response,
 *   so the loop gain depends neither on u_inj, nor on the extractor's gain,
 *   nor on errors in L_d).
 *
 * Position-harmonic thrust ripple (rip6_*, object 0x2057:16-19; all 0 = off): the
 * model's acceleration adds k_e F_rip / mass with k_e = pi / pole_pitch_m and
 *
 *   F_rip = (a0 + a1 i_q) cos 6 theta_hat + (b0 + b1 i_q) sin 6 theta_hat   (N)
 *
 * (cogging at tau / 3: a0, b0; the thrust ripple of the back-EMF's 5th and 7th
 * harmonics: a1, b1 per A of the fundamental i_q), cos / sin 6 theta_hat from the
 * period's cos / sin theta_hat (fw_obs_in_t.sc, the Park transform's) by the
 * double- and triple-angle products: no libm.
 *
 * fw_obs_update() runs once per sample after the extraction; the estimate it
 * leaves (pll.theta_rad) belongs to the next sampling instant.
 *
 * Needs the bottom layer (fw_types.h) and the PLL (fw_pll.h).
 */
#ifndef PMLSM_FW_OBS_H
#define PMLSM_FW_OBS_H

#include <stdbool.h>
#include <stdint.h>

#include "fw_pll.h"
#include "fw_types.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Observer state (caller-owned). */
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
  uint8_t rip6_on;        /**< any of rip6_a0_N .. rip6_b1_N_per_A != 0 */
  /** k_e / mass times rip6_a0_N, rip6_b0_N (rad/s^2), rip6_a1_N_per_A, rip6_b1_N_per_A
   *  (rad/(s^2 A)): the thrust ripple as electrical acceleration */
  float rip6_k[4];
  /* state */
  float est_hold_s;       /**< the error is held at 0 while > 0 (after an extractor switch) */
  float accel_dist;       /**< estimated disturbance acceleration (el. rad/s^2) */
  float pll_err_time_s;   /**< time with |err_f| above pll_err_max_rad */
  float omega_f;          /**< filtered speed for the loops */
  float i_q_ff_A;         /**< fundamental i_q of the last full period (thrust feed-forward) */
  float pos_unwrapped_e;  /**< unwrapped electrical angle estimate: remainder in [-pi, pi) ... */
  int32_t pos_turns;      /**< ... plus this many whole electrical turns (2 pi) */
  float theta_prev;       /**< the estimate the position last moved to */
  /** 1: fw_obs_update_pll moved the estimate and the position has not followed yet
   *  (fw_obs_pos_flush; fw_obs_pos_parts reads it as if it had) */
  uint8_t pos_due;
  /** the last update's bandwidth scale: pll.kp and pll.ki (which nothing in the
   *  step reads: the PLL step is inline) follow with the position */
  float lam;
  /* obs_mode 2 (FW_OBS_ADAPTIVE, docs/method.md section 5): constants ... */
  uint32_t mode;          /**< fw_obs_mode_t */
  float lam_n, lam_span;  /**< obs_bw_narrow and obs_bw_wide - obs_bw_narrow */
  float lam_bemf;         /**< bemf_obs_bw: the scale's factor on the back-EMF error */
  float lam_bemf_max;     /**< ... and the scale's cap there (fw_units_obs_w_max_bemf) */
  float lam_b_alpha;      /**< the factor's approach to lam_bemf on the back-EMF: coefficient */
  float lam_b;            /**< the factor now: 1 on injection, towards lam_bemf on the back-EMF */
  float det2;             /**< obs_detect_sigma^2 */
  float inn_alpha;        /**< short-window mean of the innovation: coefficient */
  float var_alpha;        /**< its variance (slow, clipped): coefficient */
  float att_alpha;        /**< beta towards 1 (test fires) */
  float rel_alpha;        /**< beta towards 0 (test quiet): dt / obs_release_s */
  float fric_c;           /**< configured Coulomb friction as el. acceleration, rad/s^2 */
  float fric_v;           /**< configured viscous friction / mass, 1/s */
  float inv_w_fric;       /**< 1 / speed (el. rad/s) over which the Coulomb term changes sign */
  /* ... and state */
  float inn_m;            /**< short-window mean of the innovation (rad) */
  float inn_var;          /**< measured variance of inn_m in steady state (rad^2) */
  float beta;             /**< 0 narrow .. 1 wide */
  uint8_t bemf_prev;      /**< the error source of the last sample (1: back-EMF) */
} fw_obs_t;

/** Inputs of one sample. */
typedef struct {
  float E_d_A, E_q_A;     /**< demodulated one-period HF averages */
  float bemf_err_rad;     /**< back-EMF angle error (read when bemf_active) */
  float ang_off_rad;      /**< subtracted from the HF angle error: the cross-saturation
                               map's offset (fw_xsat.h; 0 = none) */
  uint8_t hold;           /**< 1: estimate held (saliency check: injection on q^) */
  uint8_t bemf_active;    /**< 1: track the back-EMF error instead of the HF one */
  uint8_t settled;        /**< 0: extraction still settling: extrapolate, do not correct */
  uint8_t running;        /**< 1: closed loop: mechanical extension on */
  /** cos / sin of the estimate at this sampling instant (the Park transform's); read
   *  only when the thrust ripple (rip6_*) is configured */
  fw_sincos_f32_t sc;
} fw_obs_in_t;

/** Prior of fw_obs_t.inn_var at a reset, rad^2: large, so that the test does not
 *  fire before the variance is measured (it is learnt downwards in obs_var_s). */
#define FW_OBS_INN_VAR0 (0.02f * 0.02f)

/** Constants from the configuration (the state is left as it is). */
void fw_obs_init(fw_obs_t *o, const fw_config_t *cfg, float dt_s);
/** The configured thrust ripple as electrical acceleration (rad/s^2) at the estimate
 *  sc = (cos, sin) theta_hat and the thrust current i_q_A (header; rip6_on). */
static FW_ALWAYS_INLINE float fw_obs_rip6_accel(const fw_obs_t *o, fw_sincos_f32_t sc,
                                                float i_q_A) {
  const float c2 = sc.c * sc.c - sc.s * sc.s;
  const float s2 = 2.0f * sc.c * sc.s;
  const float c3 = sc.c * c2 - sc.s * s2;
  const float s3 = sc.s * c2 + sc.c * s2;
  const float c6 = c3 * c3 - s3 * s3;
  const float s6 = 2.0f * c3 * s3;
  return (o->rip6_k[0] + o->rip6_k[2] * i_q_A) * c6 + (o->rip6_k[1] + o->rip6_k[3] * i_q_A) * s6;
}

/** Observer restarts at angle 0, speed 0: PLL, error filter, disturbance,
 *  supervision timer and filtered speed cleared. The position is not touched:
 *  call fw_obs_keep_position first when the estimate restarts from 0. */
void fw_obs_reset(fw_obs_t *o, const fw_config_t *cfg);
/** The estimate is about to restart from 0: its present angle moves into the
 *  unwrapped position, so the position does not jump. */
void fw_obs_keep_position(fw_obs_t *o);
/** Estimate set to (theta, w) without moving the position (a hand-over). */
void fw_obs_set(fw_obs_t *o, float theta_rad, float w_radps);
/** Flying start: estimate set on a moving mover; filtered speed w0, no disturbance.
 *  fw_obs_catch_speed, then fw_obs_catch_angle. */
void fw_obs_catch(fw_obs_t *o, float theta_rad, float w0_radps);
/** The speed part of fw_obs_catch (the PLL's speed, the filtered speed, no
 *  disturbance): what the period's loops read. */
void fw_obs_catch_speed(fw_obs_t *o, float w0_radps);
/** The angle part of fw_obs_catch (the PLL's angle, which only the next period
 *  reads; the position follows the last move first). */
void fw_obs_catch_angle(fw_obs_t *o, float theta_rad);
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
 * adaptation signal for the SOGI. It is fw_obs_update_pll followed by
 * fw_obs_pos_flush.
 */
float fw_obs_update(fw_obs_t *o, const fw_obs_in_t *in, float *adapt_r);

/**
 * fw_obs_update without the position: the estimate's move is left for
 * fw_obs_pos_flush (pos_due), which the control step's supervision half calls
 * (fw_supervise): nothing before the duties reads the position, and its angle
 * difference and wrap (two wraps and a turn once per electrical revolution) need
 * not be in the control interrupt. The PLL's gain fields pll.kp and pll.ki, which
 * only readers outside the step see, follow with it (fw_obs_pll_gains). Call
 * fw_obs_pos_flush before the next fw_obs_update_pll (fw_ctrl: the supervision,
 * or the control half that finds it missed). Every other function of this block
 * that reads or moves the position or the estimate adds a pending move first, so
 * the position is the same, bit for bit, as fw_obs_update's.
 */
float fw_obs_update_pll(fw_obs_t *o, const fw_obs_in_t *in, float *adapt_r);

/** x (the position's remainder plus an increment) back into [-pi, pi), the turn
 *  it crossed counted in *turns (increments up to pi: the estimate's move). */
static FW_ALWAYS_INLINE float fw_obs_pos_wrap(float x, int32_t *turns) {
  /* usually in range: one test against pi; -pi and NaN take the exact tests,
   * which leave them as they are */
  if (FW_UNLIKELY(!(fabsf(x) < FW_PI_F32))) {
    if (x >= FW_PI_F32) {
      x -= FW_TWO_PI_F32;
      (*turns)++;
    } else if (x < -FW_PI_F32) {
      x += FW_TWO_PI_F32;
      (*turns)--;
    }
  }
  return x;
}

/** The position as it is once a pending move (pos_due) has been added: its
 *  whole turns and remainder (fw_obs_pos_flush stores exactly these). */
static FW_ALWAYS_INLINE void fw_obs_pos_parts(const fw_obs_t *o, int32_t *pos_turns,
                                              float *pos_unwrapped_e) {
  int32_t turns = o->pos_turns;
  float x = o->pos_unwrapped_e;
  if (o->pos_due) {
    x = fw_obs_pos_wrap(x + fw_wrap_pi_f32(o->pll.theta_rad - o->theta_prev), &turns);
  }
  *pos_turns = turns;
  *pos_unwrapped_e = x;
}

/** fw_obs_pos_flush for any move (out of line: the move across +-pi, once per
 *  electrical revolution). */
void fw_obs_pos_flush_turn(fw_obs_t *o);

/** The PLL's gain fields of the last update (kp0 lam, ki0 lam^2): set with its
 *  position (fw_obs_pos_flush), the same values fw_obs_update sets. */
static FW_ALWAYS_INLINE void fw_obs_pll_gains(fw_obs_t *o) {
  const float lam = o->lam;
  o->pll.kp = o->kp0 * lam;
  o->pll.ki = o->ki0 * (lam * lam);
}

/** The position follows the estimate's last move (fw_obs_update_pll); nothing
 *  when none is pending. Inline for the usual move, one that wraps neither the
 *  difference nor the remainder (there fw_wrap_pi_f32 and fw_obs_pos_wrap leave
 *  their argument as it is): the same sum as fw_obs_pos_parts. */
static FW_ALWAYS_INLINE void fw_obs_pos_flush(fw_obs_t *o) {
  if (o->pos_due) {
    const float theta = o->pll.theta_rad;
    const float d = theta - o->theta_prev;
    const float x = o->pos_unwrapped_e + d;
    if (FW_LIKELY(fabsf(d) < FW_PI_F32 && fabsf(x) < FW_PI_F32)) {
      o->pos_unwrapped_e = x;
      o->theta_prev = theta;
      o->pos_due = 0u;
      fw_obs_pll_gains(o);
    } else {
      fw_obs_pos_flush_turn(o);
    }
  }
}

/** Loss of lock: HF amplitude below hf_min_A * inj_scale, or (running) the
 *  filtered error above pll_err_max_rad for longer than pll_err_time_s. */
fw_fault_t fw_obs_supervise(fw_obs_t *o, const fw_config_t *cfg, float hf_amp_A,
                            float inj_scale, bool running);

/** Unwrapped electrical position, rad, from the observer's two parts. */
static inline float fw_obs_pos_e_of(int32_t pos_turns, float pos_unwrapped_e) {
  return (float)pos_turns * FW_TWO_PI_F32 + pos_unwrapped_e;
}

/** Unwrapped electrical position, rad (a pending move included). */
static inline float fw_obs_pos_e(const fw_obs_t *o) {
  int32_t turns;
  float x;
  fw_obs_pos_parts(o, &turns, &x);
  return fw_obs_pos_e_of(turns, x);
}

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_OBS_H */
