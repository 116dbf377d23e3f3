/**
 * @file fw_start.h
 * @brief Sensorless start-up block: the alignment's flying-start observer and
 *        catch, the end of the alignment, the standstill saliency check and
 *        the magnet polarity test.
 *
 * The sequence ALIGN -> SALIENCY -> POLARITY -> RUN (or ALIGN -> RUN on a
 * moving mover) is the drive state machine's (fw_ctrl.c, fw_start_phase_t);
 * this block measures and decides, and its steps (the flying catch, the
 * saliency check's judgement, the polarity test's decision) apply what they
 * decide to the observer, the back-EMF observer, the monitor and the loops;
 * the orchestrator changes the phase and latches the faults they return.
 *
 *  - ALIGN: injection + PLL at zero current converge to the angle mod pi.
 *    Meanwhile the back-EMF in the stationary frame,
 *    e_ab = u_ab - R i_ab - L di_ab/dt (low-passed), and its rotation over the
 *    observation window tell magnitude and direction of a moving mover
 *    (fw_start_fly_observe / fw_start_fly_catch).
 *  - SALIENCY: FW_SAL_PERIODS injection periods of square wave on d^, then as
 *    many on q^; the mean raw responses (first period of each not averaged)
 *    go to the integrity monitor's saliency check.
 *  - POLARITY: per pair, N samples at zero, +V, -V, 0, -V, +V on d^; with
 *    d-axis saturation the excursion along the magnet (+d) is larger.
 *
 * Needs the bottom layer and the blocks its steps act on: the observer, the
 * back-EMF observer, the integrity monitor and the loops (fw_obs.h, fw_bemf.h,
 * fw_mon.h, fw_foc.h).
 */
#ifndef PMLSM_FW_START_H
#define PMLSM_FW_START_H

#include <math.h>
#include <stdbool.h>
#include <stdint.h>

#include "fw_bemf.h"
#include "fw_foc.h"
#include "fw_mon.h"
#include "fw_obs.h"
#include "fw_types.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Injection periods per axis in the standstill saliency check (the first is
 *  not averaged: the axis change settles). */
#define FW_SAL_PERIODS 4u
/** Standstill saliency checks that may find d^ off the axis and turn the estimate
 *  by the measured angle before a miss is the EST_HF_ANGLE fault. */
#define FW_SAL_RETRIES 1u

/** Flying start: the back-EMF vector is watched from this time in the
 *  alignment through a low-pass of this time constant. */
#define FW_FLY_WINDOW_S 0.010f
#define FW_FLY_TAU_S 0.0005f

/** Outcome of one polarity-test sample. */
typedef enum {
  FW_POL_BUSY = 0,         /**< pulses still running */
  FW_POL_ALIGNED = 1,      /**< +d^ is the magnet's north: estimate right */
  FW_POL_FLIPPED = 2,      /**< -d^ is the north: add pi to the estimate */
  FW_POL_UNDETERMINED = 3  /**< responses too alike (FW_FAULT_POLARITY_UNDETERMINED) */
} fw_pol_result_t;

/** Start-up state (caller-owned). */
typedef struct {
  /* polarity test */
  uint32_t pol_k;
  float pol_base, pol_ext;
  float pol_sum_pos;        /**< summed response to + pulses */
  float pol_sum_neg;        /**< summed response to - pulses */
  /* standstill saliency check: summed responses y_dd, y_qd, y_dq, y_qq */
  float sal_acc[4];
  uint32_t sal_k;
  /* flying start: back-EMF in the stationary frame while aligning */
  float u_ab_prev_V[2];     /**< fundamental alpha/beta voltage commanded last period */
  float i_f_ab_prev_A[2];
  float fly_e_ab_V[2];      /**< low-passed alpha/beta back-EMF */
  float fly_rot_rad;        /**< rotation of that vector over the observation window */
  uint8_t flying;           /**< 1: this run started on a moving mover */
  uint8_t sal_retries;      /**< saliency checks repeated after turning the estimate */
  /* configured (fw_start_init), kept by fw_start_reset */
  float fly_a;              /**< the flying-start low-pass's coefficient 1 - exp(-T/tau) */
  float inv_dt;             /**< 1 / T, the control period's inverse (1/s) */
  /** the last period's step of the rotation, as the cross and dot products of the
   *  successive vectors, not yet added (fly_due; fw_start_fly_flush) */
  float fly_cr, fly_dot;
  /** half the margin of |fly_rot_rad| to FW_FLY_ROT_MIN_RAD when it is over 1e-3,
   *  else 0: formed where the rotation changes (fw_start_fly_add, reset) */
  float fly_rot_margin;
  uint8_t fly_due;
} fw_start_t;

/** Configure for the control period dt_s (> 0) and clear everything. */
void fw_start_init(fw_start_t *s, float dt_s);

/** Everything but the configuration cleared (an enable, or the handover to
 *  closed loop). */
void fw_start_reset(fw_start_t *s);

/* ---- ALIGN ---- */
/* The alignment's per-period functions are inline (fw_step's interrupt inlines
 * them; the Cortex-M4F image compiles this block's source for size, and GCC
 * does not inline across optimisation levels). */

