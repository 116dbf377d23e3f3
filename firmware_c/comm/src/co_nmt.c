/**
 * @file co_nmt.c
 * @brief CANopen slave, NMT: state machine, boot-up, reset node / reset communication.
 */
#include "co_internal.h"

#include <string.h>

co_nmt_state_t co_node_nmt(const co_node_t *node) {
  return node != NULL ? node->nmt : CO_NMT_INITIALISING;
}

static void co_set_nmt(co_node_t *node, co_nmt_state_t st) {
  if (node->nmt != st) {
    node->nmt = st;
    if (st == CO_NMT_OPERATIONAL) {
      /* RPDO deadlines restart with the first PDO applied in OPERATIONAL */
      for (uint8_t n = 0u; n < CO_OD_NR_RPDO; n++) {
        node->rpdo[n].watched = 0u;
        node->rpdo[n].timed_out = 0u;
      }
    }
    co_event(node, CO_EV_NMT, (uint32_t)st);
  }
}

static void co_reset_comm_rt(co_node_t *node) {
  memset(&node->sdo, 0, sizeof node->sdo);
  memset(node->rpdo, 0, sizeof node->rpdo);
  memset(node->tpdo, 0, sizeof node->tpdo);
  memset(node->hb, 0, sizeof node->hb);
  node->hb_last_us = node->now_us;
}

/** Reset the OD range [lo, hi] to defaults. */
static void co_reset_od_range(co_node_t *node, uint16_t lo, uint16_t hi) {
  uint8_t tmp[CO_OD_RAM_SIZE] = {0}; /* text slots: no stack leftovers in the tails */
  co_od_reset(tmp, sizeof tmp, node->node_id);
  for (uint16_t pos = 0u; pos < CO_OD_COUNT; pos++) {
    const co_od_entry_t *e = co_od_entry(pos);
    if (e != NULL && e->index >= lo && e->index <= hi) {
      size_t n = (size_t)e->size + (e->type == CO_TYPE_VSTRING ? 1u : 0u);
      memcpy(&node->od[e->offset], &tmp[e->offset], n);
    }
  }
}

void co_boot(co_node_t *node) {
  uint8_t zero = 0u;
  node->nmt = CO_NMT_INITIALISING;
  co_reset_comm_rt(node);
  co_send(node, (uint16_t)(CO_COB_HB + node->node_id), 1u, &zero);
  co_set_nmt(node, CO_NMT_PRE_OPERATIONAL);
}

void co_nmt_frame(co_node_t *node, const fw_can_frame_t *f) {
  if (f->dlc < 2u || f->rtr || (f->data[1] != 0u && f->data[1] != node->node_id)) {
    return;
  }
  switch (f->data[0]) {
  case 0x01u:
    co_set_nmt(node, CO_NMT_OPERATIONAL);
    break;
  case 0x02u:
    co_set_nmt(node, CO_NMT_STOPPED);
    break;
  case 0x80u:
    co_set_nmt(node, CO_NMT_PRE_OPERATIONAL);
    break;
  case 0x81u:
    co_reset_od_range(node, 0x0000u, 0xFFFFu);
    co_event(node, CO_EV_RESET_NODE, 0u);
    co_boot(node);
    break;
  case 0x82u:
    co_reset_od_range(node, 0x1000u, 0x1FFFu);
    co_event(node, CO_EV_RESET_COMM, 0u);
    co_boot(node);
    break;
  default:
    break;
  }
}
