/**
 * @file co_sdo.c
 * @brief CANopen slave, SDO server: expedited and segmented download/upload, abort, timeout.
 */
#include "co_internal.h"

#include <string.h>

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

void co_sdo_frame(co_node_t *node, const fw_can_frame_t *f) {
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

void co_sdo_check_timeout(co_node_t *node, uint32_t now_us) {
  if (node->sdo.state != CO_SDO_IDLE && co_elapsed(now_us, node->sdo.last_us, CO_SDO_TIMEOUT_US)) {
    co_sdo_abort(node, node->sdo.index, node->sdo.sub, CO_ABORT_TIMEOUT);
  }
}
