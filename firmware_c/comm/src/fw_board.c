/**
 * @file fw_board.c
 * @brief The board glue between fw_app and fw_port (fw_board.h).
 */
#include "pmlsm/fw_board.h"

#include <string.h>

fw_app_nvm_state_t fw_board_init(fw_board_t *board, fw_app_t *app, fw_port_t *port) {
  if (board == NULL || app == NULL) {
    return FW_APP_NVM_NONE;
  }
  memset(board, 0, sizeof *board);
  board->app = app;
  board->port = port;
  const fw_app_lock_t lock = {port, fw_port_critical_enter, fw_port_critical_exit};
  fw_app_attach_lock(app, &lock);
  fw_port_info_t info = {(uint8_t)FW_DRIVE_NO_IO, ""};
  fw_port_info(port, &info);
  fw_app_set_board(app, info.kind, info.board);
  const fw_app_nvm_t nvm = {port, fw_port_nvm_read, fw_port_nvm_write};
  return fw_app_attach_nvm(app, &nvm);
}

void fw_board_control_isr(fw_board_t *board) {
  fw_adc_inputs_t adc;
  fw_outputs_t out;
  const uint16_t hw = fw_port_hw_fault(board->port);
  if (FW_UNLIKELY(hw != 0u)) { /* the outputs are off in hardware already */
    fw_raise_fault(fw_app_ctrl(board->app), (fw_fault_t)hw);
    board->hw_faults++;
  }
  if (!fw_port_adc_read(board->port, &adc)) {
    /* no fresh conversion: the core steps on what the port left in adc, and
       its range check and estimator monitors judge it */
    board->adc_failed++;
  }
  /* the reference sensor at the same instant, beside (never into) the control */
  int32_t count = 0;
  const uint8_t ref = fw_port_ref_read(board->port, &count);
  fw_app_ref_sample(board->app, ref, count);
  fw_app_isr(board->app, &adc, &out);
  fw_port_pwm_write(board->port, out.duty_abc, out.pwm_enable != 0u);
  fw_port_supervision_pend(board->port);
}

void fw_board_supervision_isr(fw_board_t *board) {
  fw_outputs_t out;
  if (fw_app_supervise(board->app, &out)) {
    fw_port_pwm_write(board->port, out.duty_abc, false); /* a hard fault: off now */
  }
}

bool fw_board_can_rx_isr(fw_board_t *board, const fw_can_frame_t *frame) {
  return fw_app_can_rx(board->app, frame);
}

void fw_board_background(fw_board_t *board) {
  fw_app_background(board->app);
  for (;;) {
    if (!board->tx_is_held) {
      if (!fw_app_can_tx_pop(board->app, &board->tx_held)) {
        break;
      }
      board->tx_is_held = 1u;
    }
    if (!fw_port_can_send(board->port, &board->tx_held)) {
      break; /* controller full: offered again next pass */
    }
    board->tx_is_held = 0u;
  }
  for (;;) {
    if (board->uart_off == board->uart_len) {
      board->uart_off = 0u;
      board->uart_len = (uint16_t)fw_app_uart_read(board->app, board->uart, sizeof board->uart);
      if (board->uart_len == 0u) {
        break;
      }
    }
    size_t n = fw_port_uart_write(board->port, &board->uart[board->uart_off],
                                  (size_t)(board->uart_len - board->uart_off));
    if (n == 0u) {
      break;
    }
    board->uart_off = (uint16_t)(board->uart_off + n);
  }
}
