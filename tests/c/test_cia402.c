/* Tests for fw_cia402: every transition 0-16 of the CiA 402 state diagram
 * (full state x command table, with and without don't-care controlword
 * bits), statusword patterns, fault / fault-reset edge, quick stop. */
#include <string.h>

#include "pmlsm/fw_cia402.h"
#include "tinytest.h"

enum { NR, SOD, RTSO, SO, OE, QSA, FRA, FLT, N_STATES };
static const fw_cia402_state_t ST[N_STATES] = {
    FW_CIA402_NOT_READY_TO_SWITCH_ON, FW_CIA402_SWITCH_ON_DISABLED,
    FW_CIA402_READY_TO_SWITCH_ON,     FW_CIA402_SWITCHED_ON,
    FW_CIA402_OPERATION_ENABLED,      FW_CIA402_QUICK_STOP_ACTIVE,
    FW_CIA402_FAULT_REACTION_ACTIVE,  FW_CIA402_FAULT};

/* Bring a fresh machine to state s along the standard path (last_cw = 0
 * except where a command was needed). */
static void goto_state(fw_cia402_t *sm, int s) {
  fw_cia402_init(sm); /* transition 0 */
  if (s == NR) {
    return;
  }
  fw_cia402_init_done(sm); /* 1 */
  if (s == FRA || s == FLT) {
    fw_cia402_fault(sm); /* 13 */
    if (s == FLT) {
      fw_cia402_fault_reaction_done(sm); /* 14 */
    }
    return;
  }
  if (s == SOD) {
    return;
  }
  (void)fw_cia402_controlword(sm, FW_CW_SHUTDOWN); /* 2 */
  if (s == RTSO) {
    return;
  }
  (void)fw_cia402_controlword(sm, FW_CW_SWITCH_ON); /* 3 */
  if (s == SO) {
    return;
  }
  (void)fw_cia402_controlword(sm, FW_CW_ENABLE_OPERATION); /* 4 */
  if (s == QSA) {
    (void)fw_cia402_controlword(sm, FW_CW_QUICK_STOP); /* 11 */
  }
}

static void test_paths(void) {
  fw_cia402_t sm;
  for (int s = 0; s < N_STATES; s++) {
    goto_state(&sm, s);
    TT_CHECK(sm.state == ST[s]);
  }
}

/* Expected next state for each (state, command), written from the CiA 402
 * diagram: commands shutdown, switch on (= disable operation), enable
 * operation, disable voltage, quick stop, fault reset (rising edge). */
enum { C_SHUT, C_SWON, C_ENOP, C_DISV, C_QS, C_FR, N_CMDS };
static const uint16_t CMD[N_CMDS] = {FW_CW_SHUTDOWN, FW_CW_SWITCH_ON, FW_CW_ENABLE_OPERATION,
                                     FW_CW_DISABLE_VOLTAGE, FW_CW_QUICK_STOP, FW_CW_FAULT_RESET};
static const int NEXT[N_STATES][N_CMDS] = {
    /*          SHUT  SWON  ENOP  DISV  QS    FR  */
    /* NR   */ {NR, NR, NR, NR, NR, NR},
    /* SOD  */ {RTSO, SOD, SOD, SOD, SOD, SOD},      /* 2 */
    /* RTSO */ {RTSO, SO, OE, SOD, SOD, RTSO},       /* 3, 3+4, 7, 7 */
    /* SO   */ {RTSO, SO, OE, SOD, SOD, SO},         /* 6, 4, 10, 10 */
    /* OE   */ {RTSO, SO, OE, SOD, QSA, OE},         /* 8, 5, 9, 11 */
    /* QSA  */ {QSA, QSA, OE, SOD, QSA, QSA},        /* 16, 12 */
    /* FRA  */ {FRA, FRA, FRA, FRA, FRA, FRA},       /* waits for 14 */
    /* FLT  */ {FLT, FLT, FLT, FLT, FLT, SOD}};      /* 15 */

