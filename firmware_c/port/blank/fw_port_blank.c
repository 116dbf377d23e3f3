/**
 * @file fw_port_blank.c
 * @brief Blank port: every hardware function does nothing. It compiles for
 *        any target and proves the core needs nothing but this header.
 */
#include "pmlsm/fw_port.h"

struct fw_port {
  uint32_t unused;
};

void fw_port_pwm_write(fw_port_t *port, const float duty_abc[3], bool enable) {
  (void)port;
  (void)duty_abc;
  (void)enable;
}

void fw_port_supervision_pend(fw_port_t *port) { (void)port; }

void fw_port_info(fw_port_t *port, fw_port_info_t *info) {
  (void)port;
  info->kind = (uint8_t)FW_DRIVE_NO_IO;
  info->board = "blank";
}

uint8_t fw_port_ref_read(fw_port_t *port, int32_t *count) {
  (void)port;
  (void)count;
  return (uint8_t)FW_REF_NONE;
}

uint16_t fw_port_hw_fault(fw_port_t *port) {
  (void)port;
  return 0u;
}

bool fw_port_adc_read(fw_port_t *port, fw_adc_inputs_t *adc) {
  (void)port;
  adc->i_abc_counts[0] = 2048u;
  adc->i_abc_counts[1] = 2048u;
  adc->i_abc_counts[2] = 2048u;
  adc->u_dc_counts = 0u;
  return false;
}

bool fw_port_can_send(fw_port_t *port, const fw_can_frame_t *frame) {
  (void)port;
  (void)frame;
  return false;
}

size_t fw_port_uart_write(fw_port_t *port, const uint8_t *data, size_t len) {
  (void)port;
  (void)data;
  (void)len;
  return 0u;
}

uint32_t fw_port_critical_enter(fw_port_t *port) {
  (void)port;
  return 0u;
}

void fw_port_critical_exit(fw_port_t *port, uint32_t key) {
  (void)port;
  (void)key;
}

fw_nvm_status_t fw_port_nvm_read(fw_port_t *port, uint8_t *buf, size_t cap, size_t *len) {
  (void)port;
  (void)buf;
  (void)cap;
  if (len != NULL) {
    *len = 0u;
  }
  return FW_NVM_UNSUPPORTED;
}

fw_nvm_status_t fw_port_nvm_write(fw_port_t *port, const uint8_t *data, size_t len) {
  (void)port;
  (void)data;
  (void)len;
  return FW_NVM_UNSUPPORTED;
}
