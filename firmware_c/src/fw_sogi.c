/**
 * @file fw_sogi.c
 * @brief Pre-warped trapezoidal state-space SOGI whose states are the
 *        outputs v', qv' (see fw_sogi.h for the equations and why).
 */
#include "pmlsm/fw_sogi.h"

#include <math.h>
#include <stddef.h>

#include "pmlsm/fw_math.h"

/* Gains from the trapezoid (I - A/c) x[n+1] = (I + A/c) x[n] + (B/c) u,
 * u = v[n+1] + v[n], divided through by c (t = w / c = tan(w dt / 2)):
 *   I - A/c = [[1 + k t, t], [-t, 1]],  det = 1 + k t + t^2,
 *   inv     = [[1, -t], [t, 1 + k t]] / det,
 *   x[n+1] - x[n] = inv ((A/c) 2 x[n] + (B/c) u)
 *                 = [[-2 t (k + t), -2 t], [2 t, -2 t^2]] x[n] / det
 *                   + [k t; k t^2] u / det.
 * Row 1 gives x1 += p u - q x1 - r x2 with p = k t/det, q = 2 t (k + t)/det,
 * r = 2 t/det; row 2 equals t (x1[n] + x1[n+1]) (the trapezoid of
 * x2' = w x1), which is cheaper and is what fw_sogi_step_f32 uses. One
 * division per k change. */
static void fw_sogi_gains(fw_sogi_f32_t *s) {
  const float t = s->t;
  const float kt = s->k * t;
  const float e = 1.0f / (1.0f + kt + t * t);
  s->p = kt * e;
  s->q = 2.0f * t * (s->k + t) * e;
  s->r = 2.0f * t * e;
}

bool fw_sogi_init_f32(fw_sogi_f32_t *s, float f0_Hz, float k, float dt_s) {
  /* Rejects non-finite / non-positive arguments, k outside
   * [FW_SOGI_K_MIN, FW_SOGI_K_MAX] (a configuration error, unlike the
   * clamped run-time fw_sogi_set_k_f32) and w dt >= pi (centre at or above
   * Nyquist). On failure *s is left as a zero-output filter. */
  s->w_rad_s = 0.0f;
  s->dt_s = 0.0f;
  s->c = 1.0f;
  s->t = 0.0f;
  s->k = 0.0f;
  s->p = s->q = s->r = 0.0f;
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
  s->t = tn;
  s->k = k;
  fw_sogi_gains(s);
  return true;
}

void fw_sogi_set_k_f32(fw_sogi_f32_t *s, float k) {
  if (!fw_isfinite_f32(k) || !(s->w_rad_s > 0.0f)) {
    return; /* NaN k or uninitialised filter: keep the current gain */
  }
  s->k = fw_clampf(k, FW_SOGI_K_MIN, FW_SOGI_K_MAX);
  fw_sogi_gains(s); /* the state (x1 = v', x2 = qv', v_prev) is untouched */
}

void fw_sogi_copy_gain_f32(fw_sogi_f32_t *dst, const fw_sogi_f32_t *src) {
  if (dst == NULL || src == NULL || !(src->w_rad_s > 0.0f) ||
      !(dst->w_rad_s == src->w_rad_s) || !(dst->dt_s == src->dt_s)) {
    return; /* different filters (or uninitialised): gains would not apply */
  }
  dst->k = src->k;
  dst->p = src->p;
  dst->q = src->q;
  dst->r = src->r;
}

void fw_sogi_bump_k_f32(fw_sogi_f32_t *s, float dk) {
  /* trapezoid steady state for a DC input c: x1 = 0 and p 2 c = r x2, x2 = k c */
  const float c = s->v_prev - s->x1;
  if (fw_isfinite_f32(dk) && fw_isfinite_f32(c)) {
    s->x2 += dk * c;
  }
}

void fw_sogi_reset_f32(fw_sogi_f32_t *s) {
  s->x1 = 0.0f;
  s->x2 = 0.0f;
  s->v_prev = 0.0f;
}

/** The step of fw_sogi_step_f32 with the gains p, q, r, t given. */
static FW_ALWAYS_INLINE float sogi_step(fw_sogi_f32_t *s, float p, float q, float r, float t,
                                        float v) {
  if (!fw_isfinite_f32(v)) {
    v = 0.0f; /* a bad sample must not poison the state */
  }
  const float u = v + s->v_prev;
  const float x1_old = s->x1;
  const float x1 = x1_old + (p * u - q * x1_old - r * s->x2);
  s->x2 += t * (x1_old + x1);
  s->x1 = x1;
  s->v_prev = v;
  return x1;
}

float fw_sogi_step_f32(fw_sogi_f32_t *s, float v, float *qv) {
  const float x1 = sogi_step(s, s->p, s->q, s->r, s->t, v);
  if (qv != NULL) {
    *qv = s->x2;
  }
  return x1;
}

void fw_sogi_step_pair_f32(fw_sogi_f32_t *a, float va, fw_sogi_f32_t *b, float vb, float *ya,
                           float *yb) {
  const float p = a->p, q = a->q, r = a->r, t = a->t;
  *ya = sogi_step(a, p, q, r, t, va);
  *yb = sogi_step(b, p, q, r, t, vb);
}
