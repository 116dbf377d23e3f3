/**
 * @file fw_obs.c
 * @brief HF/back-EMF angle error, PLL with mechanical extension, position,
 *        filtered speed, estimator supervision (see fw_obs.h).
 */
#include <math.h>

#include "pmlsm/fw_obs.h"
#include "pmlsm/fw_units.h"

/* Corner of the |PLL error| filter used for adaptation and supervision. */
#define FW_ERR_FILTER_HZ 5.0f

/* obs_mode 2 (docs/method.md section 5): corner of the innovation's short-window
 * mean, time constants of its variance and of the widening, the clip of one
 * sample's contribution to the variance (times the variance: a transient raises
 * it by at most 1 + (clip - 1) dt / FW_OBS_VAR_S per sample) and the speed over
 * which the Coulomb friction of the model changes sign. */
#define FW_OBS_INN_HZ 30.0f
#define FW_OBS_VAR_S 0.2f
#define FW_OBS_ATT_S 0.002f
#define FW_OBS_VAR_CLIP 4.0f
#define FW_OBS_W_FRIC_RADPS 2.0f
/* bemf_obs_bw: time constant of the widening after the switch to the back-EMF */
#define FW_OBS_BEMF_RAMP_S 0.01f

static float lp_alpha(float f_Hz, float dt_s) {
  return 1.0f - expf(-FW_TWO_PI_F32 * f_Hz * dt_s);
}

void fw_obs_pos_flush_turn(fw_obs_t *o) {
  fw_obs_pos_parts(o, &o->pos_turns, &o->pos_unwrapped_e);
  o->theta_prev = o->pll.theta_rad;
  o->pos_due = 0u;
  fw_obs_pll_gains(o);
}

/** A pending move of the estimate into the position before a function of this
 *  block moves the estimate or the position (the order of the sums is kept).
 *  These run at commands and start-up events, where none is usually pending
 *  (fw_supervise added it): the test inline, the move out of line. */
static FW_ALWAYS_INLINE void flush_first(fw_obs_t *o) {
  if (FW_UNLIKELY(o->pos_due)) {
    fw_obs_pos_flush_turn(o);
  }
}

/** Add d (|d| <= pi) to the unwrapped position, kept as whole electrical
 *  turns plus a remainder in [-pi, pi): a single float would lose the
 *  increments once the position is large (ulp 0.06 rad at 1e6 rad). Its
 *  callers flushed first (flush_first). */
static void pos_add(fw_obs_t *o, float d) {
  o->pos_unwrapped_e = fw_obs_pos_wrap(o->pos_unwrapped_e + d, &o->pos_turns);
}

