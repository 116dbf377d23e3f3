/**
 * @file co_sync.c
 * @brief CANopen slave, SYNC consumer: synchronous RPDOs applied, synchronous TPDOs sent.
 */
#include "co_internal.h"

#include <string.h>

void co_sync(co_node_t *node) {
  if (node->nmt != CO_NMT_OPERATIONAL) {
    return;
  }
  for (uint8_t n = 0u; n < CO_OD_NR_RPDO; n++) {
    if (node->rpdo[n].pending) {
      node->rpdo[n].pending = 0u;
      co_rpdo_apply(node, n, node->rpdo[n].data, node->rpdo[n].dlc);
    }
  }
  for (uint8_t n = 0u; n < CO_OD_NR_TPDO; n++) {
    uint32_t cob = CO_TPDO_COMM(node, n, 01);
    uint32_t type = CO_TPDO_COMM(node, n, 02);
    co_tpdo_rt_t *rt = &node->tpdo[n];
    uint8_t data[8];
    if ((cob & CO_COB_INVALID) != 0u || type > 240u) {
      continue;
    }
    uint8_t len = co_tpdo_pack(node, n, data);
    if (type == 0u) {
      if (!rt->sent_once || len != rt->last_len || memcmp(data, rt->last, len) != 0) {
        co_tpdo_send(node, n, data, len);
      }
      continue;
    }
    rt->sync_count++;
    if (rt->sync_count >= type) {
      rt->sync_count = 0u;
      co_tpdo_send(node, n, data, len);
    }
  }
  co_event(node, CO_EV_SYNC, 0u);
}

co_abort_t co_sync_check_config(uint32_t v) {
  if ((v & 0x60000000u) != 0u) {
    return CO_ABORT_VALUE_RANGE; /* SYNC producer / 29-bit id: not supported */
  }
  return CO_ABORT_NONE;
}
