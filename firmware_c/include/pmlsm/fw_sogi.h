/**
 * @file fw_sogi.h
 * @brief Second-order generalized integrator (SOGI) band-pass / quadrature
 *        signal generator, fixed or adaptive gain (paper eq. 12, 13).
 *
 * Continuous prototype (centre angular frequency w, gain k), written as a
 * state-space model whose two states ARE the two outputs:
 *   x1' = k w (v - x1) - w x2,   x2' = w x1,   v' = x1,  qv' = x2
 *   D(s) = v'/v  = k w s   / (s^2 + k w s + w^2)   (band-pass, in phase)
 *   Q(s) = qv'/v = k w^2   / (s^2 + k w s + w^2)   (quadrature, -90 deg)
 *
 * Discretization: trapezoidal rule applied to the state equations, with the
 * step pre-warped at the centre frequency (1/c replaces dt/2,
 * c = w / tan(w dt / 2)). With A = [[-k w, -w], [w, 0]], B = [k w; 0]:
 *   (I - A/c) x[n+1] = (I + A/c) x[n] + (B/c) (v[n+1] + v[n]).
 * For a fixed k this is exactly the bilinear transform
 * s -> c (1 - z^-1) / (1 + z^-1) of D(s) and Q(s): the centre maps exactly,
 * so the discrete D has unity gain and zero phase at w for every sampling
 * rate below Nyquist, and the -3 dB bandwidth is k w (rad/s) up to frequency
 * warping. In the dimensionless t = w / c = tan(w dt / 2), e = 1 / (1 + k t
 * + t^2) (the closed-form inverse of I - A/c has this single divisor), one
 * step is
 *   u   = v[n+1] + v[n]
 *   x1 += p u - q x1 - r x2      p = k t e, q = 2 t (k + t) e, r = 2 t e
 *   x2 += t (x1_old + x1_new)    (trapezoid of x2' = w x1)
 * (algebraically identical to the matrix form above; the increment form
 * keeps the pole positions accurate in float32 when w dt is small).
 *
 * Why state space and not two biquads: the adaptive SOGI changes k every few
 * samples. The states here are the physical outputs v', qv' (plus the
 * previous input sample), which do not depend on k, so a k change only
 * changes the gains p, q, r and never disturbs the state: the output stays
 * continuous. (In a direct-form biquad the delay-line contents are
 * coefficient-weighted signal combinations, so changing k re-interprets them
 * and injects a glitch at every change.) At the centre frequency the
 * steady-state trajectory x1 = v, x2 = -(90 deg shifted v) satisfies the
 * recursion for every k, so toggling k leaves a centred sine undisturbed.
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
  float c;       /**< pre-warp constant w / tan(w dt / 2) (1/s) */
  float t;       /**< tan(w dt / 2) = w / c (dimensionless) */
  float k;       /**< current gain */
  float p, q, r; /**< k-dependent step gains (see above) */
  float x1;      /**< state 1 = in-phase output v' */
  float x2;      /**< state 2 = quadrature output qv' */
  float v_prev;  /**< previous input sample (trapezoid) */
} fw_sogi_f32_t;

/** Limits on k accepted by the SOGI (documented, range-checked). */
#define FW_SOGI_K_MIN 0.05f
#define FW_SOGI_K_MAX 4.0f

/** Initialise at centre frequency f0_Hz, gain k, sample time dt_s. */
bool fw_sogi_init_f32(fw_sogi_f32_t *s, float f0_Hz, float k, float dt_s);

/** Change k (clamped to [FW_SOGI_K_MIN, FW_SOGI_K_MAX]); state is kept. */
void fw_sogi_set_k_f32(fw_sogi_f32_t *s, float k);

/**
 * Copy the k-dependent gains (k, p, q, r) of src into dst, keeping dst's
 * state: gives a second SOGI the same new k with one coefficient
 * computation. Both must be initialised with the same centre frequency and
 * sample time; if w or dt differ (or either pointer is NULL) dst is left
 * unchanged.
 */
void fw_sogi_copy_gain_f32(fw_sogi_f32_t *dst, const fw_sogi_f32_t *src);

/**
 * After a change of k by dk: move the quadrature state by dk times the input's
 * low-frequency part, estimated as the last input minus the band-pass output
 * (v_prev - v'). For an input c + (a carrier) in steady state the state holds
 * qv' = k c + (the carrier's quadrature): with the state kept as it is, a new k
 * leaves it dk c off the new steady state, and the filter rings at its centre
 * frequency with an amplitude proportional to dk c (a DC or slow fundamental
 * current c of several amperes under a band-pass for the injection carrier).
 * With the move the change is bumpless for the low-frequency part, and the
 * carrier's state (unity gain at the centre, whatever k) is kept.
 */
void fw_sogi_bump_k_f32(fw_sogi_f32_t *s, float dk);

/** Clear the state (outputs and the stored previous input). */
void fw_sogi_reset_f32(fw_sogi_f32_t *s);

/**
 * One sample: returns the in-phase band-pass output v' and writes the
 * quadrature output qv' to *qv (may be NULL). A non-finite v is treated as 0.
 */
float fw_sogi_step_f32(fw_sogi_f32_t *s, float v, float *qv);

/**
 * One sample of two SOGIs that share their gains (b initialised as a, and
 * given a's gains by fw_sogi_copy_gain_f32 whenever a's k changes): each
 * exactly as fw_sogi_step_f32 (va into a, vb into b; *ya, *yb the in-phase
 * outputs), with the gains read once, from a.
 */
void fw_sogi_step_pair_f32(fw_sogi_f32_t *a, float va, fw_sogi_f32_t *b, float vb, float *ya,
                           float *yb);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_SOGI_H */
