/**
 * @file co_node.c
 * @brief CANopen slave: NMT, SDO server, PDO, SYNC, heartbeat, EMCY.
 */
#include "pmlsm/co_node.h"

#include <stdatomic.h>
#include <string.h>

#define CO_COB_NMT 0x000u
#define CO_COB_SDO_TX 0x580u
#define CO_COB_SDO_RX 0x600u
#define CO_COB_HB 0x700u
#define CO_COB_INVALID 0x80000000u
#define CO_COB_EXT 0x20000000u

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

static void co_send(co_node_t *node, uint16_t id, uint8_t dlc, const uint8_t *data) {
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

static void co_event(co_node_t *node, co_event_t ev, uint32_t arg) {
  if (node->cb.on_event != NULL) {
    node->cb.on_event(node->cb.ctx, ev, arg);
  }
}

static uint32_t co_get(const co_node_t *node, uint16_t index, uint8_t sub) {
  uint16_t pos;
  if (co_od_find(index, sub, &pos) != CO_OD_OK) {
    return 0u;
  }
  return co_od_get_u32(node->od, sizeof node->od, pos);
}

static bool co_elapsed(uint32_t now, uint32_t since, uint32_t period_us) {
  return (uint32_t)(now - since) >= period_us;
}

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

co_nmt_state_t co_node_nmt(const co_node_t *node) {
  return node != NULL ? node->nmt : CO_NMT_INITIALISING;
}

/* ---- NMT ---------------------------------------------------------------- */

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
  uint8_t tmp[CO_OD_RAM_SIZE];
  co_od_reset(tmp, sizeof tmp, node->node_id);
  for (uint16_t pos = 0u; pos < CO_OD_COUNT; pos++) {
    const co_od_entry_t *e = co_od_entry(pos);
    if (e != NULL && e->index >= lo && e->index <= hi) {
      size_t n = (size_t)e->size + (e->type == CO_TYPE_VSTRING ? 1u : 0u);
      memcpy(&node->od[e->offset], &tmp[e->offset], n);
    }
  }
}

static void co_boot(co_node_t *node) {
  uint8_t zero = 0u;
  node->nmt = CO_NMT_INITIALISING;
  co_reset_comm_rt(node);
  co_send(node, (uint16_t)(CO_COB_HB + node->node_id), 1u, &zero);
  co_set_nmt(node, CO_NMT_PRE_OPERATIONAL);
}

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

