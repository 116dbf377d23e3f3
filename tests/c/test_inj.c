/* Tests for fw_inj: the square-wave sign sequence and its history (the sign
 * that acted over the last sampled interval is the one commanded two periods
 * before), the demodulation of an ideal inductive HF response against
 * E_d = a cos(dtheta), E_q = a sin(dtheta) (a = T u / L per sample), the
 * pseudo-filter's fundamental (one-period mean), the SOGI group delay and k
 * handling, the adaptive k, and the restart of the averages on an extractor
 * switch. */
#include <math.h>
#include <string.h>

#include "pmlsm/fw_config.h"
#include "pmlsm/fw_inj.h"
#include "tinytest.h"

static void init(fw_inj_t *j, fw_config_t *cfg, fw_extractor_t ex) {
  fw_config_default(cfg); /* 24 kHz / 3 kHz: n_inj = 8 */
  cfg->estimator.extractor = (uint32_t)ex;
  fw_inj_init(j, cfg, 1.0f / cfg->sensing.f_pwm_Hz);
}

static void test_signs(void) {
  fw_config_t cfg;
  fw_inj_t j;
  init(&j, &cfg, FW_EXTRACTOR_PSEUDO);
  TT_CHECK(j.n_inj == 8u);
  TT_CHECK_NEAR(j.inv_n_inj, 0.125, 0.0);
  const float want[16] = {1, 1, 1, 1, -1, -1, -1, -1, 1, 1, 1, 1, -1, -1, -1, -1};
  float hist[16];
  for (int k = 0; k < 16; k++) {
    hist[k] = fw_inj_output(&j, true);
    TT_CHECK(hist[k] == want[k]);
    /* after commanding s(k), the sign that acts over the next sampled interval
     * is s(k-1): fw_inj_sign_applied at the next sample */
    TT_CHECK(fw_inj_sign_applied(&j) == (k >= 1 ? hist[k - 1] : 0.0f));
  }
  /* off: 0, the injection phase does not advance */
  const uint32_t idx = j.inj_idx;
  TT_CHECK(fw_inj_output(&j, false) == 0.0f && j.inj_idx == idx);
  TT_CHECK(fw_inj_output(&j, true) == want[idx]);
}

/* Ideal response of an inductance seen along angle th: the current changes by
 * a s(k-2) (cos th, sin th) per sample (one-period update delay). */
static void run_ideal(fw_inj_t *j, fw_extractor_t ex, float th, float th_hat, float a, int n,
                      fw_inj_meas_t *m, double *mean_ia) {
  fw_vec2_f32_t i = {0.3f, -0.2f}; /* fundamental offset */
  const fw_sincos_f32_t sc = fw_sincos_f32(th_hat);
  double acc = 0.0;
  for (int k = 0; k < n; k++) {
    const float s = fw_inj_sign_applied(j);
    i.x += a * s * cosf(th);
    i.y += a * s * sinf(th);
    fw_inj_update(j, ex, i, sc, th_hat, 0.0f, m);
    (void)fw_inj_output(j, true);
    if (k >= n - 8) {
      acc += (double)i.x;
    }
  }
  *mean_ia = acc / 8.0;
}

static void test_demodulation_pseudo(void) {
  fw_config_t cfg;
  fw_inj_t j;
  init(&j, &cfg, FW_EXTRACTOR_PSEUDO);
  const float a = 0.05f, th = 0.7f, dth = 0.2f;
  fw_inj_meas_t m;
  double mean_ia;
  run_ideal(&j, FW_EXTRACTOR_PSEUDO, th, th - dth, a, 64, &m, &mean_ia);
  TT_CHECK(fw_inj_settled(&j));
  TT_CHECK_NEAR(m.E_d_A, a * cos(dth), 1e-6);
  TT_CHECK_NEAR(m.E_q_A, a * sin(dth), 1e-6);
  /* the raw difference in the sampling frame, demodulated: same per sample */
  TT_CHECK_NEAR(m.e_raw_dq_A.x, a * cos(dth), 1e-6);
  TT_CHECK_NEAR(m.e_raw_dq_A.y, a * sin(dth), 1e-6);
  /* fundamental = one-period mean of the measured current */
  TT_CHECK_NEAR(m.i_f_ab_A.x, mean_ia, 1e-6);
  /* telemetry: the difference itself */
  TT_CHECK_NEAR(fabs(m.i_h_ab_A.x), a * cos(th), 1e-6);
}

