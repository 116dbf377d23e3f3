/**
 * @file fw_port.h
 * @brief The one hardware contract of the firmware.
 *
 * Everything hardware-shaped crosses this header: PWM, ADC, the reference
 * position sensor, CAN frames, UART bytes, critical sections, the
 * non-volatile parameter memory and what kind of drive the port makes. The
 * control core (fw_ctrl.h) does not call any of it: it is a pure step
 * function. The board glue (comm/src/fw_board.c: control interrupt ->
 * fw_app_isr -> PWM; background loop -> fw_app_background -> CAN/UART) is
 * the one caller of the port, in every world.
 *
 * There is no timer function: the drive's time base is the count of control
 * interrupts (fw_app.h), the same in simulation and on the MCU.
 *
 * A port defines `struct fw_port` with whatever it needs and implements
 * every function below. Ports in this repository:
 *   - port/blank/fw_port_blank.c : compiles anywhere, does nothing; proves the
 *     core has no hidden dependency (built for host and Cortex-M4F; the
 *     Cortex-M4F image links it).
 *   - sim_fallback/src/sim_port.c : the simulated drive: the ADC samples and
 *     duties of the plant's batch loop, CAN and UART queues read by the
 *     bench, one file per simulated drive as non-volatile memory.
 *   - tests/c/test_board.c : a test port that refuses frames and takes
 *     bytes piecemeal, to test the board glue.
 *   - boards/<name>/ : the board ports, one folder per board, nothing
 *     board-specific outside it (docs/boards.md): boards/mps2_an386/ the
 *     emulated board (QEMU: the image with the simulator's plant as its
 *     virtual motor), boards/nucleo_g474re/ the NUCLEO-G474RE with a
 *     three-shunt power stage (not yet tested on silicon); boards/_common/
 *     the glue they share.
 *
 * Non-volatile memory: the drive application stores one parameter block
 * (CiA 301 0x1010 'save', see fw_app.h). It does not call the two nvm
 * functions by name: the board glue hands them to fw_app_attach_nvm()
 * (fw_app_nvm_t), so the application links without a port, and a port
 * without storage returns FW_NVM_UNSUPPORTED (the drive then answers 'save'
 * with SDO abort 0x08000020 and reads 0 from 0x1010:1).
 *
 * Interrupt handlers copy and flag; the work happens in fw_app_isr (the
 * control interrupt: ADC to duties), fw_app_supervise (the supervision
 * interrupt it pends: monitors, protections, publication) and in the
 * background loop (everything else).
 */
#ifndef PMLSM_FW_PORT_H
#define PMLSM_FW_PORT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "fw_types.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Port instance, defined by each port. */
typedef struct fw_port fw_port_t;

/** A classic CAN frame (11-bit identifier). */
typedef struct {
  uint16_t id;     /**< 11-bit COB-ID */
  uint8_t dlc;     /**< 0..8 */
  uint8_t rtr;     /**< remote request */
  uint8_t data[8];
} fw_can_frame_t;

/** Latch duties for the next PWM period; enable=false opens all switches. */
void fw_port_pwm_write(fw_port_t *port, const float duty_abc[3], bool enable);

/** Pend the supervision interrupt (fw_board_supervision_isr): called by the
 *  control interrupt as its last act. The supervision must run before the
 *  duties just written take effect where the hardware allows it (a hard
 *  fault there writes the PWM off again), and in any case before the next
 *  control interrupt: at a priority below the control interrupt's and above
 *  the background's (Cortex-M: PendSV or a spare vector, tail-chained). A
 *  port that never runs it leaves the drive in FW_FAULT_SUPERVISION_MISSED,
 *  power stage off. */
void fw_port_supervision_pend(fw_port_t *port);

/**
 * A fault the power stage's hardware protection latched since the last call:
 * the PWM timer's break input (an overcurrent comparator, a gate driver's
 * fault output) has already switched the outputs off in hardware; the
 * control interrupt raises it in the core (FW_FAULT_POWER_STAGE_BREAK) at
 * its start. Returns a fw_fault_t code, 0 for none (a board without such an
 * input always returns 0).
 */
uint16_t fw_port_hw_fault(fw_port_t *port);

/** Read the ADC samples taken at the start of this PWM period. */
bool fw_port_adc_read(fw_port_t *port, fw_adc_inputs_t *adc);

/** Queue a CAN frame for transmission; false when the TX queue is full. */
bool fw_port_can_send(fw_port_t *port, const fw_can_frame_t *frame);

/** Queue bytes on the UART; returns the number accepted. */
size_t fw_port_uart_write(fw_port_t *port, const uint8_t *data, size_t len);

/** Enter / leave a critical section (disable / restore interrupts; the key
 *  is what enter returned, so sections nest). The background's changes of
 *  the control core are made inside one (fw_app_attach_lock). */
uint32_t fw_port_critical_enter(fw_port_t *port);
void fw_port_critical_exit(fw_port_t *port, uint32_t key);

/** What the port makes of the drive: published in 0x2090 (drive kind, board
 *  name) so that the bench labels every result from what the drive says,
 *  whatever interface reached it. kind is a fw_drive_kind_t (fw_enums.h:
 *  hardware, simulated, emulated, no I/O); board a static string. */
typedef struct {
  uint8_t kind;
  const char *board;
} fw_port_info_t;

/** Fill info (called once, by fw_board_init). */
void fw_port_info(fw_port_t *port, fw_port_info_t *info);

/**
 * Read the reference position sensor (on a linear rig, a quadrature scale)
 * latched at the sampling instant of this period's ADC conversion: called by
 * the control interrupt right after fw_port_adc_read. Returns a
 * fw_ref_status_t (FW_REF_NONE on a board without one; *count is then left
 * as it is). The count is the sensor's position in its counts from its
 * reference mark; the application scales it (0x2091:2, :3). The drive's
 * control never reads it: it is published beside the estimate for the
 * bench's judgement (docs/boards.md).
 */
uint8_t fw_port_ref_read(fw_port_t *port, int32_t *count);

/** Result of the non-volatile memory functions. */
typedef enum {
  FW_NVM_OK = 0,
  FW_NVM_UNSUPPORTED = 1, /**< this port has no non-volatile memory */
  FW_NVM_EMPTY = 2,       /**< read: nothing stored (erased or never written) */
  FW_NVM_ERROR = 3        /**< the medium failed, or the block does not fit */
} fw_nvm_status_t;

/**
 * Read the stored parameter block into buf (at most cap bytes); *len is its
 * size on FW_NVM_OK. The application checks the content (CRC, product,
 * firmware version) itself.
 */
fw_nvm_status_t fw_port_nvm_read(fw_port_t *port, uint8_t *buf, size_t cap, size_t *len);

/**
 * Replace the stored parameter block by data[0..len) - atomically where the
 * medium allows it (a torn write must read back as a block whose CRC fails,
 * never as a mix that passes). len == 0 erases it (FW_NVM_EMPTY afterwards).
 * Called from the SDO server in the background loop, outside any critical
 * section, while the power stage is off; a port whose medium is slow (flash
 * erase) may take milliseconds.
 */
fw_nvm_status_t fw_port_nvm_write(fw_port_t *port, const uint8_t *data, size_t len);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_PORT_H */
