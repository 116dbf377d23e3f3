/* Tests for fw_foc: Clarke + Park against hand-computed values, the current
 * PIs (proportional + integral + decoupling feed-forward, the voltage limit
 * 0.9 u_dc / sqrt(3)), the speed PI, the bumpless speed start, and the output
 * transform (inverse Park at theta + 1.5 w dt, SVPWM line-to-line duties). */
#include <math.h>

#include "pmlsm/fw_foc.h"
#include "tinytest.h"

static fw_foc_param_t params(void) {
  fw_foc_param_t p;
  p.cur_kp_V_per_A = 2.0f;
  p.cur_ki_V_per_As = 100.0f;
  p.spd_kp_A_per_radps = 0.5f;
  p.spd_ki_A_per_rad = 20.0f;
  p.i_max_A = 5.0f;
  p.R_ohm = 1.0f;
  p.L_d_H = 0.01f;
  p.L_q_H = 0.02f;
  p.psi_f_Wb = 0.2f;
  p.dt_s = 1e-3f;
  return p;
}

static void test_clarke_park(void) {
  /* (1, -1/2, -1/2) A -> alpha 1, beta 0; Park at 90 deg -> d 0, q -1 */
  fw_vec2_f32_t ab = fw_clarke_f32(1.0f, -0.5f, -0.5f);
  TT_CHECK_NEAR(ab.x, 1.0, 1e-6);
  TT_CHECK_NEAR(ab.y, 0.0, 1e-6);
  fw_vec2_f32_t dq = fw_foc_measure(ab, fw_sincos_f32((float)(M_PI / 2.0)));
  TT_CHECK_NEAR(dq.x, 0.0, 1e-6);
  TT_CHECK_NEAR(dq.y, -1.0, 1e-6);
  /* (0, sqrt(3)/2, -sqrt(3)/2) A -> alpha 0, beta 1; Park at 30 deg -> d 1/2, q sqrt(3)/2 */
  const float h = 0.8660254f;
  ab = fw_clarke_f32(0.0f, h, -h);
  TT_CHECK_NEAR(ab.x, 0.0, 1e-6);
  TT_CHECK_NEAR(ab.y, 1.0, 1e-6);
  dq = fw_foc_measure(ab, fw_sincos_f32((float)(M_PI / 6.0)));
  TT_CHECK_NEAR(dq.x, 0.5, 1e-6);
  TT_CHECK_NEAR(dq.y, 0.8660254, 1e-6);
  /* a balanced set I cos(th - 2 pi m / 3) at th seen at th - phi: (I cos phi, I sin phi) */
  const double I = 3.0, th = 2.1, phi = 0.3;
  ab = fw_clarke_f32((float)(I * cos(th)), (float)(I * cos(th - 2.0 * M_PI / 3.0)),
                     (float)(I * cos(th + 2.0 * M_PI / 3.0)));
  dq = fw_foc_measure(ab, fw_sincos_f32((float)(th - phi)));
  TT_CHECK_NEAR(dq.x, I * cos(phi), 1e-5);
  TT_CHECK_NEAR(dq.y, I * sin(phi), 1e-5);
}

static void test_current_pi(void) {
  const fw_foc_param_t p = params();
  fw_foc_t f;
  fw_foc_init(&f, &p);
  /* dt = 1e-3 s (params); w = 0: u = kp e + ki e dt per axis */
  fw_vec2_f32_t i_ref = {1.0f, -0.5f}, i = {0.0f, 0.0f};
  fw_vec2_f32_t u = fw_foc_current_update(&f, i_ref, i, 0.0f, 300.0f);
  TT_CHECK_NEAR(u.x, 2.0 * 1.0 + 100.0 * 1.0 * 1e-3, 1e-5);
  TT_CHECK_NEAR(u.y, 2.0 * -0.5 + 100.0 * -0.5 * 1e-3, 1e-5);
  /* second period: the integral doubles */
  u = fw_foc_current_update(&f, i_ref, i, 0.0f, 300.0f);
  TT_CHECK_NEAR(u.x, 2.0 + 2.0 * 0.1, 1e-5);
  /* decoupling: zero error, w = 100: u_d = -w L_q i_q, u_q = w (L_d i_d + psi_f) */
  fw_foc_reset(&f, &p);
  i.x = 0.5f;
  i.y = 1.5f;
  u = fw_foc_current_update(&f, i, i, 100.0f, 300.0f);
  TT_CHECK_NEAR(u.x, -100.0 * 0.02 * 1.5, 1e-5);
  TT_CHECK_NEAR(u.y, 100.0 * (0.01 * 0.5 + 0.2), 1e-5);
  /* limit: +-0.9 u_dc / sqrt(3) */
  fw_foc_reset(&f, &p);
  i_ref.x = 1000.0f;
  i_ref.y = -1000.0f;
  i.x = i.y = 0.0f;
  u = fw_foc_current_update(&f, i_ref, i, 0.0f, 100.0f);
  const double lim = 0.9 * 100.0 / sqrt(3.0);
  TT_CHECK_NEAR(u.x, lim, 1e-4);
  TT_CHECK_NEAR(u.y, -lim, 1e-4);
  /* commit: the applied voltage of the next period */
  fw_foc_commit(&f, u);
  TT_CHECK(fw_foc_u_applied(&f)[0] == u.x && fw_foc_u_applied(&f)[1] == u.y);
  fw_foc_reset(&f, &p);
  TT_CHECK(fw_foc_u_applied(&f)[0] == 0.0f && fw_foc_u_applied(&f)[1] == 0.0f);
}