/** The rotation a catch needs (rad): less is no motion to catch. */
#define FW_FLY_ROT_MIN_RAD 0.05f

/** The rotation's step of the last observation, when not yet added (fw_start_fly_observe):
 *  fly_rot_rad as if the observation had added it. */
void fw_start_fly_add(fw_start_t *s);
/** fw_start_fly_add when a step is due (one test inline). */
static inline void fw_start_fly_flush(fw_start_t *s) {
  if (s->fly_due) {
    fw_start_fly_add(s);
  }
}

/** Back-EMF observation with this period's fundamental current. The rotation's
 *  step (an atan2) is left to fw_start_fly_flush: the control step's supervision
 *  half adds it (fw_supervise), a catch first if it needs it. Call
 *  fw_start_fly_flush before the next observation. */
static inline void fw_start_fly_observe(fw_start_t *s, const fw_cfg_machine_t *mach,
                                        fw_vec2_f32_t i_f_ab_A, float phase_time_s) {
  const float L = 0.5f * (mach->L_d_H + mach->L_q_H);
  const float inv_dt = s->inv_dt;
  float ea = s->u_ab_prev_V[0] - mach->R_ohm * i_f_ab_A.x -
             L * (i_f_ab_A.x - s->i_f_ab_prev_A[0]) * inv_dt;
  float eb = s->u_ab_prev_V[1] - mach->R_ohm * i_f_ab_A.y -
             L * (i_f_ab_A.y - s->i_f_ab_prev_A[1]) * inv_dt;
  s->i_f_ab_prev_A[0] = i_f_ab_A.x;
  s->i_f_ab_prev_A[1] = i_f_ab_A.y;
  const float a = s->fly_a;
  float pa = s->fly_e_ab_V[0], pb = s->fly_e_ab_V[1];
  s->fly_e_ab_V[0] += a * (ea - pa);
  s->fly_e_ab_V[1] += a * (eb - pb);
  if (phase_time_s >= FW_FLY_WINDOW_S) {
    /* angle step between successive filtered vectors (cross / dot), its atan2
     * in fw_start_fly_add (the last one's added: fw_start_fly_flush) */
    s->fly_cr = pa * s->fly_e_ab_V[1] - pb * s->fly_e_ab_V[0];
    s->fly_dot = pa * s->fly_e_ab_V[0] + pb * s->fly_e_ab_V[1];
    s->fly_due = 1u;
  }
}
/** Fundamental alpha/beta voltage commanded this period (acts next period). */
static inline void fw_start_fly_set_u(fw_start_t *s, fw_vec2_f32_t u_f_ab_V) {
  s->u_ab_prev_V[0] = u_f_ab_V.x;
  s->u_ab_prev_V[1] = u_f_ab_V.y;
}
/**
 * Motion at enable: catch the mover when its back-EMF is large enough to be
 * tracked by the back-EMF observer (bemf_w_on > 0, |e| >= bemf_e_off_V, a
 * rotation of at least 0.05 rad). Returns FW_FAULT_NONE and the angle and
 * speed to start the observer from (and marks the run flying), else
 * FW_FAULT_MOVING_AT_ENABLE.
 */
fw_fault_t fw_start_fly_catch(fw_start_t *s, const fw_config_t *cfg, float bemf_w_on,
                              float *theta_rad, float *w0_radps);
/** fw_start_fly_catch in two parts. The speed: the decision and w0, what the
 *  period of the catch needs for its duties; the rotation's step of this period is
 *  added first only when it could change the decision (else it stays due:
 *  fw_start_fly_flush). */
static inline fw_fault_t fw_start_fly_catch_speed(fw_start_t *s, const fw_config_t *cfg,
                                                  float bemf_w_on, float *w0_radps) {
  /* the rotation with this period's step: only its sign and whether |.| >= 0.05
   * are read; the step (an atan2) is added here only when it could change them,
   * else fw_start_fly_flush adds it later (the same sum) */
  float rot = s->fly_rot_rad;
  if (s->fly_due) {
    /* For dot > 0, |atan2(cr, dot)| <= |cr| / dot (plus fw_atan2_f32's error,
     * FW_ATAN2_MAX_ERR): a step under half the margin m = |rot| - 0.05 leaves
     * |rot + step| > 0.05 + m / 2 - 1e-6 and the sign of rot, whatever its
     * rounding (m > 1e-3; fly_rot_margin = m / 2, or 0: no shortcut). NaN and
     * infinities fail the test. */
    const float cr = s->fly_cr, dot = s->fly_dot;
    if (!(dot > 0.0f && fabsf(cr) < s->fly_rot_margin * dot)) {
      fw_start_fly_add(s);
      rot = s->fly_rot_rad;
    }
  }
  const float ea = s->fly_e_ab_V[0], eb = s->fly_e_ab_V[1];
  const float E = sqrtf(ea * ea + eb * eb);
  if (!(bemf_w_on > 0.0f) || E < cfg->estimator.bemf_e_off_V || fabsf(rot) < FW_FLY_ROT_MIN_RAD) {
    return FW_FAULT_MOVING_AT_ENABLE; /* too slow for the back-EMF, too fast for injection */
  }
  const float w0 = (rot > 0.0f ? 1.0f : -1.0f) * E / cfg->machine.psi_f_Wb;
  *w0_radps = w0;
  s->flying = 1u;
  return FW_FAULT_NONE;
}
/** The angle of a catch fw_start_fly_catch_speed made with the speed w0_radps it
 *  gave (an atan2; only the next period needs it): fw_start_fly_catch's theta. */
