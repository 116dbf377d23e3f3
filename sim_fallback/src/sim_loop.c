/*
 * Batch closed loop: ADC sampling -> plant integration over one PWM period
 * with the duties latched one period earlier -> controller step (function
 * pointer) on the samples. The plant's period does not depend on this
 * period's controller step, so it is issued before it: the processor then
 * overlaps the sampling's dependency chain with the plant's, and the start of
 * the controller step with the plant's end (~2 % per period, same values).
 * Schedules and recording are handled here so a whole scenario runs in one C
 * call.
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "sim_internal.h"

/* ---- parameters -------------------------------------------------------- */

#define CHECK(cond, name)                                                      \
  do {                                                                         \
    if (!(cond)) {                                                             \
      if (bad_field) *bad_field = name;                                        \
      return -(++idx);                                                         \
    }                                                                          \
    ++idx;                                                                     \
  } while (0)

#define POS(f) CHECK(isfinite(p->f) && p->f > 0.0, #f)
#define NONNEG(f) CHECK(isfinite(p->f) && p->f >= 0.0, #f)

int sim_params_check(const sim_plant_params_t *p, const char **bad_field) {
  int idx = 0;
  if (bad_field) *bad_field = NULL;
  if (!p) return -1;
  POS(R_ohm);
  POS(L_d0_H);
  POS(L_q_H);
  NONNEG(psi_f_Wb);
  NONNEG(dL_sat_H);
  CHECK(p->dL_sat_H < p->L_d0_H, "dL_sat_H");
  POS(I_sat_A);
  POS(tau_m);
  POS(mass_kg);
  NONNEG(b_visc_Ns_per_m);
  NONNEG(F_coulomb_N);
  CHECK(isfinite(p->F_static_N) && p->F_static_N >= p->F_coulomb_N, "F_static_N");
  NONNEG(v_stick_mps);
  NONNEG(cog_amp_N);
  POS(cog_period_m);
  CHECK(isfinite(p->cog_phase_rad), "cog_phase_rad");
  POS(u_dc_V);
  POS(f_pwm_Hz);
  NONNEG(dead_time_s);
  CHECK(p->dead_time_s * p->f_pwm_Hz < 0.2, "dead_time_s");
  NONNEG(dead_band_A);
  CHECK(p->n_sub >= 1u && p->n_sub <= 1024u, "n_sub");
  CHECK(p->adc_bits >= 8u && p->adc_bits <= 16u, "adc_bits");
  POS(adc_i_fullscale_A);
  NONNEG(adc_noise_counts);
  for (int j = 0; j < 3; ++j) {
    CHECK(isfinite(p->adc_offset_counts[j]), "adc_offset_counts");
    CHECK(isfinite(p->adc_gain_err[j]) && fabs(p->adc_gain_err[j]) < 0.5, "adc_gain_err");
  }
  CHECK(isfinite(p->udc_fullscale_V) && p->udc_fullscale_V > p->u_dc_V, "udc_fullscale_V");
  NONNEG(udc_noise_V);
  CHECK(isfinite(p->ref_res_m) && p->ref_res_m >= 0.0 && p->ref_res_m <= 0.01, "ref_res_m");
  CHECK(isfinite(p->ref_offset_m) && fabs(p->ref_offset_m) <= 1000.0, "ref_offset_m");
  CHECK(p->ref_fault <= 1u, "ref_fault");
  CHECK(p->noise_restart <= 1u, "noise_restart");
  return 0;
}

#define RNONNEG(f) CHECK(isfinite(r->f) && r->f >= 0.0, #f)