static void test_transition_table(void) {
  /* bits 4..6 and 8..15 are operation-mode / manufacturer bits: don't care */
  const uint16_t dont_care[] = {0x0000u, 0xFF70u, 0x0110u};
  fw_cia402_t sm;
  for (unsigned d = 0; d < 3; d++) {
    for (int s = 0; s < N_STATES; s++) {
      for (int c = 0; c < N_CMDS; c++) {
        goto_state(&sm, s);
        const uint16_t cw = (uint16_t)(CMD[c] | dont_care[d]);
        const fw_cia402_state_t got = fw_cia402_controlword(&sm, cw);
        TT_CHECK(got == sm.state);
        if (got != ST[NEXT[s][c]]) {
          printf("  state %s + cw 0x%04X -> %s, expected %s\n", fw_cia402_state_name(ST[s]),
                 (unsigned)cw, fw_cia402_state_name(got),
                 fw_cia402_state_name(ST[NEXT[s][c]]));
        }
        TT_CHECK(got == ST[NEXT[s][c]]);
        TT_CHECK(sm.last_cw == cw);
      }
    }
  }
  /* with the fault-reset bit set, no other command is recognised */
  goto_state(&sm, SOD);
  TT_CHECK(fw_cia402_controlword(&sm, 0x0086u) == FW_CIA402_SWITCH_ON_DISABLED);
  goto_state(&sm, OE);
  TT_CHECK(fw_cia402_controlword(&sm, 0x0080u) == FW_CIA402_OPERATION_ENABLED);
  TT_CHECK(fw_cia402_controlword(&sm, 0x0082u) == FW_CIA402_OPERATION_ENABLED);
}

/* Statusword (value & mask) per CiA 402, plus bit 4 / bit 5 as documented
 * in fw_cia402.c: bit 4 in SO/OE/QSA/FRA, bit 5 = 1 only in RTSO/SO/OE. */
static void test_statusword(void) {
  static const uint16_t val[N_STATES] = {0x00u, 0x40u, 0x21u, 0x23u, 0x27u, 0x07u, 0x0Fu, 0x08u};
  static const uint16_t mask[N_STATES] = {0x4Fu, 0x4Fu, 0x6Fu, 0x6Fu,
                                          0x6Fu, 0x6Fu, 0x4Fu, 0x4Fu};
  static const int bit4[N_STATES] = {0, 0, 0, 1, 1, 1, 1, 0};
  static const int bit5[N_STATES] = {0, 0, 1, 1, 1, 0, 0, 0};
  static const int power[N_STATES] = {0, 0, 0, 0, 1, 1, 0, 0};
  fw_cia402_t sm;
  for (int s = 0; s < N_STATES; s++) {
    goto_state(&sm, s);
    const uint16_t sw = fw_cia402_statusword(&sm, false, false, false, false);
    TT_CHECK((sw & mask[s]) == val[s]);
    TT_CHECK(((sw >> 4) & 1u) == (unsigned)bit4[s]);
    TT_CHECK(((sw >> 5) & 1u) == (unsigned)bit5[s]);
    TT_CHECK((sw & 0x0F80u) == 0u); /* no flag bits unless asked */
    TT_CHECK(fw_cia402_power_enabled(ST[s]) == (power[s] != 0));
    /* flags */
    TT_CHECK(fw_cia402_statusword(&sm, true, false, false, false) == (uint16_t)(sw | 0x0080u));
    TT_CHECK(fw_cia402_statusword(&sm, false, true, false, false) == (uint16_t)(sw | 0x0200u));
    TT_CHECK(fw_cia402_statusword(&sm, false, false, true, false) == (uint16_t)(sw | 0x0400u));
    TT_CHECK(fw_cia402_statusword(&sm, true, true, true, false) == (uint16_t)(sw | 0x0680u));
    TT_CHECK(fw_cia402_statusword(&sm, false, false, false, true) == (uint16_t)(sw | 0x0800u));
  }
  goto_state(&sm, OE);
  TT_CHECK(fw_cia402_statusword(&sm, false, true, false, false) == 0x0237u);
}

/* 13, 14, 15: fault from every state, reaction done, fault reset only on a
 * rising edge of bit 7. */
