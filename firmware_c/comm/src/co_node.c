/**
 * @file co_node.c
 * @brief CANopen slave, node core: frame rings, OD access, generic write/read
 *        with the communication-parameter rules, init, receive dispatch and
 *        the process steps. The services: co_nmt.c, co_sdo.c, co_pdo.c,
 *        co_sync.c, co_emcy.c, co_hb.c (co_internal.h).
 */
#include "pmlsm/co_node.h"

#include "co_internal.h"

#include <stdatomic.h>
#include <string.h>

/* ---- queue ------------------------------------------------------------ */

void co_queue_init(co_queue_t *q) {
  if (q == NULL) {
    return;
  }
  memset(q, 0, sizeof *q);
}

co_status_t co_queue_push(co_queue_t *q, const fw_can_frame_t *frame) {
  if (q == NULL || frame == NULL) {
    return CO_ERR_NULL;
  }
  uint32_t head = q->head;
  if (head - q->tail >= CO_QUEUE_LEN) {
    q->dropped = q->dropped + 1u;
    return CO_ERR_FULL;
  }
  q->buf[head % CO_QUEUE_LEN] = *frame;
  if (q->buf[head % CO_QUEUE_LEN].dlc > 8u) {
    q->buf[head % CO_QUEUE_LEN].dlc = 8u;
  }
  atomic_signal_fence(memory_order_release);
  q->head = head + 1u;
  return CO_OK;
}

bool co_queue_pop(co_queue_t *q, fw_can_frame_t *frame) {
  if (q == NULL || frame == NULL) {
    return false;
  }
  uint32_t tail = q->tail;
  if (tail == q->head) {
    return false;
  }
  atomic_signal_fence(memory_order_acquire);
  *frame = q->buf[tail % CO_QUEUE_LEN];
  q->tail = tail + 1u;
  return true;
}

/* ---- helpers ------------------------------------------------------------ */

void co_send(co_node_t *node, uint16_t id, uint8_t dlc, const uint8_t *data) {
  fw_can_frame_t f;
  memset(&f, 0, sizeof f);
  f.id = (uint16_t)(id & 0x7FFu);
  f.dlc = dlc > 8u ? 8u : dlc;
  if (data != NULL && f.dlc > 0u) {
    memcpy(f.data, data, f.dlc);
  }
  if (co_queue_push(&node->txq, &f) == CO_OK) {
    node->count.tx_frames++;
  }
}

uint32_t co_get(const co_node_t *node, uint16_t index, uint8_t sub) {
  uint16_t pos;
  if (co_od_find(index, sub, &pos) != CO_OD_OK) {
    return 0u;
  }
  return co_od_get_u32(node->od, sizeof node->od, pos);
}

/* ---- direct OD access ------------------------------------------------------ */

uint32_t co_node_get_u32(const co_node_t *node, uint16_t pos) {
  return node != NULL ? co_od_get_u32(node->od, sizeof node->od, pos) : 0u;
}
int32_t co_node_get_i32(const co_node_t *node, uint16_t pos) {
  return node != NULL ? co_od_get_i32(node->od, sizeof node->od, pos) : 0;
}
float co_node_get_f32(const co_node_t *node, uint16_t pos) {
  return node != NULL ? co_od_get_f32(node->od, sizeof node->od, pos) : 0.0f;
}
void co_node_set_u32(co_node_t *node, uint16_t pos, uint32_t v) {
  if (node != NULL) {
    co_od_set_u32(node->od, sizeof node->od, pos, v);
  }
}
void co_node_set_i32(co_node_t *node, uint16_t pos, int32_t v) {
  if (node != NULL) {
    co_od_set_i32(node->od, sizeof node->od, pos, v);
  }
}
void co_node_set_f32(co_node_t *node, uint16_t pos, float v) {
  if (node != NULL) {
    co_od_set_f32(node->od, sizeof node->od, pos, v);
  }
}
void co_node_set_str(co_node_t *node, uint16_t pos, const char *s) {
  const co_od_entry_t *e = co_od_entry(pos);
  if (node == NULL || s == NULL || e == NULL || e->type != CO_TYPE_VSTRING) {
    return;
  }
  size_t n = strlen(s);
  co_od_store(node->od, sizeof node->od, pos, (const uint8_t *)s, n > e->size ? e->size : n);
}