int sim_realism_check(const sim_plant_params_t *p, const sim_realism_t *r,
                      const char **bad_field) {
  int idx = 0;
  if (bad_field) *bad_field = NULL;
  if (!p || !r) return -1;
  RNONNEG(dLq_sat_H);
  CHECK(r->dLq_sat_H < p->L_q_H, "dLq_sat_H");
  CHECK(r->dLq_sat_H == 0.0 || (isfinite(r->Iq_sat_A) && r->Iq_sat_A > 0.0), "Iq_sat_A");
  RNONNEG(cross_L_H);
  CHECK(r->cross_L_H == 0.0 || (isfinite(r->cross_I_A) && r->cross_I_A > 0.0), "cross_I_A");
  RNONNEG(sal2_L_H);
  CHECK(r->sal2_L_H == 0.0 || (r->sal2_order >= 1u && r->sal2_order <= 12u), "sal2_order");
  CHECK(isfinite(r->sal2_phase_rad), "sal2_phase_rad");
  CHECK(isfinite(r->emf_h5) && r->emf_h5 >= 0.0 && r->emf_h5 <= 0.5, "emf_h5");
  CHECK(isfinite(r->emf_h5_phase_rad), "emf_h5_phase_rad");
  CHECK(isfinite(r->emf_h7) && r->emf_h7 >= 0.0 && r->emf_h7 <= 0.5, "emf_h7");
  CHECK(isfinite(r->emf_h7_phase_rad), "emf_h7_phase_rad");
  RNONNEG(end_dL_H);
  CHECK(isfinite(r->end_psi_frac) && r->end_psi_frac >= 0.0 && r->end_psi_frac < 1.0,
        "end_psi_frac");
  CHECK(isfinite(r->end_base) && r->end_base >= 0.0 && r->end_base <= 1.0, "end_base");
  RNONNEG(end_travel_m);
  CHECK(r->end_travel_m == 0.0 || (isfinite(r->end_zone_m) && r->end_zone_m > 0.0),
        "end_zone_m");
  RNONNEG(dt_C_eq_F);
  RNONNEG(u_dev_V);
  RNONNEG(r_dev_ohm);
  /* the incremental inductance positive definite (at least 10 % of the smaller
   * unsaturated one) over twice the current ADC's range */
  CHECK(!(r->dLq_sat_H != 0.0 || r->cross_L_H != 0.0 || r->sal2_L_H != 0.0 ||
          r->end_dL_H != 0.0) ||
            sim_plant_min_inductance(p, r, 2.0 * p->adc_i_fullscale_A) >=
                0.1 * fmin(p->L_d0_H - p->dL_sat_H, p->L_q_H - r->dLq_sat_H),
        r->cross_L_H != 0.0 ? "cross_L_H" : (r->sal2_L_H != 0.0 ? "sal2_L_H" : "end_dL_H"));
  return 0;
}

/* ---- life cycle -------------------------------------------------------- */

_Static_assert(offsetof(sim_t, flux_tab) + sizeof(((sim_t *)0)->flux_tab) == sizeof(sim_t),
               "sim_new leaves the flux grid, the last member of sim_t, unzeroed");

size_t sim_sizeof(void) { return sizeof(sim_t); }

sim_t *sim_init_in(void *mem, size_t size, const sim_plant_params_t *p) {
  if (!mem || size < sizeof(sim_t) || ((uintptr_t)mem & 7u) != 0u) return NULL;
  if (sim_params_check(p, NULL) != 0) return NULL;
  /* Zeroed but for the flux grid (the last member, ~90 KiB): an entry is only
   * read once flux_ok marks it computed. calloc zeroed all of it in every
   * run (a reused heap block), ~100k instructions and the cache lines with them. */
  sim_t *s = (sim_t *)mem;
  memset(s, 0, offsetof(sim_t, flux_tab));
  s->p = *p;
  sim_plant_derive(s);
  sim_rng_seed(s, p->seed);
  s->duty[0] = s->duty[1] = s->duty[2] = 0.5;
  for (int k = 0; k < SIM_REF_COUNT; ++k) s->sched[k].last_sent = (double)NAN;
  s->sched_next_t = -(double)INFINITY;
  return s;
}

sim_t *sim_new(const sim_plant_params_t *p) {
  void *mem = malloc(sizeof(sim_t));
  if (!mem) return NULL;
  sim_t *s = sim_init_in(mem, sizeof(sim_t), p);
  if (!s) free(mem);
  return s;
}

void sim_set_load(sim_t *s, double F_N) {
  if (s && isfinite(F_N)) s->F_load_N = F_N;
}

