/**
 * @file main.c
 * @brief Minimal Cortex-M4F image of the whole drive application: control
 *        core + CANopen slave + serial telemetry (fw_app), run through the
 *        board glue (fw_board.h) over the blank port, as the interrupt
 *        handlers and the main loop of a real board run it. Exists to prove
 *        the firmware cross-compiles and links, and to measure its size
 *        (text/data/bss printed by the build).
 */
#include "pmlsm/fw_app.h"
#include "pmlsm/fw_board.h"
#include "pmlsm/fw_port.h"

struct fw_port {
  uint32_t unused;
};

/* application-owned instances (the core has no globals) */
static fw_app_t g_app;
static fw_board_t g_board;
static struct fw_port g_port;

/** PWM/ADC interrupt: ADC -> control step -> duties, nothing else. */
void pwm_adc_irq_handler(void);
void pwm_adc_irq_handler(void) { fw_board_control_isr(&g_board); }

/** Supervision interrupt (PendSV on a board: pended by the control interrupt,
 *  tail-chained to it): monitors, protections, publication. */
void supervision_irq_handler(void);
void supervision_irq_handler(void) { fw_board_supervision_isr(&g_board); }

/** CAN receive interrupt: copy and queue only (processed by the background loop). */
void can_rx_irq_handler(const fw_can_frame_t *frame);
void can_rx_irq_handler(const fw_can_frame_t *frame) {
  (void)fw_board_can_rx_isr(&g_board, frame);
}

int main(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  (void)fw_app_init(&g_app, &cfg, 1u);
  /* Lock = the port's critical section; boot from the non-volatile memory
     (CiA 301 0x1010/0x1011). The blank port has none (FW_NVM_UNSUPPORTED:
     'save' is refused with SDO abort 0x08000020). TODO(board port): one
     flash sector - erase + program in fw_port_nvm_write, called from the
     background loop with the power stage off; a torn write fails the
     block's CRC and the drive boots on defaults. */
  (void)fw_board_init(&g_board, &g_app, &g_port);
  /* TODO(board port): enable the PWM/ADC and CAN interrupts here. Without
     them (this image) the loop steps the control and the supervision once
     per pass. */
  for (;;) {
    pwm_adc_irq_handler();
    supervision_irq_handler(); /* the blank port does not pend it */
    fw_board_background(&g_board);
  }
}
