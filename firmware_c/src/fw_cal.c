/**
 * @file fw_cal.c
 * @brief Current-sensor zero calibration with the power stage off (fw_cal.h).
 */
#include <math.h>
#include <string.h>

#include "pmlsm/fw_cal.h"

void fw_cal_start(fw_cal_t *c, const fw_cfg_sensing_t *sensing, float dt_s) {
  memset(c, 0, sizeof(*c));
  c->nominal_counts = sensing->adc_offset_counts;
  for (int k = 0; k < 3; k++) {
    c->zero_counts[k] = c->nominal_counts;
  }
  c->settle = (uint32_t)ceilf(FW_CAL_SETTLE_S / dt_s);
  c->state = (uint8_t)FW_CAL_RUNNING;
}

void fw_cal_none(fw_cal_t *c) { c->state = (uint8_t)FW_CAL_NONE; }

bool fw_cal_sample(fw_cal_t *c, const fw_adc_inputs_t *adc) {
  if (c->state != (uint8_t)FW_CAL_RUNNING) {
    return false;
  }
  if (c->settle > 0u) {
    c->settle--;
    return false;
  }
  for (int k = 0; k < 3; k++) {
    const float d = (float)adc->i_abc_counts[k] - c->nominal_counts;
    c->s1[k] += d;
    c->s2[k] += d * d;
  }
  if (++c->n < FW_CAL_SAMPLES) {
    return false;
  }
  const float inv_n = 1.0f / (float)FW_CAL_SAMPLES;
  for (int k = 0; k < 3; k++) {
    const float mean = c->s1[k] * inv_n;
    const float var = c->s2[k] * inv_n - mean * mean;
    c->zero_counts[k] = c->nominal_counts + mean;
    c->spread_counts[k] = var > 0.0f ? sqrtf(var) : 0.0f;
  }
  c->state = (uint8_t)FW_CAL_DONE;
  return true;
}

fw_fault_t fw_cal_judge(const fw_cal_t *c, const fw_config_t *cfg) {
  if (c->state == (uint8_t)FW_CAL_NONE) {
    return FW_FAULT_NONE;
  }
  if (c->state != (uint8_t)FW_CAL_DONE) {
    return FW_FAULT_CURRENT_ZERO_CAL;
  }
  const float k_A = fabsf(cfg->sensing.adc_A_per_count);
  for (int k = 0; k < 3; k++) {
    const float off_A = fabsf(c->zero_counts[k] - cfg->sensing.adc_offset_counts) * k_A;
    const float spread_A = c->spread_counts[k] * k_A;
    /* written so that NaN fails too */
    if (!(off_A <= cfg->protection.mon_i_zero_max_A) ||
        !(spread_A <= cfg->protection.mon_i_zero_spread_A)) {
      return FW_FAULT_CURRENT_ZERO_CAL;
    }
  }
  return FW_FAULT_NONE;
}
