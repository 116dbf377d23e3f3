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

void sim_rng_seed(sim_t *s, uint64_t seed) {
  uint64_t x = seed;
  for (int i = 0; i < 4; ++i) s->rng[i] = splitmix64(&x);
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

static inline uint64_t rotl64(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }

static inline uint64_t xoshiro_next(uint64_t r[4]) {
  const uint64_t result = rotl64(r[1] * 5u, 7) * 9u;
  const uint64_t t = r[1] << 17;
  r[2] ^= r[0];
  r[3] ^= r[1];
  r[1] ^= r[2];
  r[0] ^= r[3];
  r[2] ^= t;
  r[3] = rotl64(r[3], 45);
  return result;
}

/** Uniform in (0, 1], 53-bit resolution. */
static inline double rng_uniform(sim_t *s) {
  return ((double)(xoshiro_next(s->rng) >> 11) + 1.0) * 0x1.0p-53;
}

/** Standard normal deviate (ziggurat; ~99 % of draws take the fast path). */
double sim_rng_gauss(sim_t *s) {
  for (;;) {
    const uint64_t r = xoshiro_next(s->rng);
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
  }
}

/* ---- plant ------------------------------------------------------------- */

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
  s->u_dt_V = p->u_dc_V * p->dead_time_s * p->f_pwm_Hz;
  s->inv_L_q = 1.0 / p->L_q_H;
  s->inv_mass = 1.0 / p->mass_kg;
  s->inv_I_sat = 1.0 / p->I_sat_A;
  s->k_cog = 2.0 * SIM_PI / p->cog_period_m;
  s->k_dL_Isat = p->dL_sat_H * p->I_sat_A;
  s->basis_valid = 0;
}

/** ln cosh(z), overflow free. */
static inline double lncosh(double z) {
  const double a = fabs(z);
  return a + log1p(exp(-2.0 * a)) - 0.69314718055994530942;
}

/*
 * Cheap stage evaluations. Inside one PWM period the angle moves by
 * omega_e T (1.7e-3 rad at 100 r/min) and i_d by a fraction of an ampere, so
 * every RK stage expands sin/cos and tanh/ln cosh around a basis point
 * computed exactly with libm:
 *   sin/cos(th0 + d): rotation by d with 4th/5th-order Taylor cos d, sin d
 *                      (truncation < 2e-11 for |d| <= 0.045),
 *   tanh(z0 + e) = T + S e - T S e^2 + S (3T^2 - 1) e^3 / 3
 *                  + T S (2 - 3T^2) e^4 / 3,                         S = 1 - T^2
 *   ln cosh(z0 + e) = g + T e + S e^2 / 2 - T S e^3 / 3 + S (3T^2 - 1) e^4 / 12
 *                  + T S (2 - 3T^2) e^5 / 15
 *                      (truncation < 2e-8 dL for |e| <= 0.05).
 * The basis is refreshed at a sub-step start whenever |d| > 0.03 rad or
 * |e| > 0.05 (i_d moved by 0.05 I_sat), so the expansion error stays far below
 * the model's own accuracy; the HF ripple of the injection (a few tenths of
 * an ampere) does not force a refresh every sub-step.
 */
#define BASIS_MAX_DTH 0.03
#define BASIS_MAX_DZ 0.05

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

/** Flux part of the basis: exact tanh and ln cosh of i_d / I_sat. */
static void basis_update_flux(sim_t *s, double i_d_A) {
  s->b_id0 = i_d_A;
  const double z = i_d_A * s->inv_I_sat;
  s->b_T0 = tanh(z);
  s->b_S0 = 1.0 - s->b_T0 * s->b_T0;
  s->b_g0 = lncosh(z);
}

static inline void basis_ensure(sim_t *s, double x_m, double i_d_A) {
  if (!s->basis_valid) {
    basis_update_angle(s, x_m);
    basis_update_flux(s, i_d_A);
    s->basis_valid = 1;
    return;
  }
  const double dx = x_m - s->b_x0;
  if (fabs(s->k_theta * dx) > BASIS_MAX_DTH ||
      (s->p.cog_amp_N != 0.0 && fabs(s->k_cog * dx) > BASIS_MAX_DTH))
    basis_update_angle(s, x_m);
  if (s->p.dL_sat_H != 0.0 && fabs((i_d_A - s->b_id0) * s->inv_I_sat) > BASIS_MAX_DZ)
    basis_update_flux(s, i_d_A);
}

/**
 * cos, sin of (angle0 + d) from cos/sin of angle0: Taylor cos d to d^4,
 * sin d to d^5 (truncation < 2e-11 resp. 1e-13 for |d| <= 1.5 BASIS_MAX_DTH),
 * libm beyond.
 */
