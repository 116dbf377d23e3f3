/**
 * @file fw_ctrl.c
 * @brief Sensorless drive core: input checks, CiA 402 supervision, start-up
 *        (angle mod pi, then magnet polarity), square-wave injection,
 *        HF extraction + demodulation, PLL, current and speed loops.
 *
 * Signal chain per PWM period k (see docs/firmware.md):
 *
 *   i_abc --Clarke--> i_ab --+--> pseudo:  h = i_ab          (eq. 11 baseline)
 *                            +--> SOGI:    h = D(z) i_ab     (eq. 12/13)
 *   dh = h(k) - h(k-1), rotated into the estimated frame at theta_hat
 *   e_d = s(k-2) dh_d,  e_q = s(k-2) dh_q      (s = injection sign; the
 *        difference over [k-1, k] saw the voltage commanded at k-2 because
 *        of the one-period PWM update delay)
 *   E_d, E_q = moving averages of e_d, e_q over one injection period
 *   With injection along d-hat and dtheta = theta - theta_hat:
 *        E_d ~ Ts u (1/Ld cos^2 + 1/Lq sin^2),  E_q ~ Ts u (1/Ld - 1/Lq) sin(2 dtheta) / 2
 *   PLL error  eps = (E_q / E_d) * Lq / (Lq - Ld)  ~ dtheta  for small dtheta
 *   This is eq. 8-9 (i_sin cos theta_hat - i_cos sin theta_hat is the
 *   q-hat component of the scaled HF difference) with the scale L_d/(T u)
 *   replaced by the measured d-hat response, so the loop gain does not
 *   depend on u_inj, the extractor's gain or errors in L_d.
 */
#include <math.h>
#include <stddef.h>
#include <string.h>

#include "pmlsm/fw_ctrl.h"

/* Corner of the |PLL error| filter used for adaptation and supervision. */
#define FW_ERR_FILTER_HZ 5.0f
/* Speed below which quick stop counts the drive as stopped (el. rad/s). */
#define FW_QS_STILL_RADPS 2.0f
#define FW_QS_STILL_TIME_S 0.02f
/* HF supervision starts after this time in a phase (filters settled). */
#define FW_HF_SUPERVISION_DELAY_S 0.005f
/* After the estimator (re)starts, the SOGI and the one-period averages need
 * this long before their output means anything; the PLL holds meanwhile. */
#define FW_EST_SETTLE_S 0.001f
/* Motion check during the alignment starts after this time (current loop and
 * monitor filter settled). */
#define FW_MOTION_CHECK_S 0.015f
/* Flying start: the back-EMF vector is watched from this time in the alignment
 * until FW_MOTION_CHECK_S, through a low-pass of this time constant. */
#define FW_FLY_WINDOW_S 0.010f
#define FW_FLY_TAU_S 0.0005f
/* Voltage headroom kept for injection when limiting the current PIs. */
#define FW_PI_VOLTAGE_SHARE 0.9f

/* ---- helpers ------------------------------------------------------------ */

static void hist_push(fw_ctrl_t *c, fw_fault_t code) {
  for (uint32_t i = FW_FAULT_HISTORY_LEN - 1u; i > 0u; i--) {
    c->fault_hist[i] = c->fault_hist[i - 1u];
  }
  c->fault_hist[0] = (uint16_t)code;
  if (c->fault_hist_count < FW_FAULT_HISTORY_LEN) {
    c->fault_hist_count++;
  }
}

/**
 * Fault reaction (CiA 402 FAULT REACTION ACTIVE). A communication fault
 * (supervisor heartbeat lost) leaves the power stage and the estimator
 * healthy: the drive first brakes under control like a quick stop, then
 * switches off. Every other fault (electrical, input, estimator) switches the
 * power stage off at once: a sensorless drive cannot brake safely once its
 * measurements or its estimate are in doubt.
 */
static bool fault_brakes_first(const fw_ctrl_t *c, fw_fault_t code) {
  if (c->cfg.fault_reaction_option == (uint32_t)FW_REACT_SWITCH_OFF) {
    return false; /* 0x605E = 0: switch off for every fault */
  }
  /* faults that leave the estimate and the measurements trustworthy */
  return code == FW_FAULT_HEARTBEAT_LOST || code == FW_FAULT_POSITION_LIMIT ||
         code == FW_FAULT_I2T;
}

static void latch_fault(fw_ctrl_t *c, fw_fault_t code) {
  if (code == FW_FAULT_NONE) {
    return;
  }
  if (c->fault == FW_FAULT_NONE) {
    c->fault = code; /* the first cause is the one reported */
  }
  if (c->fault_hist_count == 0u || c->fault_hist[0] != (uint16_t)code) {
    hist_push(c, code); /* every new cause, once while it repeats */
  }
  if (!fault_brakes_first(c, code)) {
    c->fault_hard = 1u;
  }
  if (c->sm.state == FW_CIA402_FAULT_REACTION_ACTIVE && c->fault_hard) {
    fw_cia402_fault_reaction_done(&c->sm); /* a hard fault ends any braking */
  } else if (c->sm.state != FW_CIA402_FAULT &&
             c->sm.state != FW_CIA402_FAULT_REACTION_ACTIVE) {
    fw_cia402_fault(&c->sm);
    c->qs_time_s = 0.0f; /* braking (if any) is timed like a quick stop */
    c->qs_still_s = 0.0f;
  }
}

/** Add d (|d| <= pi) to the unwrapped position, kept as whole electrical
 *  turns plus a remainder in [-pi, pi): a single float would lose the
 *  increments once the position is large (ulp 0.06 rad at 1e6 rad). */
static void pos_add(fw_ctrl_t *c, float d) {
  float x = c->pos_unwrapped_e + d;
  if (x >= FW_PI_F32) {
    x -= FW_TWO_PI_F32;
    c->pos_turns++;
  } else if (x < -FW_PI_F32) {
    x += FW_TWO_PI_F32;
    c->pos_turns--;
  }
  c->pos_unwrapped_e = x;
}

static float lp_alpha(float f_Hz, float dt_s) {
  return 1.0f - expf(-FW_TWO_PI_F32 * f_Hz * dt_s);
}

