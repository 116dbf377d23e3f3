/**
 * @file fw_snapshot.c
 * @brief The core's snapshot (see fw_snapshot.h): the carry of the period's
 *        fields, the capture of the blocks' states (loads and stores only: the
 *        supervision interrupt's path) and the completion in units (the
 *        background's).
 */
#include <string.h>

#include "pmlsm/fw_ctrl.h"
#include "pmlsm/fw_snapshot.h"

/** Copy one float as a 32-bit word: GCC (hard-float ARM) limits a float load
 *  or store, even one through core registers, to the FPU's +-1020-byte offset,
 *  so fields further into fw_ctrl_t cost an address computation each; a word
 *  has the +4095 of LDR/STR. The same bits either way. */
static FW_ALWAYS_INLINE void copy_f32(float *dst, const float *src) {
  uint32_t w;
  memcpy(&w, src, sizeof w);
  memcpy(dst, &w, sizeof w);
}

void fw_snapshot_carry(fw_snapshot_t *snap, const fw_snapshot_t *prev, unsigned written) {
  if (!(written & FW_SNAP_W_COMMON)) {
    snap->step_count = prev->step_count;
    snap->theta_hat_rad = prev->theta_hat_rad;
    snap->cia402_state = prev->cia402_state;
    snap->start_phase = prev->start_phase;
    snap->fault_code = prev->fault_code;
    snap->i_ab_A[0] = prev->i_ab_A[0];
    snap->i_ab_A[1] = prev->i_ab_A[1];
    snap->u_dc_V = prev->u_dc_V;
    snap->duty_abc[0] = prev->duty_abc[0];
    snap->duty_abc[1] = prev->duty_abc[1];
    snap->duty_abc[2] = prev->duty_abc[2];
  }
  if (!(written & FW_SNAP_W_EST)) {
    snap->pll_err_rad = prev->pll_err_rad;
    snap->hf_amp_A = prev->hf_amp_A;
    snap->hf_q_A = prev->hf_q_A;
    snap->i_h_ab_A[0] = prev->i_h_ab_A[0];
    snap->i_h_ab_A[1] = prev->i_h_ab_A[1];
  }
  if (!(written & FW_SNAP_W_OUT)) {
    snap->i_dq_A[0] = prev->i_dq_A[0];
    snap->i_dq_A[1] = prev->i_dq_A[1];
    snap->u_dq_V[0] = prev->u_dq_V[0];
    snap->u_dq_V[1] = prev->u_dq_V[1];
    snap->u_inj_V = prev->u_inj_V;
  }
  if (!(written & FW_SNAP_W_REF)) {
    snap->i_dq_ref_A[0] = prev->i_dq_ref_A[0];
    snap->i_dq_ref_A[1] = prev->i_dq_ref_A[1];
  }
}

/** The position parts with a move fw_supervise has not yet added (a snapshot
 *  captured between the two halves). */
static FW_NOINLINE void pos_pending(const fw_obs_t *o, fw_snapshot_raw_t *raw) {
  fw_obs_pos_parts(o, &raw->pos_turns, &raw->pos_unwrapped_e);
}

void fw_snapshot_capture_state(const fw_ctrl_t *ctrl, fw_snapshot_t *snap,
                               fw_snapshot_raw_t *raw) {
  /* the blocks' present states */
  snap->omega_hat_radps = ctrl->obs.pll.w_i_radps;
  snap->omega_f_radps = ctrl->obs.omega_f;
  snap->pll_err_f_rad = ctrl->obs.err_f;
  snap->accel_dist_radps2 = ctrl->obs.accel_dist;
  copy_f32(&snap->mon_angle_hf_rad, &ctrl->mon.angle_hf_rad); /* the monitor's outputs change */
  copy_f32(&snap->mon_angle_bemf_rad, &ctrl->mon.angle_bemf_rad); /* once per block */
  copy_f32(&snap->mon_e_bemf_V, &ctrl->mon.e_bemf_V);
  copy_f32(&snap->mon_i_sum_A, &ctrl->mon.isum_f);
  copy_f32(&snap->inj_scale, &ctrl->bemf.inj_scale);
  snap->bemf_active = ctrl->bemf.active;
  copy_f32(&snap->sogi_k_eff, &ctrl->inj.sogi_a.k); /* fw_inj_k */
  /* two words: the sum is the background's (after fw_supervise, the usual
   * caller's case, the estimate's last move is in them; else it is added as
   * fw_obs_pos_flush will, out of line) */
  if (FW_LIKELY(!ctrl->obs.pos_due)) {
    raw->pos_turns = ctrl->obs.pos_turns;
    raw->pos_unwrapped_e = ctrl->obs.pos_unwrapped_e;
  } else {
    pos_pending(&ctrl->obs, raw);
  }
  copy_f32(&raw->bemf_e_dq_V[0], &ctrl->bemf.e_d_f);
  copy_f32(&raw->bemf_e_dq_V[1], &ctrl->bemf.e_q_f);
  copy_f32(&raw->bemf_err_rad, &ctrl->bemf.err_rad);
  raw->bemf_fresh = ctrl->bemf.err_fresh;
  raw->bemf_w_neg = ctrl->bemf.w_neg;
}

