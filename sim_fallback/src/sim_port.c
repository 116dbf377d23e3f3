/**
 * @file sim_port.c
 * @brief The simulated drive's port (fw_port.h) and the drive it runs.
 *
 * The simulator is one more world behind the one port contract: the drive
 * application (fw_app: core + CANopen + serial) runs through the board glue
 * (fw_board.h) exactly as on the MCU:
 *
 *   - control interrupt: the batch loop (sim_loop.c) calls step_adc with the
 *     ADC counts it sampled from the plant; fw_port_adc_read hands them to
 *     fw_board_control_isr, fw_port_pwm_write latches the duties the loop
 *     applies to the plant in the next period;
 *   - supervision interrupt: pended by the control interrupt
 *     (fw_port_supervision_pend) and run right after it, tail-chained as on a
 *     Cortex-M (fw_board_supervision_isr): before the duties reach the plant,
 *     so a hard fault it finds switches them off in the same period;
 *   - background loop: every `background_every` control periods, interleaved
 *     with them (sim_controller_t.background), fw_board_background; its CAN
 *     frames and UART bytes go into queues that the bench reads
 *     (sim_app_can_pop, sim_app_uart_read) between batches;
 *   - CAN receive interrupt: sim_app_can_rx, called by the bench between
 *     batches;
 *   - critical sections: one thread runs both, so entering is counting (the
 *     depth is checked: an unbalanced exit is a bug and counted);
 *   - reference sensor: the plant's scale (sim_ref_sample), read by the batch loop
 *     with the ADC samples and handed over before the control interrupt
 *     (sim_controller_t.sample_ref);
 *   - non-volatile memory: one file per simulated drive, replaced atomically
 *     (write "<path>.tmp", fsync, rename), so a crash while saving leaves the
 *     old block or the new one, never a mix; no path: no storage
 *     (FW_NVM_UNSUPPORTED, as the blank port).
 */
#define _POSIX_C_SOURCE 200809L

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "pmlsm/fw_board.h"
#include "pmlsm/fw_port.h"
#include "pmlsm_sim.h"

#define SIM_NVM_PATH_MAX 4096u
#define SIM_PORT_CAN_LEN 256u   /* frames (power of two) */
#define SIM_PORT_UART_LEN 16384u /* bytes (power of two) */

struct fw_port {
  fw_adc_inputs_t adc; /**< this period's sample, set by the batch loop */
  uint8_t adc_fresh;
  float duty[3];
  uint8_t pwm_on;
  fw_can_frame_t can[SIM_PORT_CAN_LEN];
  uint32_t can_head, can_tail;
  uint8_t uart[SIM_PORT_UART_LEN];
  uint32_t uart_head, uart_tail;
  uint32_t crit_depth;
  uint32_t crit_unbalanced;
  uint8_t sup_pending; /**< the supervision interrupt is pended */
  uint8_t ref_status;  /**< the reference scale's reading of this period (sim_loop) */
  int32_t ref_count;
  int has_nvm;
  char path[SIM_NVM_PATH_MAX];
  char tmp[SIM_NVM_PATH_MAX + 8u];
};

/** The simulated drive: application, board glue and port in one block. */
struct sim_app {
  fw_app_t app;
  fw_board_t board;
  struct fw_port port;
};

/* ---- fw_port.h ------------------------------------------------------------- */

void fw_port_pwm_write(fw_port_t *port, const float duty_abc[3], bool enable) {
  for (int j = 0; j < 3; ++j) port->duty[j] = duty_abc[j];
  port->pwm_on = enable ? 1u : 0u;
}

void fw_port_supervision_pend(fw_port_t *port) { port->sup_pending = 1u; }

void fw_port_info(fw_port_t *port, fw_port_info_t *info) {
  (void)port;
  info->kind = (uint8_t)FW_DRIVE_SIMULATED;
  info->board = "host_sim";
}