void fw_obs_init(fw_obs_t *o, const fw_config_t *cfg, float dt_s) {
  o->dt_s = dt_s;
  o->spd_alpha = lp_alpha(cfg->loops.spd_filter_Hz, dt_s);
  o->err_alpha = lp_alpha(FW_ERR_FILTER_HZ, dt_s);
  /* reciprocals and products the step would otherwise divide for */
  o->eps_gain = cfg->machine.L_q_H / (cfg->machine.L_q_H - cfg->machine.L_d_H);
  /* > 0 (sogi_adapt_err_rad >= 0.001, checked; fabsf: never negative, so that
   * fw_obs_update's ratio needs no lower clamp) */
  o->inv_adapt_err = fabsf(1.0f / cfg->estimator.sogi_adapt_err_rad);
  o->hf_min_A = cfg->protection.hf_min_ratio * dt_s * cfg->estimator.u_inj_V / cfg->machine.L_q_H;
  /* the observer's gains and products, so the step reads nothing from cfg */
  o->bw_min = cfg->estimator.pll_bw_min;
  o->bw_span = 1.0f - cfg->estimator.pll_bw_min;
  o->kp0 = cfg->estimator.pll_kp;
  o->ki0 = cfg->estimator.pll_ki;
  o->ki0_dt = cfg->estimator.pll_ki * dt_s;
  o->kd_dt = dt_s * cfg->estimator.pll_kd;
  o->accel_per_A = cfg->estimator.pll_accel_per_A;
  o->mode = cfg->estimator.obs_mode;
  if (o->mode == (uint32_t)FW_OBS_FIXED) { /* lambda = 1 whatever the error */
    o->bw_min = 1.0f;
    o->bw_span = 0.0f;
  }
  o->lam_n = cfg->estimator.obs_bw_narrow;
  /* obs_mode 2's widening, capped where the widened poles (sum kp: for three equal
   * poles at -w, kp = 3 w) would pass the HF error's own limit (fw_units_obs_w_max):
   * beyond it the wide loop rang and lost the angle (realistic_linear, 2 kHz
   * injection, w = 229 rad/s: obs_bw_wide 2 asked for 458 rad/s against 314) */
  float lam_w = cfg->estimator.obs_bw_wide;
  const float kp_max = 3.0f * fw_units_obs_w_max(cfg);
  if (lam_w * cfg->estimator.pll_kp > kp_max) { /* pll_kp > 0 here (0: false) */
    lam_w = kp_max / cfg->estimator.pll_kp;
    lam_w = lam_w > o->lam_n ? lam_w : o->lam_n;
  }
  o->lam_span = lam_w - cfg->estimator.obs_bw_narrow;
  /* on the back-EMF error (obs_mode 0, 1): the scale times bemf_obs_bw, the poles (sum
   * kp) capped under the back-EMF filter's limit; 1 = as on injection (no cap: the drive
   * as before). obs_mode 2 sets its own bandwidth: its narrow loop doubled on the
   * back-EMF lost up to 0.45 rad at the handover back to injection under a load step
   * (iron_core_linear, 0.3 m/s, 120 N), against 0.09 without. */
  o->lam_bemf = o->mode == (uint32_t)FW_OBS_ADAPTIVE ? 1.0f : cfg->estimator.bemf_obs_bw;
  o->lam_bemf_max = 3.0f * fw_units_obs_w_max_bemf() / cfg->estimator.pll_kp; /* +inf at kp 0 */
  o->lam_b_alpha = lp_alpha(1.0f / (FW_TWO_PI_F32 * FW_OBS_BEMF_RAMP_S), dt_s);
  o->lam_b = 1.0f;
  o->det2 = cfg->estimator.obs_detect_sigma * cfg->estimator.obs_detect_sigma;
  o->inn_alpha = lp_alpha(FW_OBS_INN_HZ, dt_s);
  o->var_alpha = dt_s / FW_OBS_VAR_S;
  o->att_alpha = dt_s / FW_OBS_ATT_S;
  o->rel_alpha = dt_s / cfg->estimator.obs_release_s; /* obs_release_s >= 0.001 (checked) */
  /* el. rad per m (pole_pitch_m >= 0.001, mass_kg >= 0.001: checked) */
  const float k_e = FW_PI_F32 / cfg->machine.pole_pitch_m;
  o->fric_c = k_e * cfg->machine.coulomb_N / cfg->machine.mass_kg;
  o->fric_v = cfg->machine.visc_Ns_per_m / cfg->machine.mass_kg;
  /* the 6 theta thrust ripple (N, N/A) as el. acceleration: k_e / mass */
  const fw_cfg_compensation_t *cp = &cfg->compensation;
  const float k_acc = k_e / cfg->machine.mass_kg;
  o->rip6_k[0] = k_acc * cp->rip6_a0_N;
  o->rip6_k[1] = k_acc * cp->rip6_b0_N;
  o->rip6_k[2] = k_acc * cp->rip6_a1_N_per_A;
  o->rip6_k[3] = k_acc * cp->rip6_b1_N_per_A;
  o->rip6_on = (uint8_t)(cp->rip6_a0_N != 0.0f || cp->rip6_b0_N != 0.0f ||
                         cp->rip6_a1_N_per_A != 0.0f || cp->rip6_b1_N_per_A != 0.0f);
  o->inv_w_fric = 1.0f / FW_OBS_W_FRIC_RADPS;
}

/** obs_mode 2: the statistics restart (wide, variance unknown). */
static void adapt_reset(fw_obs_t *o) {
  o->inn_m = 0.0f;
  o->inn_var = FW_OBS_INN_VAR0;
  o->beta = 1.0f;
}

void fw_obs_reset(fw_obs_t *o, const fw_config_t *cfg) {
  flush_first(o); /* the move of the estimate it restarts */
  fw_pll_init_f32(&o->pll, cfg->estimator.pll_kp, cfg->estimator.pll_ki,
                  cfg->loops.speed_max_radps_e);
  o->err_f = 0.0f;
  o->accel_dist = 0.0f;
  o->est_hold_s = 0.0f;
  o->pll_err_time_s = 0.0f;
  o->omega_f = 0.0f;
  o->theta_prev = o->pll.theta_rad;
  adapt_reset(o);
  o->bemf_prev = 0u;
  o->lam_b = 1.0f;
}

void fw_obs_keep_position(fw_obs_t *o) {
  flush_first(o);
  pos_add(o, -o->pll.theta_rad); /* the estimate restarts from 0: keep the position */
}

void fw_obs_set(fw_obs_t *o, float theta_rad, float w_radps) {
  flush_first(o);
  fw_pll_reset_f32(&o->pll, theta_rad, w_radps);
  o->theta_prev = theta_rad;
}

