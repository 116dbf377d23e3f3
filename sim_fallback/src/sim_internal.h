/* Private definitions shared by the simulator translation units. */
#ifndef PMLSM_SIM_INTERNAL_H
#define PMLSM_SIM_INTERNAL_H

#include <math.h>

#include "pmlsm_sim.h"

#define SIM_PI 3.14159265358979323846
#define SIM_SQRT3 1.73205080756887729353
/** Order of the 1 / L_dd expansion (psi_d: one more); see sim_plant.c. */
#define SIM_FLUX_ORDER 7

/** Taylor coefficients of the d-axis flux around one i_d (see sim_plant.c). */
typedef struct {
  /** {iL[k], psi[k]}: 1 / L_dd(i_d0 + di) = sum iL[k] di^k, psi_d(i_d0 + di) =
   * sum psi[k] di^k (+ psi_top di^(ORDER+1)); interleaved so that both
   * polynomials are evaluated as one 2-wide vector. */
  _Alignas(16) double ip[SIM_FLUX_ORDER + 1][2];
  double psi_top;
} sim_flux_coef_t;

/** Flux grid: i_d / I_sat in steps of SIM_FLUX_GRID_DZ, |i_d / I_sat| <= 16. */
#define SIM_FLUX_GRID_DZ 0.05
#define SIM_FLUX_TAB_HALF 320

/** Copied breakpoint schedule with a search cursor. */
typedef struct {
  double *t_s;
  double *value;
  uint32_t n;
  uint32_t ramp;
  uint32_t cursor;   /**< last breakpoint index with t_s[cursor] <= t */
  double last_sent;  /**< last value handed to set_ref (NaN: never) */
} sim_sched_store_t;

struct sim_s {
  sim_plant_params_t p;
  sim_plant_state_t st;
  /* derived constants */
  double dt_s;          /**< PWM period */
  double k_theta;       /**< pi / tau (rad per m) */
  double adc_last_cnt[3];  /**< last current ADC counts (stuck-converter fault) */
  double adc_base[3];   /**< adc_mid + adc_offset_counts[j] */
  double adc_gain1[3];  /**< 1 + adc_gain_err[j] */
  double k_force;       /**< 1.5 pi / tau */
  double adc_lsb_A;     /**< current per count */
  double adc_mid;       /**< zero-current count */
  double adc_max;       /**< 2^bits - 1 */
  double udc_lsb_V;
  double inv_adc_lsb_A; /**< 1 / adc_lsb_A (counts per ampere) */
  double inv_udc_lsb_V;
  double u_dt_V;        /**< dead-time pole-voltage error magnitude */
  /* time */
  double t_s;
  uint64_t k;
  /* inverter: duties latched for the present period */
  double duty[3];
  int pwm_on;
  double F_load_N;      /**< load force applied over the present period */
  int32_t ref_last;     /**< the scale's last valid count (held while its signal is lost) */
  int pwm_was_on;       /**< the inverter applied PWM in the last integrated period */
  /* controller */
  sim_controller_t ctrl;
  int use_adc;
  uint32_t bg_in; /**< control periods until the controller's next background pass */
  sim_sched_store_t sched[SIM_REF_COUNT];
  double sched_next_t; /**< sim_run re-applies the schedules from this time on */
  /* Expansion points for cheap stage evaluations (see sim_plant.c): exact
   * sin/cos of theta_e and of the cogging angle at x0 (refreshed when x
   * drifts too far); Taylor coefficients of psi_d and 1 / L_dd around the
   * nearest point of a grid in i_d (exact tanh / ln cosh at the grid point,
   * computed on first use and kept). */
  int basis_valid;
  double b_x0, b_c0, b_s0, b_cc0, b_cs0;
  double b_id0;                     /**< i_d at the flux expansion point */
  const sim_flux_coef_t *fc;        /**< coefficients at b_id0 */
  int32_t flux_k;                   /**< grid index of fc (FLUX_K_NONE: scratch) */
  double flux_grid_A;               /**< grid spacing in i_d */
  double inv_flux_grid_A;
  double flux_far_A;                /**< stages beyond this |i_d - b_id0| use libm */
  sim_flux_coef_t flux_lin;         /**< linear d axis (dL = 0), or out of the grid */
  double inv_L_q, inv_mass, inv_I_sat, k_cog;
  /* plant realism (sim_plant.c, "plant realism"): 1 when a magnetic / inverter field of
   * it is set; 0 keeps every path and value of the plant without it */
  int real_mag, real_inv;
  sim_realism_t r;  /**< plant realism (sim_set_realism; zero: off) */
  /* RNG: xoshiro256** + ziggurat Gaussian (Marsaglia-Tsang / Doornik ZIGNOR,
   * 128 layers; tables per instance, no shared mutable state) */
  uint64_t rng[4];
  double zig_x[129];
  double zig_r[128];
  /* flux grid (cold: only the few entries near the operating i_d are touched) */
  uint8_t flux_ok[2 * SIM_FLUX_TAB_HALF + 1];
  sim_flux_coef_t flux_tab[2 * SIM_FLUX_TAB_HALF + 1];
};

#if defined(__GNUC__)
#define SIM_INLINE static inline __attribute__((always_inline))
#else
#define SIM_INLINE static inline
#endif