/** Reset everything that carries history across an enable. */
static void reset_dynamics(fw_ctrl_t *c) {
  const fw_config_t *cfg = &c->cfg;
  float u_lim = 1.0f; /* real limits are set every step from u_dc */
  fw_pi_init_f32(&c->pi_d, cfg->cur_kp_V_per_A, cfg->cur_ki_V_per_As, -u_lim, u_lim);
  fw_pi_init_f32(&c->pi_q, cfg->cur_kp_V_per_A, cfg->cur_ki_V_per_As, -u_lim, u_lim);
  fw_pi_init_f32(&c->pi_spd, cfg->spd_kp_A_per_radps, cfg->spd_ki_A_per_rad, -cfg->i_max_A,
                 cfg->i_max_A);
  float k = cfg->extractor == (uint32_t)FW_EXTRACTOR_SOGI_ADAPTIVE ? cfg->sogi_k_adapt_max
                                                                     : cfg->sogi_k;
  (void)fw_sogi_init_f32(&c->sogi_a, cfg->f_inj_Hz, k, c->dt_s);
  (void)fw_sogi_init_f32(&c->sogi_b, cfg->f_inj_Hz, k, c->dt_s);
  c->sogi_gd_s = c->sogi_gd_s_k / c->sogi_a.k;
  fw_pll_init_f32(&c->pll, cfg->pll_kp, cfg->pll_ki, cfg->speed_max_radps_e);
  memset(c->h_prev_raw, 0, sizeof(c->h_prev_raw));
  memset(c->h_prev_sogi, 0, sizeof(c->h_prev_sogi));
  memset(c->h_sogi, 0, sizeof(c->h_sogi));
  memset(c->sign_hist, 0, sizeof(c->sign_hist));
  c->ring_idx = 0u;
  c->ring_fill = 0u;
  c->sum_ed = c->sum_eq = c->sum_ia = c->sum_ib = 0.0f;
  memset(c->ring_ed, 0, sizeof(c->ring_ed));
  memset(c->ring_eq, 0, sizeof(c->ring_eq));
  memset(c->ring_ia, 0, sizeof(c->ring_ia));
  memset(c->ring_ib, 0, sizeof(c->ring_ib));
  c->inj_idx = 0u;
  c->inj_sign = 0.0f;
  c->err_f = 0.0f;
  c->accel_dist = 0.0f;
  c->est_hold_s = 0.0f;
  c->pll_err_time_s = 0.0f;
  c->omega_f = 0.0f;
  c->theta_prev = c->pll.theta_rad;
  c->phase = FW_START_IDLE;
  c->phase_time_s = 0.0f;
  c->pol_k = 0u;
  c->pol_base = c->pol_ext = c->pol_sum_pos = c->pol_sum_neg = 0.0f;
  c->qs_time_s = 0.0f;
  c->qs_still_s = 0.0f;
  memset(c->sal_acc, 0, sizeof(c->sal_acc));
  c->sal_k = 0u;
  memset(c->u_dq_prev_V, 0, sizeof(c->u_dq_prev_V));
  c->follow_time_s = 0.0f;
  fw_bemf_reset(&c->bemf);
  memset(c->u_ab_prev_V, 0, sizeof(c->u_ab_prev_V));
  memset(c->i_f_ab_prev_A, 0, sizeof(c->i_f_ab_prev_A));
  memset(c->fly_e_ab_V, 0, sizeof(c->fly_e_ab_V));
  c->fly_rot_rad = 0.0f;
  c->flying = 0u;
}

static void apply_config(fw_ctrl_t *c, const fw_config_t *cfg, fw_status_t st) {
  c->cfg = *cfg;
  c->cfg_ok = (uint8_t)(st == FW_OK || st == FW_ERR_SALIENCY);
  c->saliency_ok = (uint8_t)(st == FW_OK);
  c->dt_s = 1.0f / cfg->f_pwm_Hz;
  c->n_inj = (uint32_t)(cfg->f_pwm_Hz / cfg->f_inj_Hz + 0.5f);
  c->spd_alpha = lp_alpha(cfg->spd_filter_Hz, c->dt_s);
  c->err_alpha = lp_alpha(FW_ERR_FILTER_HZ, c->dt_s);
  /* Group delay of the pre-warped discrete SOGI at its centre: the analog
   * 2/(k w0) times the warping slope dW/dw = (w0 T/2) sec^2(w0 T/2) / tan(w0 T/2). */
  {
    float w0 = FW_TWO_PI_F32 * cfg->f_inj_Hz;
    float h = 0.5f * w0 * c->dt_s;
    float t = tanf(h);
    c->sogi_gd_s_k = (2.0f / w0) * h * (1.0f + t * t) / t;
  }
  /* reciprocals and products the step would otherwise divide for */
  c->eps_gain = cfg->L_q_H / (cfg->L_q_H - cfg->L_d_H);
  c->inv_n_inj = 1.0f / (float)c->n_inj;
  c->inv_adapt_err = 1.0f / cfg->sogi_adapt_err_rad;
  c->hf_min_A = cfg->hf_min_ratio * c->dt_s * cfg->u_inj_V / cfg->L_q_H;
  c->w_vmax_radps = fw_units_mps_to_radps_e(cfg, cfg->v_max_mps);
  c->w_follow_radps = fw_units_mps_to_radps_e(cfg, cfg->follow_err_mps);
  c->e_start_max_V = fw_units_mps_to_radps_e(cfg, cfg->start_speed_max_mps) * cfg->psi_f_Wb;
  fw_mon_init(&c->mon, cfg, c->dt_s);
  fw_bemf_init(&c->bemf, cfg, c->dt_s);
  /* references set under the old limits must obey the new ones */
  c->speed_ref_radps_e =
      fw_clampf(c->speed_ref_radps_e, -cfg->speed_max_radps_e, cfg->speed_max_radps_e);
  c->i_q_ref_force_A = fw_clampf(c->i_q_ref_force_A, -cfg->i_max_A, cfg->i_max_A);
  c->i_d_ref_A = fw_clampf(c->i_d_ref_A, -cfg->i_max_A, cfg->i_max_A);
  pos_add(c, -c->pll.theta_rad); /* the estimate restarts from 0: keep the position */
  reset_dynamics(c);
}

/** Smallest change of the adaptive k worth recomputing coefficients for. */
#define FW_SOGI_K_STEP 0.002f

/** Same k on both SOGIs: compute the coefficients once, copy them. */
static void sogi_set_k_both(fw_ctrl_t *c, float k) {
  fw_sogi_set_k_f32(&c->sogi_a, k);
  fw_sogi_copy_gain_f32(&c->sogi_b, &c->sogi_a);
  c->sogi_gd_s = c->sogi_gd_s_k / c->sogi_a.k; /* k is clamped > 0 by set_k */
}

/* ---- configuration and commands ----------------------------------------- */

fw_status_t fw_init(fw_ctrl_t *ctrl, const fw_config_t *cfg) {
  if (ctrl == NULL) {
    return FW_ERR_NULL;
  }
  memset(ctrl, 0, sizeof(*ctrl));
  fw_cia402_init(&ctrl->sm);
  fw_config_issue_t issue;
  fw_config_t derived;
  if (cfg != NULL) {
    derived = *cfg;
    fw_config_derive(&derived); /* gains from the physical description, if asked */
    cfg = &derived;
  }
  fw_status_t st = fw_config_check(cfg, &issue);
  if (st == FW_OK || st == FW_ERR_SALIENCY) {
    apply_config(ctrl, cfg, st);
  } else {
    fw_config_t def;
    fw_config_default(&def);
    apply_config(ctrl, &def, FW_OK);
    ctrl->cfg_ok = 0u; /* enabling must fail: the requested config was bad */
  }
  ctrl->mode = FW_MODE_SPEED;
  fw_cia402_init_done(&ctrl->sm);
  return st;
}

fw_status_t fw_set_config(fw_ctrl_t *ctrl, const fw_config_t *cfg, fw_config_issue_t *issue) {
  if (ctrl == NULL || cfg == NULL) {
    return FW_ERR_NULL;
  }
  if (fw_cia402_power_enabled(ctrl->sm.state)) {
    return FW_ERR_STATE;
  }
  fw_config_t derived = *cfg;
  fw_config_derive(&derived); /* gains from the physical description, if asked */
  fw_status_t st = fw_config_check(&derived, issue);
  if (st == FW_OK || st == FW_ERR_SALIENCY) {
    apply_config(ctrl, &derived, st);
  }
  return st;
}

const fw_config_t *fw_get_config(const fw_ctrl_t *ctrl) { return ctrl ? &ctrl->cfg : NULL; }

fw_cia402_state_t fw_state(const fw_ctrl_t *ctrl) { return ctrl->sm.state; }

uint16_t fw_statusword(const fw_ctrl_t *ctrl) {
  bool warning = ctrl->u_dc_V < ctrl->cfg.u_dc_min_V;
  bool reached = false;
  if (ctrl->sm.state == FW_CIA402_OPERATION_ENABLED && ctrl->phase == FW_START_RUN) {
    if (ctrl->mode == FW_MODE_SPEED) {
      float e = ctrl->speed_ref_radps_e - ctrl->omega_f;
      float tol = 0.02f * fabsf(ctrl->speed_ref_radps_e) + 1.0f;
      reached = fabsf(e) < tol;
    } else {
      reached = true;
    }
  }
  return fw_cia402_statusword(&ctrl->sm, warning, true, reached);
}

