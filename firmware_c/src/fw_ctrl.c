/**
 * @file fw_ctrl.c
 * @brief Sensorless drive core: the orchestration of the blocks and the drive
 *        state machine (CiA 402 reactions, start-up sequence, quick stop).
 *
 * Per PWM period k, fw_step() runs (see docs/architecture.md, docs/firmware.md):
 *   fault   input checks (fw_fault_check_inputs), latch (fw_fault_latch_update)
 *   mon     offset compensation; with the power stage off: offsets, current sum
 *   inj     extraction and demodulation of the HF response (fw_inj_update)
 *   obs     angle error, PLL, filtered speed (fw_obs_update_pll)
 *   foc     Park of the fundamental current (fw_foc_measure)
 *   bemf    back-EMF observer and handover (closed loop)
 *   start   polarity pulses and decision (fw_start_polarity) / flying-start
 *           observation and catch (fw_start_fly_catch_begin) / saliency check;
 *           the phase transitions are this file's
 *   obs     HF-loss and PLL-error supervision (fw_obs_supervise)
 *   foc     speed PI (fw_foc_speed_update), current PIs (fw_foc_current_update)
 *   mon     the integrity monitor's inputs, staged (stage_supervision)
 *   inj     the injection sign (fw_inj_output)
 *   foc     modulation (fw_foc_output); xsat: dead-time compensation of the duties
 *           (fw_xsat_deadtime) and the cross-saturation map's next offset (fw_xsat_update),
 *           which the observer subtracts from its HF error
 * and writes the snapshot, which nothing reads back. That is fw_step_into,
 * the control half: ADC to duties. fw_supervise, the supervision half, then
 * writes the current loop's snapshot fields, does what the period left to it
 * because nothing before the duties needs it (supervise_deferred: the
 * observer's position, the adaptive SOGI gain back to inj (fw_inj_adapt), the
 * back-EMF angle error, the flying-start rotation and the rest of a catch), judges
 * a completed saliency check (fw_start_saliency_done), and runs the integrity
 * monitor (fw_mon_update) and the protections (fw_protect_step) on the staged
 * inputs; a hard fault there
 * switches the duties just computed off before they take effect
 * (docs/firmware.md, "the two interrupts").
 */
#include <math.h>
#include <stddef.h>
#include <string.h>

#include "pmlsm/fw_ctrl.h"

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

/* ---- helpers ------------------------------------------------------------ */

/** A quick stop or a fault reaction brakes from now on: the time it may take
 *  (option: its fw_reaction_t; the speed: the filtered estimate's). */
static void brake_start(fw_ctrl_t *c, int32_t option) {
  c->qs_left_s = fw_fault_brake_time_max_s(&c->cfg, option,
                                           fw_units_radps_e_to_mps(&c->cfg, c->obs.omega_f));
  c->qs_still_s = 0.0f;
}

/** Latch a fault and take the CiA 402 consequences: FAULT REACTION ACTIVE
 *  (braking first only for faults fw_fault_brakes_first allows, bounded as
 *  fw_fault_brake_time_max_s says), or, for a hard fault while braking, the end
 *  of the reaction (PWM off). */
static void latch_fault(fw_ctrl_t *c, fw_fault_t code) {
  if (code == FW_FAULT_NONE) {
    return;
  }
  fw_fault_latch_update(&c->fault, code, c->cfg.protection.fault_reaction_option);
  if (c->sm.state == FW_CIA402_FAULT_REACTION_ACTIVE && c->fault.hard) {
    fw_cia402_fault_reaction_done(&c->sm); /* a hard fault ends any braking */
  } else if (c->sm.state != FW_CIA402_FAULT &&
             c->sm.state != FW_CIA402_FAULT_REACTION_ACTIVE) {
    fw_cia402_fault(&c->sm);
    brake_start(c, c->cfg.protection.fault_reaction_option); /* used if it brakes */
  }
}

static void foc_param(const fw_config_t *cfg, float dt_s, fw_foc_param_t *p) {
  p->dt_s = dt_s;
  p->cur_kp_V_per_A = cfg->loops.cur_kp_V_per_A;
  p->cur_ki_V_per_As = cfg->loops.cur_ki_V_per_As;
  p->spd_kp_A_per_radps = cfg->loops.spd_kp_A_per_radps;
  p->spd_ki_A_per_rad = cfg->loops.spd_ki_A_per_rad;
  p->i_max_A = cfg->loops.i_max_A;
  p->R_ohm = cfg->machine.R_ohm;
  p->L_d_H = cfg->machine.L_d_H;
  p->L_q_H = cfg->machine.L_q_H;
  p->psi_f_Wb = cfg->machine.psi_f_Wb;
}

/** A field of fw_snapshot_capture_slow may change (fw_ctrl_t.snap_slow_gen). */
static void snap_slow_changed(fw_ctrl_t *c) { c->snap_slow_gen++; }

/** Reset everything that carries history across an enable (the observer's
 *  position aside: see fw_obs_keep_position). */
static void reset_dynamics(fw_ctrl_t *c) {
  const fw_config_t *cfg = &c->cfg;
  snap_slow_changed(c); /* the flying-start flag */
  fw_foc_param_t fp;
  foc_param(cfg, c->dt_s, &fp);
  fw_foc_reset(&c->foc, &fp);
  fw_inj_reset(&c->inj, &cfg->estimator);
  fw_obs_reset(&c->obs, cfg);
  fw_xsat_reset(&c->comp);
  c->phase = FW_START_IDLE;
  c->phase_time_s = 0.0f;
  c->qs_left_s = 0.0f;
  c->qs_still_s = 0.0f;
  fw_protect_reset(&c->prot);
  fw_bemf_reset(&c->bemf);
  fw_start_reset(&c->start);
}

/** *dst = v clamped to +-lim: FW_ERR_RANGE when it was beyond, FW_ERR_NOT_FINITE
 *  (nothing changed) for NaN/inf. */
static fw_status_t set_clamped(float *dst, float v, float lim) {
  if (!fw_isfinite_f32(v)) {
    return FW_ERR_NOT_FINITE;
  }
  *dst = fw_clampf(v, -lim, lim);
  return (v > lim || v < -lim) ? FW_ERR_RANGE : FW_OK;
}

/** set_clamped for a target: also sets or clears its FW_REF_LIMITED_ bit. The
 *  background gives the references every pass: the snapshot's slow part changes
 *  only when the value or the bit does. */
static fw_status_t limit_ref(fw_ctrl_t *c, float *dst, float v, float lim, uint8_t bit) {
  const float before = *dst;
  const fw_status_t st = set_clamped(dst, v, lim);
  if (st == FW_ERR_NOT_FINITE) {
    return st;
  }
  const uint8_t flags =
      (uint8_t)(st == FW_ERR_RANGE ? (c->ref_limited | bit) : (c->ref_limited & ~bit));
  if (*dst != before || flags != c->ref_limited) {
    snap_slow_changed(c);
  }
  c->ref_limited = flags;
  return st;
}

