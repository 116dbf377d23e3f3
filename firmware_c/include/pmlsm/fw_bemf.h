/**
 * @file fw_bemf.h
 * @brief Back-EMF observer and the handover between injection and back-EMF.
 *
 * Above injection speeds the back-EMF is large and clean: in the estimated
 * frame the voltage equation leaves
 *     e_d = u_d - R i_d - L_d di_d/dt + w^ L_q i_q = -E sin dtheta,
 *     e_q = u_q - R i_q - L_q di_q/dt - w^ L_d i_d =  E cos dtheta,   E = w psi_f,
 * (w^ the speed the estimated frame turns at, w the mover's) so
 * dtheta = atan2(-e_d, e_q) (plus pi for w < 0) is an angle error the PLL
 * can track instead of the HF error. The handover has hysteresis on |w^| psi_f
 * and on the measured |e| (bemf_e_on_V up, bemf_e_off_V down: the back-EMF of the
 * configured speeds bemf_v_on_mps, bemf_v_off_mps, fw_config_derive): going up, the
 * PLL switches to the back-EMF error once the estimate has been above the band for 5 ms, then
 * the injection ramps down to bemf_inj_share of u_inj_V over 10 ms (the HF witness of
 * the integrity monitor keeps working on the reduced injection); going down, as soon as
 * either is below the band, the injection ramps back up first (2 ms) and the PLL returns
 * to the HF error once the extraction has settled (2 ms). The PLL state is continuous
 * through both, so the estimate does not jump.
 *
 * Needs the bottom layer only (fw_types.h).
 */
#ifndef PMLSM_FW_BEMF_H
#define PMLSM_FW_BEMF_H

#include <stdint.h>

#include "fw_types.h"

/** Time constant (s) of the back-EMF low-pass (a DC signal in the estimated frame);
 *  it bounds how fast an observer on the back-EMF error may be
 *  (fw_units_obs_w_max_bemf). */
#define FW_BEMF_TAU_S 0.001f

