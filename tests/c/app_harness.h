/**
 * @file app_harness.h
 * @brief Drive-application test harness (test_co_app.c, test_nvm.c): step the
 *        application, feed it CAN frames, collect its answers, SDO expedited
 *        read/write as a master would. The includer defines NID and the
 *        fixture g_app, g_in, g_out before including this file.
 */
#ifndef PMLSM_TEST_APP_HARNESS_H
#define PMLSM_TEST_APP_HARNESS_H

#include <string.h>

#include "pmlsm/fw_app.h"
#include "tinytest.h"

static void step_n(uint32_t n) {
  for (uint32_t k = 0; k < n; k++) fw_app_step(&g_app, &g_in, &g_out);
}

static void rx(uint16_t id, uint8_t dlc, const uint8_t *d) {
  fw_can_frame_t f;
  memset(&f, 0, sizeof f);
  f.id = id;
  f.dlc = dlc;
  if (d) memcpy(f.data, d, dlc);
  TT_CHECK(fw_app_can_rx(&g_app, &f));
}

/* collect TX frames with a given id; returns count, last in *last */
static int pop_id(uint16_t id, fw_can_frame_t *last) {
  fw_can_frame_t f;
  int n = 0;
  while (fw_app_can_tx_pop(&g_app, &f)) {
    if (f.id == id) {
      n++;
      if (last) *last = f;
    }
  }
  return n;
}

/* SDO expedited download; 0 = accepted, else the abort code (0xFFFFFFFF: no answer) */
static uint32_t sdo_write(uint16_t idx, uint8_t sub, uint32_t v, uint8_t n) {
  uint8_t req[8] = {(uint8_t)(0x23 | ((4 - n) << 2)), (uint8_t)idx, (uint8_t)(idx >> 8), sub,
                    (uint8_t)v, (uint8_t)(v >> 8), (uint8_t)(v >> 16), (uint8_t)(v >> 24)};
  fw_can_frame_t r;
  pop_id(0, NULL);
  rx((uint16_t)(0x600 + NID), 8, req);
  step_n(1);
  if (pop_id((uint16_t)(0x580 + NID), &r) != 1) return 0xFFFFFFFFu;
  if (r.data[0] == 0x60) return 0;
  return (uint32_t)(r.data[4] | (r.data[5] << 8) | (r.data[6] << 16) |
                    ((uint32_t)r.data[7] << 24));
}

/* SDO expedited upload; 0xDEAD when refused or unanswered */
static uint32_t sdo_read(uint16_t idx, uint8_t sub) {
  uint8_t req[8] = {0x40, (uint8_t)idx, (uint8_t)(idx >> 8), sub, 0, 0, 0, 0};
  fw_can_frame_t r;
  pop_id(0, NULL);
  rx((uint16_t)(0x600 + NID), 8, req);
  step_n(1);
  if (pop_id((uint16_t)(0x580 + NID), &r) != 1 || (r.data[0] & 0xE3) != 0x43) return 0xDEADu;
  return (uint32_t)(r.data[4] | (r.data[5] << 8) | (r.data[6] << 16) |
                    ((uint32_t)r.data[7] << 24));
}

#endif /* PMLSM_TEST_APP_HARNESS_H */
