/**
 * @file co_pdo.c
 * @brief CANopen slave, PDO: mapping and communication-parameter rules, RPDO
 *        (asynchronous, synchronous, deadline), TPDO (packing, event, inhibit, timer).
 */
#include "co_internal.h"

#include <string.h>

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

co_abort_t co_pdo_check_config(const co_node_t *node, uint16_t index, uint8_t sub, uint32_t v) {
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

void co_rpdo_apply(co_node_t *node, uint8_t n, const uint8_t *data, uint8_t dlc) {
  co_rpdo_rt_t *rt = &node->rpdo[n];
  uint32_t count = CO_RPDO_MAP_COUNT(node, n);
  uint32_t bit = 0u;
  if (count > 8u) {
    count = 8u;
  }
  for (uint8_t k = 1u; k <= (uint8_t)count; k++) {
    uint32_t m = CO_RPDO_MAP(node, n, k);
    uint32_t bits = m & 0xFFu;
    if (bits % 8u != 0u || bit + bits > (uint32_t)dlc * 8u) {
      node->count.rpdo_errors++;
      return;
    }
    bit += bits;
  }
  bit = 0u;
  for (uint8_t k = 1u; k <= (uint8_t)count; k++) {
    uint32_t m = CO_RPDO_MAP(node, n, k);
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

uint8_t co_tpdo_pack(const co_node_t *node, uint8_t n, uint8_t data[8]) {
  uint32_t count = CO_TPDO_MAP_COUNT(node, n);
  uint32_t byte = 0u;
  if (count > 8u) {
    count = 8u;
  }
  memset(data, 0, 8u);
  for (uint8_t k = 1u; k <= (uint8_t)count; k++) {
    uint32_t m = CO_TPDO_MAP(node, n, k);
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

void co_tpdo_send(co_node_t *node, uint8_t n, const uint8_t *data, uint8_t len) {
  uint32_t cob = CO_TPDO_COMM(node, n, 01);
  co_tpdo_rt_t *rt = &node->tpdo[n];
  co_send(node, (uint16_t)(cob & 0x7FFu), len, data);
  memcpy(rt->last, data, len);
  rt->last_len = len;
  rt->sent_once = 1u;
  rt->last_tx_us = node->now_us;
}

bool co_rpdo_frame(co_node_t *node, const fw_can_frame_t *f) {
  for (uint8_t n = 0u; n < CO_OD_NR_RPDO; n++) {
    uint32_t cob = CO_RPDO_COMM(node, n, 01);
    if ((cob & CO_COB_INVALID) != 0u || (cob & 0x7FFu) != f->id) {
      continue;
    }
    if (f->rtr) {
      return true;
    }
    uint32_t type = CO_RPDO_COMM(node, n, 02);
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

/** RPDO deadline monitoring (CiA 301 RPDO event timer, 0x1400+n:5, ms):
 *  data not applied for that long (no frame, or no SYNC for a synchronous
 *  RPDO) is reported once. Off when 0, for an invalid PDO and outside
 *  OPERATIONAL; armed by the first application. */
void co_rpdo_check(co_node_t *node, uint32_t now_us) {
  if (node->nmt != CO_NMT_OPERATIONAL) {
    return;
  }
  for (uint8_t n = 0u; n < CO_OD_NR_RPDO; n++) {
    co_rpdo_rt_t *rt = &node->rpdo[n];
    uint32_t ms = CO_RPDO_COMM(node, n, 05);
    if (ms == 0u || !rt->watched || rt->timed_out ||
        (CO_RPDO_COMM(node, n, 01) & CO_COB_INVALID) != 0u) {
      continue;
    }
    if (co_elapsed(now_us, rt->applied_us, ms * 1000u)) {
      rt->timed_out = 1u;
      node->count.rpdo_timeouts++;
      co_event(node, CO_EV_RPDO_TIMEOUT, n);
    }
  }
}

void co_tpdo_process(co_node_t *node, uint32_t now_us) {
  /* event-driven TPDOs */
  if (node->nmt != CO_NMT_OPERATIONAL) {
    return;
  }
  for (uint8_t n = 0u; n < CO_OD_NR_TPDO; n++) {
    uint32_t cob = CO_TPDO_COMM(node, n, 01);
    uint32_t type = CO_TPDO_COMM(node, n, 02);
    co_tpdo_rt_t *rt = &node->tpdo[n];
    uint8_t data[8];
    if ((cob & CO_COB_INVALID) != 0u || type < 254u) {
      continue;
    }
    uint32_t inhibit_us = CO_TPDO_COMM(node, n, 03) * 100u;
    uint32_t event_us = CO_TPDO_COMM(node, n, 05) * 1000u;
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