/** Angle-expansion limits (see sim_plant.c): refresh the basis beyond
 * SIM_BASIS_MAX_DTH at a sub-step start; libm beyond SIM_BASIS_FAR_DTH. */
#define SIM_BASIS_MAX_DTH 0.03
#define SIM_BASIS_FAR_DTH 0.06

/** cos d, sin d: Taylor to d^6 / d^7 (truncation < 5e-15 for |d| <=
 * SIM_BASIS_FAR_DTH; the caller checks the range). */
SIM_INLINE void sim_cs_poly(double d, double *cd, double *sd) {
  const double d2 = d * d, d4 = d2 * d2;
  *cd = (1.0 - 0.5 * d2) + d4 * ((1.0 / 24.0) - d2 * (1.0 / 720.0));
  *sd = d * ((1.0 - d2 * (1.0 / 6.0)) + d4 * ((1.0 / 120.0) - d2 * (1.0 / 5040.0)));
}

/** cos d, sin d: sim_cs_poly when |d| <= SIM_BASIS_FAR_DTH, libm beyond. */
SIM_INLINE void sim_cs_small(double d, double *cd, double *sd) {
  if (fabs(d) > SIM_BASIS_FAR_DTH) { /* far (huge step): exact */
    *cd = cos(d);
    *sd = sin(d);
    return;
  }
  sim_cs_poly(d, cd, sd);
}

/** cos, sin of (angle0 + d) from cos/sin of angle0. */
SIM_INLINE void sim_rot(double c0, double s0, double d, double *c, double *sn) {
  double cd, sd;
  sim_cs_small(d, &cd, &sd);
  *c = c0 * cd - s0 * sd;
  *sn = s0 * cd + c0 * sd;
}

/** cos/sin of theta_e at x (basis expansion when close, else libm). */
static inline void sim_plant_sincos(const sim_t *s, double x_m, double *c, double *sn) {
  const double d = s->k_theta * (x_m - s->b_x0);
  if (s->basis_valid && fabs(d) <= SIM_BASIS_FAR_DTH) {
    sim_rot(s->b_c0, s->b_s0, d, c, sn);
  } else {
    *c = cos(s->k_theta * x_m);
    *sn = sin(s->k_theta * x_m);
  }
}

/* xoshiro256** */
static inline uint64_t sim_rotl64(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }
/** One step on a state held in four variables (locals of a caller stay in registers). */
SIM_INLINE uint64_t sim_xoshiro_next4(uint64_t *a, uint64_t *b, uint64_t *c, uint64_t *d) {
  const uint64_t result = sim_rotl64(*b * 5u, 7) * 9u;
  const uint64_t t = *b << 17;
  *c ^= *a;
  *d ^= *b;
  *b ^= *c;
  *a ^= *d;
  *c ^= t;
  *d = sim_rotl64(*d, 45);
  return result;
}
static inline uint64_t sim_xoshiro_next(uint64_t r[4]) {
  return sim_xoshiro_next4(&r[0], &r[1], &r[2], &r[3]);
}

/* sim_plant.c */
/** Ziggurat draw that missed the fast path with raw draw r (continues on s->rng). */
double sim_rng_gauss_slow(sim_t *s, uint64_t r);

/** Standard normal deviate with the generator state in a..d (the caller copies it
 * from s->rng and back, so that over several draws it stays in registers): the
 * ziggurat's fast path inline (~99 % of draws), a miss through s->rng. */
SIM_INLINE double sim_rng_gauss4(sim_t *s, uint64_t *a, uint64_t *b, uint64_t *c, uint64_t *d) {
  const uint64_t r = sim_xoshiro_next4(a, b, c, d);
  const unsigned i = (unsigned)(r & 0x7Fu);
  const double u = (double)(r >> 11) * 0x1.0p-52 - 1.0;
  if (fabs(u) < s->zig_r[i]) return u * s->zig_x[i];
  s->rng[0] = *a;
  s->rng[1] = *b;
  s->rng[2] = *c;
  s->rng[3] = *d;
  const double g = sim_rng_gauss_slow(s, r);
  *a = s->rng[0];
  *b = s->rng[1];
  *c = s->rng[2];
  *d = s->rng[3];
  return g;
}

void sim_plant_derive(sim_t *s);
void sim_plant_period(sim_t *s, const double duty[3], int pwm_on, double dt_s,
                      uint32_t n_sub);
double sim_plant_force(const sim_t *s, const sim_plant_state_t *st);
/** Smallest eigenvalue of the incremental inductance over |i_d|, |i_q| <= i_lim and one
 *  electrical period of x (the realism terms' bounds added): the plant is well posed
 *  when it is positive (sim_params_check). */
double sim_plant_min_inductance(const sim_plant_params_t *p, const sim_realism_t *r,
                                double i_lim);
void sim_rng_seed(sim_t *s, uint64_t seed);
/** The generator's state from seed again (the ziggurat tables kept). */
void sim_rng_restart(sim_t *s, uint64_t seed);
/** Before a period's plant integration: the noise restart at a switch-on
 *  (sim_plant_params_t.noise_restart), in every loop that integrates. */
static inline void sim_noise_on_switch(sim_t *s, int pwm_on) {
  if (pwm_on && !s->pwm_was_on && s->p.noise_restart) sim_rng_restart(s, s->p.seed);
  s->pwm_was_on = pwm_on ? 1 : 0;
}
double sim_rng_gauss(sim_t *s);

#endif
