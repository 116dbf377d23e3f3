/**
 * @file fw_types.h
 * @brief Bottom layer of the drive core: the configuration (fw_config_t and its
 *        parts, generated), the codes that cross the wire (faults, enums,
 *        version, generated), the sizes of the blocks' buffers, the status of
 *        configuration checks and setters, and one period's inputs and
 *        outputs. Every block header (fw_fault.h, fw_start.h, fw_inj.h,
 *        fw_obs.h, fw_foc.h, fw_mon.h, fw_bemf.h, ...) includes this one, with
 *        fw_config.h and fw_units.h the rest of the bottom layer, and never the
 *        orchestrator's (fw_ctrl.h).
 */
#ifndef PMLSM_FW_TYPES_H
#define PMLSM_FW_TYPES_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "fw_math.h"

/* FW_VERSION_MAJOR/MINOR/PATCH, FW_VERSION_U32: generated from protocols/od.yaml
 * (device.firmware_version). */
#include "fw_version.h"
/* Extractor, control mode, start-up phase and reaction option codes: generated
 * from protocols/od.yaml (enums:), the one list for the core and the bench. */
#include "fw_enums.h"
/* Fault codes (fw_fault_t): generated from protocols/od.yaml (faults:), the one
 * list of codes, names and texts for the core, the CANopen slave, the bench and the
 * docs. */
#include "fw_faults.h"
/* Configuration: fw_config_t and its parts (fw_cfg_machine_t, fw_cfg_sensing_t,
 * fw_cfg_loops_t, fw_cfg_estimator_t, fw_cfg_protection_t), generated from
 * protocols/od.yaml (fw_config_parts:, fw_config:) with each field's doc, unit and
 * range. */
#include "fw_config_fields.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Largest supported number of PWM periods per injection period. */
#define FW_INJ_MAX_SAMPLES 64u
/** Depth of the fault history. */
#define FW_FAULT_HISTORY_LEN 8u

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

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_TYPES_H */
