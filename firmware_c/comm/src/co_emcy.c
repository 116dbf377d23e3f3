/**
 * @file co_emcy.c
 * @brief CANopen slave, EMCY producer (0x1014 COB-ID, 0x1001 error register).
 */
#include "co_internal.h"

#include <string.h>

/** CiA 301 rules for 0x1014 (EMCY COB-ID). */
co_abort_t co_emcy_check_config(const co_node_t *node, uint32_t v) {
  uint32_t cur = co_get(node, 0x1014u, 0u);
  if ((v & 0x7FFFF800u) != 0u || ((v & CO_COB_INVALID) == 0u && (v & 0x7FFu) == 0u)) {
    return CO_ABORT_VALUE_RANGE; /* 29-bit id, reserved bits, id 0 */
  }
  /* while the EMCY is valid (bit 31 = 0) bits 0-29 may not change:
     first write it invalid (same id), then the new id */
  if ((cur & CO_COB_INVALID) == 0u && (v & 0x3FFFFFFFu) != (cur & 0x3FFFFFFFu)) {
    return CO_ABORT_VALUE_RANGE;
  }
  return CO_ABORT_NONE;
}

co_status_t co_node_emcy(co_node_t *node, uint16_t code, uint8_t err_reg,
                         const uint8_t msef[5]) {
  if (node == NULL) {
    return CO_ERR_NULL;
  }
  uint16_t pos;
  if (co_od_find(0x1001u, 0u, &pos) == CO_OD_OK) {
    co_od_set_u32(node->od, sizeof node->od, pos, err_reg);
  }
  uint32_t cob = co_get(node, 0x1014u, 0u);
  if ((cob & CO_COB_INVALID) != 0u || node->nmt == CO_NMT_STOPPED ||
      node->nmt == CO_NMT_INITIALISING) {
    return CO_ERR_STATE;
  }
  uint8_t d[8] = {(uint8_t)code, (uint8_t)(code >> 8), err_reg, 0u, 0u, 0u, 0u, 0u};
  if (msef != NULL) {
    memcpy(&d[3], msef, 5u);
  }
  co_send(node, (uint16_t)(cob & 0x7FFu), 8u, d);
  node->count.emcy_sent++;
  return CO_OK;
}
