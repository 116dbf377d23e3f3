/* Tests for fw_pll: angle step and ramp vs the numpy simulation of the
 * documented difference equations, zero steady-state ramp error, limits,
 * reset, quadrature error helper, invalid input. */
#include <math.h>
#include <string.h>

#include "pmlsm/fw_pll.h"
#include "ref_vectors.h"
#include "tinytest.h"

static const double PI_D = 3.14159265358979323846;

static double wrapd(double x) { return x - 2.0 * PI_D * floor((x + PI_D) / (2.0 * PI_D)); }

/* theta_true(k) for the ramp reference, as in gen_ref_vectors.py */
static float ramp_theta(double w_radps, int k) {
  return (float)wrapd(w_radps * (double)k * (double)REF_PLL_DT);
}

/* Run the reference scenario: e = sin(theta_true - theta_hat) (eq. 9). The
 * reference is float64; tolerance 2e-4 rad on the angle and 2e-2 rad/s on
 * the speed covers float32 state rounding (theta ulp 2.4e-7 rad per step). */
static void run_ref(int ramp, const double *ref_theta, const double *ref_wi) {
  fw_pll_f32_t p;
  fw_pll_init_f32(&p, REF_PLL_KP, REF_PLL_KI, REF_PLL_WMAX);
  double dev_th = 0.0, dev_w = 0.0;
  for (int k = 0; k < REF_PLL_N; k++) {
    const float th_true = ramp ? ramp_theta((double)REF_PLL_W_RAMP, k) : REF_PLL_STEP_RAD;
    const float e = (float)sin((double)th_true - (double)p.theta_rad);
    fw_pll_step_f32(&p, e, REF_PLL_DT);
    TT_CHECK(p.theta_rad >= -FW_PI_F32 && p.theta_rad < FW_PI_F32);
    if ((k + 1) % REF_PLL_DEC == 0) {
      const int j = (k + 1) / REF_PLL_DEC - 1;
      dev_th = fmax(dev_th, fabs(wrapd((double)p.theta_rad - ref_theta[j])));
      dev_w = fmax(dev_w, fabs((double)p.w_i_radps - ref_wi[j]));
    }
  }
  printf("  %s: max |theta - ref| = %.2e rad, max |w_i - ref| = %.2e rad/s\n",
         ramp ? "ramp" : "step", dev_th, dev_w);
  TT_CHECK_NEAR(dev_th, 0.0, 2e-4);
  TT_CHECK_NEAR(dev_w, 0.0, 2e-2);
}

static void test_step_ref(void) { run_ref(0, ref_pll_step_theta, ref_pll_step_wi); }
static void test_ramp_ref(void) { run_ref(1, ref_pll_ramp_theta, ref_pll_ramp_wi); }

/* Linear step response of (kp s + ki)/(s^2 + kp s + ki): zeta = kp/(2 sqrt ki)
 * = 0.61 -> overshoot of the angle; settles to the step with zero error.
 * The reference shows where it should be at the checkpoints. */
static void test_step_shape(void) {
  /* peak of the decimated reference lies above the step (overshoot, < 30 %) */
  double peak = 0.0;
  for (int j = 0; j < REF_PLL_N / REF_PLL_DEC; j++) {
    peak = fmax(peak, ref_pll_step_theta[j]);
  }
  TT_CHECK(peak > 1.05 && peak < 1.3);
  const int last = REF_PLL_N / REF_PLL_DEC - 1;
  TT_CHECK_NEAR(ref_pll_step_theta[last], 1.0, 1e-5);
  TT_CHECK_NEAR(ref_pll_step_wi[last], 0.0, 1e-3);
}

/* Zero steady-state error on a ramp, with the real quadrature error
 * (fw_sincos + fw_pll_quad_error_f32): after 0.3 s the angle error is below
 * 5e-5 rad (+ the float32 dead zone below) and w_i is within 1e-2 rad/s
 * (+ kp * dead zone) of the ramp speed, for slow,
 * negative and fast (1257 rad/s, many wraps, started at 1200 rad/s: the
 * pull-in range of a 70 rad/s loop is far smaller) ramps. A type-1 loop
 * (ki = 0) lags by w/kp, which this check would flag. */
static double ramp_error(float kp, float ki, double w, float w0, double *w_i_err) {
  fw_pll_f32_t p;
  fw_pll_init_f32(&p, kp, ki, REF_PLL_WMAX);
  fw_pll_reset_f32(&p, 0.0f, w0); /* start speed: a PLL only pulls in near lock */
  double max_e = 0.0;
  const int n = 12000;
  for (int k = 0; k < n; k++) {
    const float th = ramp_theta(w, k);
    const fw_sincos_f32_t sc_true = fw_sincos_f32(th);
    const fw_sincos_f32_t sc_hat = fw_sincos_f32(p.theta_rad);
    fw_pll_step_f32(&p, fw_pll_quad_error_f32(sc_true.s, sc_true.c, sc_hat), REF_PLL_DT);
    if (k > 7200) { /* after 0.3 s; compare with theta_true(k + 1) */
      max_e = fmax(max_e, fabs(wrapd((double)ramp_theta(w, k + 1) - (double)p.theta_rad)));
      *w_i_err = fmax(*w_i_err, fabs((double)p.w_i_radps - w));
    }
  }
  return max_e;
}

