/* Tests for fw_math: sin/cos and atan2 accuracy, wrap, Clarke/Park, SVPWM, PI.
 * References: tests/c/ref_vectors.h (numpy, gen_ref_vectors.py). */
#include <float.h>
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "pmlsm/fw_math.h"
#include "ref_vectors.h"
#include "tinytest.h"

static const double PI_D = 3.14159265358979323846;

static fw_vec2_f32_t v2(float x, float y) {
  fw_vec2_f32_t v;
  v.x = x;
  v.y = y;
  return v;
}

/* |fw_sincos - libm double| for one angle, max over s and c */
static double sincos_err(float th) {
  const fw_sincos_f32_t sc = fw_sincos_f32(th);
  const double es = fabs((double)sc.s - sin((double)th));
  const double ec = fabs((double)sc.c - cos((double)th));
  return es > ec ? es : ec;
}

/* Dense sweep over |theta| < 1e4 rad: 2e7 uniform points (step 1e-3 rad),
 * every float in [-1, 1] with step 2^-16, and +-8 ulp around every
 * quadrant boundary k*pi/4 (where reduction and quadrant choice are
 * hardest). Bound: FW_SINCOS_MAX_ERR. */
static void test_sincos_sweep(void) {
  double max_err = 0.0, worst_th = 0.0;
  for (int32_t i = -10000000; i < 10000000; i++) {
    const float th = (float)((double)i * 1.0e-3 + 3.3e-4);
    const double e = sincos_err(th);
    if (e > max_err) {
      max_err = e;
      worst_th = (double)th;
    }
  }
  for (int32_t i = -65536; i <= 65536; i++) {
    const double e = sincos_err((float)i * (1.0f / 65536.0f));
    if (e > max_err) {
      max_err = e;
      worst_th = (double)i / 65536.0;
    }
  }
  for (int32_t k = -12733; k <= 12733; k++) {
    float th = (float)((double)k * PI_D / 4.0);
    for (int j = 0; j < 8; j++) {
      th = nextafterf(th, -FLT_MAX);
    }
    for (int j = 0; j < 17; j++) {
      if (fabsf(th) < 1.0e4f) {
        const double e = sincos_err(th);
        if (e > max_err) {
          max_err = e;
          worst_th = (double)th;
        }
      }
      th = nextafterf(th, FLT_MAX);
    }
  }
  printf("  sincos max abs error |theta|<1e4: %.3e at theta = %.9g (bound %.1e)\n",
         max_err, worst_th, (double)FW_SINCOS_MAX_ERR);
  TT_CHECK(max_err <= (double)FW_SINCOS_MAX_ERR);
  /* sanity: the sweep must be sensitive -- a 1e-5 error would be caught */
  TT_CHECK(max_err > 0.0 && max_err < 1.0e-5);
}

static void test_sincos_special(void) {
  fw_sincos_f32_t sc = fw_sincos_f32(NAN);
  TT_CHECK(sc.s == 0.0f && sc.c == 1.0f);
  sc = fw_sincos_f32(INFINITY);
  TT_CHECK(sc.s == 0.0f && sc.c == 1.0f);
  sc = fw_sincos_f32(-INFINITY);
  TT_CHECK(sc.s == 0.0f && sc.c == 1.0f);
  sc = fw_sincos_f32(0.0f);
  TT_CHECK(sc.s == 0.0f && sc.c == 1.0f);
  /* outside the accuracy domain: still bounded, and still close to 1e5 */
  const float big[] = {1.0e5f, -3.0e5f, 1.0e7f, 1.0e12f, -1.0e30f, FLT_MAX, -FLT_MAX};
  for (unsigned i = 0; i < sizeof big / sizeof big[0]; i++) {
    sc = fw_sincos_f32(big[i]);
    TT_CHECK(fabsf(sc.s) <= 1.0f + 1e-6f && fabsf(sc.c) <= 1.0f + 1e-6f);
  }
  TT_CHECK(sincos_err(1.0e5f) < 1.0e-4);
  /* identities */
  for (int i = 0; i < 1000; i++) {
    const float th = -50.0f + 0.1f * (float)i;
    sc = fw_sincos_f32(th);
    TT_CHECK_NEAR((double)(sc.s * sc.s + sc.c * sc.c), 1.0, 4e-6);
  }
}

