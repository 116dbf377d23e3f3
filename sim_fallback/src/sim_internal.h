/* Private definitions shared by the simulator translation units. */
#ifndef PMLSM_SIM_INTERNAL_H
#define PMLSM_SIM_INTERNAL_H

#include "pmlsm_sim.h"

#define SIM_PI 3.14159265358979323846
#define SIM_SQRT3 1.73205080756887729353

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
  double k_force;       /**< 1.5 pi / tau */
  double adc_lsb_A;     /**< current per count */
  double adc_mid;       /**< zero-current count */
  double adc_max;       /**< 2^bits - 1 */
  double udc_lsb_V;
  double u_dt_V;        /**< dead-time pole-voltage error magnitude */
  /* time */
  double t_s;
  uint64_t k;
  /* inverter: duties latched for the present period */
  double duty[3];
  int pwm_on;
  double F_load_N;      /**< load force applied over the present period */
  /* controller */
  sim_controller_t ctrl;
  int use_adc;
  sim_sched_store_t sched[SIM_REF_COUNT];
  /* Expansion point for cheap stage evaluations (see sim_plant.c): exact
   * sin/cos of theta_e and of the cogging angle, tanh and ln cosh of
   * i_d / I_sat at (x0, i_d0); refreshed when a state drifts too far. */
  int basis_valid;
  double b_x0, b_c0, b_s0, b_cc0, b_cs0;
  double b_id0, b_T0, b_S0, b_g0;
  double inv_L_q, inv_mass, inv_I_sat, k_cog, k_dL_Isat;
  /* RNG: xoshiro256** + ziggurat Gaussian (Marsaglia-Tsang / Doornik ZIGNOR,
   * 128 layers; tables per instance, no shared mutable state) */
  uint64_t rng[4];
  double zig_x[129];
  double zig_r[128];
};

/* sim_plant.c */
void sim_plant_derive(sim_t *s);
void sim_plant_period(sim_t *s, const double duty[3], int pwm_on, double dt_s,
                      uint32_t n_sub);
double sim_plant_force(const sim_t *s, const sim_plant_state_t *st);
/** cos/sin of theta_e at x (basis expansion when close, else libm). */
void sim_plant_sincos(sim_t *s, double x_m, double *c, double *sn);
void sim_rng_seed(sim_t *s, uint64_t seed);
double sim_rng_gauss(sim_t *s);

#endif
