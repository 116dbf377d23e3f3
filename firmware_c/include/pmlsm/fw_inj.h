/**
 * @file fw_inj.h
 * @brief Injection and extraction block: the square wave on the estimated
 *        d axis, and the HF current extraction (pseudo-filter, SOGI, adaptive
 *        SOGI, wrapping two fw_sogi filters) with its sign demodulation and
 *        one-injection-period averages.
 *
 * Per sample, with s = injection sign and the one-period PWM update delay:
 *   dh = h(k) - h(k-1)  (h = i_ab for the pseudo-filter, the SOGI output else),
 *   rotated into the frame the estimate had when the response was produced
 *   (half a period back, plus the SOGI group delay at the carrier),
 *   e = s(k-2) dh, averaged over one injection period: E_d, E_q.
 *   The fundamental for the current loop is i_ab - h (SOGI) or the one-period
 *   average of i_ab (pseudo-filter).
 * The raw difference of the measured current, demodulated in the sampling
 * frame (e_raw_dq), goes to the integrity monitor and the saliency check.
 *
 * fw_inj_update() consumes one sample, fw_inj_output() gives the sign to
 * command this period (it then ages the sign history). Both SOGIs always run,
 * so switching extractor is seamless.
 *
 * Needs the bottom layer (fw_types.h) and the SOGI (fw_sogi.h).
 */
#ifndef PMLSM_FW_INJ_H
#define PMLSM_FW_INJ_H

#include <math.h>
#include <stdbool.h>
#include <stdint.h>

#include "fw_sogi.h"
#include "fw_types.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Smallest change of the adaptive k worth recomputing coefficients for. */
#define FW_INJ_SOGI_K_STEP 0.002f

/** Injection and extraction state (caller-owned). */
typedef struct {
  /* constants from the configuration */
  float dt_s;
  uint32_t n_inj;         /**< PWM periods per injection period */
  float inv_n_inj;        /**< 1 / n_inj */
  float sogi_gd_s_k;      /**< SOGI group delay at the carrier times k (s) */
  /* state */
  fw_sogi_f32_t sogi_a, sogi_b;
  float sogi_gd_s;        /**< SOGI group delay at the present k (s) */
  uint32_t inj_idx;       /**< position inside the injection period */
  float sign_hist[2];     /**< injection signs; [0] = newest commanded, [1] = the one
                           *   before (applied over the present period) */
  float h_prev_raw[2];    /**< previous raw alpha/beta current (pseudo-filter) */
  float h_prev_sogi[2];   /**< previous SOGI output */
  /** moving average over one injection period: E_d, E_q, i_a, i_b per sample
   *  (one row per sample: one address for the four) */
  float ring[FW_INJ_MAX_SAMPLES][4];
  float sum_ed, sum_eq, sum_ia, sum_ib;
  uint32_t ring_idx, ring_fill;
  /** constant from the configuration: the SOGIs' gains as fw_inj_set_k(k_reset)
   *  leaves them (k, p, q, r of sogi_a, then of sogi_b) and the group delay, what
   *  fw_inj_reset restores when it resets to k_reset (the configured extractor's
   *  reset gain) instead of two divisions and three calls */
  float k_reset;
  float gain_reset[8];
  float gd_reset;
  /** constant from the configuration (compensation.sogi_bumpless): the adaptive
   *  gain's changes move the SOGIs' quadrature states with them (fw_inj_set_k_bumpless) */
  uint8_t bumpless;
} fw_inj_t;

/** Results of one sample. */
typedef struct {
  fw_vec2_f32_t i_f_ab_A;  /**< fundamental alpha/beta current (HF removed) */
  fw_vec2_f32_t e_raw_dq_A;/**< raw current difference, sign-demodulated, sampling frame */
  fw_vec2_f32_t i_h_ab_A;  /**< extracted HF current (telemetry): dh or the SOGI output */
  float E_d_A, E_q_A;      /**< demodulated one-period averages */
} fw_inj_meas_t;

