/**
 * @file fw_mon.h
 * @brief Estimator integrity monitor: independent witnesses, computed from
 *        what a drive can measure, that tell when the sensorless estimate or
 *        the current measurement cannot be trusted.
 *
 * A caller-owned block (fw_mon_t) with an update function per control
 * period and two one-shot checks used by start-up. It reads only the
 * sampled currents, the voltage it commands and the estimator's own states;
 * it has no path to any truth. Every witness has a documented threshold, a
 * persistence time and a fault code (docs/integrity.md):
 *
 * | witness | signal | limit | fault |
 * |---|---|---|---|
 * | HF angle | |angle error| solved from the raw HF response on d^ and q^ against the response learnt at start-up | mon_angle_max_rad | EST_HF_ANGLE |
 * | back-EMF | voltage-equation residual in the estimated frame: its angle and magnitude against omega^ psi_f | mon_bemf_max_rad, ratio 0.5..2 | EST_BEMF_MISMATCH |
 * | acceleration | observer disturbance vs the acceleration the drive can produce | 2 pll_accel_per_A i_max_A | EST_ACCEL_IMPLAUSIBLE |
 * | current sum | low-passed |i_a + i_b + i_c| | i_sum_max_A | CURRENT_SENSOR_SUM |
 * | current control | low-passed |i_dq_ref - i_dq|^2 | (0.5 i_max_A)^2 | CURRENT_CONTROL |
 * | standstill offset | per-phase mean with PWM off | i_offset_max_A | CURRENT_SENSOR_OFFSET |
 * | saliency | eigenvalues of the 2x2 HF admittance measured at standstill | saliency_min, configured saliency within a factor 1 + mon_sal_tol | SALIENCY_MISMATCH |
 * | motion at enable | |u_dq| needed to hold zero current = |omega| psi_f | start_speed_max_mps | MOVING_AT_ENABLE |
 *
 * Each witness must exceed its limit for mon_detect_time_s in a row. Every
 * period only sums its inputs; once per block of 8 periods the low-passes
 * advance on the block means (a first-order low-pass over n periods of a
 * constant input: coefficient 1 - exp(-n T / tau)) and the witnesses are
 * judged, the current sum included. A detection can therefore come up to one
 * block (8 periods) later than with per-period filters and judgements.
 */
#ifndef PMLSM_FW_MON_H
#define PMLSM_FW_MON_H

#include <math.h>
#include <stdbool.h>
#include <stdint.h>

#include "fw_types.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Periods per block: the monitor's filters advance and its witnesses are
 *  judged once per block (3 kHz at 24 kHz). */
#define FW_MON_EVAL_STEPS 8u

/** Inputs of one control period (all observable). */
typedef struct {
  float i_abc_A[3];  /**< measured phase currents (after offset compensation) */
  float e_hf_dq_A[2];/**< sign-demodulated raw HF difference on d^, q^ (A per sample) */
  float u_dq_V[2];   /**< fundamental voltage command applied this period (estimated frame) */
  float i_dq_A[2];   /**< fundamental current (estimated frame) */
  float i_dq_ref_A[2];/**< current references */
  float omega_hat_radps; /**< estimated electrical speed */
  float accel_dist_radps2; /**< observer's disturbance acceleration */
  uint8_t hf_valid;  /**< square wave injected on d^ this period (closed loop) */
  uint8_t running;   /**< closed loop (RUN phase) */
  uint8_t pwm_on;    /**< power stage switching this period */
} fw_mon_in_t;