static void test_speed_pi(void) {
  const fw_foc_param_t p = params();
  fw_foc_t f;
  fw_foc_init(&f, &p);
  /* i_q = kp e + ki e dt */
  TT_CHECK_NEAR(fw_foc_speed_update(&f, 10.0f, 8.0f), 0.5 * 2.0 + 20.0 * 2.0 * 1e-3, 1e-6);
  /* clamped to i_max */
  TT_CHECK_NEAR(fw_foc_speed_update(&f, 100.0f, 0.0f), 5.0, 1e-6);
  /* bumpless: the integrator starts from the committed i_q reference ... */
  fw_foc_reset(&f, &p);
  fw_foc_commit_ref(&f, 1.25f);
  fw_foc_speed_bumpless(&f);
  TT_CHECK_NEAR(fw_foc_speed_update(&f, 0.0f, 0.0f), 1.25, 1e-6);
  /* ... clamped to i_max; kept over a reset */
  fw_foc_commit_ref(&f, -7.0f);
  fw_foc_reset(&f, &p);
  fw_foc_speed_bumpless(&f);
  TT_CHECK_NEAR(fw_foc_speed_update(&f, 0.0f, 0.0f), -5.0, 1e-6);
  fw_foc_speed_clear(&f);
  TT_CHECK_NEAR(fw_foc_speed_update(&f, 0.0f, 0.0f), 0.0, 1e-9);
}

static void test_output(void) {
  /* u_dq = (20, 30) V at theta 0.4 rad, w 500 rad/s, dt 1/24000: the angle used
   * is 0.4 + 1.5 * 500 / 24000; line-to-line duties (d_a - d_b) u_dc = u_a - u_b */
  const float th = 0.4f, w = 500.0f, dt = 1.0f / 24000.0f, u_dc = 300.0f;
  const fw_vec2_f32_t u_dq = {20.0f, 30.0f};
  float duty[3];
  const fw_sincos_f32_t sc = fw_foc_output(u_dq, fw_sincos_f32(th), th, w, dt, u_dc, duty);
  const double a = 0.4 + 1.5 * 500.0 / 24000.0;
  TT_CHECK_NEAR(sc.s, sin(a), 2e-6);
  TT_CHECK_NEAR(sc.c, cos(a), 2e-6);
  const double ua = 20.0 * cos(a) - 30.0 * sin(a), ub = 20.0 * sin(a) + 30.0 * cos(a);
  const double u_a = ua, u_b = -0.5 * ua + 0.5 * sqrt(3.0) * ub, u_c = -0.5 * ua - 0.5 * sqrt(3.0) * ub;
  TT_CHECK_NEAR((duty[0] - duty[1]) * u_dc, u_a - u_b, 1e-3);
  TT_CHECK_NEAR((duty[1] - duty[2]) * u_dc, u_b - u_c, 1e-3);
  for (int k = 0; k < 3; k++) {
    TT_CHECK(duty[k] >= 0.0f && duty[k] <= 1.0f);
  }
}

int main(void) {
  TT_RUN(test_clarke_park);
  TT_RUN(test_current_pi);
  TT_RUN(test_speed_pi);
  TT_RUN(test_output);
  return TT_SUMMARY();
}
