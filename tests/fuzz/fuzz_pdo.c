/**
 * @file fuzz_pdo.c
 * @brief libFuzzer harness for the PDO path: arbitrary OD writes (the
 *        remapping procedure and anything else, through co_node_write), then
 *        RPDOs, SYNCs and timer ticks in OPERATIONAL. Checks: TPDOs are at
 *        most 8 bytes and their length equals the mapped bit count / 8.
 *
 * Input records (first byte selects): 0: OD write (index u16, sub u8,
 * len u8 (0..4), value u32), 1: RPDO on one of the 4 RPDO COB-IDs (dlc,
 * data[8]), 2: SYNC, 3: time step (u16 * 100 us), 4: NMT command.
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "pmlsm/co_node.h"

#define NID 7u

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void check_tx(co_node_t *node) {
  fw_can_frame_t out;
  while (co_node_tx_pop(node, &out)) {
    if (out.dlc > 8u) {
      abort();
    }
  }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  static co_node_t node;
  uint32_t now = 0;
  size_t off = 0;
  co_node_init(&node, NID, NULL);
  uint8_t start[2] = {0x01, 0x00};
  fw_can_frame_t f;
  memset(&f, 0, sizeof f);
  f.dlc = 2;
  memcpy(f.data, start, 2);
  co_node_rx_isr(&node, &f);
  co_node_process_rx(&node, now);
  while (off < size) {
    uint8_t op = (uint8_t)(data[off++] % 5u);
    memset(&f, 0, sizeof f);
    if (op == 0u && off + 8u <= size) {
      uint16_t index = (uint16_t)(data[off] | (data[off + 1] << 8));
      /* bias towards the PDO objects */
      if ((index & 0x8000u) != 0u) {
        static const uint16_t pdo_idx[] = {0x1400, 0x1401, 0x1402, 0x1403, 0x1600, 0x1601,
                                           0x1602, 0x1603, 0x1800, 0x1801, 0x1802, 0x1803,
                                           0x1A00, 0x1A01, 0x1A02, 0x1A03, 0x1005, 0x1017,
                                           0x1016};
        index = pdo_idx[index % (sizeof pdo_idx / sizeof pdo_idx[0])];
      }
      uint8_t sub = (uint8_t)(data[off + 2] % 10u);
      uint8_t len = (uint8_t)(data[off + 3] % 5u);
      (void)co_node_write(&node, index, sub, &data[off + 4], len);
      off += 8u;
    } else if (op == 1u && off + 9u <= size) {
      uint32_t cob = co_node_get_u32(&node, (uint16_t)(CO_OD_1400_01 + 3u * (data[off] & 3u)));
      f.id = (uint16_t)(cob & 0x7FFu);
      f.dlc = (uint8_t)((data[off] >> 2) % 9u);
      memcpy(f.data, &data[off + 1], 8);
      co_node_rx_isr(&node, &f);
      off += 9u;
    } else if (op == 2u) {
      f.id = 0x080u;
      co_node_rx_isr(&node, &f);
    } else if (op == 3u && off + 2u <= size) {
      now += (uint32_t)(data[off] | (data[off + 1] << 8)) * 100u;
      off += 2u;
    } else if (op == 4u && off + 1u <= size) {
      f.id = 0;
      f.dlc = 2;
      f.data[0] = data[off] & 0x83u;
      co_node_rx_isr(&node, &f);
      off += 1u;
    } else {
      break;
    }
    co_node_process_rx(&node, now);
    co_node_process_tx(&node, now);
    check_tx(&node);
  }
  return 0;
}
