/**
 * @file fw_app.h
 * @brief Drive application: the control core (fw_ctrl) + the CANopen node
 *        (co_node, CiA 402 objects) + the serial telemetry/trace link.
 *
 * One fw_app_t per drive, caller-owned, no malloc, no globals.
 *
 *     fw_app_t app;
 *     fw_app_init(&app, &cfg, 5);
 *     CAN ISR:      fw_app_can_rx(&app, &frame);          // queue only
 *     PWM/ADC ISR:  fw_app_step(&app, &in, &out);          // one control period
 *                   while (fw_app_can_tx_pop(&app, &f)) can_send(&f);
 *                   n = fw_app_uart_read(&app, buf, sizeof buf); uart_write(buf, n);
 *
 * fw_app_step and fw_app_snapshot have the signatures of the simulated
 * drive's batch loop (step(ctx, in, out), snapshot(ctx, snap)), so the sim
 * can run the whole application in place of the bare core.
 *
 * Per step: queued CAN frames are processed (NMT, SDO, SYNC, RPDO,
 * heartbeats); a written controlword is applied with fw_controlword();
 * modes (0x6060: 9 CSV -> FW_MODE_SPEED, 10 CST -> FW_MODE_FORCE), target
 * velocity (0x60FF, um/s) and target torque (0x6071, per mille of i_max_A)
 * are applied; fw_step() runs; statusword and actual values are written
 * back to the OD; a new fault sends an EMCY (and its reset an EMCY 0x0000);
 * telemetry and trace frames are queued on the UART; TPDOs and heartbeat
 * are produced. Time is step_count / f_pwm_Hz. A lost supervisor heartbeat
 * (0x1016) raises FW_FAULT_HEARTBEAT_LOST through fw_raise_fault(); a missed
 * RPDO deadline (0x1400+n:5) while OPERATION ENABLED raises 0x8250.
 *
 * NMT and the power stage: NMT stop and reset communication switch the
 * power stage off in the same control period (CiA 402 "disable voltage":
 * SWITCH ON DISABLED); reset node restarts the core as after fw_app_init
 * (same configuration, no fault, SWITCH ON DISABLED).
 */
#ifndef PMLSM_FW_APP_H
#define PMLSM_FW_APP_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "pmlsm/co_node.h"
#include "pmlsm/fw_ctrl.h"
#include "pmlsm/fw_port.h"
#include "pmlsm/fw_serial.h"

#ifdef __cplusplus
extern "C" {
#endif

#ifndef FW_APP_TRACE_FLOATS
#define FW_APP_TRACE_FLOATS 4096u /**< trace storage: samples x signals */
#endif
#ifndef FW_APP_UART_LEN
#define FW_APP_UART_LEN 4096u /**< UART TX ring (bytes, power of two) */
#endif

/** Application counters (diagnostics, tests). */
typedef struct {
  uint32_t telemetry_sent;
  uint32_t uart_dropped; /**< frames that did not fit the UART ring */
  uint32_t emcy;
  uint32_t hb_lost;
  uint32_t rpdo_timeouts; /**< RPDO event-timer deadlines missed (0x1400+n:5) */
} fw_app_counters_t;

/** The drive application. Treat the members as private. */
typedef struct {
  fw_ctrl_t ctrl;
  fw_config_t boot_cfg; /**< configuration of fw_app_init, restored by NMT reset node */
  co_node_t node;
  fw_serial_link_t link;
  fw_trace_t trace;
  float trace_buf[FW_APP_TRACE_FLOATS];
  uint8_t uart[FW_APP_UART_LEN];
  uint32_t uart_head, uart_tail;
  uint32_t step;       /**< control periods since init */
  uint32_t f_pwm_Hz;   /**< integer PWM rate for the time base */
  uint32_t now_us;     /**< time base: floor(steps * 1e6 / f_pwm_Hz), modulo 2^32 */
  uint32_t us_rem;     /**< remainder of that division (< f_pwm_Hz) */
  int32_t mode_applied; /**< fw_mode_t last accepted by fw_set_mode, -1 none */
  uint8_t cw_pending;
  uint16_t cw;
  uint16_t last_fault;
  uint8_t init_done;
  fw_app_counters_t count;
} fw_app_t;

/**
 * Initialise the core with cfg (see fw_init) and the CANopen node with
 * node_id (1..127; the boot-up message is queued). Returns the fw_init
 * status, FW_ERR_NULL or FW_ERR_RANGE (bad node id).
 */
fw_status_t fw_app_init(fw_app_t *app, const fw_config_t *cfg, uint8_t node_id);

/** CAN receive path (ISR side): queue the frame. False when the queue is full. */
bool fw_app_can_rx(fw_app_t *app, const fw_can_frame_t *frame);

/** One control period (app is a fw_app_t *). */
void fw_app_step(void *app, const fw_inputs_t *in, fw_outputs_t *out);

/** Next CAN frame to send; false when none. */
bool fw_app_can_tx_pop(fw_app_t *app, fw_can_frame_t *frame);

/** Pop up to cap bytes of serial output (COBS frames). Returns the count. */
size_t fw_app_uart_read(fw_app_t *app, uint8_t *buf, size_t cap);

/** Core snapshot (app is a const fw_app_t *). */
void fw_app_snapshot(const void *app, fw_snapshot_t *snap);

/** sizeof(fw_app_t), for bindings that allocate it. */
size_t fw_app_sizeof(void);

/** Access for tests and bindings. */
fw_ctrl_t *fw_app_ctrl(fw_app_t *app);
co_node_t *fw_app_node(fw_app_t *app);
const fw_app_counters_t *fw_app_counters(const fw_app_t *app);

/** Error register (0x1001) bits for a fault code. */
uint8_t fw_app_error_register(uint16_t fault_code);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_APP_H */
