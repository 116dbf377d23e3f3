/**
 * @file emu_board.h
 * @brief The emulated board (QEMU mps2-an386 + the simulator's plant as its
 *        virtual motor): its port (struct fw_port) and what the interrupt
 *        handlers and the background loop share. docs: emu_main.c.
 */
#ifndef PMLSM_EMU_BOARD_H
#define PMLSM_EMU_BOARD_H

#include <stdint.h>

#include "byte_ring.h"
#include "cm4.h"
#include "emu_flash.h"
#include "nvm_page.h"
#include "pmlsm/fw_port.h"
#include "pmlsm_sim.h"
#include "slcan.h"

/** Timer periods per drive period: the PWM timer runs D times slower in QEMU's
 *  virtual time (1 ns per instruction) than the drive's nominal period, so the
 *  plant (soft-float double) and the control fit in one; the plant still
 *  advances 1/f_pwm per period. Idle time is skipped (-icount sleep=off): D
 *  costs no wall time (measured: the same speed at D = 3 and 12). 12: the
 *  worst period measured (151 k instructions, a speed reversal) under half of
 *  the 500 k of one timer period (README.md). CMake: PMLSM_EMU_DILATION. */
#ifndef EMU_DILATION
#define EMU_DILATION 12u
#endif

/* Interrupt priorities (levels, 0 most urgent): the PWM timer first (it plays
   the hardware: the virtual motor's period must not wait), then the UART
   receive interrupts (one byte into a ring: the FIFO QEMU's UART lacks; above
   the drive's interrupts, so QEMU's next byte is not held back by a control
   period), the control interrupt, the supervision (PendSV). The drive's
   critical section raises BASEPRI to the control level: the timer and the
   receivers run on. The load machine's changes of the plant mask all (PRIMASK:
   an assignment, or sim_set_params re-deriving the plant's constants). */
#define EMU_PRIO_TIMER0 0u
#define EMU_PRIO_UART_RX 1u
#define EMU_PRIO_CONTROL 2u
#define EMU_PRIO_SUPERVISION 3u

#define EMU_CAN_RX_LEN 1024u  /**< UART0 bytes from the host (power of two) */
#define EMU_CAN_TX_LEN 4096u  /**< UART0 bytes to the host */
#define EMU_TEL_TX_LEN 8192u  /**< UART1 telemetry bytes */
#define EMU_LOAD_RX_LEN 256u  /**< UART2 bytes from the load machine's host */
#define EMU_LOAD_TX_LEN 1024u /**< UART2 replies */

/** Cost of one part, in SYSCLK ticks (EMU_INSN_PER_TICK instructions each),
 *  exclusive of the interrupts that preempted it. */
typedef struct {
  uint32_t n;      /**< runs measured */
  uint32_t max;    /**< largest */
  uint32_t max_at; /**< drive period of the largest */
  uint32_t last;
  uint64_t sum;
} emu_cost_t;

typedef struct {
  emu_cost_t plant;       /**< TIMER0: ADC and scale sampling, one plant period */
  emu_cost_t control;     /**< control interrupt: fw_board_control_isr */
  emu_cost_t supervision; /**< PendSV: fw_board_supervision_isr */
  emu_cost_t period;      /**< the three of one period */
  emu_cost_t background;  /**< one pass of the background loop (busy passes only) */
  emu_cost_t rx;          /**< one UART receive interrupt */
  uint32_t inner;         /**< exclusive ticks of completed handlers (nesting) */
  uint32_t period_acc;    /**< this period's ticks so far */
} emu_prof_t;

struct fw_port {
  /* the virtual motor: the PWM timer interrupt's side */
  sim_t *sim;
  fw_adc_inputs_t adc; /**< this period's conversion (TIMER0) */
  uint8_t adc_fresh;
  uint8_t ref_status; /**< this period's scale reading (TIMER0) */
  int32_t ref_count;
  volatile float duty[3]; /**< latched by the control interrupt for the next period */
  volatile uint8_t pwm_on;
  volatile uint8_t period_busy; /**< set by TIMER0, cleared when the supervision ends */
  volatile uint32_t overruns;   /**< TIMER0 periods that found the last one unfinished */
  volatile uint32_t periods;    /**< TIMER0 periods (the drive's time base, as hardware) */
  uint32_t f_pwm_int_Hz;        /**< the PWM rate, whole hertz (> 0) */
  /* CAN: UART0 speaking slcan */
  slcan_t slcan;
  byte_ring_t can_rx, can_tx;
  uint32_t can_tx_dropped; /**< drive frames while the channel was closed */
  uint32_t can_rx_held;    /**< frames parsed while the drive's queue was full (held) */
  fw_can_frame_t rx_frame; /**< a parsed frame the drive's queue refused, offered again */
  uint8_t rx_frame_held;
  /* telemetry: UART1 */
  byte_ring_t tel_tx;
  /* non-volatile memory */
  uint8_t has_nvm;
  emu_flash_t flash;
  nvm_page_t page;
  /* byte counts (diagnostics: the link rates) */
  volatile uint32_t can_rx_bytes, load_rx_bytes;
  uint32_t can_tx_bytes, tel_tx_bytes, replies_dropped;
  /* cost measurements */
  emu_prof_t prof;
  /* ring storage */
  uint8_t can_rx_buf[EMU_CAN_RX_LEN];
  uint8_t can_tx_buf[EMU_CAN_TX_LEN];
  uint8_t tel_tx_buf[EMU_TEL_TX_LEN];
};

/** The fatal path of the board (cm4_startup.c): a console line, exit status 3. */
void board_fatal(uint32_t code);

#endif /* PMLSM_EMU_BOARD_H */