uint16_t fw_controlword(fw_ctrl_t *ctrl, uint16_t cw) {
  fw_cia402_state_t before = ctrl->sm.state;
  fw_cia402_state_t after = fw_cia402_controlword(&ctrl->sm, cw);
  if (before == FW_CIA402_FAULT && after != FW_CIA402_FAULT) {
    ctrl->fault = FW_FAULT_NONE; /* fault reset: history is kept */
    ctrl->fault_hard = 0u;
  }
  if (after == FW_CIA402_OPERATION_ENABLED && before != FW_CIA402_OPERATION_ENABLED &&
      before != FW_CIA402_QUICK_STOP_ACTIVE) {
    if (!ctrl->cfg_ok) {
      latch_fault(ctrl, FW_FAULT_CONFIG_INVALID);
    } else if (!ctrl->saliency_ok) {
      latch_fault(ctrl, FW_FAULT_SALIENCY_TOO_LOW); /* injection refused */
    } else {
      fw_fault_t f = fw_mon_enable(&ctrl->mon); /* current-sensor offsets at standstill */
      if (f != FW_FAULT_NONE) {
        latch_fault(ctrl, f);
      } else {
        pos_add(ctrl, -ctrl->pll.theta_rad); /* the estimate restarts from 0 */
        reset_dynamics(ctrl);
        ctrl->phase = FW_START_ALIGN;
      }
    }
  }
  if (after == FW_CIA402_QUICK_STOP_ACTIVE && before != FW_CIA402_QUICK_STOP_ACTIVE) {
    ctrl->qs_time_s = 0.0f;
    ctrl->qs_still_s = 0.0f;
    if (ctrl->cfg.quick_stop_option == (uint32_t)FW_REACT_SWITCH_OFF) {
      fw_cia402_quick_stop_done(&ctrl->sm); /* 0x605A = 0: disable drive at once */
      ctrl->phase = FW_START_IDLE;
    }
  }
  return fw_statusword(ctrl);
}

fw_status_t fw_set_mode(fw_ctrl_t *ctrl, fw_mode_t mode) {
  if (ctrl == NULL) {
    return FW_ERR_NULL;
  }
  if (mode != FW_MODE_SPEED && mode != FW_MODE_FORCE) {
    return FW_ERR_RANGE;
  }
  if (mode != ctrl->mode && mode == FW_MODE_SPEED) {
    /* bumpless: the speed integrator starts from the present i_q reference */
    ctrl->pi_spd.integ = fw_clampf(ctrl->i_q_ref_A, -ctrl->cfg.i_max_A,
                                   ctrl->cfg.i_max_A);
  }
  ctrl->mode = mode;
  return FW_OK;
}

static fw_status_t set_clamped(float *dst, float v, float lim) {
  if (!fw_isfinite_f32(v)) {
    return FW_ERR_NOT_FINITE;
  }
  *dst = fw_clampf(v, -lim, lim);
  return (v > lim || v < -lim) ? FW_ERR_RANGE : FW_OK;
}

fw_status_t fw_set_speed_ref(fw_ctrl_t *ctrl, float w) {
  return ctrl ? set_clamped(&ctrl->speed_ref_radps_e, w, ctrl->cfg.speed_max_radps_e)
              : FW_ERR_NULL;
}

fw_status_t fw_set_iq_ref(fw_ctrl_t *ctrl, float i) {
  return ctrl ? set_clamped(&ctrl->i_q_ref_force_A, i, ctrl->cfg.i_max_A) : FW_ERR_NULL;
}

fw_status_t fw_set_force_ref(fw_ctrl_t *ctrl, float force_N) {
  if (ctrl == NULL) return FW_ERR_NULL;
  const float k_f = fw_units_force_per_A(&ctrl->cfg);
  if (!(k_f > 0.0f) || !fw_isfinite_f32(force_N)) return FW_ERR_NOT_FINITE;
  return fw_set_iq_ref(ctrl, force_N / k_f);
}

fw_status_t fw_set_id_ref(fw_ctrl_t *ctrl, float i) {
  return ctrl ? set_clamped(&ctrl->i_d_ref_A, i, ctrl->cfg.i_max_A) : FW_ERR_NULL;
}

fw_status_t fw_set_extractor(fw_ctrl_t *ctrl, fw_extractor_t ex) {
  if (ctrl == NULL) {
    return FW_ERR_NULL;
  }
  if (ex != FW_EXTRACTOR_PSEUDO && ex != FW_EXTRACTOR_SOGI && ex != FW_EXTRACTOR_SOGI_ADAPTIVE) {
    return FW_ERR_RANGE;
  }
  ctrl->cfg.extractor = (uint32_t)ex;
  sogi_set_k_both(ctrl, ex == FW_EXTRACTOR_SOGI_ADAPTIVE ? ctrl->cfg.sogi_k_adapt_max
                                                         : ctrl->cfg.sogi_k);
  /* demodulated history belongs to the old path: restart the averages, and
   * hold the PLL and the adaptation until the new path has settled (a change
   * of k moves the SOGI output for a while) */
  ctrl->est_hold_s = FW_EST_SETTLE_S;
  ctrl->ring_fill = 0u;
  ctrl->ring_idx = 0u;
  ctrl->sum_ed = ctrl->sum_eq = ctrl->sum_ia = ctrl->sum_ib = 0.0f;
  return FW_OK;
}

void fw_raise_fault(fw_ctrl_t *ctrl, fw_fault_t code) {
  if (ctrl != NULL) {
    latch_fault(ctrl, code);
  }
}

fw_fault_t fw_fault_code(const fw_ctrl_t *ctrl) { return ctrl->fault; }

uint32_t fw_fault_history(const fw_ctrl_t *ctrl, uint16_t *codes, uint32_t n) {
  uint32_t m = ctrl->fault_hist_count < n ? ctrl->fault_hist_count : n;
  for (uint32_t i = 0; i < m; i++) {
    codes[i] = ctrl->fault_hist[i];
  }
  return m;
}

size_t fw_ctrl_sizeof(void) { return sizeof(fw_ctrl_t); }

/* ---- estimator ---------------------------------------------------------- */

/** Moving average over one injection period (ring of n_inj samples). */
static void ring_push(fw_ctrl_t *c, float ed, float eq, float ia, float ib) {
  uint32_t i = c->ring_idx;
  if (c->ring_fill == c->n_inj) {
    c->sum_ed -= c->ring_ed[i];
    c->sum_eq -= c->ring_eq[i];
    c->sum_ia -= c->ring_ia[i];
    c->sum_ib -= c->ring_ib[i];
  } else {
    c->ring_fill++;
  }
  c->ring_ed[i] = ed;
  c->ring_eq[i] = eq;
  c->ring_ia[i] = ia;
  c->ring_ib[i] = ib;
  c->sum_ed += ed;
  c->sum_eq += eq;
  c->sum_ia += ia;
  c->sum_ib += ib;
  c->ring_idx = (i + 1u == c->n_inj) ? 0u : i + 1u;
}

/**
 * Extraction, demodulation and PLL for one sample. Returns the fundamental
 * alpha/beta current (HF removed) for the current loop.
 */