/* fw_sincos_add_f32: the rotation of fw_sincos_f32(theta0) by a small d
 * against libm at theta0 + d, for theta0 over |theta0| < 1e4 (1.3e5 points)
 * and d over +-1.5 FW_SINCOS_ADD_MAX_RAD (beyond the limit: the full
 * fw_sincos_f32 of theta0 + d). Bound: FW_SINCOS_MAX_ERR, as fw_sincos_f32. */
static void test_sincos_add(void) {
  double max_err = 0.0, worst_th = 0.0, worst_d = 0.0;
  const float d_max = 1.5f * FW_SINCOS_ADD_MAX_RAD;
  for (int32_t i = -65536; i <= 65536; i++) {
    const float th0 = (float)((double)i * (1.0e4 / 65536.0) + 1.7e-3);
    const fw_sincos_f32_t sc0 = fw_sincos_f32(th0);
    for (int j = -24; j <= 24; j++) {
      const float d = d_max * (float)j / 24.0f + 1.0e-4f * (float)(i & 7);
      const fw_sincos_f32_t sc = fw_sincos_add_f32(sc0, th0, d);
      /* the rotation reaches th0 + d exactly; the fallback sees th0 + d
       * rounded to float (its ulp is 1e-3 rad near 1e4, as for any caller) */
      const double a = fabsf(d) <= FW_SINCOS_ADD_MAX_RAD ? (double)th0 + (double)d
                                                         : (double)(th0 + d);
      const double es = fabs((double)sc.s - sin(a));
      const double ec = fabs((double)sc.c - cos(a));
      const double e = es > ec ? es : ec;
      if (e > max_err) {
        max_err = e;
        worst_th = (double)th0;
        worst_d = (double)d;
      }
    }
  }
  printf("  sincos_add max abs error |theta0|<1e4, |d|<=%.3g: %.3e at theta0 = %.9g, d = %.6g "
         "(bound %.1e)\n",
         (double)d_max, max_err, worst_th, worst_d, (double)FW_SINCOS_MAX_ERR);
  TT_CHECK(max_err <= (double)FW_SINCOS_MAX_ERR);
  TT_CHECK(max_err > 0.0);
  /* d = 0 returns sc0 unchanged; a non-finite d falls back (NaN angle: s 0, c 1) */
  const fw_sincos_f32_t sc0 = fw_sincos_f32(0.7f);
  fw_sincos_f32_t sc = fw_sincos_add_f32(sc0, 0.7f, 0.0f);
  TT_CHECK(sc.s == sc0.s && sc.c == sc0.c);
  sc = fw_sincos_add_f32(sc0, 0.7f, NAN);
  TT_CHECK(sc.s == 0.0f && sc.c == 1.0f);
  sc = fw_sincos_add_f32(sc0, 0.7f, INFINITY);
  TT_CHECK(sc.s == 0.0f && sc.c == 1.0f);
}

/* The largest |fw_atan2_f32(y, x) - atan2 in double| seen, and where. */
typedef struct {
  double err;
  float y, x;
} atan2_worst_t;

static void atan2_check(atan2_worst_t *w, float y, float x) {
  const double e = fabs((double)fw_atan2_f32(y, x) - atan2((double)y, (double)x));
  if (e > w->err) {
    w->err = e;
    w->y = y;
    w->x = x;
  }
}

/* fw_atan2_f32 against double atan2: 2^21 directions over the whole circle at
 * eight magnitudes from 1e-30 to 1e30 (the inputs are the float vectors, so
 * the reference sees exactly what the function sees), and +-64 ulp of the
 * ratio around every octant boundary and the reduction's tan(pi/8) switch.
 * Bound: FW_ATAN2_MAX_ERR. Outside the fast path (zeros, NaN, infinities,
 * overflowing |x| + |y|) the result is libm's atan2f, bit for bit. */