static void test_ramp_zero_error(void) {
  const double ws[] = {(double)REF_PLL_W_RAMP, -(double)REF_PLL_W_RAMP, 1256.6370614};
  const float w0s[] = {0.0f, 0.0f, 1200.0f};
  for (int i = 0; i < 3; i++) {
    double w_err = 0.0;
    const double e = ramp_error(REF_PLL_KP, REF_PLL_KI, ws[i], w0s[i], &w_err);
    printf("  ramp %.1f rad/s: steady |e| = %.2e rad, |w_i - w| = %.2e rad/s\n", ws[i], e, w_err);
    /* float32 dead zone of the integrator: ki e dt below half an ulp of
     * w_i is lost, so |e| settles anywhere below ulp(w)/(2 ki dt) (1.1e-5
     * rad at 42 rad/s, 2.9e-4 rad at 1257 rad/s); w_i then errs by kp e. */
    const float wf = (float)fabs(ws[i]);
    const double dead = (double)(nextafterf(wf, 2.0f * wf) - wf) /
                        (2.0 * (double)REF_PLL_KI * (double)REF_PLL_DT);
    TT_CHECK_NEAR(e, 0.0, 5e-5 + dead);
    TT_CHECK_NEAR(w_err, 0.0, 1e-2 + (double)REF_PLL_KP * dead);
  }
  double w_err = 0.0;
  const double e1 = ramp_error(REF_PLL_KP, 0.0f, (double)REF_PLL_W_RAMP, 0.0f, &w_err);
  TT_CHECK_NEAR(e1, asin((double)REF_PLL_W_RAMP / (double)REF_PLL_KP), 1e-3); /* type 1 lags */
}

static void test_limits_reset(void) {
  fw_pll_f32_t p;
  fw_pll_init_f32(&p, REF_PLL_KP, REF_PLL_KI, 10.0f);
  TT_CHECK(p.theta_rad == 0.0f && p.w_i_radps == 0.0f && p.w_hat_radps == 0.0f);
  float w_peak = 0.0f;
  for (int k = 0; k < 24000; k++) {
    const float th = ramp_theta(100.0, k);
    fw_pll_step_f32(&p, (float)sin((double)th - (double)p.theta_rad), REF_PLL_DT);
    TT_CHECK(p.w_i_radps <= 10.0f && p.w_i_radps >= -10.0f);
    w_peak = p.w_i_radps > w_peak ? p.w_i_radps : w_peak;
  }
  TT_CHECK(w_peak == 10.0f); /* saturated: cannot follow 100 rad/s */
  /* w_hat = w_i + kp e after a step */
  fw_pll_reset_f32(&p, 0.5f, 3.0f);
  fw_pll_step_f32(&p, 0.01f, 1e-3f);
  TT_CHECK_NEAR(p.w_i_radps, 3.0 + (double)REF_PLL_KI * 0.01 * 1e-3, 1e-5);
  TT_CHECK_NEAR(p.w_hat_radps, (double)p.w_i_radps + (double)REF_PLL_KP * 0.01, 1e-5);
  TT_CHECK_NEAR(p.theta_rad, 0.5 + (double)p.w_hat_radps * 1e-3, 1e-6);
  /* reset wraps and clamps */
  fw_pll_reset_f32(&p, 4.0f, 50.0f);
  TT_CHECK_NEAR(p.theta_rad, 4.0 - 2.0 * PI_D, 1e-6);
  TT_CHECK(p.w_i_radps == 10.0f && p.w_hat_radps == 10.0f);
  fw_pll_reset_f32(&p, NAN, NAN);
  TT_CHECK(p.theta_rad == 0.0f && p.w_i_radps == 0.0f);
  /* invalid input holds the state */
  fw_pll_reset_f32(&p, 1.0f, 2.0f);
  const fw_pll_f32_t before = p;
  fw_pll_step_f32(&p, NAN, 1e-3f);
  fw_pll_step_f32(&p, 0.1f, -1e-3f);
  fw_pll_step_f32(&p, INFINITY, 1e-3f);
  TT_CHECK(memcmp(&p, &before, sizeof p) == 0);
}

/* eq. 9: i_sin cos(theta_hat) - i_cos sin(theta_hat) = sin(theta - theta_hat) */
static void test_quad_error(void) {
  for (int i = 0; i < 100; i++) {
    const float th = -3.0f + 0.061f * (float)i, th_hat = 0.7f - 0.043f * (float)i;
    const fw_sincos_f32_t t = fw_sincos_f32(th), h = fw_sincos_f32(th_hat);
    TT_CHECK_NEAR(fw_pll_quad_error_f32(t.s, t.c, h), sin((double)th - (double)th_hat), 5e-6);
  }
}

int main(void) {
  TT_RUN(test_step_ref);
  TT_RUN(test_ramp_ref);
  TT_RUN(test_step_shape);
  TT_RUN(test_ramp_zero_error);
  TT_RUN(test_limits_reset);
  TT_RUN(test_quad_error);
  return TT_SUMMARY();
}
