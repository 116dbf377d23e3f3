/**
 * @file fw_math.c
 * @brief Control primitives (see fw_math.h): fast sin/cos, angle wrap,
 *        Clarke/Park, min-max SVPWM, PI with anti-windup. float32 only.
 */
#include "pmlsm/fw_math.h"

#include <math.h>
#include <stddef.h>

/* ---- sin/cos ------------------------------------------------------------
 * Range reduction: k = nearest integer of theta * 2/pi, r = theta - k pi/2
 * with a three-constant Cody-Waite split of pi/2 (PIO2_1 has 8 significant
 * bits, PIO2_2 about 11, so k*PIO2_1 and k*PIO2_2 are exact for
 * |k| < 2^13, i.e. |theta| < ~1.28e4 rad). The reduced-angle error there is
 * a few 1e-7 rad; the polynomials add ~1e-7 (cephes sinf/cosf minimax
 * coefficients on [-pi/4, pi/4], degree 7 / 8). Measured (test_math.c):
 * max |error| 9.3e-8 for |theta| < 1e4, < 1e-6 up to 1e5 rad; beyond that
 * k*PIO2_1 stops being exact and the error grows (3e-2 near 1e6 rad, where
 * the float angle's own ulp is 0.06 rad). The result stays bounded
 * (|s|, |c| <= 1) for every finite input. */
/* FW_PIO2_1..3, FW_TWO_OVER_PI and the fast path (fw_sincos_fast_f32, with
 * the polynomials fw_sincos_poly_f32) are in fw_math.h. */
#define FW_SINCOS_R_MAX 0.8f                  /* |r| clamp, > pi/4 + slack */
#define FW_SINCOS_K_MAX 16777216.0f           /* 2^24: k still integral */

fw_sincos_f32_t fw_sincos_f32(float theta_rad) {
  float kf, r;
  if (fabsf(theta_rad) <= FW_SINCOS_FAST_MAX) { /* false for NaN */
    kf = (theta_rad * FW_TWO_OVER_PI + FW_SINCOS_ROUND) - FW_SINCOS_ROUND;
    r = ((theta_rad - kf * FW_PIO2_1) - kf * FW_PIO2_2) - kf * FW_PIO2_3;
  } else {
    if (!fw_isfinite_f32(theta_rad)) {
      const fw_sincos_f32_t out = {0.0f, 1.0f};
      return out;
    }
    /* Nearest quadrant by float->int conversion (no floorf call: Cortex-M4
     * has no VRINT); the clamp keeps any finite input inside int32. */
    const float y = fw_clampf(theta_rad * FW_TWO_OVER_PI, -FW_SINCOS_K_MAX, FW_SINCOS_K_MAX);
    kf = (float)(int32_t)(y + (y >= 0.0f ? 0.5f : -0.5f));
    r = ((theta_rad - kf * FW_PIO2_1) - kf * FW_PIO2_2) - kf * FW_PIO2_3;
    /* Only reachable when the reduction has lost all meaning (|theta| >~ 1e7):
     * keeps the polynomials inside their domain so |s|, |c| <= 1. */
    r = fw_clampf(r, -FW_SINCOS_R_MAX, FW_SINCOS_R_MAX);
  }
  return fw_sincos_poly_f32(r, kf);
}

/* fw_sincos_add_f32: inline in fw_math.h */

/* ---- atan2: fw_atan2_inline_f32 in fw_math.h ---------------------------- */
float fw_atan2_f32(float y, float x) { return fw_atan2_inline_f32(y, x); }

/* ---- angle wrap -----------------------------------------------------------
 * n = floor((theta - lo) / 2pi), theta - n 2pi with a two-constant split of
 * 2pi (TWO_PI_1 has 8 significant bits: n*TWO_PI_1 exact for |n| < 2^16,
 * i.e. |theta| < 4e5 rad). Larger angles (float ulp >= 0.03 rad, the phase
 * is meaningless there) are first folded with the exact fmodf so the result
 * is still in range. A final compare keeps it in [lo, lo + FW_TWO_PI_F32).
 * FW_TWO_PI_1/2 are in fw_math.h: fw_wrap_pi_f32 subtracts one turn inline. */
#define FW_INV_TWO_PI 0.159154943091895336f
#define FW_WRAP_FOLD 4.0e5f