/** Monitor state. Treat members as private; read results with fw_mon_*(). */
typedef struct {
  /* configuration (copied at init) */
  float dt_s, inv_dt;
  float angle_max_rad, bemf_max_rad, bemf_min_V, detect_s;
  float i_sum_max_A, i_offset_max_A, i_ctrl_max_A, accel_max;
  float rho;          /**< (L_q + L_d) / (L_q - L_d) */
  float R_ohm, L_d_H, L_q_H, psi_f_Wb;
  float a_off;        /**< offset low-pass coefficient (per period) */
  /** block low-passes over n = 0..8 periods: 1 - exp(-n T / tau), and 1 / n */
  float a_hf_n[9], a_slow_n[9], inv_n[9];
  /* learnt at start-up */
  float e_ref_A;      /**< raw HF response along d^ when locked (0: not learnt) */
  /* filtered signals */
  float e_d_f, e_q_f;
  float r_d_f, r_q_f;
  float w_f;          /**< |w^| through the residual's low-pass (like compared with like) */
  float i_prev_A[2];  /**< fundamental current at the end of the last block (for L di/dt) */
  float i_last_A[2];  /**< last fundamental current with PWM on; 0 after a block with
                           the PWM off (the current has decayed: fw_mon_block) */
  /* sums over the present block of MON_EVAL_STEPS periods */
  float s_isum, s_imag;       /**< |i_a + i_b + i_c|, |i_a| + |i_b| + |i_c| (every period) */
  float s_rd, s_rq, s_w;      /**< residual without L di/dt, speed (PWM on) */
  float s_ed, s_eq;           /**< raw HF response (HF valid) */
  float s_ictrl;              /**< |i_ref - i|^2 (closed loop) */
  /** periods of the block NOT in those sums (PWM off, HF not valid, not running),
   *  counting from the block's start or the last clear of the sums: the sums hold
   *  FW_MON_EVAL_STEPS - miss_* periods at the block's end (no count per period
   *  on the usual path) */
  uint32_t miss_pwm, miss_hf, miss_run;
  float isum_f, ictrl_f;
  float imag_f;       /**< low-passed |i_a| + |i_b| + |i_c| */
  float off_f[3];
  float off_time_s;   /**< time with PWM off (offset learning starts after 50 ms) */
  float offset_A[3];  /**< offsets in use (latched at enable) */
  /* outputs */
  float bemf_i_tol;   /**< mon_bemf_i_tol (0: the witness as before) */
  float L_q_psi;      /**< L_q / psi_f: the angle allowance per A */
  float angle_hf_rad, angle_bemf_rad, e_bemf_V;
  float sal_meas, L_small_meas_H, L_large_meas_H, sal_axis_rad;
  /* persistence timers */
  float t_hf, t_bemf, t_accel, t_sum, t_ctrl;
  uint32_t eval_k;    /**< periods since the last block end */
  uint32_t sum_bad;   /**< current-sum witness over mon_detect_time_s (set at block ends) */
  /** first of t_ctrl, t_hf, t_bemf, t_accel over mon_detect_time_s (those
   *  timers change only at a judgement or when cleared): FW_FAULT_NONE or
   *  the fault fw_mon_update returns after the current sum's */
  uint32_t verdict;
  float r_mag_V; /**< |(r_d_f, r_q_f)|, formed where they change (fw_mon_motion) */
} fw_mon_t;

/** Copy thresholds and parameters from the configuration; forget what was learnt. */
void fw_mon_init(fw_mon_t *m, const fw_config_t *cfg, float dt_s);

/** Called every period with PWM off: learns the per-phase current offsets. */
void fw_mon_learn_offsets(fw_mon_t *m, const float i_abc_A[3]);

/** At enable: FW_FAULT_CURRENT_SENSOR_OFFSET if a learnt offset is too large,
 *  else latch the offsets for compensation and return FW_FAULT_NONE. */
fw_fault_t fw_mon_enable(fw_mon_t *m);

/** Phase current k (0..2) with its latched offset subtracted. Per value, inline:
 *  the step keeps its currents in registers (through an array pointer they went
 *  to the stack). */
static inline float fw_mon_compensated(const fw_mon_t *m, unsigned k, float i_A) {
  return i_A - m->offset_A[k];
}

/**
 * Standstill saliency check. y_dd, y_qd: mean raw HF response (A per sample,
 * sign-demodulated) on d^ and q^ to a square wave of u_inj_V on d^; y_dq,
 * y_qq: the same for injection on q^. The eigenvalues of the symmetric 2x2
 * admittance are Ts u / L_small and Ts u / L_large whatever the angle error.
 * Learns the locked HF reference on success. Returns FW_FAULT_NONE,
 * FW_FAULT_SALIENCY_MISMATCH or FW_FAULT_EST_HF_ANGLE (d^ not on the axis of
 * the configured saliency: the alignment did not lock).
 */
fw_fault_t fw_mon_saliency(fw_mon_t *m, const fw_config_t *cfg, float y_dd, float y_qd,
                           float y_dq, float y_qq, float Ts_u_Vs);