static void test_atan2(void) {
  static const float mags[] = {1e-30f, 1e-6f, 1e-3f, 0.7f, 1.0f, 311.0f, 1e6f, 1e30f};
  atan2_worst_t w = {0.0, 0.0f, 0.0f};
  int32_t out_of_range = 0;
  for (size_t m = 0; m < sizeof mags / sizeof mags[0]; m++) {
    for (int32_t i = -(1 << 20); i < (1 << 20); i++) {
      const double th = PI_D * ((double)i + 0.37) / (double)(1 << 20);
      const float x = (float)((double)mags[m] * cos(th));
      const float y = (float)((double)mags[m] * sin(th));
      const float a = fw_atan2_f32(y, x);
      out_of_range += !(a >= -(float)PI_D && a <= (float)PI_D);
      atan2_check(&w, y, x);
    }
  }
  /* ratios r around 0, tan(pi/8), 1, 1/tan(pi/8) (octant and reduction
   * switches), in every quadrant */
  static const float ratios[] = {0.0f, 0.414213562373095f, 1.0f, 2.41421356237310f};
  for (size_t k = 0; k < sizeof ratios / sizeof ratios[0]; k++) {
    float r = ratios[k];
    for (int j = 0; j < 64; j++) {
      r = nextafterf(r, 0.0f);
    }
    for (int j = 0; j < 129; j++, r = nextafterf(r, 10.0f)) {
      for (int q = 0; q < 4; q++) {
        const float x = (q & 1) ? -1.0f : 1.0f;
        const float y = (q & 2) ? -r : r;
        atan2_check(&w, y, x);
        atan2_check(&w, x, y); /* the swapped octant */
      }
    }
  }
  printf("  atan2 max abs error: %.3e at (y, x) = (%.9g, %.9g) (bound %.1e)\n", w.err,
         (double)w.y, (double)w.x, (double)FW_ATAN2_MAX_ERR);
  TT_CHECK(w.err <= (double)FW_ATAN2_MAX_ERR);
  TT_CHECK(w.err > 0.0); /* the fast path, not libm, was measured */
  TT_CHECK(out_of_range == 0);
  /* the axes */
  TT_CHECK(fw_atan2_f32(0.0f, 2.0f) == 0.0f);
  TT_CHECK(fabs((double)fw_atan2_f32(2.0f, 0.0f) - 0.5 * PI_D) <= (double)FW_ATAN2_MAX_ERR);
  TT_CHECK(fabs((double)fw_atan2_f32(-2.0f, 0.0f) + 0.5 * PI_D) <= (double)FW_ATAN2_MAX_ERR);
  TT_CHECK(fabs((double)fw_atan2_f32(0.0f, -2.0f) - PI_D) <= (double)FW_ATAN2_MAX_ERR);
  /* y's sign, a zero's included (libm: atan2(-0, x > 0) = -0, atan2(-0, x < 0) = -pi) */
  TT_CHECK(fw_atan2_f32(-0.0f, 2.0f) == 0.0f && signbit(fw_atan2_f32(-0.0f, 2.0f)));
  TT_CHECK(fabs((double)fw_atan2_f32(-0.0f, -2.0f) + PI_D) <= (double)FW_ATAN2_MAX_ERR);
  /* outside the fast path: libm's atan2f exactly */
  static const float spec[][2] = {{0.0f, 0.0f},       {-0.0f, 0.0f},      {0.0f, -0.0f},
                                  {-0.0f, -0.0f},     {INFINITY, 1.0f},   {1.0f, -INFINITY},
                                  {-INFINITY, INFINITY}, {FLT_MAX, FLT_MAX}, {-FLT_MAX, 3.0f}};
  for (size_t k = 0; k < sizeof spec / sizeof spec[0]; k++) {
    const float a = fw_atan2_f32(spec[k][0], spec[k][1]);
    const float b = atan2f(spec[k][0], spec[k][1]);
    TT_CHECK(memcmp(&a, &b, sizeof a) == 0);
  }
  TT_CHECK(isnan(fw_atan2_f32(NAN, 1.0f)) && isnan(fw_atan2_f32(1.0f, NAN)));
  TT_CHECK(isnan(fw_atan2_f32(NAN, INFINITY)));
}

