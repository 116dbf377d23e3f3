/**
 * @file fw_units.c
 * @brief Unit conversions with the configured machine (see fw_units.h).
 */
#include "pmlsm/fw_units.h"

#include "pmlsm/fw_bemf.h"

float fw_units_mps_to_radps_e(const fw_config_t *cfg, float v) {
  return FW_PI_F32 * v / cfg->machine.pole_pitch_m;
}
float fw_units_bemf_V(const fw_config_t *cfg, float v) {
  return fw_units_mps_to_radps_e(cfg, v) * cfg->machine.psi_f_Wb;
}
float fw_units_radps_e_to_mps(const fw_config_t *cfg, float w) {
  return w * cfg->machine.pole_pitch_m / FW_PI_F32;
}
float fw_units_rad_e_to_m(const fw_config_t *cfg, float pos_e) {
  return fw_units_radps_e_to_mps(cfg, pos_e);
}
float fw_units_rpm_to_radps_e(const fw_config_t *cfg, float n) {
  return n * FW_TWO_PI_F32 * cfg->machine.pole_pairs / 60.0f;
}
float fw_units_radps_e_to_rpm(const fw_config_t *cfg, float w) {
  return w * 60.0f / (FW_TWO_PI_F32 * cfg->machine.pole_pairs);
}
float fw_units_force_per_A(const fw_config_t *cfg) {
  return 1.5f * (FW_PI_F32 / cfg->machine.pole_pitch_m) * cfg->machine.psi_f_Wb;
}

float fw_units_obs_w_max(const fw_config_t *cfg) {
  return FW_TWO_PI_F32 * cfg->estimator.f_inj_Hz / 40.0f;
}
float fw_units_obs_w_max_bemf(void) { return 0.5f / FW_BEMF_TAU_S; }
