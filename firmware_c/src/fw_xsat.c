/**
 * @file fw_xsat.c
 * @brief Cross-saturation angle map, position ripple and dead-time compensation (see fw_xsat.h).
 */
#include <math.h>

#include "pmlsm/fw_xsat.h"

void fw_xsat_init(fw_xsat_t *x, const fw_config_t *cfg, float dt_s) {
  const fw_cfg_compensation_t *c = &cfg->compensation;
  x->xsat_on = (uint8_t)(c->xsat_di_A > 0.0f);
  x->inv_di = x->xsat_on ? 1.0f / c->xsat_di_A : 0.0f;
  x->off[0] = 0.0f;
  x->off[1] = c->xsat_off1_rad;
  x->off[2] = c->xsat_off2_rad;
  x->off[3] = c->xsat_off3_rad;
  x->off[4] = c->xsat_off4_rad;
  x->off[5] = c->xsat_off5_rad;
  x->off[6] = c->xsat_off6_rad;
  x->rip_c[0] = c->rip_a2_rad;
  x->rip_c[1] = c->rip_b2_rad;
  x->rip_c[2] = c->rip_a4_rad;
  x->rip_c[3] = c->rip_b4_rad;
  x->rip_on = (uint8_t)(c->rip_a2_rad != 0.0f || c->rip_b2_rad != 0.0f ||
                        c->rip_a4_rad != 0.0f || c->rip_b4_rad != 0.0f);
  /* time constant: half an injection period (f_inj_Hz >= 100, checked) */
  const float tau_s = 0.5f / cfg->estimator.f_inj_Hz;
  x->iq_alpha = 1.0f - expf(-dt_s / tau_s);
  x->dt_on = (uint8_t)(c->dt_comp_s > 0.0f || c->dt_comp_drop_V > 0.0f);
  x->dt_duty = c->dt_comp_s * cfg->sensing.f_pwm_Hz;
  x->drop_V = c->dt_comp_drop_V;
  x->band2 = c->dt_comp_band_A * c->dt_comp_band_A;
  fw_xsat_reset(x);
}

void fw_xsat_reset(fw_xsat_t *x) {
  x->iq_f = 0.0f;
  x->off_rad = 0.0f;
}

float fw_xsat_map(const fw_xsat_t *x, float i_q_A) {
  if (!x->xsat_on || !fw_isfinite_f32(i_q_A)) {
    return 0.0f;
  }
  const float u = fabsf(i_q_A) * x->inv_di; /* in steps of xsat_di_A */
  float o;
  if (u >= (float)FW_XSAT_POINTS) {
    o = x->off[FW_XSAT_POINTS]; /* held beyond the last point */
  } else {
    const uint32_t k = (uint32_t)u; /* 0 .. 5 */
    const float f = u - (float)k;
    o = x->off[k] + f * (x->off[k + 1u] - x->off[k]);
  }
  return i_q_A < 0.0f ? -o : o;
}

/** The smooth sign i / sqrt(i^2 + b^2) (b = 0: the sign, 0 at 0). */
static float smooth_sign(float i, float band2) {
  const float d = sqrtf(i * i + band2);
  return d > 0.0f ? i / d : 0.0f;
}

void fw_xsat_deadtime(const fw_xsat_t *x, fw_vec2_f32_t i_ab_A, float u_dc_V,
                      float duty_abc[3]) {
  if (FW_LIKELY(!x->dt_on)) {
    return;
  }
  /* duty per unit of sign: the dead time's share of the period plus the drop's of u_dc */
  const float k = x->dt_duty + (u_dc_V > 1.0f ? x->drop_V / u_dc_V : 0.0f);
  /* phase currents from alpha/beta (amplitude-invariant Clarke) */
  const float i_a = i_ab_A.x;
  const float i_b = -0.5f * i_ab_A.x + 0.5f * FW_SQRT3_F32 * i_ab_A.y;
  const float i_c = -i_a - i_b;
  const float i_abc[3] = {i_a, i_b, i_c};
  for (int j = 0; j < 3; j++) {
    duty_abc[j] = fw_clampf(duty_abc[j] + k * smooth_sign(i_abc[j], x->band2), 0.0f, 1.0f);
  }
}