/* fw_wrap_pi_f32's inline one-turn path against the general wrap
 * (fw_wrap_pi_slow_f32): every float with pi <= |theta| < FW_WRAP_TURN_MAX
 * (about 2.4e7 of them), bit for bit, and the neighbours of both limits. */
static void test_wrap_one_turn(void) {
  uint32_t differ = 0, n = 0;
  for (int sign = -1; sign <= 1; sign += 2) {
    const float lo = nextafterf(FW_PI_F32, 0.0f);
    const float hi = nextafterf(FW_WRAP_TURN_MAX, 10.0f);
    for (float a = lo; a <= hi; a = nextafterf(a, 10.0f)) {
      const float th = (float)sign * a;
      const float w = fw_wrap_pi_f32(th);
      const float ws = fw_wrap_pi_slow_f32(th);
      differ += memcmp(&w, &ws, sizeof w) != 0;
      differ += !(w >= -FW_PI_F32 && w < FW_PI_F32);
      n++;
    }
  }
  printf("  wrap one turn: %u floats, %u differ from the general wrap\n", (unsigned)n,
         (unsigned)differ);
  TT_CHECK(n > 23000000u);
  TT_CHECK(differ == 0u);
}

/* Fast path (|theta| <= 8192 rad) and the clamped path beyond it agree at the
 * boundary; fw_isfinite_f32 as a single subtraction. */
static void test_sincos_paths_and_isfinite(void) {
  double max_err = 0.0;
  for (int side = -1; side <= 1; side += 2) {
    float th = (float)side * 8192.0f;
    for (int j = 0; j < 64; j++) {
      th = nextafterf(th, -FLT_MAX);
    }
    for (int j = 0; j < 129; j++) {
      const double e = sincos_err(th);
      max_err = e > max_err ? e : max_err;
      th = nextafterf(th, FLT_MAX);
    }
  }
  TT_CHECK(max_err <= (double)FW_SINCOS_MAX_ERR);
  TT_CHECK(fw_isfinite_f32(0.0f) && fw_isfinite_f32(-FLT_MAX) && fw_isfinite_f32(FLT_MIN));
  TT_CHECK(fw_isfinite_f32(1.0e-45f) && fw_isfinite_f32(-3.5f));
  TT_CHECK(!fw_isfinite_f32(NAN) && !fw_isfinite_f32(INFINITY) && !fw_isfinite_f32(-INFINITY));
}

/* wrapped difference in double, for comparisons modulo 2 pi */
static double wrapd(double x) { return x - 2.0 * PI_D * floor((x + PI_D) / (2.0 * PI_D)); }

static void test_wrap(void) {
  int bad_range = 0, bad_val = 0;
  for (int32_t i = -200000; i <= 200000; i++) {
    const float th = (float)i * 0.0500123f; /* up to ~1e4 rad */
    const float w = fw_wrap_pi_f32(th);
    const float w2 = fw_wrap_2pi_f32(th);
    if (!(w >= -FW_PI_F32 && w < FW_PI_F32) || !(w2 >= 0.0f && w2 < FW_TWO_PI_F32)) {
      bad_range++;
    }
    if (fabs(wrapd((double)w - (double)th)) > 1.0e-6 ||
        fabs(wrapd((double)w2 - (double)th)) > 1.0e-6) {
      bad_val++;
    }
  }
  TT_CHECK(bad_range == 0);
  TT_CHECK(bad_val == 0);
  /* edges */
  TT_CHECK(fw_wrap_pi_f32(FW_PI_F32) < 0.0f);
  TT_CHECK(fw_wrap_pi_f32(-FW_PI_F32) == -FW_PI_F32);
  TT_CHECK(fw_wrap_pi_f32(-1e-9f) == -1e-9f);
  TT_CHECK(fw_wrap_2pi_f32(-1e-9f) >= 0.0f && fw_wrap_2pi_f32(-1e-9f) < FW_TWO_PI_F32);
  TT_CHECK(fw_wrap_2pi_f32(FW_TWO_PI_F32) < FW_TWO_PI_F32);
  TT_CHECK_NEAR(fw_wrap_pi_f32(3.5f), 3.5 - 2.0 * PI_D, 1e-6);
  TT_CHECK_NEAR(fw_wrap_2pi_f32(-0.5f), 2.0 * PI_D - 0.5, 1e-6);
  TT_CHECK(fw_wrap_pi_f32(NAN) == 0.0f && fw_wrap_2pi_f32(INFINITY) == 0.0f);
  /* huge angles (fold path): still inside the documented ranges */
  const float huge[] = {4.1e5f, -7.7e6f, 1e30f, -FLT_MAX, FLT_MAX};
  for (unsigned i = 0; i < sizeof huge / sizeof huge[0]; i++) {
    const float w = fw_wrap_pi_f32(huge[i]), w2 = fw_wrap_2pi_f32(huge[i]);
    TT_CHECK(w >= -FW_PI_F32 && w < FW_PI_F32 && w2 >= 0.0f && w2 < FW_TWO_PI_F32);
  }
}

