/**
 * @file fw_port.h
 * @brief The one hardware contract of the firmware.
 *
 * Everything hardware-shaped crosses this header: PWM, ADC, CAN frames,
 * UART bytes, time and critical sections. The control core (fw_ctrl.h) does
 * not call any of it: it is a pure step function. The application glue
 * (fw_app.c: interrupt -> fw_step -> PWM, CAN/UART queues) calls the port.
 *
 * A port defines `struct fw_port` with whatever it needs and implements
 * every function below. Ports in this repository:
 *   - port/blank/fw_port_blank.c : compiles anywhere, does nothing; proves the
 *     core has no hidden dependency (built for host and Cortex-M4F).
 *   - sim_fallback/src : the simulated drive (plant + ADC + inverter model).
 *
 * Interrupt handlers copy and flag; work happens in the step function.
 */
#ifndef PMLSM_FW_PORT_H
#define PMLSM_FW_PORT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "fw_ctrl.h"

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

/** Read the ADC samples taken at the start of this PWM period. */
bool fw_port_adc_read(fw_port_t *port, fw_adc_inputs_t *adc);

/** Monotonic time in microseconds (wraps). */
uint32_t fw_port_time_us(fw_port_t *port);

/** Queue a CAN frame for transmission; false when the TX queue is full. */
bool fw_port_can_send(fw_port_t *port, const fw_can_frame_t *frame);

/** Queue bytes on the UART; returns the number accepted. */
size_t fw_port_uart_write(fw_port_t *port, const uint8_t *data, size_t len);

/** Enter / leave a critical section (disable / restore interrupts). */
uint32_t fw_port_critical_enter(fw_port_t *port);
void fw_port_critical_exit(fw_port_t *port, uint32_t key);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_PORT_H */