static void co_nmt_frame(co_node_t *node, const fw_can_frame_t *f) {
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

/* ---- PDO configuration rules ------------------------------------------- */

static bool co_is_rpdo_comm(uint16_t i) { return i >= 0x1400u && i < 0x1400u + CO_OD_NR_RPDO; }
static bool co_is_tpdo_comm(uint16_t i) { return i >= 0x1800u && i < 0x1800u + CO_OD_NR_TPDO; }
static bool co_is_rpdo_map(uint16_t i) { return i >= 0x1600u && i < 0x1600u + CO_OD_NR_RPDO; }
static bool co_is_tpdo_map(uint16_t i) { return i >= 0x1A00u && i < 0x1A00u + CO_OD_NR_TPDO; }

/** Check one mapping entry 0xIIIISSLL for a receive (rx) or transmit PDO. */
static co_abort_t co_check_map_entry(uint32_t m, bool rx) {
  uint16_t pos;
  if (m == 0u) {
    return CO_ABORT_NONE;
  }
  uint16_t idx = (uint16_t)(m >> 16);
  uint8_t sub = (uint8_t)(m >> 8);
  uint8_t bits = (uint8_t)m;
  if (co_od_find(idx, sub, &pos) != CO_OD_OK) {
    return CO_ABORT_NO_OBJECT;
  }
  const co_od_entry_t *e = co_od_entry(pos);
  if (e == NULL || (e->flags & CO_FLAG_PDO) == 0u || e->type == CO_TYPE_VSTRING) {
    return CO_ABORT_NO_MAP;
  }
  if (rx && (e->access & CO_ACC_W) == 0u) {
    return CO_ABORT_NO_MAP;
  }
  if (!rx && (e->access & CO_ACC_R) == 0u) {
    return CO_ABORT_NO_MAP;
  }
  if ((uint32_t)bits != (uint32_t)e->size * 8u) {
    return CO_ABORT_MAP_LEN;
  }
  return CO_ABORT_NONE;
}

/** CiA 301 rules for 0x1014 (EMCY COB-ID) and 0x1016 (heartbeat consumers). */
static co_abort_t co_check_comm_write(const co_node_t *node, uint16_t index, uint8_t sub,
                                      uint32_t v) {
  if (index == 0x1014u) {
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
  if (index == 0x1016u && sub >= 1u && sub <= CO_HB_CONSUMERS) {
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

static co_abort_t co_check_pdo_write(const co_node_t *node, uint16_t index, uint8_t sub,
                                     const uint8_t *data, size_t len) {
  uint32_t v = co_le_get(data, len > 4u ? 4u : len);
  if (index == 0x1005u && (v & 0x60000000u) != 0u) {
    return CO_ABORT_VALUE_RANGE; /* SYNC producer / 29-bit id: not supported */
  }
  if (index == 0x1014u || index == 0x1016u) {
    return co_check_comm_write(node, index, sub, v);
  }
  if (co_is_rpdo_comm(index) || co_is_tpdo_comm(index)) {
    uint32_t cur = co_get(node, index, 1u);
    if (sub == 1u) {
      if ((v & CO_COB_EXT) != 0u || ((v & CO_COB_INVALID) == 0u && (v & 0x7FFu) == 0u)) {
        return CO_ABORT_VALUE_RANGE;
      }
      if ((cur & CO_COB_INVALID) == 0u && (v & CO_COB_INVALID) == 0u &&
          (v & 0x7FFu) != (cur & 0x7FFu)) {
        return CO_ABORT_VALUE_RANGE; /* change the COB-ID of a valid PDO */
      }
    } else if (sub == 2u) {
      if (v > 240u && v < 254u) {
        return CO_ABORT_VALUE_RANGE;
      }
    }
    return CO_ABORT_NONE;
  }
  bool rx = co_is_rpdo_map(index);
  if (!rx && !co_is_tpdo_map(index)) {
    return CO_ABORT_NONE;
  }
  uint16_t comm = (uint16_t)(rx ? (index - 0x1600u + 0x1400u) : (index - 0x1A00u + 0x1800u));
  bool valid = (co_get(node, comm, 1u) & CO_COB_INVALID) == 0u;
  if (valid) {
    return CO_ABORT_UNSUPPORTED;
  }
  if (sub == 0u) {
    uint32_t bits = 0u;
    for (uint8_t k = 1u; k <= (uint8_t)v; k++) {
      uint32_t m = co_get(node, index, k);
      co_abort_t a = co_check_map_entry(m, rx);
      if (a != CO_ABORT_NONE) {
        return a;
      }
      bits += m & 0xFFu;
    }
    if (bits > 64u) {
      return CO_ABORT_MAP_LEN;
    }
    return CO_ABORT_NONE;
  }
  if (co_get(node, index, 0u) != 0u) {
    return CO_ABORT_UNSUPPORTED;
  }
  return co_check_map_entry(v, rx);
}

/* ---- generic write / read --------------------------------------------- */

static co_abort_t co_write_pos(co_node_t *node, uint16_t pos, const uint8_t *data, size_t len,
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
    a = co_check_pdo_write(node, e->index, e->sub, data, len);
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

/* ---- SDO server ---------------------------------------------------------- */

static void co_sdo_send(co_node_t *node, const uint8_t d[8]) {
  co_send(node, (uint16_t)(CO_COB_SDO_TX + node->node_id), 8u, d);
}

static void co_sdo_abort(co_node_t *node, uint16_t index, uint8_t sub, co_abort_t code) {
  uint8_t d[8] = {0x80u, (uint8_t)index, (uint8_t)(index >> 8), sub, 0u, 0u, 0u, 0u};
  co_le_put(&d[4], 4u, (uint32_t)code);
  co_sdo_send(node, d);
  node->sdo.state = CO_SDO_IDLE;
  node->count.sdo_aborts++;
}

static void co_sdo_init_download(co_node_t *node, const uint8_t *d) {
  uint16_t index = (uint16_t)(d[1] | (d[2] << 8));
  uint8_t sub = d[3];
  bool expedited = (d[0] & 0x02u) != 0u;
  bool size_ind = (d[0] & 0x01u) != 0u;
  uint16_t pos;
  co_od_status_t st = co_od_find(index, sub, &pos);
  node->sdo.state = CO_SDO_IDLE;
  if (st != CO_OD_OK) {
    co_sdo_abort(node, index, sub, st == CO_OD_NO_SUB ? CO_ABORT_NO_SUB : CO_ABORT_NO_OBJECT);
    return;
  }
  const co_od_entry_t *e = co_od_entry(pos);
  if (e == NULL || (e->access & CO_ACC_W) == 0u) {
    co_sdo_abort(node, index, sub, CO_ABORT_READ_ONLY);
    return;
  }
  if (expedited) {
    size_t n = size_ind ? (size_t)(4u - ((d[0] >> 2) & 0x03u)) : 4u;
    if (!size_ind && e->type != CO_TYPE_VSTRING && e->size < 4u) {
      n = e->size; /* size not indicated: take the object's size */
    }
    co_abort_t a = co_write_pos(node, pos, &d[4], n, false);
    if (a != CO_ABORT_NONE) {
      co_sdo_abort(node, index, sub, a);
      return;
    }
    uint8_t r[8] = {0x60u, d[1], d[2], d[3], 0u, 0u, 0u, 0u};
    co_sdo_send(node, r);
    return;
  }
  uint32_t size = size_ind ? co_le_get(&d[4], 4u) : 0u;
  uint32_t cap = e->size;
  if (size_ind && size > cap) {
    co_sdo_abort(node, index, sub, CO_ABORT_TYPE_LEN);
    return;
  }
  node->sdo.state = CO_SDO_DOWNLOAD;
  node->sdo.index = index;
  node->sdo.sub = sub;
  node->sdo.pos = pos;
  node->sdo.toggle = 0u;
  node->sdo.size_known = size_ind ? 1u : 0u;
  node->sdo.size = (uint16_t)size;
  node->sdo.done = 0u;
  node->sdo.last_us = node->now_us;
  uint8_t r[8] = {0x60u, d[1], d[2], d[3], 0u, 0u, 0u, 0u};
  co_sdo_send(node, r);
}

/** A segment request must arrive in the expected transfer state with the
 *  expected toggle bit; otherwise the transfer is aborted. */
static bool co_sdo_segment_ok(co_node_t *node, const uint8_t *d, co_sdo_state_t want) {
  co_sdo_t *s = &node->sdo;
  if (s->state != want) {
    co_sdo_abort(node, s->index, s->sub, CO_ABORT_CMD);
    return false;
  }
  if ((uint8_t)((d[0] >> 4) & 1u) != s->toggle) {
    co_sdo_abort(node, s->index, s->sub, CO_ABORT_TOGGLE);
    return false;
  }
  return true;
}

static void co_sdo_download_segment(co_node_t *node, const uint8_t *d) {
  co_sdo_t *s = &node->sdo;
  if (!co_sdo_segment_ok(node, d, CO_SDO_DOWNLOAD)) {
    return;
  }
  const uint8_t t = s->toggle; /* checked equal to the request's toggle bit */
  size_t n = (size_t)(7u - ((d[0] >> 1) & 0x07u));
  bool last = (d[0] & 0x01u) != 0u;
  if ((size_t)s->done + n > sizeof s->buf) {
    co_sdo_abort(node, s->index, s->sub, CO_ABORT_TYPE_LEN);
    return;
  }
  memcpy(&s->buf[s->done], &d[1], n);
  s->done = (uint16_t)(s->done + n);
  s->last_us = node->now_us;
  uint8_t r[8] = {(uint8_t)(0x20u | ((uint32_t)t << 4)), 0u, 0u, 0u, 0u, 0u, 0u, 0u};
  if (!last) {
    s->toggle ^= 1u;
    co_sdo_send(node, r);
    return;
  }
  if (s->size_known && s->done != s->size) {
    co_sdo_abort(node, s->index, s->sub, CO_ABORT_TYPE_LEN);
    return;
  }
  co_abort_t a = co_write_pos(node, s->pos, s->buf, s->done, false);
  if (a != CO_ABORT_NONE) {
    co_sdo_abort(node, s->index, s->sub, a);
    return;
  }
  s->state = CO_SDO_IDLE;
  co_sdo_send(node, r);
}

static void co_sdo_init_upload(co_node_t *node, const uint8_t *d) {
  uint16_t index = (uint16_t)(d[1] | (d[2] << 8));
  uint8_t sub = d[3];
  co_sdo_t *s = &node->sdo;
  size_t len = sizeof s->buf;
  s->state = CO_SDO_IDLE;
  co_abort_t a = co_node_read(node, index, sub, s->buf, &len);
  if (a != CO_ABORT_NONE) {
    co_sdo_abort(node, index, sub, a);
    return;
  }
  uint16_t pos = 0u;
  (void)co_od_find(index, sub, &pos);
  uint8_t r[8] = {0u, d[1], d[2], d[3], 0u, 0u, 0u, 0u};
  if (len >= 1u && len <= 4u) {
    r[0] = (uint8_t)(0x43u | ((4u - len) << 2));
    memcpy(&r[4], s->buf, len);
    co_sdo_send(node, r);
    return;
  }
  r[0] = 0x41u;
  co_le_put(&r[4], 4u, (uint32_t)len);
  s->state = CO_SDO_UPLOAD;
  s->index = index;
  s->sub = sub;
  s->pos = pos;
  s->toggle = 0u;
  s->size = (uint16_t)len;
  s->done = 0u;
  s->last_us = node->now_us;
  co_sdo_send(node, r);
}

static void co_sdo_upload_segment(co_node_t *node, const uint8_t *d) {
  co_sdo_t *s = &node->sdo;
  if (!co_sdo_segment_ok(node, d, CO_SDO_UPLOAD)) {
    return;
  }
  const uint8_t t = s->toggle; /* checked equal to the request's toggle bit */
  size_t remaining = (size_t)(s->size - s->done);
  size_t n = remaining > 7u ? 7u : remaining;
  bool last = remaining <= 7u;
  uint8_t r[8] = {0u, 0u, 0u, 0u, 0u, 0u, 0u, 0u};
  r[0] = (uint8_t)(((size_t)t << 4) | ((7u - n) << 1) | (last ? 1u : 0u));
  memcpy(&r[1], &s->buf[s->done], n);
  s->done = (uint16_t)(s->done + n);
  s->toggle ^= 1u;
  s->last_us = node->now_us;
  if (last) {
    s->state = CO_SDO_IDLE;
  }
  co_sdo_send(node, r);
}

static void co_sdo_frame(co_node_t *node, const fw_can_frame_t *f) {
  if (f->dlc != 8u || f->rtr) {
    return; /* CiA 301: SDO frames are 8-byte data frames; ignore others */
  }
  const uint8_t *d = f->data;
  uint8_t ccs = (uint8_t)(d[0] >> 5);
  switch (ccs) {
  case 0u:
    co_sdo_download_segment(node, d);
    break;
  case 1u:
    co_sdo_init_download(node, d);
    break;
  case 2u:
    co_sdo_init_upload(node, d);
    break;
  case 3u:
    co_sdo_upload_segment(node, d);
    break;
  case 4u:
    node->sdo.state = CO_SDO_IDLE; /* abort from the client: no answer */
    break;
  default: {
    uint16_t index = (uint16_t)(d[1] | (d[2] << 8));
    co_sdo_abort(node, index, d[3], CO_ABORT_CMD);
    break;
  }
  }
}

/* ---- PDO ---------------------------------------------------------------- */

static void co_rpdo_apply(co_node_t *node, uint8_t n, const uint8_t *data, uint8_t dlc) {
  uint16_t map = (uint16_t)(0x1600u + n);
  co_rpdo_rt_t *rt = &node->rpdo[n];
  uint32_t count = co_get(node, map, 0u);
  uint32_t bit = 0u;
  if (count > 8u) {
    count = 8u;
  }
  for (uint8_t k = 1u; k <= (uint8_t)count; k++) {
    uint32_t m = co_get(node, map, k);
    uint32_t bits = m & 0xFFu;
    if (bits % 8u != 0u || bit + bits > (uint32_t)dlc * 8u) {
      node->count.rpdo_errors++;
      return;
    }
    bit += bits;
  }
  bit = 0u;
  for (uint8_t k = 1u; k <= (uint8_t)count; k++) {
    uint32_t m = co_get(node, map, k);
    uint32_t nbytes = (m & 0xFFu) / 8u;
    uint16_t pos;
    if (co_od_find((uint16_t)(m >> 16), (uint8_t)(m >> 8), &pos) == CO_OD_OK &&
        co_write_pos(node, pos, &data[bit / 8u], nbytes, true) != CO_ABORT_NONE) {
      node->count.rpdo_errors++;
    }
    bit += nbytes * 8u;
  }
  /* deadline (0x1400+n:5): fresh data was applied */
  rt->watched = 1u;
  rt->timed_out = 0u;
  rt->applied_us = node->now_us;
  co_event(node, CO_EV_RPDO, n);
}

/** Pack TPDO n into data; returns the length in bytes. */
static uint8_t co_tpdo_pack(const co_node_t *node, uint8_t n, uint8_t data[8]) {
  uint16_t map = (uint16_t)(0x1A00u + n);
  uint32_t count = co_get(node, map, 0u);
  uint32_t byte = 0u;
  if (count > 8u) {
    count = 8u;
  }
  memset(data, 0, 8u);
  for (uint8_t k = 1u; k <= (uint8_t)count; k++) {
    uint32_t m = co_get(node, map, k);
    uint32_t nbytes = (m & 0xFFu) / 8u;
    uint16_t pos;
    if (byte + nbytes > 8u) {
      break;
    }
    if (co_od_find((uint16_t)(m >> 16), (uint8_t)(m >> 8), &pos) == CO_OD_OK) {
      uint8_t tmp[8];
      size_t got = co_od_load(node->od, sizeof node->od, pos, tmp, sizeof tmp);
      if (got == nbytes) {
        memcpy(&data[byte], tmp, nbytes);
      }
    }
    byte += nbytes;
  }
  return (uint8_t)byte;
}

static void co_tpdo_send(co_node_t *node, uint8_t n, const uint8_t *data, uint8_t len) {
  uint32_t cob = co_get(node, (uint16_t)(0x1800u + n), 1u);
  co_tpdo_rt_t *rt = &node->tpdo[n];
  co_send(node, (uint16_t)(cob & 0x7FFu), len, data);
  memcpy(rt->last, data, len);
  rt->last_len = len;
  rt->sent_once = 1u;
  rt->last_tx_us = node->now_us;
}

static void co_sync(co_node_t *node) {
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
    uint32_t cob = co_get(node, (uint16_t)(0x1800u + n), 1u);
    uint32_t type = co_get(node, (uint16_t)(0x1800u + n), 2u);
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

static bool co_rpdo_frame(co_node_t *node, const fw_can_frame_t *f) {
  for (uint8_t n = 0u; n < CO_OD_NR_RPDO; n++) {
    uint32_t cob = co_get(node, (uint16_t)(0x1400u + n), 1u);
    if ((cob & CO_COB_INVALID) != 0u || (cob & 0x7FFu) != f->id) {
      continue;
    }
    if (f->rtr) {
      return true;
    }
    uint32_t type = co_get(node, (uint16_t)(0x1400u + n), 2u);
    if (type <= 240u) {
      node->rpdo[n].pending = 1u;
      node->rpdo[n].dlc = f->dlc;
      memcpy(node->rpdo[n].data, f->data, sizeof f->data);
    } else {
      co_rpdo_apply(node, n, f->data, f->dlc);
    }
    return true;
  }
  return false;
}

/* ---- heartbeat ------------------------------------------------------------ */

static void co_hb_frame(co_node_t *node, const fw_can_frame_t *f) {
  uint8_t nid = (uint8_t)(f->id - CO_COB_HB);
  if (f->dlc < 1u || f->rtr) {
    return;
  }
  for (uint8_t k = 0u; k < CO_HB_CONSUMERS; k++) {
    uint32_t cfg = co_get(node, 0x1016u, (uint8_t)(k + 1u));
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
static void co_hb_check(co_node_t *node, uint32_t now_us) {
  for (uint8_t k = 0u; k < CO_HB_CONSUMERS; k++) {
    uint32_t cfg = co_get(node, 0x1016u, (uint8_t)(k + 1u));
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

/** RPDO deadline monitoring (CiA 301 RPDO event timer, 0x1400+n:5, ms):
 *  data not applied for that long (no frame, or no SYNC for a synchronous
 *  RPDO) is reported once. Off when 0, for an invalid PDO and outside
 *  OPERATIONAL; armed by the first application. */
static void co_rpdo_check(co_node_t *node, uint32_t now_us) {
  if (node->nmt != CO_NMT_OPERATIONAL) {
    return;
  }
  for (uint8_t n = 0u; n < CO_OD_NR_RPDO; n++) {
    co_rpdo_rt_t *rt = &node->rpdo[n];
    uint16_t comm = (uint16_t)(0x1400u + n);
    uint32_t ms = co_get(node, comm, 5u);
    if (ms == 0u || !rt->watched || rt->timed_out ||
        (co_get(node, comm, 1u) & CO_COB_INVALID) != 0u) {
      continue;
    }
    if (co_elapsed(now_us, rt->applied_us, ms * 1000u)) {
      rt->timed_out = 1u;
      node->count.rpdo_timeouts++;
      co_event(node, CO_EV_RPDO_TIMEOUT, n);
    }
  }
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
    uint32_t sync_cob = co_get(node, 0x1005u, 0u);
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
  /* SDO timeout */
  if (node->sdo.state != CO_SDO_IDLE && co_elapsed(now_us, node->sdo.last_us, CO_SDO_TIMEOUT_US)) {
    co_sdo_abort(node, node->sdo.index, node->sdo.sub, CO_ABORT_TIMEOUT);
  }
  /* heartbeat producer */
  uint32_t hb_ms = co_get(node, 0x1017u, 0u);
  if (hb_ms > 0u && co_elapsed(now_us, node->hb_last_us, hb_ms * 1000u)) {
    uint8_t st = (uint8_t)node->nmt;
    node->hb_last_us = now_us;
    co_send(node, (uint16_t)(CO_COB_HB + node->node_id), 1u, &st);
  }
  co_hb_check(node, now_us);
  co_rpdo_check(node, now_us);
  /* event-driven TPDOs */
  if (node->nmt != CO_NMT_OPERATIONAL) {
    return;
  }
  for (uint8_t n = 0u; n < CO_OD_NR_TPDO; n++) {
    uint16_t comm = (uint16_t)(0x1800u + n);
    uint32_t cob = co_get(node, comm, 1u);
    uint32_t type = co_get(node, comm, 2u);
    co_tpdo_rt_t *rt = &node->tpdo[n];
    uint8_t data[8];
    if ((cob & CO_COB_INVALID) != 0u || type < 254u) {
      continue;
    }
    uint32_t inhibit_us = co_get(node, comm, 3u) * 100u;
    uint32_t event_us = co_get(node, comm, 5u) * 1000u;
    if (rt->sent_once && !co_elapsed(now_us, rt->last_tx_us, inhibit_us)) {
      continue;
    }
    uint8_t len = co_tpdo_pack(node, n, data);
    bool changed = !rt->sent_once || len != rt->last_len || memcmp(data, rt->last, len) != 0;
    bool timer = event_us > 0u && co_elapsed(now_us, rt->last_tx_us, event_us);
    if (changed || timer) {
      co_tpdo_send(node, n, data, len);
    }
  }
}

bool co_node_tx_pop(co_node_t *node, fw_can_frame_t *frame) {
  if (node == NULL || frame == NULL) {
    return false;
  }
  return co_queue_pop(&node->txq, frame);
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
