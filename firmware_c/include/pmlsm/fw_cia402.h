/**
 * @file fw_cia402.h
 * @brief CiA 402 drive state machine (power drive system states).
 *
 * Pure state machine: the controlword selects transitions, the caller
 * reports faults and the end of quick stop / fault reaction. No timing, no
 * I/O. Statusword bits follow CiA 402 (0x6041):
 *   bit0 ready to switch on, bit1 switched on, bit2 operation enabled,
 *   bit3 fault, bit4 voltage enabled, bit5 quick stop (active low),
 *   bit6 switch on disabled, bit7 warning, bit9 remote, bit10 target reached.
 */
#ifndef PMLSM_FW_CIA402_H
#define PMLSM_FW_CIA402_H

#include <stdbool.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef enum {
  FW_CIA402_NOT_READY_TO_SWITCH_ON = 0,
  FW_CIA402_SWITCH_ON_DISABLED = 1,
  FW_CIA402_READY_TO_SWITCH_ON = 2,
  FW_CIA402_SWITCHED_ON = 3,
  FW_CIA402_OPERATION_ENABLED = 4,
  FW_CIA402_QUICK_STOP_ACTIVE = 5,
  FW_CIA402_FAULT_REACTION_ACTIVE = 6,
  FW_CIA402_FAULT = 7
} fw_cia402_state_t;

/** Controlword command values (with the masks that recognise them). */
#define FW_CW_SHUTDOWN 0x0006u          /* mask 0x0087 */
#define FW_CW_SWITCH_ON 0x0007u         /* mask 0x008F */
#define FW_CW_DISABLE_VOLTAGE 0x0000u   /* mask 0x0082 */
#define FW_CW_QUICK_STOP 0x0002u        /* mask 0x0086 */
#define FW_CW_DISABLE_OPERATION 0x0007u /* mask 0x008F */
#define FW_CW_ENABLE_OPERATION 0x000Fu  /* mask 0x008F */
#define FW_CW_FAULT_RESET 0x0080u       /* rising edge of bit 7 */

typedef struct {
  fw_cia402_state_t state;
  uint16_t last_cw; /**< previous controlword, for the fault-reset edge */
} fw_cia402_t;

/** Start in NOT READY TO SWITCH ON. */
void fw_cia402_init(fw_cia402_t *sm);

/** Self-test / initialisation finished: NOT READY -> SWITCH ON DISABLED. */
void fw_cia402_init_done(fw_cia402_t *sm);

/**
 * Apply a controlword. Returns the new state. A fault reset (rising edge
 * of bit 7) in FAULT goes to SWITCH ON DISABLED; whether the fault cause
 * is gone is the caller's business (it re-reports the fault if not).
 */
fw_cia402_state_t fw_cia402_controlword(fw_cia402_t *sm, uint16_t cw);

/** A fault occurred: any state except FAULT -> FAULT REACTION ACTIVE. */
void fw_cia402_fault(fw_cia402_t *sm);

/** Fault reaction finished (PWM off): FAULT REACTION ACTIVE -> FAULT. */
void fw_cia402_fault_reaction_done(fw_cia402_t *sm);

/** Quick stop finished (drive stopped): QUICK STOP ACTIVE -> SWITCH ON DISABLED. */
void fw_cia402_quick_stop_done(fw_cia402_t *sm);

/** Statusword for the current state plus the given flags (bit 7 warning, bit 9
 *  remote, bit 10 target reached, bit 11 internal limit active). */
uint16_t fw_cia402_statusword(const fw_cia402_t *sm, bool warning, bool remote,
                              bool target_reached, bool internal_limit);

/** True in the states in which the power stage switches. */
bool fw_cia402_power_enabled(fw_cia402_state_t st);

/** Human-readable state name (static string). */
const char *fw_cia402_state_name(fw_cia402_state_t st);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_CIA402_H */