/* Transforms vs numpy. Tolerances: Clarke 1e-5 (|x| <= 10, float rounding),
 * Park 5e-5 (adds the sin/cos error 2e-6 times |ab| <= 14). */
static void test_transforms_ref(void) {
  for (int i = 0; i < REF_N_XFORM; i++) {
    const float *abc = &ref_xf_abc[3 * i];
    const fw_vec2_f32_t ab = fw_clarke_f32(abc[0], abc[1], abc[2]);
    TT_CHECK_NEAR(ab.x, ref_xf_clarke_ab[2 * i], 1e-5);
    TT_CHECK_NEAR(ab.y, ref_xf_clarke_ab[2 * i + 1], 1e-5);

    const fw_vec2_f32_t in = v2(ref_xf_ab[2 * i], ref_xf_ab[2 * i + 1]);
    float out[3];
    fw_inv_clarke_f32(in, out);
    for (int j = 0; j < 3; j++) {
      TT_CHECK_NEAR(out[j], ref_xf_invclarke_abc[3 * i + j], 1e-5);
    }
    const fw_sincos_f32_t sc = fw_sincos_f32(ref_xf_theta[i]);
    const fw_vec2_f32_t dq = fw_park_f32(in, sc);
    TT_CHECK_NEAR(dq.x, ref_xf_park_dq[2 * i], 5e-5);
    TT_CHECK_NEAR(dq.y, ref_xf_park_dq[2 * i + 1], 5e-5);
    const fw_vec2_f32_t ab2 = fw_inv_park_f32(in, sc);
    TT_CHECK_NEAR(ab2.x, ref_xf_invpark_ab[2 * i], 5e-5);
    TT_CHECK_NEAR(ab2.y, ref_xf_invpark_ab[2 * i + 1], 5e-5);
  }
}

static void test_transforms_props(void) {
  /* amplitude invariance: balanced peak I -> |i_ab| = I, angle preserved */
  for (int i = 0; i < 36; i++) {
    const float th = 0.1745329f * (float)i, amp = 7.5f;
    const fw_sincos_f32_t sa = fw_sincos_f32(th);
    const fw_sincos_f32_t sb = fw_sincos_f32(th - 2.0943951f);
    const fw_sincos_f32_t scc = fw_sincos_f32(th + 2.0943951f);
    const fw_vec2_f32_t ab = fw_clarke_f32(amp * sa.c, amp * sb.c, amp * scc.c);
    TT_CHECK_NEAR(ab.x, (double)amp * cos((double)th), 1e-4);
    TT_CHECK_NEAR(ab.y, (double)amp * sin((double)th), 1e-4);
    /* Park at the same angle: pure d axis */
    const fw_vec2_f32_t dq = fw_park_f32(ab, sa);
    TT_CHECK_NEAR(dq.x, amp, 1e-4);
    TT_CHECK_NEAR(dq.y, 0.0, 1e-4);
    /* round trips */
    const fw_vec2_f32_t ab2 = fw_inv_park_f32(dq, sa);
    TT_CHECK_NEAR(ab2.x, ab.x, 1e-5);
    TT_CHECK_NEAR(ab2.y, ab.y, 1e-5);
    float abc[3];
    fw_inv_clarke_f32(ab, abc);
    TT_CHECK_NEAR((double)abc[0] + (double)abc[1] + (double)abc[2], 0.0, 1e-5);
    TT_CHECK_NEAR(abc[1], (double)amp * cos((double)th - 2.0 * PI_D / 3.0), 1e-4);
  }
  /* zero sequence is removed */
  const fw_vec2_f32_t z = fw_clarke_f32(3.0f, 3.0f, 3.0f);
  TT_CHECK_NEAR(z.x, 0.0, 1e-6);
  TT_CHECK_NEAR(z.y, 0.0, 1e-6);
}