static void test_demodulation_sogi(void) {
  /* the SOGI passes the carrier's fundamental; the averaged E_d/E_q of a
   * triangle response keep their ratio tan(dtheta) */
  fw_config_t cfg;
  fw_inj_t j;
  init(&j, &cfg, FW_EXTRACTOR_SOGI);
  const float a = 0.05f, th = -1.1f, dth = -0.15f;
  fw_inj_meas_t m;
  double mean_ia;
  run_ideal(&j, FW_EXTRACTOR_SOGI, th, th - dth, a, 2400, &m, &mean_ia);
  TT_CHECK(m.E_d_A > 0.5f * a);
  TT_CHECK_NEAR(atan2(m.E_q_A, m.E_d_A), dth, 2e-3);
  /* fundamental = measured - extracted */
  TT_CHECK_NEAR(m.i_f_ab_A.x + m.i_h_ab_A.x, j.h_prev_raw[0], 1e-6);
}

static void test_group_delay_and_k(void) {
  fw_config_t cfg;
  fw_inj_t j;
  init(&j, &cfg, FW_EXTRACTOR_SOGI);
  /* pre-warped SOGI: 2/(k w0) * (w0 T/2) sec^2(w0 T/2) / tan(w0 T/2) */
  const double w0 = 2.0 * M_PI * 3000.0, h = 0.5 * w0 / 24000.0, t = tan(h);
  const double gd_k = (2.0 / w0) * h * (1.0 + t * t) / t;
  TT_CHECK_NEAR(j.sogi_gd_s_k, gd_k, 1e-9);
  TT_CHECK_NEAR(fw_inj_k(&j), cfg.estimator.sogi_k, 0.0);
  TT_CHECK_NEAR(j.sogi_gd_s, gd_k / (double)cfg.estimator.sogi_k, 1e-9);
  fw_inj_set_k(&j, 0.8f);
  TT_CHECK(j.sogi_a.k == 0.8f && j.sogi_b.k == 0.8f && j.sogi_b.p == j.sogi_a.p);
  TT_CHECK_NEAR(j.sogi_gd_s, gd_k / 0.8, 1e-9);
  /* adaptive: k = kmin + (kmax - kmin) r, changed only beyond the step */
  fw_inj_adapt(&j, &cfg.estimator, 1.0f);
  TT_CHECK_NEAR(fw_inj_k(&j), cfg.estimator.sogi_k_adapt_max, 1e-7);
  fw_inj_adapt(&j, &cfg.estimator, 0.0f);
  TT_CHECK_NEAR(fw_inj_k(&j), cfg.estimator.sogi_k_adapt_min, 1e-7);
  const float k0 = fw_inj_k(&j);
  const float r_small = 0.5f * FW_INJ_SOGI_K_STEP /
                        (cfg.estimator.sogi_k_adapt_max - cfg.estimator.sogi_k_adapt_min);
  fw_inj_adapt(&j, &cfg.estimator, r_small);
  TT_CHECK(fw_inj_k(&j) == k0);
  /* extractor switch: k of the new path, averages restart */
  fw_inj_meas_t m;
  double mean_ia;
  run_ideal(&j, FW_EXTRACTOR_SOGI, 0.0f, 0.0f, 0.01f, 20, &m, &mean_ia);
  TT_CHECK(fw_inj_settled(&j));
  fw_inj_set_extractor(&j, &cfg.estimator, FW_EXTRACTOR_SOGI_ADAPTIVE);
  TT_CHECK(j.ring_fill == 0u && j.sum_ed == 0.0f && !fw_inj_settled(&j));
  TT_CHECK_NEAR(fw_inj_k(&j), cfg.estimator.sogi_k_adapt_max, 1e-7);
  /* reset: k by the configured extractor, histories cleared */
  fw_inj_reset(&j, &cfg.estimator);
  TT_CHECK_NEAR(fw_inj_k(&j), cfg.estimator.sogi_k, 0.0);
  TT_CHECK(j.inj_idx == 0u && fw_inj_sign_applied(&j) == 0.0f && j.h_prev_raw[0] == 0.0f);
}

/* A reset (every enable, and the handover to closed loop) gives what a fresh
 * fw_inj_init gives, without the SOGIs' tanf and without clearing the ring:
 * for each extractor, a block that ran (its SOGI gain moved, its ring full)
 * and then had its ring filled with NaN is reset and fed the same samples as a
 * fresh block; every output is the same bit for bit, so no stale row is read. */
