/*
 * PMLSM plant, float64: dq model in the true rotor frame with d-axis
 * saturation, linear mechanics with stick-slip friction and cogging,
 * average-model inverter with optional dead time, RK4 with sub-steps.
 * See docs/simulator.md for the equations.
 */
#include <math.h>
#include <string.h>

#include "sim_internal.h"

/* ---- RNG: splitmix64 seeding, xoshiro256**, ziggurat Gaussian ----------- */

static uint64_t splitmix64(uint64_t *x) {
  uint64_t z = (*x += 0x9E3779B97F4A7C15ull);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

/* Ziggurat constants for 128 layers (Marsaglia & Tsang 2000, Doornik 2005). */
#define ZIG_C 128
#define ZIG_R 3.442619855899
#define ZIG_V 9.91256303526217e-3

void sim_rng_restart(sim_t *s, uint64_t seed) {
  uint64_t x = seed;
  for (int i = 0; i < 4; ++i) s->rng[i] = splitmix64(&x);
}

void sim_rng_seed(sim_t *s, uint64_t seed) {
  sim_rng_restart(s, seed);
  /* layer tables */
  double f = exp(-0.5 * ZIG_R * ZIG_R);
  s->zig_x[0] = ZIG_V / f;
  s->zig_x[1] = ZIG_R;
  s->zig_x[ZIG_C] = 0.0;
  for (int i = 2; i < ZIG_C; ++i) {
    s->zig_x[i] = sqrt(-2.0 * log(ZIG_V / s->zig_x[i - 1] + f));
    f = exp(-0.5 * s->zig_x[i] * s->zig_x[i]);
  }
  for (int i = 0; i < ZIG_C; ++i) s->zig_r[i] = s->zig_x[i + 1] / s->zig_x[i];
}

/** Uniform in (0, 1], 53-bit resolution. */
static inline double rng_uniform(sim_t *s) {
  return ((double)(sim_xoshiro_next(s->rng) >> 11) + 1.0) * 0x1.0p-53;
}

/** Tail / wedge of the ziggurat for raw draw r, then further draws if rejected. */
double sim_rng_gauss_slow(sim_t *s, uint64_t r) {
  for (;;) {
    const unsigned i = (unsigned)(r & 0x7Fu);                        /* layer */
    const double u = (double)(r >> 11) * 0x1.0p-52 - 1.0;           /* [-1, 1) */
    if (fabs(u) < s->zig_r[i]) return u * s->zig_x[i];
    if (i == 0u) { /* base layer: sample the tail beyond R */
      double xt, yt;
      do {
        xt = log(rng_uniform(s)) / ZIG_R;
        yt = log(rng_uniform(s));
      } while (-2.0 * yt < xt * xt);
      return (u < 0.0) ? xt - ZIG_R : ZIG_R - xt;
    }
    const double x = u * s->zig_x[i];
    const double f0 = exp(-0.5 * (s->zig_x[i] * s->zig_x[i] - x * x));
    const double f1 = exp(-0.5 * (s->zig_x[i + 1] * s->zig_x[i + 1] - x * x));
    if (f1 + rng_uniform(s) * (f0 - f1) < 1.0) return x;
    r = sim_xoshiro_next(s->rng);
  }
}

/** Standard normal deviate (ziggurat; ~99 % of draws take the fast path). */
double sim_rng_gauss(sim_t *s) {
  uint64_t a = s->rng[0], b = s->rng[1], c = s->rng[2], d = s->rng[3];
  const double g = sim_rng_gauss4(s, &a, &b, &c, &d);
  s->rng[0] = a;
  s->rng[1] = b;
  s->rng[2] = c;
  s->rng[3] = d;
  return g;
}

/* ---- plant ------------------------------------------------------------- */

/*
 * Cheap stage evaluations. Inside one PWM period the angle moves by
 * omega_e T (1.7e-3 rad at 100 r/min) and i_d by a fraction of an ampere, so
 * every RK stage expands around a basis point computed exactly with libm:
 *   sin/cos(th0 + d): rotation by d with Taylor cos d to d^6, sin d to d^7
 *       (truncation < 5e-15 for |d| <= SIM_BASIS_FAR_DTH = 0.06 rad),
 *   psi_d(i_d0 + di) and 1 / L_dd(i_d0 + di): Taylor polynomials of orders
 *       8 and 7 in di, coefficients from the power series of tanh
 *       (y' = 1 - y^2) and its reciprocal around i_d0 = the grid point
 *       (spacing 0.05 I_sat) nearest to i_d at the sub-step start; relative
 *       truncation of 1 / L_dd < 4e-12 for |di| <= 0.075 I_sat and < 4e-11 at
 *       the far limit |di| = BASIS_FAR_DZ I_sat = 0.1 I_sat (psi_d < 2e-13).
 * The grid coefficients are computed with libm on first use and kept, so the
 * injection's HF ripple (+-0.25 A, more than a grid step) costs a table
 * look-up, not a libm refresh. Polynomials are evaluated in Estrin form
 * (short dependency chains) and 1 / L_dd is a polynomial: no stage divides.
 * The angle basis is refreshed at a sub-step start whenever |d| > 0.03 rad.
 * A stage further away than the far limits (huge steps, e.g. h = 1 ms in the
 * convergence test) uses libm directly.
 */
#define BASIS_MAX_DTH SIM_BASIS_MAX_DTH
#define BASIS_FAR_DZ 0.10

void sim_plant_derive(sim_t *s) {
  const sim_plant_params_t *p = &s->p;
  s->dt_s = 1.0 / p->f_pwm_Hz;
  s->k_theta = SIM_PI / p->tau_m;
  s->k_force = 1.5 * SIM_PI / p->tau_m;
  const double full = ldexp(1.0, (int)p->adc_bits);
  s->adc_lsb_A = 2.0 * p->adc_i_fullscale_A / full;
  s->adc_mid = 0.5 * full;
  s->adc_max = full - 1.0;
  s->udc_lsb_V = p->udc_fullscale_V / full;
  s->inv_adc_lsb_A = 1.0 / s->adc_lsb_A;
  s->inv_udc_lsb_V = 1.0 / s->udc_lsb_V;
  for (int j = 0; j < 3; ++j) {
    s->adc_base[j] = s->adc_mid + p->adc_offset_counts[j];
    s->adc_gain1[j] = 1.0 + p->adc_gain_err[j];
  }
  s->u_dt_V = p->u_dc_V * p->dead_time_s * p->f_pwm_Hz;
  s->inv_L_q = 1.0 / p->L_q_H;
  s->inv_mass = 1.0 / p->mass_kg;
  s->inv_I_sat = 1.0 / p->I_sat_A;
  s->k_cog = 2.0 * SIM_PI / p->cog_period_m;
  s->flux_grid_A = SIM_FLUX_GRID_DZ * p->I_sat_A;
  s->inv_flux_grid_A = 1.0 / s->flux_grid_A;
  s->flux_far_A = (p->dL_sat_H == 0.0) ? (double)INFINITY : BASIS_FAR_DZ * p->I_sat_A;
  s->basis_valid = 0;
  /* the flux grid's coefficients depend on psi_f, L_d0, dL_sat and I_sat: after a
   * parameter change (sim_set_params) every entry is computed afresh when used */
  memset(s->flux_ok, 0, sizeof s->flux_ok);
  const sim_realism_t *r = &s->r;
  s->real_mag = r->dLq_sat_H != 0.0 || r->cross_L_H != 0.0 || r->sal2_L_H != 0.0 ||
                r->emf_h5 != 0.0 || r->emf_h7 != 0.0 || r->end_dL_H != 0.0 ||
                r->end_psi_frac != 0.0;
  s->real_inv = r->dt_C_eq_F != 0.0 || r->u_dev_V != 0.0 || r->r_dev_ohm != 0.0;
}

/** ln cosh(z), overflow free. */
static inline double lncosh(double z) {
  const double a = fabs(z);
  return a + log1p(exp(-2.0 * a)) - 0.69314718055994530942;
}

/** Angle part of the basis: exact sin/cos of theta_e (and the cogging angle) at x. */
static void basis_update_angle(sim_t *s, double x_m) {
  const sim_plant_params_t *p = &s->p;
  const double th = s->k_theta * x_m;
  s->b_x0 = x_m;
  s->b_c0 = cos(th);
  s->b_s0 = sin(th);
  if (p->cog_amp_N != 0.0) {
    const double a = s->k_cog * x_m + p->cog_phase_rad;
    s->b_cc0 = cos(a);
    s->b_cs0 = sin(a);
  } else {
    s->b_cc0 = 1.0;
    s->b_cs0 = 0.0;
  }
}

/** Taylor coefficients of psi_d and 1 / L_dd around i_d0 (exact libm anchor). */
static void flux_coef(const sim_t *s, double i_d0, sim_flux_coef_t *fc) {
  const sim_plant_params_t *p = &s->p;
  enum { N = SIM_FLUX_ORDER };
  double psi[N + 2], iL[N + 1];
  for (int k = 0; k <= N + 1; ++k) psi[k] = 0.0;
  for (int k = 0; k <= N; ++k) iL[k] = 0.0;
  if (p->dL_sat_H == 0.0) { /* linear: exact for every di */
    psi[0] = p->psi_f_Wb + p->L_d0_H * i_d0;
    psi[1] = p->L_d0_H;
    iL[0] = 1.0 / p->L_d0_H;
  } else {
    const double z = i_d0 * s->inv_I_sat;
    /* tanh(z + e) = sum c_k e^k from y' = 1 - y^2 */
    double c[N + 1];
    c[0] = tanh(z);
    for (int k = 0; k < N; ++k) {
      double acc = (k == 0) ? 1.0 : 0.0;
      for (int j = 0; j <= k; ++j) acc -= c[j] * c[k - j];
      c[k + 1] = acc / (double)(k + 1);
    }
    /* L_dd(i_d0 + di) = sum a_k di^k; psi_d' = L_dd */
    double a[N + 1];
    double sc = 1.0; /* inv_I_sat^k */
    for (int k = 0; k <= N; ++k) {
      a[k] = -p->dL_sat_H * c[k] * sc;
      sc *= s->inv_I_sat;
    }
    a[0] += p->L_d0_H;
    psi[0] = p->psi_f_Wb + p->L_d0_H * i_d0 - p->dL_sat_H * p->I_sat_A * lncosh(z);
    for (int k = 0; k <= N; ++k) psi[k + 1] = a[k] / (double)(k + 1);
    /* reciprocal series */
    const double b0 = 1.0 / a[0];
    iL[0] = b0;
    for (int n = 1; n <= N; ++n) {
      double acc = 0.0;
      for (int k = 1; k <= n; ++k) acc += a[k] * iL[n - k];
      iL[n] = -acc * b0;
    }
  }
  for (int k = 0; k <= N; ++k) {
    fc->ip[k][0] = iL[k];
    fc->ip[k][1] = psi[k];
  }
  fc->psi_top = psi[N + 1];
}

#define FLUX_K_NONE INT32_MIN

/** Flux expansion point for a sub-step starting at i_d: nearest grid point. */
static inline void flux_select(sim_t *s, double i_d_A) {
  if (s->p.dL_sat_H == 0.0) {
    if (s->flux_k != 0) { /* linear: one exact set, never refreshed */
      flux_coef(s, 0.0, &s->flux_lin);
      s->b_id0 = 0.0;
      s->fc = &s->flux_lin;
      s->flux_k = 0;
    }
    return;
  }
  const double q = i_d_A * s->inv_flux_grid_A;
  if (fabs(q) < (double)SIM_FLUX_TAB_HALF) {
    /* No "same grid point as before?" test: the HF injection moves i_d across
     * grid points in most periods, and that branch was mispredicted often;
     * the point and its coefficients are the same values either way. */
    const int32_t k = (int32_t)lrint(q);
    const size_t j = (size_t)(k + SIM_FLUX_TAB_HALF);
    s->b_id0 = (double)k * s->flux_grid_A;
    if (!s->flux_ok[j]) {
      flux_coef(s, s->b_id0, &s->flux_tab[j]);
      s->flux_ok[j] = 1;
    }
    s->fc = &s->flux_tab[j];
    s->flux_k = k;
  } else { /* beyond the grid (|i_d| > 16 I_sat): expand at i_d itself */
    s->b_id0 = i_d_A;
    flux_coef(s, i_d_A, &s->flux_lin);
    s->fc = &s->flux_lin;
    s->flux_k = FLUX_K_NONE;
  }
}

static inline void basis_ensure(sim_t *s, double x_m, double i_d_A) {
  if (!s->basis_valid) {
    basis_update_angle(s, x_m);
    s->flux_k = FLUX_K_NONE;
    flux_select(s, i_d_A);
    s->basis_valid = 1;
    return;
  }
  const double dx = x_m - s->b_x0;
  if (fabs(s->k_theta * dx) > BASIS_MAX_DTH ||
      (s->p.cog_amp_N != 0.0 && fabs(s->k_cog * dx) > BASIS_MAX_DTH))
    basis_update_angle(s, x_m);
  flux_select(s, i_d_A);
}

/** Exact (libm) psi_d(i_d) and 1 / L_dd(i_d). */
/* cos/sin of a stage's angle offset d from the expansion point: the checked
 * polynomial (flagging a far stage) when far != NULL, else the short series */
static inline void stage_cs(double d, int *far, double *cd, double *sd) {
  if (far) {
    *far |= fabs(d) > SIM_BASIS_FAR_DTH;
    sim_cs_poly(d, cd, sd);
  } else {
    sim_cs_small(d, cd, sd);
  }
}

static void d_axis_flux_exact(const sim_plant_params_t *p, double i_d, double *psi_d,
                              double *inv_L_dd) {
  if (p->dL_sat_H == 0.0) {
    *psi_d = p->psi_f_Wb + p->L_d0_H * i_d;
    *inv_L_dd = 1.0 / p->L_d0_H;
    return;
  }
  const double z = i_d / p->I_sat_A;
  *psi_d = p->psi_f_Wb + p->L_d0_H * i_d - p->dL_sat_H * p->I_sat_A * lncosh(z);
  *inv_L_dd = 1.0 / (p->L_d0_H - p->dL_sat_H * tanh(z));
}

/* ---- plant realism: the full magnetic model (libm, no expansions) -------------
 *
 * One co-energy per unit of (3/2) (amplitude-invariant Clarke: the stator co-energy is
 * W' = 3/2 w, psi_alpha_beta = grad w, thrust F = 3/2 dw/dx at fixed stator currents):
 *   w = w_m(i_d, i_q) + w_h(i_alpha_beta, x)
 *   w_m  = psi_f i_d + L_d0 i_d^2/2 - dL I_s^2 Lambda(i_d/I_s)       (Lambda' = ln cosh)
 *        + L_q i_q^2/2 - dLq (i_q^2/2 - Iq^2 ln cosh(i_q/Iq))          (q saturation)
 *        - L_x I_x^2 tanh(i_d/I_x) ln cosh(i_q/I_x)                    (cross-saturation)
 *   w_h  = i . Psi_57(theta)                                           (back-EMF 5th, 7th)
 *        + L_n/2 i^T [[cos a, sin a], [sin a, -cos a]] i, a = n theta + phi  (saliency n)
 *        + 2/3 (-dL_e(x)/2 (i_a^2 + i_c^2) - eps e(x) (psi_PM,a i_a + psi_PM,c i_c))
 *                                                                      (end effect)
 * Every flux is a gradient of w, so the flux maps are reciprocal (d psi_d / d i_q =
 * d psi_q / d i_d) and the thrust is the co-energy's derivative: energy-consistent. */

/** End-effect exposure e(x) in [0, 1] and de/dx. */
static void end_exposure(const sim_realism_t *r, double x, double *e, double *de) {
  double edge = 0.0, dedge = 0.0;
  if (r->end_travel_m > 0.0) {
    const double k = 1.0 / r->end_zone_m, h = 0.5 * r->end_travel_m;
    const double th = tanh((x - h) * k), tl = tanh((x + h) * k);
    edge = 0.5 * (1.0 + th) + 0.5 * (1.0 - tl);
    dedge = 0.5 * k * ((1.0 - th * th) - (1.0 - tl * tl));
  }
  *e = r->end_base + (1.0 - r->end_base) * edge;
  *de = (1.0 - r->end_base) * dedge;
}

/** The rotor-frame part w_m: psi_m, its incremental inductance (dd, dq, qq). */
static void mag_dq(const sim_plant_params_t *p, const sim_realism_t *r, double i_d, double i_q,
                   double psi[2], double L[3]) {
  double inv_L_dd;
  d_axis_flux_exact(p, i_d, &psi[0], &inv_L_dd);
  L[0] = p->L_d0_H - p->dL_sat_H * tanh(i_d / p->I_sat_A);
  L[1] = 0.0;
  psi[1] = p->L_q_H * i_q;
  L[2] = p->L_q_H;
  if (r->dLq_sat_H != 0.0) {
    const double tq = tanh(i_q / r->Iq_sat_A);
    psi[1] -= r->dLq_sat_H * (i_q - r->Iq_sat_A * tq);
    L[2] -= r->dLq_sat_H * tq * tq;
  }
  if (r->cross_L_H != 0.0) {
    const double Lx = r->cross_L_H, Ix = r->cross_I_A;
    const double td = tanh(i_d / Ix), tq = tanh(i_q / Ix), lc = lncosh(i_q / Ix);
    const double sd2 = 1.0 - td * td, sq2 = 1.0 - tq * tq;
    psi[0] -= Lx * Ix * sd2 * lc;
    psi[1] -= Lx * Ix * td * tq;
    L[0] += 2.0 * Lx * td * sd2 * lc;
    L[1] = -Lx * sd2 * tq;
    L[2] -= Lx * td * sq2;
  }
}

/** The full model at (i_d, i_q, x); cs = {cos, sin} theta_e for the caller. */
static void mag_eval(const sim_plant_params_t *p, const sim_realism_t *r, double i_d,
                     double i_q, double x, sim_magnetics_t *m, double cs[2]) {
  const double k_th = SIM_PI / p->tau_m, th = k_th * x;
  const double c = cos(th), sn = sin(th);
  cs[0] = c;
  cs[1] = sn;
  double psi_m[2], L[3];
  mag_dq(p, r, i_d, i_q, psi_m, L);
  const double i_a = c * i_d - sn * i_q, i_b = sn * i_d + c * i_q; /* alpha, beta */
  double ph[2] = {0.0, 0.0}, H[3] = {0.0, 0.0, 0.0}, dph[2] = {0.0, 0.0}, dw = 0.0;
  if (r->emf_h5 != 0.0) { /* negative sequence: psi = A5 e^{-j(5 th + phi)} */
    const double A = p->psi_f_Wb * r->emf_h5 / 5.0, a = 5.0 * th + r->emf_h5_phase_rad;
    const double ca = cos(a), sa = sin(a);
    const double d0 = -5.0 * k_th * A * sa, d1 = -5.0 * k_th * A * ca;
    ph[0] += A * ca;
    ph[1] -= A * sa;
    dph[0] += d0;
    dph[1] += d1;
    dw += i_a * d0 + i_b * d1;
  }
  if (r->emf_h7 != 0.0) { /* positive sequence: psi = A7 e^{j(7 th + phi)} */
    const double A = p->psi_f_Wb * r->emf_h7 / 7.0, a = 7.0 * th + r->emf_h7_phase_rad;
    const double ca = cos(a), sa = sin(a);
    const double d0 = -7.0 * k_th * A * sa, d1 = 7.0 * k_th * A * ca;
    ph[0] += A * ca;
    ph[1] += A * sa;
    dph[0] += d0;
    dph[1] += d1;
    dw += i_a * d0 + i_b * d1;
  }
  if (r->sal2_L_H != 0.0) {
    const double n = (double)r->sal2_order, a = n * th + r->sal2_phase_rad;
    const double ca = r->sal2_L_H * cos(a), sa = r->sal2_L_H * sin(a);
    H[0] += ca;
    H[1] += sa;
    H[2] -= ca;
    ph[0] += ca * i_a + sa * i_b;
    ph[1] += sa * i_a - ca * i_b;
    /* dH/dx = n k_th L_n [[-sin a, cos a], [cos a, sin a]] */
    const double g0 = n * k_th * (-sa * i_a + ca * i_b), g1 = n * k_th * (ca * i_a + sa * i_b);
    dph[0] += g0;
    dph[1] += g1;
    dw += 0.5 * (i_a * g0 + i_b * g1);
  }
  if (r->end_dL_H != 0.0 || r->end_psi_frac != 0.0) {
    double e, de;
    end_exposure(r, x, &e, &de);
    const double dL = r->end_dL_H * e, ddL = r->end_dL_H * de, eps = r->end_psi_frac;
    const double h3 = 0.5 * SIM_SQRT3;
    const double ia = i_a, ic = -0.5 * i_a - h3 * i_b; /* phase currents a, c */
    const double pa = p->psi_f_Wb * c, pc = p->psi_f_Wb * (-0.5 * c - h3 * sn);
    const double dpa = -k_th * p->psi_f_Wb * sn, dpc = -k_th * p->psi_f_Wb * (-0.5 * sn + h3 * c);
    const double fa = -dL * ia - eps * e * pa, fc = -dL * ic - eps * e * pc; /* abc fluxes */
    const double ga = -ddL * ia - eps * (de * pa + e * dpa);
    const double gc = -ddL * ic - eps * (de * pc + e * dpc);
    /* 2/3 K^T: k_a = (1, 0), k_c = (-1/2, -sqrt3/2) */
    ph[0] += (2.0 / 3.0) * (fa - 0.5 * fc);
    ph[1] += (2.0 / 3.0) * (-h3 * fc);
    dph[0] += (2.0 / 3.0) * (ga - 0.5 * gc);
    dph[1] += (2.0 / 3.0) * (-h3 * gc);
    H[0] -= (2.0 / 3.0) * dL * 1.25;
    H[1] -= (2.0 / 3.0) * dL * 0.25 * SIM_SQRT3;
    H[2] -= (2.0 / 3.0) * dL * 0.75;
    dw += (2.0 / 3.0) * (-0.5 * ddL * (ia * ia + ic * ic) -
                         eps * ((de * pa + e * dpa) * ia + (de * pc + e * dpc) * ic));
  }
  /* stator-frame terms into the rotor frame: R(-th) v, R(-th) H R(th) */
  const double cc = c * c, ss = sn * sn, cs2 = c * sn;
  const double Hdd = H[0] * cc + 2.0 * H[1] * cs2 + H[2] * ss;
  const double Hdq = (H[2] - H[0]) * cs2 + H[1] * (cc - ss);
  const double Hqq = H[0] * ss - 2.0 * H[1] * cs2 + H[2] * cc;
  m->psi_dq_Wb[0] = psi_m[0] + (c * ph[0] + sn * ph[1]);
  m->psi_dq_Wb[1] = psi_m[1] + (-sn * ph[0] + c * ph[1]);
  m->L_dq_H[0] = L[0] + Hdd;
  m->L_dq_H[1] = L[1] + Hdq;
  m->L_dq_H[2] = L[2] + Hqq;
  /* speed voltage per velocity: k_th (J psi_m + H_dq J i) + R(-th) d psi_h/dx; J i = (-i_q, i_d) */
  m->e_dq_V_per_mps[0] = k_th * (-psi_m[1] + (-Hdd * i_q + Hdq * i_d)) + (c * dph[0] + sn * dph[1]);
  m->e_dq_V_per_mps[1] = k_th * (psi_m[0] + (-Hdq * i_q + Hqq * i_d)) + (-sn * dph[0] + c * dph[1]);
  m->force_N = 1.5 * k_th * (psi_m[0] * i_q - psi_m[1] * i_d) + 1.5 * dw;
}

void sim_plant_magnetics(const sim_t *s, double i_d_A, double i_q_A, double x_m,
                         sim_magnetics_t *out) {
  double cs[2];
  if (s && out) mag_eval(&s->p, &s->r, i_d_A, i_q_A, x_m, out, cs);
}

double sim_plant_min_inductance(const sim_plant_params_t *p, const sim_realism_t *r,
                                double i_lim) {
  /* the rotor-frame part on a grid; the stator-frame terms' largest eigenvalues bound
   * the rest: |sal2_L| (the saliency term) and end_dL_H (2/3 end_dL (k_a k_a^T + k_c
   * k_c^T) has the eigenvalues end_dL and end_dL / 3) */
  enum { N = 24 };
  double lo = (double)INFINITY;
  for (int a = -N; a <= N; ++a) {
    for (int b = -N; b <= N; ++b) {
      double psi[2], L[3];
      mag_dq(p, r, i_lim * a / N, i_lim * b / N, psi, L);
      const double mean = 0.5 * (L[0] + L[2]), dif = 0.5 * (L[0] - L[2]);
      const double lmin = mean - sqrt(dif * dif + L[1] * L[1]);
      if (!(lmin >= lo)) lo = lmin; /* NaN propagates */
    }
  }
  return lo - fabs(r->sal2_L_H) - r->end_dL_H;
}

#if SIM_FLUX_ORDER != 7
#error "d_axis_flux evaluates order-7 polynomials"
#endif
#if defined(__GNUC__) && !defined(SIM_NO_VECTOR)
/* 2-wide vectors (SSE2 / NEON / scalar code by the compiler): element-wise IEEE
 * operations, so the same values as the scalar fallback (-DSIM_NO_VECTOR). */
#define SIM_VECTOR 1
typedef double sim_v2d __attribute__((vector_size(16), may_alias));
#else
#define SIM_VECTOR 0
#endif

/** psi_d and 1 / L_dd from the basis expansion at di = i_d - b_id0 (the caller
 * checks |di| <= flux_far_A). */
SIM_INLINE void d_axis_flux_poly(const sim_t *s, double di, double *psi_d, double *inv_L_dd) {
  const double d2 = di * di, d4 = d2 * d2;
  const sim_flux_coef_t *fc = s->fc;
  /* Estrin: (c0 + c1 x) + x^2 (c2 + c3 x) + x^4 ((c4 + c5 x) + x^2 (c6 + c7 x)) */
#if SIM_VECTOR
  const sim_v2d *c = (const sim_v2d *)fc->ip;
  const sim_v2d r = (c[0] + c[1] * di) + d2 * (c[2] + c[3] * di) +
                    d4 * ((c[4] + c[5] * di) + d2 * (c[6] + c[7] * di));
  *inv_L_dd = r[0];
  *psi_d = r[1] + (d4 * d4) * fc->psi_top;
#else
  double r[2];
  for (int j = 0; j < 2; ++j) {
    const double(*c)[2] = fc->ip;
    r[j] = (c[0][j] + c[1][j] * di) + d2 * (c[2][j] + c[3][j] * di) +
           d4 * ((c[4][j] + c[5][j] * di) + d2 * (c[6][j] + c[7][j] * di));
  }
  *inv_L_dd = r[0];
  *psi_d = r[1] + (d4 * d4) * fc->psi_top;
#endif
}

/** psi_d and 1 / L_dd from the basis expansion (libm when far). */
SIM_INLINE void d_axis_flux(const sim_t *s, double i_d, double *psi_d, double *inv_L_dd) {
  const double di = i_d - s->b_id0;
  if (fabs(di) > s->flux_far_A) { /* far stage (huge step): exact */
    d_axis_flux_exact(&s->p, i_d, psi_d, inv_L_dd);
    return;
  }
  d_axis_flux_poly(s, di, psi_d, inv_L_dd);
}

double sim_plant_force(const sim_t *s, const sim_plant_state_t *st) {
  if (s->real_mag) {
    sim_magnetics_t m;
    double cs[2];
    mag_eval(&s->p, &s->r, st->i_d_A, st->i_q_A, st->x_m, &m, cs);
    return m.force_N;
  }
  double psi_d, inv_L_dd;
  if (s->basis_valid)
    d_axis_flux(s, st->i_d_A, &psi_d, &inv_L_dd); /* expansion (exact when far) */
  else
    d_axis_flux_exact(&s->p, st->i_d_A, &psi_d, &inv_L_dd);
  return s->k_force * (psi_d * st->i_q_A - s->p.L_q_H * st->i_q_A * st->i_d_A);
}

/** Inputs held constant over one RK4 sub-step. */
typedef struct {
  double u_dq0_V[2];  /**< stator voltage in the rotor frame at the basis angle */
  double u_ab_V[2];   /**< the same in the stator frame (plant realism: deriv_real) */
  double F_load_N;
  /** F_em + load_add = (F_em + 0.0) - F_load_N for every F_em (no cogging):
   * -F_load_N, or +0.0 when F_load_N is a zero (x - (+0.0) keeps x = -0.0,
   * the + 0.0 of the cogging-free sum does not) */
  double load_add;
  int mech_dir;       /**< 0: stuck/locked; +1/-1: sliding direction (Coulomb sign) */
  int elec_open;      /**< 1: PWM off and currents extinct: i held at 0 */
} substep_in_t;

/** dy/dt for y = {i_d, i_q, x, v} with the full magnetic model (plant realism, libm):
 * M di/dt = u_dq - R i - e v (M, e: mag_eval); returns the net drive force. */
/** The mechanical half of dy/dt (dx/dt, dv/dt) from the net drive force: viscous and
 *  kinetic friction against it; both 0 while the mover sticks or is held (!slide). One
 *  definition for the fast model (deriv_t) and the full magnetic one (deriv_real). */
SIM_INLINE void mech_deriv(const sim_t *s, const double y[4], const substep_in_t *in,
                           double F_drive, double dy[4], const int slide) {
  const sim_plant_params_t *p = &s->p;
  if (slide) {
    dy[2] = y[3];
    dy[3] = ((F_drive - p->b_visc_Ns_per_m * y[3]) - p->F_coulomb_N * (double)in->mech_dir) *
            s->inv_mass;
  } else {
    dy[2] = 0.0;
    dy[3] = 0.0;
  }
}

static double deriv_real(const sim_t *s, const double y[4], const substep_in_t *in,
                         double dy[4], const int elec, const int slide) {
  const sim_plant_params_t *p = &s->p;
  sim_magnetics_t m;
  double cs[2];
  mag_eval(p, &s->r, y[0], y[1], y[2], &m, cs);
  if (elec) {
    const double u_d = cs[0] * in->u_ab_V[0] + cs[1] * in->u_ab_V[1];
    const double u_q = -cs[1] * in->u_ab_V[0] + cs[0] * in->u_ab_V[1];
    const double r0 = u_d - p->R_ohm * y[0] - m.e_dq_V_per_mps[0] * y[3];
    const double r1 = u_q - p->R_ohm * y[1] - m.e_dq_V_per_mps[1] * y[3];
    const double *L = m.L_dq_H;
    const double inv_det = 1.0 / (L[0] * L[2] - L[1] * L[1]);
    dy[0] = (L[2] * r0 - L[1] * r1) * inv_det;
    dy[1] = (L[0] * r1 - L[1] * r0) * inv_det;
  } else {
    dy[0] = 0.0;
    dy[1] = 0.0;
  }
  const double F_cog =
      p->cog_amp_N != 0.0 ? p->cog_amp_N * sin(s->k_cog * y[2] + p->cog_phase_rad) : 0.0;
  const double F_drive = (m.force_N + F_cog) - in->F_load_N;
  mech_deriv(s, y, in, F_drive, dy, slide);
  return F_drive;
}

/**
 * dy/dt for y = {i_d, i_q, x, v}; returns the net drive force (without
 * friction). cog / elec / slide are compile-time constants at the
 * specialised call sites (rk4_*), so the common case carries no branches.
 * far == NULL: a far stage (|di| > flux_far_A, angle offset beyond
 * SIM_BASIS_FAR_DTH) takes libm; else the expansions are used whatever the
 * distance and *far is set when a stage was far (the caller then redoes the
 * step with far == NULL: the same values as checking every stage, without
 * libm calls, and the register spills they cost, in the common code).
 * Inlined so that k1..k4 stay in registers.
 */
SIM_INLINE double deriv_t(const sim_t *s, const double y[4], const substep_in_t *in,
                          double dy[4], const int cog, const int elec, const int slide,
                          const int real, int *far) {
  if (real) return deriv_real(s, y, in, dy, elec, slide);
  const sim_plant_params_t *p = &s->p;
  const double dx = y[2] - s->b_x0;
  double psi_d, inv_L_dd;
  if (far) {
    const double di = y[0] - s->b_id0;
    *far |= fabs(di) > s->flux_far_A;
    d_axis_flux_poly(s, di, &psi_d, &inv_L_dd);
  } else {
    d_axis_flux(s, y[0], &psi_d, &inv_L_dd);
  }
  if (elec) {
    /* rotor-frame voltage: the basis-frame voltage rotated back by the
     * stage's angle offset d (cos/sin(-d) = cos d, -sin d) */
    double cd, sd;
    stage_cs(s->k_theta * dx, far, &cd, &sd);
    const double u_d = cd * in->u_dq0_V[0] + sd * in->u_dq0_V[1];
    const double u_q = cd * in->u_dq0_V[1] - sd * in->u_dq0_V[0];
    const double w = s->k_theta * y[3];
    dy[0] = ((u_d - p->R_ohm * y[0]) + w * p->L_q_H * y[1]) * inv_L_dd;
    dy[1] = ((u_q - p->R_ohm * y[1]) - w * psi_d) * s->inv_L_q;
  } else {
    dy[0] = 0.0;
    dy[1] = 0.0;
  }
  const double F_em = s->k_force * (psi_d * y[1] - p->L_q_H * y[1] * y[0]);
  double F_cog = 0.0;
  if (cog) {
    double cd, sd;
    stage_cs(s->k_cog * dx, far, &cd, &sd);
    /* sin of the cogging angle, as sim_rot */
    F_cog = p->cog_amp_N * (s->b_cs0 * cd + s->b_cc0 * sd);
  }
  /* without cogging one addition instead of two, the same value (see load_add) */
  const double F_drive = cog ? (F_em + F_cog) - in->F_load_N : F_em + in->load_add;
  mech_deriv(s, y, in, F_drive, dy, slide);
  return F_drive;
}

/** One classical RK4 step of length h from y0 to y1 (far: see deriv_t). */
SIM_INLINE void rk4_body(const sim_t *s, const substep_in_t *in, const double y0[4], double h,
                         double y1[4], const int cog, const int elec, const int slide,
                         const int real, int *far) {
  double k1[4], k2[4], k3[4], k4[4], yt[4];
  const double hh = 0.5 * h, h6 = h * (1.0 / 6.0);
  /* Stuck (slide == 0): k[2] = k[3] = 0.0 and hh * 0.0 == h * 0.0 for every h
   * (the same signed zero, or the same NaN), so stages 2..4 see one x and v:
   * written as one expression, their angle terms are evaluated once. */
  const double z = hh * 0.0;
  (void)deriv_t(s, y0, in, k1, cog, elec, slide, real, far);
  for (int j = 0; j < 4; ++j) yt[j] = y0[j] + hh * k1[j];
  if (!slide) yt[2] = y0[2] + z, yt[3] = y0[3] + z;
  (void)deriv_t(s, yt, in, k2, cog, elec, slide, real, far);
  for (int j = 0; j < 4; ++j) yt[j] = y0[j] + hh * k2[j];
  if (!slide) yt[2] = y0[2] + z, yt[3] = y0[3] + z;
  (void)deriv_t(s, yt, in, k3, cog, elec, slide, real, far);
  for (int j = 0; j < 4; ++j) yt[j] = y0[j] + h * k3[j];
  if (!slide) yt[2] = y0[2] + z, yt[3] = y0[3] + z;
  (void)deriv_t(s, yt, in, k4, cog, elec, slide, real, far);
  for (int j = 0; j < 4; ++j) y1[j] = y0[j] + h6 * ((k1[j] + k4[j]) + 2.0 * (k2[j] + k3[j]));
}

/** The step with every stage checked (libm for far stages): any case. */
#if defined(__GNUC__)
__attribute__((noinline, cold))
#endif
static void rk4_exact(const sim_t *s, const substep_in_t *in, const double y0[4], double h,
                      double y1[4]) {
  rk4_body(s, in, y0, h, y1, s->p.cog_amp_N != 0.0, !in->elec_open, in->mech_dir != 0, 0,
           NULL);
}

/** The step with the full magnetic model (plant realism). */
static void rk4_real(const sim_t *s, const substep_in_t *in, const double y0[4], double h,
                     double y1[4]) {
  rk4_body(s, in, y0, h, y1, 0, !in->elec_open, in->mech_dir != 0, 1, NULL);
}

/** The step on the expansions; redone by rk4_exact when a stage was far. */
SIM_INLINE void rk4_t(const sim_t *s, const substep_in_t *in, const double y0[4], double h,
                      double y1[4], const int cog, const int elec, const int slide) {
  int far = 0;
  rk4_body(s, in, y0, h, y1, cog, elec, slide, 0, &far);
  if (far) rk4_exact(s, in, y0, h, y1);
}

/* Specialisations: the common cases (PWM on, without or with cogging, sliding
 * or stuck) and a generic one. */
static void rk4_slide(const sim_t *s, const substep_in_t *in, const double y0[4], double h,
                      double y1[4]) {
  rk4_t(s, in, y0, h, y1, 0, 1, 1);
}
static void rk4_stuck(const sim_t *s, const substep_in_t *in, const double y0[4], double h,
                      double y1[4]) {
  rk4_t(s, in, y0, h, y1, 0, 1, 0);
}
static void rk4_cog_slide(const sim_t *s, const substep_in_t *in, const double y0[4],
                          double h, double y1[4]) {
  rk4_t(s, in, y0, h, y1, 1, 1, 1);
}
static void rk4_cog_stuck(const sim_t *s, const substep_in_t *in, const double y0[4],
                          double h, double y1[4]) {
  rk4_t(s, in, y0, h, y1, 1, 1, 0);
}
static void rk4_generic(const sim_t *s, const substep_in_t *in, const double y0[4], double h,
                        double y1[4]) {
  rk4_t(s, in, y0, h, y1, s->p.cog_amp_N != 0.0, !in->elec_open, in->mech_dir != 0);
}

/** Net drive force at y (stuck / break-away decisions). */
static double drive_force(const sim_t *s, const double y[4], const substep_in_t *in) {
  double dtmp[4];
  substep_in_t in0 = *in;
  in0.mech_dir = 0;
  if (s->real_mag) return deriv_real(s, y, &in0, dtmp, 0, 0);
  return deriv_t(s, y, &in0, dtmp, s->p.cog_amp_N != 0.0, 0, 0, 0, NULL);
}

/** RK4 step with the specialisation matching the sub-step's inputs. */
static inline void rk4_dispatch(const sim_t *s, const substep_in_t *in, const double y0[4],
                                double h, double y1[4]) {
  if (s->real_mag) {
    rk4_real(s, in, y0, h, y1);
  } else if (in->elec_open) {
    rk4_generic(s, in, y0, h, y1);
  } else if (s->p.cog_amp_N == 0.0) {
    if (in->mech_dir != 0)
      rk4_slide(s, in, y0, h, y1);
    else
      rk4_stuck(s, in, y0, h, y1);
  } else if (in->mech_dir != 0) {
    rk4_cog_slide(s, in, y0, h, y1);
  } else {
    rk4_cog_stuck(s, in, y0, h, y1);
  }
}

/** Linearised sign for the dead-time error. */
static inline double sgn_band(double i, double band) {
  if (band <= 0.0) return (i > 0.0) ? 1.0 : ((i < 0.0) ? -1.0 : 0.0);
  const double r = i / band;
  return r > 1.0 ? 1.0 : (r < -1.0 ? -1.0 : r);
}

/**
 * Pole-voltage error of the realistic inverter (plant realism) for phase current i:
 * dead time with capacitive commutation (pole capacitance C = dt_C_eq_F charged by the
 * phase current during the dead time t_d; i_c = C u_dc / t_d):
 *   |i| <= i_c:  f_pwm t_d^2 |i| / (2 C)           (the zero-current clamp: linear in i)
 *   |i| >  i_c:  f_pwm (u_dc t_d - C u_dc^2 / (2 |i|))   (-> u_dc t_d f_pwm)
 * (continuous with its slope at i_c), times sgn(i); without C (dt_C_eq_F = 0) the sign
 * model over dead_band_A; plus the device drops u_dev sgn_band(i) + r_dev i.
 */
static double inverter_error(const sim_t *s, double i) {
  const sim_plant_params_t *p = &s->p;
  const sim_realism_t *r = &s->r;
  double e;
  if (r->dt_C_eq_F > 0.0) {
    const double a = fabs(i), td = p->dead_time_s, C = r->dt_C_eq_F;
    const double m = (a * td <= C * p->u_dc_V)
                         ? td * td * a / (2.0 * C)
                         : p->u_dc_V * td - C * p->u_dc_V * p->u_dc_V / (2.0 * a);
    e = p->f_pwm_Hz * (i < 0.0 ? -m : m);
  } else {
    e = s->u_dt_V * sgn_band(i, p->dead_band_A);
  }
  return e + r->u_dev_V * sgn_band(i, p->dead_band_A) + r->r_dev_ohm * i;
}

/** A sub-step's inputs but the voltage: the load (see load_add), the phases conducting. */
static inline void substep_in_begin(const sim_t *s, substep_in_t *in) {
  in->F_load_N = s->F_load_N;
  in->load_add = (s->F_load_N == 0.0) ? 0.0 : -s->F_load_N;
  in->elec_open = 0;
}

/** The stator voltage u_ab turned into the rotor frame at the basis angle. */
static inline void substep_in_voltage(const sim_t *s, const double u_ab[2], substep_in_t *in) {
  in->u_dq0_V[0] = s->b_c0 * u_ab[0] + s->b_s0 * u_ab[1];
  in->u_dq0_V[1] = -s->b_s0 * u_ab[0] + s->b_c0 * u_ab[1];
}

/** The sub-step's end state y = {i_d, i_q, x, v} becomes the plant's. */
static inline void state_store(sim_plant_state_t *st, const double y[4]) {
  st->i_d_A = y[0];
  st->i_q_A = y[1];
  st->x_m = y[2];
  st->v_mps = y[3];
}

/** One RK4 sub-step of length h. */
static void substep(sim_t *s, const double duty[3], int pwm_on, double h,
                    const double *u_ab_fixed) {
  const sim_plant_params_t *p = &s->p;
  sim_plant_state_t *st = &s->st;
  basis_ensure(s, st->x_m, st->i_d_A);
  substep_in_t in;
  substep_in_begin(s, &in);
  double u_ab[2];
  double i_al = 0.0, i_be = 0.0;
  if (u_ab_fixed) {
    /* ideal inverter: the voltage is the same for every sub-step */
    u_ab[0] = u_ab_fixed[0];
    u_ab[1] = u_ab_fixed[1];
  } else {
    /* phase currents at sub-step start select dead-time error / diode rail */
    double c, sn;
    sim_rot(s->b_c0, s->b_s0, s->k_theta * (st->x_m - s->b_x0), &c, &sn);
    i_al = c * st->i_d_A - sn * st->i_q_A;
    i_be = sn * st->i_d_A + c * st->i_q_A;
    const double i_abc[3] = {i_al, -0.5 * i_al + 0.5 * SIM_SQRT3 * i_be,
                             -0.5 * i_al - 0.5 * SIM_SQRT3 * i_be};
    double u_pole[3];
    if (pwm_on && s->real_inv) {
      for (int j = 0; j < 3; ++j) u_pole[j] = duty[j] * p->u_dc_V - inverter_error(s, i_abc[j]);
    } else if (pwm_on) {
      for (int j = 0; j < 3; ++j)
        u_pole[j] = duty[j] * p->u_dc_V - s->u_dt_V * sgn_band(i_abc[j], p->dead_band_A);
    } else if (i_al * i_al + i_be * i_be > 1e-12) {
      /* switches off: freewheeling diodes clamp each pole to a rail */
      for (int j = 0; j < 3; ++j) u_pole[j] = (i_abc[j] < 0.0) ? p->u_dc_V : 0.0;
    } else {
      for (int j = 0; j < 3; ++j) u_pole[j] = 0.0;
      in.elec_open = 1;
    }
    u_ab[0] = (2.0 / 3.0) * (u_pole[0] - 0.5 * u_pole[1] - 0.5 * u_pole[2]);
    u_ab[1] = (u_pole[1] - u_pole[2]) * (1.0 / SIM_SQRT3);
  }

  substep_in_voltage(s, u_ab, &in);
  in.u_ab_V[0] = u_ab[0];
  in.u_ab_V[1] = u_ab[1];

  /* mechanics: stuck, or sliding in a fixed direction for this sub-step */
  double y0[4] = {st->i_d_A, st->i_q_A, st->x_m, st->v_mps};
  int can_break = 0;  /* stuck over this sub-step: may break away inside it */
  double F0 = 0.0;    /* drive force at the sub-step start (when stuck) */
  if (p->locked) {
    in.mech_dir = 0;
  } else if (st->stuck || st->v_mps == 0.0) {
    in.mech_dir = 0;
    F0 = drive_force(s, y0, &in);
    if (fabs(F0) > p->F_static_N) {
      in.mech_dir = F0 > 0.0 ? 1 : -1;
      st->stuck = 0;
    } else {
      st->stuck = 1;
      st->v_mps = 0.0;
      y0[3] = 0.0;
      can_break = 1;
    }
  } else {
    in.mech_dir = st->v_mps > 0.0 ? 1 : -1;
  }

  double y1[4];
  rk4_dispatch(s, &in, y0, h, y1);

  /* break-away inside the sub-step: the drive force crossed F_static. The
   * crossing is located by regula falsi on the drive force (re-integrating
   * from the sub-step start; three RK4 passes, only at this rare event), and
   * the sub-step is redone as stuck up to it and sliding after it. */
  if (can_break) {
    const double F1 = drive_force(s, y1, &in);
    if (fabs(F1) > p->F_static_N) {
      const double dir = F1 > 0.0 ? 1.0 : -1.0;
      double fa = 0.0, ga = dir * F0 - p->F_static_N, fb = 1.0, gb = dir * F1 - p->F_static_N;
      double f = (ga < 0.0) ? -ga / (gb - ga) : 0.0;
      double ym[4];
      for (int it = 0;; ++it) {
        if (f > 0.0) {
          rk4_dispatch(s, &in, y0, f * h, ym);
        } else {
          for (int j = 0; j < 4; ++j) ym[j] = y0[j];
        }
        if (it == 2 || f <= 0.0) break;
        const double gm = dir * drive_force(s, ym, &in) - p->F_static_N;
        if (gm == 0.0) break;
        if (gm < 0.0) {
          fa = f;
          ga = gm;
        } else {
          fb = f;
          gb = gm;
        }
        f = fa + (fb - fa) * (-ga) / (gb - ga);
      }
      in.mech_dir = (int)dir;
      st->stuck = 0;
      if (f < 1.0) {
        rk4_dispatch(s, &in, ym, (1.0 - f) * h, y1);
      } else {
        for (int j = 0; j < 4; ++j) y1[j] = ym[j];
      }
      for (int j = 0; j < 4; ++j) y0[j] = ym[j]; /* start of the sliding part */
      h *= 1.0 - f;
    }
  }

  /* sliding ended? velocity crossed zero, or entered the stick band */
  if (in.mech_dir != 0) {
    const int crossed = (in.mech_dir > 0) ? (y1[3] <= 0.0) : (y1[3] >= 0.0);
    /* without any friction force the reversal is smooth: no event */
    const int friction = p->F_coulomb_N != 0.0 || p->F_static_N != 0.0;
    if (crossed && friction && y0[3] != y1[3]) {
      /* v crossed zero inside the sub-step: locate the crossing (regula
       * falsi on v, re-integrating from the sub-step start; three RK4 passes,
       * only at this rare event), then decide stick or reversal there and
       * integrate the rest with the right friction (stuck, or Coulomb of
       * the new direction) */
      double fa = 0.0, va = y0[3], fb = 1.0, vb = y1[3];
      double f = va / (va - vb);
      double ym[4];
      for (int it = 0;; ++it) {
        if (f > 0.0) {
          rk4_dispatch(s, &in, y0, f * h, ym);
        } else {
          for (int j = 0; j < 4; ++j) ym[j] = y0[j];
        }
        const double vm = ym[3];
        if (it == 2 || vm == 0.0) break;
        if ((vm > 0.0) == (va > 0.0)) {
          fa = f;
          va = vm;
        } else {
          fb = f;
          vb = vm;
        }
        f = fa + (fb - fa) * va / (va - vb);
      }
      ym[3] = 0.0;
      const double F_drive = drive_force(s, ym, &in);
      if (fabs(F_drive) <= p->F_static_N) {
        in.mech_dir = 0; /* static friction holds: stick */
        st->stuck = 1;
      } else {
        in.mech_dir = F_drive > 0.0 ? 1 : -1; /* keeps going the other way */
      }
      if (f < 1.0) {
        rk4_dispatch(s, &in, ym, (1.0 - f) * h, y1);
      } else {
        for (int j = 0; j < 4; ++j) y1[j] = ym[j];
      }
      if (in.mech_dir == 0) y1[3] = 0.0;
    } else if (fabs(y1[3]) < p->v_stick_mps) {
      const double y1z[4] = {y1[0], y1[1], y1[2], 0.0};
      if (fabs(drive_force(s, y1z, &in)) <= p->F_static_N) {
        y1[3] = 0.0; /* static friction holds: stick */
        st->stuck = 1;
      }
    }
  }
  /* diode conduction ends when the current vector reverses or vanishes (after
   * the mechanical events, which may redo the sub-step) */
  if (!pwm_on && !in.elec_open) {
    const double th1 = s->k_theta * y1[2];
    const double c1 = cos(th1), s1 = sin(th1);  /* rare path: exact */
    const double a1 = c1 * y1[0] - s1 * y1[1], b1 = s1 * y1[0] + c1 * y1[1];
    if (a1 * i_al + b1 * i_be <= 0.0 || sqrt(a1 * a1 + b1 * b1) < 1e-3) {
      y1[0] = 0.0;
      y1[1] = 0.0;
    }
  }
  if (p->open_phase_mask) {
    /* open phase j: no current along its axis (the floating terminal takes
     * whatever voltage that needs); rare path, exact trigonometry */
    const double th1 = s->k_theta * y1[2];
    const double c1 = cos(th1), s1 = sin(th1);
    double a1 = c1 * y1[0] - s1 * y1[1], b1 = s1 * y1[0] + c1 * y1[1];
    for (int j = 0; j < 3; ++j) {
      if (!(p->open_phase_mask & (1u << j))) continue;
      const double nx = cos(2.0 * SIM_PI / 3.0 * j), ny = sin(2.0 * SIM_PI / 3.0 * j);
      const double dot = a1 * nx + b1 * ny;
      a1 -= dot * nx;
      b1 -= dot * ny;
    }
    y1[0] = c1 * a1 + s1 * b1;
    y1[1] = -s1 * a1 + c1 * b1;
  }
  state_store(st, y1);
}

/**
 * The common sub-steps (PWM on without dead time, no cogging, no open phase):
 * the mover sliding and still sliding the same way at the end, clear of the
 * stick band; or held by static friction over the whole sub-step. The same
 * operations as substep() in those cases, without its event handling. Returns
 * 0 without touching the state when the sub-step is not one of them: the
 * caller then runs substep() from the same start (the basis update done here
 * is idempotent).
 */
static int substep_fast(sim_t *s, double h, const double u_ab[2]) {
  const sim_plant_params_t *p = &s->p;
  sim_plant_state_t *st = &s->st;
  basis_ensure(s, st->x_m, st->i_d_A);
  substep_in_t in;
  substep_in_begin(s, &in);
  substep_in_voltage(s, u_ab, &in);
  double y0[4] = {st->i_d_A, st->i_q_A, st->x_m, st->v_mps};
  double y1[4];
  if (st->stuck || st->v_mps == 0.0) {
    in.mech_dir = 0;
    if (fabs(drive_force(s, y0, &in)) > p->F_static_N) return 0; /* breaks away */
    y0[3] = 0.0;
    rk4_stuck(s, &in, y0, h, y1);
    if (fabs(drive_force(s, y1, &in)) > p->F_static_N) return 0; /* breaks away inside */
    st->stuck = 1;
    state_store(st, y1);
    return 1;
  }
  in.mech_dir = st->v_mps > 0.0 ? 1 : -1;
  rk4_slide(s, &in, y0, h, y1);
  /* substep()'s end-of-sliding tests: velocity reversal or stick band */
  const int crossed = (in.mech_dir > 0) ? (y1[3] <= 0.0) : (y1[3] >= 0.0);
  if (crossed || fabs(y1[3]) < p->v_stick_mps) return 0;
  state_store(st, y1);
  return 1;
}

/* Not inlined into sim_run (link-time optimisation did that when this function
 * was smaller): inlined there, one process in two ran the closed loop ~11 %
 * slower (262 instead of 235 ns per period, paper_salient load step), which of
 * the two set by where the stack landed (address-space randomisation); called,
 * every process runs at the fast figure. */
#if defined(__GNUC__)
__attribute__((noinline))
#endif
void sim_plant_period(sim_t *s, const double duty[3], int pwm_on, double dt_s,
                      uint32_t n_sub) {
  if (n_sub == 0u) n_sub = 1u;
  const double h = dt_s / (double)n_sub;
  double u_ab[2];
  const double *u_fixed = NULL;
  if (pwm_on && s->u_dt_V == 0.0 && !s->real_inv) {
    const double ua = duty[0] * s->p.u_dc_V, ub = duty[1] * s->p.u_dc_V,
                 uc = duty[2] * s->p.u_dc_V;
    u_ab[0] = (2.0 / 3.0) * (ua - 0.5 * ub - 0.5 * uc);
    u_ab[1] = (ub - uc) * (1.0 / SIM_SQRT3);
    u_fixed = u_ab;
  }
  const int fast = u_fixed && !s->p.locked && s->p.cog_amp_N == 0.0 && !s->p.open_phase_mask &&
                   !s->real_mag;
  for (uint32_t j = 0; j < n_sub; ++j)
    if (!(fast && substep_fast(s, h, u_fixed))) substep(s, duty, pwm_on, h, u_fixed);
}
