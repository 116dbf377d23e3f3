/**
 * @file main.c
 * @brief Minimal Cortex-M4F image of the whole drive application: control
 *        core + CANopen slave + serial telemetry (fw_app), driven through the
 *        blank port as the interrupt handlers of a real board would drive it.
 *        Exists to prove the firmware cross-compiles and links, and to measure
 *        its size (text/data/bss printed by the build).
 */
#include "pmlsm/fw_app.h"
#include "pmlsm/fw_port.h"

struct fw_port {
  uint32_t unused;
};

static fw_app_t g_app; /* application-owned instance (the core has no globals) */
static struct fw_port g_port;

/** PWM/ADC interrupt: sample, one control step, latch duties, drain CAN/UART. */
void pwm_adc_irq_handler(void);
void pwm_adc_irq_handler(void) {
  fw_adc_inputs_t adc;
  fw_inputs_t in;
  fw_outputs_t out;
  (void)fw_port_adc_read(&g_port, &adc);
  fw_ctrl_t *ctrl = fw_app_ctrl(&g_app);
  if (!fw_adc_convert(fw_get_config(ctrl), &adc, &in)) { /* the core's one ADC scaling */
    fw_raise_fault(ctrl, FW_FAULT_ADC_RANGE);
  }
  fw_app_step(&g_app, &in, &out);
  fw_port_pwm_write(&g_port, out.duty_abc, out.pwm_enable != 0u);
  fw_can_frame_t f;
  while (fw_app_can_tx_pop(&g_app, &f) && fw_port_can_send(&g_port, &f)) {
  }
  uint8_t buf[64];
  size_t n = fw_app_uart_read(&g_app, buf, sizeof buf);
  (void)fw_port_uart_write(&g_port, buf, n);
}

/** CAN receive interrupt: copy and queue only (processed in the control step). */
void can_rx_irq_handler(const fw_can_frame_t *frame);
void can_rx_irq_handler(const fw_can_frame_t *frame) { (void)fw_app_can_rx(&g_app, frame); }

int main(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  (void)fw_app_init(&g_app, &cfg, 1u);
  /* Boot from the non-volatile memory (CiA 301 0x1010/0x1011). The blank
     port has none (FW_NVM_UNSUPPORTED: 'save' is refused with SDO abort
     0x08000020). TODO(board port): one flash sector - erase + program in
     fw_port_nvm_write, called from the SDO server with the power stage off;
     a torn write fails the block's CRC and the drive boots on defaults. */
  const fw_app_nvm_t nvm = {&g_port, fw_port_nvm_read, fw_port_nvm_write};
  (void)fw_app_attach_nvm(&g_app, &nvm);
  for (;;) {
    pwm_adc_irq_handler();
  }
}
