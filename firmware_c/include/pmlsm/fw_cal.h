/**
 * @file fw_cal.h
 * @brief Current-sensor zero calibration: each phase's zero count measured with
 *        the power stage off, before the drive can be enabled.
 *
 * A production drive (VESC, ODrive, ST MCSDK) measures the zero of each
 * current channel with the switches off before it enables the power stage;
 * the configured zero (adc_offset_counts, the nominal mid-scale count) is
 * only its starting point. The core does it at boot, in the CiA 402 state
 * NOT READY TO SWITCH ON (the standard's self-test state): after
 * FW_CAL_SETTLE_S with the PWM off (an earlier switch-off's current decayed,
 * the front end settled) it averages FW_CAL_SAMPLES raw ADC samples of each
 * phase, one per PWM period, and then passes to SWITCH ON DISABLED. The
 * measured zeros replace the nominal one in the ADC conversion
 * (fw_adc_convert, the one scaling). It reads the raw samples only, what a real
 * drive measures.
 *
 * Plausibility (fw_cal_judge, at the end and again at every enable, with the
 * configuration then in force): a phase whose zero lies further than
 * mon_i_zero_max_A from the nominal zero (a wrong or damaged sensor, an ADC
 * stuck at a rail), or whose samples spread more than mon_i_zero_spread_A
 * RMS about their mean (current flowing, a noisy ADC), is
 * FW_FAULT_CURRENT_ZERO_CAL: latched at the end of the calibration (the drive
 * goes to FAULT instead of SWITCH ON DISABLED) and at every enable request
 * until the core restarts; the drive never runs on it.
 *
 * The counts are integers and the sums are of their deviations from the
 * nominal zero, so the float32 sums are exact for |deviation| up to 2^24 /
 * FW_CAL_SAMPLES (16384 counts, every 16-bit ADC) and their squares to
 * 128 counts; beyond that the zero is far outside any plausible limit.
 *
 * Fixed size, no division per period; caller-owned (fw_ctrl_t.cal).
 */
#ifndef PMLSM_FW_CAL_H
#define PMLSM_FW_CAL_H

#include <stdbool.h>
#include <stdint.h>

#include "fw_types.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Raw samples averaged per phase: 1024 PWM periods, 42.7 ms at 24 kHz. With
 *  white ADC noise of sigma counts RMS the zero's error is sigma / 32. */
#define FW_CAL_SAMPLES 1024u
/** PWM off this long before the first sample (the current of a switch-off
 *  decays in about L i / u_dc, a millisecond; the front end settles). */
#define FW_CAL_SETTLE_S 0.005f

/** Where the calibration stands. */
typedef enum {
  FW_CAL_RUNNING = 0, /**< settling or sampling: the zeros are the nominal one */
  FW_CAL_DONE = 1,    /**< measured: zero_counts and spread_counts hold the results */
  FW_CAL_NONE = 2     /**< no raw samples (the core was stepped in physical units,
                           fw_step: the caller converts, and owns the zero) */
} fw_cal_state_t;

/** Calibration state and results. Treat members as private; read with fw_cal_*(). */
typedef struct {
  float zero_counts[3];   /**< per-phase zero in use (the nominal until measured) */
  float spread_counts[3]; /**< RMS of the samples about their mean (0 until measured) */
  float nominal_counts;   /**< the nominal zero the sums are taken from */
  float s1[3], s2[3];     /**< sums of (count - nominal) and of its square */
  uint32_t settle;        /**< periods still to skip before the first sample */
  uint32_t n;             /**< samples so far */
  uint8_t state;          /**< fw_cal_state_t */
} fw_cal_t;

/** Start (or restart) the calibration: zeros back to the nominal, settle time
 *  from the sampling period dt_s. */
void fw_cal_start(fw_cal_t *c, const fw_cfg_sensing_t *sensing, float dt_s);

/** One period's raw samples, the PWM off (a cold path: only while RUNNING).
 *  Returns true in the period the calibration completes (state DONE). */
bool fw_cal_sample(fw_cal_t *c, const fw_adc_inputs_t *adc);

/** No raw samples to calibrate on (the core is stepped in physical units):
 *  state NONE, the zeros stay the nominal one. */
void fw_cal_none(fw_cal_t *c);

/** The judgement with the configuration in force: FW_FAULT_CURRENT_ZERO_CAL when
 *  a measured phase's zero is further than mon_i_zero_max_A from
 *  adc_offset_counts or its spread above mon_i_zero_spread_A (both scaled by
 *  adc_A_per_count), FW_FAULT_NONE otherwise (also for state NONE). While
 *  RUNNING: FW_FAULT_CURRENT_ZERO_CAL (nothing measured yet: no enable). */
fw_fault_t fw_cal_judge(const fw_cal_t *c, const fw_config_t *cfg);

/** Per-phase zero count in use (k = 0..2). */
static inline float fw_cal_zero(const fw_cal_t *c, unsigned k) { return c->zero_counts[k]; }

/** fw_cal_state_t of the calibration. */
static inline fw_cal_state_t fw_cal_state(const fw_cal_t *c) { return (fw_cal_state_t)c->state; }

#ifdef __cplusplus
}
#endif

#endif /* PMLSM_FW_CAL_H */