static void test_fault_and_reset_edge(void) {
  fw_cia402_t sm;
  for (int s = 0; s < N_STATES; s++) {
    goto_state(&sm, s);
    fw_cia402_fault(&sm);
    TT_CHECK(sm.state == (s == FLT ? FW_CIA402_FAULT : FW_CIA402_FAULT_REACTION_ACTIVE));
    fw_cia402_fault_reaction_done(&sm);
    TT_CHECK(sm.state == FW_CIA402_FAULT);
  }
  /* reaction_done / quick_stop_done do nothing in other states */
  for (int s = 0; s < N_STATES; s++) {
    goto_state(&sm, s);
    fw_cia402_fault_reaction_done(&sm);
    TT_CHECK(sm.state == (s == FRA ? FW_CIA402_FAULT : ST[s]));
    goto_state(&sm, s);
    fw_cia402_quick_stop_done(&sm);
    TT_CHECK(sm.state == (s == QSA ? FW_CIA402_SWITCH_ON_DISABLED : ST[s]));
    goto_state(&sm, s);
    fw_cia402_init_done(&sm);
    TT_CHECK(sm.state == (s == NR ? FW_CIA402_SWITCH_ON_DISABLED : ST[s]));
  }
  /* edge: bit 7 held high through a new fault does not reset again */
  goto_state(&sm, FLT);
  TT_CHECK(fw_cia402_controlword(&sm, FW_CW_FAULT_RESET) == FW_CIA402_SWITCH_ON_DISABLED);
  fw_cia402_fault(&sm);
  fw_cia402_fault_reaction_done(&sm);
  TT_CHECK(fw_cia402_controlword(&sm, FW_CW_FAULT_RESET) == FW_CIA402_FAULT);
  TT_CHECK(fw_cia402_controlword(&sm, 0x0000u) == FW_CIA402_FAULT);
  TT_CHECK(fw_cia402_controlword(&sm, 0x0086u) == FW_CIA402_SWITCH_ON_DISABLED);
  /* a reset edge during the fault reaction is ignored (no edge left for FAULT) */
  goto_state(&sm, FRA);
  TT_CHECK(fw_cia402_controlword(&sm, FW_CW_FAULT_RESET) == FW_CIA402_FAULT_REACTION_ACTIVE);
  fw_cia402_fault_reaction_done(&sm);
  TT_CHECK(fw_cia402_controlword(&sm, FW_CW_FAULT_RESET) == FW_CIA402_FAULT);
  TT_CHECK(fw_cia402_controlword(&sm, FW_CW_SHUTDOWN) == FW_CIA402_FAULT);
  TT_CHECK(fw_cia402_controlword(&sm, FW_CW_FAULT_RESET) == FW_CIA402_SWITCH_ON_DISABLED);
  /* after the reset, the normal path works again */
  TT_CHECK(fw_cia402_controlword(&sm, FW_CW_SHUTDOWN) == FW_CIA402_READY_TO_SWITCH_ON);
  TT_CHECK(fw_cia402_controlword(&sm, FW_CW_ENABLE_OPERATION) == FW_CIA402_OPERATION_ENABLED);
}

/* 11, 12, 16: quick stop from OPERATION ENABLED */
static void test_quick_stop(void) {
  fw_cia402_t sm;
  goto_state(&sm, OE);
  TT_CHECK((fw_cia402_statusword(&sm, false, false, false, false) & 0x20u) != 0u);
  TT_CHECK(fw_cia402_controlword(&sm, FW_CW_QUICK_STOP) == FW_CIA402_QUICK_STOP_ACTIVE);
  TT_CHECK((fw_cia402_statusword(&sm, false, false, false, false) & 0x6Fu) == 0x07u);
  TT_CHECK(fw_cia402_power_enabled(sm.state)); /* still ramping down */
  /* holding the quick-stop command keeps it active until the drive stops */
  TT_CHECK(fw_cia402_controlword(&sm, FW_CW_QUICK_STOP) == FW_CIA402_QUICK_STOP_ACTIVE);
  fw_cia402_quick_stop_done(&sm);
  TT_CHECK(sm.state == FW_CIA402_SWITCH_ON_DISABLED);
  TT_CHECK(!fw_cia402_power_enabled(sm.state));
  /* 16: back to operation */
  goto_state(&sm, QSA);
  TT_CHECK(fw_cia402_controlword(&sm, FW_CW_ENABLE_OPERATION) == FW_CIA402_OPERATION_ENABLED);
  /* 12 by disable voltage */
  goto_state(&sm, QSA);
  TT_CHECK(fw_cia402_controlword(&sm, FW_CW_DISABLE_VOLTAGE) == FW_CIA402_SWITCH_ON_DISABLED);
  /* fault during quick stop */
  goto_state(&sm, QSA);
  fw_cia402_fault(&sm);
  TT_CHECK(sm.state == FW_CIA402_FAULT_REACTION_ACTIVE);
}

static void test_names(void) {
  static const char *const names[N_STATES] = {
      "NOT READY TO SWITCH ON", "SWITCH ON DISABLED", "READY TO SWITCH ON", "SWITCHED ON",
      "OPERATION ENABLED",      "QUICK STOP ACTIVE",  "FAULT REACTION ACTIVE", "FAULT"};
  for (int s = 0; s < N_STATES; s++) {
    TT_CHECK(strcmp(fw_cia402_state_name(ST[s]), names[s]) == 0);
  }
  TT_CHECK(strcmp(fw_cia402_state_name((fw_cia402_state_t)42), "INVALID") == 0);
}

int main(void) {
  TT_RUN(test_paths);
  TT_RUN(test_transition_table);
  TT_RUN(test_statusword);
  TT_RUN(test_fault_and_reset_edge);
  TT_RUN(test_quick_stop);
  TT_RUN(test_names);
  return TT_SUMMARY();
}
