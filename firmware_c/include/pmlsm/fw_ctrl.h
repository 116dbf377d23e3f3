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
 *
 * Layers (docs/firmware.md): this header is the top of the core. Below it the
 * blocks (fw_fault.h, fw_start.h, fw_inj.h, fw_obs.h, fw_foc.h, fw_mon.h,
 * fw_bemf.h, fw_cia402.h), each a caller-owned struct; at the bottom the
 * configuration, units and shared types (fw_types.h, fw_config.h, fw_units.h)
 * that every block includes. The snapshot (fw_snapshot.h) reads the core.
 */
#ifndef PMLSM_FW_CTRL_H
#define PMLSM_FW_CTRL_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "fw_bemf.h"
#include "fw_cia402.h"
#include "fw_config.h"
#include "fw_fault.h"
#include "fw_cal.h"
#include "fw_foc.h"
#include "fw_inj.h"
#include "fw_mon.h"
#include "fw_obs.h"
#include "fw_snapshot.h"
#include "fw_start.h"
#include "fw_types.h"
#include "fw_units.h"
#include "fw_xsat.h"

#ifdef __cplusplus
extern "C" {
#endif

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
 *   cal     fw_cal.h    current-sensor zeros measured with the PWM off at boot
 * The core itself keeps only the drive state machine (start-up phase and its
 * time, quick stop), the references and the configuration.
 */
struct fw_ctrl {
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
  /** the per-phase current zeros (fw_cal.h): measured in NOT READY TO SWITCH ON,
   *  read by the ADC conversion every period */
  fw_cal_t cal;
  /* blocks */
  fw_fault_latch_t fault;
  fw_protect_t prot;
  fw_start_t start;
  fw_obs_t obs;
  fw_foc_t foc;
  fw_mon_t mon;
  fw_xsat_t comp; /**< cross-saturation map and dead-time compensation */
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
}; /* fw_ctrl_t: typedef in fw_snapshot.h */

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
/** The statusword from the signals it depends on: fw_statusword on the core's
 *  present state, fw_snapshot_complete on a snapshot's (the configuration's
 *  u_dc_min_V for the warning bit, i_max_A for the speed loop's limit). */
uint16_t fw_statusword_of(const fw_config_t *cfg, fw_cia402_state_t state, float u_dc_V,
                          fw_start_phase_t phase, fw_mode_t mode, float speed_ref_radps_e,
                          float omega_f_radps, uint8_t ref_limited, float i_q_ref_A);

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
 * (fw_protect_step) on what fw_step_into staged for them. Call it once after
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

/** The one ADC scaling: counts -> A and V with cfg->adc_* and the per-phase zero
 *  counts zero_counts[3] (the core's: fw_current_zero_counts, measured with the
 *  PWM off at boot; the nominal adc_offset_counts until then). Returns false when a
 *  count is above adc_max_count (the caller raises FW_FAULT_ADC_RANGE; fw_step_adc
 *  does). */
bool fw_adc_convert(const fw_config_t *cfg, const float zero_counts[3],
                    const fw_adc_inputs_t *adc, fw_inputs_t *in);

/** Phase k's (0..2) current zero in ADC counts as the conversion uses it: measured
 *  with the PWM off at boot (fw_cal.h), the nominal adc_offset_counts until then. */
float fw_current_zero_counts(const fw_ctrl_t *ctrl, unsigned k);

/** The caller converts the ADC samples and owns the current zero (the core stepped in
 *  physical units, fw_step: a replay, a benchmark, a host model): no calibration, the
 *  nominal zero, and NOT READY TO SWITCH ON -> SWITCH ON DISABLED at once, so that the
 *  enable walk works before the first period. Call it after fw_init; it does nothing
 *  once the calibration has ended or the drive has left NOT READY TO SWITCH ON. */
void fw_current_zero_external(fw_ctrl_t *ctrl);

/** Where the boot's current-zero calibration stands (fw_cal_state_t). */
fw_cal_state_t fw_current_zero_state(const fw_ctrl_t *ctrl);

/** Changes (+1) whenever a field fw_snapshot_capture_slow copies may have changed
 *  (fw_snapshot.h: a caller that keeps snapshots copies the slow part when it
 *  differs from the value at its last copy). */
static inline uint32_t fw_snapshot_slow_gen(const fw_ctrl_t *ctrl) { return ctrl->snap_slow_gen; }

/** sizeof(fw_ctrl_t), for bindings that allocate it. */
size_t fw_ctrl_sizeof(void);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_CTRL_H */