void fw_obs_catch(fw_obs_t *o, float theta_rad, float w0_radps) {
  fw_obs_catch_speed(o, w0_radps);
  fw_obs_catch_angle(o, theta_rad);
}

void fw_obs_catch_speed(fw_obs_t *o, float w0_radps) {
  fw_pll_set_speed_f32(&o->pll, w0_radps);
  o->omega_f = w0_radps;
  o->accel_dist = 0.0f;
  adapt_reset(o);
}

void fw_obs_catch_angle(fw_obs_t *o, float theta_rad) {
  flush_first(o); /* the last move, from the angle before */
  fw_pll_set_angle_f32(&o->pll, theta_rad);
  o->theta_prev = theta_rad; /* as fw_obs_set */
}

void fw_obs_flip(fw_obs_t *o) {
  flush_first(o);
  fw_pll_reset_f32(&o->pll, o->pll.theta_rad + FW_PI_F32, 0.0f);
  o->theta_prev = o->pll.theta_rad;
  pos_add(o, FW_PI_F32);
}

void fw_obs_rotate(fw_obs_t *o, float d_rad) {
  flush_first(o);
  fw_pll_reset_f32(&o->pll, fw_wrap_pi_f32(o->pll.theta_rad + d_rad), 0.0f);
  o->theta_prev = o->pll.theta_rad;
  pos_add(o, d_rad);
  o->err_f = 0.0f;
  o->accel_dist = 0.0f;
  adapt_reset(o);
}

void fw_obs_hold(fw_obs_t *o, float t_s) { o->est_hold_s = t_s; }

/** obs_mode 2: the bandwidth scale of this sample from the innovation test
 *  (docs/method.md section 5). The short-window mean of the innovation eps
 *  against its own measured standard deviation: beyond obs_detect_sigma the
 *  scale goes to obs_bw_wide within FW_OBS_ATT_S, quiet it returns to
 *  obs_bw_narrow with obs_release_s. Outside the closed loop the configured
 *  gains (scale 1) and the test restarts wide; a change of the error source
 *  (HF <-> back-EMF) restarts it wide too. */
static FW_ALWAYS_INLINE float adapt_lambda(fw_obs_t *o, const fw_obs_in_t *in, float eps) {
  if (FW_UNLIKELY(!in->running || !in->settled || in->hold ||
                  in->bemf_active != o->bemf_prev || !(eps - eps == 0.0f))) {
    o->bemf_prev = in->bemf_active;
    o->beta = 1.0f;
    return in->running ? o->lam_n + o->lam_span : 1.0f;
  }
  const float m = o->inn_m + o->inn_alpha * (eps - o->inn_m);
  o->inn_m = m;
  const float m2 = m * m;
  const float v = o->inn_var;
  const float clip = FW_OBS_VAR_CLIP * v;
  o->inn_var = v + o->var_alpha * ((m2 < clip ? m2 : clip) - v);
  float beta = o->beta;
  if (m2 > o->det2 * v) {
    beta += o->att_alpha * (1.0f - beta);
  } else {
    beta -= o->rel_alpha * beta;
  }
  o->beta = beta;
  return o->lam_n + o->lam_span * beta;
}

