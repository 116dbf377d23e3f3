/**
 * @file fw_fault.h
 * @brief Fault block: the latch (first cause, hard/braking reaction, history)
 *        and the protections on the sampled inputs and on the estimate
 *        (overcurrent, DC link, i2t, overspeed, software position limits,
 *        speed following error).
 *
 * The codes themselves (fw_fault_t) are generated into fw_faults.h. The CiA 402
 * consequences of a latched fault (FAULT REACTION ACTIVE, braking, PWM off)
 * are the drive state machine's (fw_ctrl.c); this block only decides and
 * remembers.
 *
 * Needs the bottom layer (fw_types.h, fw_units.h) and, for the protections'
 * inputs, the observer (fw_obs.h).
 */
#ifndef PMLSM_FW_FAULT_H
#define PMLSM_FW_FAULT_H

#include <math.h>
#include <stdbool.h>
#include <stdint.h>

#include "fw_obs.h"
#include "fw_types.h"
#include "fw_units.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Fault latch and history (caller-owned). */
typedef struct {
  fw_fault_t code;     /**< latched first cause, FW_FAULT_NONE if none */
  uint8_t hard;        /**< a latched fault needs the power stage off at once */
  uint16_t hist[FW_FAULT_HISTORY_LEN]; /**< newest first (depth: fw_types.h) */
  uint32_t hist_count;
} fw_fault_latch_t;

/** Empty latch, empty history. */
void fw_fault_latch_init(fw_fault_latch_t *f);
/**
 * Latch a cause: the first one is the one reported, every new cause enters
 * the history (once while it repeats), a cause that does not brake first
 * (fw_fault_brakes_first) makes the latch hard. FW_FAULT_NONE is ignored.
 */
void fw_fault_latch_update(fw_fault_latch_t *f, fw_fault_t code, int32_t fault_reaction_option);
/** Fault reset: cause and hard flag cleared, history kept. */
void fw_fault_latch_reset(fw_fault_latch_t *f);
/** Latched cause (FW_FAULT_NONE if none). */
fw_fault_t fw_fault_latch_code(const fw_fault_latch_t *f);
/** History, newest first, into codes[0..n); returns the number written. */
uint32_t fw_fault_latch_history(const fw_fault_latch_t *f, uint16_t *codes, uint32_t n);

/**
 * Fault reaction (CiA 402 0x605E): true when the drive may brake under
 * control before switching off. Only faults that leave the estimate and the
 * measurements trustworthy do (heartbeat lost, position limit, i2t); with
 * option FW_REACT_SWITCH_OFF none does.
 */
bool fw_fault_brakes_first(int32_t fault_reaction_option, fw_fault_t code);

/**
 * Longest braking of a reaction (fw_reaction_t `option`: 0x605A quick stop,
 * 0x605E fault reaction) that starts at |speed_mps|, s; the drive switches the
 * PWM off at standstill or at this bound, whichever comes first:
 *   FW_REACT_BRAKE_TIMED      fault_brake_time_s, whatever the speed (the mover
 *                             coasts from the speed it has then);
 *   FW_REACT_RAMP, QUICK_RAMP |speed| / a + quick_stop_time_s, a = K_F i_max_A /
 *                             mass_kg the deceleration the current limit gives
 *                             the configured mass (friction, which helps, aside):
 *                             the ramp reaches standstill inside it unless the
 *                             mass or the thrust is misconfigured, and never
 *                             brakes forever;
 *   FW_REACT_SWITCH_OFF, other 0 (PWM off at once).
 */
float fw_fault_brake_time_max_s(const fw_config_t *cfg, int32_t option, float speed_mps);

/**
 * Checks on one period's sampled inputs: NaN/inf, overcurrent on any phase,
 * DC-link overvoltage, and undervoltage while the power stage is enabled.
 */