static inline void rot_taylor(double c0, double s0, double d, double *c, double *sn) {
  double cd, sd;
  if (fabs(d) > 1.5 * BASIS_MAX_DTH) { /* far stage (huge step): exact */
    cd = cos(d);
    sd = sin(d);
  } else {
    const double d2 = d * d;
    cd = 1.0 - d2 * (0.5 - d2 * (1.0 / 24.0));
    sd = d * (1.0 - d2 * (1.0 / 6.0 - d2 * (1.0 / 120.0)));
  }
  *c = c0 * cd - s0 * sd;
  *sn = s0 * cd + c0 * sd;
}

/** Exact (libm) psi_d(i_d) and incremental L_dd(i_d). */
static inline void d_axis_flux_exact(const sim_plant_params_t *p, double i_d, double *psi_d,
                                     double *L_dd) {
  if (p->dL_sat_H == 0.0) {
    *psi_d = p->psi_f_Wb + p->L_d0_H * i_d;
    *L_dd = p->L_d0_H;
    return;
  }
  const double z = i_d / p->I_sat_A;
  *psi_d = p->psi_f_Wb + p->L_d0_H * i_d - p->dL_sat_H * p->I_sat_A * lncosh(z);
  *L_dd = p->L_d0_H - p->dL_sat_H * tanh(z);
}

/** psi_d and L_dd from the basis expansion. */
static inline void d_axis_flux(const sim_t *s, double i_d, double *psi_d, double *L_dd) {
  const sim_plant_params_t *p = &s->p;
  if (p->dL_sat_H == 0.0) {
    *psi_d = p->psi_f_Wb + p->L_d0_H * i_d;
    *L_dd = p->L_d0_H;
    return;
  }
  const double e = (i_d - s->b_id0) * s->inv_I_sat;
  if (fabs(e) > 1.5 * BASIS_MAX_DZ) { /* far stage (huge step): exact */
    d_axis_flux_exact(p, i_d, psi_d, L_dd);
    return;
  }
  const double T = s->b_T0, S = s->b_S0, c3 = S * (3.0 * T * T - 1.0);
  const double c4 = T * S * (2.0 - 3.0 * T * T);
  const double th = T + e * (S + e * (-T * S + e * (c3 / 3.0 + e * (c4 / 3.0))));
  const double lc =
      s->b_g0 + e * (T + e * (0.5 * S + e * (-T * S / 3.0 + e * (c3 / 12.0 + e * (c4 / 15.0)))));
  *psi_d = p->psi_f_Wb + p->L_d0_H * i_d - s->k_dL_Isat * lc;
  *L_dd = p->L_d0_H - p->dL_sat_H * th;
}

void sim_plant_sincos(sim_t *s, double x_m, double *c, double *sn) {
  const double d = s->k_theta * (x_m - s->b_x0);
  if (s->basis_valid && fabs(d) <= BASIS_MAX_DTH) {
    rot_taylor(s->b_c0, s->b_s0, d, c, sn);
  } else {
    *c = cos(s->k_theta * x_m);
    *sn = sin(s->k_theta * x_m);
  }
}

double sim_plant_force(const sim_t *s, const sim_plant_state_t *st) {
  double psi_d, L_dd;
  if (s->basis_valid)
    d_axis_flux(s, st->i_d_A, &psi_d, &L_dd); /* expansion (exact when far) */
  else
    d_axis_flux_exact(&s->p, st->i_d_A, &psi_d, &L_dd);
  return s->k_force * (psi_d * st->i_q_A - s->p.L_q_H * st->i_q_A * st->i_d_A);
}

/** Inputs held constant over one RK4 sub-step. */
typedef struct {
  double u_ab_V[2];   /**< stator voltage, stationary frame */
  double u_dq0_V[2];  /**< the same in the rotor frame at the basis angle */
  double F_load_N;
  int mech_dir;       /**< 0: stuck/locked; +1/-1: sliding direction (Coulomb sign) */
  int elec_open;      /**< 1: PWM off and currents extinct: i held at 0 */
} substep_in_t;

/* Inlined into the RK4 stages so that k1..k4 stay in registers (a call
 * returning them through memory costs store-forwarding stalls). */
#if defined(__GNUC__)
#define SIM_INLINE static inline __attribute__((always_inline))
#else
#define SIM_INLINE static inline
#endif