#ifdef __cplusplus
extern "C" {
#endif

/** Observer and handover state (caller-owned). */
typedef struct {
  float R_ohm, L_d_H, L_q_H, psi_f_Wb, dt_s, a_f;
  float inv_psi;        /**< 1 / psi_f */
  float dL_H;           /**< L_q - L_d with bemf_xc_comp, else 0 (fw_bemf_update) */
  float w_on, w_off;    /**< handover band, el. rad/s (w_on = 0: handover off) */
  float e_on2, e_off2;  /**< the same band in back-EMF, squared (V^2) */
  float e_min2;         /**< (half the switch-off back-EMF)^2: below it, no angle */
  float inj_share;      /**< injection scale while on back-EMF */
  float step_down, step_back; /**< injection scale change per period, down / back up */
  float i_prev_A[2];
  float e_d_f, e_q_f;   /**< filtered back-EMF in the estimated frame, V */
  float err_rad;        /**< angle error from the last update, when err_fresh */
  uint8_t err_fresh;    /**< err_rad is computed (by fw_bemf_prepare while active, or
                         *   at the handover; otherwise fw_bemf_error computes it on
                         *   demand from the filters) */
  uint8_t w_neg;        /**< speed estimate negative at the last update */
  float inv_dt;
  uint8_t active;       /**< PLL driven by the back-EMF error */
  uint8_t going_up;     /**< injection ramping down (1) or up (0) */
  float t_cond_s;       /**< time the switching condition has held */
  float inj_scale;      /**< injection amplitude scale now (1 = full) */
  float t_full_s;       /**< time since the injection is back at full */
} fw_bemf_t;

/**
 * Voltage-equation residual in the estimated frame (the back-EMF when the
 * frame is right): e = u - R i - L di/dt - w^ (-L_q i_q, L_d i_d), with
 * di/dt as the difference to i_prev (updated here). One implementation for
 * the observer and the integrity monitor's back-EMF witness.
 */
static inline void fw_bemf_residual(const float u_dq_V[2], const float i_dq_A[2],
                                    float i_prev_A[2], float inv_dt, float w_hat, float R_ohm,
                                    float L_d_H, float L_q_H, float e_dq_V[2]) {
  const float did = (i_dq_A[0] - i_prev_A[0]) * inv_dt;
  const float diq = (i_dq_A[1] - i_prev_A[1]) * inv_dt;
  i_prev_A[0] = i_dq_A[0];
  i_prev_A[1] = i_dq_A[1];
  e_dq_V[0] = u_dq_V[0] - R_ohm * i_dq_A[0] - L_d_H * did + w_hat * L_q_H * i_dq_A[1];
  e_dq_V[1] = u_dq_V[1] - R_ohm * i_dq_A[1] - L_q_H * diq - w_hat * L_d_H * i_dq_A[0];
}

/** Parameters from the configuration; state cleared. */
void fw_bemf_init(fw_bemf_t *b, const fw_config_t *cfg, float dt_s);
/** Closed loop (re)starts: injection full, PLL on the HF error. */
void fw_bemf_reset(fw_bemf_t *b);
/** Filter the back-EMF from the applied voltage and the fundamental current. w_hat: the
 *  speed estimate (el. rad/s); w_frame: the speed the estimated frame turned at from the
 *  last sample to this one (the PLL's w_hat of the last period), for the cross-coupling
 *  terms: with the speed estimate there instead, an error e in the PLL's output moves the
 *  residual by kp e L_q i_q, which at low back-EMF and high thrust (kp L_q i_q > |w| psi_f)
 *  closes a positive feedback on the angle error (a 0.48 rad oscillation at 0.3 m/s on a
 *  loaded randomized motor, docs/identify.md). */
void fw_bemf_update(fw_bemf_t *b, const float u_dq_V[2], const float i_dq_A[2], float w_hat,
                    float w_frame);
/** Angle error dtheta seen by the back-EMF at the last update (rad, [-pi, pi)); 0 when
 *  |E| is too small or the speed far below the handover (not observed there).
 *  The value fw_bemf_prepare formed, or else computed here on demand. */
float fw_bemf_error(const fw_bemf_t *b);
/** Form the angle error of the last update while the PLL tracks it (active), for the
 *  PLL's next period; nothing when it is formed already or not tracked. The
 *  supervision interrupt calls it (fw_supervise): the value depends only on the
 *  update's filters, which nothing changes before the next update, so the control
 *  interrupt need not spend the atan2 (about 150 cycles on the Cortex-M4F). Without it
 *  fw_bemf_error computes the same value on demand. */
void fw_bemf_prepare(fw_bemf_t *b);
/** The angle error of a filtered back-EMF (e_d, e_q) in the estimated frame, with the
 *  speed's sign (w_neg) and b's threshold: what fw_bemf_error computes from b's own
 *  filters, for values captured earlier (fw_snapshot_complete). */
float fw_bemf_angle_of(const fw_bemf_t *b, float e_d, float e_q, uint8_t w_neg);
/** Flying start: the PLL is set on a moving mover at speed w0 (el. rad/s):
 *  the observer starts locked at |E| = |w0| psi_f, injection ramps down. */
void fw_bemf_catch(fw_bemf_t *b, float w0, const float i_dq_A[2]);
/** Handover logic for this period; hf_settled: the HF path has a full period
 *  of data at full injection. Up when the speed estimate has been above the band for
 *  5 ms; down as soon as the estimate or the measured back-EMF is below it (injection
 *  back over 2 ms, the PLL on the HF error 2 ms later, or at once when the back-EMF is
 *  too small to give an angle); back up on the way down only when both are above it.
 *  Updates active and inj_scale. */
void fw_bemf_schedule(fw_bemf_t *b, float w_hat, uint8_t hf_settled);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_BEMF_H */
