/**
 * @file co_hb.c
 * @brief CANopen slave, heartbeat: producer (0x1017) and consumer (0x1016).
 */
#include "co_internal.h"

#include <string.h>

/* 0x1016:1..CO_HB_CONSUMERS by compile-time handle (co_node.h): back to back */
_Static_assert(CO_HB_CONSUMERS == 2u && CO_OD_LEN_1016_01 == 4u && CO_OD_LEN_1016_02 == 4u &&
                   CO_OD_OFF_1016_02 == CO_OD_OFF_1016_01 + 4u,
               "0x1016:1..2 contiguous");

/** Consumer k (0-based): 0x1016:k+1. */
static uint32_t co_hb_consumer(const co_node_t *node, uint8_t k) {
  return co_node_get_at(node, (uint16_t)(CO_OD_OFF_1016_01 + 4u * k), 4u);
}

/** CiA 301 rules for 0x1016 (heartbeat consumers). */
co_abort_t co_hb_check_config(const co_node_t *node, uint8_t sub, uint32_t v) {
  if (sub >= 1u && sub <= CO_HB_CONSUMERS) {
    uint8_t nid = (uint8_t)(v >> 16);
    if ((v & 0xFF000000u) != 0u) {
      return CO_ABORT_VALUE_RANGE; /* bits 24-31 reserved */
    }
    if ((v & 0xFFFFu) == 0u || nid == 0u) {
      return CO_ABORT_NONE; /* an unused entry */
    }
    if (nid > 127u) {
      return CO_ABORT_VALUE_RANGE;
    }
    for (uint8_t k = 1u; k <= CO_HB_CONSUMERS; k++) {
      uint32_t other = co_get(node, 0x1016u, k);
      if (k != sub && (other & 0xFFFFu) != 0u && (uint8_t)(other >> 16) == nid) {
        return CO_ABORT_PARAM_INCOMPAT; /* one entry per node id */
      }
    }
  }
  return CO_ABORT_NONE;
}

void co_hb_frame(co_node_t *node, const fw_can_frame_t *f) {
  uint8_t nid = (uint8_t)(f->id - CO_COB_HB);
  if (f->dlc < 1u || f->rtr) {
    return;
  }
  for (uint8_t k = 0u; k < CO_HB_CONSUMERS; k++) {
    uint32_t cfg = co_hb_consumer(node, k);
    uint8_t cfg_nid = (uint8_t)(cfg >> 16);
    if ((cfg & 0xFFFFu) == 0u || cfg_nid != nid || cfg_nid == 0u) {
      continue;
    }
    co_hb_rt_t *hb = &node->hb[k];
    hb->state = (uint8_t)(f->data[0] & 0x7Fu);
    hb->last_us = node->now_us;
    hb->active = 1u;
    if (hb->lost) {
      hb->lost = 0u;
      co_event(node, CO_EV_HB_RESUMED, nid);
    }
  }
}

/** Consumer timeouts: called after the received frames and again before
 *  transmitting, so a timeout is seen in the control period it happens. */
void co_hb_check(co_node_t *node, uint32_t now_us) {
  for (uint8_t k = 0u; k < CO_HB_CONSUMERS; k++) {
    uint32_t cfg = co_hb_consumer(node, k);
    co_hb_rt_t *hb = &node->hb[k];
    if ((cfg & 0xFFFFu) == 0u || !hb->active || hb->lost) {
      continue;
    }
    if (co_elapsed(now_us, hb->last_us, (cfg & 0xFFFFu) * 1000u)) {
      hb->lost = 1u;
      co_event(node, CO_EV_HB_LOST, (cfg >> 16) & 0xFFu);
    }
  }
}

void co_hb_produce(co_node_t *node, uint32_t now_us) {
  uint32_t hb_ms = CO_NODE_GET(node, 1017_00);
  if (hb_ms > 0u && co_elapsed(now_us, node->hb_last_us, hb_ms * 1000u)) {
    uint8_t st = (uint8_t)node->nmt;
    node->hb_last_us = now_us;
    co_send(node, (uint16_t)(CO_COB_HB + node->node_id), 1u, &st);
  }
}