/** The speed target's limit: speed_max_radps_e, or v_max_mps (CiA 402 0x6080, "Max
 *  motor speed") when smaller; OVERSPEED trips only above v_max_mps x overspeed_margin. */
static float speed_ref_max(const fw_config_t *cfg) {
  return fminf(cfg->loops.speed_max_radps_e,
               fw_units_mps_to_radps_e(cfg, cfg->protection.v_max_mps));
}

static void apply_config(fw_ctrl_t *c, const fw_config_t *cfg, fw_status_t st) {
  snap_slow_changed(c); /* extractor, speed reference */
  c->cfg = *cfg;
  c->cfg_ok = (uint8_t)(st == FW_OK || st == FW_ERR_SALIENCY);
  c->saliency_ok = (uint8_t)(st == FW_OK);
  c->dt_s = 1.0f / cfg->sensing.f_pwm_Hz;
  fw_inj_init(&c->inj, cfg, c->dt_s);
  fw_obs_init(&c->obs, cfg, c->dt_s);
  fw_xsat_init(&c->comp, cfg, c->dt_s);
  fw_protect_config(&c->prot, cfg, c->dt_s);
  c->e_start_max_V = fw_units_bemf_V(cfg, cfg->protection.start_speed_max_mps);
  fw_mon_init(&c->mon, cfg, c->dt_s);
  fw_bemf_init(&c->bemf, cfg, c->dt_s);
  fw_start_init(&c->start, c->dt_s);
  /* references set under the old limits must obey the new ones (a reference clamped
     before stays marked: the background gives the raw one again at its next pass) */
  const uint8_t was_limited = c->ref_limited;
  c->speed_ref_max_radps_e = speed_ref_max(cfg);
  (void)limit_ref(c, &c->speed_ref_radps_e, c->speed_ref_radps_e, c->speed_ref_max_radps_e,
                  FW_REF_LIMITED_SPEED);
  (void)limit_ref(c, &c->i_q_ref_force_A, c->i_q_ref_force_A, cfg->loops.i_max_A,
                  FW_REF_LIMITED_FORCE);
  c->ref_limited |= was_limited;
  c->i_d_ref_A = fw_clampf(c->i_d_ref_A, -cfg->loops.i_max_A, cfg->loops.i_max_A);
  fw_obs_keep_position(&c->obs); /* the estimate restarts from 0 */
  reset_dynamics(c);
}

/* ---- configuration and commands ----------------------------------------- */

