/**
 * @file fuzz_app.c
 * @brief libFuzzer harness for the PDO/SDO path through the whole drive
 *        application (fw_app + the control core): arbitrary frames on the
 *        SDO, RPDO1-3, SYNC, NMT and heartbeat COB-IDs, interleaved with
 *        control periods fed with fuzzed (finite or not) phase currents.
 *        Checks: duties in [0, 1] and finite, CAN frames well formed.
 *
 * Input records of 12 bytes: sel, dlc, data[8], steps, current byte.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "pmlsm/fw_app.h"

#define NID 5u

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static uint16_t pick_id(uint8_t sel) {
  static const uint16_t ids[] = {0x000u, 0x080u, 0x200u + NID, 0x300u + NID, 0x400u + NID,
                                 0x600u + NID, 0x600u + NID, 0x600u + NID, 0x701u};
  return ids[sel % (sizeof ids / sizeof ids[0])];
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  static fw_app_t app; /* harness state only */
  fw_config_t cfg;
  fw_inputs_t in;
  fw_outputs_t out;
  fw_config_default(&cfg);
  if (fw_app_init(&app, &cfg, NID) != FW_OK) {
    abort();
  }
  memset(&in, 0, sizeof in);
  in.u_dc_V = 300.0f;
  for (size_t off = 0; off + 12u <= size; off += 12u) {
    fw_can_frame_t f;
    memset(&f, 0, sizeof f);
    f.id = pick_id(data[off]);
    f.dlc = (uint8_t)(data[off + 1] % 9u);
    memcpy(f.data, &data[off + 2], 8);
    (void)fw_app_can_rx(&app, &f);
    uint8_t c = data[off + 11];
    float i = (float)(int8_t)c * 0.05f;
    if (c == 0x7Fu) {
      i = NAN;
    }
    in.i_abc_A[0] = i;
    in.i_abc_A[1] = -0.5f * i;
    in.i_abc_A[2] = -0.5f * i;
    uint32_t steps = 1u + data[off + 10] % 48u;
    for (uint32_t k = 0; k < steps; k++) {
      fw_app_step(&app, &in, &out);
      for (int p = 0; p < 3; p++) {
        if (!(out.duty_abc[p] >= 0.0f && out.duty_abc[p] <= 1.0f)) {
          abort();
        }
      }
    }
    fw_can_frame_t o;
    while (fw_app_can_tx_pop(&app, &o)) {
      if (o.dlc > 8u || o.id > 0x7FFu) {
        abort();
      }
    }
    uint8_t sink[256];
    (void)fw_app_uart_read(&app, sink, sizeof sink);
  }
  return 0;
}
