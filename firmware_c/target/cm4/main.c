/**
 * @file main.c
 * @brief Minimal Cortex-M4F image: the control core driven through the blank
 *        port, as an interrupt handler would drive it. Exists to prove the
 *        core cross-compiles and links, and to measure its size.
 */
#include "pmlsm/fw_ctrl.h"
#include "pmlsm/fw_port.h"

struct fw_port {
  uint32_t unused;
};

static fw_ctrl_t g_ctrl; /* application-owned instance (not in the core) */
static struct fw_port g_port;

/** What the PWM/ADC interrupt does every period. */
void pwm_adc_irq_handler(void);
void pwm_adc_irq_handler(void) {
  fw_adc_inputs_t adc;
  fw_outputs_t out;
  (void)fw_port_adc_read(&g_port, &adc);
  fw_step_adc(&g_ctrl, &adc, &out);
  fw_port_pwm_write(&g_port, out.duty_abc, out.pwm_enable != 0u);
}

int main(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  (void)fw_init(&g_ctrl, &cfg);
  for (;;) {
    pwm_adc_irq_handler();
  }
}
