/* Tests for fw_start: the end of the alignment (time and injection index
 * n/4 - 1), the saliency check's schedule (d^ then q^, first period of each
 * not averaged) and means, the polarity test's voltage pattern, timing and
 * decision, and the flying-start catch on a synthetic rotating back-EMF
 * (angle and speed against e_ab = w psi_f (-sin th, cos th)). */
#include <math.h>
#include <stddef.h>
#include <string.h>

#include "pmlsm/fw_config.h"
#include "pmlsm/fw_start.h"
#include "tinytest.h"

static void test_align_done(void) {
  fw_config_t cfg;
  fw_config_default(&cfg); /* align 0.08 s, n_inj 8: last index 1 */
  TT_CHECK(!fw_start_align_done(&cfg.estimator, 0.079f, 1u, 8u));
  TT_CHECK(fw_start_align_done(&cfg.estimator, 0.08f, 1u, 8u));
  TT_CHECK(!fw_start_align_done(&cfg.estimator, 0.09f, 2u, 8u));
  TT_CHECK(fw_start_align_done(&cfg.estimator, 0.09f, 3u, 16u));
  TT_CHECK(fw_start_align_done(&cfg.estimator, 0.09f, 0u, 2u)); /* n/4 = 0: index 0 */
}

static void test_saliency(void) {
  fw_start_t s;
  fw_start_reset(&s);
  fw_start_saliency_begin(&s);
  const uint32_t n = 8u, col = FW_SAL_PERIODS * n;
  int done_at = -1;
  for (uint32_t k = 0; k < 2u * col; k++) {
    const bool on_q = k >= col;
    TT_CHECK(fw_start_saliency_on_q(&s, n) == on_q);
    /* the first period of each axis carries junk that must not count */
    const bool first = (k % col) < n;
    fw_vec2_f32_t e;
    e.x = first ? 100.0f : (on_q ? 3.0f : 1.0f);
    e.y = first ? -100.0f : (on_q ? 4.0f : 2.0f);
    fw_start_saliency_update(&s, n, e);
    if (fw_start_saliency_advance(&s, n) && done_at < 0) {
      done_at = (int)k;
    }
  }
  TT_CHECK(done_at == (int)(2u * col - 1u));
  float y[4];
  fw_start_saliency_means(&s, n, y);
  TT_CHECK_NEAR(y[0], 1.0, 1e-6);
  TT_CHECK_NEAR(y[1], 2.0, 1e-6);
  TT_CHECK_NEAR(y[2], 3.0, 1e-6);
  TT_CHECK_NEAR(y[3], 4.0, 1e-6);
}

/* Synthetic d^ current: each excursion rises linearly to +peak_pos (+ pulse)
 * or falls to -peak_neg (- pulse) and returns; 0 elsewhere. */
static fw_pol_result_t run_polarity(float peak_pos, float peak_neg, uint32_t *steps,
                                    fw_start_t *s) {
  fw_config_t cfg;
  fw_config_default(&cfg); /* N = 12, 4 pairs, margin */
  const uint32_t N = cfg.estimator.pol_pulse_samples;
  fw_start_reset(s);
  fw_start_polarity_begin(s);
  fw_pol_result_t res = FW_POL_BUSY;
  uint32_t k = 0;
  float v_prev = 0.0f, i_d = 0.0f;
  int bad_v = 0;
  for (; k < 10000u && res == FW_POL_BUSY; k++) {
    /* the current follows the voltage of the previous sample */
    const float peak = v_prev > 0.0f ? peak_pos : peak_neg;
    i_d += v_prev / cfg.estimator.pol_pulse_V * peak / (float)N;
    const float v = fw_start_polarity_step(s, &cfg.estimator, i_d, &res);
    if (res == FW_POL_BUSY) {
      const uint32_t seg = (k % (6u * N)) / N;
      const float want = (seg == 1u || seg == 5u) ? cfg.estimator.pol_pulse_V
                         : (seg == 2u || seg == 4u) ? -cfg.estimator.pol_pulse_V : 0.0f;
      bad_v += v != want;
    } else {
      bad_v += v != 0.0f;
    }
    v_prev = v;
  }
  TT_CHECK(bad_v == 0);
  *steps = k;
  return res;
}

static void test_polarity(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  const uint32_t total = 6u * cfg.estimator.pol_pulse_samples * cfg.estimator.pol_pulse_pairs;
  fw_start_t s;
  uint32_t steps;
  /* the + excursion (along the magnet) larger: estimate right */
  TT_CHECK(run_polarity(2.0f, 1.5f, &steps, &s) == FW_POL_ALIGNED);
  TT_CHECK(steps == total + 1u);
  /* each pair adds its excursion: the sums are pairs x peak */
  TT_CHECK_NEAR(s.pol_sum_pos, 4.0 * 2.0, 1e-4);
  TT_CHECK_NEAR(s.pol_sum_neg, 4.0 * 1.5, 1e-4);
  TT_CHECK(run_polarity(1.5f, 2.0f, &steps, &s) == FW_POL_FLIPPED);
  /* within the margin: undetermined */
  const float m = 1.0f + 0.5f * cfg.estimator.pol_margin;
  TT_CHECK(run_polarity(2.0f * m, 2.0f, &steps, &s) == FW_POL_UNDETERMINED);
}

