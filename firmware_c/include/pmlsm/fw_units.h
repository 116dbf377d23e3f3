/**
 * @file fw_units.h
 * @brief Bottom layer: unit conversions with the configured machine (fw_units.c).
 *
 * Inside the core angles and speeds are *electrical* (theta_e = pi x / tau =
 * p theta_m); these give m, m/s, r/min, V and N from them, and back.
 */
#ifndef PMLSM_FW_UNITS_H
#define PMLSM_FW_UNITS_H

#include "fw_types.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Linear speed (m/s) -> electrical rad/s: w_e = pi v / tau. */
float fw_units_mps_to_radps_e(const fw_config_t *cfg, float v_mps);
float fw_units_radps_e_to_mps(const fw_config_t *cfg, float w_radps_e);
/** Unwrapped electrical position (rad) -> m: the factor tau / pi of
 *  fw_units_radps_e_to_mps. */
float fw_units_rad_e_to_m(const fw_config_t *cfg, float pos_rad_e);
/** Back-EMF magnitude w psi_f (V) of a mover at v_mps (the one conversion used by
 *  fw_config_derive for the handover and witness levels, and the start check). */
float fw_units_bemf_V(const fw_config_t *cfg, float v_mps);
/** Rotary-equivalent r/min -> electrical rad/s: w_e = p 2 pi n / 60. */
float fw_units_rpm_to_radps_e(const fw_config_t *cfg, float n_rpm);
float fw_units_radps_e_to_rpm(const fw_config_t *cfg, float w_radps_e);
/** Nominal thrust constant K_F = 1.5 (pi/tau) psi_f (N per A of i_q); the one
 *  definition used by the gain derivation, force mode and the snapshot. */
float fw_units_force_per_A(const fw_config_t *cfg);
/** The fastest observer pole (rad/s) the HF error supports: 2 pi f_inj / 40 (the HF
 *  demodulation gives one error per injection period). fw_config_derive caps the derived
 *  observer bandwidth at it; fw_obs_init caps obs_mode 2's widening (obs_bw_wide) so
 *  that the widened poles stay under it. */
float fw_units_obs_w_max(const fw_config_t *cfg);
/** The fastest observer pole (rad/s) on the back-EMF error: 1 / (2 FW_BEMF_TAU_S),
 *  half the corner of the back-EMF's low-pass, whose lag a faster loop would ring on.
 *  fw_obs_init caps the widening bemf_obs_bw under it. */
float fw_units_obs_w_max_bemf(void);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_UNITS_H */
