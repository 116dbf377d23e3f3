/**
 * @file fuzz_sdo.c
 * @brief libFuzzer harness: arbitrary CAN frame sequences into the CANopen
 *        node (SDO server mostly, plus NMT/SYNC/heartbeat/PDO ids) with
 *        advancing time. Checks: every transmitted frame is well formed and
 *        every SDO response is 8 bytes with a valid server command.
 *
 * Input: repeated records of 11 bytes: sel, dlc, data[8], dt.
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "pmlsm/co_node.h"

#define NID 5u

static uint16_t pick_id(uint8_t sel) {
  switch (sel & 0x0Fu) {
  case 0:
    return 0x000u; /* NMT */
  case 1:
    return 0x080u; /* SYNC */
  case 2:
    return (uint16_t)(0x200u + NID);
  case 3:
    return (uint16_t)(0x700u + (sel >> 4)); /* heartbeats */
  default:
    return (uint16_t)(0x600u + NID); /* SDO */
  }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  static co_node_t node; /* harness state only */
  uint32_t now = 0;
  co_node_init(&node, NID, NULL);
  for (size_t off = 0; off + 11u <= size; off += 11u) {
    fw_can_frame_t f;
    memset(&f, 0, sizeof f);
    f.id = pick_id(data[off]);
    f.rtr = (uint8_t)((data[off] >> 7) & (data[off + 1] >> 7));
    f.dlc = (uint8_t)(data[off + 1] & 0x0Fu); /* 0..15: > 8 must be clamped */
    memcpy(f.data, &data[off + 2], 8);
    co_node_rx_isr(&node, &f);
    now += (uint32_t)data[off + 10] * 977u;
    co_node_process_rx(&node, now);
    co_node_process_tx(&node, now);
    fw_can_frame_t out;
    while (co_node_tx_pop(&node, &out)) {
      if (out.dlc > 8u || out.id > 0x7FFu) {
        abort();
      }
      if (out.id == 0x580u + NID) {
        uint8_t scs = (uint8_t)(out.data[0] >> 5);
        if (out.dlc != 8u || !(scs == 0u || scs == 1u || scs == 2u || scs == 3u || scs == 4u)) {
          abort();
        }
      }
    }
  }
  /* OD invariant: reading every entry works and fits */
  for (uint16_t pos = 0; pos < co_od_count(); pos++) {
    const co_od_entry_t *e = co_od_entry(pos);
    uint8_t buf[CO_SDO_BUF_LEN];
    size_t len = sizeof buf;
    if (co_node_read(&node, e->index, e->sub, buf, &len) == CO_ABORT_NONE && len > e->size) {
      abort();
    }
  }
  return 0;
}