/** Motion check during the alignment: |u - R i - L di/dt| (low-passed; the
 *  zero-current loop's voltage, whose back-EMF feed-forward is off until closed
 *  loop) against the back-EMF at start_speed_max_mps. Returns
 *  FW_FAULT_MOVING_AT_ENABLE or NONE. The magnitude is the one the block end
 *  formed (r_mag_V: the filters change only there), not a square root per call. */
static inline fw_fault_t fw_mon_motion(const fw_mon_t *m, float e_start_max_V) {
  /* sqrtf(r_d_f^2 + r_q_f^2), formed by the block end (fw_mon_block) or the reset
   * that last changed them */
  return m->r_mag_V > e_start_max_V ? FW_FAULT_MOVING_AT_ENABLE : FW_FAULT_NONE;
}

/** Closed loop starts: forget the filtered signals of the start-up pulses. */
void fw_mon_run_start(fw_mon_t *m);

/** End of a block of FW_MON_EVAL_STEPS periods (called by fw_mon_update):
 *  low-passes on the block means, judgements. pwm_on, running and the
 *  disturbance are those of the block's last period. */
void fw_mon_block(fw_mon_t *m, bool pwm_on, bool running, float accel_dist_radps2);

/** One control period of the witnesses: sums its inputs, and every
 *  FW_MON_EVAL_STEPS periods advances the filters and judges (fw_mon_block).
 *  Returns the first witness over its limit for mon_detect_time_s (the
 *  current sum first), else FW_FAULT_NONE. Inline: the caller's input struct
 *  then stays in registers. */
static FW_ALWAYS_INLINE fw_fault_t fw_mon_update(fw_mon_t *m, const fw_mon_in_t *in) {
  /* Every period: sums only. The low-passes and the judgements run once per
   * block of FW_MON_EVAL_STEPS periods on the block means (fw_mon.h). */
  const float ia = in->i_abc_A[0], ib = in->i_abc_A[1], ic = in->i_abc_A[2];
  /* current sum: a star-connected winding has i_a + i_b + i_c = 0. Judged with
   * the power stage on, after offset compensation (with PWM off a constant
   * sum is an offset: the per-phase offset check at enable names it). */
  m->s_isum += fabsf(ia + ib + ic);
  /* limit: a floor plus a share of the phase current amplitude (a gain error g on
   * one phase gives a sum of about 0.64 g |i|) */
  m->s_imag += fabsf(ia) + fabsf(ib) + fabsf(ic);
  if (in->pwm_on) {
    m->off_time_s = 0.0f;
    /* voltage-equation residual without its L di/dt part, which telescopes
     * over the block (sum of the differences = last - first) */
    const float w = in->omega_hat_radps;
    const float id = in->i_dq_A[0], iq = in->i_dq_A[1];
    m->s_rd += in->u_dq_V[0] - m->R_ohm * id + w * m->L_q_H * iq;
    m->s_rq += in->u_dq_V[1] - m->R_ohm * iq - w * m->L_d_H * id;
    /* the speed the residual is compared with goes through the same low-pass:
     * otherwise the 5 ms lag of the residual alone reads as a mismatch whenever
     * the speed changes fast (2 m/s -> 0 in 10 ms at full thrust) */
    m->s_w += w;
    m->i_last_A[0] = id;
    m->i_last_A[1] = iq;
  } else {
    m->miss_pwm++;
  }
  if (FW_UNLIKELY(!in->running)) {
    m->t_hf = m->t_bemf = m->t_accel = m->t_ctrl = 0.0f;
    m->verdict = FW_FAULT_NONE;
    m->miss_run++;
    m->miss_hf++;
  } else {
    if (FW_LIKELY(in->hf_valid)) {
      m->s_ed += in->e_hf_dq_A[0];
      m->s_eq += in->e_hf_dq_A[1];
    } else {
      m->miss_hf++;
    }
    const float ed = in->i_dq_ref_A[0] - in->i_dq_A[0];
    const float eq = in->i_dq_ref_A[1] - in->i_dq_A[1];
    m->s_ictrl += ed * ed + eq * eq; /* mean-square error */
  }
  if (++m->eval_k >= FW_MON_EVAL_STEPS) {
    m->eval_k = 0u;
    fw_mon_block(m, in->pwm_on != 0u, in->running != 0u, in->accel_dist_radps2);
  }
  return m->sum_bad ? FW_FAULT_CURRENT_SENSOR_SUM : (fw_fault_t)m->verdict;
}

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_MON_H */