static void test_fly_catch(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  const float dt = 1.0f / cfg.sensing.f_pwm_Hz;
  const float psi = cfg.machine.psi_f_Wb;
  for (int dir = -1; dir <= 1; dir += 2) {
    fw_start_t s;
    fw_start_init(&s, dt);
    const double w = dir * 400.0; /* el. rad/s: |e| = 73 V */
    double th = 0.3;
    const fw_vec2_f32_t i0 = {0.0f, 0.0f};
    float t = 0.0f;
    for (int k = 0; k < 360; k++) { /* 15 ms at zero current: e_ab = u_ab */
      t += dt;
      fw_start_fly_flush(&s); /* the last step of the rotation (the supervision's) */
      fw_start_fly_observe(&s, &cfg.machine, i0, t);
      th += w * (double)dt;
      const fw_vec2_f32_t u = {(float)(-w * psi * sin(th)), (float)(w * psi * cos(th))};
      fw_start_fly_set_u(&s, u);
    }
    float th_hat, w0;
    TT_CHECK(fw_start_fly_catch(&s, &cfg, 0.0f, &th_hat, &w0) == FW_FAULT_MOVING_AT_ENABLE);
    TT_CHECK(s.flying == 0u);
    TT_CHECK(fw_start_fly_catch(&s, &cfg, 100.0f, &th_hat, &w0) == FW_FAULT_NONE);
    TT_CHECK(s.flying == 1u);
    /* first-order lag tau: |H| = 1 / sqrt(1 + (w tau)^2); the voltage acts one
     * period later, the catch adds w tau for the filter's lag */
    const double wt = w * FW_FLY_TAU_S;
    TT_CHECK_NEAR(w0, w / sqrt(1.0 + wt * wt), 0.01 * fabs(w));
    double err = fmod((double)th_hat - (th - w * (double)dt) + 3.0 * M_PI, 2.0 * M_PI) - M_PI;
    TT_CHECK_NEAR(err, 0.0, 0.02);
  }
  /* standing still: refused */
  fw_start_t s;
  fw_start_init(&s, dt);
  /* the configuration: exp(-T/tau) in double; a reset keeps it and clears the rest */
  TT_CHECK_NEAR(s.fly_a, 1.0 - exp(-(double)dt / FW_FLY_TAU_S), 1e-6);
  TT_CHECK_NEAR(s.inv_dt, (double)cfg.sensing.f_pwm_Hz, 1e-3);
  const float fly_a = s.fly_a, inv_dt = s.inv_dt;
  s.fly_e_ab_V[0] = 5.0f;
  s.fly_rot_rad = 1.0f;
  fw_start_reset(&s);
  TT_CHECK(s.fly_a == fly_a && s.inv_dt == inv_dt);
  TT_CHECK(s.fly_e_ab_V[0] == 0.0f && s.fly_rot_rad == 0.0f);
  float th_hat, w0;
  TT_CHECK(fw_start_fly_catch(&s, &cfg, 100.0f, &th_hat, &w0) == FW_FAULT_MOVING_AT_ENABLE);
}

/* The catch in two parts: fw_start_fly_catch_speed with this period's rotation
 * step still due decides and finds the same speed as with the step added first,
 * bit for bit, whether it adds the step (near the 0.05 rad threshold, a step
 * that could change the rotation's sign, a non-finite step) or leaves it to
 * fw_start_fly_flush; the state is then the same; fw_start_fly_catch is the two
 * parts. */
