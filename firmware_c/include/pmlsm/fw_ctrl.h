/**
 * @file fw_ctrl.h
 * @brief Sensorless PMLSM drive core: FOC + square-wave HF injection on the
 *        estimated d axis + HF current extraction (pseudo-filter, SOGI,
 *        adaptive SOGI) + quadrature PLL + speed loop + CiA 402 + faults.
 *
 * Usage (one call per PWM period, from the ADC/PWM interrupt or a loop):
 *
 *     fw_config_t cfg; fw_config_default(&cfg);
 *     fw_ctrl_t ctrl;  fw_init(&ctrl, &cfg);      // validates cfg
 *     fw_controlword(&ctrl, FW_CW_SHUTDOWN);      // CiA 402 walk ...
 *     fw_controlword(&ctrl, FW_CW_ENABLE_OPERATION);
 *     fw_set_speed_ref(&ctrl, w_ref_radps_e);
 *     for (;;) { fw_step(&ctrl, &in, &out); pwm(out.duty_abc); }
 *
 * The core sees only what a drive sees: sampled phase currents (or ADC
 * counts) and the DC-link voltage. It has no path to any simulation truth.
 *
 * Units: SI; angles and speeds are *electrical* inside the core
 * (theta_e = pi x / tau = p theta_m). Conversions to m, m/s, rad, r/min are
 * in the snapshot and in fw_units_* helpers.
 */
#ifndef PMLSM_FW_CTRL_H
#define PMLSM_FW_CTRL_H

#include <stddef.h>
#include <stdint.h>

#include "fw_cia402.h"
#include "fw_math.h"
#include "fw_pll.h"
#include "fw_sogi.h"