int sim_set_params(sim_t *s, const sim_plant_params_t *p, const char **bad_field) {
  if (!s) return -1;
  int rc = sim_params_check(p, bad_field);
  if (rc == 0) rc = sim_realism_check(p, &s->r, bad_field); /* the realism still fits */
  if (rc != 0) return rc;
  s->p = *p;
  sim_plant_derive(s);
  return 0;
}

int sim_set_realism(sim_t *s, const sim_realism_t *r, const char **bad_field) {
  if (!s) return -1;
  const sim_realism_t off = {0};
  if (!r) r = &off;
  const int rc = sim_realism_check(&s->p, r, bad_field);
  if (rc != 0) return rc;
  s->r = *r;
  sim_plant_derive(s);
  return 0;
}

void sim_free(sim_t *s) {
  if (!s) return;
  for (int k = 0; k < SIM_REF_COUNT; ++k) {
    free(s->sched[k].t_s);
    free(s->sched[k].value);
  }
  free(s);
}

void sim_set_controller(sim_t *s, const sim_controller_t *c) {
  if (s && c) {
    s->ctrl = *c;
    s->bg_in = 0u;
    s->sched_next_t = -(double)INFINITY; /* references go to the new controller */
  }
}

void sim_set_use_adc_counts(sim_t *s, int on) {
  if (s) s->use_adc = on ? 1 : 0;
}

int sim_set_schedule(sim_t *s, sim_ref_kind_t kind, const double *t_s,
                     const double *value, uint32_t n, uint32_t ramp) {
  if (!s || (unsigned)kind >= (unsigned)SIM_REF_COUNT) return -1;
  if (n > 0u && (!t_s || !value)) return -1;
  for (uint32_t i = 0; i < n; ++i) {
    if (!isfinite(t_s[i]) || !isfinite(value[i])) return -1;
    if (i > 0u && t_s[i] < t_s[i - 1u]) return -1;
  }
  sim_sched_store_t *sc = &s->sched[kind];
  s->sched_next_t = -(double)INFINITY;
  free(sc->t_s);
  free(sc->value);
  sc->t_s = sc->value = NULL;
  sc->n = 0u;
  sc->cursor = 0u;
  sc->ramp = ramp ? 1u : 0u;
  sc->last_sent = (double)NAN;
  if (n == 0u) return 0;
  sc->t_s = (double *)malloc(n * sizeof(double));
  sc->value = (double *)malloc(n * sizeof(double));
  if (!sc->t_s || !sc->value) return -1;
  memcpy(sc->t_s, t_s, n * sizeof(double));
  memcpy(sc->value, value, n * sizeof(double));
  sc->n = n;
  return 0;
}

void sim_set_state(sim_t *s, const sim_plant_state_t *st) {
  if (!s || !st) return;
  s->st = *st;
  s->basis_valid = 0; /* expansion point of sim_plant.c must be recomputed */
}
void sim_get_state(const sim_t *s, sim_plant_state_t *st) {
  if (s && st) *st = s->st;
}
void sim_set_latched_duty(sim_t *s, const double duty_abc[3], int pwm_enable) {
  if (!s || !duty_abc) return;
  for (int j = 0; j < 3; ++j) s->duty[j] = duty_abc[j];
  s->pwm_on = pwm_enable ? 1 : 0;
}
double sim_time_s(const sim_t *s) { return s ? s->t_s : 0.0; }
uint64_t sim_step_count(const sim_t *s) { return s ? s->k : 0u; }

/** Schedule value at time t (NaN when the schedule is empty). */
static double sched_eval(sim_sched_store_t *sc, double t) {
  if (sc->n == 0u) return (double)NAN;
  if (t < sc->t_s[0]) return sc->value[0];
  /* cursor only moves forward; time is monotonic */
  while (sc->cursor + 1u < sc->n && sc->t_s[sc->cursor + 1u] <= t) ++sc->cursor;
  const uint32_t i = sc->cursor;
  if (!sc->ramp || i + 1u >= sc->n) return sc->value[i];
  const double t0 = sc->t_s[i], t1 = sc->t_s[i + 1u];
  if (t1 <= t0) return sc->value[i + 1u];
  const double a = (t - t0) / (t1 - t0);
  return sc->value[i] + a * (sc->value[i + 1u] - sc->value[i]);
}