static fw_vec2_f32_t estimator_step(fw_ctrl_t *c, fw_vec2_f32_t i_ab, float *hf_amp_A) {
  const fw_config_t *cfg = &c->cfg;
  fw_extractor_t ex = (fw_extractor_t)cfg->extractor;

  /* Both SOGIs always run so that switching extractor is seamless. */
  float h_a = fw_sogi_step_f32(&c->sogi_a, i_ab.x, NULL);
  float h_b = fw_sogi_step_f32(&c->sogi_b, i_ab.y, NULL);
  c->h_sogi[0] = h_a;
  c->h_sogi[1] = h_b;

  fw_vec2_f32_t dh;
  if (ex == FW_EXTRACTOR_PSEUDO) {
    dh.x = i_ab.x - c->h_prev_raw[0];
    dh.y = i_ab.y - c->h_prev_raw[1];
  } else {
    dh.x = h_a - c->h_prev_sogi[0];
    dh.y = h_b - c->h_prev_sogi[1];
  }
  c->h_prev_raw[0] = i_ab.x;
  c->h_prev_raw[1] = i_ab.y;
  c->h_prev_sogi[0] = h_a;
  c->h_prev_sogi[1] = h_b;

  /* Demodulate in the frame the estimate had when this HF response was
   * produced: half a period back for the difference, plus the SOGI's group
   * delay at the carrier. Rotating by the present estimate instead mixes the
   * delay into the saliency term and locks at a lag of about
   * (1 + G_sum/G_diff) w tau / 2 (3 w tau for Lq = 1.5 Ld). */
  float tau_s = 0.5f * c->dt_s;
  if (ex != FW_EXTRACTOR_PSEUDO) {
    tau_s += c->sogi_gd_s;
  }
  fw_sincos_f32_t sc_d = fw_sincos_f32(c->pll.theta_rad - c->pll.w_i_radps * tau_s);
  fw_vec2_f32_t dh_dq = fw_park_f32(dh, sc_d);
  /* Voltage applied over [k-1, k] was commanded at k-2. sign_hist is shifted
   * later in this step, so here sign_hist[0] = s(k-1), sign_hist[1] = s(k-2). */
  float s = c->sign_hist[1];
  ring_push(c, s * dh_dq.x, s * dh_dq.y, i_ab.x, i_ab.y);
  float inv_n = c->ring_fill == c->n_inj ? c->inv_n_inj : 1.0f / (float)c->ring_fill;
  float E_d = c->sum_ed * inv_n;
  float E_q = c->sum_eq * inv_n;

  float eps = 0.0f;
  float floor_A = 1e-6f;
  if (E_d > floor_A) {
    eps = (E_q / E_d) * c->eps_gain;
    eps = fw_clampf(eps, -1.0f, 1.0f);
  }
  if (c->est_hold_s > 0.0f) { /* extractor just switched */
    c->est_hold_s -= c->dt_s;
    eps = 0.0f;
  }
  if (c->phase == FW_START_SALIENCY) {
    eps = 0.0f; /* injection moves to q^ during the check: hold the estimate */
  } else if (c->bemf.active) {
    eps = fw_bemf_error(&c->bemf); /* above injection speeds */
  }
  /* Low-passed *signed* error: its magnitude is the tracking error. The
   * per-sample eps carries ~0.04 rad of sensor noise, so a filtered |eps|
   * would measure the noise, not the lock. */
  c->err_f += c->err_alpha * (eps - c->err_f);
  const float err_abs = fabsf(c->err_f);

  if (ex == FW_EXTRACTOR_SOGI_ADAPTIVE) {
    /* Observable adaptation (replaces eq. 13's theta - theta_hat): a wide
     * band while the PLL error is large, a narrow one when locked. */
    float r = fw_clampf(err_abs * c->inv_adapt_err, 0.0f, 1.0f);
    float k = cfg->sogi_k_adapt_min + (cfg->sogi_k_adapt_max - cfg->sogi_k_adapt_min) * r;
    if (fabsf(k - c->sogi_a.k) > FW_SOGI_K_STEP) {
      sogi_set_k_both(c, k);
    }
  }

  if (c->ring_fill < c->n_inj || c->phase_time_s < FW_EST_SETTLE_S) {
    eps = 0.0f; /* filters still settling: extrapolate, do not correct */
  }
  /* Bandwidth scheduling: all observer poles scaled by lambda in [bw_min, 1],
   * lambda rising with the tracking error (same observable as the SOGI). */
  {
    float lam = cfg->pll_bw_min +
                (1.0f - cfg->pll_bw_min) * fw_clampf(err_abs * c->inv_adapt_err, 0.0f, 1.0f);
    c->pll_scale = lam;
    c->pll.kp = cfg->pll_kp * lam;
    c->pll.ki = cfg->pll_ki * lam * lam;
  }
  fw_pll_step_f32(&c->pll, eps, c->dt_s);
  /* Mechanical observer extension of the PLL: the speed state also
   * integrates the acceleration the measured thrust current predicts, plus
   * an estimated disturbance (load, friction) driven by the same error.
   * Error dynamics: e''' + kp e'' + ki e' + kd e = (disturbance changes). */
  if (c->phase == FW_START_RUN) {
    c->pll.w_i_radps += c->dt_s * (cfg->pll_accel_per_A * c->i_q_ff_A + c->accel_dist);
    c->pll.w_i_radps = fw_clampf(c->pll.w_i_radps, -cfg->speed_max_radps_e, cfg->speed_max_radps_e);
    c->accel_dist += c->dt_s * cfg->pll_kd * c->pll_scale * c->pll_scale * c->pll_scale * eps;
  }
  float dth = fw_wrap_pi_f32(c->pll.theta_rad - c->theta_prev);
  pos_add(c, dth);
  c->theta_prev = c->pll.theta_rad;
  c->omega_f += c->spd_alpha * (c->pll.w_i_radps - c->omega_f);

  c->snap.pll_err_rad = eps;
  c->snap.hf_amp_A = E_d;
  *hf_amp_A = E_d;
  c->snap.hf_q_A = E_q;
  c->snap.i_h_ab_A[0] = ex == FW_EXTRACTOR_PSEUDO ? dh.x : h_a;
  c->snap.i_h_ab_A[1] = ex == FW_EXTRACTOR_PSEUDO ? dh.y : h_b;

  fw_vec2_f32_t i_f;
  if (ex == FW_EXTRACTOR_PSEUDO) {
    i_f.x = c->sum_ia * inv_n; /* one-period average removes the square-wave response */
    i_f.y = c->sum_ib * inv_n;
  } else {
    i_f.x = i_ab.x - h_a; /* eq. 10: fundamental = measured - extracted HF */
    i_f.y = i_ab.y - h_b;
  }
  return i_f;
}

/** HF-response and PLL-error supervision (loss of lock). */
static void supervise_estimator(fw_ctrl_t *c, float hf_amp_A) {
  const fw_config_t *cfg = &c->cfg;
  if (c->phase_time_s < FW_HF_SUPERVISION_DELAY_S || c->ring_fill < c->n_inj) {
    return;
  }
  if (cfg->u_inj_V > 0.0f && hf_amp_A < c->hf_min_A * c->bemf.inj_scale) {
    latch_fault(c, FW_FAULT_EST_HF_LOW);
    return;
  }
  if (c->phase == FW_START_RUN) {
    if (fabsf(c->err_f) > cfg->pll_err_max_rad) {
      c->pll_err_time_s += c->dt_s;
      if (c->pll_err_time_s > cfg->pll_err_time_s) {
        latch_fault(c, FW_FAULT_EST_PLL_ERROR);
      }
    } else {
      c->pll_err_time_s = 0.0f;
    }
  }
}

/* ---- start-up: magnet polarity ------------------------------------------ */

/**
 * Polarity test: per pair, N samples at zero, +V for N and -V for N
 * (positive current excursion and return), N at zero, then -V / +V
 * (negative excursion and return). With d-axis saturation the excursion along the magnet
 * (+d) is larger. Returns the d-hat voltage to apply this sample.
 */
