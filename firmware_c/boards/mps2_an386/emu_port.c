/**
 * @file emu_port.c
 * @brief fw_port.h on the emulated board: the virtual motor's ADC, scale and
 *        PWM latch (filled and applied by the TIMER0 interrupt, emu_main.c),
 *        CAN frames as slcan lines on UART0, telemetry bytes on UART1, the
 *        critical section as BASEPRI, the flash page with a host file behind.
 */
#include <string.h>

#include "emu_board.h"
#include "emu_hw.h"

void fw_port_pwm_write(fw_port_t *port, const float duty_abc[3], bool enable) {
  for (int j = 0; j < 3; ++j) {
    port->duty[j] = duty_abc[j];
  }
  port->pwm_on = enable ? 1u : 0u;
}

void fw_port_supervision_pend(fw_port_t *port) {
  (void)port;
  cm4_pendsv_set();
}

uint16_t fw_port_hw_fault(fw_port_t *port) {
  (void)port;
  return 0u; /* the virtual power stage has no break input */
}

bool fw_port_adc_read(fw_port_t *port, fw_adc_inputs_t *adc) {
  *adc = port->adc;
  const bool fresh = port->adc_fresh != 0u;
  port->adc_fresh = 0u;
  return fresh;
}

uint8_t fw_port_ref_read(fw_port_t *port, int32_t *count) {
  if (port->ref_status != (uint8_t)FW_REF_NONE) {
    *count = port->ref_count;
  }
  return port->ref_status;
}

bool fw_port_can_send(fw_port_t *port, const fw_can_frame_t *frame) {
  if (!slcan_is_open(&port->slcan)) {
    port->can_tx_dropped++; /* the adapter is off the bus */
    return true;
  }
  char line[SLCAN_FRAME_MAX];
  /* time stamps (Z1): the drive's time in ms, from its PWM period count */
  const uint32_t ms = (uint32_t)((uint64_t)port->periods * 1000u / port->f_pwm_int_Hz);
  const size_t n = slcan_encode(&port->slcan, frame, ms, line, sizeof line);
  if (n == 0u) {
    port->can_tx_dropped++; /* not an 11-bit frame */
    return true;
  }
  if ((size_t)(port->can_tx.mask + 1u - byte_ring_used(&port->can_tx)) < n) {
    return false; /* the host link is behind: the board glue offers it again */
  }
  (void)byte_ring_write(&port->can_tx, (const uint8_t *)line, n);
  return true;
}

size_t fw_port_uart_write(fw_port_t *port, const uint8_t *data, size_t len) {
  return byte_ring_write(&port->tel_tx, data, len);
}

uint32_t fw_port_critical_enter(fw_port_t *port) {
  (void)port;
  return cm4_critical_enter(EMU_PRIO_CONTROL); /* never masks the PWM timer */
}

void fw_port_critical_exit(fw_port_t *port, uint32_t key) {
  (void)port;
  cm4_critical_exit(key);
}

void fw_port_info(fw_port_t *port, fw_port_info_t *info) {
  (void)port;
  info->kind = (uint8_t)FW_DRIVE_EMULATED;
  info->board = "mps2_an386";
}

fw_nvm_status_t fw_port_nvm_read(fw_port_t *port, uint8_t *buf, size_t cap, size_t *len) {
  if (port == NULL || buf == NULL || len == NULL) {
    return FW_NVM_ERROR;
  }
  if (!port->has_nvm) {
    *len = 0u;
    return FW_NVM_UNSUPPORTED;
  }
  return nvm_page_read(&port->page, buf, cap, len);
}

fw_nvm_status_t fw_port_nvm_write(fw_port_t *port, const uint8_t *data, size_t len) {
  if (port == NULL) {
    return FW_NVM_ERROR;
  }
  if (!port->has_nvm) {
    return FW_NVM_UNSUPPORTED;
  }
  return nvm_page_write(&port->page, data, len);
}
