/**
 * @file fw_inj.c
 * @brief Square-wave injection and HF current extraction (see fw_inj.h).
 */
#include <math.h>
#include <string.h>

#include "pmlsm/fw_inj.h"

/** The SOGI gain after a reset: the adaptive extractor starts at its largest. */
static float reset_k(const fw_cfg_estimator_t *est) {
  return est->extractor == (uint32_t)FW_EXTRACTOR_SOGI_ADAPTIVE ? est->sogi_k_adapt_max
                                                                : est->sogi_k;
}

void fw_inj_init(fw_inj_t *j, const fw_config_t *cfg, float dt_s) {
  j->dt_s = dt_s;
  j->n_inj = (uint32_t)(cfg->sensing.f_pwm_Hz / cfg->estimator.f_inj_Hz + 0.5f);
  j->bumpless = (uint8_t)(cfg->compensation.sogi_bumpless != 0u);
  j->inv_n_inj = 1.0f / (float)j->n_inj;
  /* Group delay of the pre-warped discrete SOGI at its centre: the analog
   * 2/(k w0) times the warping slope dW/dw = (w0 T/2) sec^2(w0 T/2) / tan(w0 T/2). */
  const float w0 = FW_TWO_PI_F32 * cfg->estimator.f_inj_Hz;
  const float h = 0.5f * w0 * dt_s;
  const float t = tanf(h);
  j->sogi_gd_s_k = (2.0f / w0) * h * (1.0f + t * t) / t;
  /* the SOGIs' centre frequency (a tanf) once, with the gain a reset gives
   * them; a reset sets only the gain */
  const fw_cfg_estimator_t *est = &cfg->estimator;
  const float k = reset_k(est);
  (void)fw_sogi_init_f32(&j->sogi_a, est->f_inj_Hz, k, dt_s);
  (void)fw_sogi_init_f32(&j->sogi_b, est->f_inj_Hz, k, dt_s);
  /* the gains a reset to k gives (fw_inj_set_k: a function of k and of the
   * filters' constants, which only this function sets), kept for fw_inj_reset */
  fw_inj_set_k(j, k);
  j->k_reset = k;
  j->gain_reset[0] = j->sogi_a.k;
  j->gain_reset[1] = j->sogi_a.p;
  j->gain_reset[2] = j->sogi_a.q;
  j->gain_reset[3] = j->sogi_a.r;
  j->gain_reset[4] = j->sogi_b.k;
  j->gain_reset[5] = j->sogi_b.p;
  j->gain_reset[6] = j->sogi_b.q;
  j->gain_reset[7] = j->sogi_b.r;
  j->gd_reset = j->sogi_gd_s;
  /* once: after a reset every row is written before it is read (ring_fill) */
  memset(j->ring, 0, sizeof(j->ring));
  fw_inj_reset(j, est);
}

static void restart_averages(fw_inj_t *j) {
  j->ring_idx = 0u;
  j->ring_fill = 0u;
  j->sum_ed = j->sum_eq = j->sum_ia = j->sum_ib = 0.0f;
}

void fw_inj_reset(fw_inj_t *j, const fw_cfg_estimator_t *est) {
  const float k = reset_k(est);
  /* what fw_sogi_init_f32 with k would give on the filters fw_inj_init set up
   * (the same gains from the same k, the state cleared), without its tanf; a
   * filter the configuration left uninitialised stays a zero-output one */
  fw_sogi_reset_f32(&j->sogi_a);
  fw_sogi_reset_f32(&j->sogi_b);
  if (k == j->k_reset) { /* the configured extractor's: what fw_inj_set_k(k) gives */
    j->sogi_a.k = j->gain_reset[0];
    j->sogi_a.p = j->gain_reset[1];
    j->sogi_a.q = j->gain_reset[2];
    j->sogi_a.r = j->gain_reset[3];
    j->sogi_b.k = j->gain_reset[4];
    j->sogi_b.p = j->gain_reset[5];
    j->sogi_b.q = j->gain_reset[6];
    j->sogi_b.r = j->gain_reset[7];
    j->sogi_gd_s = j->gd_reset;
  } else { /* another extractor set since (fw_inj_set_extractor), or a NaN k */
    fw_inj_set_k(j, k);
  }
  memset(j->h_prev_raw, 0, sizeof(j->h_prev_raw));
  memset(j->h_prev_sogi, 0, sizeof(j->h_prev_sogi));
  memset(j->sign_hist, 0, sizeof(j->sign_hist));
  restart_averages(j); /* the ring's rows are rewritten before they are read */
  j->inj_idx = 0u;
}

void fw_inj_set_k(fw_inj_t *j, float k) {
  fw_sogi_set_k_f32(&j->sogi_a, k);
  fw_sogi_copy_gain_f32(&j->sogi_b, &j->sogi_a);
  j->sogi_gd_s = j->sogi_gd_s_k / j->sogi_a.k; /* k is clamped > 0 by set_k */
}

void fw_inj_set_k_bumpless(fw_inj_t *j, float k) {
  const float k0 = j->sogi_a.k;
  fw_inj_set_k(j, k);
  const float dk = j->sogi_a.k - k0; /* the change made (set_k clamps k) */
  fw_sogi_bump_k_f32(&j->sogi_a, dk);
  fw_sogi_bump_k_f32(&j->sogi_b, dk);
}