#ifdef __cplusplus
extern "C" {
#endif

/* FW_VERSION_MAJOR/MINOR/PATCH, FW_VERSION_U32: generated from protocols/od.yaml
 * (device.firmware_version). */
#include "fw_version.h"

/** Largest supported number of PWM periods per injection period. */
#define FW_INJ_MAX_SAMPLES 64u
/** Depth of the fault history. */
#define FW_FAULT_HISTORY_LEN 8u

/* Extractor, control mode, start-up phase and reaction option codes: generated
 * from protocols/od.yaml (enums:), the one list for the core and the bench. */
#include "fw_enums.h"

/** Injection periods per axis in the standstill saliency check (the first is
 *  not averaged: the axis change settles). */
#define FW_SAL_PERIODS 4u
/** Standstill saliency checks that may find d^ off the axis and turn the estimate
 *  by the measured angle before a miss is the EST_HF_ANGLE fault. */
#define FW_SAL_RETRIES 1u

/* Fault codes (fw_fault_t): generated from protocols/od.yaml (faults:), the one
 * list of codes, names and texts for the core, the CANopen slave, the bench and the
 * docs. */
#include "fw_faults.h"

/** Result of configuration checks and setters. */
typedef enum {
  FW_OK = 0,
  FW_ERR_NULL = 1,         /**< NULL pointer */
  FW_ERR_RANGE = 2,        /**< a field outside its documented range */
  FW_ERR_NOT_FINITE = 3,   /**< a field is NaN or inf */
  FW_ERR_SALIENCY = 4,     /**< saliency below saliency_min: injection refused */
  FW_ERR_INCONSISTENT = 5, /**< fields valid alone but not together */
  FW_ERR_STATE = 6         /**< not allowed in the current drive state */
} fw_status_t;

/* Configuration: fw_config_t and its parts (fw_cfg_machine_t, fw_cfg_sensing_t,
 * fw_cfg_loops_t, fw_cfg_estimator_t, fw_cfg_protection_t), generated from
 * protocols/od.yaml (fw_config_parts:, fw_config:) with each field's doc, unit and
 * range. */
#include "fw_config_fields.h"

#include "fw_mon.h"
#include "fw_bemf.h"

/** One configuration field, for validation messages, the OD and tools. */
typedef struct {
  const char *name; /**< field name as in fw_config_t */
  const char *unit; /**< SI unit, "" for dimensionless */
  size_t offset;    /**< offsetof(fw_config_t, part.name) */
  uint8_t is_int;   /**< 1: a 32-bit integer field (uint32_t, int32_t when is_signed);
                         0: float field */
  uint8_t is_signed; /**< with is_int: int32_t (signed option codes) */
  float min;        /**< inclusive */
  float max;        /**< inclusive */
} fw_config_field_t;

/** Where a configuration check failed. */
typedef struct {
  fw_status_t status;
  const char *field; /**< offending field (NULL if none) */
  float value;       /**< its value */
  float min, max;    /**< its allowed range */
} fw_config_issue_t;

/** Sampled inputs of one PWM period, physical units. */
typedef struct {
  float i_abc_A[3]; /**< phase currents */
  float u_dc_V;     /**< DC-link voltage */
} fw_inputs_t;

/** Sampled inputs of one PWM period, raw ADC counts. */
typedef struct {
  uint16_t i_abc_counts[3];
  uint16_t u_dc_counts;
} fw_adc_inputs_t;

/** Outputs of one step. */
typedef struct {
  float duty_abc[3];   /**< 0..1, to be latched at the next PWM period */
  uint8_t pwm_enable;  /**< 0: all switches off */
} fw_outputs_t;

#include "fw_fault.h"
#include "fw_foc.h"
#include "fw_inj.h"
#include "fw_obs.h"
#include "fw_start.h"

/** Read-only view of internal signals, for telemetry. */
typedef struct {
  uint32_t step_count;
  uint16_t statusword;
  uint8_t cia402_state;  /**< fw_cia402_state_t */
  uint8_t start_phase;   /**< fw_start_phase_t */
  uint8_t extractor;     /**< fw_extractor_t in use */
  uint8_t mode;          /**< fw_mode_t */
  uint8_t polarity_flipped; /**< 1 when start-up added pi to the estimate */
  uint16_t fault_code;   /**< latched fw_fault_t, 0 if none */
  /* estimator */
  float theta_hat_rad;   /**< electrical angle estimate at the sampling instant of this step, [-pi, pi) */
  float omega_hat_radps; /**< electrical speed estimate (PLL integrator) */
  float omega_f_radps;   /**< filtered speed used by the speed loop */
  float pos_hat_m;       /**< unwrapped linear position estimate */
  float speed_hat_mps;
  float pos_hat_mech_rad;  /**< unwrapped rotary-equivalent position */
  float speed_hat_rpm;     /**< rotary-equivalent speed */
  float pll_err_rad;       /**< normalised PLL error (approx theta - theta_hat) */
  float pll_err_f_rad;     /**< low-passed signed PLL error; |.| drives adaptation, supervision */
  float accel_dist_radps2; /**< observer's disturbance acceleration (load, friction) */
  float hf_amp_A;          /**< demodulated HF amplitude on d-hat per sample */
  float hf_q_A;            /**< demodulated HF q-hat component per sample */
  float sogi_k_eff;        /**< SOGI gain in use */
  float pol_dI_pos_A;      /**< polarity test: summed response to + pulses */
  float pol_dI_neg_A;      /**< polarity test: summed response to - pulses */
  /* current and voltage (estimated frame) */
  float i_dq_A[2];       /**< fundamental current */
  float i_dq_ref_A[2];
  float u_dq_V[2];       /**< fundamental voltage command (without injection) */
  float u_inj_V;         /**< signed injection voltage commanded this step */
  float i_ab_A[2];       /**< measured alpha/beta current */
  float i_h_ab_A[2];     /**< extracted HF current */
  float speed_ref_radps_e;
  float force_hat_N;     /**< thrust from i_q estimate, 1.5 (pi/tau) psi_f i_q */
  float torque_hat_Nm;   /**< rotary equivalent, 1.5 p psi_f i_q */
  float u_dc_V;
  float duty_abc[3];
  /* integrity monitor (fw_mon.h) */
  float mon_angle_hf_rad;   /**< |angle error| solved from the raw HF response */
  float mon_angle_bemf_rad; /**< angle of the voltage residual against the estimate */
  float mon_e_bemf_V;       /**< |voltage residual| (back-EMF magnitude); in start-up the
                             *   motion check's statistic (MOVING_AT_ENABLE) */
  float mon_i_sum_A;        /**< low-passed |i_a + i_b + i_c| */
  float sal_meas;           /**< saliency measured at start-up (L_large / L_small - 1) */
  float L_small_meas_H;     /**< smaller inductance measured at start-up */
  float L_large_meas_H;     /**< larger inductance measured at start-up */
  /* back-EMF observer (fw_bemf.h) */
  float bemf_err_rad;       /**< angle error seen by the back-EMF (its observer's present
                             *   value, computed by fw_get_snapshot) */
  float inj_scale;          /**< injection amplitude in use, share of u_inj_V */
  uint8_t bemf_active;      /**< 1: the PLL tracks the back-EMF, 0: the HF response */
  uint8_t flying_start;     /**< 1: closed loop was entered on a moving mover */
  uint8_t ref_limited;      /**< FW_REF_LIMITED_* of the references in use */
  /* the board's reference position sensor (fw_port_ref_read), for the bench's
   * judgement only: written by the drive application (fw_app) into the periods
   * it publishes, never by the core, which never reads it */
  float ref_pos_m; /**< reference sensor position (electrical zero at 0), NaN: none */
} fw_snapshot_t;

/**
 * Drive core state. Allocate it yourself (static or on a stack); treat the
 * members as private. No pointers inside, so it can be copied.
 *
 * fw_step() orchestrates the blocks, each a caller-owned struct with its own
 * init/reset and update/output functions (docs/architecture.md):
 *   fault   fw_fault.h  latch, history, input checks; prot: linear-axis protections
 *   start   fw_start.h  alignment (flying start), saliency check, polarity test
 *   inj     fw_inj.h    square-wave injection, HF extraction (SOGIs), demodulation
 *   obs     fw_obs.h    angle error, PLL + mechanical extension, position, speed filter
 *   foc     fw_foc.h    speed and current PIs, voltage limit, modulation
 *   mon     fw_mon.h    integrity monitor;  bemf fw_bemf.h back-EMF observer, handover
 *   sm      fw_cia402.h CiA 402 state machine
 * The core itself keeps only the drive state machine (start-up phase and its
 * time, quick stop), the references and the configuration.
 */
typedef struct {
  fw_config_t cfg;
  uint8_t cfg_ok;        /**< cfg passed fw_config_check (saliency aside) */
  uint8_t saliency_ok;
  fw_cia402_t sm;
  fw_mode_t mode;
  uint32_t step_count;
  /** Changes (+1) whenever a field fw_snapshot_capture_slow copies may have
   *  changed: start-up results, mode, speed reference, extractor, flags. Kept
   *  across fw_init. */
  uint32_t snap_slow_gen;
  float dt_s;
  /* references */
  float speed_ref_radps_e;
  float i_d_ref_A;
  float i_q_ref_force_A;
  uint8_t ref_limited; /**< FW_REF_LIMITED_*: a reference was clamped to its limit */
  /* drive state machine inside OPERATION ENABLED */
  fw_start_phase_t phase;
  float phase_time_s;
  uint8_t polarity_flipped; /**< 1 when start-up added pi to the estimate */
  float qs_left_s;        /**< quick stop / fault braking: time left before PWM off
                               (fw_fault_brake_time_max_s at its start) */
  float qs_still_s;       /**< time at standstill during quick stop */
  float theta_k;          /**< estimate at this step's sampling instant */
  float u_dc_V;           /**< DC link of the last step (statusword warning) */
  float e_start_max_V;    /**< back-EMF at start_speed_max_mps */
  /* blocks */
  fw_fault_latch_t fault;
  fw_protect_t prot;
  fw_start_t start;
  union {
    fw_obs_t obs;
    /* The observer's PLL and error filter under their former names, for tests
     * and tools that read them (tests/c/test_ctrl.c, benchmarks/): the same
     * storage as obs.pll and obs.err_f (common initial sequence). */
    struct {
      fw_pll_f32_t pll;
      float err_f;
    };
  };
  fw_foc_t foc;
  fw_mon_t mon;
  /** The period's supervision (fw_supervise), staged by fw_step_into: the
   *  integrity monitor's inputs, the quick stop, and whether they wait; and the
   *  work of the period that nothing before the duties needs, left to it. */
  struct {
    fw_mon_in_t mon;
    uint8_t quick_stop;
    uint8_t due;      /**< staged and not yet judged */
    uint8_t adapt;    /**< the adaptive SOGI's gain follows adapt_r (fw_inj_adapt) */
    uint8_t saliency; /**< the standstill saliency check is complete: judge it */
    uint8_t caught;   /**< a flying start: its angle, back-EMF and monitor restart */
    float adapt_r;    /**< the observer's adaptation signal of the period */
  } sup;
  fw_bemf_t bemf;
  /* last: its rings are large, the hot blocks above stay within the FPU's
   * 1 KB load/store offset from the controller's address */
  fw_inj_t inj;
  /* last signals for the snapshot (written only, never read back) */
  fw_snapshot_t snap;
  /** The speed target's limit: speed_max_radps_e, or v_max_mps (0x6080) when
   *  smaller (set with the configuration; the background sets the target every
   *  pass) */
  float speed_ref_max_radps_e;
} fw_ctrl_t;

/* ---- configuration ---------------------------------------------------- */

/**
 * Defaults: the paper's Table 1 machine and gains, with the salient variant
 * L_q = 1.5 L_d (Table 1 itself has L_q = L_d, which cannot be tracked by
 * injection; see docs/method-notes). 24 kHz PWM, 3 kHz injection.
 */
void fw_config_default(fw_config_t *cfg);

/**
 * Derive the back-EMF levels of the configured speeds (always):
 *   bemf_e_on_V = psi_f (pi/tau) bemf_v_on_mps, bemf_e_off_V likewise from bemf_v_off_mps,
 *   mon_bemf_min_V from mon_bemf_min_mps (the back-EMF w psi_f at that speed),
 * and the gains from the physical description when gains_auto is set:
 *   K_F = 1.5 (pi/tau) psi_f (N/A),
 *   cur_kp = L_d w_c, cur_ki = R w_c (w_c = cur_bw_radps),
 *   spd_kp = m w_s / K_F * tau / pi (A per el. rad/s), spd_ki = spd_kp w_s / 6,
 *   pll_accel_per_A = (pi/tau) K_F / m (el. rad/s^2 per A),
 *   observer poles at -w: pll_kp = 3 w, pll_ki = 3 w^2, pll_kd = w^3 with
 *   w = sqrt(a_d / (3 * 0.05 rad)), a_d = (pi/tau) 0.2 K_F i_max / m (a load step of
 *   20 % of the peak thrust leaves about 0.05 rad), w within [30, 2 pi f_inj / 40].
 * fw_init and fw_set_config apply it, so the stored configuration (and the
 * object dictionary) shows the levels and gains in use; fw_config_default applies it
 * too. The gains are left as they are when gains_auto is 0.
 */
void fw_config_derive(fw_config_t *cfg);

/** Range and consistency check. Saliency below saliency_min -> FW_ERR_SALIENCY. */
fw_status_t fw_config_check(const fw_config_t *cfg, fw_config_issue_t *issue);

/** Number of entries in the configuration field table. */
size_t fw_config_field_count(void);
/** Field i of the table (NULL when out of range). */
const fw_config_field_t *fw_config_field(size_t i);
/** Look a field up by name (NULL when unknown). */
const fw_config_field_t *fw_config_field_find(const char *name);

/* ---- life cycle ------------------------------------------------------- */

/**
 * Initialise the core with a configuration. Returns the fw_config_check
 * status. On FW_ERR_SALIENCY the config is stored but enabling operation
 * raises FW_FAULT_SALIENCY_TOO_LOW. On other errors the defaults are used
 * and enabling raises FW_FAULT_CONFIG_INVALID.
 */
fw_status_t fw_init(fw_ctrl_t *ctrl, const fw_config_t *cfg);

/**
 * Replace the configuration at run time (only outside OPERATION ENABLED).
 * An invalid configuration is refused and the old one kept.
 */
fw_status_t fw_set_config(fw_ctrl_t *ctrl, const fw_config_t *cfg,
                          fw_config_issue_t *issue);

/** Current configuration (read only). */
const fw_config_t *fw_get_config(const fw_ctrl_t *ctrl);

/* ---- commands --------------------------------------------------------- */

/** Apply a CiA 402 controlword; returns the new statusword. */
uint16_t fw_controlword(fw_ctrl_t *ctrl, uint16_t cw);
/** Current statusword. */
uint16_t fw_statusword(const fw_ctrl_t *ctrl);
fw_cia402_state_t fw_state(const fw_ctrl_t *ctrl);

fw_status_t fw_set_mode(fw_ctrl_t *ctrl, fw_mode_t mode);
/** fw_ctrl_t.ref_limited / fw_snapshot_t.ref_limited: the last speed or force
 *  reference given was beyond its limit and is clamped. In the mode that uses it,
 *  the statusword shows it as bit 11 (internal limit active), as it does the
 *  speed loop's current demand at i_max_A. */
#define FW_REF_LIMITED_SPEED 0x01u
#define FW_REF_LIMITED_FORCE 0x02u

/** Speed reference, electrical rad/s (clamped to speed_max_radps_e: FW_ERR_RANGE,
 *  and statusword bit 11 in SPEED mode until a reference within the limit). */
fw_status_t fw_set_speed_ref(fw_ctrl_t *ctrl, float omega_ref_radps_e);
/** q-axis current reference for FORCE mode (clamped to i_max_A: FW_ERR_RANGE, and
 *  statusword bit 11 in FORCE mode until a reference within the limit). */
fw_status_t fw_set_iq_ref(fw_ctrl_t *ctrl, float i_q_ref_A);
/** Force mode: thrust reference in N, converted with fw_units_force_per_A and
 *  clamped like fw_set_iq_ref; FW_ERR_NOT_FINITE for NaN/inf or K_F <= 0. */
fw_status_t fw_set_force_ref(fw_ctrl_t *ctrl, float force_N);
/** d-axis current reference (clamped to i_max_A), default 0. */
fw_status_t fw_set_id_ref(fw_ctrl_t *ctrl, float i_d_ref_A);
/** Switch extractor at run time: the one-period averages restart and the
 *  PLL and the adaptation hold for 1 ms while the new path settles. */
fw_status_t fw_set_extractor(fw_ctrl_t *ctrl, fw_extractor_t ex);

/** Raise an external fault (e.g. heartbeat lost). Latches like any other. */
void fw_raise_fault(fw_ctrl_t *ctrl, fw_fault_t code);
fw_fault_t fw_fault_code(const fw_ctrl_t *ctrl);
/** Fault history, newest first; returns the number written (<= n). */
uint32_t fw_fault_history(const fw_ctrl_t *ctrl, uint16_t *codes, uint32_t n);

/* ---- real time -------------------------------------------------------- */

/**
 * One control period. Checks the inputs (NaN, overcurrent, DC-link range),
 * runs the state machine, the estimator and the loops, and returns the
 * duties to latch at the next PWM period (one-sample update delay). It is
 * fw_step_into (the control half) followed by fw_supervise (the
 * supervision half); an MCU runs the two halves in two interrupts.
 */
void fw_step(fw_ctrl_t *ctrl, const fw_inputs_t *in, fw_outputs_t *out);

/**
 * The period's supervision half: the current loop's snapshot fields of a period
 * that reached the modulation (i_dq, its references, u_dq, u_inj, i.e. the
 * FW_SNAP_W_OUT and FW_SNAP_W_REF groups' values, into snap); the work of the
 * period that nothing before its duties needs (also in a period with nothing
 * staged): the observer's position, the rest of a flying start (the angle, the
 * back-EMF observer, the monitor's restart), the back-EMF angle error the PLL
 * reads next period (fw_bemf_prepare), the adaptive SOGI's gain, the flying-start
 * rotation; the standstill saliency check's judgement when the period completed
 * it; then the integrity monitor (fw_mon_update) and the linear-axis protections
 * (fw_protect_update) on what fw_step_into staged for them. Call it once after
 * every fw_step_into, before the next one and before the duties take effect
 * (fw_app: the supervision interrupt, pended by the control interrupt and
 * tail-chained to it). A fault it finds latches in the same period as before the
 * split (the saliency check's first); a hard one switches the outputs off: out
 * gets duties 0.5 and pwm_enable 0, snap the duties, state and fault code, and it
 * returns true (the caller then writes the PWM again). Returns false when it left
 * out unchanged (and when out or snap is NULL: the staged inputs then stay
 * unjudged). A period whose supervision did not run before the next
 * fw_step_into is FW_FAULT_SUPERVISION_MISSED (hard): the monitors did not judge
 * it; that control half does the period's deferred work and the saliency
 * judgement first (the period's current-loop snapshot fields stay unwritten).
 */
bool fw_supervise(fw_ctrl_t *ctrl, fw_outputs_t *out, fw_snapshot_t *snap);

/** Groups of the snapshot fields fw_step writes (fw_step_into's result): the
 *  period's common signals (step count, the angle estimate at the sample
 *  (theta_hat_rad), states, fault code, alpha/beta current,
 *  DC link, duties), the extraction's (PLL error, HF amplitudes, HF current),
 *  the current loop's (i_dq, u_dq, u_inj) and the current references. A field
 *  of a group not written keeps its value of the period before. */
#define FW_SNAP_W_COMMON 1u
#define FW_SNAP_W_EST 2u
#define FW_SNAP_W_OUT 4u
#define FW_SNAP_W_REF 8u
#define FW_SNAP_W_ALL 15u

/**
 * fw_step (adc NULL) or fw_step_adc (adc not NULL: the inputs converted from it;
 * in is then not read) with the period's snapshot fields written into snap
 * instead of the core's own (ctrl->snap; fw_step is
 * fw_step_into(ctrl, in, NULL, out, &ctrl->snap)):
 * a caller that keeps snapshots (fw_app's ring) has the step write into the
 * one it hands to its consumer, instead of copying them after the step. The
 * core never reads snap. Returns the FW_SNAP_W_* groups written (by the period:
 * on a period that reaches the modulation fw_supervise writes the current loop's
 * fields into the same snap): the others are the previous period's
 * (fw_snapshot_carry copies them from where that one was written).
 */
unsigned fw_step_into(fw_ctrl_t *ctrl, const fw_inputs_t *in, const fw_adc_inputs_t *adc,
                      fw_outputs_t *out, fw_snapshot_t *snap);

/** Same, from raw ADC counts scaled by the adc_* configuration. */
void fw_step_adc(fw_ctrl_t *ctrl, const fw_adc_inputs_t *in, fw_outputs_t *out);

/** The one ADC scaling: counts -> A and V with cfg->adc_* (also for callers that
 *  step through another layer, e.g. fw_app_step). Returns false when a count is
 *  above adc_max_count (the caller raises FW_FAULT_ADC_RANGE; fw_step_adc does). */
bool fw_adc_convert(const fw_config_t *cfg, const fw_adc_inputs_t *adc, fw_inputs_t *in);

/** Copy of the internal signals after the last step (fw_snapshot_capture +
 *  fw_snapshot_complete, with the statusword of the core's present state). */
void fw_get_snapshot(const fw_ctrl_t *ctrl, fw_snapshot_t *snap);
/** fw_get_snapshot when the last period's snapshot fields were written into
 *  period (fw_step_into) rather than into ctrl->snap. */
void fw_get_snapshot_of(const fw_ctrl_t *ctrl, const fw_snapshot_t *period,
                        fw_snapshot_t *snap);

/** What fw_snapshot_complete needs besides the captured snapshot fields. */
typedef struct {
  int32_t pos_turns;      /**< the observer's position (fw_obs_pos_e_of: whole turns ... */
  float pos_unwrapped_e;  /**< ... and the remainder), summed in fw_snapshot_complete */
  float bemf_e_dq_V[2]; /**< the back-EMF observer's filtered back-EMF */
  float bemf_err_rad;  /**< its angle error, when bemf_fresh */
  uint8_t bemf_fresh;  /**< bemf_err_rad is computed (fw_bemf_t.err_fresh) */
  uint8_t bemf_w_neg;  /**< fw_bemf_t.w_neg */
} fw_snapshot_raw_t;

/**
 * The snapshot in two halves, for a control interrupt that hands its periods
 * to a background loop (fw_app): fw_snapshot_capture copies this period's
 * signals and the blocks' present states (loads and stores only: no unit
 * conversion, no division, no statusword, no atan2) into snap and raw;
 * fw_snapshot_complete computes the rest of snap from them (positions and
 * speeds in units, thrust, torque, the back-EMF angle error, the statusword)
 * with ctrl's configuration, later and elsewhere. Right after fw_step (with
 * inputs), capture + complete give exactly fw_get_snapshot.
 */
void fw_snapshot_capture(const fw_ctrl_t *ctrl, fw_snapshot_t *snap, fw_snapshot_raw_t *raw);
/**
 * fw_snapshot_capture in parts:
 *  - fw_snapshot_carry copies the groups of the period's fields (what fw_step
 *    wrote) not in written (FW_SNAP_W_*) from prev: with written 0 and prev
 *    &ctrl->snap, all of them;
 *  - _state the blocks' present states (a caller of fw_step_into, which wrote
 *    the period's fields itself, captures only these and the slow part);
 *  - _slow the fields that change only at start-up events and on commands
 *    (polarity and saliency results, polarity flag, flying start, extractor,
 *    mode, speed reference). A caller that keeps snapshots (fw_app's ring
 *    slots) copies the slow part only when fw_snapshot_slow_gen differs from
 *    the value it had at its last copy into that snapshot.
 */
void fw_snapshot_carry(fw_snapshot_t *snap, const fw_snapshot_t *prev, unsigned written);
void fw_snapshot_capture_state(const fw_ctrl_t *ctrl, fw_snapshot_t *snap, fw_snapshot_raw_t *raw);
void fw_snapshot_capture_slow(const fw_ctrl_t *ctrl, fw_snapshot_t *snap);
static inline uint32_t fw_snapshot_slow_gen(const fw_ctrl_t *ctrl) { return ctrl->snap_slow_gen; }
void fw_snapshot_complete(const fw_ctrl_t *ctrl, fw_snapshot_t *snap,
                          const fw_snapshot_raw_t *raw);

/** sizeof(fw_ctrl_t), for bindings that allocate it. */
size_t fw_ctrl_sizeof(void);

/* ---- unit helpers ----------------------------------------------------- */

/** Linear speed (m/s) -> electrical rad/s: w_e = pi v / tau. */
float fw_units_mps_to_radps_e(const fw_config_t *cfg, float v_mps);
float fw_units_radps_e_to_mps(const fw_config_t *cfg, float w_radps_e);
/** Back-EMF magnitude w psi_f (V) of a mover at v_mps (the one conversion used by
 *  fw_config_derive for the handover and witness levels, and the start check). */
float fw_units_bemf_V(const fw_config_t *cfg, float v_mps);
/** Rotary-equivalent r/min -> electrical rad/s: w_e = p 2 pi n / 60. */
float fw_units_rpm_to_radps_e(const fw_config_t *cfg, float n_rpm);
float fw_units_radps_e_to_rpm(const fw_config_t *cfg, float w_radps_e);
/** Nominal thrust constant K_F = 1.5 (pi/tau) psi_f (N per A of i_q); the one
 *  definition used by the gain derivation, force mode and the snapshot. */
float fw_units_force_per_A(const fw_config_t *cfg);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_CTRL_H */