/* SVPWM vs the numpy sector/dwell-time reference. Tolerance 1e-5 on duties
 * (float rounding of u/u_dc), 1e-5 * u_dc on the realised voltage. The
 * limited flag is checked except within 1e-5 of the circle. */
static void test_svpwm_ref(void) {
  for (int i = 0; i < REF_N_SVPWM; i++) {
    const fw_vec2_f32_t u = v2(ref_sv_u_ab[2 * i], ref_sv_u_ab[2 * i + 1]);
    const float udc = ref_sv_udc[i];
    float d[3];
    fw_vec2_f32_t ur;
    const bool lim = fw_svpwm_f32(u, udc, d, &ur);
    for (int j = 0; j < 3; j++) {
      TT_CHECK_NEAR(d[j], ref_sv_duty[3 * i + j], 1e-5);
    }
    TT_CHECK_NEAR(ur.x, ref_sv_u_real[2 * i], 1e-5 * (double)udc);
    TT_CHECK_NEAR(ur.y, ref_sv_u_real[2 * i + 1], 1e-5 * (double)udc);
    const double m = hypot((double)u.x, (double)u.y) / ((double)udc / sqrt(3.0));
    if (fabs(m - 1.0) > 1e-5) {
      TT_CHECK(lim == (ref_sv_limited[i] != 0));
    }
  }
}

/* Properties over a dense sweep: duties in [0,1]; the voltage realised by
 * the duties, u_x = (d_x - mean(d)) u_dc through Clarke, equals the command
 * inside the circle, and outside has the command's direction and magnitude
 * u_dc/sqrt(3). Tolerance 2e-5 * u_dc. */
static void test_svpwm_props(void) {
  int out_of_range = 0, bad_inside = 0, bad_outside = 0, bad_flag = 0;
  const float udc = 48.0f;
  const double umax = (double)udc / sqrt(3.0);
  for (int im = 0; im <= 60; im++) {
    const double m = 0.05 * im; /* 0 .. 3 x circle radius */
    for (int ia = 0; ia < 720; ia++) {
      const double a = 2.0 * PI_D * ia / 720.0;
      const fw_vec2_f32_t u = v2((float)(m * umax * cos(a)), (float)(m * umax * sin(a)));
      float d[3];
      fw_vec2_f32_t ur;
      const bool lim = fw_svpwm_f32(u, udc, d, &ur);
      const double mean = ((double)d[0] + (double)d[1] + (double)d[2]) / 3.0;
      const double ua = ((double)d[0] - mean) * (double)udc;
      const double ub = ((double)d[1] - mean) * (double)udc;
      const double uc = ((double)d[2] - mean) * (double)udc;
      const double rx = (2.0 * ua - ub - uc) / 3.0, ry = (ub - uc) / sqrt(3.0);
      for (int j = 0; j < 3; j++) {
        if (!(d[j] >= 0.0f && d[j] <= 1.0f)) {
          out_of_range++;
        }
      }
      if (m < 0.9999) {
        if (fabs(rx - (double)u.x) > 2e-5 * (double)udc ||
            fabs(ry - (double)u.y) > 2e-5 * (double)udc || lim) {
          bad_inside++;
        }
      } else if (m > 1.0001) {
        const double cross = rx * (double)u.y - ry * (double)u.x;
        const double dot = rx * (double)u.x + ry * (double)u.y;
        if (fabs(hypot(rx, ry) - umax) > 2e-5 * (double)udc ||
            fabs(cross) > 2e-5 * (double)udc * hypot((double)u.x, (double)u.y) ||
            dot <= 0.0 || fabs((double)ur.x - rx) > 2e-5 * (double)udc) {
          bad_outside++;
        }
        if (!lim) {
          bad_flag++;
        }
      }
    }
  }
  TT_CHECK(out_of_range == 0);
  TT_CHECK(bad_inside == 0);
  TT_CHECK(bad_outside == 0);
  TT_CHECK(bad_flag == 0);
  /* zero command: 50 % on all phases */
  float d[3];
  TT_CHECK(!fw_svpwm_f32(v2(0.0f, 0.0f), udc, d, NULL));
  TT_CHECK(d[0] == 0.5f && d[1] == 0.5f && d[2] == 0.5f);
  /* invalid inputs: zero vector, flagged */
  fw_vec2_f32_t ur = v2(9.0f, 9.0f);
  TT_CHECK(fw_svpwm_f32(v2(10.0f, 0.0f), 0.0f, d, &ur));
  TT_CHECK(d[0] == 0.5f && d[1] == 0.5f && d[2] == 0.5f && ur.x == 0.0f && ur.y == 0.0f);
  TT_CHECK(fw_svpwm_f32(v2(NAN, 0.0f), udc, d, NULL));
  TT_CHECK(d[0] == 0.5f && d[1] == 0.5f && d[2] == 0.5f);
  TT_CHECK(fw_svpwm_f32(v2(1.0f, 0.0f), -48.0f, d, NULL));
  TT_CHECK(fw_svpwm_f32(v2(1.0f, 0.0f), INFINITY, d, NULL));
}