/* ---- init ----------------------------------------------------------------- */

co_status_t co_node_init(co_node_t *node, uint8_t node_id, const co_callbacks_t *cb) {
  if (node == NULL) {
    return CO_ERR_NULL;
  }
  if (node_id < 1u || node_id > 127u) {
    return CO_ERR_ARG;
  }
  memset(node, 0, sizeof *node);
  node->node_id = node_id;
  if (cb != NULL) {
    node->cb = *cb;
  }
  co_queue_init(&node->rxq);
  co_queue_init(&node->txq);
  co_od_reset(node->od, sizeof node->od, node_id);
  co_boot(node);
  return CO_OK;
}

/* ---- generic write / read --------------------------------------------- */

/** CiA 301 rules for the communication parameters, by the service that owns them. */
static co_abort_t co_check_comm_write(const co_node_t *node, uint16_t index, uint8_t sub,
                                      const uint8_t *data, size_t len) {
  uint32_t v = co_le_get(data, len > 4u ? 4u : len);
  if (index == 0x1005u) {
    return co_sync_check_config(v);
  }
  if (index == 0x1014u) {
    return co_emcy_check_config(node, v);
  }
  if (index == 0x1016u) {
    return co_hb_check_config(node, sub, v);
  }
  if (co_is_store_cmd(index, sub)) {
    /* CiA 301: a wrong signature is refused with 0x08000020; without an
       application there is nothing that could store or restore */
    uint32_t want = index == 0x1010u ? CO_SIGNATURE_SAVE : CO_SIGNATURE_LOAD;
    return (len == 4u && v == want && node->cb.on_write != NULL) ? CO_ABORT_NONE : CO_ABORT_APP;
  }
  return co_pdo_check_config(node, index, sub, v);
}

co_abort_t co_write_pos(co_node_t *node, uint16_t pos, const uint8_t *data, size_t len,
                        bool from_pdo) {
  const co_od_entry_t *e = co_od_entry(pos);
  if (e == NULL) {
    return CO_ABORT_NO_OBJECT;
  }
  if ((e->access & CO_ACC_W) == 0u) {
    return CO_ABORT_READ_ONLY;
  }
  co_abort_t a = co_od_check(pos, data, len);
  if (a != CO_ABORT_NONE) {
    return a;
  }
  if (!from_pdo) {
    a = co_check_comm_write(node, e->index, e->sub, data, len);
    if (a != CO_ABORT_NONE) {
      return a;
    }
  }
  if (node->cb.on_write != NULL) {
    a = node->cb.on_write(node->cb.ctx, e->index, e->sub, data, len);
    if (a != CO_ABORT_NONE) {
      return a;
    }
  }
  if (co_is_store_cmd(e->index, e->sub)) {
    return CO_ABORT_NONE; /* a command, done by the hook: the OD keeps the capabilities */
  }
  co_od_store(node->od, sizeof node->od, pos, data, len);
  /* side effects */
  if (e->index == 0x1016u && e->sub >= 1u && e->sub <= CO_HB_CONSUMERS) {
    memset(&node->hb[e->sub - 1u], 0, sizeof node->hb[0]);
  }
  if (co_is_tpdo_comm(e->index)) {
    memset(&node->tpdo[e->index - 0x1800u], 0, sizeof node->tpdo[0]);
  }
  if (co_is_rpdo_comm(e->index)) {
    memset(&node->rpdo[e->index - 0x1400u], 0, sizeof node->rpdo[0]);
  }
  return CO_ABORT_NONE;
}