void fw_snapshot_capture_slow(const fw_ctrl_t *ctrl, fw_snapshot_t *snap) {
  const fw_snapshot_t *s = &ctrl->snap;
  snap->pol_dI_pos_A = s->pol_dI_pos_A;
  snap->pol_dI_neg_A = s->pol_dI_neg_A;
  snap->sal_meas = s->sal_meas;
  snap->L_small_meas_H = s->L_small_meas_H;
  snap->L_large_meas_H = s->L_large_meas_H;
  snap->flying_start = ctrl->start.flying;
  snap->extractor = (uint8_t)ctrl->cfg.estimator.extractor;
  snap->mode = (uint8_t)ctrl->mode;
  snap->polarity_flipped = ctrl->polarity_flipped;
  snap->speed_ref_radps_e = ctrl->speed_ref_radps_e;
  snap->ref_limited = ctrl->ref_limited;
}

/** The raw snapshot of the period whose step wrote `period`: what the step
 *  wrote (every field it writes; the start-up results are in the slow part),
 *  the blocks' present states, the slow part. */
static void capture_of(const fw_ctrl_t *ctrl, const fw_snapshot_t *period, fw_snapshot_t *snap,
                       fw_snapshot_raw_t *raw) {
  fw_snapshot_carry(snap, period, 0u);
  fw_snapshot_capture_state(ctrl, snap, raw);
  fw_snapshot_capture_slow(ctrl, snap);
}

void fw_snapshot_capture(const fw_ctrl_t *ctrl, fw_snapshot_t *snap, fw_snapshot_raw_t *raw) {
  capture_of(ctrl, &ctrl->snap, snap, raw);
}

void fw_snapshot_complete(const fw_ctrl_t *ctrl, fw_snapshot_t *snap,
                          const fw_snapshot_raw_t *raw) {
  const fw_config_t *cfg = &ctrl->cfg;
  const float w = snap->omega_hat_radps;
  const float pos_e_rad = fw_obs_pos_e_of(raw->pos_turns, raw->pos_unwrapped_e);
  snap->pos_hat_m = fw_units_rad_e_to_m(cfg, pos_e_rad);
  snap->speed_hat_mps = fw_units_radps_e_to_mps(cfg, w);
  snap->pos_hat_mech_rad = pos_e_rad / cfg->machine.pole_pairs;
  snap->speed_hat_rpm = fw_units_radps_e_to_rpm(cfg, w);
  snap->force_hat_N = fw_units_force_per_A(cfg) * snap->i_dq_A[1];
  snap->torque_hat_Nm = 1.5f * cfg->machine.pole_pairs * cfg->machine.psi_f_Wb * snap->i_dq_A[1];
  /* the observer's angle error as at the capture (an atan2 on demand, as fw_bemf_error) */
  snap->bemf_err_rad = raw->bemf_fresh ? raw->bemf_err_rad
                                       : fw_bemf_angle_of(&ctrl->bemf, raw->bemf_e_dq_V[0],
                                                          raw->bemf_e_dq_V[1], raw->bemf_w_neg);
  snap->statusword =
      fw_statusword_of(cfg, (fw_cia402_state_t)snap->cia402_state, snap->u_dc_V,
                       (fw_start_phase_t)snap->start_phase, (fw_mode_t)snap->mode,
                       snap->speed_ref_radps_e, snap->omega_f_radps, snap->ref_limited,
                       snap->i_dq_ref_A[1]);
}

void fw_get_snapshot_of(const fw_ctrl_t *ctrl, const fw_snapshot_t *period,
                        fw_snapshot_t *snap) {
  if (ctrl == NULL || period == NULL || snap == NULL) {
    return;
  }
  fw_snapshot_raw_t raw;
  *snap = ctrl->snap; /* padding as before */
  capture_of(ctrl, period, snap, &raw);
  fw_snapshot_complete(ctrl, snap, &raw);
  snap->statusword = fw_statusword(ctrl); /* the present state (a command may follow the step) */
}

void fw_get_snapshot(const fw_ctrl_t *ctrl, fw_snapshot_t *snap) {
  if (ctrl == NULL) {
    return;
  }
  fw_get_snapshot_of(ctrl, &ctrl->snap, snap);
}
