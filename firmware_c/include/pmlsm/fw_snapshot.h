/**
 * @file fw_snapshot.h
 * @brief The core's snapshot: a read-only view of its internal signals, for
 *        telemetry (fw_snapshot_t), and its capture (fw_snapshot.c).
 *
 * The control step writes the period's own fields into a snapshot as it goes
 * (fw_step_into: the groups FW_SNAP_W_*); the rest are the blocks' present
 * states, captured after the step, and values in units completed later
 * (fw_snapshot_complete). The core never reads a snapshot back.
 *
 * The snapshot sits beside the core: fw_ctrl_t holds the last one (ctrl->snap),
 * and the capture reads fw_ctrl_t, declared here only by name (fw_ctrl.h
 * defines it).
 */
#ifndef PMLSM_FW_SNAPSHOT_H
#define PMLSM_FW_SNAPSHOT_H

#include <stdint.h>

#include "fw_types.h"

#ifdef __cplusplus
extern "C" {
#endif

/** The drive core (fw_ctrl.h). */
typedef struct fw_ctrl fw_ctrl_t;

/** Read-only view of internal signals, for telemetry. */
typedef struct {
  uint32_t step_count;
  uint16_t statusword;
  uint8_t cia402_state;  /**< fw_cia402_state_t */
  uint8_t start_phase;   /**< fw_start_phase_t */
  uint8_t extractor;     /**< fw_extractor_t in use */
  uint8_t mode;          /**< fw_mode_t */
  uint8_t polarity_flipped; /**< 1 when start-up added pi to the estimate */
  uint16_t fault_code;   /**< latched fw_fault_t, 0 if none */
  /* estimator */
  float theta_hat_rad;   /**< electrical angle estimate at the sampling instant of this step, [-pi, pi) */
  float omega_hat_radps; /**< electrical speed estimate (PLL integrator) */
  float omega_f_radps;   /**< filtered speed used by the speed loop */
  float pos_hat_m;       /**< unwrapped linear position estimate */
  float speed_hat_mps;
  float pos_hat_mech_rad;  /**< unwrapped rotary-equivalent position */
  float speed_hat_rpm;     /**< rotary-equivalent speed */
  float pll_err_rad;       /**< normalised PLL error (approx theta - theta_hat) */
  float pll_err_f_rad;     /**< low-passed signed PLL error; |.| drives adaptation, supervision */
  float accel_dist_radps2; /**< observer's disturbance acceleration (load, friction) */
  float hf_amp_A;          /**< demodulated HF amplitude on d-hat per sample */
  float hf_q_A;            /**< demodulated HF q-hat component per sample */
  float sogi_k_eff;        /**< SOGI gain in use */
  float pol_dI_pos_A;      /**< polarity test: summed response to + pulses */
  float pol_dI_neg_A;      /**< polarity test: summed response to - pulses */
  /* current and voltage (estimated frame) */
  float i_dq_A[2];       /**< fundamental current */
  float i_dq_ref_A[2];
  float u_dq_V[2];       /**< fundamental voltage command (without injection) */
  float u_inj_V;         /**< signed injection voltage commanded this step */
  float i_ab_A[2];       /**< measured alpha/beta current */
  float i_h_ab_A[2];     /**< extracted HF current */
  float speed_ref_radps_e;
  float force_hat_N;     /**< thrust from i_q estimate, 1.5 (pi/tau) psi_f i_q */
  float torque_hat_Nm;   /**< rotary equivalent, 1.5 p psi_f i_q */
  float u_dc_V;
  float duty_abc[3];
  /* integrity monitor (fw_mon.h) */
  float mon_angle_hf_rad;   /**< |angle error| solved from the raw HF response */
  float mon_angle_bemf_rad; /**< angle of the voltage residual against the estimate */
  float mon_e_bemf_V;       /**< |voltage residual| (back-EMF magnitude); in start-up the
                             *   motion check's statistic (MOVING_AT_ENABLE) */
  float mon_i_sum_A;        /**< low-passed |i_a + i_b + i_c| */
  float sal_meas;           /**< saliency measured at start-up (L_large / L_small - 1) */
  float L_small_meas_H;     /**< smaller inductance measured at start-up */
  float L_large_meas_H;     /**< larger inductance measured at start-up */
  /* back-EMF observer (fw_bemf.h) */
  float bemf_err_rad;       /**< angle error seen by the back-EMF (its observer's present
                             *   value, computed by fw_get_snapshot) */
  float inj_scale;          /**< injection amplitude in use, share of u_inj_V */
  uint8_t bemf_active;      /**< 1: the PLL tracks the back-EMF, 0: the HF response */
  uint8_t flying_start;     /**< 1: closed loop was entered on a moving mover */
  uint8_t ref_limited;      /**< FW_REF_LIMITED_* of the references in use */
  /* the board's reference position sensor (fw_port_ref_read), for the bench's
   * judgement only: written by the drive application (fw_app) into the periods
   * it publishes, never by the core, which never reads it */
  float ref_pos_m; /**< reference sensor position (electrical zero at 0), NaN: none */
} fw_snapshot_t;

/** Groups of the snapshot fields fw_step writes (fw_step_into's result): the
 *  period's common signals (step count, the angle estimate at the sample
 *  (theta_hat_rad), states, fault code, alpha/beta current,
 *  DC link, duties), the extraction's (PLL error, HF amplitudes, HF current),
 *  the current loop's (i_dq, u_dq, u_inj) and the current references. A field
 *  of a group not written keeps its value of the period before. */
#define FW_SNAP_W_COMMON 1u
#define FW_SNAP_W_EST 2u
#define FW_SNAP_W_OUT 4u
#define FW_SNAP_W_REF 8u
#define FW_SNAP_W_ALL 15u

/** What fw_snapshot_complete needs besides the captured snapshot fields. */
typedef struct {
  int32_t pos_turns;      /**< the observer's position (fw_obs_pos_e_of: whole turns ... */
  float pos_unwrapped_e;  /**< ... and the remainder), summed in fw_snapshot_complete */
  float bemf_e_dq_V[2]; /**< the back-EMF observer's filtered back-EMF */
  float bemf_err_rad;  /**< its angle error, when bemf_fresh */
  uint8_t bemf_fresh;  /**< bemf_err_rad is computed (fw_bemf_t.err_fresh) */
  uint8_t bemf_w_neg;  /**< fw_bemf_t.w_neg */
} fw_snapshot_raw_t;

/** Copy of the internal signals after the last step (fw_snapshot_capture +
 *  fw_snapshot_complete, with the statusword of the core's present state). */
void fw_get_snapshot(const fw_ctrl_t *ctrl, fw_snapshot_t *snap);
/** fw_get_snapshot when the last period's snapshot fields were written into
 *  period (fw_step_into) rather than into ctrl->snap. */
void fw_get_snapshot_of(const fw_ctrl_t *ctrl, const fw_snapshot_t *period,
                        fw_snapshot_t *snap);

/**
 * The snapshot in two halves, for a control interrupt that hands its periods
 * to a background loop (fw_app): fw_snapshot_capture copies this period's
 * signals and the blocks' present states (loads and stores only: no unit
 * conversion, no division, no statusword, no atan2) into snap and raw;
 * fw_snapshot_complete computes the rest of snap from them (positions and
 * speeds in units, thrust, torque, the back-EMF angle error, the statusword)
 * with ctrl's configuration, later and elsewhere. Right after fw_step (with
 * inputs), capture + complete give exactly fw_get_snapshot.
 */
void fw_snapshot_capture(const fw_ctrl_t *ctrl, fw_snapshot_t *snap, fw_snapshot_raw_t *raw);
/**
 * fw_snapshot_capture in parts:
 *  - fw_snapshot_carry copies the groups of the period's fields (what fw_step
 *    wrote) not in written (FW_SNAP_W_*) from prev: with written 0 and prev
 *    &ctrl->snap, all of them;
 *  - _state the blocks' present states (a caller of fw_step_into, which wrote
 *    the period's fields itself, captures only these and the slow part);
 *  - _slow the fields that change only at start-up events and on commands
 *    (polarity and saliency results, polarity flag, flying start, extractor,
 *    mode, speed reference). A caller that keeps snapshots (fw_app's ring
 *    slots) copies the slow part only when fw_snapshot_slow_gen differs from
 *    the value it had at its last copy into that snapshot.
 */
void fw_snapshot_carry(fw_snapshot_t *snap, const fw_snapshot_t *prev, unsigned written);
void fw_snapshot_capture_state(const fw_ctrl_t *ctrl, fw_snapshot_t *snap, fw_snapshot_raw_t *raw);
void fw_snapshot_capture_slow(const fw_ctrl_t *ctrl, fw_snapshot_t *snap);
void fw_snapshot_complete(const fw_ctrl_t *ctrl, fw_snapshot_t *snap,
                          const fw_snapshot_raw_t *raw);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_SNAPSHOT_H */