/* PI vs the numpy re-implementation, tolerance 1e-5 (240 float steps). */
static void test_pi_ref(void) {
  fw_pi_f32_t pi;
  fw_pi_init_f32(&pi, REF_PI_KP, REF_PI_KI, REF_PI_MIN, REF_PI_MAX);
  double max_dev = 0.0;
  for (int k = 0; k < REF_N_PI; k++) {
    const float o = fw_pi_step_f32(&pi, ref_pi_e[k], ref_pi_ff[k], REF_PI_DT);
    TT_CHECK(o == pi.out);
    const double d1 = fabs((double)o - ref_pi_out[k]);
    const double d2 = fabs((double)pi.integ - ref_pi_integ[k]);
    max_dev = fmax(max_dev, fmax(d1, d2));
  }
  TT_CHECK_NEAR(max_dev, 0.0, 1e-5);
}

/* Anti-windup properties: integrator bounded in [min, max]; after a long
 * + saturation, the first step with a negative error leaves saturation. */
static void test_pi_antiwindup(void) {
  fw_pi_f32_t pi;
  fw_pi_init_f32(&pi, 2.0f, 50.0f, -1.0f, 1.5f);
  for (int k = 0; k < 10000; k++) {
    (void)fw_pi_step_f32(&pi, 5.0f, 0.0f, 1e-3f);
    TT_CHECK(pi.integ <= 1.5f && pi.integ >= -1.0f);
  }
  TT_CHECK(pi.out == 1.5f);
  /* back-calculation: integrator parked where kp e + integ = out_max would
   * hold, never beyond the limit; with e = 5, kp e = 10 > max, so the
   * integrator may not have run away above out_max */
  TT_CHECK(pi.integ <= 1.5f);
  const float o = fw_pi_step_f32(&pi, -0.1f, 0.0f, 1e-3f);
  TT_CHECK(o < 1.5f);                      /* recovered in one step */
  TT_CHECK_NEAR(o, (double)pi.integ - 0.2, 1e-6); /* = kp e + integ */
  /* symmetric on the low side, with feed-forward */
  fw_pi_reset_f32(&pi);
  TT_CHECK(pi.integ == 0.0f && pi.out == 0.0f);
  for (int k = 0; k < 5000; k++) {
    (void)fw_pi_step_f32(&pi, -3.0f, 0.3f, 1e-3f);
  }
  TT_CHECK(pi.out == -1.0f && pi.integ >= -1.0f);
  TT_CHECK(fw_pi_step_f32(&pi, 0.05f, 0.3f, 1e-3f) > -1.0f);
  /* the integrator is held in [out_min, out_max] even when a large
   * feed-forward keeps the output unsaturated (only the final clamp acts) */
  fw_pi_init_f32(&pi, 2.0f, 50.0f, -1.0f, 1.5f);
  for (int k = 0; k < 2000; k++) {
    (void)fw_pi_step_f32(&pi, 1.0f, -10.0f, 1e-3f);
  }
  TT_CHECK(pi.integ == 1.5f);
  TT_CHECK(pi.out == -1.0f); /* 2 + 1.5 - 10 -> clamped */
  fw_pi_init_f32(&pi, 2.0f, 50.0f, -1.0f, 1.5f);
  for (int k = 0; k < 2000; k++) {
    (void)fw_pi_step_f32(&pi, -1.0f, 10.0f, 1e-3f);
  }
  TT_CHECK(pi.integ == -1.0f);
  /* linear region: pure PI, exact */
  fw_pi_init_f32(&pi, 0.5f, 10.0f, -100.0f, 100.0f);
  float acc = 0.0f;
  for (int k = 0; k < 100; k++) {
    const float e = 0.01f * (float)(k % 7) - 0.03f;
    acc += 10.0f * e * 1e-3f;
    TT_CHECK_NEAR(fw_pi_step_f32(&pi, e, 0.25f, 1e-3f), (double)(0.5f * e + acc + 0.25f), 1e-6);
  }
  /* invalid input holds state and output */
  const fw_pi_f32_t before = pi;
  TT_CHECK(fw_pi_step_f32(&pi, NAN, 0.0f, 1e-3f) == before.out);
  TT_CHECK(fw_pi_step_f32(&pi, 1.0f, 0.0f, -1e-3f) == before.out);
  TT_CHECK(memcmp(&pi, &before, sizeof pi) == 0);
}

