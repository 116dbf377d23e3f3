/**
 * @file fw_start.h
 * @brief Sensorless start-up block: the alignment's flying-start observer and
 *        catch, the end of the alignment, the standstill saliency check and
 *        the magnet polarity test.
 *
 * The sequence ALIGN -> SALIENCY -> POLARITY -> RUN (or ALIGN -> RUN on a
 * moving mover) is the drive state machine's (fw_ctrl.c, fw_start_phase_t);
 * this block measures and decides, the orchestrator applies the decisions
 * to the observer and the loops.
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
 * Included by fw_ctrl.h (needs fw_config_t).
 */
#ifndef PMLSM_FW_START_H
#define PMLSM_FW_START_H

#include <stdbool.h>
#include <stdint.h>

#ifndef PMLSM_FW_CTRL_H
#error "include pmlsm/fw_ctrl.h"
#endif

#ifdef __cplusplus
extern "C" {
#endif

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
} fw_start_t;

/** Configure for the control period dt_s (> 0) and clear everything. */
void fw_start_init(fw_start_t *s, float dt_s);

/** Everything but the configuration cleared (an enable, or the handover to
 *  closed loop). */
void fw_start_reset(fw_start_t *s);

/* ---- ALIGN ---- */
/** Back-EMF observation with this period's fundamental current. */
void fw_start_fly_observe(fw_start_t *s, const fw_cfg_machine_t *mach, fw_vec2_f32_t i_f_ab_A,
                          float phase_time_s);
/** Fundamental alpha/beta voltage commanded this period (acts next period). */
void fw_start_fly_set_u(fw_start_t *s, fw_vec2_f32_t u_f_ab_V);
/**
 * Motion at enable: catch the mover when its back-EMF is large enough to be
 * tracked by the back-EMF observer (bemf_w_on > 0, |e| >= bemf_e_off_V, a
 * rotation of at least 0.05 rad). Returns FW_FAULT_NONE and the angle and
 * speed to start the observer from (and marks the run flying), else
 * FW_FAULT_MOVING_AT_ENABLE.
 */
fw_fault_t fw_start_fly_catch(fw_start_t *s, const fw_config_t *cfg, float bemf_w_on,
                              float *theta_rad, float *w0_radps);
/** End of the alignment: align_time_s elapsed and this period commands
 *  injection index n/4 - 1, the last + command before the HF current triangle
 *  crosses its mean (no residual HF current biases the next test). */
bool fw_start_align_done(const fw_cfg_estimator_t *est, float phase_time_s, uint32_t inj_idx,
                         uint32_t n_inj);

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

/* ---- POLARITY ---- */
void fw_start_polarity_begin(fw_start_t *s);
/**
 * One sample with the measured d^ current; returns the d^ voltage to apply
 * and, in *res, the decision once all pulse pairs are done (the voltage is
 * then 0).
 */
float fw_start_polarity_step(fw_start_t *s, const fw_cfg_estimator_t *est, float i_d_A,
                             fw_pol_result_t *res);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_START_H */