/** dy/dt for y = {i_d, i_q, x, v}. Returns the net drive force (without friction). */
SIM_INLINE double deriv(const sim_t *s, const double y[4], const substep_in_t *in,
                    double dy[4]) {
  const sim_plant_params_t *p = &s->p;
  const double dx = y[2] - s->b_x0;
  /* rotor-frame voltage: the basis-frame voltage rotated back by the stage's
   * angle offset d (cos/sin(-d) = cos d, -sin d) */
  double cd, sd;
  rot_taylor(1.0, 0.0, s->k_theta * dx, &cd, &sd);
  const double u_d = cd * in->u_dq0_V[0] + sd * in->u_dq0_V[1];
  const double u_q = cd * in->u_dq0_V[1] - sd * in->u_dq0_V[0];
  const double w = s->k_theta * y[3];
  double psi_d, L_dd;
  d_axis_flux(s, y[0], &psi_d, &L_dd);
  if (in->elec_open) {
    dy[0] = 0.0;
    dy[1] = 0.0;
  } else {
    dy[0] = (u_d - p->R_ohm * y[0] + w * p->L_q_H * y[1]) / L_dd;
    dy[1] = (u_q - p->R_ohm * y[1] - w * psi_d) * s->inv_L_q;
  }
  const double F_em = s->k_force * (psi_d * y[1] - p->L_q_H * y[1] * y[0]);
  double F_cog = 0.0;
  if (p->cog_amp_N != 0.0) {
    double cc, cs;
    rot_taylor(s->b_cc0, s->b_cs0, s->k_cog * dx, &cc, &cs);
    F_cog = p->cog_amp_N * cs;
  }
  const double F_drive = F_em + F_cog - in->F_load_N;
  if (in->mech_dir == 0) {
    dy[2] = 0.0;
    dy[3] = 0.0;
  } else {
    dy[2] = y[3];
    dy[3] = (F_drive - p->b_visc_Ns_per_m * y[3] - p->F_coulomb_N * (double)in->mech_dir) *
            s->inv_mass;
  }
  return F_drive;
}

/** Linearised sign for the dead-time error. */
static inline double sgn_band(double i, double band) {
  if (band <= 0.0) return (i > 0.0) ? 1.0 : ((i < 0.0) ? -1.0 : 0.0);
  const double r = i / band;
  return r > 1.0 ? 1.0 : (r < -1.0 ? -1.0 : r);
}