/* The configured variant (ki dt precomputed, symmetric limits per call) follows
 * fw_pi_step_f32 within rounding on a sequence that saturates both ways. */
static void test_pi_cfg(void) {
  fw_pi_f32_t a, b;
  const float dt = 1.0f / 24000.0f, lim = 2.0f;
  fw_pi_init_f32(&a, 0.7f, 900.0f, -lim, lim);
  fw_pi_init_f32(&b, 0.7f, 900.0f, -1.0f, 1.0f); /* stored limits unused */
  fw_pi_set_dt_f32(&b, dt);
  TT_CHECK(b.ki_dt == 900.0f * dt);
  for (int k = 0; k < 2000; k++) {
    const float e = 4.0f * sinf(0.01f * (float)k), ff = 0.3f * cosf(0.003f * (float)k);
    const float oa = fw_pi_step_f32(&a, e, ff, dt);
    const float ob = fw_pi_step_cfg_f32(&b, e, ff, lim);
    TT_CHECK_NEAR(ob, oa, 1e-5);
    TT_CHECK(ob <= lim && ob >= -lim);
  }
  TT_CHECK_NEAR(b.integ, a.integ, 1e-5);
  const fw_pi_f32_t before = b;
  TT_CHECK(fw_pi_step_cfg_f32(&b, NAN, 0.0f, lim) == before.out);
  TT_CHECK(fw_pi_step_cfg_f32(&b, 1.0f, INFINITY, lim) == before.out);
  TT_CHECK(b.integ == before.integ);
}

int main(void) {
  TT_RUN(test_sincos_sweep);
  TT_RUN(test_sincos_special);
  TT_RUN(test_sincos_add);
  TT_RUN(test_sincos_paths_and_isfinite);
  TT_RUN(test_atan2);
  TT_RUN(test_wrap);
  TT_RUN(test_wrap_one_turn);
  TT_RUN(test_transforms_ref);
  TT_RUN(test_transforms_props);
  TT_RUN(test_svpwm_ref);
  TT_RUN(test_svpwm_props);
  TT_RUN(test_pi_ref);
  TT_RUN(test_pi_antiwindup);
  TT_RUN(test_pi_cfg);
  return TT_SUMMARY();
}
