/**
 * @file fw_fault.c
 * @brief Fault latch, history and protections (see fw_fault.h).
 */
#include <math.h>
#include <string.h>

#include "pmlsm/fw_fault.h"

void fw_fault_latch_init(fw_fault_latch_t *f) { memset(f, 0, sizeof(*f)); }

bool fw_fault_brakes_first(int32_t fault_reaction_option, fw_fault_t code) {
  if (fault_reaction_option == (int32_t)FW_REACT_SWITCH_OFF) {
    return false; /* 0x605E = 0: switch off for every fault */
  }
  /* faults that leave the estimate and the measurements trustworthy */
  return code == FW_FAULT_HEARTBEAT_LOST || code == FW_FAULT_POSITION_LIMIT ||
         code == FW_FAULT_I2T;
}

static void hist_push(fw_fault_latch_t *f, fw_fault_t code) {
  for (uint32_t i = FW_FAULT_HISTORY_LEN - 1u; i > 0u; i--) {
    f->hist[i] = f->hist[i - 1u];
  }
  f->hist[0] = (uint16_t)code;
  if (f->hist_count < FW_FAULT_HISTORY_LEN) {
    f->hist_count++;
  }
}

float fw_fault_brake_time_max_s(const fw_config_t *cfg, int32_t option, float speed_mps) {
  switch (option) {
  case (int32_t)FW_REACT_BRAKE_TIMED:
    return cfg->protection.fault_brake_time_s;
  case (int32_t)FW_REACT_RAMP:
  case (int32_t)FW_REACT_QUICK_RAMP: {
    /* K_F i_max / m > 0 for every accepted configuration (fw_config_check) */
    const float a_mps2 = fw_units_force_per_A(cfg) * cfg->loops.i_max_A / cfg->machine.mass_kg;
    const float t_stop = fabsf(speed_mps) / a_mps2;
    /* NaN (never from the core's estimate) counts as no time: the margin alone */
    return (t_stop >= 0.0f ? t_stop : 0.0f) + cfg->protection.quick_stop_time_s;
  }
  default:
    return 0.0f; /* FW_REACT_SWITCH_OFF */
  }
}

void fw_fault_latch_update(fw_fault_latch_t *f, fw_fault_t code, int32_t fault_reaction_option) {
  if (code == FW_FAULT_NONE) {
    return;
  }
  if (f->code == FW_FAULT_NONE) {
    f->code = code; /* the first cause is the one reported */
  }
  if (f->hist_count == 0u || f->hist[0] != (uint16_t)code) {
    hist_push(f, code); /* every new cause, once while it repeats */
  }
  if (!fw_fault_brakes_first(fault_reaction_option, code)) {
    f->hard = 1u;
  }
}

void fw_fault_latch_reset(fw_fault_latch_t *f) {
  f->code = FW_FAULT_NONE;
  f->hard = 0u;
}

fw_fault_t fw_fault_latch_code(const fw_fault_latch_t *f) { return f->code; }

uint32_t fw_fault_latch_history(const fw_fault_latch_t *f, uint16_t *codes, uint32_t n) {
  uint32_t m = f->hist_count < n ? f->hist_count : n;
  for (uint32_t i = 0; i < m; i++) {
    codes[i] = f->hist[i];
  }
  return m;
}

/* ---- linear-axis protections -------------------------------------------- */

void fw_protect_config(fw_protect_t *p, const fw_config_t *cfg, float dt_s) {
  p->dt_s = dt_s;
  /* the target is limited to v_max_mps (fw_set_speed_ref); the trip leaves room
     above it for the speed loop's overshoot and the estimate's ripple */
  p->w_trip_radps = fw_units_mps_to_radps_e(
      cfg, cfg->protection.v_max_mps * cfg->protection.overspeed_margin);
  p->w_follow_radps = fw_units_mps_to_radps_e(cfg, cfg->protection.follow_err_mps);
  /* the step's products of configuration values, once */
  p->ir2_A2 = cfg->protection.i_rated_A * cfg->protection.i_rated_A;
  p->i2t_max_A2s =
      (cfg->loops.i_max_A * cfg->loops.i_max_A - p->ir2_A2) * cfg->protection.i2t_time_s;
  p->i2t_on = (uint8_t)(cfg->protection.i_rated_A < cfg->loops.i_max_A);
  p->pos_on = (uint8_t)(cfg->protection.pos_limit_min_m < cfg->protection.pos_limit_max_m);
}

