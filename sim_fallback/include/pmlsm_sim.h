/**
 * @file pmlsm_sim.h
 * @brief Simulated PMLSM drive: float64 plant (dq model with d-axis
 *        saturation, stick-slip friction, cogging, average inverter with
 *        one-sample update delay, 12-bit current ADC) and a batch closed
 *        loop that runs any controller with the fw_step() signature.
 *
 * Truth (position, speed, thrust, true currents) stays inside sim_t and
 * flows only into the recording. The controller receives nothing but the
 * ADC-sampled phase currents and the sampled DC-link voltage.
 *
 * Units: SI, linear mechanics (m, m/s, N, kg). Angles and speeds electrical
 * unless named otherwise: theta_e = pi x / tau.
 */
#ifndef PMLSM_SIM_H
#define PMLSM_SIM_H

#include <stddef.h>
#include <stdint.h>

#include "pmlsm/fw_ctrl.h"
#include "pmlsm/fw_port.h"

#ifdef __cplusplus
extern "C" {
#endif

#define SIM_VERSION_U32 0x00000100u

/** Plant parameters, linear units (rotary sets are converted by the loader). */
typedef struct {
  /* electrical */
  double R_ohm;      /**< phase resistance */
  double L_d0_H;     /**< unsaturated d-axis incremental inductance */
  double L_q_H;      /**< q-axis inductance (linear) */
  double psi_f_Wb;   /**< PM flux linkage */
  double dL_sat_H;   /**< d-axis saturation depth: L_dd = L_d0 - dL tanh(i_d/I_sat) */
  double I_sat_A;    /**< d-axis saturation current scale (> 0) */
  /* mechanical */
  double tau_m;         /**< pole pitch; theta_e = pi x / tau */
  double mass_kg;       /**< mover (+ load) mass */
  double b_visc_Ns_per_m; /**< viscous friction */
  double F_coulomb_N;   /**< kinetic (Coulomb) friction magnitude */
  double F_static_N;    /**< break-away (static) friction, >= F_coulomb_N */
  double v_stick_mps;   /**< |v| below this at a sign change -> stick */
  double cog_amp_N;     /**< cogging amplitude */
  double cog_period_m;  /**< cogging period in position */
  double cog_phase_rad; /**< cogging phase */
  int32_t locked;       /**< 1: mover clamped (x, v frozen), for RL tests */
  /* inverter */
  double u_dc_V;        /**< DC-link voltage (constant) */
  double f_pwm_Hz;      /**< PWM = sampling = control rate */
  double dead_time_s;   /**< 0: ideal; else pole-voltage error -sgn(i) u_dc t_d f_pwm */
  double dead_band_A;   /**< current band over which the dead-time sign is linearised */
  uint32_t n_sub;       /**< RK4 sub-steps per PWM period (>= 1) */
  /* sensing */
  uint32_t adc_bits;         /**< current ADC resolution, e.g. 12 */
  double adc_i_fullscale_A;  /**< current ADC range +-fullscale */
  double adc_noise_counts;   /**< Gaussian noise std per current sample (counts) */
  double adc_offset_counts[3]; /**< per-phase offset error (counts, hidden from the controller) */
  double adc_gain_err[3];    /**< per-phase relative gain error (0 = ideal) */
  double udc_fullscale_V;    /**< DC-link ADC full scale (same resolution) */
  double udc_noise_V;        /**< Gaussian noise std on the DC-link measurement */
  uint64_t seed;             /**< RNG seed (xoshiro256** via splitmix64) */
  /* fault injection (0 = healthy) */
  uint32_t open_phase_mask;  /**< bit j: phase j open (no current can flow in it) */
  uint32_t adc_stuck_mask;   /**< bit j: current ADC channel j repeats its last count */
  /* reference position sensor: the rig's quadrature scale, sampled with the ADC */
  double ref_res_m;          /**< scale resolution (m per count); 0: no scale fitted */
  double ref_offset_m;       /**< scale reading (m) at x = 0 (electrical angle 0) */
  uint32_t ref_fault;        /**< 0 healthy; 1 signal lost: the scale's error output is
                                  set (FW_REF_FAULT) and its count frozen */
  uint32_t noise_restart;    /**< 1: the noise generator restarts from seed when the inverter
                                  is switched on (the first PWM period after an off one): the
                                  noise after an enable depends on the seed alone, not on how
                                  long the drive idled before (twin comparisons of the host
                                  and the emulated drive); 0: one stream from creation */
} sim_plant_params_t;

/**
 * Plant realism (docs/simulator.md "Plant realism"): the magnetics and inverter effects
 * beyond sim_plant_params_t, set with sim_set_realism. Every field 0 = off (a new
 * simulation has all of them 0), and with all of them 0 the plant computes exactly what
 * it does without them. A separate block, not part of sim_plant_params_t, whose layout the
 * emulated board's boot block pins (firmware_c/boards/mps2_an386/emu_boot.c).
 */
typedef struct {
  double dLq_sat_H;     /**< q-axis saturation depth: L_qq = L_q - dLq tanh^2(i_q/Iq_sat) */
  double Iq_sat_A;      /**< q-axis saturation current scale (> 0 when dLq_sat_H > 0) */
  double cross_L_H;     /**< cross-saturation: L_dq(0, i_q) = -cross_L tanh(i_q/cross_I) */
  double cross_I_A;     /**< cross-saturation current scale (> 0 when cross_L_H > 0) */
  double sal2_L_H;      /**< secondary spatial saliency: stator-frame inductance term
                             sal2_L [[cos a, sin a], [sin a, -cos a]], a = n theta_e + phase */
  uint32_t sal2_order;  /**< its order n (1..12; used when sal2_L_H > 0) */
  uint32_t pad_real_;
  double sal2_phase_rad;  /**< its phase */
  double emf_h5;        /**< 5th back-EMF harmonic / fundamental (PM flux harmonic h5/5 psi_f) */
  double emf_h5_phase_rad; /**< its phase: psi_a = psi_f (cos th + h5/5 cos(5 th + phase) + ...) */
  double emf_h7;        /**< 7th back-EMF harmonic / fundamental */
  double emf_h7_phase_rad; /**< its phase */
  double end_dL_H;      /**< end effect: self-inductance reduction of the outer phases a, c
                             at full exposure e(x) = 1 */
  double end_psi_frac;  /**< end effect: relative PM flux reduction of phases a, c at e = 1 */
  double end_base;      /**< exposure in the middle of the travel (0..1; 1: short primary) */
  double end_travel_m;  /**< stator length, centred on x = 0 (0: exposure end_base everywhere) */
  double end_zone_m;    /**< length over which the exposure rises at the ends (> 0 with travel) */
  double dt_C_eq_F;     /**< dead time: pole parasitic capacitance (0: the sign model over
                             dead_band_A); > 0: the capacitive-commutation error with its
                             zero-current clamp */
  double u_dev_V;       /**< device threshold drop (V_ce0 = V_f), pole error -u_dev sgn(i) */
  double r_dev_ohm;     /**< device on-resistance, pole error -r_dev i */
} sim_realism_t;

/** Plant state (truth). */
typedef struct {
  double i_d_A, i_q_A; /**< currents in the true rotor frame */
  double x_m;          /**< position (unwrapped), theta_e = pi x / tau */
  double v_mps;        /**< velocity */
  int32_t stuck;       /**< 1: static friction holds the mover */
  int32_t pad_;
} sim_plant_state_t;

/** The machine's magnetics at one operating point (sim_plant_magnetics): what the
 *  plant's electrical equations and thrust use, for tests and identification. */
typedef struct {
  double psi_dq_Wb[2];      /**< flux linkage in the rotor frame, R(-theta_e) psi_alpha_beta */
  double L_dq_H[3];         /**< incremental inductance d psi_dq / d i_dq at fixed x: dd, dq, qq */
  double e_dq_V_per_mps[2]; /**< speed voltage per velocity: u_dq = R i + L di/dt + e v */
  double force_N;           /**< electromagnetic thrust (co-energy derivative; no cogging) */
} sim_magnetics_t;

/** Schedule kinds, also the argument of sim_controller_t.set_ref. */
typedef enum {
  SIM_REF_SPEED = 0, /**< speed reference, electrical rad/s */
  SIM_REF_FORCE = 1, /**< thrust reference, N (controller converts to i_q) */
  SIM_REF_LOAD = 2,  /**< external load force on the plant, N (opposes +x) */
  SIM_REF_COUNT = 3
} sim_ref_kind_t;

/** Breakpoint schedule: value(t) = v[i] for t in [t[i], t[i+1]) (step) or linear (ramp). */
typedef struct {
  const double *t_s;   /**< ascending breakpoint times (NULL/n=0: unused) */
  const double *value; /**< values at the breakpoints */
  uint32_t n;
  uint32_t ramp; /**< 0: piecewise constant, 1: linear between breakpoints */
} sim_sched_t;

/**
 * Controller port. step() receives physical units after quantisation;
 * step_adc (used instead of step when non-NULL and use_adc_counts is set in
 * sim_t, or when step is NULL) receives the raw counts. set_ref may be NULL.
 * background (optional) is the drive's background loop: called before the
 * control step of every background_every-th period (0 counts as 1), so it
 * runs at its own rate, interleaved with the control interrupts.
 */
typedef struct {
  void *ctx;
  void (*step)(void *ctx, const fw_inputs_t *in, fw_outputs_t *out);
  void (*step_adc)(void *ctx, const fw_adc_inputs_t *in, fw_outputs_t *out);
  void (*snapshot)(const void *ctx, fw_snapshot_t *snap);
  void (*set_ref)(void *ctx, sim_ref_kind_t kind, double value);
  void (*background)(void *ctx);
  uint32_t background_every;
  /** optional: the reference sensor's reading (fw_ref_status_t, count) at the sampling
   *  instant, handed over right before the control step of every period */
  void (*sample_ref)(void *ctx, uint8_t status, int32_t count);
} sim_controller_t;

/**
 * Recording buffers, one entry per recorded period (every `decimation`
 * periods). Any pointer may be NULL (= not recorded). Vectors are
 * interleaved (n x 2 or n x 3, C order).
 */
typedef struct {
  double *t_s;
  /* truth */
  double *theta_e_rad;  /**< true electrical angle, unwrapped */
  double *omega_e_radps;/**< true electrical speed */
  double *x_m;
  double *v_mps;
  double *force_N;      /**< electromagnetic thrust */
  double *load_N;       /**< external load force */
  double *i_d_A;        /**< true frame currents */
  double *i_q_A;
  /* what the controller saw */
  double *i_abc_meas_A; /**< n x 3, phase currents handed to the controller */
  double *u_dc_meas_V;
  /* controller snapshot */
  double *theta_hat_rad;
  double *omega_hat_radps; /**< PLL speed (integrator) */
  double *omega_f_radps;   /**< filtered speed estimate used by the speed loop */
  double *pll_err_rad;
  double *hf_amp_A;
  double *sogi_k_eff;
  double *i_dq_hat_A;   /**< n x 2, fundamental current, estimated frame */
  double *duty_abc;     /**< n x 3 */
  double *speed_ref_radps_e;
  uint8_t *cia402_state;
  uint8_t *start_phase;
  uint16_t *fault_code;
  uint32_t capacity;    /**< entries available in every non-NULL buffer */
  uint32_t pad_;
} sim_record_t;

/** Opaque simulation. */
typedef struct sim_s sim_t;

/* ---- life cycle ------------------------------------------------------- */

/** Validate parameters; returns 0 or a negative index naming the bad field. */
int sim_params_check(const sim_plant_params_t *p, const char **bad_field);
/** Replace the plant parameters of a running simulation (state, time, RNG and
 *  schedules kept): fault injection such as a DC-link sag or a sensor fault at
 *  a chosen instant. Returns 0, or the sim_params_check code (nothing changed). */
int sim_set_params(sim_t *s, const sim_plant_params_t *p, const char **bad_field);
/** Validate plant realism against the plant parameters it goes with: 0 or a negative
 *  index naming the bad field (the incremental inductance must stay positive definite
 *  over twice the current ADC's range). */
int sim_realism_check(const sim_plant_params_t *p, const sim_realism_t *r,
                      const char **bad_field);
/** Set the plant realism of a simulation (NULL: all off), at creation or mid-run (state,
 *  time kept). Returns 0, or the sim_realism_check code (nothing changed). */
int sim_set_realism(sim_t *s, const sim_realism_t *r, const char **bad_field);
/** Create (malloc) a simulation; NULL on bad params. Initial state zero. */
sim_t *sim_new(const sim_plant_params_t *p);
/** sizeof(sim_t): storage for sim_init_in. */
size_t sim_sizeof(void);
/**
 * sim_new into caller-owned storage (size bytes, 8-byte aligned): no malloc,
 * for an image that runs the plant as an on-target virtual motor. NULL on bad
 * params or too small a block. Never sim_free such a simulation; it must not
 * get schedules (sim_set_schedule allocates): use sim_set_load instead.
 */
sim_t *sim_init_in(void *mem, size_t size, const sim_plant_params_t *p);
/** The external load force from now on (N, opposes +x); without a load schedule. */
void sim_set_load(sim_t *s, double F_N);
/**
 * One PWM period of the plant alone, as the batch loop runs it: the duties the
 * inverter applies (NaN or infinite -> 0.5, others clamped to [0, 1]) over
 * [t_k, t_k + T), n_sub RK4 steps, then the time advances. Sample (sim_sample,
 * sim_ref_sample) before it for the period's ADC and scale readings.
 */
void sim_plant_step(sim_t *s, const float duty_abc[3], int pwm_on);
void sim_free(sim_t *s);
/** Attach a controller (copied). */
void sim_set_controller(sim_t *s, const sim_controller_t *c);
/** Feed raw counts to step_adc instead of physical units to step (0/1). */
void sim_set_use_adc_counts(sim_t *s, int on);
/** Set the schedule of one kind (arrays are copied). Returns 0 or -1. */
int sim_set_schedule(sim_t *s, sim_ref_kind_t kind, const double *t_s,
                     const double *value, uint32_t n, uint32_t ramp);
/** Overwrite the plant state (e.g. random initial position). */
void sim_set_state(sim_t *s, const sim_plant_state_t *st);
void sim_get_state(const sim_t *s, sim_plant_state_t *st);
/** Duties latched for the current period (initial: 0.5, PWM off). */
void sim_set_latched_duty(sim_t *s, const double duty_abc[3], int pwm_enable);
double sim_time_s(const sim_t *s);
uint64_t sim_step_count(const sim_t *s);
/** Current value of a schedule at the present time. */
double sim_sched_value(const sim_t *s, sim_ref_kind_t kind);

/* ---- stepping --------------------------------------------------------- */

/**
 * Run n_steps control periods: sample -> controller -> integrate one
 * period with the duties returned one period earlier. Records every
 * `decimation`-th period (counted from the start of the simulation, so
 * chunks join seamlessly). Returns the number of entries written to rec
 * (never more than rec->capacity), or -1 on bad arguments.
 */
int64_t sim_run(sim_t *s, uint64_t n_steps, uint32_t decimation,
                sim_record_t *rec);

/**
 * The drive's boot: the controller (and its background) runs on the plant's
 * samples, the power stage off, until its snapshot leaves CiA 402 NOT READY TO
 * SWITCH ON (the firmware's current-zero calibration, fw_cal.h) or max_steps.
 * advance_time 0: before t = 0, neither the plant nor the time advance (the core
 * alone, whose scenarios start at the enable); 1: as
 * sim_run, the plant and the time advance (a drive with its own clock, the drive
 * application, whose period count must stay the simulator's). The boot's ADC noise
 * comes from a stream of its own (from the seed); the run's noise generator is
 * left where it was, so a run's noise is the same with and without it. Returns the periods
 * it took, or -1 on bad arguments, a controller that switched the PWM on, or one
 * still not ready after max_steps.
 */
int64_t sim_boot(sim_t *s, uint64_t max_steps, int advance_time);

/* ---- plant alone (for tests and bring-your-own-controller) ------------ */

/** Integrate the plant for dt_s with fixed duties (n_sub RK4 steps), no sampling. */
void sim_plant_advance(sim_t *s, const double duty_abc[3], int pwm_enable,
                       double dt_s, uint32_t n_sub);
/** Sample the ADC now (advances the RNG). */
void sim_sample(sim_t *s, fw_inputs_t *in, fw_adc_inputs_t *adc);
/** The reference scale's reading now: a fw_ref_status_t (FW_REF_NONE without a
 *  scale, ref_res_m = 0) and, when valid, *count = floor((x + ref_offset_m) /
 *  ref_res_m) saturated to int32 (the plant's true position quantised). */
uint8_t sim_ref_sample(sim_t *s, int32_t *count);
/** Truth: electromagnetic thrust at the present state. */
double sim_force_N(const sim_t *s);
/** The magnetics (flux, incremental inductance, speed voltage, thrust) of the plant's
 *  parameters at currents i_d, i_q (true rotor frame) and position x: the full model
 *  with libm, the same equations the plant integrates (docs/simulator.md). */
void sim_plant_magnetics(const sim_t *s, double i_d_A, double i_q_A, double x_m,
                         sim_magnetics_t *out);

/* ---- controllers ------------------------------------------------------ */

/** Fixed-duty controller (test equipment: RL step, free acceleration). */
typedef struct {
  float duty_abc[3];
  uint8_t pwm_enable;
  uint32_t calls;
} sim_ctrl_const_t;
void sim_ctrl_const_step(void *ctx, const fw_inputs_t *in, fw_outputs_t *out);
void sim_ctrl_const_snapshot(const void *ctx, fw_snapshot_t *snap);
/** Fill a sim_controller_t for a sim_ctrl_const_t. */
void sim_ctrl_const_port(sim_ctrl_const_t *c, sim_controller_t *port);

/** fw_ctrl_t adapters (the firmware core, same sources). */
void sim_fw_step(void *ctx, const fw_inputs_t *in, fw_outputs_t *out);
void sim_fw_step_adc(void *ctx, const fw_adc_inputs_t *in, fw_outputs_t *out);
void sim_fw_snapshot(const void *ctx, fw_snapshot_t *snap);
void sim_fw_set_ref(void *ctx, sim_ref_kind_t kind, double value);
/** Fill a sim_controller_t for an fw_ctrl_t. */
void sim_fw_port(fw_ctrl_t *ctrl, sim_controller_t *port);
/** Heap fw_ctrl_t (zeroed) for bindings; free with sim_fw_free. */
fw_ctrl_t *sim_fw_new(void);
void sim_fw_free(fw_ctrl_t *ctrl);

/**
 * The whole drive (fw_app: core + CANopen + serial) behind the simulator's
 * port, sim_port.c: the simulated drive the bench talks to. sim_app_new
 * initialises it with cfg and node_id and boots from nvm_path (NULL or "":
 * no storage); NULL on a refused configuration (*status: fw_status_t).
 */
typedef struct sim_app sim_app_t;
sim_app_t *sim_app_new(const fw_config_t *cfg, uint8_t node_id, const char *nvm_path,
                       int *status);
void sim_app_free(sim_app_t *d);
/** Fill a sim_controller_t: control interrupt on ADC counts + background loop. */
void sim_app_controller(sim_app_t *d, uint32_t background_every, sim_controller_t *c);
/** The CAN receive interrupt (a frame from the bus). False when the queue is full. */
bool sim_app_can_rx(sim_app_t *d, const fw_can_frame_t *frame);
/** Next frame the drive sent through its port; false when none. */
bool sim_app_can_pop(sim_app_t *d, fw_can_frame_t *frame);
/** Bytes the drive wrote to its UART (at most cap). */
size_t sim_app_uart_read(sim_app_t *d, uint8_t *buf, size_t cap);
/** One background pass now (outside the batch loop: after boot, at close). */
void sim_app_background_now(sim_app_t *d);
/** The drive's fw_app_t (a void * here: this header does not need fw_app.h), for tests. */
void *sim_app_fw_app(sim_app_t *d);
/** The drive's running configuration (fw_config_t of its core: the one it booted with,
 *  from its non-volatile memory when that held one, as changed since over the bus). */
void sim_app_config(sim_app_t *d, fw_config_t *out);
/** fw_app_nvm_state_t of the boot. */
int sim_app_nvm_state(const sim_app_t *d);
/** Unbalanced critical sections seen (0 in a correct firmware). */
uint32_t sim_app_crit_unbalanced(const sim_app_t *d);

/* ---- layout checks for bindings -------------------------------------- */

/** sizeof of a named struct ("fw_config_t", "sim_plant_params_t", ...); 0 if unknown. */
size_t sim_layout_sizeof(const char *type_name);
/** offsetof of a named field; -1 if unknown. */
int64_t sim_layout_offsetof(const char *type_name, const char *field);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_SIM_H */