static void test_reset_equals_init(void) {
  for (int e = 0; e < 3; e++) {
    const fw_extractor_t ex = e == 0   ? FW_EXTRACTOR_PSEUDO
                              : e == 1 ? FW_EXTRACTOR_SOGI
                                       : FW_EXTRACTOR_SOGI_ADAPTIVE;
    fw_config_t cfg;
    static fw_inj_t used, fresh;
    fw_inj_meas_t m;
    double mean;
    init(&used, &cfg, ex);
    run_ideal(&used, ex, 0.4f, 0.1f, 0.02f, 37, &m, &mean);
    fw_inj_set_k(&used, 0.9f * cfg.estimator.sogi_k_adapt_min + 0.01f);
    for (uint32_t r = 0; r < FW_INJ_MAX_SAMPLES; r++) {
      for (int col = 0; col < 4; col++) {
        used.ring[r][col] = NAN;
      }
    }
    fw_inj_reset(&used, &cfg.estimator);
    init(&fresh, &cfg, ex);
    TT_CHECK(memcmp(&used.sogi_a, &fresh.sogi_a, sizeof used.sogi_a) == 0);
    TT_CHECK(memcmp(&used.sogi_b, &fresh.sogi_b, sizeof used.sogi_b) == 0);
    TT_CHECK(used.sogi_gd_s == fresh.sogi_gd_s && used.inj_idx == 0u && used.ring_fill == 0u);
    fw_inj_meas_t mu, mf;
    double mean_u, mean_f;
    bool same = true;
    for (int n = 1; n <= 40; n++) { /* past one full ring (8 samples) five times */
      run_ideal(&used, ex, -0.7f, -0.5f, 0.02f, 1, &mu, &mean_u);
      run_ideal(&fresh, ex, -0.7f, -0.5f, 0.02f, 1, &mf, &mean_f);
      same = same && memcmp(&mu, &mf, sizeof mu) == 0 && isfinite(mu.E_d_A);
    }
    TT_CHECK(same);
  }
}

/* A reset to the configured extractor's gain restores the gains fw_inj_init
 * computed for it: the same, bit for bit, as fw_inj_set_k of that gain on the
 * filters however their gain moved since; a reset to another gain (the extractor
 * switched since the configuration) computes them. */
static void test_reset_gains(void) {
  for (int e = 1; e < 3; e++) {
    const fw_extractor_t ex = e == 1 ? FW_EXTRACTOR_SOGI : FW_EXTRACTOR_SOGI_ADAPTIVE;
    fw_config_t cfg;
    static fw_inj_t j, ref;
    init(&j, &cfg, ex);
    const float k_cfg =
        ex == FW_EXTRACTOR_SOGI ? cfg.estimator.sogi_k : cfg.estimator.sogi_k_adapt_max;
    TT_CHECK(j.k_reset == k_cfg);
    for (int n = 0; n < 5; n++) {
      fw_inj_set_k(&j, 0.3f + 0.25f * (float)n); /* the adaptation moved it */
      fw_inj_reset(&j, &cfg.estimator);
      ref = j;
      fw_inj_set_k(&ref, k_cfg);
      TT_CHECK(memcmp(&j.sogi_a, &ref.sogi_a, sizeof j.sogi_a) == 0);
      TT_CHECK(memcmp(&j.sogi_b, &ref.sogi_b, sizeof j.sogi_b) == 0);
      TT_CHECK(memcmp(&j.sogi_gd_s, &ref.sogi_gd_s, sizeof j.sogi_gd_s) == 0);
    }
    /* the other extractor's gain: computed */
    fw_cfg_estimator_t other = cfg.estimator;
    other.extractor =
        (uint32_t)(ex == FW_EXTRACTOR_SOGI ? FW_EXTRACTOR_SOGI_ADAPTIVE : FW_EXTRACTOR_SOGI);
    const float k_other =
        ex == FW_EXTRACTOR_SOGI ? cfg.estimator.sogi_k_adapt_max : cfg.estimator.sogi_k;
    fw_inj_reset(&j, &other);
    ref = j;
    fw_inj_set_k(&ref, k_other);
    TT_CHECK(j.sogi_a.k == k_other);
    TT_CHECK(memcmp(&j.sogi_a, &ref.sogi_a, sizeof j.sogi_a) == 0 &&
             memcmp(&j.sogi_b, &ref.sogi_b, sizeof j.sogi_b) == 0 && j.sogi_gd_s == ref.sogi_gd_s);
  }
}

int main(void) {
  TT_RUN(test_reset_equals_init);
  TT_RUN(test_reset_gains);
  TT_RUN(test_signs);
  TT_RUN(test_demodulation_pseudo);
  TT_RUN(test_demodulation_sogi);
  TT_RUN(test_group_delay_and_k);
  return TT_SUMMARY();
}
