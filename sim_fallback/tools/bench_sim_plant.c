/**
 * @file bench_sim_plant.c
 * @brief Cost of the simulated plant alone (sim_plant_advance), without the
 *        firmware, sampling or the loop: paper_salient values, mover at
 *        100 r/min carrying 3.4 A of i_q, 50 V / 3 kHz d-axis injection (the
 *        firmware's defaults), one call per 24 kHz PWM period. Also the mover
 *        held by static friction (the start-up's standstill injection: the
 *        same d-axis injection, no i_q), n_sub = 1.
 *
 * Usage: bench_sim_plant [n_periods]   (prints ns per period for n_sub = 1, 2, 4
 * and at standstill, median over 7 runs of CPU time, with the driver's own
 * cost (median) subtracted; the median, not the minimum: on a virtual machine a
 * run's CPU clock is now and then short by 10 %)
 * Profile with: valgrind --tool=callgrind bench_sim_plant 24000
 */
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "pmlsm_sim.h"

static int cmp_d(const void *a, const void *b) {
  const double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}

/** Median of 7. */
static double med7(double v[7]) {
  qsort(v, 7, sizeof v[0], cmp_d);
  return v[3];
}

static double cpu_s(void) {
  struct timespec t;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static void paper_salient(sim_plant_params_t *p) {
  const double r = 4.0 * 0.024 / 3.14159265358979323846; /* equivalent radius p tau / pi */
  *p = (sim_plant_params_t){0};
  p->R_ohm = 0.958;
  p->L_d0_H = 0.012;
  p->L_q_H = 0.018;
  p->psi_f_Wb = 0.1827;
  p->dL_sat_H = 0.0012;
  p->I_sat_A = 5.0;
  p->tau_m = 0.024;
  p->mass_kg = 0.03 / (r * r);
  p->b_visc_Ns_per_m = 0.008 / (r * r);
  p->F_coulomb_N = 1.5 / r;
  p->F_static_N = 1.5 / r;
  p->v_stick_mps = 1e-6;
  p->cog_period_m = 0.008;
  p->u_dc_V = 300.0;
  p->f_pwm_Hz = 24000.0;
  p->dead_band_A = 0.05;
  p->n_sub = 1u;
  p->adc_bits = 12u;
  p->adc_i_fullscale_A = 25.0;
  p->udc_fullscale_V = 500.0;
}

/* CPU ns per period of n periods; n_sub = 0: the driver alone; still: mover at
 * standstill (no i_q, no motion in the voltages). */
static double run(const sim_plant_params_t *p0, uint32_t n_sub, long n, sim_plant_state_t *end,
                  int still) {
  sim_plant_params_t p = *p0;
  p.n_sub = n_sub ? n_sub : 1u;
  sim_t *s = sim_new(&p);
  if (!s) {
    fprintf(stderr, "sim_new failed\n");
    exit(1);
  }
  const sim_plant_state_t st0 = {0.0, still ? 0.0 : 3.4, 0.003, still ? 0.0 : 0.32, still, 0};
  sim_set_state(s, &st0);
  const double T = 1.0 / p.f_pwm_Hz, k_th = 3.14159265358979323846 / p.tau_m;
  const double v = still ? 0.0 : 0.32, iq = still ? 0.0 : 3.4;
  volatile double sink = 0.0;
  const double c0 = cpu_s();
  for (long k = 0; k < n; ++k) {
    /* voltages from the nominal trajectory (cheap; the same for every n_sub) */
    const double th = k_th * (0.003 + v * (double)k * T), w = k_th * v;
    const double ud = 50.0 * cos(2.0 * 3.14159265358979323846 * 3000.0 * (double)k * T) -
                      w * p.L_q_H * iq;
    const double uq = p.R_ohm * iq + w * p.psi_f_Wb;
    const double ua = ud * cos(th) - uq * sin(th), ub = ud * sin(th) + uq * cos(th);
    const double d[3] = {0.5 + ua / 300.0, 0.5 + (-0.5 * ua + 0.8660254037844386 * ub) / 300.0,
                         0.5 + (-0.5 * ua - 0.8660254037844386 * ub) / 300.0};
    if (n_sub)
      sim_plant_advance(s, d, 1, T, n_sub);
    else
      sink = sink + d[0] + d[1] + d[2];
  }
  const double ns = (cpu_s() - c0) / (double)n * 1e9;
  if (end) sim_get_state(s, end);
  sim_free(s);
  (void)sink;
  return ns;
}

int main(int argc, char **argv) {
  const long n = argc > 1 ? atol(argv[1]) : 240000;
  sim_plant_params_t p;
  paper_salient(&p);
  double v[7];
  for (int r = 0; r < 7; ++r) v[r] = run(&p, 0u, n, NULL, 0);
  const double drv = med7(v);
  const uint32_t subs[3] = {1u, 2u, 4u};
  for (int j = 0; j < 3; ++j) {
    sim_plant_state_t st;
    for (int r = 0; r < 7; ++r) v[r] = run(&p, subs[j], n, &st, 0);
    const double best = med7(v);
    printf("plant alone, n_sub=%u: %.1f ns per PWM period (driver %.1f ns subtracted)"
           "  end state x=%.9f v=%.9f i_d=%.6f i_q=%.6f\n",
           (unsigned)subs[j], best - drv, drv, st.x_m, st.v_mps, st.i_d_A, st.i_q_A);
  }
  sim_plant_state_t st;
  for (int r = 0; r < 7; ++r) v[r] = run(&p, 1u, n, &st, 1);
  const double best = med7(v);
  printf("plant alone, standstill (static friction holds), n_sub=1: %.1f ns per PWM period"
         "  end state x=%.9f v=%.9f i_d=%.6f i_q=%.6f\n",
         best - drv, st.x_m, st.v_mps, st.i_d_A, st.i_q_A);
  return 0;
}
