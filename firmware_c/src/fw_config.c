/**
 * @file fw_config.c
 * @brief Default configuration, the configuration field table (names,
 *        units, ranges) and its validation, including the saliency check.
 */
#include <math.h>
#include <stddef.h>
#include <string.h>

#include "pmlsm/fw_config.h"
#include "pmlsm/fw_sogi.h"
#include "pmlsm/fw_units.h"

/* The table itself is generated from protocols/od.yaml (fw_config:), the one
 * source of the ranges (engineering limits for this drive class, not tuning
 * advice) and of the defaults (last argument), which fw_config_default() below
 * applies. */
#define F32(part, name, unit, lo, hi, dflt) \
  {#name, unit, offsetof(fw_config_t, part.name), 0u, 0u, lo, hi},
#define U32(part, name, unit, lo, hi, dflt) \
  {#name, unit, offsetof(fw_config_t, part.name), 1u, 0u, lo, hi},
#define I32(part, name, unit, lo, hi, dflt) \
  {#name, unit, offsetof(fw_config_t, part.name), 1u, 1u, lo, hi},
static const fw_config_field_t k_fields[] = {FW_CONFIG_FIELDS(F32, U32, I32)};
#undef F32
#undef U32
#undef I32

/* Observer design point of fw_config_derive (docs/tuning.md): a load step of this
 * fraction of the peak thrust K_F i_max leaves at most this angle error. */
#define FW_PLL_DESIGN_LOAD 0.2f
#define FW_PLL_DESIGN_ERR_RAD 0.05f
#define FW_PLL_W_MIN 30.0f /* rad/s: about the paper's observer (kp 86.6 = 3 x 29) */

#define K_NFIELDS (sizeof(k_fields) / sizeof(k_fields[0]))

void fw_config_default(fw_config_t *cfg) {
  if (cfg == NULL) {
    return;
  }
  memset(cfg, 0, sizeof(*cfg));
  /* every default is od.yaml's (fw_config: default:, with the reasons in each
     field's doc): the paper's motor and loops, this drive class's protections */
#define F32(part, name, unit, lo, hi, dflt) cfg->part.name = (dflt);
#define U32(part, name, unit, lo, hi, dflt) cfg->part.name = (dflt);
#define I32(part, name, unit, lo, hi, dflt) cfg->part.name = (dflt);
  FW_CONFIG_FIELDS(F32, U32, I32)
#undef F32
#undef U32
#undef I32
  fw_config_derive(cfg); /* the back-EMF levels of the speeds above */
}

void fw_config_derive(fw_config_t *cfg) {
  if (cfg == NULL) {
    return;
  }
  /* Back-EMF levels of the handover and witness speeds: where the handover sits in
   * speed does not depend on psi_f (docs/bemf.md). A bad pole pitch or psi_f makes
   * them non-finite; the range check reports the bad field first. */
  cfg->estimator.bemf_e_on_V = fw_units_bemf_V(cfg, cfg->estimator.bemf_v_on_mps);
  cfg->estimator.bemf_e_off_V = fw_units_bemf_V(cfg, cfg->estimator.bemf_v_off_mps);
  cfg->protection.mon_bemf_min_V = fw_units_bemf_V(cfg, cfg->protection.mon_bemf_min_mps);
  if (cfg->loops.gains_auto == 0u || !(cfg->machine.pole_pitch_m > 0.0f) ||
      !(cfg->machine.mass_kg > 0.0f)) {
    return; /* explicit gains; the range check reports bad fields */
  }
  const float k_e = fw_units_mps_to_radps_e(cfg, 1.0f); /* el. rad per m */
  const float K_F = fw_units_force_per_A(cfg);     /* N per A of i_q */
  cfg->loops.cur_kp_V_per_A = cfg->machine.L_d_H * cfg->loops.cur_bw_radps;
  cfg->loops.cur_ki_V_per_As = cfg->machine.R_ohm * cfg->loops.cur_bw_radps;
  cfg->loops.spd_kp_A_per_radps = cfg->machine.mass_kg * cfg->loops.spd_bw_radps / K_F / k_e;
  cfg->loops.spd_ki_A_per_rad = cfg->loops.spd_kp_A_per_radps * cfg->loops.spd_bw_radps / 6.0f;
  cfg->estimator.pll_accel_per_A = k_e * K_F / cfg->machine.mass_kg;
  /* Observer (PLL) bandwidth w from the mechanics: the angle error of the PLL to an
   * acceleration step a it does not know (a load step) is about a / ki. A load of
   * FW_PLL_DESIGN_LOAD x the peak thrust K_F i_max must leave at most
   * FW_PLL_DESIGN_ERR_RAD, with ki = 3 w^2 (three poles at -w: kp = 3 w, ki = 3 w^2,
   * kd = w^3). Bounded below by the paper's observer (about 30 rad/s) and above by
   * the injection: the HF demodulation is one sample per injection period. */
  const float a_d = k_e * FW_PLL_DESIGN_LOAD * K_F * cfg->loops.i_max_A / cfg->machine.mass_kg;
  const float w_max = fw_units_obs_w_max(cfg);
  float w = sqrtf((a_d > 0.0f ? a_d : 0.0f) / (3.0f * FW_PLL_DESIGN_ERR_RAD));
  w = fw_clampf(w, FW_PLL_W_MIN, (w_max > FW_PLL_W_MIN ? w_max : FW_PLL_W_MIN));
  cfg->estimator.pll_kp = 3.0f * w;
  cfg->estimator.pll_ki = 3.0f * w * w;
  cfg->estimator.pll_kd = w * w * w;
}

size_t fw_config_field_count(void) { return K_NFIELDS; }

const fw_config_field_t *fw_config_field(size_t i) { return i < K_NFIELDS ? &k_fields[i] : NULL; }

const fw_config_field_t *fw_config_field_find(const char *name) {
  if (name == NULL) {
    return NULL;
  }
  for (size_t i = 0; i < K_NFIELDS; i++) {
    if (strcmp(k_fields[i].name, name) == 0) {
      return &k_fields[i];
    }
  }
  return NULL;
}

static float field_value(const fw_config_t *cfg, const fw_config_field_t *f) {
  const uint8_t *base = (const uint8_t *)cfg + f->offset;
  if (f->is_int && f->is_signed) {
    int32_t i;
    memcpy(&i, base, sizeof(i));
    return (float)i;
  }
  if (f->is_int) {
    uint32_t u;
    memcpy(&u, base, sizeof(u));
    return (float)u;
  }
  float x;
  memcpy(&x, base, sizeof(x));
  return x;
}

static fw_status_t report(fw_config_issue_t *issue, fw_status_t st, const char *field, float v,
                          float lo, float hi) {
  if (issue != NULL) {
    issue->status = st;
    issue->field = field;
    issue->value = v;
    issue->min = lo;
    issue->max = hi;
  }
  return st;
}

fw_status_t fw_config_check(const fw_config_t *cfg, fw_config_issue_t *issue) {
  if (cfg == NULL) {
    return report(issue, FW_ERR_NULL, NULL, 0.0f, 0.0f, 0.0f);
  }
  for (size_t i = 0; i < K_NFIELDS; i++) {
    const fw_config_field_t *f = &k_fields[i];
    float v = field_value(cfg, f);
    if (!fw_isfinite_f32(v)) {
      return report(issue, FW_ERR_NOT_FINITE, f->name, v, f->min, f->max);
    }
    if (v < f->min || v > f->max) {
      return report(issue, FW_ERR_RANGE, f->name, v, f->min, f->max);
    }
  }
  /* Cross-field consistency. */
  float ratio = cfg->sensing.f_pwm_Hz / cfg->estimator.f_inj_Hz;
  uint32_t n = (uint32_t)(ratio + 0.5f);
  float rerr = ratio - (float)n;
  if (rerr > 1e-3f || rerr < -1e-3f || (n % 2u) != 0u || n < 4u || n > FW_INJ_MAX_SAMPLES) {
    return report(issue, FW_ERR_INCONSISTENT, "f_inj_Hz", cfg->estimator.f_inj_Hz,
                  cfg->sensing.f_pwm_Hz / (float)FW_INJ_MAX_SAMPLES, cfg->sensing.f_pwm_Hz / 4.0f);
  }
  if (cfg->protection.u_dc_min_V >= cfg->protection.u_dc_max_V) {
    return report(issue, FW_ERR_INCONSISTENT, "u_dc_min_V", cfg->protection.u_dc_min_V, 1.0f,
                  cfg->protection.u_dc_max_V);
  }
  if (cfg->loops.i_max_A >= cfg->protection.i_trip_A) {
    return report(issue, FW_ERR_INCONSISTENT, "i_max_A", cfg->loops.i_max_A, 0.05f,
                  cfg->protection.i_trip_A);
  }
  if (cfg->estimator.sogi_k_adapt_min > cfg->estimator.sogi_k_adapt_max) {
    return report(issue, FW_ERR_INCONSISTENT, "sogi_k_adapt_min", cfg->estimator.sogi_k_adapt_min,
                  FW_SOGI_K_MIN, cfg->estimator.sogi_k_adapt_max);
  }
  if (cfg->estimator.bemf_v_on_mps > 0.0f &&
      cfg->estimator.bemf_v_off_mps >= cfg->estimator.bemf_v_on_mps) {
    return report(issue, FW_ERR_INCONSISTENT, "bemf_v_off_mps", cfg->estimator.bemf_v_off_mps, 0.0f,
                  cfg->estimator.bemf_v_on_mps);
  }
  if (cfg->estimator.pll_kd > 0.0f &&
      cfg->estimator.pll_kd >= cfg->estimator.pll_kp * cfg->estimator.pll_ki) {
    return report(issue, FW_ERR_INCONSISTENT, "pll_kd", cfg->estimator.pll_kd, 0.0f,
                  cfg->estimator.pll_kp * cfg->estimator.pll_ki);
  }
  /* Dead-time compensation: at most 10 % of the PWM period (a duty correction of 0.1) */
  if (cfg->compensation.dt_comp_s * cfg->sensing.f_pwm_Hz > 0.1f) {
    return report(issue, FW_ERR_INCONSISTENT, "dt_comp_s", cfg->compensation.dt_comp_s, 0.0f,
                  0.1f / cfg->sensing.f_pwm_Hz);
  }
  /* Saliency: injection needs |Lq - Ld| / Ld >= saliency_min (method.md 3.1). */
  float sal = (cfg->machine.L_q_H - cfg->machine.L_d_H) / cfg->machine.L_d_H;
  if (sal < 0.0f) {
    sal = -sal;
  }
  /* 1e-6 absorbs float32 rounding: Lq = 1.1 Ld must pass a 10 % threshold */
  /* sal = 0 is refused even with saliency_min = 0: L_q / (L_q - L_d) is inf */
  if (sal < cfg->protection.saliency_min - 1e-6f || !(sal > 0.0f)) {
    return report(issue, FW_ERR_SALIENCY, "L_q_H", cfg->machine.L_q_H,
                  cfg->machine.L_d_H * (1.0f + cfg->protection.saliency_min),
                  cfg->machine.L_d_H * 10.0f);
  }
  return report(issue, FW_OK, NULL, 0.0f, 0.0f, 0.0f);
}