/** Earliest time after t at which sched_eval(sc, .) may differ from its value at t
 * (sched_eval just called at t): the next breakpoint of a step schedule, +inf after
 * the last one, -inf inside a ramp (changes every period). */
static double sched_valid_until(const sim_sched_store_t *sc, double t) {
  if (t < sc->t_s[0]) return sc->t_s[0];
  if (sc->cursor + 1u >= sc->n) return (double)INFINITY;
  return sc->ramp ? -(double)INFINITY : sc->t_s[sc->cursor + 1u];
}

/** The references of the period at t: each schedule's value to the controller
 * (set_ref, when it changed) or the plant (load force). Returns the time until
 * which none of them changes: the batch loop calls this again only from then on
 * (before, every schedule would give the value last handed on, and nothing would
 * be called or changed). */
static double sched_apply(sim_t *s, double t) {
  double until = (double)INFINITY;
  for (int kd = 0; kd < SIM_REF_COUNT; ++kd) {
    sim_sched_store_t *sc = &s->sched[kd];
    if (sc->n == 0u) continue;
    const double v = sched_eval(sc, t);
    if (kd == SIM_REF_LOAD) {
      s->F_load_N = v;
    } else if (v != sc->last_sent) {
      if (!s->ctrl.set_ref) {
        until = -(double)INFINITY; /* not handed on: again next period */
        continue;
      }
      s->ctrl.set_ref(s->ctrl.ctx, (sim_ref_kind_t)kd, v);
      sc->last_sent = v;
    }
    const double u = sched_valid_until(sc, t);
    if (u < until) until = u;
  }
  return until;
}

double sim_sched_value(const sim_t *s, sim_ref_kind_t kind) {
  if (!s || (unsigned)kind >= (unsigned)SIM_REF_COUNT) return (double)NAN;
  sim_sched_store_t tmp = s->sched[kind];
  tmp.cursor = 0u;
  return sched_eval(&tmp, s->t_s);
}

/* ---- sensing ----------------------------------------------------------- */

static inline double clampd(double x, double lo, double hi) {
  return x < lo ? lo : (x > hi ? hi : x);
}

/** ADC count: x clamped to [0, max] (max an integer below 2^52), then rounded to
 * the nearest integer in the current rounding mode without a libm call (x86-64
 * before SSE4.1 has no rounding instruction): (c + 2^52) - 2^52 for 0 <= c < 2^52.
 * Clamping first gives the same count as rounding first for every x (NaN
 * included), and needs neither a range test nor the sign for the 2^52 trick. */
static inline double adc_quantise(double x, double max) {
  const double c = clampd(x, 0.0, max);
  return (c + 0x1p52) - 0x1p52;
}

/** The ADC model: current counts cnt[0..2] and the DC-link count cnt[3] at the
 * present state (noise drawn in the order phase a, b, c, DC link). Per-phase
 * constants from sim_plant_derive: adc_base = adc_mid + offset, adc_gain1 =
 * 1 + gain error, so cnt = adc_base + i (1 + gain err) / lsb is evaluated as the
 * model writes it, operation for operation. The counts are held in scalars, not
 * an array: the compiler kept the array on the stack, stored its elements one by
 * one and read two of them back as one 16-byte load (adc_last_cnt), which cannot
 * be forwarded from two stores and stalled every period (~12 % of sample_adc). */
