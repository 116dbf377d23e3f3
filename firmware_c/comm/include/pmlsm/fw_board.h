/**
 * @file fw_board.h
 * @brief The board glue, once: what the interrupt handlers and the
 *        background loop of every world do with the drive application
 *        (fw_app.h) and the port (fw_port.h).
 *
 * The Cortex-M4F image (target/cm4/main.c) and the simulated drive
 * (sim_fallback/src/sim_port.c) both run the drive through these four
 * functions, so the code between a port and the application exists once:
 *
 *     fw_board_t board;
 *     fw_board_init(&board, &app, &port);         // after fw_app_init: boots from storage
 *     PWM/ADC interrupt: fw_board_control_isr(&board);   // pends the next
 *     supervision:       fw_board_supervision_isr(&board);
 *     CAN RX interrupt:  fw_board_can_rx_isr(&board, &frame);
 *     main loop:         for (;;) fw_board_background(&board);
 *
 * fw_board_init tells the application what the port makes of the drive
 * (fw_port_info: 0x2090). The control interrupt first raises a fault the
 * power stage's hardware protection latched (fw_port_hw_fault: the outputs
 * are off in hardware already), then reads the ADC and the
 * reference position sensor (fw_port_ref_read, handed to fw_app_ref_sample:
 * published, never controlled on), runs fw_app_isr (conversion, control
 * step) and latches the duties, then pends the supervision interrupt, which
 * runs fw_app_supervise (integrity monitor, protections, publication) and
 * writes the PWM off when that found a hard fault. The background runs
 * fw_app_background and moves the frames and bytes the application produced
 * to the port; a frame or bytes the port cannot take now are held and
 * offered again on the next call, never dropped here. The application's
 * changes of the core from the background are made inside the port's
 * critical section (fw_port_critical_enter/exit).
 */
#ifndef PMLSM_FW_BOARD_H
#define PMLSM_FW_BOARD_H

#include <stdbool.h>
#include <stdint.h>

#include "pmlsm/fw_app.h"
#include "pmlsm/fw_port.h"

#ifdef __cplusplus
extern "C" {
#endif

#ifndef FW_BOARD_UART_CHUNK
#define FW_BOARD_UART_CHUNK 64u /**< bytes moved to the UART per attempt */
#endif

/** Board glue state, caller-owned. Treat the members as private. */
typedef struct {
  fw_app_t *app;
  fw_port_t *port;
  fw_can_frame_t tx_held; /**< a frame the port refused, offered again */
  uint8_t tx_is_held;
  uint8_t uart[FW_BOARD_UART_CHUNK]; /**< bytes the port has not taken yet */
  uint16_t uart_off, uart_len;
  uint32_t adc_failed; /**< control periods whose ADC read failed (stepped anyway) */
  uint32_t hw_faults;  /**< hardware protection trips the port reported (fw_port_hw_fault) */
} fw_board_t;

/**
 * Bind an initialised application to a port: attaches the port's critical
 * section as the application's lock and its non-volatile memory (the boot,
 * fw_app_attach_nvm). Call once, before the interrupts run. Returns the
 * boot's fw_app_nvm_state_t.
 */
fw_app_nvm_state_t fw_board_init(fw_board_t *board, fw_app_t *app, fw_port_t *port);

/** The PWM/ADC interrupt: ADC -> fw_app_isr -> PWM, then pends the
 *  supervision interrupt (fw_port_supervision_pend). */
void fw_board_control_isr(fw_board_t *board);

/** The supervision interrupt (lower priority than the control interrupt,
 *  higher than the background): fw_app_supervise; a hard fault it finds
 *  writes the PWM off at once. */
void fw_board_supervision_isr(fw_board_t *board);

/** The CAN receive interrupt: queue the frame. False when the queue is full. */
bool fw_board_can_rx_isr(fw_board_t *board, const fw_can_frame_t *frame);

/** One pass of the background loop. */
void fw_board_background(fw_board_t *board);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_BOARD_H */
