/**
 * @file fw_cia402.c
 * @brief CiA 402 power drive system state machine (transitions 0-16 of the
 *        CiA 402 state diagram) and statusword 0x6041 encoding.
 */
#include "pmlsm/fw_cia402.h"

/* Controlword command recognition: (cw & mask) == value. Bit 7 (fault reset)
 * is in every mask, so a controlword with bit 7 set issues no command. */
#define FW_CW_MASK_SHUTDOWN 0x0087u
#define FW_CW_MASK_SWITCH_ON 0x008Fu /* also disable / enable operation */
#define FW_CW_MASK_DISABLE_VOLTAGE 0x0082u
#define FW_CW_MASK_QUICK_STOP 0x0086u
#define FW_CW_BIT_FAULT_RESET 0x0080u

/* Statusword bits (0x6041). */
#define FW_SW_READY_TO_SWITCH_ON 0x0001u
#define FW_SW_SWITCHED_ON 0x0002u
#define FW_SW_OPERATION_ENABLED 0x0004u
#define FW_SW_FAULT 0x0008u
#define FW_SW_VOLTAGE_ENABLED 0x0010u
#define FW_SW_QUICK_STOP 0x0020u /* 1 = quick stop NOT active */
#define FW_SW_SWITCH_ON_DISABLED 0x0040u
#define FW_SW_WARNING 0x0080u
#define FW_SW_REMOTE 0x0200u
#define FW_SW_TARGET_REACHED 0x0400u
#define FW_SW_INTERNAL_LIMIT 0x0800u

static bool fw_cw_is(uint16_t cw, unsigned mask, unsigned value) {
  return ((unsigned)cw & mask) == value;
}

void fw_cia402_init(fw_cia402_t *sm) { /* transition 0 */
  sm->state = FW_CIA402_NOT_READY_TO_SWITCH_ON;
  sm->last_cw = 0u;
}

void fw_cia402_init_done(fw_cia402_t *sm) { /* transition 1 */
  if (sm->state == FW_CIA402_NOT_READY_TO_SWITCH_ON) {
    sm->state = FW_CIA402_SWITCH_ON_DISABLED;
  }
}

fw_cia402_state_t fw_cia402_controlword(fw_cia402_t *sm, uint16_t cw) {
  const bool shutdown = fw_cw_is(cw, FW_CW_MASK_SHUTDOWN, FW_CW_SHUTDOWN);
  const bool switch_on = fw_cw_is(cw, FW_CW_MASK_SWITCH_ON, FW_CW_SWITCH_ON);
  const bool enable_op =
      fw_cw_is(cw, FW_CW_MASK_SWITCH_ON, FW_CW_ENABLE_OPERATION);
  const bool disable_voltage =
      fw_cw_is(cw, FW_CW_MASK_DISABLE_VOLTAGE, FW_CW_DISABLE_VOLTAGE);
  const bool quick_stop = fw_cw_is(cw, FW_CW_MASK_QUICK_STOP, FW_CW_QUICK_STOP);
  const bool reset_edge = ((unsigned)cw & FW_CW_BIT_FAULT_RESET) != 0u &&
                          ((unsigned)sm->last_cw & FW_CW_BIT_FAULT_RESET) == 0u;
  sm->last_cw = cw;

  switch (sm->state) {
  case FW_CIA402_SWITCH_ON_DISABLED:
    if (shutdown) {
      sm->state = FW_CIA402_READY_TO_SWITCH_ON; /* 2 */
    }
    break;
  case FW_CIA402_READY_TO_SWITCH_ON:
    if (disable_voltage || quick_stop) {
      sm->state = FW_CIA402_SWITCH_ON_DISABLED; /* 7 */
    } else if (switch_on) {
      sm->state = FW_CIA402_SWITCHED_ON; /* 3 */
    } else if (enable_op) {
      sm->state = FW_CIA402_OPERATION_ENABLED; /* 3 + 4 in one call */
    }
    break;
  case FW_CIA402_SWITCHED_ON:
    if (disable_voltage || quick_stop) {
      sm->state = FW_CIA402_SWITCH_ON_DISABLED; /* 10 */
    } else if (shutdown) {
      sm->state = FW_CIA402_READY_TO_SWITCH_ON; /* 6 */
    } else if (enable_op) {
      sm->state = FW_CIA402_OPERATION_ENABLED; /* 4 */
    }
    break;
  case FW_CIA402_OPERATION_ENABLED:
    if (disable_voltage) {
      sm->state = FW_CIA402_SWITCH_ON_DISABLED; /* 9 */
    } else if (quick_stop) {
      sm->state = FW_CIA402_QUICK_STOP_ACTIVE; /* 11 */
    } else if (shutdown) {
      sm->state = FW_CIA402_READY_TO_SWITCH_ON; /* 8 */
    } else if (switch_on) { /* = disable operation */
      sm->state = FW_CIA402_SWITCHED_ON; /* 5 */
    }
    break;
  case FW_CIA402_QUICK_STOP_ACTIVE:
    if (disable_voltage) {
      sm->state = FW_CIA402_SWITCH_ON_DISABLED; /* 12 */
    } else if (enable_op) {
      sm->state = FW_CIA402_OPERATION_ENABLED; /* 16 */
    }
    break;
  case FW_CIA402_FAULT:
    if (reset_edge) {
      sm->state = FW_CIA402_SWITCH_ON_DISABLED; /* 15 */
    }
    break;
  case FW_CIA402_NOT_READY_TO_SWITCH_ON:   /* waits for init_done (1) */
  case FW_CIA402_FAULT_REACTION_ACTIVE:    /* waits for reaction done (14) */
  default:
    break;
  }
  return sm->state;
}