co_abort_t co_node_write(co_node_t *node, uint16_t index, uint8_t sub, const uint8_t *data,
                         size_t len) {
  uint16_t pos;
  if (node == NULL || (data == NULL && len > 0u)) {
    return CO_ABORT_GENERAL;
  }
  co_od_status_t st = co_od_find(index, sub, &pos);
  if (st == CO_OD_NO_OBJECT) {
    return CO_ABORT_NO_OBJECT;
  }
  if (st == CO_OD_NO_SUB) {
    return CO_ABORT_NO_SUB;
  }
  return co_write_pos(node, pos, data, len, false);
}

co_abort_t co_node_read(const co_node_t *node, uint16_t index, uint8_t sub, uint8_t *buf,
                        size_t *len) {
  uint16_t pos;
  if (node == NULL || buf == NULL || len == NULL) {
    return CO_ABORT_GENERAL;
  }
  co_od_status_t st = co_od_find(index, sub, &pos);
  if (st == CO_OD_NO_OBJECT) {
    return CO_ABORT_NO_OBJECT;
  }
  if (st == CO_OD_NO_SUB) {
    return CO_ABORT_NO_SUB;
  }
  const co_od_entry_t *e = co_od_entry(pos);
  if (e == NULL || (e->access & CO_ACC_R) == 0u) {
    return CO_ABORT_WRITE_ONLY;
  }
  if (*len < e->size) {
    return CO_ABORT_GENERAL;
  }
  *len = co_od_load(node->od, sizeof node->od, pos, buf, *len);
  return CO_ABORT_NONE;
}

/* ---- process ---------------------------------------------------------------- */

co_status_t co_node_rx_isr(co_node_t *node, const fw_can_frame_t *frame) {
  if (node == NULL || frame == NULL) {
    return CO_ERR_NULL;
  }
  return co_queue_push(&node->rxq, frame);
}

void co_node_process_rx(co_node_t *node, uint32_t now_us) {
  fw_can_frame_t f;
  if (node == NULL) {
    return;
  }
  node->now_us = now_us;
  while (co_queue_pop(&node->rxq, &f)) {
    uint16_t id = (uint16_t)(f.id & 0x7FFu);
    f.id = id;
    if (f.dlc > 8u) {
      f.dlc = 8u;
    }
    node->count.rx_frames++;
    if (id == CO_COB_NMT) {
      co_nmt_frame(node, &f);
      continue;
    }
    if (node->nmt == CO_NMT_STOPPED) {
      if (id > CO_COB_HB && id <= CO_COB_HB + 127u) {
        co_hb_frame(node, &f);
      }
      continue;
    }
    uint32_t sync_cob = CO_NODE_GET(node, 1005_00);
    if (id == (sync_cob & 0x7FFu) && !f.rtr) {
      co_sync(node);
    } else if (id == CO_COB_SDO_RX + node->node_id) {
      co_sdo_frame(node, &f);
    } else if (id > CO_COB_HB && id <= CO_COB_HB + 127u) {
      co_hb_frame(node, &f);
    } else if (node->nmt == CO_NMT_OPERATIONAL) {
      (void)co_rpdo_frame(node, &f);
    }
  }
  co_hb_check(node, now_us);
  co_rpdo_check(node, now_us);
}

void co_node_process_tx(co_node_t *node, uint32_t now_us) {
  if (node == NULL) {
    return;
  }
  node->now_us = now_us;
  co_sdo_check_timeout(node, now_us);
  co_hb_produce(node, now_us);
  co_hb_check(node, now_us);
  co_rpdo_check(node, now_us);
  co_tpdo_process(node, now_us);
}

bool co_node_tx_pop(co_node_t *node, fw_can_frame_t *frame) {
  if (node == NULL || frame == NULL) {
    return false;
  }
  return co_queue_pop(&node->txq, frame);
}