uint8_t fw_port_ref_read(fw_port_t *port, int32_t *count) {
  if (port->ref_status != (uint8_t)FW_REF_NONE) {
    *count = port->ref_count;
  }
  return port->ref_status;
}

uint16_t fw_port_hw_fault(fw_port_t *port) {
  (void)port;
  return 0u; /* the simulated inverter has no break input */
}

bool fw_port_adc_read(fw_port_t *port, fw_adc_inputs_t *adc) {
  *adc = port->adc;
  bool fresh = port->adc_fresh != 0u;
  port->adc_fresh = 0u;
  return fresh;
}

bool fw_port_can_send(fw_port_t *port, const fw_can_frame_t *frame) {
  if (port->can_head - port->can_tail >= SIM_PORT_CAN_LEN) {
    return false; /* the bench has not collected: the board glue holds the frame */
  }
  port->can[port->can_head % SIM_PORT_CAN_LEN] = *frame;
  port->can_head++;
  return true;
}

size_t fw_port_uart_write(fw_port_t *port, const uint8_t *data, size_t len) {
  size_t room = SIM_PORT_UART_LEN - (port->uart_head - port->uart_tail);
  size_t n = len < room ? len : room;
  for (size_t i = 0u; i < n; i++) {
    port->uart[(port->uart_head + i) % SIM_PORT_UART_LEN] = data[i];
  }
  port->uart_head += (uint32_t)n;
  return n;
}

uint32_t fw_port_critical_enter(fw_port_t *port) { return port->crit_depth++; }

void fw_port_critical_exit(fw_port_t *port, uint32_t key) {
  if (port->crit_depth == 0u || key != port->crit_depth - 1u) {
    port->crit_unbalanced++;
  }
  port->crit_depth = key;
}

fw_nvm_status_t fw_port_nvm_read(fw_port_t *port, uint8_t *buf, size_t cap, size_t *len) {
  if (port == NULL || buf == NULL || len == NULL) {
    return FW_NVM_ERROR;
  }
  if (!port->has_nvm) {
    *len = 0u;
    return FW_NVM_UNSUPPORTED;
  }
  *len = 0u;
  FILE *f = fopen(port->path, "rb");
  if (f == NULL) {
    return FW_NVM_EMPTY;
  }
  size_t n = fread(buf, 1u, cap, f);
  int more = fgetc(f); /* a file larger than the block cannot be ours */
  int err = ferror(f);
  (void)fclose(f);
  if (err != 0 || more != EOF) {
    return FW_NVM_ERROR;
  }
  *len = n;
  return n == 0u ? FW_NVM_EMPTY : FW_NVM_OK;
}

fw_nvm_status_t fw_port_nvm_write(fw_port_t *port, const uint8_t *data, size_t len) {
  if (port == NULL || (data == NULL && len > 0u)) {
    return FW_NVM_ERROR;
  }
  if (!port->has_nvm) {
    return FW_NVM_UNSUPPORTED;
  }
  if (len == 0u) { /* erase */
    return (remove(port->path) == 0 || access(port->path, F_OK) != 0) ? FW_NVM_OK
                                                                       : FW_NVM_ERROR;
  }
  FILE *f = fopen(port->tmp, "wb");
  if (f == NULL) {
    return FW_NVM_ERROR;
  }
  size_t n = fwrite(data, 1u, len, f);
  int ok = n == len && fflush(f) == 0 && fsync(fileno(f)) == 0;
  ok = (fclose(f) == 0) && ok;
  if (!ok || rename(port->tmp, port->path) != 0) {
    (void)remove(port->tmp);
    return FW_NVM_ERROR;
  }
  return FW_NVM_OK;
}

/* ---- the simulated drive ----------------------------------------------------- */