void fw_cia402_fault(fw_cia402_t *sm) { /* 13 */
  if (sm->state != FW_CIA402_FAULT) {
    sm->state = FW_CIA402_FAULT_REACTION_ACTIVE;
  }
}

void fw_cia402_fault_reaction_done(fw_cia402_t *sm) { /* 14 */
  if (sm->state == FW_CIA402_FAULT_REACTION_ACTIVE) {
    sm->state = FW_CIA402_FAULT;
  }
}

void fw_cia402_quick_stop_done(fw_cia402_t *sm) { /* 12 */
  if (sm->state == FW_CIA402_QUICK_STOP_ACTIVE) {
    sm->state = FW_CIA402_SWITCH_ON_DISABLED;
  }
}

uint16_t fw_cia402_statusword(const fw_cia402_t *sm, bool warning, bool remote,
                              bool target_reached, bool internal_limit) {
  /* Bit 4 (voltage enabled): set in the states in which the power stage may
   * be energised: SWITCHED ON, OPERATION ENABLED, QUICK STOP ACTIVE and
   * FAULT REACTION ACTIVE (PWM is being switched off). Bit 5 (quick stop,
   * active low) is 1 in READY TO SWITCH ON / SWITCHED ON / OPERATION
   * ENABLED, 0 in QUICK STOP ACTIVE and in the states where the standard
   * leaves it open. */
  unsigned sw;
  switch (sm->state) {
  case FW_CIA402_SWITCH_ON_DISABLED:
    sw = FW_SW_SWITCH_ON_DISABLED; /* 0x40 */
    break;
  case FW_CIA402_READY_TO_SWITCH_ON:
    sw = FW_SW_QUICK_STOP | FW_SW_READY_TO_SWITCH_ON; /* 0x21 */
    break;
  case FW_CIA402_SWITCHED_ON:
    sw = FW_SW_QUICK_STOP | FW_SW_SWITCHED_ON | FW_SW_READY_TO_SWITCH_ON |
         FW_SW_VOLTAGE_ENABLED; /* 0x23 | bit4 */
    break;
  case FW_CIA402_OPERATION_ENABLED:
    sw = FW_SW_QUICK_STOP | FW_SW_OPERATION_ENABLED | FW_SW_SWITCHED_ON |
         FW_SW_READY_TO_SWITCH_ON | FW_SW_VOLTAGE_ENABLED; /* 0x27 | bit4 */
    break;
  case FW_CIA402_QUICK_STOP_ACTIVE:
    sw = FW_SW_OPERATION_ENABLED | FW_SW_SWITCHED_ON |
         FW_SW_READY_TO_SWITCH_ON | FW_SW_VOLTAGE_ENABLED; /* 0x07 | bit4 */
    break;
  case FW_CIA402_FAULT_REACTION_ACTIVE:
    sw = FW_SW_FAULT | FW_SW_OPERATION_ENABLED | FW_SW_SWITCHED_ON |
         FW_SW_READY_TO_SWITCH_ON | FW_SW_VOLTAGE_ENABLED; /* 0x0F | bit4 */
    break;
  case FW_CIA402_FAULT:
    sw = FW_SW_FAULT; /* 0x08 */
    break;
  case FW_CIA402_NOT_READY_TO_SWITCH_ON:
  default:
    sw = 0u; /* 0x00 */
    break;
  }
  if (warning) {
    sw |= FW_SW_WARNING;
  }
  if (remote) {
    sw |= FW_SW_REMOTE;
  }
  if (target_reached) {
    sw |= FW_SW_TARGET_REACHED;
  }
  if (internal_limit) {
    sw |= FW_SW_INTERNAL_LIMIT;
  }
  return (uint16_t)sw;
}

bool fw_cia402_power_enabled(fw_cia402_state_t st) {
  /* The bridge switches while the drive function is enabled: in OPERATION
   * ENABLED and while ramping down in QUICK STOP ACTIVE. FAULT REACTION
   * ACTIVE is excluded on purpose: this drive's fault reaction is "PWM off". */
  return st == FW_CIA402_OPERATION_ENABLED || st == FW_CIA402_QUICK_STOP_ACTIVE;
}

const char *fw_cia402_state_name(fw_cia402_state_t st) {
  switch (st) {
  case FW_CIA402_NOT_READY_TO_SWITCH_ON: return "NOT READY TO SWITCH ON";
  case FW_CIA402_SWITCH_ON_DISABLED: return "SWITCH ON DISABLED";
  case FW_CIA402_READY_TO_SWITCH_ON: return "READY TO SWITCH ON";
  case FW_CIA402_SWITCHED_ON: return "SWITCHED ON";
  case FW_CIA402_OPERATION_ENABLED: return "OPERATION ENABLED";
  case FW_CIA402_QUICK_STOP_ACTIVE: return "QUICK STOP ACTIVE";
  case FW_CIA402_FAULT_REACTION_ACTIVE: return "FAULT REACTION ACTIVE";
  case FW_CIA402_FAULT: return "FAULT";
  default: return "INVALID";
  }
}