fw_status_t fw_init(fw_ctrl_t *ctrl, const fw_config_t *cfg) {
  if (ctrl == NULL) {
    return FW_ERR_NULL;
  }
  /* the generation goes on across a restart: a snapshot copied before it
   * must not look current (its value is unspecified only on a first init of
   * uninitialised storage, when no snapshot exists yet) */
  const uint32_t gen = ctrl->snap_slow_gen;
  memset(ctrl, 0, sizeof(*ctrl));
  ctrl->snap_slow_gen = gen + 1u;
  fw_cia402_init(&ctrl->sm);
  fw_fault_latch_init(&ctrl->fault);
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
  snap_slow_changed(ctrl);
  /* NOT READY TO SWITCH ON until the current zeros are measured (fw_cal.h;
   * boot_calibrate passes to SWITCH ON DISABLED) */
  fw_cal_start(&ctrl->cal, &ctrl->cfg.sensing, ctrl->dt_s);
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

uint16_t fw_statusword_of(const fw_config_t *cfg, fw_cia402_state_t state, float u_dc_V,
                          fw_start_phase_t phase, fw_mode_t mode, float speed_ref,
                          float omega_f, uint8_t ref_limited, float i_q_ref) {
  bool warning = u_dc_V < cfg->protection.u_dc_min_V;
  bool reached = false;
  bool limit = false;
  if (state == FW_CIA402_OPERATION_ENABLED) {
    /* bit 11, internal limit active: the target of the mode in use is clamped, or
       (closed loop, speed mode) the speed loop asks for the current limit */
    limit = (ref_limited & (mode == FW_MODE_SPEED ? FW_REF_LIMITED_SPEED
                                                  : FW_REF_LIMITED_FORCE)) != 0u;
    if (phase == FW_START_RUN) {
      if (mode == FW_MODE_SPEED) {
        float e = speed_ref - omega_f;
        float tol = 0.02f * fabsf(speed_ref) + 1.0f;
        reached = fabsf(e) < tol;
        limit = limit || fabsf(i_q_ref) >= cfg->loops.i_max_A;
      } else {
        reached = true;
      }
    }
  }
  const fw_cia402_t sm = {.state = state};
  return fw_cia402_statusword(&sm, warning, true, reached, limit);
}

uint16_t fw_statusword(const fw_ctrl_t *ctrl) {
  /* the core's own state, not the snapshot (write-only, and in fw_app a ring slot:
     ctrl->snap holds the last period only when the ring was full) */
  return fw_statusword_of(&ctrl->cfg, ctrl->sm.state, ctrl->u_dc_V, ctrl->phase, ctrl->mode,
                          ctrl->speed_ref_radps_e, ctrl->obs.omega_f, ctrl->ref_limited,
                          fw_foc_i_q_ref(&ctrl->foc));
}

uint16_t fw_controlword(fw_ctrl_t *ctrl, uint16_t cw) {
  snap_slow_changed(ctrl); /* commands are rare: no need to be precise */
  fw_cia402_state_t before = ctrl->sm.state;
  fw_cia402_state_t after = fw_cia402_controlword(&ctrl->sm, cw);
  if (before == FW_CIA402_FAULT && after != FW_CIA402_FAULT) {
    fw_fault_latch_reset(&ctrl->fault); /* fault reset: history is kept */
  }
  if (after == FW_CIA402_OPERATION_ENABLED && before != FW_CIA402_OPERATION_ENABLED &&
      before != FW_CIA402_QUICK_STOP_ACTIVE) {
    if (!ctrl->cfg_ok) {
      latch_fault(ctrl, FW_FAULT_CONFIG_INVALID);
    } else if (!ctrl->saliency_ok) {
      latch_fault(ctrl, FW_FAULT_SALIENCY_TOO_LOW); /* injection refused */
    } else {
      /* the current zeros measured at boot, judged with the configuration in force;
       * then the offsets learnt at standstill since (drift) */
      fw_fault_t f = fw_cal_judge(&ctrl->cal, &ctrl->cfg);
      if (f == FW_FAULT_NONE) {
        f = fw_mon_enable(&ctrl->mon);
      }
      if (f != FW_FAULT_NONE) {
        latch_fault(ctrl, f);
      } else {
        fw_obs_keep_position(&ctrl->obs); /* the estimate restarts from 0 */
        reset_dynamics(ctrl);
        ctrl->phase = FW_START_ALIGN;
      }
    }
  }
  if (after == FW_CIA402_QUICK_STOP_ACTIVE && before != FW_CIA402_QUICK_STOP_ACTIVE) {
    brake_start(ctrl, ctrl->cfg.protection.quick_stop_option);
    if (ctrl->cfg.protection.quick_stop_option == (int32_t)FW_REACT_SWITCH_OFF) {
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
    fw_foc_speed_bumpless(&ctrl->foc);
  }
  ctrl->mode = mode;
  snap_slow_changed(ctrl);
  return FW_OK;
}

fw_status_t fw_set_speed_ref(fw_ctrl_t *ctrl, float w) {
  return ctrl ? limit_ref(ctrl, &ctrl->speed_ref_radps_e, w, ctrl->speed_ref_max_radps_e,
                          FW_REF_LIMITED_SPEED)
              : FW_ERR_NULL;
}

fw_status_t fw_set_iq_ref(fw_ctrl_t *ctrl, float i) {
  return ctrl ? limit_ref(ctrl, &ctrl->i_q_ref_force_A, i, ctrl->cfg.loops.i_max_A,
                          FW_REF_LIMITED_FORCE)
              : FW_ERR_NULL;
}

fw_status_t fw_set_force_ref(fw_ctrl_t *ctrl, float force_N) {
  if (ctrl == NULL) return FW_ERR_NULL;
  const float k_f = fw_units_force_per_A(&ctrl->cfg);
  if (!(k_f > 0.0f) || !fw_isfinite_f32(force_N)) return FW_ERR_NOT_FINITE;
  return fw_set_iq_ref(ctrl, force_N / k_f);
}

fw_status_t fw_set_id_ref(fw_ctrl_t *ctrl, float i) {
  return ctrl ? set_clamped(&ctrl->i_d_ref_A, i, ctrl->cfg.loops.i_max_A) : FW_ERR_NULL;
}

fw_status_t fw_set_extractor(fw_ctrl_t *ctrl, fw_extractor_t ex) {
  if (ctrl == NULL) {
    return FW_ERR_NULL;
  }
  if (ex != FW_EXTRACTOR_PSEUDO && ex != FW_EXTRACTOR_SOGI && ex != FW_EXTRACTOR_SOGI_ADAPTIVE) {
    return FW_ERR_RANGE;
  }
  ctrl->cfg.estimator.extractor = (uint32_t)ex;
  snap_slow_changed(ctrl);
  /* demodulated history belongs to the old path: restart the averages, and
   * hold the PLL and the adaptation until the new path has settled (a change
   * of k moves the SOGI output for a while) */
  fw_inj_set_extractor(&ctrl->inj, &ctrl->cfg.estimator, ex);
  fw_obs_hold(&ctrl->obs, FW_EST_SETTLE_S);
  return FW_OK;
}

void fw_raise_fault(fw_ctrl_t *ctrl, fw_fault_t code) {
  if (ctrl != NULL) {
    latch_fault(ctrl, code);
  }
}

fw_fault_t fw_fault_code(const fw_ctrl_t *ctrl) { return fw_fault_latch_code(&ctrl->fault); }

uint32_t fw_fault_history(const fw_ctrl_t *ctrl, uint16_t *codes, uint32_t n) {
  return fw_fault_latch_history(&ctrl->fault, codes, n);
}

size_t fw_ctrl_sizeof(void) { return sizeof(fw_ctrl_t); }

/* ---- start-up transitions ----------------------------------------------- */

/** Enter a start-up phase (or closed loop, FW_START_RUN): its time starts. */
static void enter_phase(fw_ctrl_t *c, fw_start_phase_t phase) {
  c->phase = phase;
  c->phase_time_s = 0.0f;
}

/**
 * One polarity-test sample (fw_start_polarity: the test and its decision on the
 * estimate); on the decision the drive goes to closed loop with clean filters.
 * Returns the d^ voltage to apply.
 */
static float polarity_step(fw_ctrl_t *c, float i_d) {
  float v;
  const fw_pol_result_t res =
      fw_start_polarity(&c->start, &c->cfg.estimator, &c->obs, i_d, &v, &c->polarity_flipped);
  c->snap.pol_dI_pos_A = c->start.pol_sum_pos;
  c->snap.pol_dI_neg_A = c->start.pol_sum_neg;
  if (res == FW_POL_BUSY) {
    return v;
  }
  if (res == FW_POL_UNDETERMINED) {
    latch_fault(c, FW_FAULT_POLARITY_UNDETERMINED);
    return 0.0f;
  }
  /* hand over to closed loop with clean filters */
  const float th = c->obs.pll.theta_rad;
  reset_dynamics(c);
  fw_obs_set(&c->obs, th, 0.0f);
  enter_phase(c, FW_START_RUN);
  return 0.0f;
}

/**
 * Motion at enable: catch the mover with the back-EMF observer when its
 * back-EMF is large enough to be tracked (flying start: fw_start_fly_catch_begin
 * sets what this period's loops read), else refuse. The rest of the catch in
 * the supervision half (supervise_deferred: fw_start_fly_catch_finish).
 * Returns FW_FAULT_NONE when caught.
 */
static fw_fault_t fly_catch(fw_ctrl_t *c) {
  const fw_fault_t f =
      fw_start_fly_catch_begin(&c->start, &c->cfg, c->bemf.w_on, &c->obs, &c->foc);
  if (f != FW_FAULT_NONE) {
    return f; /* too slow for the back-EMF, too fast for injection */
  }
  enter_phase(c, FW_START_RUN);
  c->sup.caught = 1u;
  return FW_FAULT_NONE;
}

/** The rest of a flying start (fly_catch), in the supervision half before its
 *  monitor update (fw_start_fly_catch_finish). */
static FW_NOINLINE void catch_rest(fw_ctrl_t *c) {
  c->sup.caught = 0u;
  fw_start_fly_catch_finish(&c->start, &c->obs, &c->bemf, &c->mon);
}

/** End of the standstill saliency check (fw_start_saliency_done: the judgement,
 *  and an estimate turned for another try): align again, latch its fault, or go
 *  on to the polarity test. */
static FW_NOINLINE void saliency_done(fw_ctrl_t *c) {
  bool again;
  const fw_fault_t f = fw_start_saliency_done(&c->start, &c->cfg, c->inj.n_inj, c->dt_s,
                                              &c->mon, &c->obs, &again);
  c->snap.sal_meas = c->mon.sal_meas;
  c->snap.L_small_meas_H = c->mon.L_small_meas_H;
  c->snap.L_large_meas_H = c->mon.L_large_meas_H;
  if (again) {
    enter_phase(c, FW_START_ALIGN);
  } else if (f != FW_FAULT_NONE) {
    latch_fault(c, f);
  } else {
    enter_phase(c, FW_START_POLARITY);
  }
}

/* ---- the step ----------------------------------------------------------- */

static void outputs_off(fw_outputs_t *out) {
  out->duty_abc[0] = out->duty_abc[1] = out->duty_abc[2] = 0.5f;
  out->pwm_enable = 0u;
}

/** The duties into the snapshot (stage_output copies them right after the
 *  modulation, while they are still in registers). */
static void snapshot_duties(fw_snapshot_t *snap, const fw_outputs_t *out) {
  snap->duty_abc[0] = out->duty_abc[0];
  snap->duty_abc[1] = out->duty_abc[1];
  snap->duty_abc[2] = out->duty_abc[2];
}

/** Signals of one period, passed between the stages of fw_step (each stage
 *  is called once and inlined). Only values: what a block fills through a
 *  pointer (inputs, monitor inputs, extraction results) lives in separate
 *  locals, so this one stays in registers. */
typedef struct {
  float i_abc[3];          /**< phase currents, checked and offset-compensated */
  float u_dc_V;            /**< DC link, checked */
  fw_vec2_f32_t i_ab;      /**< measured alpha/beta current */
  fw_vec2_f32_t i_f_ab;    /**< its fundamental (the extraction's; dead-time compensation) */
  bool braking;            /**< controlled braking after a fault */
  bool quick_stop;         /**< quick stop or fault braking */
  bool pulses;             /**< polarity pulses instead of injection and current loop */
  fw_sincos_f32_t sc;      /**< estimate at the sampling instant */
  fw_vec2_f32_t i_dq;      /**< fundamental current, estimated frame */
  float u_d_pulse;         /**< polarity pulse voltage */
  fw_vec2_f32_t i_ref;     /**< current references */
  fw_vec2_f32_t u_dq;      /**< fundamental voltage command */
  bool adapt;              /**< the adaptive SOGI's gain follows adapt_r (adapt_at_end) */
  float adapt_r;           /**< the observer's adaptation signal of this period */
} fw_period_t;

/** The adaptive SOGI's gain (fw_inj_adapt) after the step, on every path that
 *  ran the extraction: handed to the supervision half (supervise_deferred).
 *  Nothing in the step reads the gains after the SOGI steps of
 *  stage_estimate, and nothing else reads them before the next period's: the
 *  same gains in the same periods. The gain's recomputation (fw_inj_set_k, two
 *  divisions and two calls, about 110 cycles on the Cortex-M4F whenever k moves
 *  by more than FW_INJ_SOGI_K_STEP) was the alignment's and the injection
 *  regime's worst period; the test alone cost the control half about ten. */
static FW_ALWAYS_INLINE void adapt_at_end(fw_ctrl_t *c, const fw_period_t *p) {
  c->sup.adapt_r = p->adapt_r; /* 0 when not adapting (stage_estimate) */
  c->sup.adapt = (uint8_t)p->adapt;
}

/** What a period leaves to its supervision half because nothing before its duties
 *  needs it, each read first in the next period or on demand (fw_supervise runs
 *  it, also after a period with nothing staged; the control half runs it when it
 *  finds the last supervision missed): the observer's position (fw_obs_pos_flush),
 *  the rest of a flying start (catch_rest), the back-EMF angle error the PLL reads
 *  next period (fw_bemf_prepare), the adaptive SOGI's gain (adapt_at_end), the
 *  flying-start observer's rotation (fw_start_fly_flush). The same values, bit for
 *  bit, as when the control half formed them. */
static FW_ALWAYS_INLINE void supervise_deferred(fw_ctrl_t *c) {
  fw_obs_pos_flush(&c->obs);
  if (FW_UNLIKELY(c->sup.caught)) {
    catch_rest(c); /* after the position's last move, before the back-EMF's error */
  }
  fw_bemf_prepare(&c->bemf);
  if (FW_LIKELY(c->sup.adapt)) { /* the default extractor, every period */
    c->sup.adapt = 0u;
    fw_inj_adapt(&c->inj, &c->cfg.estimator, c->sup.adapt_r);
  }
  fw_start_fly_flush(&c->start);
}

/** The snapshot groups written (fw_step_into's result): w, and the
 *  extraction's when it ran (not during the polarity pulses). */
static unsigned snap_written_est(const fw_period_t *p, unsigned w) {
  return FW_UNLIKELY(p->pulses) ? w : w | FW_SNAP_W_EST;
}

/** Raw signals of this step into the snapshot; unit conversions, the
 *  statusword and the blocks' states (the estimator's angle, speeds, error and
 *  disturbance, the monitor's outputs, the injection scale and the back-EMF
 *  flags: only fw_step and the commands that restart the blocks change them)
 *  are read in fw_get_snapshot (off the hot path). */
static void fill_snapshot_common(const fw_ctrl_t *c, fw_snapshot_t *s) {
  /* (the period's signals went in after stage_inputs: snapshot_inputs) */
  s->cia402_state = (uint8_t)c->sm.state;
  s->start_phase = (uint8_t)c->phase;
  s->fault_code = (uint16_t)c->fault.code;
}

/** The sample's signals into the snapshot as soon as they are known (every
 *  path after stage_inputs writes the common group): stored at the end of the
 *  step they held three FP registers through it. */
static void snapshot_inputs(const fw_period_t *p, fw_snapshot_t *s) {
  s->i_ab_A[0] = p->i_ab.x;
  s->i_ab_A[1] = p->i_ab.y;
  s->u_dc_V = p->u_dc_V;
}

/** End of a period that does not reach stage_output: outputs off, in the snapshot
 *  too. */
static void end_off(const fw_ctrl_t *c, fw_outputs_t *out, fw_snapshot_t *snap) {
  outputs_off(out);
  snapshot_duties(snap, out);
  fill_snapshot_common(c, snap);
}

/** The last period's supervision did not run (fw_step_into finds it still due):
 *  what that period left to it, as it would have done it (its judgements stay
 *  undone: that is the fault), then FW_FAULT_SUPERVISION_MISSED. Out of line:
 *  the control half's usual path only tests for it. */
static FW_NOINLINE void supervision_missed(fw_ctrl_t *c) {
  c->sup.due = 0u;
  supervise_deferred(c);
  if (c->sup.saliency) {
    c->sup.saliency = 0u;
    saliency_done(c);
  }
  latch_fault(c, FW_FAULT_SUPERVISION_MISSED);
}

/** Input checks (fault on a bad sample; NaN never enters the state), offset
 *  compensation, Clarke. */
static void stage_inputs(fw_ctrl_t *c, float ia, float ib, float ic, float u_dc,
                         fw_period_t *p) {
  const fw_inputs_t in = {{ia, ib, ic}, u_dc};
  const fw_fault_t f =
      fw_fault_check_inputs(&c->cfg.protection, &in, fw_cia402_power_enabled(c->sm.state));
  /* in scalars, into the period's values at the end: they then stay in
   * registers (a struct copy is an LDM/STM pair through the stack, and a
   * memset, a compensation through a pointer or a struct whose address a
   * cold path takes keep them on the stack) */
  if (FW_UNLIKELY(f != FW_FAULT_NONE)) {
    latch_fault(c, f);
    if (f == FW_FAULT_INPUT_INVALID) {
      ia = ib = ic = u_dc = 0.0f; /* never propagate NaN into the state */
    }
  }
  c->u_dc_V = u_dc; /* for the statusword's warning bit */
  if (FW_LIKELY(c->phase != FW_START_IDLE)) {
    /* offsets learnt at standstill */
    ia = fw_mon_compensated(&c->mon, 0u, ia);
    ib = fw_mon_compensated(&c->mon, 1u, ib);
    ic = fw_mon_compensated(&c->mon, 2u, ic);
  }
  p->i_abc[0] = ia;
  p->i_abc[1] = ib;
  p->i_abc[2] = ic;
  p->u_dc_V = u_dc;
  p->i_ab = fw_clarke_f32(ia, ib, ic);
}

/** Fault reaction (brake under control first, or switch off now: latch_fault).
 *  Returns false when the power stage is off. */
static bool stage_power(fw_ctrl_t *c, fw_period_t *p) {
  p->braking = false;
  if (FW_UNLIKELY(c->sm.state == FW_CIA402_FAULT_REACTION_ACTIVE)) {
    if (!c->fault.hard && c->phase == FW_START_RUN) {
      p->braking = true;
    } else {
      fw_cia402_fault_reaction_done(&c->sm);
    }
  }
  const bool on = fw_cia402_power_enabled(c->sm.state) || p->braking;
  return FW_LIKELY(on && c->phase != FW_START_IDLE);
}

/** Boot (NOT READY TO SWITCH ON): the current zeros measured on the raw samples
 *  with the PWM off (fw_cal.h); when done, SWITCH ON DISABLED, or the fault of an
 *  implausible calibration. Stepped in physical units (no raw samples, adc NULL)
 *  there is nothing to calibrate: the nominal zero, SWITCH ON DISABLED at once. */
static FW_NOINLINE void boot_calibrate(fw_ctrl_t *c, const fw_adc_inputs_t *adc) {
  if (adc == NULL) {
    fw_cal_none(&c->cal);
  } else if (!fw_cal_sample(&c->cal, adc)) {
    return; /* still settling or sampling */
  }
  snap_slow_changed(c);
  const fw_fault_t f = fw_cal_judge(&c->cal, &c->cfg);
  if (f != FW_FAULT_NONE) {
    latch_fault(c, f); /* NOT READY -> FAULT REACTION ACTIVE -> FAULT (13, 14) */
  } else {
    fw_cia402_init_done(&c->sm); /* 1 */
  }
}

/** Power stage off: current-sensor offsets and sum, i2t cools down. */
static void stage_off(fw_ctrl_t *c, const fw_period_t *p, fw_snapshot_t *snap) {
  c->phase = FW_START_IDLE;
  const float i_abc[3] = {p->i_abc[0], p->i_abc[1], p->i_abc[2]};
  fw_mon_learn_offsets(&c->mon, i_abc);
  fw_protect_cool(&c->prot, &c->cfg);
  fw_mon_in_t mi;
  memset(&mi, 0, sizeof mi);
  mi.i_abc_A[0] = p->i_abc[0];
  mi.i_abc_A[1] = p->i_abc[1];
  mi.i_abc_A[2] = p->i_abc[2];
  const fw_fault_t mf = fw_mon_update(&c->mon, &mi); /* current sum with PWM off */
  if (mf != FW_FAULT_NONE) {
    latch_fault(c, mf);
  }
  fw_obs_set_iq(&c->obs, 0.0f);
  memset(snap->i_dq_A, 0, sizeof(snap->i_dq_A));
  memset(snap->u_dq_V, 0, sizeof(snap->u_dq_V));
  snap->u_inj_V = 0.0f;
}

/** Extraction and observer (not during the polarity pulses), Park of the
 *  fundamental, back-EMF observer in closed loop. */
static void stage_estimate(fw_ctrl_t *c, fw_inj_meas_t *hf, fw_period_t *p,
                           fw_snapshot_t *snap) {
  const fw_config_t *cfg = &c->cfg;
  /* theta_hat at the sampling instant: for the current Park and (advanced)
   * the output transform; the demodulation uses its own delayed frame */
  p->sc = fw_sincos_fast_f32(c->theta_k);
  hf->i_f_ab_A = p->i_ab;
  hf->e_raw_dq_A.x = hf->e_raw_dq_A.y = 0.0f; /* raw HF difference, for the monitor */
  hf->E_d_A = 0.0f;
  p->adapt = false;
  p->adapt_r = 0.0f; /* not read when !adapt */
  const float w_frame = c->obs.pll.w_hat_radps; /* theta_hat turned at this from k-1 to k */
  if (FW_LIKELY(!p->pulses)) {
    const fw_extractor_t ex = (fw_extractor_t)cfg->estimator.extractor;
    fw_inj_update(&c->inj, ex, p->i_ab, p->sc, c->obs.pll.theta_rad, c->obs.pll.w_i_radps,
                  hf);
    fw_obs_in_t oi;
    oi.E_d_A = hf->E_d_A;
    oi.E_q_A = hf->E_q_A;
    oi.hold = (uint8_t)(c->phase == FW_START_SALIENCY);
    oi.bemf_active = c->bemf.active;
    oi.bemf_err_rad = c->bemf.active ? fw_bemf_error(&c->bemf) : 0.0f;
    /* cross-saturation map and position ripple at theta_hat (0: off) */
    oi.ang_off_rad = fw_xsat_offset_at(&c->comp, p->sc);
    oi.settled =
        (uint8_t)FW_LIKELY(!(!fw_inj_settled(&c->inj) || c->phase_time_s < FW_EST_SETTLE_S));
    oi.running = (uint8_t)(c->phase == FW_START_RUN);
    oi.sc = p->sc; /* the thrust ripple's 6 theta_hat (read only when configured) */
    float adapt_r;
    /* the position follows in the supervision half (fw_obs_pos_flush) */
    const float eps = fw_obs_update_pll(&c->obs, &oi, &adapt_r);
    /* the default extractor: the gain follows adapt_r at the end of the step */
    p->adapt = FW_LIKELY(ex == FW_EXTRACTOR_SOGI_ADAPTIVE);
    p->adapt_r = adapt_r;
    snap->pll_err_rad = eps;
    snap->hf_amp_A = hf->E_d_A;
    snap->hf_q_A = hf->E_q_A;
    snap->i_h_ab_A[0] = hf->i_h_ab_A.x;
    snap->i_h_ab_A[1] = hf->i_h_ab_A.y;
  }
  p->i_f_ab = hf->i_f_ab_A;
  p->i_dq = fw_foc_measure(hf->i_f_ab_A, p->sc);
  if (FW_LIKELY(c->phase == FW_START_RUN && !p->pulses)) {
    const float i_dq_arr[2] = {p->i_dq.x, p->i_dq.y};
    fw_bemf_update(&c->bemf, fw_foc_u_applied(&c->foc), i_dq_arr, c->obs.pll.w_i_radps,
                   w_frame);
    fw_bemf_schedule(&c->bemf, c->obs.pll.w_i_radps, (uint8_t)fw_inj_settled(&c->inj));
  }
}

/** Start-up sequence (polarity pulses, flying start, end of the alignment,
 *  saliency check) and the estimator supervision. */
static void stage_startup(fw_ctrl_t *c, const fw_inj_meas_t *hf, fw_period_t *p) {
  const fw_config_t *cfg = &c->cfg;
  const uint32_t n_inj = c->inj.n_inj;
  p->u_d_pulse = 0.0f;
  if (p->pulses) {
    p->u_d_pulse = polarity_step(c, p->i_dq.x);
    if (c->phase == FW_START_RUN) {
      fw_mon_run_start(&c->mon);
    }
  } else if (FW_LIKELY(c->phase != FW_START_SALIENCY &&
                       c->phase_time_s >= FW_HF_SUPERVISION_DELAY_S &&
                       fw_inj_settled(&c->inj))) {
    const fw_fault_t ef =
        fw_obs_supervise(&c->obs, cfg, hf->E_d_A, c->bemf.inj_scale, c->phase == FW_START_RUN);
    if (FW_UNLIKELY(ef != FW_FAULT_NONE)) {
      latch_fault(c, ef);
    }
  }
  /* During the alignment the zero-current loop holds i = 0: the voltage it
   * needs is the back-EMF of a moving mover (judged once the loop and the
   * monitor's filter have settled, and again at the end). */
  if (FW_UNLIKELY(c->phase == FW_START_ALIGN)) {
    fw_start_fly_observe(&c->start, &cfg->machine, hf->i_f_ab_A, c->phase_time_s);
  }
  if (c->phase == FW_START_ALIGN && c->phase_time_s >= FW_MOTION_CHECK_S &&
      fw_mon_motion(&c->mon, c->e_start_max_V) != FW_FAULT_NONE) {
    const fw_fault_t ff = fly_catch(c); /* moving: catch it on the back-EMF, or refuse */
    if (FW_UNLIKELY(ff != FW_FAULT_NONE)) {
      latch_fault(c, ff);
    }
  }
  if (c->phase == FW_START_ALIGN &&
      fw_start_align_done(&cfg->estimator, c->phase_time_s, c->inj.inj_idx, n_inj) &&
      c->fault.code == FW_FAULT_NONE) {
    enter_phase(c, FW_START_SALIENCY); /* whole injection periods: ends on the same phase */
    fw_start_saliency_begin(&c->start);
  }
  if (c->phase == FW_START_SALIENCY) {
    fw_start_saliency_update(&c->start, n_inj, hf->e_raw_dq_A);
  }
}

/** Current references (speed loop or FORCE), quick stop and fault braking
 *  timing: the braking ends at standstill (in speed mode the filtered estimate
 *  below FW_QS_STILL_RADPS for FW_QS_STILL_TIME_S; in force mode the force is
 *  zero at once), or when the time brake_start allowed it is up (0x605E -1:
 *  fault_brake_time_s; the ramps: |speed| / deceleration + quick_stop_time_s).
 *  Returns false when the braking has ended (PWM off). */
static bool stage_references(fw_ctrl_t *c, fw_period_t *p) {
  const float dt = c->dt_s;
  p->i_ref.x = p->i_ref.y = 0.0f;
  if (FW_LIKELY(c->phase == FW_START_RUN)) {
    const float w_ref = p->quick_stop ? 0.0f : c->speed_ref_radps_e;
    p->i_ref.x = c->i_d_ref_A;
    if (c->mode == FW_MODE_SPEED) {
      p->i_ref.y = fw_foc_speed_update(&c->foc, w_ref, c->obs.omega_f);
    } else {
      p->i_ref.y = p->quick_stop ? 0.0f : c->i_q_ref_force_A;
    }
  }
  if (FW_UNLIKELY(p->quick_stop)) {
    c->qs_left_s -= dt;
    const bool still = c->mode == FW_MODE_FORCE || fabsf(c->obs.omega_f) < FW_QS_STILL_RADPS ||
                       c->phase != FW_START_RUN;
    c->qs_still_s = still ? c->qs_still_s + dt : 0.0f;
    if (c->qs_still_s >= FW_QS_STILL_TIME_S || c->qs_left_s <= 0.0f) {
      if (p->braking) {
        fw_cia402_fault_reaction_done(&c->sm); /* stopped: PWM off, FAULT */
      } else {
        fw_cia402_quick_stop_done(&c->sm);
      }
      c->phase = FW_START_IDLE;
      return false;
    }
  }
  return true;
}

/** The integrity monitor's inputs of this period, staged for fw_supervise
 *  (after the duties): what the rest of the step changes (the applied voltage,
 *  the injection sign, the start-up phase) is taken now. */
static void stage_supervision(fw_ctrl_t *c, const fw_inj_meas_t *hf, const fw_period_t *p) {
  const bool running = c->phase == FW_START_RUN;
  const float *u_applied = fw_foc_u_applied(&c->foc);
  fw_mon_in_t *const mi = &c->sup.mon;
  mi->i_abc_A[0] = p->i_abc[0]; /* after the offset compensation */
  mi->i_abc_A[1] = p->i_abc[1];
  mi->i_abc_A[2] = p->i_abc[2];
  /* the raw HF difference: fw_supervise scales it (the injection scale does
   * not change before it runs) */
  mi->e_hf_dq_A[0] = hf->e_raw_dq_A.x;
  mi->e_hf_dq_A[1] = hf->e_raw_dq_A.y;
  mi->u_dq_V[0] = u_applied[0];
  mi->u_dq_V[1] = u_applied[1];
  mi->i_dq_A[0] = p->i_dq.x;
  mi->i_dq_A[1] = p->i_dq.y;
  mi->i_dq_ref_A[0] = p->i_ref.x;
  mi->i_dq_ref_A[1] = p->i_ref.y;
  mi->omega_hat_radps = c->obs.pll.w_i_radps; /* saliency_done may restart the observer */
  mi->accel_dist_radps2 = c->obs.accel_dist;
  mi->running = (uint8_t)running;
  /* the phase's time first: false in the periods that enter closed loop (the
   * handover, a flying start), which then skip the rest */
  mi->hf_valid =
      (uint8_t)FW_LIKELY(running && c->phase_time_s >= FW_HF_SUPERVISION_DELAY_S && !p->pulses &&
                         fw_inj_settled(&c->inj) && fw_inj_sign_applied(&c->inj) != 0.0f &&
                         (c->bemf.inj_scale >= 1.0f || c->bemf.inj_scale <= c->bemf.inj_share));
  mi->pwm_on = 1u;
  c->sup.quick_stop = (uint8_t)p->quick_stop;
  c->sup.due = 1u;
}

/** Square-wave injection on the estimated d axis (on q^ in the second half of
 *  the saliency check) and the modulation. */
static void stage_output(fw_ctrl_t *c, const fw_period_t *p, float u_dc_V, fw_outputs_t *out,
                         fw_snapshot_t *snap) {
  const fw_config_t *cfg = &c->cfg;
  const float s = fw_inj_output(&c->inj, !p->pulses && cfg->estimator.u_inj_V > 0.0f);
  const bool inj_q =
      c->phase == FW_START_SALIENCY && fw_start_saliency_on_q(&c->start, c->inj.n_inj);
  const float u_inj = cfg->estimator.u_inj_V * c->bemf.inj_scale;
  const fw_vec2_f32_t u_dq = p->u_dq;
  const fw_vec2_f32_t u_cmd = {u_dq.x + (inj_q ? 0.0f : s * u_inj),
                               u_dq.y + (inj_q ? s * u_inj : 0.0f)};
  const fw_sincos_f32_t sc_out =
      fw_foc_output(u_cmd, p->sc, c->theta_k, c->obs.pll.w_hat_radps, c->dt_s, u_dc_V,
                    out->duty_abc);
  fw_xsat_deadtime(&c->comp, p->i_f_ab, u_dc_V, out->duty_abc); /* nothing when off */
  snapshot_duties(snap, out);
  if (c->phase == FW_START_ALIGN) { /* fundamental only, for the flying-start observer */
    fw_start_fly_set_u(&c->start, fw_inv_park_f32(u_dq, sc_out));
  }
  out->pwm_enable = 1u;

  fw_obs_set_iq(&c->obs, p->i_dq.y);
  fw_xsat_update(&c->comp, p->i_dq.y); /* the map's offset for the next period */
  fw_foc_commit_ref(&c->foc, p->i_ref.y);
  /* the current loop's snapshot fields (i_dq, references, u_dq, u_inj): written
   * by the supervision half (snapshot_loops), from the monitor's inputs staged
   * above and the blocks' states */
}

/** The snapshot fields of the current loop of a period that reached the modulation
 *  (its supervision was staged: fw_supervise): the fundamental current and its
 *  references as staged for the monitor, the voltage committed (fw_foc_commit),
 *  the injection's signed voltage (the sign fw_inj_output gave times u_inj_V times
 *  the injection scale): what stage_output used to store, the same values, read
 *  where nothing changes them before the supervision. */
static void snapshot_loops(const fw_ctrl_t *c, fw_snapshot_t *snap) {
  const fw_mon_in_t *const mi = &c->sup.mon;
  snap->i_dq_A[0] = mi->i_dq_A[0];
  snap->i_dq_A[1] = mi->i_dq_A[1];
  snap->i_dq_ref_A[0] = mi->i_dq_ref_A[0];
  snap->i_dq_ref_A[1] = mi->i_dq_ref_A[1];
  const float *const u_dq = fw_foc_u_applied(&c->foc); /* this period's, committed */
  snap->u_dq_V[0] = u_dq[0];
  snap->u_dq_V[1] = u_dq[1];
  const float u_inj = c->cfg.estimator.u_inj_V * c->bemf.inj_scale;
  snap->u_inj_V = c->inj.sign_hist[0] * u_inj;
}

/** The period's inputs from the ADC counts (the control interrupt's path, fw_app:
 *  the one conversion and range check). Its own function for the cycle accounting
 *  (benchmarks/pil.py: the interrupt's glue). */
static FW_ALWAYS_INLINE void inputs_from_adc(fw_ctrl_t *c, const fw_adc_inputs_t *adc, float *ia,
                                             float *ib, float *ic, float *u_dc) {
  fw_inputs_t x;
  if (!fw_adc_convert(&c->cfg, c->cal.zero_counts, adc, &x)) {
    latch_fault(c, FW_FAULT_ADC_RANGE);
  }
  *ia = x.i_abc_A[0];
  *ib = x.i_abc_A[1];
  *ic = x.i_abc_A[2];
  *u_dc = x.u_dc_V;
}

/** The period's inputs in physical units (fw_step; the replays of benchmarks/pil.py,
 *  which count them out of the control interrupt: its path is inputs_from_adc). */
static FW_ALWAYS_INLINE void inputs_of(const fw_inputs_t *in, float *ia, float *ib, float *ic,
                                       float *u_dc) {
  *ia = in->i_abc_A[0];
  *ib = in->i_abc_A[1];
  *ic = in->i_abc_A[2];
  *u_dc = in->u_dc_V;
}

unsigned fw_step_into(fw_ctrl_t *c, const fw_inputs_t *in, const fw_adc_inputs_t *adc,
                      fw_outputs_t *out, fw_snapshot_t *snap) {
  if (c == NULL || out == NULL || snap == NULL) {
    return 0u;
  }
  /* the inputs in scalars: the ADC's converted in registers, not through
     a struct on the stack */
  float ia = 0.0f, ib = 0.0f, ic = 0.0f, u_dc = 0.0f;
  if (adc != NULL) {
    inputs_from_adc(c, adc, &ia, &ib, &ic, &u_dc);
  } else if (in != NULL) {
    inputs_of(in, &ia, &ib, &ic, &u_dc);
  }
  /* outputs_off on every path that does not reach stage_output (which writes
   * every output): not stored twice in the usual period */
  c->step_count++;
  if (FW_UNLIKELY(c->sup.due)) { /* the last period's supervision did not run */
    supervision_missed(c);
  }
  if (adc == NULL && in == NULL) {
    outputs_off(out);
    latch_fault(c, FW_FAULT_INPUT_INVALID);
    return 0u;
  }
  snap->step_count = c->step_count; /* while it is in a register */
  const float theta_k = c->obs.pll.theta_rad; /* the estimate belonging to this sample */
  c->theta_k = theta_k;
  snap->theta_hat_rad = theta_k;
  fw_period_t p;
  stage_inputs(c, ia, ib, ic, u_dc, &p);
  snapshot_inputs(&p, snap);
  if (FW_UNLIKELY(!stage_power(c, &p))) {
    if (FW_UNLIKELY(c->sm.state == FW_CIA402_NOT_READY_TO_SWITCH_ON)) {
      boot_calibrate(c, adc);
    }
    stage_off(c, &p, snap);
    end_off(c, out, snap);
    return FW_SNAP_W_COMMON | FW_SNAP_W_OUT;
  }
  if (FW_UNLIKELY(c->phase != FW_START_RUN)) {
    /* start-up: its results and flags (polarity, saliency, flying start) may
     * change in any of its periods */
    snap_slow_changed(c);
  }
  c->phase_time_s += c->dt_s;
  p.quick_stop = c->sm.state == FW_CIA402_QUICK_STOP_ACTIVE || p.braking;
  p.pulses = c->phase == FW_START_POLARITY;

  fw_inj_meas_t hf;
  stage_estimate(c, &hf, &p, snap);
  stage_startup(c, &hf, &p);
  p.braking = p.braking && c->sm.state == FW_CIA402_FAULT_REACTION_ACTIVE;
  if (FW_UNLIKELY(!(fw_cia402_power_enabled(c->sm.state) || p.braking) || /* a fault, above */
                  !stage_references(c, &p))) { /* quick stop / braking done */
    end_off(c, out, snap);
    adapt_at_end(c, &p);
    return snap_written_est(&p, FW_SNAP_W_COMMON);
  }
  /* current loop in the estimated frame, or the polarity pulses */
  if (FW_UNLIKELY(p.pulses)) {
    p.u_dq.x = p.u_d_pulse;
    p.u_dq.y = 0.0f;
  } else {
    /* The decoupling feed-forward (w psi_f on q^, w L i) only in closed loop. In
     * start-up the PLL's speed is its convergence from an unknown angle (up to
     * 200 rad/s el. on a mover at rest), not a motion: fed forward as w psi_f it
     * is a phantom back-EMF of tens of volts that the current loop turns into
     * real thrust, and the motion check then refuses the mover it pushed. A
     * moving mover's back-EMF is held by the PI's integrator instead. */
    const float w_ff = FW_LIKELY(c->phase == FW_START_RUN) ? c->obs.omega_f : 0.0f;
    p.u_dq = fw_foc_current_update(&c->foc, p.i_ref, p.i_dq, w_ff, p.u_dc_V);
  }
  stage_supervision(c, &hf, &p); /* judged by fw_supervise, after the duties */
  fw_foc_commit(&c->foc, p.u_dq);
  stage_output(c, &p, p.u_dc_V, out, snap);
  if (c->phase == FW_START_SALIENCY && fw_start_saliency_advance(&c->start, c->inj.n_inj)) {
    /* the judgement (fw_mon_saliency: a square root, an atan2 and six divisions,
     * about 300 cycles on the Cortex-M4F) in the supervision half: its
     * decisions act from the next period on, a hard fault switches this
     * period's outputs off there */
    c->sup.saliency = 1u;
  }
  fill_snapshot_common(c, snap);
  adapt_at_end(c, &p);
  return snap_written_est(&p, FW_SNAP_W_COMMON | FW_SNAP_W_OUT | FW_SNAP_W_REF);
}

bool fw_supervise(fw_ctrl_t *c, fw_outputs_t *out, fw_snapshot_t *snap) {
  if (c == NULL || out == NULL || snap == NULL) {
    return false;
  }
  /* taken at once: a control half that preempts this one sees nothing due and
   * leaves what follows to it */
  const bool due = c->sup.due != 0u;
  c->sup.due = 0u;
  if (FW_LIKELY(due)) {
    snapshot_loops(c, snap); /* first: from the states the control half left */
  }
  /* the period's deferred work (also after a switch-off period, where nothing
   * is due: its values are the same whenever they are formed) */
  supervise_deferred(c);
  if (!due) {
    return false;
  }
  /* the standstill saliency check completed in this period: judged first, as
   * when the control half did it (the monitor's update below neither reads nor
   * changes what it decides; its fault latches after this one's) */
  bool judged = false;
  if (FW_UNLIKELY(c->sup.saliency)) {
    c->sup.saliency = 0u;
    saliency_done(c);
    judged = true;
  }
  fw_mon_in_t *const mi = &c->sup.mon;
  /* the HF witness judges the response per volt of injection: scale back (no
   * division while the injection is full, the usual case) */
  if (FW_UNLIKELY(c->bemf.inj_scale < 1.0f)) {
    const float inv_scale = 1.0f / c->bemf.inj_scale;
    mi->e_hf_dq_A[0] *= inv_scale;
    mi->e_hf_dq_A[1] *= inv_scale;
  }
  fw_fault_t mf = fw_mon_update(&c->mon, mi);
  if (FW_LIKELY(mf == FW_FAULT_NONE && mi->running)) {
    const fw_vec2_f32_t i_dq = {mi->i_dq_A[0], mi->i_dq_A[1]};
    mf = fw_protect_step(&c->prot, &c->cfg, &c->obs, i_dq, c->mode, c->speed_ref_radps_e,
                         c->i_q_ref_force_A, c->sup.quick_stop != 0u);
  }
  if (FW_LIKELY(mf == FW_FAULT_NONE && !judged)) {
    return false;
  }
  latch_fault(c, mf); /* nothing for FW_FAULT_NONE */
  if (c->fault.hard) {
    end_off(c, out, snap);
    return true;
  }
  /* braking faults go on braking; the judgement's phase change */
  fill_snapshot_common(c, snap);
  return false;
}

void fw_step(fw_ctrl_t *c, const fw_inputs_t *in, fw_outputs_t *out) {
  if (c != NULL) {
    (void)fw_step_into(c, in, NULL, out, &c->snap);
    (void)fw_supervise(c, out, &c->snap);
  }
}

void fw_step_adc(fw_ctrl_t *c, const fw_adc_inputs_t *in, fw_outputs_t *out) {
  if (c != NULL) {
    (void)fw_step_into(c, NULL, in, out, &c->snap);
    (void)fw_supervise(c, out, &c->snap);
  }
}

bool fw_adc_convert(const fw_config_t *cfg, const float zero_counts[3],
                    const fw_adc_inputs_t *adc, fw_inputs_t *in) {
  const uint32_t a = adc->i_abc_counts[0], b = adc->i_abc_counts[1], c = adc->i_abc_counts[2];
  const uint32_t u = adc->u_dc_counts;
  const float k = cfg->sensing.adc_A_per_count;
  in->i_abc_A[0] = ((float)a - zero_counts[0]) * k;
  in->i_abc_A[1] = ((float)b - zero_counts[1]) * k;
  in->i_abc_A[2] = ((float)c - zero_counts[2]) * k;
  in->u_dc_V = (float)u * cfg->sensing.adc_V_per_count;
  /* one range test: the largest of the four counts (no branch per count) */
  uint32_t m = a > b ? a : b;
  m = m > c ? m : c;
  m = m > u ? m : u;
  return m <= cfg->sensing.adc_max_count;
}

float fw_current_zero_counts(const fw_ctrl_t *ctrl, unsigned k) {
  return (ctrl != NULL && k < 3u) ? fw_cal_zero(&ctrl->cal, k) : 0.0f;
}

void fw_current_zero_external(fw_ctrl_t *ctrl) {
  if (ctrl != NULL && ctrl->sm.state == FW_CIA402_NOT_READY_TO_SWITCH_ON &&
      fw_cal_state(&ctrl->cal) == FW_CAL_RUNNING) {
    boot_calibrate(ctrl, NULL);
  }
}

fw_cal_state_t fw_current_zero_state(const fw_ctrl_t *ctrl) {
  return ctrl != NULL ? fw_cal_state(&ctrl->cal) : FW_CAL_RUNNING;
}
