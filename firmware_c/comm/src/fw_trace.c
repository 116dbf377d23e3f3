/**
 * @file fw_trace.c
 * @brief The drive application's trace (0x2070, fw_app.h): the command object's
 *        handler (od.yaml hook: stop, arm from 0x2070's settings, trigger at
 *        the next period the trace samples, upload) and, per published period,
 *        the sample and one upload frame. The recorder itself (fw_trace_t) is
 *        the serial link's (fw_serial.h).
 */
#include "fw_app_hooks.h"
#include "fw_app_internal.h"
#include "pmlsm/fw_app.h"

co_abort_t fw_app_hook_trace_command(fw_app_t *app, uint32_t value) {
  co_node_t *n = &app->node;
  switch ((uint8_t)value) {
  case 0u:
    fw_trace_stop(&app->trace);
    break;
  case 1u: {
    uint8_t ids[FW_SERIAL_MAX_SIGNALS];
    uint8_t cnt = (uint8_t)co_node_get_u32(n, CO_OD_2070_07);
    if (cnt > FW_SERIAL_MAX_SIGNALS) {
      cnt = FW_SERIAL_MAX_SIGNALS;
    }
    for (uint8_t k = 0u; k < cnt; k++) {
      ids[k] = (uint8_t)co_node_get_u32(n, (uint16_t)(CO_OD_2070_08 + k));
    }
    float dt = app->f_pwm_Hz > 0u ? 1.0f / (float)app->f_pwm_Hz : 0.0f;
    (void)fw_trace_arm(&app->trace, ids, cnt, co_node_get_u32(n, CO_OD_2070_06),
                       (uint8_t)co_node_get_u32(n, CO_OD_2070_03),
                       co_node_get_f32(n, CO_OD_2070_04),
                       (fw_trace_edge_t)co_node_get_u32(n, CO_OD_2070_05), dt);
    break;
  }
  case 2u: {
    /* at the next period the trace will sample: the oldest one the background
       has not processed yet, or the next the interrupt will publish */
    uint32_t tail = atomic_load_explicit(&app->ring_tail, memory_order_relaxed);
    uint32_t head = atomic_load_explicit(&app->ring_head, memory_order_acquire);
    fw_trace_trigger(&app->trace,
                     tail != head ? app->ring[tail % FW_APP_SNAP_RING].step : app->step);
    break;
  }
  case 3u:
    (void)fw_trace_upload_start(&app->trace);
    break;
  default:
    break;
  }
  return CO_ABORT_NONE;
}

void fw_app_trace_period(fw_app_t *app, const fw_snapshot_t *s) {
  fw_trace_sample(&app->trace, s, s->fault_code != 0u);
  if (app->trace.state == FW_TRACE_UPLOADING) {
    /* one upload frame per control period, when the UART has room */
    uint32_t used = app->uart_head - app->uart_tail;
    if (FW_APP_UART_LEN - used >= FW_SERIAL_MAX_ENCODED) {
      uint8_t type = 0u;
      uint8_t payload[FW_SERIAL_MAX_PAYLOAD];
      size_t len = 0u;
      if (fw_trace_upload_next(&app->trace, &type, payload, sizeof payload, &len)) {
        fw_app_send_frame(app, type, payload, len);
      }
    }
  }
}