static void test_fly_catch_parts(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  const float dt = 1.0f / cfg.sensing.f_pwm_Hz;
  uint32_t st = 2024u;
  int bad = 0, left_due = 0, added = 0, near = 0, caught = 0;
  for (int t = 0; t < 200000; t++) {
    fw_start_t a;
    fw_start_init(&a, dt);
    /* the rotation so far (one step from 0: fw_start_fly_add forms its margin) */
    const float r0 = t % 4 == 0 ? tt_rng_f(&st, -0.08f, 0.08f) : tt_rng_f(&st, -3.1f, 3.1f);
    near += fabsf(r0) < 0.08f;
    a.fly_cr = sinf(r0);
    a.fly_dot = cosf(r0);
    fw_start_fly_add(&a);
    /* this period's step, due: mostly small, some large, some backwards or not finite */
    const float step = t % 7 == 0 ? tt_rng_f(&st, -3.1f, 3.1f) : tt_rng_f(&st, -0.06f, 0.06f);
    const float mag = tt_rng_f(&st, 1e-3f, 100.0f);
    a.fly_cr = mag * sinf(step);
    a.fly_dot = mag * cosf(step);
    if (t % 997 == 0) {
      a.fly_dot = NAN;
    } else if (t % 991 == 0) {
      a.fly_cr = INFINITY;
    }
    a.fly_due = 1u;
    a.fly_e_ab_V[0] = tt_rng_f(&st, -80.0f, 80.0f);
    a.fly_e_ab_V[1] = tt_rng_f(&st, -80.0f, 80.0f);
    fw_start_t b = a, c = a;
    float w_a = -1.0f, w_b = -1.0f, th_c = -1.0f, w_c = -1.0f;
    fw_start_fly_flush(&a); /* the step first: the decision on the full rotation */
    const fw_fault_t fa = fw_start_fly_catch_speed(&a, &cfg, 100.0f, &w_a);
    const fw_fault_t fb = fw_start_fly_catch_speed(&b, &cfg, 100.0f, &w_b);
    left_due += b.fly_due;
    added += !b.fly_due;
    fw_start_fly_flush(&b);
    bad += fa != fb || memcmp(&w_a, &w_b, sizeof w_a) != 0 || memcmp(&a, &b, sizeof a) != 0;
    const fw_fault_t fc = fw_start_fly_catch(&c, &cfg, 100.0f, &th_c, &w_c);
    bad += fc != fa || memcmp(&c, &a, sizeof a) != 0;
    if (fa == FW_FAULT_NONE) {
      caught++;
      const float th_a = fw_start_fly_catch_angle(&a, w_a);
      bad += memcmp(&th_a, &th_c, sizeof th_a) != 0 || memcmp(&w_c, &w_a, sizeof w_a) != 0;
    }
  }
  printf("  200000 catches (%d near the threshold, %d caught): step left due %d, added %d\n", near,
         caught, left_due, added);
  TT_CHECK(bad == 0);
  TT_CHECK(left_due > 50000 && added > 20000 && caught > 50000);
}

/* fw_start_reset clears every field but the configured ones (field by field:
 * compared with a fresh block, the padding aside). */
static void test_reset_clears_all(void) {
  fw_start_t a, b;
  fw_start_init(&b, 1.0f / 24000.0f);
  memset(&a, 0x5a, sizeof a);
  a.fly_a = b.fly_a;
  a.inv_dt = b.inv_dt;
  fw_start_reset(&a);
  /* the padding: after sal_retries up to fly_a, after fly_due to the end */
  const size_t p0 = offsetof(fw_start_t, sal_retries) + 1u, p1 = offsetof(fw_start_t, fly_a);
  const size_t p2 = offsetof(fw_start_t, fly_due) + 1u;
  memset((char *)&a + p0, 0, p1 - p0);
  memset((char *)&a + p2, 0, sizeof a - p2);
  TT_CHECK(memcmp(&a, &b, sizeof a) == 0);
}

/* The polarity test's decision without the division: pulses are over exactly
 * when pol_k / (6 n) >= pairs, up to the largest counts. */
static void test_polarity_decision(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  const uint32_t ns[] = {1u, 7u, 12u, 1000u}, pairs[] = {1u, 3u, 4u, 64u};
  int bad = 0, n_checked = 0;
  for (int i = 0; i < 4; i++) {
    for (int j = 0; j < 4; j++) {
      cfg.estimator.pol_pulse_samples = ns[i];
      cfg.estimator.pol_pulse_pairs = pairs[j];
      const uint32_t per_pair = 6u * ns[i], edge = per_pair * pairs[j];
      const uint32_t ks[] = {0u,          1u,         edge - 2u,       edge - 1u,
                             edge,        edge + 1u,  edge + per_pair, 0x7fffffffu,
                             0xfffffffeu, 0xffffffffu};
      for (int q = 0; q < 10; q++) {
        fw_start_t s;
        fw_start_init(&s, 1.0f / 24000.0f);
        fw_start_polarity_begin(&s);
        s.pol_k = ks[q];
        fw_pol_result_t res;
        (void)fw_start_polarity_step(&s, &cfg.estimator, 0.0f, &res);
        bad += (res != FW_POL_BUSY) != (ks[q] / per_pair >= pairs[j]);
        n_checked++;
      }
    }
  }
  TT_CHECK(n_checked == 160 && bad == 0);
}

int main(void) {
  TT_RUN(test_align_done);
  TT_RUN(test_saliency);
  TT_RUN(test_polarity);
  TT_RUN(test_fly_catch);
  TT_RUN(test_fly_catch_parts);
  TT_RUN(test_reset_clears_all);
  TT_RUN(test_polarity_decision);
  return TT_SUMMARY();
}
