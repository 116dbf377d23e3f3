/**
 * @file emu_hw.h
 * @brief The peripherals of QEMU's mps2-an386 machine (ARM AN386 FPGA image:
 *        Cortex-M4F, CMSDK APB UARTs and timers) that the emulated board
 *        uses, from QEMU's hw/arm/mps2.c, hw/char/cmsdk-apb-uart.c and
 *        hw/timer/cmsdk-apb-timer.c (and ARM DDI 0479, the CMSDK TRM).
 *
 * Memory: ZBT SSRAM1 0x00000000 (4 MiB, code), SSRAM2/3 0x20000000 (4 MiB,
 * data), PSRAM 0x21000000 (16 MiB: the boot block is loaded there).
 * SYSCLK 25 MHz: at -icount shift=0 (1 ns per instruction) one timer tick
 * is 40 instructions.
 */
#ifndef PMLSM_EMU_HW_H
#define PMLSM_EMU_HW_H

#include <stdint.h>

#include "cm4.h"

#define EMU_SYSCLK_HZ 25000000u
#define EMU_INSN_PER_TICK 40u /**< instructions per SYSCLK tick at -icount shift=0 */

#define EMU_PSRAM_BASE 0x21000000u
#define EMU_PSRAM_SIZE 0x01000000u

/* CMSDK APB UART (QEMU holds one received byte: no FIFO) */
#define EMU_UART0_BASE 0x40004000u /**< CAN: the slcan endpoint */
#define EMU_UART1_BASE 0x40005000u /**< serial telemetry */
#define EMU_UART2_BASE 0x40006000u /**< the virtual load machine */
#define EMU_UART_DATA 0x00u
#define EMU_UART_STATE 0x04u
#define EMU_UART_CTRL 0x08u
#define EMU_UART_INTSTATUS 0x0Cu /**< write 1 to clear */
#define EMU_UART_BAUDDIV 0x10u   /**< >= 16 */
#define EMU_UART_STATE_TXFULL 0x01u
#define EMU_UART_STATE_RXFULL 0x02u
#define EMU_UART_STATE_TXOVR 0x04u
#define EMU_UART_STATE_RXOVR 0x08u
#define EMU_UART_CTRL_TXEN 0x01u
#define EMU_UART_CTRL_RXEN 0x02u
#define EMU_UART_CTRL_TXINTEN 0x04u
#define EMU_UART_CTRL_RXINTEN 0x08u
#define EMU_UART_INT_TX 0x01u
#define EMU_UART_INT_RX 0x02u

/* CMSDK APB timer (32-bit down-counter at SYSCLK) */
#define EMU_TIMER0_BASE 0x40000000u /**< the PWM timer: the virtual motor's period */
#define EMU_TIMER1_BASE 0x40001000u /**< free running: the cost measurements */
#define EMU_TIMER_CTRL 0x00u
#define EMU_TIMER_VALUE 0x04u
#define EMU_TIMER_RELOAD 0x08u
#define EMU_TIMER_INTCLEAR 0x0Cu
#define EMU_TIMER_CTRL_EN 0x01u
#define EMU_TIMER_CTRL_IRQEN 0x08u

/* NVIC lines (32 on this machine) */
#define EMU_IRQ_UART0_RX 0u
#define EMU_IRQ_UART2_RX 4u
#define EMU_IRQ_TIMER0 8u
#define EMU_IRQ_CONTROL 31u /**< no device on it: the control interrupt, pended by TIMER0 */
#define EMU_IRQ_COUNT 32u

static inline uint32_t emu_rd(uint32_t base, uint32_t off) {
  return CM4_REG(base + off);
}
static inline void emu_wr(uint32_t base, uint32_t off, uint32_t v) {
  CM4_REG(base + off) = v;
}

#endif /* PMLSM_EMU_HW_H */