static float fw_wrap_core(float theta_rad, float lo) {
  /* lo = -pi for [-pi, pi), 0 for [0, 2pi) */
  if (theta_rad > FW_WRAP_FOLD || theta_rad < -FW_WRAP_FOLD) {
    theta_rad = fmodf(theta_rad, FW_TWO_PI_F32); /* cold path */
  }
  const float y = (theta_rad - lo) * FW_INV_TWO_PI;
  int32_t n = (int32_t)y; /* truncation toward zero ... */
  if ((float)n > y) {
    n--; /* ... corrected to floor */
  }
  const float nf = (float)n;
  float r = (theta_rad - nf * FW_TWO_PI_1) - nf * FW_TWO_PI_2;
  if (r >= lo + FW_TWO_PI_F32) {
    r -= FW_TWO_PI_F32;
  }
  if (r < lo) {
    r += FW_TWO_PI_F32;
  }
  /* r + 2pi may round up to exactly lo + 2pi for tiny negative r. */
  if (r >= lo + FW_TWO_PI_F32) {
    r = lo;
  }
  return r;
}

float fw_wrap_pi_slow_f32(float theta_rad) {
  if (theta_rad >= -FW_PI_F32 && theta_rad < FW_PI_F32) {
    return theta_rad; /* already wrapped (also false for NaN) */
  }
  if (!fw_isfinite_f32(theta_rad)) {
    return 0.0f;
  }
  return fw_wrap_core(theta_rad, -FW_PI_F32);
}

float fw_wrap_2pi_f32(float theta_rad) {
  if (!fw_isfinite_f32(theta_rad)) {
    return 0.0f;
  }
  return fw_wrap_core(theta_rad, 0.0f);
}

/* ---- Clarke / Park ------------------------------------------------------- */
fw_vec2_f32_t fw_clarke_f32(float a, float b, float c) {
  /* alpha = (2a - b - c)/3, beta = (b - c)/sqrt(3); equals a, (a+2b)/sqrt3
   * when a + b + c = 0, and also removes any zero-sequence component. */
  fw_vec2_f32_t ab;
  ab.x = (2.0f * a - b - c) * (1.0f / 3.0f);
  ab.y = (b - c) * FW_INV_SQRT3_F32;
  return ab;
}

void fw_inv_clarke_f32(fw_vec2_f32_t ab, float abc[3]) {
  const float h = 0.5f * FW_SQRT3_F32 * ab.y;
  abc[0] = ab.x;
  abc[1] = -0.5f * ab.x + h;
  abc[2] = -0.5f * ab.x - h;
}

fw_vec2_f32_t fw_park_f32(fw_vec2_f32_t ab, fw_sincos_f32_t sc) {
  fw_vec2_f32_t dq;
  dq.x = sc.c * ab.x + sc.s * ab.y;
  dq.y = -sc.s * ab.x + sc.c * ab.y;
  return dq;
}

fw_vec2_f32_t fw_inv_park_f32(fw_vec2_f32_t dq, fw_sincos_f32_t sc) {
  fw_vec2_f32_t ab;
  ab.x = sc.c * dq.x - sc.s * dq.y;
  ab.y = sc.s * dq.x + sc.c * dq.y;
  return ab;
}

/* ---- SVPWM ----------------------------------------------------------------
 * Phase voltages from inverse Clarke plus zero sequence -(max+min)/2, which
 * centres the three references in the carrier; duty = 1/2 + u_x/u_dc.
 * Invalid input (u_dc <= 0 or non-finite, non-finite command) gives a zero
 * voltage vector (all duties 0.5) and reports "limited". */