SIM_INLINE void sample_counts(sim_t *s, double cnt[4]) {
  const sim_plant_params_t *p = &s->p;
  double c, sn;
  sim_plant_sincos(s, s->st.x_m, &c, &sn);
  const double i_al = c * s->st.i_d_A - sn * s->st.i_q_A;
  const double i_be = sn * s->st.i_d_A + c * s->st.i_q_A;
  const double i_b = -0.5 * i_al + 0.5 * SIM_SQRT3 * i_be;
  const double i_c = -0.5 * i_al - 0.5 * SIM_SQRT3 * i_be;
  double ca = s->adc_base[0] + i_al * s->adc_gain1[0] * s->inv_adc_lsb_A;
  double cb = s->adc_base[1] + i_b * s->adc_gain1[1] * s->inv_adc_lsb_A;
  double cc = s->adc_base[2] + i_c * s->adc_gain1[2] * s->inv_adc_lsb_A;
  double u = p->u_dc_V;
  const double sig_i = p->adc_noise_counts, sig_u = p->udc_noise_V;
  if (sig_i > 0.0 || sig_u > 0.0) {
    uint64_t ra = s->rng[0], rb = s->rng[1], rc = s->rng[2], rd = s->rng[3];
    if (sig_i > 0.0) {
      ca += sig_i * sim_rng_gauss4(s, &ra, &rb, &rc, &rd);
      cb += sig_i * sim_rng_gauss4(s, &ra, &rb, &rc, &rd);
      cc += sig_i * sim_rng_gauss4(s, &ra, &rb, &rc, &rd);
    }
    if (sig_u > 0.0) u += sig_u * sim_rng_gauss4(s, &ra, &rb, &rc, &rd);
    s->rng[0] = ra;
    s->rng[1] = rb;
    s->rng[2] = rc;
    s->rng[3] = rd;
  }
  const double top = s->adc_max;
  ca = adc_quantise(ca, top);
  cb = adc_quantise(cb, top);
  cc = adc_quantise(cc, top);
  const uint32_t stuck = p->adc_stuck_mask;
  if (stuck) { /* frozen converter */
    if (stuck & 1u) ca = s->adc_last_cnt[0];
    if (stuck & 2u) cb = s->adc_last_cnt[1];
    if (stuck & 4u) cc = s->adc_last_cnt[2];
  }
  s->adc_last_cnt[0] = cnt[0] = ca;
  s->adc_last_cnt[1] = cnt[1] = cb;
  s->adc_last_cnt[2] = cnt[2] = cc;
  cnt[3] = adc_quantise(u * s->inv_udc_lsb_V, top);
}

void sim_sample(sim_t *s, fw_inputs_t *in, fw_adc_inputs_t *adc) {
  double cnt[4];
  sample_counts(s, cnt);
  for (int j = 0; j < 3; ++j) {
    if (adc) adc->i_abc_counts[j] = (uint16_t)cnt[j];
    /* what the drive computes with its nominal scaling */
    if (in) in->i_abc_A[j] = (float)((cnt[j] - s->adc_mid) * s->adc_lsb_A);
  }
  if (adc) adc->u_dc_counts = (uint16_t)cnt[3];
  if (in) in->u_dc_V = (float)(cnt[3] * s->udc_lsb_V);
}

/** sim_sample for a controller that takes counts (the firmware's control interrupt):
 * the batch loop's common case, without the physical conversion. */
#if defined(__GNUC__)
__attribute__((noinline))
#endif
static void sample_adc(sim_t *s, fw_adc_inputs_t *adc) {
  double cnt[4];
  sample_counts(s, cnt);
  for (int j = 0; j < 3; ++j) adc->i_abc_counts[j] = (uint16_t)cnt[j];
  adc->u_dc_counts = (uint16_t)cnt[3];
}

/** The scale's reading with the mover at x_m (sim_ref_sample). */
static uint8_t ref_sample_at(sim_t *s, double x_m, int32_t *count) {
  const sim_plant_params_t *p = &s->p;
  if (!(p->ref_res_m > 0.0)) return (uint8_t)FW_REF_NONE;
  if (p->ref_fault != 0u) { /* signal lost: the error output set, the count frozen */
    *count = s->ref_last;
    return (uint8_t)FW_REF_FAULT;
  }
  const double c = floor((x_m + p->ref_offset_m) / p->ref_res_m);
  s->ref_last = c >= 2147483647.0 ? INT32_MAX : (c <= -2147483648.0 ? INT32_MIN : (int32_t)c);
  *count = s->ref_last;
  return (uint8_t)FW_REF_OK;
}

uint8_t sim_ref_sample(sim_t *s, int32_t *count) {
  return (s && count) ? ref_sample_at(s, s->st.x_m, count) : (uint8_t)FW_REF_NONE;
}

double sim_force_N(const sim_t *s) { return s ? sim_plant_force(s, &s->st) : (double)NAN; }