static float polarity_step(fw_ctrl_t *c, float i_d) {
  const fw_config_t *cfg = &c->cfg;
  uint32_t n = cfg->pol_pulse_samples;
  uint32_t per_pair = 6u * n;
  uint32_t pair = c->pol_k / per_pair;
  uint32_t j = c->pol_k % per_pair;
  uint32_t seg = j / n;
  uint32_t in_seg = j % n;
  float v = cfg->pol_pulse_V;

  if (pair >= cfg->pol_pulse_pairs) {
    /* decision */
    float p = c->pol_sum_pos, m = c->pol_sum_neg;
    c->snap.pol_dI_pos_A = p;
    c->snap.pol_dI_neg_A = m;
    if (p > m * (1.0f + cfg->pol_margin)) {
      c->polarity_flipped = 0u;
    } else if (m > p * (1.0f + cfg->pol_margin)) {
      c->polarity_flipped = 1u;
      fw_pll_reset_f32(&c->pll, c->pll.theta_rad + FW_PI_F32, 0.0f);
      c->theta_prev = c->pll.theta_rad;
      pos_add(c, FW_PI_F32);
    } else {
      latch_fault(c, FW_FAULT_POLARITY_UNDETERMINED);
      return 0.0f;
    }
    /* hand over to closed loop with clean filters */
    float th = c->pll.theta_rad;
    reset_dynamics(c);
    fw_pll_reset_f32(&c->pll, th, 0.0f);
    c->theta_prev = th;
    c->phase = FW_START_RUN;
    c->phase_time_s = 0.0f;
    return 0.0f;
  }

  /* Per pair: 0 (settle, lets the last command take effect), +V, -V, 0, -V, +V.
   * The baseline is sampled at the start of each excursion, the extreme over
   * the pulse and the return (the one-period delay puts the peak one sample
   * into the return segment). */
  if (in_seg == 0u && (seg == 1u || seg == 4u)) {
    c->pol_base = i_d;
    c->pol_ext = i_d;
  }
  if (seg == 1u || seg == 2u) {
    c->pol_ext = i_d > c->pol_ext ? i_d : c->pol_ext;
  } else if (seg == 4u || seg == 5u) {
    c->pol_ext = i_d < c->pol_ext ? i_d : c->pol_ext;
  }
  if (in_seg == n - 1u && seg == 2u) {
    c->pol_sum_pos += c->pol_ext - c->pol_base;
  } else if (in_seg == n - 1u && seg == 5u) {
    c->pol_sum_neg += c->pol_base - c->pol_ext;
  }
  c->pol_k++;
  c->snap.pol_dI_pos_A = c->pol_sum_pos;
  c->snap.pol_dI_neg_A = c->pol_sum_neg;
  switch (seg) {
  case 1u:
  case 5u:
    return v;
  case 2u:
  case 4u:
    return -v;
  default:
    return 0.0f;
  }
}

/* ---- linear-axis protections -------------------------------------------- */

/** Unwrapped estimated position, m. */
static float pos_hat_m(const fw_ctrl_t *c) {
  const float pos_e = (float)c->pos_turns * FW_TWO_PI_F32 + c->pos_unwrapped_e;
  return pos_e * c->cfg.pole_pitch_m / FW_PI_F32;
}

/**
 * i2t, overspeed, software position limits and the speed following error,
 * all on the estimate (the drive has nothing else). A position limit trips
 * only while the command points further out, so that the axis can be driven
 * back after a fault reset.
 */
static fw_fault_t protect(fw_ctrl_t *c, fw_vec2_f32_t i_dq, bool quick_stop) {
  const fw_config_t *cfg = &c->cfg;
  const float dt = c->dt_s;
  const float ir2 = cfg->i_rated_A * cfg->i_rated_A;
  c->i2t_A2s += (i_dq.x * i_dq.x + i_dq.y * i_dq.y - ir2) * dt;
  c->i2t_A2s = c->i2t_A2s > 0.0f ? c->i2t_A2s : 0.0f;
  if (cfg->i_rated_A < cfg->i_max_A &&
      c->i2t_A2s > (cfg->i_max_A * cfg->i_max_A - ir2) * cfg->i2t_time_s) {
    return FW_FAULT_I2T;
  }
  if (fabsf(c->pll.w_i_radps) > c->w_vmax_radps) {
    return FW_FAULT_OVERSPEED;
  }
  if (cfg->pos_limit_min_m < cfg->pos_limit_max_m) {
    const float x = pos_hat_m(c);
    const float cmd = c->mode == FW_MODE_SPEED ? c->speed_ref_radps_e : c->i_q_ref_force_A;
    if ((x > cfg->pos_limit_max_m && !(cmd < 0.0f)) ||
        (x < cfg->pos_limit_min_m && !(cmd > 0.0f))) {
      return FW_FAULT_POSITION_LIMIT;
    }
  }
  bool follow = c->mode == FW_MODE_SPEED && !quick_stop &&
                fabsf(c->speed_ref_radps_e - c->omega_f) > c->w_follow_radps;
  c->follow_time_s = follow ? c->follow_time_s + dt : 0.0f;
  if (c->follow_time_s > cfg->follow_err_time_s) {
    return FW_FAULT_FOLLOWING_ERROR;
  }
  return FW_FAULT_NONE;
}

/**
 * While aligning, follow the back-EMF in the stationary frame,
 * e_ab = u_ab - R i_ab - L di_ab/dt (low-passed), and its rotation over the
 * observation window: magnitude and direction of a moving mover.
 */
static void fly_observe(fw_ctrl_t *c, fw_vec2_f32_t i_f_ab) {
  const fw_config_t *cfg = &c->cfg;
  const float L = 0.5f * (cfg->L_d_H + cfg->L_q_H);
  const float inv_dt = 1.0f / c->dt_s;
  float ea = c->u_ab_prev_V[0] - cfg->R_ohm * i_f_ab.x - L * (i_f_ab.x - c->i_f_ab_prev_A[0]) * inv_dt;
  float eb = c->u_ab_prev_V[1] - cfg->R_ohm * i_f_ab.y - L * (i_f_ab.y - c->i_f_ab_prev_A[1]) * inv_dt;
  c->i_f_ab_prev_A[0] = i_f_ab.x;
  c->i_f_ab_prev_A[1] = i_f_ab.y;
  const float a = 1.0f - expf(-c->dt_s / FW_FLY_TAU_S);
  float pa = c->fly_e_ab_V[0], pb = c->fly_e_ab_V[1];
  c->fly_e_ab_V[0] += a * (ea - pa);
  c->fly_e_ab_V[1] += a * (eb - pb);
  if (c->phase_time_s >= FW_FLY_WINDOW_S) {
    /* angle step between successive filtered vectors (cross / dot) */
    float cr = pa * c->fly_e_ab_V[1] - pb * c->fly_e_ab_V[0];
    float dt = pa * c->fly_e_ab_V[0] + pb * c->fly_e_ab_V[1];
    c->fly_rot_rad += atan2f(cr, dt);
  }
}

/**
 * Motion at enable: catch the mover with the back-EMF observer when its
 * back-EMF is large enough to be tracked (flying start), else refuse.
 * Returns FW_FAULT_NONE when caught.
 */