void fw_protect_init(fw_protect_t *p, const fw_config_t *cfg, float dt_s) {
  p->i2t_A2s = 0.0f;
  p->follow_time_s = 0.0f;
  fw_protect_config(p, cfg, dt_s);
}

void fw_protect_reset(fw_protect_t *p) { p->follow_time_s = 0.0f; }

void fw_protect_cool(fw_protect_t *p, const fw_config_t *cfg) {
  p->i2t_A2s -= cfg->protection.i_rated_A * cfg->protection.i_rated_A * p->dt_s;
  p->i2t_A2s = p->i2t_A2s > 0.0f ? p->i2t_A2s : 0.0f;
}

fw_fault_t fw_protect_update(fw_protect_t *p, const fw_config_t *cfg, const fw_protect_in_t *in) {
  const float dt = p->dt_s;
  float i2t = p->i2t_A2s +
              (in->i_dq_A[0] * in->i_dq_A[0] + in->i_dq_A[1] * in->i_dq_A[1] - p->ir2_A2) * dt;
  i2t = i2t > 0.0f ? i2t : 0.0f;
  p->i2t_A2s = i2t;
  if (p->i2t_on && i2t > p->i2t_max_A2s) {
    return FW_FAULT_I2T;
  }
  if (FW_UNLIKELY(fabsf(in->omega_hat_radps) > p->w_trip_radps)) {
    return FW_FAULT_OVERSPEED;
  }
  if (FW_UNLIKELY(p->pos_on)) { /* software limits: off by default */
    const float x = in->pos_m;
    if ((x > cfg->protection.pos_limit_max_m && !(in->cmd < 0.0f)) ||
        (x < cfg->protection.pos_limit_min_m && !(in->cmd > 0.0f))) {
      return FW_FAULT_POSITION_LIMIT;
    }
  }
  bool follow = in->speed_mode && !in->quick_stop &&
                fabsf(in->speed_ref_radps_e - in->omega_f_radps) > p->w_follow_radps;
  p->follow_time_s = follow ? p->follow_time_s + dt : 0.0f;
  if (FW_UNLIKELY(p->follow_time_s > cfg->protection.follow_err_time_s)) {
    return FW_FAULT_FOLLOWING_ERROR;
  }
  return FW_FAULT_NONE;
}

fw_fault_t fw_protect_step(fw_protect_t *p, const fw_config_t *cfg, const fw_obs_t *obs,
                           fw_vec2_f32_t i_dq, fw_mode_t mode, float speed_ref_radps_e,
                           float i_q_ref_force_A, bool quick_stop) {
  fw_protect_in_t pi;
  pi.i_dq_A[0] = i_dq.x;
  pi.i_dq_A[1] = i_dq.y;
  pi.omega_hat_radps = obs->pll.w_i_radps;
  pi.omega_f_radps = obs->omega_f;
  /* the position (a division) only when the limits are on */
  const bool pos_on = FW_UNLIKELY(p->pos_on); /* off by default */
  pi.pos_m = pos_on ? fw_units_rad_e_to_m(cfg, fw_obs_pos_e_of(obs->pos_turns,
                                                               obs->pos_unwrapped_e))
                    : 0.0f;
  /* the command's sign matters only to the position limits (fw_protect_update
   * reads it nowhere else): not selected per mode on the usual period */
  pi.cmd = pos_on ? (mode == FW_MODE_SPEED ? speed_ref_radps_e : i_q_ref_force_A) : 0.0f;
  pi.speed_ref_radps_e = speed_ref_radps_e;
  pi.speed_mode = (uint8_t)(mode == FW_MODE_SPEED);
  pi.quick_stop = (uint8_t)quick_stop;
  return fw_protect_update(p, cfg, &pi);
}