static void sim_app_step_adc(void *ctx, const fw_adc_inputs_t *adc, fw_outputs_t *out) {
  sim_app_t *d = (sim_app_t *)ctx;
  d->port.adc = *adc;
  d->port.adc_fresh = 1u;
  fw_board_control_isr(&d->board);
  if (d->port.sup_pending) { /* tail-chained, before the duties take effect */
    d->port.sup_pending = 0u;
    fw_board_supervision_isr(&d->board);
  }
  for (int j = 0; j < 3; ++j) out->duty_abc[j] = d->port.duty[j];
  out->pwm_enable = d->port.pwm_on;
}

static void sim_app_background(void *ctx) { fw_board_background(&((sim_app_t *)ctx)->board); }

static void sim_app_sample_ref(void *ctx, uint8_t status, int32_t count) {
  sim_app_t *d = (sim_app_t *)ctx;
  d->port.ref_status = status;
  d->port.ref_count = count;
}

static void sim_app_snapshot(const void *ctx, fw_snapshot_t *snap) {
  fw_app_snapshot(&((const sim_app_t *)ctx)->app, snap);
}

sim_app_t *sim_app_new(const fw_config_t *cfg, uint8_t node_id, const char *nvm_path,
                       int *status) {
  int st_dummy;
  int *st = status != NULL ? status : &st_dummy;
  size_t n = nvm_path != NULL ? strlen(nvm_path) : 0u;
  if (cfg == NULL || n >= SIM_NVM_PATH_MAX) {
    *st = (int)FW_ERR_NULL;
    return NULL;
  }
  sim_app_t *d = (sim_app_t *)calloc(1u, sizeof *d);
  if (d == NULL) {
    *st = (int)FW_ERR_NULL;
    return NULL;
  }
  *st = (int)fw_app_init(&d->app, cfg, node_id);
  if (*st != (int)FW_OK && *st != (int)FW_ERR_SALIENCY) {
    free(d);
    return NULL;
  }
  if (n > 0u) {
    d->port.has_nvm = 1;
    memcpy(d->port.path, nvm_path, n + 1u);
    memcpy(d->port.tmp, nvm_path, n);
    memcpy(&d->port.tmp[n], ".tmp", 5u);
  }
  (void)fw_board_init(&d->board, &d->app, &d->port); /* boots from the file */
  return d;
}

void sim_app_free(sim_app_t *d) { free(d); }

void sim_app_controller(sim_app_t *d, uint32_t background_every, sim_controller_t *c) {
  memset(c, 0, sizeof *c);
  c->ctx = d;
  c->step_adc = sim_app_step_adc;
  c->snapshot = sim_app_snapshot;
  c->background = sim_app_background;
  c->sample_ref = sim_app_sample_ref;
  c->background_every = background_every > 0u ? background_every : 1u;
}

bool sim_app_can_rx(sim_app_t *d, const fw_can_frame_t *frame) {
  return fw_board_can_rx_isr(&d->board, frame);
}

bool sim_app_can_pop(sim_app_t *d, fw_can_frame_t *frame) {
  fw_port_t *p = &d->port;
  if (p->can_tail == p->can_head) {
    return false;
  }
  *frame = p->can[p->can_tail % SIM_PORT_CAN_LEN];
  p->can_tail++;
  return true;
}

size_t sim_app_uart_read(sim_app_t *d, uint8_t *buf, size_t cap) {
  fw_port_t *p = &d->port;
  size_t n = 0u;
  while (n < cap && p->uart_tail != p->uart_head) {
    buf[n++] = p->uart[p->uart_tail % SIM_PORT_UART_LEN];
    p->uart_tail++;
  }
  return n;
}

void sim_app_background_now(sim_app_t *d) { fw_board_background(&d->board); }

void *sim_app_fw_app(sim_app_t *d) { return &d->app; }

void sim_app_config(sim_app_t *d, fw_config_t *out) { *out = fw_app_ctrl(&d->app)->cfg; }

int sim_app_nvm_state(const sim_app_t *d) { return (int)fw_app_nvm_state(&d->app); }

uint32_t sim_app_crit_unbalanced(const sim_app_t *d) {
  return d->port.crit_unbalanced + (d->port.crit_depth != 0u ? 1u : 0u);
}