static fw_fault_t fly_catch(fw_ctrl_t *c) {
  const fw_config_t *cfg = &c->cfg;
  const float ea = c->fly_e_ab_V[0], eb = c->fly_e_ab_V[1];
  const float E = sqrtf(ea * ea + eb * eb);
  if (!(c->bemf.w_on > 0.0f) || E < cfg->bemf_e_off_V || fabsf(c->fly_rot_rad) < 0.05f) {
    return FW_FAULT_MOVING_AT_ENABLE; /* too slow for the back-EMF, too fast for injection */
  }
  const float w0 = (c->fly_rot_rad > 0.0f ? 1.0f : -1.0f) * E / cfg->psi_f_Wb;
  /* e_ab = w psi_f (-sin theta, cos theta); the filter lags by about w tau */
  float th = atan2f(-ea, eb) + (w0 < 0.0f ? FW_PI_F32 : 0.0f) + w0 * FW_FLY_TAU_S;
  th = fw_wrap_pi_f32(th);
  fw_pll_reset_f32(&c->pll, th, w0);
  c->theta_prev = th;
  c->omega_f = w0;
  c->accel_dist = 0.0f;
  c->pi_spd.integ = 0.0f;
  c->phase = FW_START_RUN;
  c->phase_time_s = 0.0f;
  c->flying = 1u;
  const float i0[2] = {0.0f, 0.0f};
  fw_bemf_catch(&c->bemf, w0, i0);
  fw_mon_run_start(&c->mon); /* no standstill saliency check: the HF witness stays off */
  return FW_FAULT_NONE;
}

/** End of the standstill saliency check: judge, then go on to the polarity test. */
static void saliency_done(fw_ctrl_t *c) {
  const float n_avg = (float)((FW_SAL_PERIODS - 1u) * c->n_inj);
  const float inv = 1.0f / n_avg;
  fw_fault_t f = fw_mon_saliency(&c->mon, &c->cfg, c->sal_acc[0] * inv, c->sal_acc[1] * inv,
                                 c->sal_acc[2] * inv, c->sal_acc[3] * inv,
                                 c->dt_s * c->cfg.u_inj_V);
  c->snap.sal_meas = c->mon.sal_meas;
  c->snap.L_small_meas_H = c->mon.L_small_meas_H;
  c->snap.L_large_meas_H = c->mon.L_large_meas_H;
  if (f != FW_FAULT_NONE) {
    latch_fault(c, f);
    return;
  }
  c->phase = FW_START_POLARITY;
  c->phase_time_s = 0.0f;
  c->pol_k = 0u;
  c->pol_sum_pos = c->pol_sum_neg = 0.0f;
}

/* ---- the step ----------------------------------------------------------- */

static fw_fault_t check_inputs(const fw_ctrl_t *c, const fw_inputs_t *in) {
  for (int i = 0; i < 3; i++) {
    if (!fw_isfinite_f32(in->i_abc_A[i])) {
      return FW_FAULT_INPUT_INVALID;
    }
  }
  if (!fw_isfinite_f32(in->u_dc_V)) {
    return FW_FAULT_INPUT_INVALID;
  }
  for (int i = 0; i < 3; i++) {
    if (fabsf(in->i_abc_A[i]) > c->cfg.i_trip_A) {
      return FW_FAULT_OVERCURRENT;
    }
  }
  if (in->u_dc_V > c->cfg.u_dc_max_V) {
    return FW_FAULT_DC_OVERVOLTAGE;
  }
  if (fw_cia402_power_enabled(c->sm.state) && in->u_dc_V < c->cfg.u_dc_min_V) {
    return FW_FAULT_DC_UNDERVOLTAGE;
  }
  return FW_FAULT_NONE;
}

static void outputs_off(fw_outputs_t *out) {
  out->duty_abc[0] = out->duty_abc[1] = out->duty_abc[2] = 0.5f;
  out->pwm_enable = 0u;
}

/** Raw signals of this step into the snapshot; unit conversions and the
 *  statusword are derived on demand in fw_get_snapshot (off the hot path). */
static void fill_snapshot_common(fw_ctrl_t *c, const fw_inputs_t *in, fw_vec2_f32_t i_ab,
                                 const fw_outputs_t *out) {
  fw_snapshot_t *s = &c->snap;
  s->step_count = c->step_count;
  s->cia402_state = (uint8_t)c->sm.state;
  s->start_phase = (uint8_t)c->phase;
  s->fault_code = (uint16_t)c->fault;
  s->theta_hat_rad = c->theta_k;
  s->omega_hat_radps = c->pll.w_i_radps;
  s->omega_f_radps = c->omega_f;
  s->pll_err_f_rad = c->err_f;
  s->accel_dist_radps2 = c->accel_dist;
  s->i_ab_A[0] = i_ab.x;
  s->i_ab_A[1] = i_ab.y;
  s->u_dc_V = in->u_dc_V;
  s->duty_abc[0] = out->duty_abc[0];
  s->duty_abc[1] = out->duty_abc[1];
  s->duty_abc[2] = out->duty_abc[2];
}