void sim_plant_advance(sim_t *s, const double duty_abc[3], int pwm_enable, double dt_s,
                       uint32_t n_sub) {
  if (!s || !duty_abc || !(dt_s > 0.0)) return;
  sim_plant_period(s, duty_abc, pwm_enable, dt_s, n_sub);
  s->t_s += dt_s;
}

/* ---- batch loop -------------------------------------------------------- */

/** A duty the plant applies: NaN or infinite -> 0.5, others clamped to [0, 1]
 * (the common in-range duty with two comparisons). */
static inline double sanitize_duty(float d) {
  const double x = (double)d;
  if (x >= 0.0 && x <= 1.0) return x;
  if (!isfinite(x)) return 0.5;
  return x < 0.0 ? 0.0 : 1.0;
}

/* ---- the pieces of a period (sim_plant_step, sim_run, sim_boot) ----------- */

/** Whether the controller is stepped on raw ADC counts (it converts them itself). */
static inline int ctrl_adc_mode(const sim_t *s) {
  return s->ctrl.step_adc && (s->use_adc || !s->ctrl.step);
}

/** Control periods per run of the drive's background loop (at least 1). */
static inline uint32_t ctrl_bg_every(const sim_t *s) {
  return s->ctrl.background_every > 0u ? s->ctrl.background_every : 1u;
}

/** The drive's background loop, at its own rate between control interrupts: in the
 *  slot before this period's interrupt, so a command that arrived before the period
 *  takes effect in it. */
static inline void background_slot(sim_t *s, uint32_t bg_every) {
  if (s->ctrl.background) {
    if (s->bg_in == 0u) {
      s->ctrl.background(s->ctrl.ctx);
      s->bg_in = bg_every - 1u;
    } else {
      s->bg_in--;
    }
  }
}

/** The samples at t_k: raw counts, or (the controller stepped in physical units) the
 *  converted inputs too. */
static inline void sample_period(sim_t *s, int adc_mode, fw_inputs_t *in,
                                 fw_adc_inputs_t *adc) {
  if (adc_mode)
    sample_adc(s, adc); /* the drive converts counts itself */
  else
    sim_sample(s, in, adc);
}

/** The controller (the control interrupt) on the samples of t_k: out cleared first. */
static inline void ctrl_period(sim_t *s, int adc_mode, const fw_inputs_t *in,
                               const fw_adc_inputs_t *adc, fw_outputs_t *out) {
  memset(out, 0, sizeof *out);
  if (adc_mode)
    s->ctrl.step_adc(s->ctrl.ctx, adc, out);
  else
    s->ctrl.step(s->ctrl.ctx, in, out);
}

/** The plant over [t_k, t_k+1) with the latched duties. */
static inline void plant_period(sim_t *s) {
  sim_noise_on_switch(s, s->pwm_on);
  sim_plant_period(s, s->duty, s->pwm_on, s->dt_s, s->p.n_sub);
}

/** The next period's time (from its count: no accumulated rounding). */
static inline void next_period(sim_t *s) {
  s->k++;
  s->t_s = (double)s->k * s->dt_s;
}

void sim_plant_step(sim_t *s, const float duty_abc[3], int pwm_on) {
  if (!s || !duty_abc) return;
  for (int j = 0; j < 3; ++j) s->duty[j] = sanitize_duty(duty_abc[j]);
  s->pwm_on = pwm_on ? 1 : 0;
  plant_period(s);
  next_period(s);
}