bool fw_svpwm_f32(fw_vec2_f32_t u_ab_V, float u_dc_V, float duty_abc[3],
                  fw_vec2_f32_t *u_ab_out_V) {
  bool limited = false;
  fw_vec2_f32_t u = u_ab_V;
  /* one test for the three finiteness checks: x - x is 0 for a finite x,
   * NaN for NaN and inf, and NaN absorbs the sum */
  const float nf = (u.x - u.x) + (u.y - u.y) + (u_dc_V - u_dc_V);
  if (!(nf == 0.0f && u_dc_V > 0.0f)) {
    u.x = 0.0f;
    u.y = 0.0f;
    u_dc_V = 1.0f;
    limited = true;
  } else {
    const float u_max_V = u_dc_V * FW_INV_SQRT3_F32; /* inscribed circle */
    const float mag2 = u.x * u.x + u.y * u.y;
    if (mag2 > u_max_V * u_max_V) { /* the square root only when limiting */
      const float scale = u_max_V / sqrtf(mag2); /* keep the direction */
      u.x *= scale;
      u.y *= scale;
      limited = true;
    }
  }
  /* the inverse Clarke (fw_inv_clarke_f32) and the three phases in scalars,
   * not an array: at -Os an array stays on the stack and the duty loop is not
   * unrolled (same expressions, same order) */
  const float h = 0.5f * FW_SQRT3_F32 * u.y;
  const float ph0 = u.x;
  const float ph1 = -0.5f * u.x + h;
  const float ph2 = -0.5f * u.x - h;
  /* largest and smallest phase in two compares: the larger of ph1, ph2 is
   * -u.x/2 + |h| and the smaller -u.x/2 - |h|, the same roundings as ph1 and
   * ph2 themselves (x - h is x + (-h)). Only the sign of a zero result can
   * differ (h = -0), and the duties see u_hi and u_lo only through their sum
   * and difference, where it does not show. Branch-free: selecting ph1 or ph2
   * on h >= 0 cost a taken branch in half the periods. */
  const float mid12 = -0.5f * u.x;
  const float hi12 = mid12 + fabsf(h);
  const float lo12 = mid12 - fabsf(h);
  const float u_hi = hi12 > ph0 ? hi12 : ph0;
  const float u_lo = lo12 < ph0 ? lo12 : ph0;
  const float u0_V = -0.5f * (u_hi + u_lo);
  const float inv_dc = 1.0f / u_dc_V;
  duty_abc[0] = 0.5f + (ph0 + u0_V) * inv_dc;
  duty_abc[1] = 0.5f + (ph1 + u0_V) * inv_dc;
  duty_abc[2] = 0.5f + (ph2 + u0_V) * inv_dc;
  /* the duties span (u_hi - u_lo) / u_dc around 1/2; a span within 0.999 of
   * the carrier cannot leave [0, 1] by rounding, so the clamp (which only
   * absorbs rounding on the circle boundary) runs only near the boundary */
  if (FW_UNLIKELY(!((u_hi - u_lo) * inv_dc < 0.999f))) {
    for (int i = 0; i < 3; i++) {
      duty_abc[i] = fw_clampf(duty_abc[i], 0.0f, 1.0f);
    }
  }
  if (u_ab_out_V != NULL) {
    *u_ab_out_V = u;
  }
  return limited;
}

/* ---- PI -------------------------------------------------------------------
 * Backward-Euler integrator (integ already includes this step's ki*e*dt,
 * like the PLL in fw_pll.h):
 *   di   = ki e dt,  i_try = integ + di,  u_try = kp e + i_try + ff
 *   if u_try > out_max and di > 0: integ = max(integ, out_max - kp e - ff)
 *   if u_try < out_min and di < 0: integ = min(integ, out_min - kp e - ff)
 *   else integ = i_try                          (conditional integration)
 *   integ = clamp(integ, out_min, out_max)      (integrator held in limits)
 *   out   = clamp(kp e + integ + ff, out_min, out_max)
 * i.e. when the step would saturate, the integrator advances only up to the
 * value that puts the output exactly on the limit (back-calculation clamp)
 * and never further. Non-finite e/ff or dt_s < 0 (or non-finite): the state
 * is not touched and the last output is returned. */
void fw_pi_init_f32(fw_pi_f32_t *pi, float kp, float ki, float out_min,
                    float out_max) {
  pi->kp = kp;
  pi->ki = ki;
  pi->ki_dt = 0.0f;
  pi->out_min = out_min;
  pi->out_max = out_max;
  fw_pi_reset_f32(pi);
}

void fw_pi_reset_f32(fw_pi_f32_t *pi) {
  pi->integ = 0.0f;
  pi->out = 0.0f;
}

void fw_pi_set_dt_f32(fw_pi_f32_t *pi, float dt_s) { pi->ki_dt = pi->ki * dt_s; }

float fw_pi_step_f32(fw_pi_f32_t *pi, float e, float ff, float dt_s) {
  /* finite e, ff, dt_s in one test (x - x: 0 or NaN), dt_s >= 0 */
  const float nf = (e - e) + (ff - ff) + (dt_s - dt_s);
  if (!(nf == 0.0f && dt_s >= 0.0f)) {
    return pi->out;
  }
  return fw_pi_core_f32(pi, e, ff, pi->ki * e * dt_s, pi->out_min, pi->out_max);
}
