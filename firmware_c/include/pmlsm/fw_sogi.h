/**
 * @file fw_sogi.h
 * @brief Second-order generalized integrator (SOGI) band-pass / quadrature
 *        signal generator, fixed or adaptive gain (paper eq. 12, 13).
 *
 * Continuous prototype (centre angular frequency w, gain k):
 *   D(s) = v'/v  = k w s   / (s^2 + k w s + w^2)   (band-pass, in phase)
 *   Q(s) = qv'/v = k w^2   / (s^2 + k w s + w^2)   (quadrature, -90 deg)
 *
 * Discretization: bilinear (Tustin) with pre-warping at the centre
 * frequency, s -> c (1 - z^-1) / (1 + z^-1), c = w / tan(w dt / 2). The
 * centre frequency maps exactly, so the discrete D has unity gain and zero
 * phase at w for every sampling rate below Nyquist; the -3 dB bandwidth is
 * k w (rad/s) up to frequency warping. Each output is one direct-form-II
 * transposed biquad sharing the denominator
 *   a0 = c^2 + k w c + w^2, a1 = 2 (w^2 - c^2), a2 = c^2 - k w c + w^2
 *   D:  b = k w c  * [1, 0, -1] / a0
 *   Q:  b = k w^2  * [1, 2,  1] / a0
 * Changing k (adaptive SOGI) recomputes the coefficients and keeps the
 * state, which is valid because the state is the transposed-form delay line.
 *
 * Requires w dt < pi (centre below Nyquist); fw_sogi_init_f32 returns false
 * otherwise, and also for non-positive or non-finite arguments.
 */
#ifndef PMLSM_FW_SOGI_H
#define PMLSM_FW_SOGI_H

#include <stdbool.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
  float w_rad_s; /**< centre angular frequency */
  float dt_s;    /**< sample time */
  float c;       /**< pre-warp constant w / tan(w dt / 2) */
  float k;       /**< current gain */
  float bd0, bq0, bq1, a1, a2; /**< normalised coefficients (bd1=0, bd2=-bd0, bq2=bq0) */
  float zd1, zd2;  /**< D biquad state */
  float zq1, zq2;  /**< Q biquad state */
} fw_sogi_f32_t;

/** Limits on k accepted by the SOGI (documented, range-checked). */
#define FW_SOGI_K_MIN 0.05f
#define FW_SOGI_K_MAX 4.0f

/** Initialise at centre frequency f0_Hz, gain k, sample time dt_s. */
bool fw_sogi_init_f32(fw_sogi_f32_t *s, float f0_Hz, float k, float dt_s);

/** Change k (clamped to [FW_SOGI_K_MIN, FW_SOGI_K_MAX]); state is kept. */
void fw_sogi_set_k_f32(fw_sogi_f32_t *s, float k);

/** Clear the state. */
void fw_sogi_reset_f32(fw_sogi_f32_t *s);

/**
 * One sample: returns the in-phase band-pass output v' and writes the
 * quadrature output qv' to *qv (may be NULL).
 */
float fw_sogi_step_f32(fw_sogi_f32_t *s, float v, float *qv);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_SOGI_H */