int64_t sim_run(sim_t *s, uint64_t n_steps, uint32_t decimation, sim_record_t *rec) {
  if (!s || (!s->ctrl.step && !s->ctrl.step_adc) || decimation == 0u) return -1;
  const uint32_t cap = rec ? rec->capacity : 0u;
  const int want_snap =
      rec && (rec->theta_hat_rad || rec->omega_hat_radps || rec->omega_f_radps || rec->pll_err_rad ||
              rec->hf_amp_A || rec->sogi_k_eff || rec->i_dq_hat_A || rec->speed_ref_radps_e ||
              rec->cia402_state || rec->start_phase || rec->fault_code);
  uint32_t n_rec = 0u;
  /* periods until the next recorded one (k % decimation == 0), counted down
   * instead of a 64-bit modulo per period */
  uint64_t rec_in = (decimation - s->k % decimation) % decimation;
  fw_inputs_t in;
  fw_adc_inputs_t adc;
  fw_outputs_t out;
  fw_snapshot_t snap;
  memset(&snap, 0, sizeof snap);
  const int adc_mode = ctrl_adc_mode(s);
  const uint32_t bg_every = ctrl_bg_every(s);

  for (uint64_t n = 0; n < n_steps; ++n) {
    /* 1. references for this period (only when a schedule may have moved) */
    if (s->t_s >= s->sched_next_t) s->sched_next_t = sched_apply(s, s->t_s);
    /* 2. the drive's background loop (background_slot) */
    background_slot(s, bg_every);
    /* 3. sample: the ADC at t_k */
    sample_period(s, adc_mode, &in, &adc);

    /* 4. record the truth at t_k and the samples */
    const int rec_now = (rec_in == 0u) && n_rec < cap;
    rec_in = (rec_in == 0u) ? decimation - 1u : rec_in - 1u;
    const uint32_t r = n_rec;
    if (rec_now) {
      const double th = s->k_theta * s->st.x_m;
      if (rec->t_s) rec->t_s[r] = s->t_s;
      if (rec->theta_e_rad) rec->theta_e_rad[r] = th;
      if (rec->omega_e_radps) rec->omega_e_radps[r] = s->k_theta * s->st.v_mps;
      if (rec->x_m) rec->x_m[r] = s->st.x_m;
      if (rec->v_mps) rec->v_mps[r] = s->st.v_mps;
      if (rec->force_N) rec->force_N[r] = sim_plant_force(s, &s->st);
      if (rec->load_N) rec->load_N[r] = s->F_load_N;
      if (rec->i_d_A) rec->i_d_A[r] = s->st.i_d_A;
      if (rec->i_q_A) rec->i_q_A[r] = s->st.i_q_A;
      if (rec->i_abc_meas_A)
        for (int j = 0; j < 3; ++j)
          rec->i_abc_meas_A[3u * r + (uint32_t)j] =
              adc_mode ? ((double)adc.i_abc_counts[j] - s->adc_mid) * s->adc_lsb_A
                       : (double)in.i_abc_A[j];
      if (rec->u_dc_meas_V)
        rec->u_dc_meas_V[r] = adc_mode ? (double)adc.u_dc_counts * s->udc_lsb_V : (double)in.u_dc_V;
    }

    /* 5. plant over [t_k, t_k+1) with the duties from step k-1 (independent of
     * step k below, which sees only the samples taken above) */
    const double x_k = s->st.x_m;
    plant_period(s);

    /* 6. controller (the control interrupt) on the samples of t_k; the reference
     * scale read at the same instant, beside them (s->st is x(t_k + T) by now: the
     * position at t_k was x_k, kept below) */
    if (s->ctrl.sample_ref) {
      int32_t cnt = 0;
      const uint8_t st = ref_sample_at(s, x_k, &cnt);
      s->ctrl.sample_ref(s->ctrl.ctx, st, cnt);
    }
    ctrl_period(s, adc_mode, &in, &adc, &out);
    if (rec_now) {
      n_rec++;
      if (want_snap && s->ctrl.snapshot) s->ctrl.snapshot(s->ctrl.ctx, &snap);
      if (rec->theta_hat_rad) rec->theta_hat_rad[r] = (double)snap.theta_hat_rad;
      if (rec->omega_hat_radps) rec->omega_hat_radps[r] = (double)snap.omega_hat_radps;
      if (rec->omega_f_radps) rec->omega_f_radps[r] = (double)snap.omega_f_radps;
      if (rec->pll_err_rad) rec->pll_err_rad[r] = (double)snap.pll_err_rad;
      if (rec->hf_amp_A) rec->hf_amp_A[r] = (double)snap.hf_amp_A;
      if (rec->sogi_k_eff) rec->sogi_k_eff[r] = (double)snap.sogi_k_eff;
      if (rec->i_dq_hat_A) {
        rec->i_dq_hat_A[2u * r] = (double)snap.i_dq_A[0];
        rec->i_dq_hat_A[2u * r + 1u] = (double)snap.i_dq_A[1];
      }
      if (rec->speed_ref_radps_e) rec->speed_ref_radps_e[r] = (double)snap.speed_ref_radps_e;
      if (rec->duty_abc)
        for (int j = 0; j < 3; ++j)
          rec->duty_abc[3u * r + (uint32_t)j] = out.pwm_enable ? (double)out.duty_abc[j] : (double)NAN;
      if (rec->cia402_state) rec->cia402_state[r] = snap.cia402_state;
      if (rec->start_phase) rec->start_phase[r] = snap.start_phase;
      if (rec->fault_code) rec->fault_code[r] = snap.fault_code;
    }
    /* 7. latch the new duties for the next period */
    s->pwm_on = out.pwm_enable ? 1 : 0;
    for (int j = 0; j < 3; ++j) s->duty[j] = sanitize_duty(out.duty_abc[j]);
    next_period(s);
  }
  return (int64_t)n_rec;
}

