/**
 * @file fw_config.h
 * @brief Bottom layer: the configuration's defaults, derived values, field
 *        table and validation (fw_config.c). The types are in fw_types.h.
 */
#ifndef PMLSM_FW_CONFIG_H
#define PMLSM_FW_CONFIG_H

#include <stddef.h>
#include <stdint.h>

#include "fw_types.h"

#ifdef __cplusplus
extern "C" {
#endif

/** One configuration field, for validation messages, the OD and tools. */
typedef struct {
  const char *name; /**< field name as in fw_config_t */
  const char *unit; /**< SI unit, "" for dimensionless */
  size_t offset;    /**< offsetof(fw_config_t, part.name) */
  uint8_t is_int;   /**< 1: a 32-bit integer field (uint32_t, int32_t when is_signed);
                         0: float field */
  uint8_t is_signed; /**< with is_int: int32_t (signed option codes) */
  float min;        /**< inclusive */
  float max;        /**< inclusive */
} fw_config_field_t;

/** Where a configuration check failed. */
typedef struct {
  fw_status_t status;
  const char *field; /**< offending field (NULL if none) */
  float value;       /**< its value */
  float min, max;    /**< its allowed range */
} fw_config_issue_t;

/**
 * Defaults: the paper's Table 1 machine and gains, with the salient variant
 * L_q = 1.5 L_d (Table 1 itself has L_q = L_d, which cannot be tracked by
 * injection; see docs/method-notes). 24 kHz PWM, 3 kHz injection.
 */
void fw_config_default(fw_config_t *cfg);

/**
 * Derive the back-EMF levels of the configured speeds (always):
 *   bemf_e_on_V = psi_f (pi/tau) bemf_v_on_mps, bemf_e_off_V likewise from bemf_v_off_mps,
 *   mon_bemf_min_V from mon_bemf_min_mps (the back-EMF w psi_f at that speed),
 * and the gains from the physical description when gains_auto is set:
 *   K_F = 1.5 (pi/tau) psi_f (N/A),
 *   cur_kp = L_d w_c, cur_ki = R w_c (w_c = cur_bw_radps),
 *   spd_kp = m w_s / K_F * tau / pi (A per el. rad/s), spd_ki = spd_kp w_s / 6,
 *   pll_accel_per_A = (pi/tau) K_F / m (el. rad/s^2 per A),
 *   observer poles at -w: pll_kp = 3 w, pll_ki = 3 w^2, pll_kd = w^3 with
 *   w = sqrt(a_d / (3 * 0.05 rad)), a_d = (pi/tau) 0.2 K_F i_max / m (a load step of
 *   20 % of the peak thrust leaves about 0.05 rad), w within [30, 2 pi f_inj / 40].
 * fw_init and fw_set_config apply it, so the stored configuration (and the
 * object dictionary) shows the levels and gains in use; fw_config_default applies it
 * too. The gains are left as they are when gains_auto is 0.
 */
void fw_config_derive(fw_config_t *cfg);

/** Range and consistency check. Saliency below saliency_min -> FW_ERR_SALIENCY. */
fw_status_t fw_config_check(const fw_config_t *cfg, fw_config_issue_t *issue);

/** Number of entries in the configuration field table. */
size_t fw_config_field_count(void);
/** Field i of the table (NULL when out of range). */
const fw_config_field_t *fw_config_field(size_t i);
/** Look a field up by name (NULL when unknown). */
const fw_config_field_t *fw_config_field_find(const char *name);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_CONFIG_H */