void fw_inj_set_extractor(fw_inj_t *j, const fw_cfg_estimator_t *est, fw_extractor_t ex) {
  fw_inj_set_k(j, ex == FW_EXTRACTOR_SOGI_ADAPTIVE ? est->sogi_k_adapt_max : est->sogi_k);
  restart_averages(j); /* the demodulated history belongs to the old path */
}

/** Moving average over one injection period (ring of n_inj samples). The
 *  current columns only for the pseudo extractor, the only one that reads
 *  their average (an extractor change restarts the averages, so every row is
 *  rewritten before it is subtracted). */
static FW_ALWAYS_INLINE void ring_push(fw_inj_t *j, float ed, float eq, float ia, float ib,
                                       bool currents) {
  const uint32_t i = j->ring_idx;
  const bool full = j->ring_fill == j->n_inj;
  /* the row as j->ring[i][.], not through a float pointer: a store through a
   * pointer could alias any float of the controller, and GCC then reloaded what
   * it held (the sums here, and fields of the stages after); the sums in
   * locals (the same operations in the same order) */
  float sum_ed = j->sum_ed;
  float sum_eq = j->sum_eq;
  if (FW_LIKELY(full)) {
    sum_ed -= j->ring[i][0];
    sum_eq -= j->ring[i][1];
  } else {
    j->ring_fill++;
  }
  j->ring[i][0] = ed;
  j->ring[i][1] = eq;
  j->sum_ed = sum_ed + ed;
  j->sum_eq = sum_eq + eq;
  if (currents) {
    float sum_ia = j->sum_ia;
    float sum_ib = j->sum_ib;
    if (full) {
      sum_ia -= j->ring[i][2];
      sum_ib -= j->ring[i][3];
    }
    j->ring[i][2] = ia;
    j->ring[i][3] = ib;
    j->sum_ia = sum_ia + ia;
    j->sum_ib = sum_ib + ib;
  }
  /* next row, 0 after the last: as a product, which GCC does not turn into a
   * branch (it laid the usual case out of line, two taken branches) */
  const uint32_t next = i + 1u;
  j->ring_idx = next * (uint32_t)(next != j->n_inj);
}

void fw_inj_update(fw_inj_t *j, fw_extractor_t ex, fw_vec2_f32_t i_ab, fw_sincos_f32_t sc_k,
                   float theta_hat, float w_hat, fw_inj_meas_t *m) {
  /* Voltage applied over [k-1, k] was commanded at k-2. sign_hist is aged by
   * fw_inj_output later in this period, so here sign_hist[0] = s(k-1),
   * sign_hist[1] = s(k-2). */
  const float s = j->sign_hist[1];
  /* raw HF difference in the sampling frame, for the monitor */
  const fw_vec2_f32_t dh_raw = {i_ab.x - j->h_prev_raw[0], i_ab.y - j->h_prev_raw[1]};
  m->e_raw_dq_A = fw_park_f32(dh_raw, sc_k);
  m->e_raw_dq_A.x *= s;
  m->e_raw_dq_A.y *= s;

  /* sogi_b has sogi_a's gains (fw_inj_reset, fw_inj_set_k) */
  float h_a, h_b;
  fw_sogi_step_pair_f32(&j->sogi_a, i_ab.x, &j->sogi_b, i_ab.y, &h_a, &h_b);
  fw_vec2_f32_t dh;
  if (ex == FW_EXTRACTOR_PSEUDO) {
    dh.x = i_ab.x - j->h_prev_raw[0];
    dh.y = i_ab.y - j->h_prev_raw[1];
  } else {
    dh.x = h_a - j->h_prev_sogi[0];
    dh.y = h_b - j->h_prev_sogi[1];
  }
  j->h_prev_raw[0] = i_ab.x;
  j->h_prev_raw[1] = i_ab.y;
  j->h_prev_sogi[0] = h_a;
  j->h_prev_sogi[1] = h_b;

  /* Demodulate in the frame the estimate had when this HF response was
   * produced: half a period back for the difference, plus the SOGI's group
   * delay at the carrier. Rotating by the present estimate instead mixes the
   * delay into the saliency term and locks at a lag of about
   * (1 + G_sum/G_diff) w tau / 2 (3 w tau for Lq = 1.5 Ld). */
  float tau_s = 0.5f * j->dt_s;
  if (ex != FW_EXTRACTOR_PSEUDO) {
    tau_s += j->sogi_gd_s;
  }
  const fw_sincos_f32_t sc_d = fw_sincos_add_f32(sc_k, theta_hat, -w_hat * tau_s);
  const fw_vec2_f32_t dh_dq = fw_park_f32(dh, sc_d);
  ring_push(j, s * dh_dq.x, s * dh_dq.y, i_ab.x, i_ab.y, ex == FW_EXTRACTOR_PSEUDO);
  const float inv_n = j->ring_fill == j->n_inj ? j->inv_n_inj : 1.0f / (float)j->ring_fill;
  m->E_d_A = j->sum_ed * inv_n;
  m->E_q_A = j->sum_eq * inv_n;

  if (ex == FW_EXTRACTOR_PSEUDO) {
    m->i_h_ab_A = dh;
    m->i_f_ab_A.x = j->sum_ia * inv_n; /* one-period average removes the square-wave response */
    m->i_f_ab_A.y = j->sum_ib * inv_n;
  } else {
    m->i_h_ab_A.x = h_a;
    m->i_h_ab_A.y = h_b;
    m->i_f_ab_A.x = i_ab.x - h_a; /* eq. 10: fundamental = measured - extracted HF */
    m->i_f_ab_A.y = i_ab.y - h_b;
  }
}