/* The boot's noise stream: the seed's, xor this (sim_boot). */
#define SIM_BOOT_STREAM 0xB0075EED0C0FFEEull

/** sim_boot's periods (the RNG already on the boot's stream). */
static int64_t boot_periods(sim_t *s, uint64_t max_steps, int advance_time) {
  const int adc_mode = ctrl_adc_mode(s);
  const uint32_t bg_every = ctrl_bg_every(s);
  fw_inputs_t in;
  fw_adc_inputs_t adc;
  fw_outputs_t out;
  fw_snapshot_t snap;
  memset(&snap, 0, sizeof snap);
  for (uint64_t n = 0; n < max_steps; ++n) {
    s->ctrl.snapshot(s->ctrl.ctx, &snap);
    if (snap.cia402_state != (uint8_t)FW_CIA402_NOT_READY_TO_SWITCH_ON) return (int64_t)n;
    background_slot(s, bg_every);
    sample_period(s, adc_mode, &in, &adc);
    if (advance_time) plant_period(s); /* as sim_run (the PWM off) */
    ctrl_period(s, adc_mode, &in, &adc, &out);
    if (out.pwm_enable) return -1;
    if (advance_time) next_period(s);
  }
  s->ctrl.snapshot(s->ctrl.ctx, &snap);
  return snap.cia402_state != (uint8_t)FW_CIA402_NOT_READY_TO_SWITCH_ON ? (int64_t)max_steps : -1;
}

int64_t sim_boot(sim_t *s, uint64_t max_steps, int advance_time) {
  if (!s || (!s->ctrl.step && !s->ctrl.step_adc) || !s->ctrl.snapshot) return -1;
  /* the boot's ADC noise from a stream of its own (from the seed), the scenario's
   * generator left where it was: a run's noise is the same with and without the boot */
  uint64_t keep[4];
  memcpy(keep, s->rng, sizeof keep);
  sim_rng_restart(s, s->p.seed ^ SIM_BOOT_STREAM);
  const int64_t n = boot_periods(s, max_steps, advance_time);
  memcpy(s->rng, keep, sizeof keep);
  return n;
}

/* ---- fixed-duty controller (test equipment) --------------------------- */

void sim_ctrl_const_step(void *ctx, const fw_inputs_t *in, fw_outputs_t *out) {
  sim_ctrl_const_t *c = (sim_ctrl_const_t *)ctx;
  (void)in;
  for (int j = 0; j < 3; ++j) out->duty_abc[j] = c->duty_abc[j];
  out->pwm_enable = c->pwm_enable;
  c->calls++;
}

void sim_ctrl_const_snapshot(const void *ctx, fw_snapshot_t *snap) {
  const sim_ctrl_const_t *c = (const sim_ctrl_const_t *)ctx;
  memset(snap, 0, sizeof *snap);
  snap->step_count = c->calls;
  for (int j = 0; j < 3; ++j) snap->duty_abc[j] = c->duty_abc[j];
}

void sim_ctrl_const_port(sim_ctrl_const_t *c, sim_controller_t *port) {
  memset(port, 0, sizeof *port);
  port->ctx = c;
  port->step = sim_ctrl_const_step;
  port->snapshot = sim_ctrl_const_snapshot;
}