static inline fw_fault_t fw_fault_check_inputs(const fw_cfg_protection_t *prot,
                                               const fw_inputs_t *in, bool power_enabled) {
  /* usual case first: every sample inside its limits (each comparison is
   * false for NaN, and for inf against the finite limits) */
  const float u_max = prot->u_dc_max_V; /* read once (it was loaded twice) */
  const float u_min = power_enabled ? prot->u_dc_min_V : -u_max;
  if (FW_LIKELY(fabsf(in->i_abc_A[0]) <= prot->i_trip_A && fabsf(in->i_abc_A[1]) <= prot->i_trip_A &&
                fabsf(in->i_abc_A[2]) <= prot->i_trip_A && in->u_dc_V <= u_max &&
                in->u_dc_V >= u_min)) {
    return FW_FAULT_NONE;
  }
  for (int i = 0; i < 3; i++) {
    if (!fw_isfinite_f32(in->i_abc_A[i])) {
      return FW_FAULT_INPUT_INVALID;
    }
  }
  if (!fw_isfinite_f32(in->u_dc_V)) {
    return FW_FAULT_INPUT_INVALID;
  }
  for (int i = 0; i < 3; i++) {
    if (fabsf(in->i_abc_A[i]) > prot->i_trip_A) {
      return FW_FAULT_OVERCURRENT;
    }
  }
  if (in->u_dc_V > prot->u_dc_max_V) {
    return FW_FAULT_DC_OVERVOLTAGE;
  }
  if (power_enabled && in->u_dc_V < prot->u_dc_min_V) {
    return FW_FAULT_DC_UNDERVOLTAGE;
  }
  return FW_FAULT_NONE;
}

/** Linear-axis protections on the estimate (caller-owned). */
typedef struct {
  float i2t_A2s;         /**< integral of i^2 above i_rated_A^2 */
  float follow_time_s;   /**< time outside the following-error window */
  float w_trip_radps;    /**< OVERSPEED above: v_max_mps x overspeed_margin, electrical rad/s */
  float w_follow_radps;  /**< follow_err_mps in electrical rad/s */
  float dt_s;
  float ir2_A2;          /**< i_rated_A^2 */
  float i2t_max_A2s;     /**< (i_max_A^2 - i_rated_A^2) i2t_time_s */
  uint8_t i2t_on;        /**< i_rated_A < i_max_A */
  uint8_t pos_on;        /**< pos_limit_min_m < pos_limit_max_m */
} fw_protect_t;

/** Inputs of one closed-loop period. */
typedef struct {
  float i_dq_A[2];          /**< fundamental current */
  float omega_hat_radps;    /**< observer speed (overspeed) */
  float omega_f_radps;      /**< filtered speed (following error) */
  float pos_m;              /**< estimated position; read only when the limits are on */
  float cmd;                /**< command whose sign says where the axis is driven:
                                 speed reference (SPEED) or i_q reference (FORCE) */
  float speed_ref_radps_e;  /**< speed reference (following error) */
  uint8_t speed_mode;       /**< 1: SPEED mode (following error supervised) */
  uint8_t quick_stop;       /**< 1: braking: no following-error supervision */
} fw_protect_in_t;

/** Thresholds from the configuration; i2t and following-error state cleared. */
void fw_protect_init(fw_protect_t *p, const fw_config_t *cfg, float dt_s);
/** New configuration: thresholds only (the i2t state, i.e. the heat, is kept). */
void fw_protect_config(fw_protect_t *p, const fw_config_t *cfg, float dt_s);
/** Closed loop (re)starts: following-error timer cleared (i2t kept). */
void fw_protect_reset(fw_protect_t *p);
/** Power stage off: i2t cools down at the rated current. */
void fw_protect_cool(fw_protect_t *p, const fw_config_t *cfg);
/**
 * One closed-loop period: i2t, overspeed, software position limits (a limit
 * trips only while the command points further out, so that the axis can be
 * driven back after a fault reset) and the speed following error, in this
 * order; returns the first fault found.
 */
fw_fault_t fw_protect_update(fw_protect_t *p, const fw_config_t *cfg, const fw_protect_in_t *in);
/**
 * fw_protect_update on a closed-loop period of the drive: its inputs from the
 * observer (its speed and filtered speed; its position, a division, only when
 * the position limits are on: pos_on), the fundamental current i_dq, the mode
 * and its references (the command's sign matters only to the position limits:
 * the speed reference in SPEED mode, the i_q reference in FORCE mode), and
 * whether the drive brakes (quick_stop). The observer's position must be
 * flushed (fw_obs_pos_flush: its parts are read as they are).
 */
fw_fault_t fw_protect_step(fw_protect_t *p, const fw_config_t *cfg, const fw_obs_t *obs,
                           fw_vec2_f32_t i_dq, fw_mode_t mode, float speed_ref_radps_e,
                           float i_q_ref_force_A, bool quick_stop);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_FAULT_H */
