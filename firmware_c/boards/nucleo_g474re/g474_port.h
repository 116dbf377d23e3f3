/**
 * @file g474_port.h
 * @brief The NUCLEO-G474RE port's state (struct fw_port) and the entry points
 *        the image's interrupt handlers and main() call (main.c).
 *        NOT YET TESTED ON SILICON.
 *
 * Interrupt priorities (four bits on the G4, level << 4; lower is more urgent):
 *   0  TIM1 break (the power stage's hardware trip: records it only)
 *   1  ADC1/ADC2 end of injected sequence = the control interrupt
 *   2  PendSV = the supervision interrupt (fw_port_supervision_pend)
 *   3  FDCAN1 line 0 (receive FIFO 0)
 *   4  DMA1 channel 1 (serial link transmission)
 *   background: main loop (fw_board_background, watchdog kick)
 * The critical section (fw_port_critical_enter) raises BASEPRI to level 1:
 * it masks the control interrupt and everything below, never the break.
 * NMI: flash ECC double error and the clock security system (main.c).
 */
#ifndef PMLSM_G474_PORT_H
#define PMLSM_G474_PORT_H

#include <stdatomic.h>
#include <stdbool.h>
#include <stdint.h>

#include "byte_ring.h"
#include "g474_calc.h"
#include "nvm_page.h"
#include "pmlsm/fw_board.h"
#include "pmlsm/fw_port.h"

#define G474_PRIO_BREAK 0u
#define G474_PRIO_CONTROL 1u
#define G474_PRIO_SUPERVISION 2u
#define G474_PRIO_CAN 3u
#define G474_PRIO_UART 4u

#define G474_SYSCLK_HZ 170000000u /**< SYSCLK = HCLK = PCLK1 = PCLK2 = TIM1 clock */
#define G474_HSE_HZ 24000000u     /**< NUCLEO-G474RE X3 crystal (UM2505) */
#define G474_LSI_HZ 32000u        /**< watchdog clock, nominal */
#define G474_IWDG_TIMEOUT_MS 250u /**< README.md, "Watchdog" */
#define G474_UART_RING 1024u      /**< serial transmit ring (power of two) */

/** board_fatal codes of this board (cm4_startup.c uses 0xDEAD, 0xBAD, 0xFA17). */
#define G474_FATAL_CLOCK 0xC10Cu     /**< HSE or PLL did not start, or a bad plan */
#define G474_FATAL_CSS 0xC55Fu       /**< clock security system: the HSE failed */
#define G474_FATAL_ECC 0xECCDu       /**< double ECC error outside the parameter page */
#define G474_FATAL_NMI 0x0A11u       /**< any other NMI */
#define G474_FATAL_ADC 0xADC0u       /**< ADC regulator, calibration or ready timeout */
#define G474_FATAL_PWM_PHASE 0x9A5Eu /**< TIM1's update event not on the counter peak */
#define G474_FATAL_CAN 0xCA70u       /**< FDCAN did not enter or leave initialisation */
#define G474_FATAL_CONFIG 0xCF60u    /**< a register value the plan cannot give */

struct fw_port {
  /* PWM */
  uint32_t arr;                 /**< TIM1 ARR (24 kHz centre-aligned) */
  uint32_t ccr_half;            /**< ARR / 2: the duties while off */
  _Atomic uint32_t brk_latched; /**< set by the break interrupt, taken by fw_port_hw_fault */
  uint32_t brk_count;           /**< break trips since power-up */
  /* ADC */
  uint32_t adc_pending; /**< the control interrupt saw ADC1's end of sequence */
  uint32_t adc_stale;   /**< periods whose ADC2 sequence was not complete */
  uint16_t adc_max;     /**< full-scale count (4095, or 8191 oversampled) */
  /* reference scale */
  uint32_t ref_referenced;   /**< the index has been seen (or none is wired) */
  uint32_t ref_origin;       /**< the count at the index */
  uint32_t ref_latch_missed; /**< periods without the TRGO capture: CNT read instead */
  /* CAN */
  uint32_t can_rx_dropped; /**< frames the application's queue refused */
  uint32_t can_rx_lost;    /**< RX FIFO 0 overflows (FDCAN IR.RF0L) */
  uint32_t can_bus_off;    /**< bus-off recoveries started */
  /* serial link: ring -> DMA1 channel 1 -> LPUART1 */
  byte_ring_t tx;
  uint8_t tx_buf[G474_UART_RING];
  uint32_t dma_len; /**< bytes in flight (0: idle), written at UART priority */
  uint32_t dma_errors;
  /* parameter page */
  nvm_page_t nvm;
  g474_nvm_geom_t geom;
  uint32_t flash_kb;
  uint32_t dual_bank;
  _Atomic uint32_t nvm_ecc_bad; /**< the NMI found a double ECC error in the page */
  uint32_t ecc_events;          /**< such errors since power-up */
  uint32_t flash_errors;        /**< FLASH_SR error flags seen by erase/program */
  /* diagnostics for the bring-up (read with the debugger) */
  uint32_t isr_cycles_max; /**< longest control interrupt (DWT cycles) */
  uint32_t isr_cycles_last;
};

/** Clocks: HSE -> PLL -> 170 MHz, range 1 boost, flash wait states. */
void g474_clock_init(void);

/** Everything but the interrupts and the counters: GPIO, TIM1 (outputs off),
 *  ADC1/ADC2, TIM2, FDCAN1, LPUART1 + DMA, the parameter page. */
void g474_port_init(fw_port_t *port);

/** Priorities, interrupts on, TIM1 started (its update event checked on the
 *  counter peak), the watchdog started. After fw_board_init. */
void g474_port_start(fw_port_t *port);

/** The background's watchdog kick. */
void g474_iwdg_kick(void);

/** Interrupt bodies (main.c's handlers call them). */
bool g474_adc_irq_ack(fw_port_t *port);
void g474_isr_cycles(fw_port_t *port, uint32_t start);
uint32_t g474_cycles(void);
void g474_brk_irq(fw_port_t *port);
void g474_can_rx_irq(fw_port_t *port, fw_board_t *board);
void g474_uart_dma_irq(fw_port_t *port);
void g474_nmi(fw_port_t *port);

/** Outputs off at once, whatever was initialised (board_fatal, NMI). */
void g474_outputs_off(void);

#endif /* PMLSM_G474_PORT_H */