float fw_obs_update_pll(fw_obs_t *o, const fw_obs_in_t *in, float *adapt_r) {
  /* the last move is added (fw_obs_pos_flush): theta_prev is the estimate it
   * starts from */
  const float dt = o->dt_s;
  float eps = 0.0f;
  const float floor_A = 1e-6f;
  const bool switched = o->est_hold_s > 0.0f; /* extractor just switched: no HF error */
  if (FW_UNLIKELY(switched)) {
    o->est_hold_s -= dt;
  }
  if (FW_UNLIKELY(in->hold)) {
    eps = 0.0f; /* injection moves to q^ during the saliency check: hold the estimate */
  } else if (in->bemf_active) {
    eps = in->bemf_err_rad; /* above injection speeds (the HF error is not formed) */
  } else if (FW_LIKELY(!switched && in->E_d_A > floor_A)) {
    eps = (in->E_q_A / in->E_d_A) * o->eps_gain - in->ang_off_rad;
    eps = fw_clamp_symf(eps, 1.0f);
  }
  /* Low-passed *signed* error: its magnitude is the tracking error. The
   * per-sample eps carries ~0.04 rad of sensor noise, so a filtered |eps|
   * would measure the noise, not the lock. */
  o->err_f += o->err_alpha * (eps - o->err_f);
  /* fw_clampf(x, 0, 1) for an x that is >= 0 or NaN (inv_adapt_err >= 0) */
  const float r_raw = fabsf(o->err_f) * o->inv_adapt_err;
  const float r = FW_UNLIKELY(r_raw > 1.0f) ? 1.0f : r_raw;
  *adapt_r = r;

  if (!in->settled) {
    eps = 0.0f; /* filters still settling: extrapolate, do not correct */
  }
  /* Bandwidth scheduling: all observer poles scaled by lambda in [bw_min, 1],
   * lambda rising with the tracking error (same observable as the SOGI); fixed
   * gains: bw_min = 1, bw_span = 0. The PLL step (fw_pll_step_f32) inline, with
   * ki dt precomputed. */
  float lam = o->bw_min + o->bw_span * r;
  const bool adaptive = o->mode == (uint32_t)FW_OBS_ADAPTIVE;
  if (adaptive) {
    lam = adapt_lambda(o, in, eps);
  }
  if (FW_UNLIKELY(o->lam_bemf != 1.0f)) { /* the back-EMF: a wider loop (bemf_obs_bw) */
    /* in over FW_OBS_BEMF_RAMP_S after the switch to the back-EMF (no step of the
     * gains with the change of error source), out at once on the way back (the HF
     * error's own limit) */
    o->lam_b = in->bemf_active ? o->lam_b + o->lam_b_alpha * (o->lam_bemf - o->lam_b) : 1.0f;
    const float lb = lam * o->lam_b;
    const float cap = o->lam_bemf_max > lam ? o->lam_bemf_max : lam; /* never below lam */
    lam = lb < cap ? lb : cap;
  }
  const float lam2 = lam * lam;
  const float kp = o->kp0 * lam;
  o->lam = lam; /* pll.kp, pll.ki: set with the position (fw_obs_pll_gains) */
  fw_pll_f32_t *const pll = &o->pll;
  const float w_max = pll->w_max_radps;
  float w_i = pll->w_i_radps;
  if (FW_LIKELY(eps - eps == 0.0f)) { /* a non-finite error holds the PLL (as fw_pll_step_f32) */
    w_i = fw_clamp_symf(w_i + (o->ki0_dt * lam2) * eps, w_max);
    const float w_hat = w_i + kp * eps;
    pll->w_hat_radps = w_hat;
    pll->theta_rad = fw_wrap_pi_f32(pll->theta_rad + w_hat * dt);
  }
  /* Mechanical observer extension of the PLL: the speed state also
   * integrates the acceleration the measured thrust current predicts, plus
   * an estimated disturbance (load, friction) driven by the same error.
   * Error dynamics: e''' + kp e'' + ki e' + kd e = (disturbance changes).
   * The configured 6 theta thrust ripple (cogging, back-EMF harmonics) is in
   * the model when set (rip6_on), at the estimate of this sample. */
  float accel = 0.0f;
  if (in->running) {
    accel = o->accel_per_A * o->i_q_ff_A + o->accel_dist;
    if (FW_UNLIKELY(o->rip6_on)) {
      accel += fw_obs_rip6_accel(o, in->sc, o->i_q_ff_A);
    }
    if (adaptive) { /* the configured friction in the model: the disturbance is the rest */
      accel -= o->fric_v * w_i + o->fric_c * fw_clamp_symf(w_i * o->inv_w_fric, 1.0f);
    }
    w_i += dt * accel;
    w_i = fw_clamp_symf(w_i, w_max); /* w_max = speed_max_radps_e (checked > 0) */
    o->accel_dist += o->kd_dt * lam * lam * lam * eps;
  }
  pll->w_i_radps = w_i;
  o->pos_due = 1u; /* the position follows in fw_obs_pos_flush */
  if (adaptive) {
    /* the speed for the loops: low-passed, but the acceleration the model knows
     * passes without the filter's lag */
    o->omega_f += dt * accel;
  }
  o->omega_f += o->spd_alpha * (w_i - o->omega_f);
  return eps;
}

float fw_obs_update(fw_obs_t *o, const fw_obs_in_t *in, float *adapt_r) {
  const float eps = fw_obs_update_pll(o, in, adapt_r);
  fw_obs_pos_flush(o);
  return eps;
}

fw_fault_t fw_obs_supervise(fw_obs_t *o, const fw_config_t *cfg, float hf_amp_A,
                            float inj_scale, bool running) {
  if (cfg->estimator.u_inj_V > 0.0f && hf_amp_A < o->hf_min_A * inj_scale) {
    return FW_FAULT_EST_HF_LOW;
  }
  if (FW_LIKELY(running)) { /* closed loop */
    if (FW_UNLIKELY(fabsf(o->err_f) > cfg->protection.pll_err_max_rad)) {
      o->pll_err_time_s += o->dt_s;
      if (o->pll_err_time_s > cfg->protection.pll_err_time_s) {
        return FW_FAULT_EST_PLL_ERROR;
      }
    } else {
      o->pll_err_time_s = 0.0f;
    }
  }
  return FW_FAULT_NONE;
}