void fw_step(fw_ctrl_t *c, const fw_inputs_t *in, fw_outputs_t *out) {
  if (c == NULL || out == NULL) {
    return;
  }
  outputs_off(out);
  c->step_count++;
  if (in == NULL) {
    latch_fault(c, FW_FAULT_INPUT_INVALID);
    return;
  }
  const fw_config_t *cfg = &c->cfg;
  const float dt = c->dt_s;
  c->theta_k = c->pll.theta_rad; /* the estimate belonging to this sample */

  fw_fault_t f = check_inputs(c, in);
  fw_inputs_t safe = *in;
  if (f != FW_FAULT_NONE) {
    latch_fault(c, f);
    if (f == FW_FAULT_INPUT_INVALID) {
      memset(&safe, 0, sizeof(safe)); /* never propagate NaN into the state */
    }
  }
  c->u_dc_V = safe.u_dc_V; /* for the statusword's warning bit */
  if (c->phase != FW_START_IDLE) {
    fw_mon_compensate(&c->mon, safe.i_abc_A); /* offsets learnt at standstill */
  }
  /* monitor inputs: every field is written before fw_mon_update reads it
   * (no memset on the hot path) */
  fw_mon_in_t mi;
  mi.i_abc_A[0] = safe.i_abc_A[0];
  mi.i_abc_A[1] = safe.i_abc_A[1];
  mi.i_abc_A[2] = safe.i_abc_A[2];
  fw_vec2_f32_t i_ab = fw_clarke_f32(safe.i_abc_A[0], safe.i_abc_A[1], safe.i_abc_A[2]);

  /* Fault reaction: brake under control first, or switch off now (latch_fault). */
  bool braking = false;
  if (c->sm.state == FW_CIA402_FAULT_REACTION_ACTIVE) {
    if (!c->fault_hard && c->phase == FW_START_RUN) {
      braking = true;
    } else {
      fw_cia402_fault_reaction_done(&c->sm);
    }
  }
  if (!(fw_cia402_power_enabled(c->sm.state) || braking) || c->phase == FW_START_IDLE) {
    c->phase = FW_START_IDLE;
    fw_mon_learn_offsets(&c->mon, safe.i_abc_A);
    c->i2t_A2s -= c->cfg.i_rated_A * c->cfg.i_rated_A * dt; /* cools down */
    c->i2t_A2s = c->i2t_A2s > 0.0f ? c->i2t_A2s : 0.0f;
    memset(&mi.e_hf_dq_A, 0, sizeof(mi) - offsetof(fw_mon_in_t, e_hf_dq_A));
    fw_fault_t mf = fw_mon_update(&c->mon, &mi); /* current sum with PWM off */
    if (mf != FW_FAULT_NONE) {
      latch_fault(c, mf);
    }
    c->snap.mon_i_sum_A = c->mon.isum_f;
    c->i_q_ff_A = 0.0f;
    memset(c->snap.i_dq_A, 0, sizeof(c->snap.i_dq_A));
    memset(c->snap.u_dq_V, 0, sizeof(c->snap.u_dq_V));
    c->snap.u_inj_V = 0.0f;
    fill_snapshot_common(c, &safe, i_ab, out);
    return;
  }

  c->phase_time_s += dt;
  bool quick_stop = c->sm.state == FW_CIA402_QUICK_STOP_ACTIVE || braking;

  /* ---- estimator and start-up ---- */
  fw_vec2_f32_t i_f_ab = i_ab;
  float u_d_pulse = 0.0f;
  bool pulses = c->phase == FW_START_POLARITY;
  /* theta_hat at the sampling instant: for the current Park and (advanced)
   * the output transform; the demodulation uses its own delayed frame */
  const float theta_k = c->theta_k;
  const fw_sincos_f32_t sc = fw_sincos_f32(theta_k);
  fw_vec2_f32_t e_raw = {0.0f, 0.0f}; /* raw HF difference, sign-demodulated, for the monitor */
  float hf_amp_A = 0.0f;               /* demodulated HF amplitude of this period */
  if (!pulses) {
    fw_vec2_f32_t dh_raw = {i_ab.x - c->h_prev_raw[0], i_ab.y - c->h_prev_raw[1]};
    e_raw = fw_park_f32(dh_raw, sc);
    e_raw.x *= c->sign_hist[1];
    e_raw.y *= c->sign_hist[1];
    i_f_ab = estimator_step(c, i_ab, &hf_amp_A);
  }
  fw_vec2_f32_t i_dq = fw_park_f32(pulses ? i_ab : i_f_ab, sc);
  if (c->phase == FW_START_RUN && !pulses) {
    const float i_dq_arr[2] = {i_dq.x, i_dq.y};
    fw_bemf_update(&c->bemf, c->u_dq_prev_V, i_dq_arr, c->pll.w_i_radps);
    fw_bemf_schedule(&c->bemf, c->pll.w_i_radps, (uint8_t)(c->ring_fill == c->n_inj));
  }
  if (pulses) {
    u_d_pulse = polarity_step(c, i_dq.x);
    if (c->phase == FW_START_RUN) {
      fw_mon_run_start(&c->mon);
    }
  } else if (c->phase != FW_START_SALIENCY) {
    supervise_estimator(c, hf_amp_A);
  }
  /* End ALIGN where the HF current triangle crosses its mean (the middle of
   * the positive half period): no residual HF current biases the pulses.
   * This step commands injection index inj_idx; the last + command before
   * the mean is index n/4 - 1. */
  uint32_t last_idx = c->n_inj / 4u > 0u ? c->n_inj / 4u - 1u : 0u;
  /* During the alignment the zero-current loop holds i = 0: the voltage it
   * needs is the back-EMF of a moving mover (judged once the loop and the
   * monitor's filter have settled, and again at the end). */
  if (c->phase == FW_START_ALIGN) {
    fly_observe(c, i_f_ab);
  }
  if (c->phase == FW_START_ALIGN && c->phase_time_s >= FW_MOTION_CHECK_S &&
      fw_mon_motion(&c->mon, c->e_start_max_V) != FW_FAULT_NONE) {
    fw_fault_t mf = fly_catch(c); /* moving: catch it on the back-EMF, or refuse */
    if (mf != FW_FAULT_NONE) {
      latch_fault(c, mf);
    }
  }
  if (c->phase == FW_START_ALIGN && c->phase_time_s >= cfg->align_time_s &&
      c->inj_idx == last_idx && c->fault == FW_FAULT_NONE) {
    {
      c->phase = FW_START_SALIENCY; /* whole injection periods: ends on the same phase */
      c->phase_time_s = 0.0f;
      c->sal_k = 0u;
      memset(c->sal_acc, 0, sizeof(c->sal_acc));
    }
  }
  const uint32_t sal_col_len = FW_SAL_PERIODS * c->n_inj;
  if (c->phase == FW_START_SALIENCY && c->sal_k % sal_col_len >= c->n_inj) {
    uint32_t col = c->sal_k / sal_col_len; /* 0: square wave on d^, 1: on q^ */
    c->sal_acc[2u * col] += e_raw.x;
    c->sal_acc[2u * col + 1u] += e_raw.y;
  }
  braking = braking && c->sm.state == FW_CIA402_FAULT_REACTION_ACTIVE;
  if (!(fw_cia402_power_enabled(c->sm.state) || braking)) { /* a fault was latched above */
    fill_snapshot_common(c, &safe, i_ab, out);
    return;
  }

  /* ---- references ---- */
  float i_d_ref = 0.0f, i_q_ref = 0.0f;
  if (c->phase == FW_START_RUN) {
    float w_ref = quick_stop ? 0.0f : c->speed_ref_radps_e;
    i_d_ref = c->i_d_ref_A;
    if (c->mode == FW_MODE_SPEED) {
      i_q_ref = fw_pi_step_f32(&c->pi_spd, w_ref - c->omega_f, 0.0f, dt);
    } else {
      i_q_ref = quick_stop ? 0.0f : c->i_q_ref_force_A;
    }
  }
  if (quick_stop) {
    c->qs_time_s += dt;
    bool still = c->mode == FW_MODE_FORCE || fabsf(c->omega_f) < FW_QS_STILL_RADPS ||
                 c->phase != FW_START_RUN;
    c->qs_still_s = still ? c->qs_still_s + dt : 0.0f;
    /* braking after a fault is bounded by fault_brake_time_s: a lost
     * supervisor must see the power stage off soon, at any speed */
    float t_max = braking ? cfg->fault_brake_time_s : cfg->quick_stop_time_s;
    if (c->qs_still_s >= FW_QS_STILL_TIME_S || c->qs_time_s >= t_max) {
      if (braking) {
        fw_cia402_fault_reaction_done(&c->sm); /* stopped: PWM off, FAULT */
      } else {
        fw_cia402_quick_stop_done(&c->sm);
      }
      c->phase = FW_START_IDLE;
      fill_snapshot_common(c, &safe, i_ab, out);
      return;
    }
  }

  /* ---- current loop (estimated frame) ---- */
  float u_lim = FW_PI_VOLTAGE_SHARE * safe.u_dc_V * FW_INV_SQRT3_F32;
  c->pi_d.out_min = c->pi_q.out_min = -u_lim;
  c->pi_d.out_max = c->pi_q.out_max = u_lim;
  float w = c->omega_f;
  fw_vec2_f32_t u_dq;
  if (pulses) {
    u_dq.x = u_d_pulse;
    u_dq.y = 0.0f;
  } else {
    float ff_d = -w * cfg->L_q_H * i_dq.y;
    float ff_q = w * (cfg->L_d_H * i_dq.x + cfg->psi_f_Wb);
    u_dq.x = fw_pi_step_f32(&c->pi_d, i_d_ref - i_dq.x, ff_d, dt);
    u_dq.y = fw_pi_step_f32(&c->pi_q, i_q_ref - i_dq.y, ff_q, dt);
  }

  /* ---- integrity monitor and protections ---- */
  {
    const bool running = c->phase == FW_START_RUN;
    const bool scale_full = c->bemf.inj_scale >= 1.0f;
    const bool scale_steady = scale_full || c->bemf.inj_scale <= c->bemf.inj_share;
    /* the HF witness judges the response per volt of injection: scale back (no
     * division while the injection is full, the usual case) */
    const float inv_scale = scale_full ? 1.0f : 1.0f / c->bemf.inj_scale;
    mi.e_hf_dq_A[0] = e_raw.x * inv_scale;
    mi.e_hf_dq_A[1] = e_raw.y * inv_scale;
    mi.u_dq_V[0] = c->u_dq_prev_V[0];
    mi.u_dq_V[1] = c->u_dq_prev_V[1];
    mi.i_dq_A[0] = i_dq.x;
    mi.i_dq_A[1] = i_dq.y;
    mi.i_dq_ref_A[0] = i_d_ref;
    mi.i_dq_ref_A[1] = i_q_ref;
    mi.omega_hat_radps = c->pll.w_i_radps;
    mi.accel_dist_radps2 = c->accel_dist;
    mi.running = (uint8_t)running;
    mi.hf_valid = (uint8_t)(running && !pulses && scale_steady && c->ring_fill == c->n_inj &&
                            c->phase_time_s >= FW_HF_SUPERVISION_DELAY_S &&
                            c->sign_hist[1] != 0.0f);
    mi.pwm_on = 1u;
    fw_fault_t mf = fw_mon_update(&c->mon, &mi);
    if (mf == FW_FAULT_NONE && running) {
      mf = protect(c, i_dq, quick_stop);
    }
    c->snap.mon_angle_hf_rad = c->mon.angle_hf_rad;
    c->snap.mon_angle_bemf_rad = c->mon.angle_bemf_rad;
    c->snap.mon_e_bemf_V = c->mon.e_bemf_V;
    c->snap.mon_i_sum_A = c->mon.isum_f;
    if (mf != FW_FAULT_NONE) {
      latch_fault(c, mf);
      if (c->fault_hard) { /* switch off now; braking faults go on braking */
        fill_snapshot_common(c, &safe, i_ab, out);
        return;
      }
    }
  }
  c->u_dq_prev_V[0] = u_dq.x;
  c->u_dq_prev_V[1] = u_dq.y;

  /* ---- square-wave injection on the estimated d axis ---- */
  float s = 0.0f;
  if (!pulses && cfg->u_inj_V > 0.0f) {
    s = (c->inj_idx < c->n_inj / 2u) ? 1.0f : -1.0f;
    c->inj_idx = (c->inj_idx + 1u == c->n_inj) ? 0u : c->inj_idx + 1u;
  }
  c->sign_hist[3] = c->sign_hist[2];
  c->sign_hist[2] = c->sign_hist[1];
  c->sign_hist[1] = c->sign_hist[0];
  c->sign_hist[0] = s;
  const bool inj_q = c->phase == FW_START_SALIENCY && c->sal_k >= sal_col_len;
  const float u_inj = cfg->u_inj_V * c->bemf.inj_scale;
  fw_vec2_f32_t u_cmd = {u_dq.x + (inj_q ? 0.0f : s * u_inj), u_dq.y + (inj_q ? s * u_inj : 0.0f)};

  /* ---- modulation: the voltage acts over [k+1, k+2] (update delay), so the
   * transform uses the angle 1.5 periods after sampling ---- */
  fw_sincos_f32_t sc_out = fw_sincos_f32(theta_k + 1.5f * c->pll.w_hat_radps * dt);
  fw_vec2_f32_t u_ab = fw_inv_park_f32(u_cmd, sc_out);
  if (c->phase == FW_START_ALIGN) { /* fundamental only, for the flying-start observer */
    fw_vec2_f32_t u_f = fw_inv_park_f32(u_dq, sc_out);
    c->u_ab_prev_V[0] = u_f.x;
    c->u_ab_prev_V[1] = u_f.y;
  }
  (void)fw_svpwm_f32(u_ab, safe.u_dc_V, out->duty_abc, NULL);
  out->pwm_enable = 1u;

  c->i_q_ff_A = i_dq.y;
  c->i_q_ref_A = i_q_ref;
  c->snap.i_dq_A[0] = i_dq.x;
  c->snap.i_dq_A[1] = i_dq.y;
  c->snap.i_dq_ref_A[0] = i_d_ref;
  c->snap.i_dq_ref_A[1] = i_q_ref;
  c->snap.u_dq_V[0] = u_dq.x;
  c->snap.u_dq_V[1] = u_dq.y;
  c->snap.u_inj_V = s * u_inj;
  c->snap.inj_scale = c->bemf.inj_scale;
  c->snap.bemf_active = c->bemf.active;
  c->snap.flying_start = c->flying;
  c->snap.bemf_err_rad = fw_bemf_error(&c->bemf);
  if (c->phase == FW_START_SALIENCY && ++c->sal_k == 2u * sal_col_len) {
    saliency_done(c);
    if (c->fault_hard) {
      outputs_off(out);
    }
  }
  fill_snapshot_common(c, &safe, i_ab, out);
}