/** One RK4 sub-step of length h. */
static void substep(sim_t *s, const double duty[3], int pwm_on, double h,
                    const double *u_ab_fixed) {
  const sim_plant_params_t *p = &s->p;
  sim_plant_state_t *st = &s->st;
  basis_ensure(s, st->x_m, st->i_d_A);
  substep_in_t in;
  in.F_load_N = s->F_load_N;
  in.elec_open = 0;
  double i_al = 0.0, i_be = 0.0;
  if (u_ab_fixed) {
    /* ideal inverter: the voltage is the same for every sub-step */
    in.u_ab_V[0] = u_ab_fixed[0];
    in.u_ab_V[1] = u_ab_fixed[1];
  } else {
    /* phase currents at sub-step start select dead-time error / diode rail */
    double c, sn;
    rot_taylor(s->b_c0, s->b_s0, s->k_theta * (st->x_m - s->b_x0), &c, &sn);
    i_al = c * st->i_d_A - sn * st->i_q_A;
    i_be = sn * st->i_d_A + c * st->i_q_A;
    const double i_abc[3] = {i_al, -0.5 * i_al + 0.5 * SIM_SQRT3 * i_be,
                             -0.5 * i_al - 0.5 * SIM_SQRT3 * i_be};
    double u_pole[3];
    if (pwm_on) {
      for (int j = 0; j < 3; ++j)
        u_pole[j] = duty[j] * p->u_dc_V - s->u_dt_V * sgn_band(i_abc[j], p->dead_band_A);
    } else if (i_al * i_al + i_be * i_be > 1e-12) {
      /* switches off: freewheeling diodes clamp each pole to a rail */
      for (int j = 0; j < 3; ++j) u_pole[j] = (i_abc[j] < 0.0) ? p->u_dc_V : 0.0;
    } else {
      for (int j = 0; j < 3; ++j) u_pole[j] = 0.0;
      in.elec_open = 1;
    }
    in.u_ab_V[0] = (2.0 / 3.0) * (u_pole[0] - 0.5 * u_pole[1] - 0.5 * u_pole[2]);
    in.u_ab_V[1] = (u_pole[1] - u_pole[2]) * (1.0 / SIM_SQRT3);
  }

  in.u_dq0_V[0] = s->b_c0 * in.u_ab_V[0] + s->b_s0 * in.u_ab_V[1];
  in.u_dq0_V[1] = -s->b_s0 * in.u_ab_V[0] + s->b_c0 * in.u_ab_V[1];

  /* mechanics: stuck, or sliding in a fixed direction for this sub-step */
  double y0[4] = {st->i_d_A, st->i_q_A, st->x_m, st->v_mps};
  double k1[4], k2[4], k3[4], k4[4], yt[4];
  if (p->locked) {
    in.mech_dir = 0;
  } else if (st->stuck || st->v_mps == 0.0) {
    in.mech_dir = 0;
    const double F_drive = deriv(s, y0, &in, k1);
    if (fabs(F_drive) > p->F_static_N) {
      in.mech_dir = F_drive > 0.0 ? 1 : -1;
      st->stuck = 0;
    } else {
      st->stuck = 1;
      st->v_mps = 0.0;
      y0[3] = 0.0;
    }
  } else {
    in.mech_dir = st->v_mps > 0.0 ? 1 : -1;
  }

  deriv(s, y0, &in, k1);
  for (int j = 0; j < 4; ++j) yt[j] = y0[j] + 0.5 * h * k1[j];
  deriv(s, yt, &in, k2);
  for (int j = 0; j < 4; ++j) yt[j] = y0[j] + 0.5 * h * k2[j];
  deriv(s, yt, &in, k3);
  for (int j = 0; j < 4; ++j) yt[j] = y0[j] + h * k3[j];
  (void)deriv(s, yt, &in, k4);
  double y1[4];
  for (int j = 0; j < 4; ++j) y1[j] = y0[j] + h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]);

  /* diode conduction ends when the current vector reverses or vanishes */
  if (!pwm_on && !in.elec_open) {
    const double th1 = s->k_theta * y1[2];
    const double c1 = cos(th1), s1 = sin(th1);  /* rare path: exact */
    const double a1 = c1 * y1[0] - s1 * y1[1], b1 = s1 * y1[0] + c1 * y1[1];
    if (a1 * i_al + b1 * i_be <= 0.0 || sqrt(a1 * a1 + b1 * b1) < 1e-3) {
      y1[0] = 0.0;
      y1[1] = 0.0;
    }
  }
  /* sliding ended? velocity crossed zero, or entered the stick band */
  if (in.mech_dir != 0) {
    const double dir = (double)in.mech_dir;
    const int crossed = (in.mech_dir > 0) ? (y1[3] <= 0.0) : (y1[3] >= 0.0);
    if (crossed || fabs(y1[3]) < p->v_stick_mps) {
      double dtmp[4];
      substep_in_t in0 = in;
      in0.mech_dir = 0;
      const double y1z[4] = {y1[0], y1[1], y1[2], 0.0};
      const double F_drive = deriv(s, y1z, &in0, dtmp);
      if (fabs(F_drive) <= p->F_static_N) {
        y1[3] = 0.0; /* static friction holds: stick */
        st->stuck = 1;
      } else if (crossed) {
        /* keeps going the other way: after the crossing (fraction f of the
         * sub-step, linear estimate) Coulomb friction flips sign, which
         * adds 2 F_c dir / m over the rest of the sub-step */
        const double f = y0[3] / (y0[3] - y1[3]);
        const double v = y1[3] + (1.0 - f) * h * 2.0 * p->F_coulomb_N * dir * s->inv_mass;
        if (v * dir >= 0.0) {
          y1[3] = 0.0;
          st->stuck = 1;
        } else {
          y1[3] = v;
        }
      }
    }
  }
  st->i_d_A = y1[0];
  st->i_q_A = y1[1];
  st->x_m = y1[2];
  st->v_mps = y1[3];
}

void sim_plant_period(sim_t *s, const double duty[3], int pwm_on, double dt_s,
                      uint32_t n_sub) {
  if (n_sub == 0u) n_sub = 1u;
  const double h = dt_s / (double)n_sub;
  double u_ab[2];
  const double *u_fixed = NULL;
  if (pwm_on && s->u_dt_V == 0.0) {
    const double ua = duty[0] * s->p.u_dc_V, ub = duty[1] * s->p.u_dc_V,
                 uc = duty[2] * s->p.u_dc_V;
    u_ab[0] = (2.0 / 3.0) * (ua - 0.5 * ub - 0.5 * uc);
    u_ab[1] = (ub - uc) * (1.0 / SIM_SQRT3);
    u_fixed = u_ab;
  }
  for (uint32_t j = 0; j < n_sub; ++j) substep(s, duty, pwm_on, h, u_fixed);
}