/** Constants from the configuration (n_inj, the SOGIs' centre frequency and group
 *  delay), the ring cleared once; then fw_inj_reset. */
void fw_inj_init(fw_inj_t *j, const fw_config_t *cfg, float dt_s);
/** Clear every history (the ring by restarting its fill: each row is written before
 *  it is read); SOGIs restart with k for est->extractor (their gains only: no tanf,
 *  about 1,300 cycles less on the Cortex-M4F at the handover to closed loop; for the
 *  configured extractor the gains fw_inj_init computed, copied: about 60 less). */
void fw_inj_reset(fw_inj_t *j, const fw_cfg_estimator_t *est);
/** Same k on both SOGIs (coefficients computed once). */
void fw_inj_set_k(fw_inj_t *j, float k);
/** fw_inj_set_k, then each SOGI's quadrature state moved by the change of k times
 *  its input's low-frequency part (fw_sogi_bump_k_f32): a gain change does not ring
 *  the filters in proportion to the fundamental current. */
void fw_inj_set_k_bumpless(fw_inj_t *j, float k);
/** Extractor switched: k for the new path, the one-period averages restart. */
void fw_inj_set_extractor(fw_inj_t *j, const fw_cfg_estimator_t *est, fw_extractor_t ex);
/**
 * One sample: raw difference for the monitor, SOGIs, difference, demodulation
 * at theta_hat - w_hat tau (tau = dt/2 [+ SOGI group delay]), averages.
 * sc_k: sine/cosine of the estimate at this sampling instant, theta_hat_rad
 * (the demodulation frame is sc_k rotated by -w_hat tau).
 */
void fw_inj_update(fw_inj_t *j, fw_extractor_t ex, fw_vec2_f32_t i_ab_A, fw_sincos_f32_t sc_k,
                   float theta_hat_rad, float w_hat_radps, fw_inj_meas_t *m);
/** Adaptive SOGI: k from kmin..kmax by r in [0, 1] (r = 1: widest band);
 *  the coefficients are recomputed only when k moves by more than
 *  FW_INJ_SOGI_K_STEP. */
static inline void fw_inj_adapt(fw_inj_t *j, const fw_cfg_estimator_t *est, float r) {
  /* Observable adaptation (replaces eq. 13's theta - theta_hat): a wide band
   * while the PLL error is large, a narrow one when locked. */
  const float k = est->sogi_k_adapt_min + (est->sogi_k_adapt_max - est->sogi_k_adapt_min) * r;
  const float dk = k - j->sogi_a.k;
  if (FW_UNLIKELY(fabsf(dk) > FW_INJ_SOGI_K_STEP)) { /* |dk| exact: dk > step or dk < -step */
    if (FW_UNLIKELY(j->bumpless)) {
      fw_inj_set_k_bumpless(j, k);
    } else {
      fw_inj_set_k(j, k);
    }
  }
}
/** Sign to command this period (+1/-1 by half injection period, 0 when off);
 *  advances the injection phase when on and ages the sign history. */
static inline float fw_inj_output(fw_inj_t *j, bool on) {
  float s = 0.0f;
  if (on) {
    s = (j->inj_idx < j->n_inj / 2u) ? 1.0f : -1.0f;
    j->inj_idx = (j->inj_idx + 1u == j->n_inj) ? 0u : j->inj_idx + 1u;
  }
  j->sign_hist[1] = j->sign_hist[0];
  j->sign_hist[0] = s;
  return s;
}
/** One full injection period of samples in the averages. */
static inline bool fw_inj_settled(const fw_inj_t *j) { return j->ring_fill == j->n_inj; }
/** Sign of the voltage that acted over the last sampled interval, s(k-2). */
static inline float fw_inj_sign_applied(const fw_inj_t *j) { return j->sign_hist[1]; }
/** SOGI gain in use. */
static inline float fw_inj_k(const fw_inj_t *j) { return j->sogi_a.k; }

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_INJ_H */
