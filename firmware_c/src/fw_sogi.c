/**
 * @file fw_sogi.c
 * @brief Pre-warped Tustin SOGI, two DF2T biquads sharing one denominator
 *        (see fw_sogi.h for the transfer functions and coefficients).
 */
#include "pmlsm/fw_sogi.h"

#include <math.h>
#include <stddef.h>

#include "pmlsm/fw_math.h"

/* Coefficients from the header formulas divided through by c^2, with
 * t = w / c = tan(w dt / 2) (dimensionless). Same values, but no c^2 ~ 1e9
 * (rad/s)^2 intermediates and less cancellation in a1 when w dt is small:
 *   a0 = 1 + k t + t^2, a1 = 2 (t^2 - 1), a2 = 1 - k t + t^2,
 *   bd0 = k t / a0, bq0 = k t^2 / a0, bq1 = 2 bq0. */
static void fw_sogi_coeffs(fw_sogi_f32_t *s) {
  const float t = s->w_rad_s / s->c;
  const float t2 = t * t;
  const float kt = s->k * t;
  const float inv_a0 = 1.0f / (1.0f + kt + t2);
  s->bd0 = kt * inv_a0;
  s->bq0 = kt * t * inv_a0;
  s->bq1 = 2.0f * s->bq0;
  s->a1 = 2.0f * (t2 - 1.0f) * inv_a0;
  s->a2 = (1.0f - kt + t2) * inv_a0;
}

bool fw_sogi_init_f32(fw_sogi_f32_t *s, float f0_Hz, float k, float dt_s) {
  /* Rejects non-finite / non-positive arguments, k outside
   * [FW_SOGI_K_MIN, FW_SOGI_K_MAX] (a configuration error, unlike the
   * clamped run-time fw_sogi_set_k_f32) and w dt >= pi (centre at or above
   * Nyquist). On failure *s is left as a zero-output filter. */
  s->w_rad_s = 0.0f;
  s->dt_s = 0.0f;
  s->c = 1.0f;
  s->k = 0.0f;
  s->bd0 = s->bq0 = s->bq1 = s->a1 = s->a2 = 0.0f;
  fw_sogi_reset_f32(s);
  if (!fw_isfinite_f32(f0_Hz) || !fw_isfinite_f32(k) || !fw_isfinite_f32(dt_s) ||
      !(f0_Hz > 0.0f) || !(dt_s > 0.0f) || !(k >= FW_SOGI_K_MIN) ||
      !(k <= FW_SOGI_K_MAX)) {
    return false;
  }
  const float w_rad_s = FW_TWO_PI_F32 * f0_Hz;
  const float half_wdt = 0.5f * w_rad_s * dt_s; /* rad, must be < pi/2 */
  if (!(half_wdt < 0.5f * FW_PI_F32)) {
    return false;
  }
  const float tn = tanf(half_wdt);
  if (!(tn > 0.0f) || !fw_isfinite_f32(tn)) {
    return false;
  }
  s->w_rad_s = w_rad_s;
  s->dt_s = dt_s;
  s->c = w_rad_s / tn; /* pre-warp constant (1/s) */
  s->k = k;
  fw_sogi_coeffs(s);
  return true;
}

void fw_sogi_set_k_f32(fw_sogi_f32_t *s, float k) {
  if (!fw_isfinite_f32(k) || !(s->w_rad_s > 0.0f)) {
    return; /* NaN k or uninitialised filter: keep the current gain */
  }
  s->k = fw_clampf(k, FW_SOGI_K_MIN, FW_SOGI_K_MAX);
  fw_sogi_coeffs(s); /* state (transposed delay line) is kept */
}

void fw_sogi_reset_f32(fw_sogi_f32_t *s) {
  s->zd1 = s->zd2 = 0.0f;
  s->zq1 = s->zq2 = 0.0f;
}

float fw_sogi_step_f32(fw_sogi_f32_t *s, float v, float *qv) {
  if (!fw_isfinite_f32(v)) {
    v = 0.0f; /* a bad sample must not poison the delay line */
  }
  /* D: b = [bd0, 0, -bd0]  (DF2T) */
  const float d = s->bd0 * v + s->zd1;
  s->zd1 = s->zd2 - s->a1 * d;
  s->zd2 = -s->bd0 * v - s->a2 * d;
  /* Q: b = [bq0, 2 bq0, bq0] */
  const float q = s->bq0 * v + s->zq1;
  s->zq1 = s->bq1 * v + s->zq2 - s->a1 * q;
  s->zq2 = s->bq0 * v - s->a2 * q;
  if (qv != NULL) {
    *qv = q;
  }
  return d;
}