void fw_step_adc(fw_ctrl_t *c, const fw_adc_inputs_t *in, fw_outputs_t *out) {
  if (c == NULL || out == NULL) {
    return;
  }
  if (in == NULL) {
    fw_step(c, NULL, out);
    return;
  }
  fw_inputs_t x;
  if (!fw_adc_convert(&c->cfg, in, &x)) {
    latch_fault(c, FW_FAULT_ADC_RANGE);
  }
  fw_step(c, &x, out);
}

bool fw_adc_convert(const fw_config_t *cfg, const fw_adc_inputs_t *adc, fw_inputs_t *in) {
  bool ok = adc->u_dc_counts <= cfg->adc_max_count;
  for (int i = 0; i < 3; i++) {
    ok = ok && adc->i_abc_counts[i] <= cfg->adc_max_count;
    in->i_abc_A[i] = ((float)adc->i_abc_counts[i] - cfg->adc_offset_counts) * cfg->adc_A_per_count;
  }
  in->u_dc_V = (float)adc->u_dc_counts * cfg->adc_V_per_count;
  return ok;
}

void fw_get_snapshot(const fw_ctrl_t *ctrl, fw_snapshot_t *snap) {
  if (ctrl == NULL || snap == NULL) {
    return;
  }
  const fw_config_t *cfg = &ctrl->cfg;
  *snap = ctrl->snap;
  snap->extractor = (uint8_t)cfg->extractor;
  snap->mode = (uint8_t)ctrl->mode;
  snap->polarity_flipped = ctrl->polarity_flipped;
  const float pos_e = (float)ctrl->pos_turns * FW_TWO_PI_F32 + ctrl->pos_unwrapped_e;
  snap->pos_hat_m = pos_hat_m(ctrl);
  snap->speed_hat_mps = fw_units_radps_e_to_mps(cfg, ctrl->pll.w_i_radps);
  snap->pos_hat_mech_rad = pos_e / cfg->pole_pairs;
  snap->speed_hat_rpm = fw_units_radps_e_to_rpm(cfg, ctrl->pll.w_i_radps);
  snap->sogi_k_eff = ctrl->sogi_a.k;
  snap->speed_ref_radps_e = ctrl->speed_ref_radps_e;
  snap->force_hat_N = fw_units_force_per_A(cfg) * snap->i_dq_A[1];
  snap->torque_hat_Nm = 1.5f * cfg->pole_pairs * cfg->psi_f_Wb * snap->i_dq_A[1];
  snap->statusword = fw_statusword(ctrl);
}

/* ---- units ---------------------------------------------------------------- */

float fw_units_mps_to_radps_e(const fw_config_t *cfg, float v) {
  return FW_PI_F32 * v / cfg->pole_pitch_m;
}
float fw_units_radps_e_to_mps(const fw_config_t *cfg, float w) {
  return w * cfg->pole_pitch_m / FW_PI_F32;
}
float fw_units_rpm_to_radps_e(const fw_config_t *cfg, float n) {
  return n * FW_TWO_PI_F32 * cfg->pole_pairs / 60.0f;
}
float fw_units_radps_e_to_rpm(const fw_config_t *cfg, float w) {
  return w * 60.0f / (FW_TWO_PI_F32 * cfg->pole_pairs);
}
float fw_units_force_per_A(const fw_config_t *cfg) {
  return 1.5f * (FW_PI_F32 / cfg->pole_pitch_m) * cfg->psi_f_Wb;
}