float fw_start_fly_catch_angle(const fw_start_t *s, float w0_radps);
/**
 * The period of a flying catch (the motion check found the mover moving):
 * fw_start_fly_catch_speed's decision and, when caught, what this period's loops
 * and modulation read: the observer's speeds (fw_obs_catch_speed) and the speed
 * loop cleared (fw_foc_speed_clear). The injection's scale, which they read too,
 * is the full one fw_bemf_catch's reset gives (only fw_bemf_schedule changes it,
 * in closed loop, and an enable resets it). The rest of the catch waits for
 * fw_start_fly_catch_finish. Returns FW_FAULT_NONE when caught, else
 * FW_FAULT_MOVING_AT_ENABLE (too slow for the back-EMF, too fast for injection).
 */
fw_fault_t fw_start_fly_catch_begin(fw_start_t *s, const fw_config_t *cfg, float bemf_w_on,
                                    fw_obs_t *obs, fw_foc_t *foc);
/**
 * The rest of a flying catch (fw_start_fly_catch_begin), in the supervision half
 * before its monitor update: the observer's angle (an atan2,
 * fw_start_fly_catch_angle), the back-EMF observer started locked
 * (fw_bemf_catch), the monitor's closed-loop restart (no standstill saliency
 * check: the HF witness stays off). The same states as a catch done at once.
 */
void fw_start_fly_catch_finish(const fw_start_t *s, fw_obs_t *obs, fw_bemf_t *bemf,
                               fw_mon_t *mon);
/** End of the alignment: align_time_s elapsed and this period commands
 *  injection index n/4 - 1, the last + command before the HF current triangle
 *  crosses its mean (no residual HF current biases the next test). */
static inline bool fw_start_align_done(const fw_cfg_estimator_t *est, float phase_time_s,
                                       uint32_t inj_idx, uint32_t n_inj) {
  const uint32_t last_idx = n_inj / 4u > 0u ? n_inj / 4u - 1u : 0u;
  return phase_time_s >= est->align_time_s && inj_idx == last_idx;
}

/* ---- SALIENCY ---- */
void fw_start_saliency_begin(fw_start_t *s);
/** Accumulate this period's raw demodulated response (not in an axis' first period). */
void fw_start_saliency_update(fw_start_t *s, uint32_t n_inj, fw_vec2_f32_t e_raw_dq_A);
/** Square wave on q^ (second half of the check) instead of d^. */
bool fw_start_saliency_on_q(const fw_start_t *s, uint32_t n_inj);
/** Count this period; true once both axes are done. */
bool fw_start_saliency_advance(fw_start_t *s, uint32_t n_inj);
/** Mean responses y_dd, y_qd, y_dq, y_qq per sample. */
void fw_start_saliency_means(const fw_start_t *s, uint32_t n_inj, float y[4]);
/**
 * End of the standstill saliency check: the monitor's judgement
 * (fw_mon_saliency on the mean responses; dt_s the control period). An angle
 * miss (FW_FAULT_EST_HF_ANGLE: the alignment ended on or near its unstable
 * equilibrium pi/2 from the axis, where the PLL's error signal vanishes too)
 * turns the estimate by the measured error (fw_obs_rotate), up to
 * FW_SAL_RETRIES times: *again is then true, FW_FAULT_NONE returned, and the
 * orchestrator aligns and checks again. A pass starts the polarity test
 * (fw_start_polarity_begin). Returns the fault found, FW_FAULT_NONE when none.
 */
fw_fault_t fw_start_saliency_done(fw_start_t *s, const fw_config_t *cfg, uint32_t n_inj,
                                  float dt_s, fw_mon_t *mon, fw_obs_t *obs, bool *again);

/* ---- POLARITY ---- */
void fw_start_polarity_begin(fw_start_t *s);
/**
 * One sample with the measured d^ current; returns the d^ voltage to apply
 * and, in *res, the decision once all pulse pairs are done (the voltage is
 * then 0).
 */
float fw_start_polarity_step(fw_start_t *s, const fw_cfg_estimator_t *est, float i_d_A,
                             fw_pol_result_t *res);
/**
 * fw_start_polarity_step with its decision applied: FW_POL_FLIPPED adds pi to
 * the estimate (fw_obs_flip) and sets *flipped, FW_POL_ALIGNED clears it
 * (FW_POL_BUSY and FW_POL_UNDETERMINED leave it). Returns the result; *u_d_V is
 * the d^ voltage to apply.
 */
fw_pol_result_t fw_start_polarity(fw_start_t *s, const fw_cfg_estimator_t *est, fw_obs_t *obs,
                                  float i_d_A, float *u_d_V, uint8_t *flipped);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_START_H */
